"""Synthetic monocular video of retargeted people filmed by a slowly moving hand-held camera (3DPW-like).

:func:`synthesise_video` poses a :class:`~mocap.BodyMotion` with :func:`geometry.body_forward`, places a
camera that keeps everyone in view for the whole clip, moves it slowly (an orbit about the people, a dolly
towards or away from them and a smooth hand-held wobble), renders every frame with
:func:`~mocap.render_people` and returns the ground truth a mesh-from-video model trains on, all in the
CAMERA frame (OpenCV axes: x right, y down, z forward, metres): SMPL24 local rotations whose root carries
the person's orientation in the camera frame, betas, a translation such that
``body_forward(model, rotations[p, t], betas[p], translation[p, t])`` gives the camera-frame mesh and joints,
the joints in 3D and in pixels, tight boxes and how much of each person is visible.

Pixels follow :mod:`geometry._camera`: pixel (column c, row r) is centred at image coordinates (c, r), the
principal point is the image centre ``((W - 1) / 2, (H - 1) / 2)``, so the horizontal mirror
(:func:`flip_video`) maps ``x`` to ``W - 1 - x``.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import numpy as np
from jaxtyping import Array, ArrayLike, Float, UInt8

import geometry
from geometry import BodyModel, Camera

from ._render import covered_pixels, render_people
from ._retarget import BodyMotion, _rest_joints

__all__ = ["Video", "VideoConfig", "flip_video", "jitter_boxes", "mirror_pose", "synthesise_video"]

_MIRROR_X = np.diag([-1.0, 1.0, 1.0])
"""The mirror of the camera frame that a horizontal image flip is."""


@dataclasses.dataclass(frozen=True)
class VideoConfig:
    """How :func:`synthesise_video` films a motion."""

    image_size: tuple[int, int] = (320, 240)
    """(width, height), pixels."""
    focal: float = 300.0
    """Focal length, pixels (square pixels, no skew); principal point at the image centre, no distortion."""
    distance: tuple[float, float] = (3.5, 6.0)
    """Range of the camera's starting horizontal distance from the people's mean pelvis, metres; the
    distance is increased beyond it where needed to keep everyone in view."""
    height: tuple[float, float] = (1.0, 1.8)
    """Range of the camera centre's height above the ground (z = 0), metres."""
    orbit_speed: float = 6.0
    """Largest orbit rate about the people, degrees per second (the rate is drawn in +-this)."""
    dolly_speed: float = 0.1
    """Largest rate of change of the camera's distance, metres per second (drawn in +-this)."""
    wobble_shift: float = 0.01
    """Largest hand-held displacement of the camera centre along each world axis, metres."""
    wobble_angle: float = 0.5
    """Largest hand-held pan and tilt, degrees (no roll: the camera stays upright)."""
    wobble_frequency: float = 1.0
    """Highest frequency in the hand-held wobble, hertz."""
    margin: float = 0.05
    """Fraction of the image width and height kept free of the people on every side."""

    def __post_init__(self) -> None:
        width, height = self.image_size
        if width < 1 or height < 1:
            raise ValueError(f"image_size must be positive (width, height) pixels, got {self.image_size}")
        for name in ("distance", "height"):
            low, high = getattr(self, name)
            if not 0 < low <= high:
                raise ValueError(f"{name} must be a range 0 < low <= high (metres), got {(low, high)}")
        if not self.focal > 0:
            raise ValueError(f"focal must be positive (pixels), got {self.focal}")
        for name in ("orbit_speed", "dolly_speed", "wobble_shift", "wobble_angle", "wobble_frequency"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"{name} must be non-negative, got {getattr(self, name)}")
        if not 0 <= self.margin < 0.5:
            raise ValueError(f"margin must be a fraction in [0, 0.5), got {self.margin}")

    @property
    def intrinsics(self) -> Float[np.ndarray, "3 3"]:
        """K, pixels: the principal point at the image centre."""
        width, height = self.image_size
        return np.array([[self.focal, 0.0, (width - 1) / 2], [0.0, self.focal, (height - 1) / 2], [0.0, 0.0, 1.0]])


class Video(NamedTuple):
    """A rendered clip and its camera-frame ground truth (NumPy, except the camera)."""

    frames: UInt8[np.ndarray, "T H W 3"]
    """RGB frames."""
    camera: Camera
    """Per-frame camera (leaves with a leading T axis): K, world-to-camera R and t (metres), zero distortion and
    the image size; the world is the motion's z-up world."""
    rotations: Float[np.ndarray, "P T 24 3 3"]
    """SMPL24 local rotations; the root's is its GLOBAL orientation in the camera frame."""
    betas: Float[np.ndarray, "P S"]
    translation: Float[np.ndarray, "P T 3"]
    """Camera frame, metres: ``body_forward(model, rotations[p, t], betas[p], translation[p, t])`` is the person
    in the camera frame."""
    joints3d: Float[np.ndarray, "P T 24 3"]
    """SMPL24 joints in the camera frame, metres."""
    joints2d: Float[np.ndarray, "P T 24 2"]
    """SMPL24 joints in pixels."""
    boxes: Float[np.ndarray, "P T 4"]
    """``(x0, y0, x1, y1)`` pixels: the tight box of the person's projected vertices (not clipped to the image)."""
    visibility: Float[np.ndarray, "P T"]
    """Visible fraction of the person's projected area, with the others and the image border cutting it."""


_POSE_CHUNK = 16
"""Frames posed per call of the jitted kernel (one compilation for every clip length, bounded memory)."""

_pose_frames = jax.jit(jax.vmap(geometry.body_forward, in_axes=(None, 0, None, 0)))


def _pose_person(model: BodyModel, rotations: Float[np.ndarray, "T 24 3 3"], betas: Float[np.ndarray, "S"],
                 translation: Float[np.ndarray, "T 3"]) -> tuple[np.ndarray, np.ndarray]:
    """World vertices ``(T, V, 3)`` and joints ``(T, 24, 3)`` (metres) of one person over the frames."""
    num_frames = len(rotations)
    padded = -(-num_frames // _POSE_CHUNK) * _POSE_CHUNK
    repeat_last = np.minimum(np.arange(padded), num_frames - 1)
    rotations, translation = rotations[repeat_last], translation[repeat_last]
    outputs = [_pose_frames(model, rotations[start:start + _POSE_CHUNK], betas, translation[start:start + _POSE_CHUNK])
               for start in range(0, padded, _POSE_CHUNK)]
    vertices = np.concatenate([np.asarray(out.vertices, np.float64) for out in outputs])[:num_frames]
    joints = np.concatenate([np.asarray(out.joints, np.float64) for out in outputs])[:num_frames]
    return vertices, joints


def _smooth_wobble(times: Float[np.ndarray, "T"], amplitude: float, frequency: float, channels: int,
                   rng: np.random.Generator) -> Float[np.ndarray, "T C"]:
    """Smooth random signals, at most ``amplitude`` in size: the mean of three sines per channel with random
    phases and frequencies up to ``frequency`` (hertz)."""
    frequencies = rng.uniform(0.2, 1.0, (channels, 3)) * frequency
    phases = rng.uniform(0.0, 2 * np.pi, (channels, 3))
    waves = np.sin(2 * np.pi * frequencies[None] * times[:, None, None] + phases[None])
    return amplitude * waves.mean(axis=-1)


class _CameraPath(NamedTuple):
    """The random part of a camera trajectory; the starting distance is fitted afterwards."""

    centre: Float[np.ndarray, "3"]
    """The people's mean pelvis, looked at, metres."""
    azimuth: Float[np.ndarray, "T"]
    """Direction from the centre to the camera, radians about world z."""
    distance_change: Float[np.ndarray, "T"]
    """Dolly: horizontal distance minus the starting distance, metres."""
    height: float
    """Camera centre above the ground before the wobble, metres."""
    shift: Float[np.ndarray, "T 3"]
    """Hand-held displacement of the camera centre, metres."""
    pan_tilt: Float[np.ndarray, "T 2"]
    """Hand-held turn about the camera's y (pan) and x (tilt) axes, radians."""


def _random_path(centre: np.ndarray, num_frames: int, fps: float, config: VideoConfig,
                 rng: np.random.Generator) -> _CameraPath:
    times = np.arange(num_frames) / fps
    azimuth = rng.uniform(0.0, 2 * np.pi) + np.radians(rng.uniform(-1.0, 1.0) * config.orbit_speed) * times
    distance_change = rng.uniform(-1.0, 1.0) * config.dolly_speed * times
    height = rng.uniform(*config.height)
    shift = _smooth_wobble(times, config.wobble_shift, config.wobble_frequency, 3, rng)
    pan_tilt = _smooth_wobble(times, np.radians(config.wobble_angle), config.wobble_frequency, 2, rng)
    return _CameraPath(centre, azimuth, distance_change, float(height), shift, pan_tilt)


@jax.jit
def _looking_and_turning(eye: Float[ArrayLike, "T 3"], target: Float[ArrayLike, "3"],
                         turn: Float[ArrayLike, "T 3"]) -> tuple[Float[Array, "T 3 3"], Float[Array, "T 3 3"]]:
    """The rotations looking from each ``eye`` at ``target``, and the axis-angle ``turn`` rotations: compiled, as
    :func:`_fitted_distance` asks for them up to 80 times (op by op they took most of a video's camera fitting)."""
    return jax.vmap(geometry.look_at, in_axes=(0, None))(eye, target), geometry.axis_angle_to_matrix(turn)


def _extrinsics(path: _CameraPath, distance: float) -> tuple[np.ndarray, np.ndarray]:
    """World-to-camera ``R (T, 3, 3)`` and ``t (T, 3)`` of the path started at ``distance`` metres."""
    horizontal = distance + path.distance_change
    eye = np.stack([path.centre[0] + horizontal * np.cos(path.azimuth),
                    path.centre[1] + horizontal * np.sin(path.azimuth),
                    np.full(len(horizontal), path.height)], axis=-1) + path.shift
    pan, tilt = path.pan_tilt[:, 0], path.pan_tilt[:, 1]
    upright, turn = (np.asarray(r, np.float64) for r in _looking_and_turning(
        eye, path.centre, np.stack([tilt, pan, np.zeros_like(pan)], -1)))
    rotation = turn @ upright
    return rotation, -np.einsum("tij,tj->ti", rotation, eye)


def _in_view(points: Float[np.ndarray, "T N 3"], rotation: np.ndarray, translation: np.ndarray,
             config: VideoConfig) -> bool:
    """Whether every point is in front of the camera and inside the image less its margins in every frame."""
    in_camera = np.einsum("tij,tnj->tni", rotation, points) + translation[:, None]
    if np.any(in_camera[..., 2] < 0.5):  # not too near: half a metre
        return False
    pixels = np.einsum("ij,tnj->tni", config.intrinsics, in_camera)[..., :2] / in_camera[..., 2:]
    size = np.array(config.image_size, float)
    low, high = config.margin * size, (1 - config.margin) * size - 1
    return bool(np.all((pixels >= low) & (pixels <= high)))


def _fitted_distance(path: _CameraPath, points: np.ndarray, config: VideoConfig, rng: np.random.Generator) -> float:
    """A random starting distance from the config's range, increased by 10 % steps until everyone is in view."""
    distance = rng.uniform(*config.distance)
    for _ in range(80):
        if _in_view(points, *_extrinsics(path, distance), config):
            return distance
        distance *= 1.1
    raise ValueError("cannot keep the people in view: the image is too small for the margin, or they spread too far")


def _person_area(in_camera: Float[np.ndarray, "V 3"], faces: np.ndarray, K: Float[np.ndarray, "3 3"],
                 box: Float[np.ndarray, "4"]) -> int:
    """Pixels the person covers alone, counting those beyond the image border: rasterised on a canvas over
    its box, shifted by whole pixels so the canvas samples the image's pixel centres."""
    corner = np.floor(box[:2])
    size = np.ceil(box[2:]).astype(int) - corner.astype(int) + 1
    shifted = K.copy()
    shifted[:2, 2] -= corner
    return covered_pixels(in_camera, faces, shifted, (int(size[0]), int(size[1])))


def _visibility(person_image: np.ndarray, in_camera: Float[np.ndarray, "P V 3"], faces: np.ndarray,
                K: Float[np.ndarray, "3 3"], boxes: Float[np.ndarray, "P 4"]) -> Float[np.ndarray, "P"]:
    """Each person's pixels in the rendered ``person_image`` over the pixels they would cover alone."""
    visible = np.bincount(person_image[person_image >= 0], minlength=len(in_camera))
    areas = np.array([_person_area(v, faces, K, box) for v, box in zip(in_camera, boxes)])
    return np.where(areas > 0, np.minimum(visible / np.maximum(areas, 1), 1.0), 0.0)


def _check_motion(motion: BodyMotion, model: BodyModel) -> None:
    rotations, betas, translation = (np.asarray(x) for x in (motion.rotations, motion.betas, motion.translation))
    joints = model.skeleton.num_joints
    if rotations.ndim != 5 or rotations.shape[2:] != (joints, 3, 3) or 0 in rotations.shape[:2]:
        raise ValueError(f"motion rotations must be (P, T, {joints}, 3, 3) with P, T > 0, got {rotations.shape}")
    people, frames = rotations.shape[:2]
    if betas.shape != (people, model.num_shapes):
        raise ValueError(f"motion betas must be (P, S) = ({people}, {model.num_shapes}), got {betas.shape}")
    if translation.shape != (people, frames, 3):
        raise ValueError(f"motion translation must be (P, T, 3) = ({people}, {frames}, 3), got {translation.shape}")
    for name, value in (("rotations", rotations), ("betas", betas), ("translation", translation)):
        if not np.all(np.isfinite(value)):
            raise ValueError(f"motion {name} contain NaN or inf")
    if not motion.fps > 0:
        raise ValueError(f"motion frame rate must be positive, got {motion.fps}")


def _to_camera(points: np.ndarray, rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """World points ``(P, T, N, 3)`` into each frame's camera, ``R (T, 3, 3)``, ``t (T, 3)``."""
    return np.einsum("tij,ptnj->ptni", rotation, points) + translation[None, :, None]


def _project(K: Float[np.ndarray, "3 3"], in_camera: Float[np.ndarray, "P T N 3"]) -> Float[np.ndarray, "P T N 2"]:
    return np.asarray(geometry.project_pinhole(np.broadcast_to(K, in_camera.shape[:2] + (3, 3)), in_camera))


def synthesise_video(motion: BodyMotion, model: BodyModel, config: VideoConfig, rng: np.random.Generator) -> Video:
    """Render ``motion`` filmed by a slowly moving camera and return the camera-frame ground truth (module
    docstring).

    The camera looks at the people's mean pelvis over the clip from a random azimuth and height, orbits
    and dollies at random rates up to the config's and wobbles smoothly; its starting distance is drawn
    from the config's range and increased until everyone stays inside the image margins all along.
    Deterministic given ``rng``'s state.
    """
    _check_motion(motion, model)
    rotations, betas, translation = (np.asarray(x, np.float64) for x in
                                     (motion.rotations, motion.betas, motion.translation))
    num_people, num_frames = rotations.shape[:2]
    posed = [_pose_person(model, rotations[p], betas[p], translation[p]) for p in range(num_people)]
    vertices = np.stack([v for v, _ in posed])  # (P, T, V, 3) world
    joints = np.stack([j for _, j in posed])  # (P, T, 24, 3) world

    centre = joints[:, :, model.skeleton.root].mean(axis=(0, 1))
    path = _random_path(centre, num_frames, motion.fps, config, rng)
    # A few hundred vertices per person are enough to fit the view; the margin absorbs the rest.
    sample = vertices[:, :, :: max(1, vertices.shape[2] // 300)]
    sample = np.swapaxes(sample, 0, 1).reshape(num_frames, -1, 3)
    camera_R, camera_t = _extrinsics(path, _fitted_distance(path, sample, config, rng))

    K = config.intrinsics
    vertices_camera = _to_camera(vertices, camera_R, camera_t)
    joints3d = _to_camera(joints, camera_R, camera_t)
    projected = _project(K, vertices_camera)
    boxes = np.concatenate([projected.min(axis=2), projected.max(axis=2)], axis=-1)

    camera = Camera.create(np.broadcast_to(K, (num_frames, 3, 3)), camera_R, camera_t, None,
                           np.broadcast_to(np.array(config.image_size, float), (num_frames, 2)))
    faces = np.asarray(model.faces)
    frames, visibility = [], []
    for t in range(num_frames):
        rendering = render_people(Camera(K, camera_R[t], camera_t[t], np.zeros(5), np.array(config.image_size, float)),
                                  list(vertices[:, t]), model, config.image_size)
        frames.append(rendering.image)
        visibility.append(_visibility(rendering.person, vertices_camera[:, t], faces, K, boxes[:, t]))

    # Camera-frame parameters: the root turns with the camera, and the translation keeps the pelvis (at rest
    # J0 + translation) where R (J0 + translation) + t puts it.
    rest_root = _rest_joints(model, betas)[:, model.skeleton.root][:, None]  # (P, 1, 3)
    rotations_camera = rotations.copy()
    rotations_camera[:, :, model.skeleton.root] = camera_R[None] @ rotations[:, :, model.skeleton.root]
    translation_camera = (np.einsum("tij,ptj->pti", camera_R, translation + rest_root) + camera_t[None]
                          - rest_root)
    return Video(np.stack(frames), camera, rotations_camera, betas, translation_camera, joints3d,
                 _project(K, joints3d), boxes, np.stack(visibility, axis=1))


def mirror_pose(rotations: Float[np.ndarray, "*b J 3 3"], joints: Float[np.ndarray, "*b J 3"],
                skeleton: geometry.Skeleton) -> tuple[Float[np.ndarray, "*b J 3 3"], Float[np.ndarray, "*b J 3"]]:
    """Poses in a world mirrored through its yz plane (x -> -x), each person's left and right swapped
    (:attr:`~geometry.Skeleton.mirror`): rotations ``M R M`` and points ``M p`` with ``M = diag(-1, 1, 1)``
    (float64; the signs change, the values stay exact). For a left-right symmetric body model the mirrored
    rotations pose it into the mirrored joints; mirroring twice is the identity."""
    mirror = list(skeleton.mirror)
    return _MIRROR_X @ rotations[..., mirror, :, :] @ _MIRROR_X, joints[..., mirror, :] @ _MIRROR_X


def flip_video(video: Video, model: BodyModel, redraw: bool = False) -> Video:
    """The horizontal mirror of ``video``: what a mirrored world, with every person's left and right swapped
    (:attr:`~geometry.Skeleton.mirror`), looks like. Pixels ``x -> W - 1 - x``; camera-frame points
    ``(x, y, z) -> (-x, y, z)``; rotations ``M R M`` with ``M = diag(-1, 1, 1)``; the camera mirrored to match
    (``K``'s principal point and skew, ``R -> M R M``, ``t -> M t``). For a left-right symmetric model,
    ``body_forward`` of the flipped parameters gives the flipped joints. Flipping twice is the identity.

    ``redraw=False`` mirrors the pixels, which is the mirror of real footage. A render of
    :func:`~mocap.render_people` marks left and right by its part colours, and mirrored pixels keep each colour on
    its part while the labels swap: a mirrored person facing the camera then looks like an unmirrored one facing
    away. ``redraw=True`` renders the flipped people anew (the same silhouettes for a symmetric model, the part
    colours following the swapped labels), at the cost of a second rendering.
    """
    width = video.frames.shape[2]
    mirror = list(model.skeleton.mirror)
    rest_root = _rest_joints(model, video.betas)[:, model.skeleton.root][:, None]  # (P, 1, 3)
    # The flipped person's pelvis M (J0 + translation) must equal J0 + flipped translation.
    translation = (video.translation + rest_root) @ _MIRROR_X - rest_root
    rotations, joints3d = mirror_pose(video.rotations, video.joints3d, model.skeleton)
    joints2d = video.joints2d[:, :, mirror].copy()
    joints2d[..., 0] = width - 1 - joints2d[..., 0]
    x0, y0, x1, y1 = np.moveaxis(video.boxes, -1, 0)
    K = np.array(video.camera.K, np.float64)
    K[:, 0, 1] *= -1
    K[:, 0, 2] = width - 1 - K[:, 0, 2]
    camera = Camera.create(K, _MIRROR_X @ np.asarray(video.camera.R, np.float64) @ _MIRROR_X,
                           np.asarray(video.camera.t, np.float64) @ _MIRROR_X, video.camera.dist,
                           video.camera.image_size)
    frames = (_redraw(model, rotations, video.betas, translation, K, video.frames.shape[1:3]) if redraw
              else np.ascontiguousarray(video.frames[:, :, ::-1]))
    return Video(frames, camera, rotations, video.betas.copy(), translation, joints3d, joints2d,
                 np.stack([width - 1 - x1, y0, width - 1 - x0, y1], axis=-1), video.visibility.copy())


def _redraw(model: BodyModel, rotations: Float[np.ndarray, "P T 24 3 3"], betas: Float[np.ndarray, "P S"],
            translation: Float[np.ndarray, "P T 3"], K: Float[np.ndarray, "T 3 3"],
            shape: tuple[int, int]) -> UInt8[np.ndarray, "T H W 3"]:
    """The frames of people given by camera-frame parameters, seen by cameras ``K`` at the origin."""
    height, width = shape
    vertices = np.stack([_pose_person(model, rotations[p], betas[p], translation[p])[0]
                         for p in range(len(betas))])  # (P, T, V, 3), camera frame
    return np.stack([render_people(Camera(K[t], np.eye(3), np.zeros(3), np.zeros(5), np.array([width, height], float)),
                                   list(vertices[:, t]), model, (width, height)).image
                     for t in range(len(K))])


def _moving_average(values: Float[np.ndarray, "*tracks T C"], window: int) -> Float[np.ndarray, "*tracks T C"]:
    """Centred mean over ``window`` frames, over only the frames that exist near the ends of the track."""
    num_frames = values.shape[-2]
    sums = np.concatenate([np.zeros_like(values[..., :1, :]), np.cumsum(values, axis=-2)], axis=-2)
    start = np.clip(np.arange(num_frames) - window // 2, 0, num_frames)
    stop = np.clip(np.arange(num_frames) - window // 2 + window, 0, num_frames)
    return (sums[..., stop, :] - sums[..., start, :]) / (stop - start)[:, None]


def jitter_boxes(boxes: Float[np.ndarray, "*tracks T 4"], rng: np.random.Generator, scale: float = 0.1,
                 shift: float = 0.1, smoothing: int = 5) -> Float[np.ndarray, "*tracks T 4"]:
    """Boxes ``(x0, y0, x1, y1)`` randomly rescaled about their centres and shifted, frame by frame, as HMMR and
    PHD augment their tracks: each side's length times a factor in ``[1 - scale, 1 + scale]`` and the centre
    moved by up to ``shift`` times the box's width (x) and height (y). The random draws are averaged over a
    window of ``smoothing`` frames, so the jitter drifts rather than flickers while staying in those bounds.
    """
    boxes = np.asarray(boxes, np.float64)
    if boxes.ndim < 2 or boxes.shape[-1] != 4:
        raise ValueError(f"boxes must be (..., T, 4), got {boxes.shape}")
    if not np.all(np.isfinite(boxes)):
        raise ValueError("boxes contain NaN or inf")
    if not (0 <= scale < 1 and shift >= 0 and smoothing >= 1):
        raise ValueError(f"need 0 <= scale < 1, shift >= 0 and smoothing >= 1, got {scale}, {shift}, {smoothing}")
    noise = rng.uniform(-1.0, 1.0, boxes.shape[:-1] + (3,))  # scale, centre x, centre y
    smooth = _moving_average(noise, smoothing)
    centre, size = 0.5 * (boxes[..., :2] + boxes[..., 2:]), boxes[..., 2:] - boxes[..., :2]
    centre = centre + shift * smooth[..., 1:] * size
    size = size * (1.0 + scale * smooth[..., :1])
    return np.concatenate([centre - 0.5 * size, centre + 0.5 * size], axis=-1)

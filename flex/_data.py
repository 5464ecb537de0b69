"""Training samples for FLEX from 3D motion: K virtual cameras, static or moving, seeing one person.

A sample (:func:`make_sample`) takes ``frames`` consecutive frames of one person of a shipped CMU clip
(:func:`mocap.load_clip`, 30 fps; a clip shorter than the window plays forwards then backwards), places
``views`` cameras around it and simulates what a 2D detector reports in each view:

- **Cameras** (:class:`DataConfig`): pinhole, no distortion, random focal length, aimed with
  :func:`geometry.look_at`. ``"static"``: fixed cameras on a ring around the person's mean position, each at its
  own distance and height, aimed at the mean root plus a random offset. ``"dynamic"`` (the paper's dynamic
  setting): every camera orbits at its own angular, radial and vertical speed around a centre that follows the
  person partway, and pans and tilts to track the root plus its offset, so extrinsics and the relative poses
  between cameras change during the sequence. Ring radii grow with the extent of the person's path so that no
  camera comes closer than ``distance[0]``. With ``rig`` set, every sample is seen by the same fixed cameras
  instead (the paper's protocol: one rig, Human3.6M's), and the person moves: its path is turned about the vertical
  by a random heading and centred on a random point near the rig's centre (:func:`fixed_rig`, :func:`rig_centre`).
- **2D joints**: the detector model of :mod:`mocap` (:func:`mocap.detect_with_events`: noise scaled by the
  apparent size, occlusion, left/right swaps, misses, confidences) runs on the BODY25 joints of every person of
  the clip (the two-person clips' partner occludes the person: mutual occlusion), each view
  in its own camera frame (an identity-extrinsics camera, so moving cameras cost nothing extra). Each
  :data:`geometry.STRUCTRI17` joint then gets the detector's error of its BODY25 counterpart (the mean error and mean
  confidence of several for the spine, neck and head, which BODY25 lacks), added to its exact projection;
  unreported joints have confidence 0.

The ground truth is what the losses need: per-view camera-frame STRUCTRI17 joints relative to the root, the root in
each view's normalised camera (:mod:`flex._model`; from the input's own normalisation, so no calibration is
needed at test time), the symmetric bone lengths, foot contacts, and the "real" rotations for the
discriminator: FLEX20 local rotations from the positions (:func:`local_rotations`) and each view's root rotation.

The root (``mid_hip``) is the centre of the hips, the Human3.6M pelvis and FLEX's rest pose (hips at +-x), and
BODY25's mid-hip; the shipped clips' ``mid_hip`` (CMU's root, about 11 cm above the hips) is replaced by it.
Everything is a pure function of the JAX key and the config.
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path
from typing import Literal, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

import geometry
import mocap
from geometry import BODY25, FLEX20, FLEX20_BONE_OF_JOINT, FLEX20_REST_DIRECTIONS, FLEX20_ROTATING, STRUCTRI17, Camera

from ._detections import input_from_detections
from ._normalise import normalise_2d

__all__ = [
    "Batch", "DataConfig", "FIXED_RIGS", "fixed_rig", "local_rotations", "make_batch", "make_sample", "rig_centre",
    "root_frame", "sign_continuous", "symmetric_bone_lengths",
]

_ROOT = STRUCTRI17.index("mid_hip")
_FEET = (STRUCTRI17.index("r_ankle"), STRUCTRI17.index("l_ankle"))
_BODY25_PROXIES: dict[str, tuple[str, ...]] = {
    "spine": ("mid_hip", "neck"),
    "thorax": ("neck",),
    "neck_nose": ("nose", "l_ear", "r_ear"),
    "head": ("nose", "l_eye", "r_eye", "l_ear", "r_ear"),
}
"""BODY25 joints whose detection error an STRUCTRI17 joint without a BODY25 namesake takes (mean over the reported)."""


def _proxy_matrix() -> np.ndarray:
    """(17, 25) 0/1 map: entry (k, b) is 1 when BODY25 joint b gives its detection error to STRUCTRI17 joint k."""
    matrix = np.zeros((STRUCTRI17.num_joints, BODY25.num_joints))
    for k, name in enumerate(STRUCTRI17.joints):
        for proxy in _BODY25_PROXIES.get(name, (name,)):
            matrix[k, BODY25.index(proxy)] = 1.0
    return matrix


_PROXIES = _proxy_matrix()

FIXED_RIGS: tuple[str, ...] = ("h36m_ring", "shelf")
"""Named fixed rigs of :attr:`DataConfig.rig` (:func:`fixed_rig`)."""


@functools.cache
def fixed_rig(name: str) -> Camera:
    """A fixed rig (metres, z-up world, no distortion), by name or calibration file:

    - ``"h36m_ring"``: four cameras like Human3.6M's (not its calibration): at the corners of a square, 5 m from its
      centre, 1.6 m high, aimed at a point 1 m above the centre, focal length 1145 px, 1000 x 1000 px images;
    - ``"shelf"``: the real Shelf calibration (:func:`mocap.shelf_cameras`, 5 cameras, 1032 x 776 px);
    - a path: any calibration file or folder :func:`geometry.load_calibration` reads (its lens distortion, if any,
      is dropped: samples are projected and triangulated without it)."""
    if name == "h36m_ring":
        return geometry.ring_rig(4, radius=5.0, target=(0.0, 0.0, 1.0), height=1.6, focal=1145.0,
                                 image_size=(1000.0, 1000.0), start_angle=np.pi / 4)
    if name == "shelf":
        rig = mocap.shelf_cameras()
    elif Path(name).exists():
        rig = geometry.load_calibration(name).rig
    else:
        raise ValueError(f"rig must be one of {FIXED_RIGS} or a calibration file, got {name!r}")
    return rig._replace(dist=jnp.zeros_like(rig.dist))


def rig_centre(rig: Camera) -> Float[np.ndarray, "3"]:
    """The point nearest (least squares) to every camera's optical axis: where a rig looks (metres)."""
    R, centres = np.asarray(rig.R, np.float64), np.asarray(geometry.camera_centre(rig), np.float64)
    axes = R[:, 2]  # each camera's z axis in world coordinates
    across = np.eye(3) - axes[:, :, None] * axes[:, None, :]  # projections orthogonal to each axis
    return np.linalg.solve(across.sum(0), np.einsum("vij,vj->i", across, centres))


@dataclasses.dataclass(frozen=True)
class DataConfig:
    """How samples are drawn (metres, seconds, pixels)."""

    views: int = 4
    frames: int = 196
    """T (the official code's window)."""
    clips: tuple[str, ...] | None = None
    """Shipped clip names or paths of motion files (:func:`mocap.load_clip_file`); None: all shipped clips
    (:func:`mocap.list_clips`)."""
    camera_motion: Literal["static", "dynamic"] = "static"
    rig: str | None = None
    """None: every sample draws its own cameras (the settings below). Otherwise a fixed rig (:func:`fixed_rig`:
    ``"h36m_ring"``, ``"shelf"`` or a calibration file) seen through its first ``views`` cameras, static."""
    placement_radius: float = 0.5
    """With a fixed rig: the person's mean root is placed uniformly within this distance (metres, horizontal) of
    the rig's centre (:func:`rig_centre`), its path turned by a uniform random heading."""
    distance: tuple[float, float] = (3.5, 6.0)
    """Horizontal distance of a camera from the person's mean root (plus the path's extent), uniform."""
    height: tuple[float, float] = (0.8, 2.2)
    """Camera height above the floor (z = 0), uniform."""
    focal: tuple[float, float] = (700.0, 1400.0)
    """Focal length in pixels (fx = fy), uniform per view; the principal point is the image centre."""
    image_size: tuple[float, float] = (1000.0, 1000.0)
    aim_jitter: float = 0.3
    """Standard deviation (metres, per axis) of the offset between a camera's aim and the root."""
    orbit_speed: float = 0.6
    """Dynamic: maximum angular speed (rad/s) about the orbit centre, uniform in +-."""
    radial_speed: float = 0.5
    """Dynamic: maximum speed (m/s) towards or away from the orbit centre."""
    vertical_speed: float = 0.2
    """Dynamic: maximum vertical speed (m/s); heights stay in [0.3, 3] m."""
    detector: mocap.DetectorConfig = mocap.DetectorConfig()
    input_joints: Literal["structri17", "detected"] = "structri17"
    """The model's 2D input: ``"structri17"``, the STRUCTRI17 joints' projections with the detector's error of their
    nearest BODY25 joints; ``"detected"``, made from the detected BODY25 keypoints by
    :func:`~flex.input_from_detections`, as it is made from a real detector's output."""
    contact_speed: float = 0.3
    """A foot (ankle) is in contact when slower than this (m/s) ..."""
    contact_height: float = 0.06
    """... and at most this far (m) above its lowest height in the clip."""

    def __post_init__(self) -> None:
        if self.views < 1 or self.frames < 2:
            raise ValueError(f"need views >= 1 and frames >= 2, got {self.views}, {self.frames}")
        if self.camera_motion not in ("static", "dynamic"):
            raise ValueError(f"camera_motion must be 'static' or 'dynamic', got {self.camera_motion!r}")
        if self.input_joints not in ("structri17", "detected"):
            raise ValueError(f"input_joints must be 'structri17' or 'detected', got {self.input_joints!r}")
        for name in ("distance", "height", "focal"):
            low, high = getattr(self, name)
            if not 0 < low <= high:
                raise ValueError(f"{name} must be a range 0 < low <= high, got {(low, high)}")
        if self.rig is not None:
            if self.camera_motion != "static":
                raise ValueError(f"a fixed rig ({self.rig!r}) has static cameras, got camera_motion="
                                 f"{self.camera_motion!r}")
            available = fixed_rig(self.rig).num_views
            if self.views > available:
                raise ValueError(f"rig {self.rig!r} has {available} cameras, fewer than views={self.views}")
        if not self.placement_radius >= 0:
            raise ValueError(f"placement_radius must be >= 0 metres, got {self.placement_radius}")
        unknown = sorted(c for c in set(self.clip_names) - set(mocap.list_clips()) if not Path(c).is_file())
        if not self.clip_names or unknown:
            raise ValueError(f"clips must be shipped clips ({mocap.list_clips()}) or motion files, got unknown "
                             f"{unknown} or none")

    @property
    def clip_names(self) -> tuple[str, ...]:
        return tuple(mocap.list_clips()) if self.clips is None else self.clips


class Batch(NamedTuple):
    """Model input and ground truth (leading ``batch`` axis from :func:`make_batch`; none from :func:`make_sample`)."""

    points_2d: Float[Array, "batch views frames 17 2"]
    """Detected STRUCTRI17 joints, pixels (0 where missing)."""
    confidences: Float[Array, "batch views frames 17"]
    """Detector confidences in [0, 1], 0 where missing."""
    joints: Float[Array, "batch views frames 17 3"]
    """Camera-frame STRUCTRI17 joints relative to the root (metres): L_P's target."""
    root_position: Float[Array, "batch views frames 3"]
    """The root in each view's normalised camera (``(x d, y d, d)``, metres; :mod:`flex._model`): L_R, L_FC."""
    bone_lengths: Float[Array, "batch 10"]
    """Symmetric bone lengths (:data:`geometry.FLEX20_BONES`, metres): L_S."""
    contacts: Float[Array, "batch frames 2"]
    """1 where the right / left foot touches the ground: L_F, L_FC."""
    rotations: Float[Array, "batch frames 14 4"]
    """FLEX20 local rotations of :data:`geometry.FLEX20_ROTATING` (unit quaternions, sign-continuous in time):
    D's real samples."""
    root_rotations: Float[Array, "batch views frames 4"]
    """Each view's root rotation (body frame to camera), unit quaternions, sign-continuous: D_0's real samples."""
    cameras: Camera
    """Every view's camera at every frame (leaves ``(batch, views, frames, ...)``), for evaluation only."""


def _frame(x: Float[Array, "*b 3"], y: Float[Array, "*b 3"], exact: Literal["x", "y"]) -> Float[Array, "*b 3 3"]:
    """The rotation with x column along ``x`` and y column along ``y``: the ``exact`` one normalised, the other
    orthogonalised against it (Gram-Schmidt of :func:`geometry.rotation_6d_to_matrix`)."""
    if exact == "x":
        return geometry.rotation_6d_to_matrix(jnp.concatenate([x, y], axis=-1))
    columns = geometry.rotation_6d_to_matrix(jnp.concatenate([y, x], axis=-1))  # (y, x', y cross x')
    return jnp.stack([columns[..., 1], columns[..., 0], -columns[..., 2]], axis=-1)


def _matvec_t(m: Float[Array, "*b 3 3"], v: Float[Array, "*b 3"]) -> Float[Array, "*b 3"]:
    return jnp.sum(m * v[..., :, None], axis=-2)


@functools.partial(jax.jit, static_argnames="rest_pose")
def local_rotations(
    joints: Float[ArrayLike, "*b 20 3"], rest_pose: Literal["totem", "tpose"] = "totem"
) -> Float[Array, "*b 20 3 3"]:
    """FLEX20 local rotations that pose the rest skeleton (:data:`geometry.FLEX20_REST_DIRECTIONS`) like ``joints``.

    Forward kinematics of the result with each joint's own bone length reproduces ``joints`` exactly (up to the
    root position); with the symmetric lengths the bone directions are exact. The rotations that positions leave
    free are fixed as motion-capture skeletons usually do: the root's frame has x along the hips (right -> left)
    and y towards the spine; the spine's has y towards the thorax and x along the shoulders; every other joint turns
    by the smallest rotation (no twist) from its child's T-pose direction, after the fixed turn from the rest
    direction to it, so the totem's upward arms do not meet the singular half turn when the arms hang down.
    End effectors get the identity.
    """
    joints = jnp.asarray(joints, jnp.result_type(float))
    j = FLEX20.index
    rest = jnp.asarray(FLEX20_REST_DIRECTIONS[rest_pose], joints.dtype)
    reference = jnp.asarray(FLEX20_REST_DIRECTIONS["tpose"], joints.dtype)
    identity = jnp.broadcast_to(jnp.eye(3, dtype=joints.dtype), joints.shape[:-2] + (3, 3))
    globals_ = {j("mid_hip"): _frame(joints[..., j("l_hip"), :] - joints[..., j("r_hip"), :],
                                     joints[..., j("spine"), :] - joints[..., j("mid_hip"), :], "x")}
    local = {j("mid_hip"): globals_[j("mid_hip")]}
    # A joint's child; the root and the spine, which have several, get frames instead.
    children = {p: c for c, p in enumerate(FLEX20.parents) if p >= 0}
    for joint in FLEX20.topological_order[1:]:
        parent = globals_[FLEX20.parents[joint]]
        if joint == j("spine"):
            globals_[joint] = _frame(joints[..., j("l_shoulder"), :] - joints[..., j("r_shoulder"), :],
                                     joints[..., j("thorax"), :] - joints[..., j("spine"), :], "y")
            local[joint] = jnp.swapaxes(parent, -1, -2) @ globals_[joint]
        elif joint in FLEX20_ROTATING:
            child = children[joint]
            target = _matvec_t(parent, joints[..., child, :] - joints[..., joint, :])
            local[joint] = (geometry.rotation_between(reference[child], target)
                            @ geometry.rotation_between(rest[child], reference[child]))
            globals_[joint] = parent @ local[joint]
        else:
            local[joint] = globals_[joint] = identity
    return jnp.stack([local[k] for k in range(FLEX20.num_joints)], axis=-3)


def symmetric_bone_lengths(joints: Float[ArrayLike, "*b 20 3"]) -> Float[Array, "*b 10"]:
    """:data:`geometry.FLEX20_BONES` of a FLEX20 pose (metres): each the mean of the bones sharing it."""
    lengths = geometry.bone_lengths(joints, FLEX20)  # bone k ends at joint k + 1 (root 0)
    bones = np.arange(len(geometry.FLEX20_BONES))
    assign = (np.asarray(FLEX20_BONE_OF_JOINT[1:])[:, None] == bones[None, :]).astype(np.float64)
    assign = assign / assign.sum(0, keepdims=True)
    return jnp.einsum("...k,kb->...b", lengths, jnp.asarray(assign, lengths.dtype))


def root_frame(
    root_pixels: Float[ArrayLike, "*b 2"], depth: Float[ArrayLike, "*b"], centre: Float[ArrayLike, "..."],
    scale: Float[ArrayLike, "..."], focal: Float[ArrayLike, "..."],
) -> Float[Array, "*b 3"]:
    """A root at ``root_pixels`` and metric ``depth`` in the normalised camera of :mod:`flex._model`:
    ``(x d, y d, d)`` with ``(x, y) = (pixels - centre) / scale`` and ``d = depth * scale / focal``.

    ``centre`` (``(..., 2)``), ``scale`` and ``focal`` (pixels) broadcast against ``depth`` (same rank)."""
    root_pixels, depth, centre, scale, focal = (jnp.asarray(a) for a in (root_pixels, depth, centre, scale, focal))
    d = depth * scale / focal
    return jnp.concatenate([(root_pixels - centre) / scale[..., None] * d[..., None], d[..., None]], axis=-1)


def _window(rng: np.random.Generator, length: int, frames: int) -> np.ndarray:
    """``frames`` consecutive clip frames from a random start; a short clip plays forwards then backwards."""
    start = int(rng.integers(0, max(length - frames, 0) + 1))
    index = start + np.arange(frames)
    if length == 1:
        return np.zeros(frames, int)
    period = 2 * (length - 1)
    phase = index % period
    return np.where(phase < length, phase, period - phase)


def _cameras(rng: np.random.Generator, config: DataConfig, root: np.ndarray, fps: float) -> Camera:
    """Per view and frame world-to-camera extrinsics around the root trajectory ``root`` (frames, 3)."""
    k, frames = config.views, root.shape[0]
    mean = root.mean(0)
    extent = float(np.max(np.linalg.norm(root[:, :2] - mean[:2], axis=-1)))
    time = np.arange(frames) / fps
    spread = np.pi / (2 * k)
    azimuth = rng.uniform(0, 2 * np.pi) + 2 * np.pi * np.arange(k) / k + rng.uniform(-spread, spread, k)
    distance, height = rng.uniform(*config.distance, k), rng.uniform(*config.height, k)
    focal = rng.uniform(*config.focal, k)
    aim = rng.normal(0.0, config.aim_jitter, (k, 3))
    if config.camera_motion == "static":
        follow = np.zeros(k)
        azimuth = np.broadcast_to(azimuth[:, None], (k, frames))
        radius = np.broadcast_to((distance + extent)[:, None], (k, frames))
        z = np.broadcast_to(height[:, None], (k, frames))
        target = np.broadcast_to(mean, (k, frames, 3)) + aim[:, None]
    else:
        follow = rng.uniform(0.0, 1.0, k)
        azimuth = azimuth[:, None] + rng.uniform(-config.orbit_speed, config.orbit_speed, k)[:, None] * time
        radial = rng.uniform(-config.radial_speed, config.radial_speed, k)[:, None] * time
        radius = np.maximum(distance[:, None] + radial, config.distance[0]) + ((1.0 - follow) * extent)[:, None]
        vertical = rng.uniform(-config.vertical_speed, config.vertical_speed, k)[:, None] * time
        z = np.clip(height[:, None] + vertical, 0.3, 3.0)
        target = root[None] + aim[:, None]
    centre = mean[None, None, :2] + follow[:, None, None] * (root[None, :, :2] - mean[None, None, :2])
    eye = np.concatenate([centre + radius[..., None] * np.stack([np.cos(azimuth), np.sin(azimuth)], -1),
                          z[..., None]], axis=-1)  # (K, T, 3)
    R = np.asarray(jax.vmap(geometry.look_at)(eye.reshape(-1, 3), target.reshape(-1, 3))).reshape(k, frames, 3, 3)
    width, height_px = config.image_size
    intrinsics = np.zeros((k, 3, 3))
    intrinsics[:, 0, 0] = intrinsics[:, 1, 1] = focal
    intrinsics[:, :, 2] = np.stack([np.full(k, (width - 1) / 2), np.full(k, (height_px - 1) / 2), np.ones(k)], -1)
    return Camera(np.broadcast_to(intrinsics[:, None], (k, frames, 3, 3)), R, -np.einsum("ktij,ktj->kti", R, eye),
                  np.zeros((k, frames, 5)), np.broadcast_to(np.asarray(config.image_size), (k, frames, 2)))


def _on_fixed_rig(rng: np.random.Generator, config: DataConfig, h36m: np.ndarray, body25: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, Camera]:
    """The window's people (STRUCTRI17 ``(T, 17, 3)``, BODY25 ``(T, people, 25, 3)``, world metres) turned about
    the vertical and moved to the fixed rig (:attr:`DataConfig.placement_radius`), and the rig per frame."""
    rig = fixed_rig(config.rig)
    heading = rng.uniform(0.0, 2.0 * np.pi)
    c, s = np.cos(heading), np.sin(heading)
    turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    angle, radius = rng.uniform(0.0, 2.0 * np.pi), config.placement_radius * np.sqrt(rng.uniform())
    place = rig_centre(rig)[:2] + radius * np.array([np.cos(angle), np.sin(angle)])
    shift = np.append(place - (h36m[:, _ROOT] @ turn.T).mean(0)[:2], 0.0)
    frames = h36m.shape[0]
    cameras = jax.tree.map(lambda leaf: np.broadcast_to(np.asarray(leaf, np.float64)[:config.views, None],
                                                        (config.views, frames) + np.shape(leaf)[1:]), rig)
    return h36m @ turn.T + shift, body25 @ turn.T + shift, cameras


def _detect(key: Array, config: DataConfig, cameras: Camera, body25: np.ndarray, person: int, h36m: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per view: ``person``'s detected STRUCTRI17 pixels (views, T, 17, 2) and confidences (views, T, 17), and the
    exact projections (views, T, 17, 2), from the detector model run in each view's camera frame on all the
    clip's people ``body25`` (T, people, 25, 3), so that the others occlude the person."""
    points, confidences, exact = [], [], []
    for view, view_key in enumerate(jax.random.split(key, config.views)):
        R, t = cameras.R[view], cameras.t[view]  # (T, 3, 3), (T, 3)

        def in_camera(x: np.ndarray) -> np.ndarray:  # world (T, ..., 3) -> this view's camera frame
            return np.einsum("tij,t...j->t...i", R, x) + np.expand_dims(t, tuple(range(1, x.ndim - 1)))

        rig = Camera.create(cameras.K[view, :1], np.eye(3)[None], np.zeros((1, 3)),
                            image_size=cameras.image_size[view, :1])
        frames, events = mocap.detect_with_events(view_key, rig, in_camera(body25), config.detector)
        found = mocap.oracle_keypoints(mocap.pad_detections(frames), body25.shape[1])[:, 0, person]  # (T, 25, 3)
        reported = found[..., 2] > 0
        error = np.where(reported[..., None], found[..., :2] - events.geometry.pixels[:, 0, person], 0.0)
        weight = _PROXIES[None] * reported[:, None, :]  # (T, 17, 25)
        count = weight.sum(-1)
        projected = np.asarray(geometry.project(rig.select(0), in_camera(h36m)))
        mean_error = np.einsum("tkb,tbc->tkc", weight, error) / np.maximum(count, 1)[..., None]
        confidence = np.einsum("kb,tb->tk", _PROXIES / _PROXIES.sum(-1, keepdims=True), found[..., 2])
        if config.input_joints == "detected":
            detected, confidence = input_from_detections(found[..., :2], found[..., 2])
            seen = confidence > 0
            points.append(np.where(seen[..., None], detected, 0.0))
        else:
            seen = count > 0
            points.append(np.where(seen[..., None], projected + mean_error, 0.0))
        confidences.append(np.where(seen, confidence, 0.0))
        exact.append(projected)
    return np.stack(points), np.stack(confidences), np.stack(exact)


def sign_continuous(q: Float[ArrayLike, "frames *b 4"]) -> Float[Array, "frames *b 4"]:
    """Flip quaternion signs along axis 0 (time) so that consecutive ones are in the same hemisphere (the
    rotations are unchanged; temporal differences of the result are small where the rotation changes slowly)."""
    q = jnp.asarray(q)
    same = jnp.sum(q[1:] * q[:-1], axis=-1) >= 0
    sign = jnp.cumprod(jnp.concatenate([jnp.ones_like(same[:1], q.dtype), jnp.where(same, 1.0, -1.0)]), axis=0)
    return q * sign[..., None]


@jax.jit
def _continuous_quaternions(matrices: Float[ArrayLike, "frames *b 3 3"]) -> Float[Array, "frames *b 4"]:
    """The rotations as quaternions, sign-continuous in time (compiled: a sample makes a few such calls)."""
    return sign_continuous(geometry.matrix_to_quaternion(matrices))


def make_sample(key: ArrayLike, config: DataConfig, rest_pose: Literal["totem", "tpose"] = "totem") -> Batch:
    """One sample (NumPy leaves, float64, no batch axis) drawn from ``key``; see the module docstring.

    ``rest_pose`` must be the model's (:attr:`~flex.FlexConfig.rest_pose`): the real rotations are relative to it.
    """
    key = jnp.asarray(key) if isinstance(key, jax.Array) else jax.random.key(int(key))
    choice_key, detector_key = jax.random.split(key)
    rng = np.random.default_rng(np.asarray(jax.random.key_data(choice_key)).astype(np.uint64).ravel().tolist())
    clip = mocap.shared_clip(config.clip_names[int(rng.integers(len(config.clip_names)))])
    person = int(rng.integers(clip.num_people))
    window = _window(rng, clip.num_frames, config.frames)
    h36m, body25 = clip.structri17[person].copy(), np.moveaxis(clip.body25[:, window], 0, 1)  # (T, people, 25, 3)
    h36m[:, _ROOT] = 0.5 * (h36m[:, STRUCTRI17.index("l_hip")] + h36m[:, STRUCTRI17.index("r_hip")])
    lowest = h36m[:, _FEET, 2].min()
    h36m = h36m[window]

    if config.rig is None:
        cameras = _cameras(rng, config, h36m[:, _ROOT], clip.fps)
    else:
        h36m, body25, cameras = _on_fixed_rig(rng, config, h36m, body25)
    points, confidences, exact = _detect(detector_key, config, cameras, body25, person, h36m)
    camera_joints = np.einsum("ktij,tnj->ktni", cameras.R, h36m) + cameras.t[:, :, None, :]  # (K, T, 17, 3)
    normalised = normalise_2d(points, confidences, _ROOT)
    focal = 0.5 * (cameras.K[:, 0, 0, 0] + cameras.K[:, 0, 1, 1])
    root_position = root_frame(exact[:, :, _ROOT], camera_joints[:, :, _ROOT, 2], normalised.centre[:, None],
                               normalised.scale[:, None], focal[:, None])

    velocity = np.gradient(h36m[:, _FEET], axis=0) * clip.fps  # (T, 2, 3)
    contacts = (np.linalg.norm(velocity, axis=-1) < config.contact_speed) & (
        h36m[:, _FEET, 2] < lowest + config.contact_height)
    flex20 = np.asarray(geometry.flex20_from_structri17(h36m))
    local = local_rotations(flex20, rest_pose)
    rotations = np.asarray(_continuous_quaternions(local[:, np.asarray(FLEX20_ROTATING)]))
    root_in_views = np.einsum("ktij,tjl->tkil", cameras.R, np.asarray(local[:, 0]))  # (T, K, 3, 3)
    root_rotations = np.moveaxis(np.asarray(_continuous_quaternions(root_in_views)), 1, 0)
    return Batch(
        points_2d=points, confidences=confidences, joints=camera_joints - camera_joints[:, :, _ROOT:_ROOT + 1],
        root_position=np.asarray(root_position), bone_lengths=np.asarray(symmetric_bone_lengths(flex20)).mean(0),
        contacts=contacts.astype(np.float64), rotations=rotations, root_rotations=root_rotations, cameras=cameras,
    )


def make_batch(
    key: ArrayLike, config: DataConfig, batch_size: int, rest_pose: Literal["totem", "tpose"] = "totem"
) -> Batch:
    """``batch_size`` samples from ``jax.random.split(key, batch_size)``, stacked (NumPy leaves)."""
    key = key if isinstance(key, jax.Array) else jax.random.key(int(key))
    samples = [make_sample(k, config, rest_pose) for k in jax.random.split(key, batch_size)]
    return jax.tree.map(lambda *leaves: np.stack(leaves), *samples)

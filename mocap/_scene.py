"""Synthetic multi-person, multi-view scenes: real motion clips placed on a floor, seen by a rig.

:func:`synthesise_scene` takes people from the shipped motion clips (the two partners of a salsa
pair always together, keeping their interaction), places them on the z = 0 floor with random
ground-plane offsets, headings and time shifts such that no two root trajectories come closer than
``min_separation`` at any frame, and runs the detector model (:func:`~mocap.detect`) on them. The
result holds the 3D ground truth in three joint sets, its projections, per-view visibility and the
detections ``[frame][view]``, the structure of the real Shelf loader. Everything is a pure function
of the JAX key and the arguments.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike, Bool, Float, Int

import geometry
from geometry import BODY25, STRUCTRI17, Camera

from ._clips import Clip, list_clips, load_clip
from ._detections import Detections
from ._detector import DetectorConfig, DetectorEvents, _numpy_rng, detect_with_events
from ._procedural import procedural_clip

__all__ = [
    "Scene", "ScenePlacement", "MotionGroup", "capture_area", "place_groups", "compose_scene", "synthesise_scene",
    "motion_group",
]


class MotionGroup(NamedTuple):
    """People moving together (one clip, or the partners of a pair), placed as one rigid unit."""

    names: tuple[str, ...]
    """One clip name per person."""
    body25: Float[np.ndarray, "time people 25 3"]
    """BODY25 joints in metres, world z up, feet on z = 0, at the scene's frame rate."""
    structri17: Float[np.ndarray, "time people 17 3"]
    """STRUCTRI17 joints (Structural Triangulation order) of the same people and frames."""


class ScenePlacement(NamedTuple):
    """How each group was put into the scene: rotate about z by ``heading`` around its centre, then
    move the centre to ``offset`` (metres), with clip frame ``time_shift + t`` at scene frame t."""

    group_of_person: Int[np.ndarray, " people"]
    names: tuple[str, ...]
    """Clip name of each person."""
    offset: Float[np.ndarray, "groups 2"]
    heading: Float[np.ndarray, " groups"]
    """Radians, counter-clockwise seen from above."""
    time_shift: Int[np.ndarray, " groups"]
    path_scale: Float[np.ndarray, " groups"]
    """Factor (<= 1) by which the group's horizontal path was shrunk to fit the area."""
    min_root_distance: float
    """The smallest horizontal distance (metres) between the mid-hips of people of different groups
    over the whole scene (inf with one group)."""


class Scene(NamedTuple):
    """A synthetic capture: ground truth, the rig and the simulated detections."""

    rig: Camera
    body25: Float[np.ndarray, "frames people 25 3"]
    """Ground-truth BODY25 joints, metres, world z up."""
    shelf15: Float[np.ndarray, "frames people 15 3"]
    """Ground truth in the Shelf evaluation joint set, from the STRUCTRI17 joints like the clips'
    (``geometry.to_shelf15`` with the ``"h36m"`` rule: head bottom = H36M neck/nose, head top = H36M head), so it does
    not share the BODY25 head geometry the detections come from."""
    structri17: Float[np.ndarray, "frames people 17 3"]
    body25_pixels: Float[np.ndarray, "frames views people 25 2"]
    """Projected BODY25 ground truth (pixels; meaningless where the joint is behind the camera)."""
    shelf15_pixels: Float[np.ndarray, "frames views people 15 2"]
    visible: Bool[np.ndarray, "frames views people 25"]
    """BODY25 joint inside the image and less than half occluded by bodies (:class:`~mocap.ViewGeometry`)."""
    detections: list[list[Detections]]
    """Simulated detections ``[frame][view]``, with ``person_ids`` indexing the people axis."""
    events: DetectorEvents
    placement: ScenePlacement
    fps: float

    @property
    def num_frames(self) -> int:
        return self.body25.shape[0]

    @property
    def num_people(self) -> int:
        return self.body25.shape[1]


def capture_area(rig: Camera, half_size_fraction: float = 0.4) -> tuple[float, float, float, float]:
    """The floor rectangle ``(x_min, y_min, x_max, y_max)`` in metres the rig looks at.

    Its centre is the point nearest (least squares) to all optical axes, dropped onto the z = 0
    floor; its half side is ``half_size_fraction`` times the median horizontal distance from that
    centre to the cameras (1.4 m for the Shelf rig)."""
    centres = np.asarray(geometry.camera_centre(rig), np.float64).reshape(-1, 3)
    axes = np.asarray(rig.R, np.float64).reshape(-1, 3, 3)[:, 2]
    # Least-squares point p minimising the distances to the lines centre + s * axis.
    projector = np.eye(3)[None] - axes[:, :, None] * axes[:, None, :]
    point = np.linalg.lstsq(projector.sum(0), np.einsum("vij,vj->i", projector, centres), rcond=None)[0]
    centre = point[:2]
    half = half_size_fraction * float(np.median(np.linalg.norm(centres[:, :2] - centre, axis=-1)))
    return (centre[0] - half, centre[1] - half, centre[0] + half, centre[1] + half)


def _ping_pong(indices: np.ndarray, length: int) -> np.ndarray:
    """Map any frame index onto a clip played forwards then backwards (continuous, no jump)."""
    if length == 1:
        return np.zeros_like(indices)
    period = 2 * (length - 1)
    phase = np.mod(indices, period)
    return np.where(phase < length, phase, period - phase)


def _rotation_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


class _PlacedGroup(NamedTuple):
    body25: np.ndarray  # (frames, n, 25, 3)
    structri17: np.ndarray  # (frames, n, 17, 3)
    root: np.ndarray  # (frames, n, 2) mid-hip on the floor
    offset: np.ndarray
    heading: float
    time_shift: int
    path_scale: float


def _random_placement(
    rng: np.random.Generator,
    group: MotionGroup,
    num_frames: int,
    area: tuple[float, float, float, float],
    max_path_fraction: float,
) -> _PlacedGroup:
    x_min, y_min, x_max, y_max = area
    size = np.array([x_max - x_min, y_max - y_min])
    hip = BODY25.index("mid_hip")
    length = group.body25.shape[0]
    shift = int(rng.integers(0, max(length - num_frames, 0) + 1))
    heading = float(rng.uniform(0.0, 2.0 * np.pi))
    frames = _ping_pong(shift + np.arange(num_frames), length)
    b25, h17 = group.body25[frames], group.structri17[frames]
    centre = b25[:, :, hip, :2].reshape(-1, 2).mean(0)
    rotation = _rotation_z(heading)
    root = np.einsum("ij,...j->...i", rotation[:2, :2], b25[:, :, hip, :2] - centre)
    # Shrink long paths (walking, running) so the group stays in the area: poses unchanged, the
    # body moves along a scaled-down path (the feet slide, which 2D detections hardly show).
    path = root.mean(1)
    extent = np.maximum(path.max(0) - path.min(0), 1e-9)
    scale = min(1.0, float(np.min(max_path_fraction * size / extent)))
    squeeze = (scale - 1.0) * (path - path.mean(0))  # (frames, 2)
    root = root + squeeze[:, None]
    # The whole root path inside the area when it fits, else centred.
    low = np.array([x_min, y_min]) - root.reshape(-1, 2).min(0)
    high = np.array([x_max, y_max]) - root.reshape(-1, 2).max(0)
    offset = np.where(low <= high, rng.uniform(np.minimum(low, high), np.maximum(low, high)), (low + high) / 2)
    translation = np.array([*offset, 0.0]) - rotation @ np.array([*centre, 0.0])
    translation = translation + np.pad(squeeze, ((0, 0), (0, 1)))[:, None, None, :]
    return _PlacedGroup(
        np.einsum("ij,...j->...i", rotation, b25) + translation,
        np.einsum("ij,...j->...i", rotation, h17) + translation,
        root + offset, offset, heading, shift, scale,
    )


def _min_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Smallest distance between any person of roots ``a`` and any of ``b`` (frames, n, 2) at equal times."""
    return float(np.min(np.linalg.norm(a[:, :, None] - b[:, None], axis=-1)))


def place_groups(
    rng: np.random.Generator,
    groups: Sequence[MotionGroup],
    num_frames: int,
    area: tuple[float, float, float, float],
    min_separation: float,
    *,
    max_attempts: int = 20,
    attempts_per_group: int = 50,
    max_path_fraction: float = 0.5,
) -> tuple[Float[np.ndarray, "frames people 25 3"], Float[np.ndarray, "frames people 17 3"], ScenePlacement]:
    """Place the groups one after another with random (time shift, heading, offset) in ``area``.

    A group is re-drawn up to ``attempts_per_group`` times until its mid-hips keep ``min_separation``
    metres (horizontally) from every person already placed, at every frame; when a group does not
    fit, the whole placement starts over, up to ``max_attempts`` times, then ``ValueError``. A group
    whose mid-hip path is longer than ``max_path_fraction`` of the area's side moves along a path
    shrunk to that length. Deterministic given the generator's state."""
    x_min, y_min, x_max, y_max = area
    if not (x_max > x_min and y_max > y_min):
        raise ValueError(f"area must be (x_min, y_min, x_max, y_max) with positive size, got {area}")
    for _restart in range(max_attempts):
        placed: list[_PlacedGroup] = []
        for group in groups:
            for _attempt in range(attempts_per_group):
                candidate = _random_placement(rng, group, num_frames, area, max_path_fraction)
                if all(_min_distance(candidate.root, other.root) >= min_separation for other in placed):
                    placed.append(candidate)
                    break
            else:
                break
        if len(placed) == len(groups):
            break
    else:
        raise ValueError(
            f"could not place {len(groups)} groups ({sum(len(g.names) for g in groups)} people) with mid-hips at least "
            f"{min_separation} m apart in the area {area} ({max_attempts} restarts); use a larger area, fewer people "
            "or a smaller min_separation"
        )
    group_ids = np.concatenate([np.full(len(g.names), i) for i, g in enumerate(groups)])
    pairs = [(i, k) for i in range(len(placed)) for k in range(i)]
    min_distance = min((_min_distance(placed[i].root, placed[k].root) for i, k in pairs), default=float("inf"))
    placement = ScenePlacement(
        group_ids, tuple(n for g in groups for n in g.names), np.array([p.offset for p in placed]),
        np.array([p.heading for p in placed]), np.array([p.time_shift for p in placed]),
        np.array([p.path_scale for p in placed]), min_distance,
    )
    return (np.concatenate([p.body25 for p in placed], axis=1), np.concatenate([p.structri17 for p in placed], axis=1),
            placement)


def compose_scene(
    key: ArrayLike,
    rig: Camera,
    groups: Sequence[MotionGroup],
    *,
    num_frames: int,
    fps: float,
    area: Sequence[float | int] | None = None,
    detector: DetectorConfig = DetectorConfig(),
    min_separation: float = 0.7,
    max_attempts: int = 20,
) -> Scene:
    """Place the given motion groups (:func:`place_groups`) and simulate the detections.

    ``area`` defaults to :func:`capture_area` of the rig. The key is split into a placement key
    and a detector key."""
    if num_frames < 1:
        raise ValueError(f"num_frames must be >= 1, got {num_frames}")
    if not groups:
        raise ValueError("a scene needs at least one motion group")
    for group in groups:
        n = len(group.names)
        if group.body25.ndim != 4 or group.body25.shape[1:] != (n, 25, 3):
            raise ValueError(f"group {group.names}: body25 must be (time, {n}, 25, 3), got {group.body25.shape}")
        if group.structri17.shape != group.body25.shape[:2] + (17, 3):
            raise ValueError(f"group {group.names}: structri17 must be {group.body25.shape[:2] + (17, 3)}, "
                             f"got {group.structri17.shape}")
    placement_key, detector_key = jax.random.split(_as_key(key))
    area = capture_area(rig) if area is None else tuple(float(a) for a in area)
    if len(area) != 4:
        raise ValueError(f"area must be (x_min, y_min, x_max, y_max) in metres, got {len(area)} values")
    body25, structri17, placement = place_groups(
        _numpy_rng(placement_key), groups, num_frames, area, min_separation, max_attempts=max_attempts
    )
    detections, events = detect_with_events(detector_key, rig, body25, detector)
    shelf15 = np.asarray(geometry.to_shelf15(structri17, STRUCTRI17))
    shelf15_pixels = np.asarray(geometry.project_to_views(rig, shelf15)).transpose(1, 0, 2, 3, 4)
    return Scene(
        rig=rig, body25=body25, shelf15=shelf15, structri17=structri17, body25_pixels=events.geometry.pixels,
        shelf15_pixels=shelf15_pixels, visible=events.geometry.visible, detections=detections, events=events,
        placement=placement, fps=fps,
    )


def motion_group(clip: Clip) -> MotionGroup:
    """A clip's people as one :class:`MotionGroup` (time axis first)."""
    names = tuple(clip.name if clip.num_people == 1 else f"{clip.name}[{p}]" for p in range(clip.num_people))
    return MotionGroup(names, np.swapaxes(clip.body25, 0, 1), np.swapaxes(clip.structri17, 0, 1))


def synthesise_scene(
    key: ArrayLike,
    rig: Camera,
    *,
    num_people: int = 4,
    num_frames: int = 300,
    clips: Sequence[str | Clip] | None = None,
    area: Sequence[float | int] | None = None,
    detector: DetectorConfig = DetectorConfig(),
    min_separation: float = 0.7,
    max_attempts: int = 20,
) -> Scene:
    """A synthetic capture of ``num_people`` people from motion clips, seen by ``rig``.

    ``clips`` are shipped clip names (:func:`~mocap.list_clips`) or :class:`~mocap.Clip` objects;
    by default all shipped clips, or procedural walkers when none are shipped. They are shuffled
    by the key and taken in turn (a two-person clip, the salsa pair, brings both partners; it is
    skipped when only one person is still needed; clips are reused, with other time shifts and
    headings, when there are fewer clips than people). All clips must share one frame rate, which
    becomes the scene's. Clips shorter than ``num_frames`` play forwards and backwards.

    People are placed in ``area`` = ``(x_min, y_min, x_max, y_max)`` metres on the z = 0 floor
    (default :func:`capture_area`, where the rig's optical axes meet) with mid-hips at least
    ``min_separation`` metres apart at every frame (see :func:`place_groups`); the detections come
    from :func:`~mocap.detect` with ``detector``. A pure function of ``key`` and the arguments.
    """
    if num_people < 1:
        raise ValueError(f"num_people must be >= 1, got {num_people}")
    placement_key, scene_key = jax.random.split(_as_key(key))
    rng = _numpy_rng(placement_key)
    if clips is None:
        names = list_clips()
        loaded = [load_clip(n) for n in names] if names else [
            procedural_clip(seed=s, num_frames=max(num_frames, 120)) for s in range(num_people)
        ]
    else:
        loaded = [load_clip(c) if isinstance(c, str) else c for c in clips]
    if not loaded:
        raise ValueError("clips is empty")
    rates = {c.fps for c in loaded}
    if len(rates) != 1:
        raise ValueError(f"all clips need one frame rate, got {sorted(rates)} fps")
    if min(c.num_people for c in loaded) > num_people:
        raise ValueError(f"every clip has more than num_people={num_people} people")
    groups: list[MotionGroup] = []
    needed = num_people
    while needed:
        for i in rng.permutation(len(loaded)):
            if 0 < loaded[i].num_people <= needed:
                groups.append(motion_group(loaded[i]))
                needed -= loaded[i].num_people
    return compose_scene(
        scene_key, rig, groups, num_frames=num_frames, fps=rates.pop(), area=area, detector=detector,
        min_separation=min_separation, max_attempts=max_attempts,
    )


def _as_key(key: ArrayLike) -> jax.Array:
    return key if isinstance(key, jax.Array) else jnp.asarray(key, jnp.uint32)

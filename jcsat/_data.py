"""Training windows for the JCSAT model from synthetic Shelf-rig scenes (paper Sec. 4.1.3, reference sections 3-5).

A scene (:func:`mocap.synthesise_scene`: the shipped Shelf calibration, CMU clips, the realistic
detector) goes through exactly the test-time path, :func:`~association.track_people`: detections -> Joint Cloud ->
per-frame K-Means persons -> tracks -> :func:`~association.person_joint_cloud`. Ground truth never enters that path; it
is used only afterwards, to label each (track, frame) with the ground-truth person whose BODY25 mid-hip
lies within ``match_radius`` of the track's centre (the JCSAT protocol's 0.5 m).

Storage (:class:`WindowDataset`): one *row* per (track, frame) of every kept track, in world
coordinates, and one window per start row (``window`` consecutive rows of one track whose first row
is labelled). A window's frame n has a valid target iff its row is labelled with the same person as
the first row. :func:`window_batch` gathers windows, centres them on the first frame's cluster centre
and rotates them about the vertical (the paper's augmentation); :func:`sample_batch` draws the
windows and angles from a key.

Shapes: ``R`` rows, ``W`` windows, ``S`` scenes, ``V`` views, ``P = V (V - 1) / 2`` view pairs,
``M`` candidates per pair, ``J = 25`` BODY25 joint types, ``N`` frames per window, ``B`` batch.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

import geometry
import mocap
import training
from association import ClusterConfig, JointCloudConfig, track_people
from geometry import BODY25

__all__ = [
    "TRAIN_CLIPS",
    "VALIDATION_CLIPS",
    "DataConfig",
    "WindowDataset",
    "Batch",
    "scene_windows",
    "build_dataset",
    "window_batch",
    "sample_batch",
]

VALIDATION_CLIPS: tuple[str, ...] = ("02_05_punch", "03_01_uneven", "60_05_61_05_salsa")
"""Shipped clips held out of training: validation scenes use motions the model never saw."""
TRAIN_CLIPS: tuple[str, ...] = tuple(c for c in mocap.list_clips() if c not in VALIDATION_CLIPS)

_MID_HIP = BODY25.index("mid_hip")
_CACHE_VERSION = 2
"""Bump when the stored arrays change meaning, so stale caches are not reused."""


@dataclasses.dataclass(frozen=True)
class DataConfig:
    """Which synthetic scenes become windows, and how (everything the cache key depends on)."""

    clips: tuple[str, ...] = TRAIN_CLIPS
    """Shipped clip names or motion files (:func:`mocap.load_clip_file`, paths as :func:`mocap.resolve_clip` gives
    them), e.g. the CMU-Mocap benchmark's train split (:func:`mocap.cmu_expmap_files`); the scenes draw their
    people from these."""
    num_scenes: int = 16
    first_seed: int = 0
    """Scene i is ``mocap.synthesise_scene(jax.random.key(first_seed + i), ...)``; K-Means uses the same key."""
    num_people: int = 4
    num_frames: int = 150
    window: int = 10
    """N: frames per window (the paper's 10)."""
    window_stride: int = 1
    """Frames between the starts of consecutive windows of a track."""
    match_radius: float = 0.5
    """Metres: a track's frame is labelled with the ground-truth person whose mid-hip is nearest to
    the track's centre, if closer than this (JCSAT protocol)."""
    max_candidates: int = 8
    """2D candidates per view and joint type after padding (raised for a scene that has more); a
    fixed size lets all scenes share one compilation."""
    joint_cloud: JointCloudConfig = JointCloudConfig()
    cluster: ClusterConfig = ClusterConfig()
    head_rule: geometry.HeadRule = "h36m"
    """How the labels' head joints (Shelf15 12 and 13) are made; the other joints do not depend on it.
    ``"h36m"``: from the mocap skeleton's own neck and head (STRUCTRI17); any other rule of
    :func:`geometry.to_shelf15`: from the BODY25 ears, shoulders and neck, e.g. ``"4da"``, the rule of JCSAT's
    official code (its auxiliary "morph" target) and of the 4D-association output, whose head top lies
    further in front of the shoulders, as Shelf's annotations do."""

    def __post_init__(self) -> None:
        if self.head_rule not in geometry.HEAD_RULES:
            raise ValueError(f"head_rule must be one of {geometry.HEAD_RULES}, got {self.head_rule!r}")
        if not self.clips:
            raise ValueError("clips names no clip")
        for clip in self.clips:
            mocap.clip_files(clip)  # a ValueError naming a clip that is neither shipped nor a file
        for name in ("num_scenes", "num_people", "window", "window_stride", "max_candidates"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.num_frames < self.window:
            raise ValueError(f"num_frames ({self.num_frames}) must be at least window ({self.window})")
        if self.match_radius <= 0:
            raise ValueError(f"match_radius must be positive (metres), got {self.match_radius}")

    @property
    def seeds(self) -> range:
        return range(self.first_seed, self.first_seed + self.num_scenes)

    def cache_key(self) -> str:
        text = json.dumps({"version": _CACHE_VERSION, **dataclasses.asdict(self)}, sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


class WindowDataset(NamedTuple):
    """Rows (track frames) and windows of one or more scenes, NumPy, world frame (see the module docstring)."""

    points: Float[np.ndarray, "R P M J 3"]
    """float32 metres; 0 where not ``mask``."""
    mask: Bool[np.ndarray, "R P M J"]
    centre: Float[np.ndarray, "R 3"]
    """The track's K-Means MidHip centre in the row's frame (metres; 0 where the track is absent)."""
    target: Float[np.ndarray, "R 15 3"]
    """float64 Shelf15 ground truth of ``person`` (metres; 0 where ``person`` is -1)."""
    person: Int[np.ndarray, " R"]
    """Ground-truth person (index in its scene) the row is labelled with, -1 for none."""
    frame: Int[np.ndarray, " R"]
    scene: Int[np.ndarray, " R"]
    """Index into ``projections`` / ``image_size``."""
    window_start: Int[np.ndarray, " W"]
    """Row of each window's first frame; the window is rows ``start .. start + N - 1``."""
    projections: Float[np.ndarray, "S V 3 4"]
    """``K [R | t]`` of each scene's rig (the Shelf rig has no distortion, so these are exact)."""
    image_size: Float[np.ndarray, "S V 2"]

    @property
    def num_windows(self) -> int:
        return self.window_start.shape[0]


class Batch(NamedTuple):
    """Model input and targets of B windows in each window's model frame (centred, rotated about z)."""

    points: Float[Array, "B N P M J 3"]
    """float32 metres: world points minus the first frame's cluster centre, rotated; 0 where not ``mask``."""
    mask: Bool[Array, "B N P M J"]
    target: Float[Array, "B N 15 3"]
    """Shelf15 ground truth in the same frame (the widest enabled float); 0 where not ``target_valid``."""
    target_valid: Bool[Array, "B N"]
    projections: Float[Array, "B V 3 4"]
    """``P @ [[R^T, c], [0, 1]]``: maps model-frame points to the real pixels."""
    image_size: Float[Array, "B V 2"]
    """Width and height in pixels."""


def _label_rows(centre: np.ndarray, present: np.ndarray, hips: np.ndarray, radius: float) -> np.ndarray:
    """Ground-truth person of every (track, frame): nearest mid-hip within ``radius``, else -1.

    centre (T, F, 3), present (T, F), hips (F, people, 3) -> (T, F) int.
    """
    distance = np.linalg.norm(centre[:, :, None, :] - hips[None, :, :, :], axis=-1)  # (T, F, people)
    nearest = np.argmin(distance, axis=-1)
    close = np.take_along_axis(distance, nearest[..., None], axis=-1)[..., 0] < radius
    return np.where(present & close, nearest, -1).astype(np.int32)


def scene_windows(scene: mocap.Scene, config: DataConfig, key: ArrayLike, scene_index: int = 0) -> WindowDataset:
    """Windows of ONE synthetic scene, through the test-time pipeline (``key`` seeds K-Means)."""
    largest = max(len(c) for frame in scene.detections for det in frame for c in det.joints)
    padded = mocap.pad_detections(scene.detections, max(config.max_candidates, largest))
    tracks = track_people(scene.rig, padded, key, config.joint_cloud, config.cluster).person_cloud

    person = _label_rows(tracks.centre, tracks.present, scene.body25[:, :, _MID_HIP], config.match_radius)
    starts = np.arange(0, person.shape[1] - config.window + 1, config.window_stride)
    labelled = person[:, starts] >= 0  # (T, windows per track)
    # Keep, per track, only the frames its labelled windows cover (spurious tracks cost nothing).
    row_track, row_frame, window_start = [], [], []
    offset = 0
    for track in np.flatnonzero(labelled.any(axis=1)):
        first = starts[labelled[track]]
        frames = np.arange(first[0], first[-1] + config.window)
        window_start.append(offset + first - first[0])
        row_track.append(np.full(len(frames), track))
        row_frame.append(frames)
        offset += len(frames)
    row_track, row_frame, window_start = (
        np.concatenate(parts) if parts else np.zeros(0, np.int64) for parts in (row_track, row_frame, window_start)
    )
    row_person = person[row_track, row_frame]
    target = _labels(scene, config.head_rule)[row_frame, np.maximum(row_person, 0)]
    return WindowDataset(
        points=np.asarray(tracks.points, np.float32)[row_track, row_frame],
        mask=np.asarray(tracks.mask)[row_track, row_frame],
        centre=tracks.centre[row_track, row_frame],
        target=np.where((row_person >= 0)[:, None, None], target, 0.0),
        person=row_person,
        frame=row_frame.astype(np.int32),
        scene=np.full(len(row_track), scene_index, np.int32),
        window_start=window_start.astype(np.int32),
        projections=np.asarray(geometry.projection_matrix(scene.rig))[None],
        image_size=np.asarray(scene.rig.image_size)[None],
    )


def _labels(scene: mocap.Scene, head_rule: str) -> Float[np.ndarray, "frames people 15 3"]:
    """The scene's Shelf15 ground truth with its head joints made by ``head_rule``."""
    if head_rule == "h36m":
        return scene.shelf15
    return np.asarray(geometry.to_shelf15(scene.body25, BODY25, head_rule), np.float64)


def _concatenate(parts: list[WindowDataset]) -> WindowDataset:
    offsets = np.cumsum([0] + [len(p.person) for p in parts[:-1]])
    fields = {name: np.concatenate([getattr(p, name) for p in parts]) for name in WindowDataset._fields}
    fields["window_start"] = np.concatenate([p.window_start + o for p, o in zip(parts, offsets)]).astype(np.int32)
    fields["scene"] = np.concatenate([np.full_like(p.scene, i) for i, p in enumerate(parts)])
    return WindowDataset(**fields)


def build_dataset(config: DataConfig, cache_dir: str | Path | None = None, *, workers: int = 1) -> WindowDataset:
    """All windows of ``config.num_scenes`` seeded scenes, cached as ``<cache_dir>/windows_<key>.npz``.

    The cache file name is a hash of the whole config, so changing any field builds anew; the file is
    written under a temporary name and renamed, so an interrupted build leaves no partial cache.
    ``workers > 1`` builds scenes in that many CPU-only processes (a scene takes seconds and scenes are
    independent); the windows are the same as a one-process build's, in the same order.
    """
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    path = None if cache_dir is None else Path(cache_dir) / f"windows_{config.cache_key()}.npz"
    if path is not None and path.is_file():
        with np.load(path) as stored:
            return WindowDataset(**{name: stored[name] for name in WindowDataset._fields})
    parts = training.process_map(_seeded_scene_windows,
                                 [(config, seed, index) for index, seed in enumerate(config.seeds)], workers)
    dataset = _concatenate(parts)
    if path is not None:
        training.write_atomically(path, lambda file: np.savez_compressed(file, **dataset._asdict()))
    return dataset


def _seeded_scene_windows(config: DataConfig, seed: int, index: int) -> WindowDataset:
    clips = [mocap.shared_clip(name) for name in config.clips]
    key = jax.random.key(seed)
    scene = mocap.synthesise_scene(key, mocap.shelf_cameras(), num_people=config.num_people,
                                   num_frames=config.num_frames, clips=clips)
    return scene_windows(scene, config, key, index)


def window_batch(
    data: WindowDataset, index: Int[ArrayLike, " B"], angle: Float[ArrayLike, " B"], window: int
) -> Batch:
    """Windows ``index`` of ``data`` (NumPy or jax leaves), centred and rotated by ``angle`` (radians) about z.

    Pure and jit-able (``window`` static). With R the rotation and c the first frame's centre, a
    world point x becomes ``R (x - c)`` and each projection ``P`` becomes ``P [[R^T, c], [0, 1]]``.
    """
    # Geometry in the widest enabled float (float64 under x64) so targets and projections stay exact;
    # only the model input is cast to float32.
    dtype = jnp.result_type(float)
    index, angle = jnp.asarray(index), jnp.asarray(angle, dtype)
    batch = index.shape[0]
    rows = jnp.asarray(data.window_start)[index][:, None] + jnp.arange(window)[None, :]  # (B, N)
    first = rows[:, 0]
    centre = jnp.asarray(data.centre, dtype)[first]  # (B, 3)
    axis = jnp.zeros((batch, 3), dtype).at[:, 2].set(1.0)
    rotation = geometry.axis_angle_to_matrix(angle[:, None] * axis)  # (B, 3, 3)

    def to_model(world: Array) -> Array:  # (B, ..., 3) -> (B, ..., 3)
        shape = (batch,) + (1,) * (world.ndim - 2) + (3,)
        return jnp.einsum("bij,b...j->b...i", rotation, world - centre.reshape(shape))

    mask = jnp.asarray(data.mask)[rows]
    points = jnp.where(mask[..., None], to_model(jnp.asarray(data.points, dtype)[rows]), 0.0)
    person = jnp.asarray(data.person)[rows]
    valid = person == person[:, :1]
    target = jnp.where(valid[..., None, None], to_model(jnp.asarray(data.target, dtype)[rows]), 0.0)
    inverse = jnp.zeros((batch, 4, 4), dtype)
    inverse = inverse.at[:, :3, :3].set(jnp.swapaxes(rotation, -1, -2)).at[:, :3, 3].set(centre).at[:, 3, 3].set(1.0)
    scene = jnp.asarray(data.scene)[first]
    projections = jnp.einsum("bvij,bjk->bvik", jnp.asarray(data.projections, dtype)[scene], inverse)
    image_size = jnp.asarray(data.image_size, dtype)[scene]
    return Batch(points.astype(jnp.float32), mask, target, valid, projections, image_size)


def sample_batch(data: WindowDataset, key: Array, batch_size: int, window: int) -> Batch:
    """``batch_size`` windows drawn uniformly with replacement and angles uniform in [0, 2 pi), from ``key``.

    Pure and jit-able (``batch_size`` and ``window`` static): the same key gives the same batch.
    """
    index_key, angle_key = jax.random.split(key)
    index = jax.random.randint(index_key, (batch_size,), 0, data.window_start.shape[0])
    angle = jax.random.uniform(angle_key, (batch_size,), jnp.result_type(float), 0.0, 2.0 * jnp.pi)
    return window_batch(data, index, angle, window)

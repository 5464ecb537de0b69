"""The whole learning-free pipeline: detections -> Joint Cloud -> persons and tracks -> geometric poses -> Shelf15."""

from __future__ import annotations

import dataclasses
import time
from typing import NamedTuple

import jax
import numpy as np
from jaxtyping import Bool, Float, Int

import geometry
import mocap
from geometry import BODY25, Camera

from ._clustering import (
    ClusterConfig,
    FrameClusters,
    PersonJointCloud,
    cluster_frames,
    people_count,
    person_joint_cloud,
    track_centres,
)
from ._geometric import (
    GeometricConfig,
    GeometricPoses,
    fill_missing,
    geometric_poses,
    reject_temporal_outliers,
    structural_refinement,
)
from ._joint_cloud import JointCloud, JointCloudConfig, build_joint_cloud

__all__ = ["BaselineConfig", "BaselineResult", "PersonTracks", "run_geometric_baseline", "track_people"]


@dataclasses.dataclass(frozen=True)
class BaselineConfig:
    """Every parameter of the geometric baseline (saved next to its outputs)."""

    joint_cloud: JointCloudConfig = JointCloudConfig()
    cluster: ClusterConfig = ClusterConfig()
    geometric: GeometricConfig = GeometricConfig()
    seed: int = 0
    """K-Means key: ``jax.random.key(seed)``."""
    min_track_frames: int = 5
    """Tracks present in fewer frames than this are dropped from the predictions: a short-lived
    track is a spurious cluster (cross-person candidates, a split person), not a new person."""
    max_gap_frames: int = 5
    """A track absent for at most this many frames between two frames where it is present is
    bridged: the gap frames take each joint from the nearest frame that has it
    (:func:`~association.fill_missing`). A person whose MidHip goes undetected for a moment keeps a pose."""
    outlier_half_window: int = 2
    """Frames on either side of the temporal median of :func:`~association.reject_temporal_outliers`
    (0: no outlier rejection). Chosen with ``outlier_distance`` on a 3 x 5 grid of synthetic Shelf-rig
    validation scenes (``python -m experiments.shelf_validate``; the grid and its scores: ``docs/jcsat.md``,
    "How the settings were chosen")."""
    outlier_distance: float = 0.05
    """Metres from that median beyond which a joint is replaced by it (0: every joint is)."""
    duplicate_distance: float = 0.2
    """Metres: :func:`mocap.suppress_duplicates` on the predictions, ranked by support (the number of Joint
    Cloud candidates the track's cluster holds in the frame). A surplus K-Means centre beside a person
    gathers that person's candidates too and becomes a second skeleton of them; ranking puts the
    better-supported one first, which is the one the JCSAT protocol scores, and this distance drops the
    other (0: ranking only).
    0.2 m, below any two people's mean joint distance, also drops near-copies; chosen by ``python -m
    experiments.shelf_validate --protocol jcsat`` (``docs/jcsat.md``)."""
    max_candidates: int | None = None
    """Pad every view and joint type to this many 2D candidates (default: the largest count). A fixed
    size lets runs of different scenes share one compilation."""

    def __post_init__(self) -> None:
        if self.outlier_half_window < 0:
            raise ValueError(f"outlier_half_window must be >= 0 frames, got {self.outlier_half_window}")
        if not (self.outlier_distance >= 0.0 and np.isfinite(self.outlier_distance)):
            raise ValueError(f"outlier_distance must be a finite number of metres >= 0, got {self.outlier_distance}")
        if not (self.duplicate_distance >= 0.0 and np.isfinite(self.duplicate_distance)):
            raise ValueError(f"duplicate_distance must be a finite number of metres >= 0, got {self.duplicate_distance}")


class BaselineResult(NamedTuple):
    predictions: mocap.PosePredictions
    """Shelf15 poses, one row per (frame, track) where the track is present and the track lasts at
    least ``min_track_frames``, less duplicates (``duplicate_distance``); rows by frame, then by
    decreasing ``score``, the support; joints never seen by the track are (0, 0, 0)."""
    body25: Float[np.ndarray, "T F 25 3"]
    """Per track, after :func:`~association.fill_missing` (metres)."""
    body25_valid: Bool[np.ndarray, "T F 25"]
    present: Bool[np.ndarray, "T F"]
    cloud: JointCloud
    clusters: FrameClusters
    track_of: Int[np.ndarray, "F K"]
    person_cloud: PersonJointCloud
    seconds: dict[str, float]
    """Wall time of each stage (including compilation on the first call)."""
    consensus: GeometricPoses
    """The consensus re-triangulation per frame and centre slot (``track_of`` gives each slot's track), before
    the structural refinement and the temporal filters: the 2D detections and weights each joint was
    triangulated from, for re-solving the tracks with other triangulation methods."""


def _timed(seconds: dict[str, float], name: str, fn, *args):
    start = time.perf_counter()
    out = jax.block_until_ready(fn(*args))
    seconds[name] = time.perf_counter() - start
    return out


class PersonTracks(NamedTuple):
    """The stages the geometric baseline and the model share: the Joint Cloud, its people per frame and their tracks."""

    cloud: JointCloud
    clusters: FrameClusters
    track_of: Int[np.ndarray, "F K"]
    """Track of each frame's cluster (-1: none)."""
    person_cloud: PersonJointCloud
    """Per track and frame, the candidates near the person's centre: the model's input."""
    seconds: dict[str, float]
    """Wall time of each stage (including compilation on the first call)."""


def track_people(
    rig: Camera,
    padded: mocap.PaddedDetections,
    key: jax.Array,
    joint_cloud: JointCloudConfig = JointCloudConfig(),
    cluster: ClusterConfig = ClusterConfig(),
) -> PersonTracks:
    """Padded detections seen by ``rig`` -> Joint Cloud -> people per frame (K-Means seeded by ``key``) -> tracks
    -> each track's candidate tensor."""
    seconds: dict[str, float] = {}
    cloud = _timed(seconds, "joint_cloud", build_joint_cloud, rig, padded.xy, padded.score, padded.mask, joint_cloud)
    counts = people_count(padded.score, padded.mask, cluster)
    clusters = _timed(seconds, "clustering", cluster_frames, cloud, counts, key, cluster)
    track_of = _timed(seconds, "tracking", track_centres, clusters.centres, clusters.active, cluster.track_gate)
    person_cloud = _timed(seconds, "model_tensor", person_joint_cloud, cloud, clusters, track_of, cluster)
    return PersonTracks(cloud, clusters, track_of, person_cloud, seconds)


def _bridge_gaps(present: Bool[np.ndarray, "T F"], max_gap: int) -> Bool[np.ndarray, "T F"]:
    """``present`` with every run of at most ``max_gap`` absent frames between two present ones set."""
    bridged = present.copy()
    for track in range(present.shape[0]):
        seen = np.flatnonzero(present[track])
        for first, last in zip(seen[:-1], seen[1:]):
            if 1 < last - first <= max_gap + 1:
                bridged[track, first + 1:last] = True
    return bridged


def run_geometric_baseline(
    rig: Camera,
    detections: list[list[mocap.Detections]],
    frame_indices: Int[np.ndarray, " F"],
    config: BaselineConfig = BaselineConfig(),
) -> BaselineResult:
    """Run the baseline on ``detections[f][view]`` (BODY25) seen by ``rig``.

    ``frame_indices[f]`` is the frame number written into the predictions (actorsGT index on Shelf).
    """
    frame_indices = np.asarray(frame_indices)
    if len(frame_indices) != len(detections):
        raise ValueError(f"{len(detections)} frames of detections but {len(frame_indices)} frame indices")
    padded = mocap.pad_detections(detections, config.max_candidates)
    cloud, clusters, track_of, person_cloud, seconds = track_people(rig, padded, jax.random.key(config.seed),
                                                                    config.joint_cloud, config.cluster)
    poses = _timed(seconds, "geometric", geometric_poses, rig, padded.xy, padded.score, cloud, clusters,
                   config.geometric)

    start = time.perf_counter()
    num_tracks = person_cloud.present.shape[0]
    frame_of, slot_of = np.nonzero(track_of >= 0)

    def by_track(per_slot):  # (F, K, ...) -> (T, F, ...), zero where the track is absent
        per_slot = np.asarray(per_slot)
        out = np.zeros((num_tracks,) + per_slot.shape[:1] + per_slot.shape[2:], per_slot.dtype)
        out[track_of[frame_of, slot_of], frame_of] = per_slot[frame_of, slot_of]
        return out

    body25, valid = by_track(poses.body25).astype(float), by_track(poses.valid)
    if config.geometric.structural_steps:
        body25, _ = structural_refinement(
            geometry.projection_matrix(rig), body25, valid, by_track(poses.num_views), by_track(poses.pixels),
            by_track(poses.view_weight), config.geometric.structural_steps, config.geometric.structural_prior_weight,
            max_bone_deviation=config.geometric.max_bone_deviation)
    present = _bridge_gaps(person_cloud.present, config.max_gap_frames)
    for t in range(num_tracks):
        body25[t] = reject_temporal_outliers(body25[t], valid[t], config.outlier_half_window, config.outlier_distance)
        body25[t], valid[t] = fill_missing(body25[t], valid[t], present[t])
    shelf15 = np.asarray(geometry.to_shelf15(body25, BODY25))
    shelf_valid = np.asarray(geometry.to_shelf15_validity(valid, BODY25))
    shelf15 = np.where(shelf_valid[..., None], shelf15, 0.0)
    kept = present & (person_cloud.present.sum(axis=1) >= config.min_track_frames)[:, None]
    track, frame = np.nonzero(kept.T)[::-1]  # rows ordered by frame, then track
    order = np.lexsort((track, frame))
    track, frame = track[order], frame[order]
    support = np.asarray(person_cloud.mask).sum(axis=(2, 3, 4))  # (T, F)
    predictions = mocap.suppress_duplicates(mocap.PosePredictions.create(
        frame_indices[frame].astype(np.int64), track.astype(np.int64), shelf15[track, frame],
        score=support[track, frame].astype(np.float64),
    ), config.duplicate_distance)
    seconds["assemble"] = time.perf_counter() - start
    return BaselineResult(predictions, body25, valid, present, cloud, clusters, track_of,
                          person_cloud, seconds, poses)

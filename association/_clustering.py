"""Person clustering of the Joint Cloud (JCSAT Algorithm 1 and supplementary 1.2), tracking, and the model tensor.

Per frame: K-Means on the MidHip candidates gives one centre per person, with the number of people
``k`` read from the detections (:func:`people_count`, no ground truth); each 3D candidate joins the
nearest centre if it lies within that joint type's radius (:data:`BODY25_JOINT_RADIUS`, the official
code's thresholds). Centres are then linked over frames by Hungarian matching
(:func:`track_centres`), so a person keeps one track id. :func:`person_joint_cloud` finally packs
each track's candidates into the padded tensor the JCSAT model consumes.

Shapes: ``F`` frames, ``P`` view pairs, ``J = 25`` BODY25 joint types, ``C`` candidates per view and
joint type, ``K`` = ``ClusterConfig.max_people`` centre slots per frame (``active`` marks the used
ones), ``T`` tracks, ``M`` = ``ClusterConfig.candidates_per_pair`` candidates kept per view pair.
"""

from __future__ import annotations

import dataclasses
from functools import partial
from typing import Literal, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import scipy.optimize
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from geometry import BODY25

from ._joint_cloud import JointCloud

__all__ = [
    "BODY25_JOINT_RADIUS",
    "ClusterConfig",
    "KMeansResult",
    "FrameClusters",
    "PersonJointCloud",
    "people_count",
    "kmeans",
    "cluster_frames",
    "track_centres",
    "person_joint_cloud",
    "window_frames",
]

_RADIUS_BY_NAME = {
    "nose": 0.85, "neck": 0.7, "r_shoulder": 0.7, "l_shoulder": 0.7,
    "r_elbow": 0.8, "l_elbow": 0.7, "r_wrist": 0.8, "l_wrist": 0.8,
    "mid_hip": 0.3, "r_hip": 0.3, "l_hip": 0.3, "r_knee": 0.6, "l_knee": 0.6,
    "r_ankle": 1.0, "l_ankle": 1.0, "l_big_toe": 1.0, "l_small_toe": 1.0, "l_heel": 1.0,
    "r_big_toe": 1.0, "r_small_toe": 1.0, "r_heel": 1.0,
    "r_eye": 0.9, "l_eye": 0.9, "r_ear": 0.85, "l_ear": 0.85,
}
BODY25_JOINT_RADIUS: tuple[float, ...] = tuple(_RADIUS_BY_NAME[name] for name in BODY25.joints)
"""Metres, BODY25 order: a candidate joins a person if closer than this to the person's centre
(official JCSAT code, ``docs/jcsat.md``, "Where the paper is silent"; the asymmetric elbows are the code's)."""

_MID_HIP = BODY25.index("mid_hip")


@dataclasses.dataclass(frozen=True)
class ClusterConfig:
    """Clustering, tracking and packing parameters."""

    people_rule: Literal["min", "median", "max"] = "max"
    """How the number of people k of a frame is read from the detections: this statistic, over views,
    of the number of MidHip candidates scoring above ``count_min_score`` (the paper uses "min";
    see :func:`people_count`)."""
    count_min_score: float = 0.2
    """Detector score a MidHip candidate must exceed to be counted by ``people_rule``."""
    max_people: int = 6
    """Centre slots per frame (static shape); k is clipped to it."""
    kmeans_restarts: int = 8
    """K-Means runs from different seeds per frame; the one of least cost is kept."""
    kmeans_iterations: int = 20
    """Lloyd iterations of each K-Means run."""
    trimmed_kmeans: bool = True
    """Trim K-Means at the MidHip radius (see :func:`kmeans`): MidHip candidates that no person
    would accept (farther than that radius from every centre) do not pull the centres. Spurious
    cross-person candidates otherwise drag centres by tens of centimetres on Shelf. False: the
    paper's plain K-Means."""
    joint_radius: tuple[float, ...] = BODY25_JOINT_RADIUS
    """Metres, per BODY25 joint type: a candidate joins a person only within this distance of its centre."""
    track_gate: float = 0.5
    """Metres: a centre continues a track only if it moved less than this since the track was last seen."""
    candidates_per_pair: int = 4
    """M: candidates kept per (frame, view pair, joint) in the model tensor (the paper's M-hat = 4)."""

    def __post_init__(self) -> None:
        if self.people_rule not in ("min", "median", "max"):
            raise ValueError(f"people_rule must be 'min', 'median' or 'max', got {self.people_rule!r}")
        for name in ("max_people", "kmeans_restarts", "kmeans_iterations", "candidates_per_pair"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if len(self.joint_radius) != BODY25.num_joints or min(self.joint_radius) <= 0:
            raise ValueError(f"joint_radius needs {BODY25.num_joints} positive radii (metres)")
        if self.track_gate <= 0:
            raise ValueError(f"track_gate must be positive (metres), got {self.track_gate}")


def people_count(
    score: Float[ArrayLike, "*f V J C"], mask: Bool[ArrayLike, "*f V J C"], config: ClusterConfig = ClusterConfig()
) -> Int[np.ndarray, "*f"]:
    """Number of people per frame from the detections alone (no ground truth).

    Bottom-up detections have no persons, so a view's person count is its number of MidHip
    candidates scoring above ``config.count_min_score``; the frame's count is the ``people_rule``
    statistic over views (median rounded down), clipped to ``[0, max_people]``. "min" (the paper)
    undercounts whenever one view misses a person (occlusion); "median" tolerates a minority of
    views missing or hallucinating one.
    """
    score, mask = np.asarray(score), np.asarray(mask, bool)
    per_view = np.sum(mask[..., _MID_HIP, :] & (score[..., _MID_HIP, :] > config.count_min_score), axis=-1)
    statistic = {"min": np.min, "median": np.median, "max": np.max}[config.people_rule]
    return np.clip(np.floor(statistic(per_view, axis=-1)).astype(np.int32), 0, config.max_people)


class KMeansResult(NamedTuple):
    centres: Float[Array, "K 3"]
    """Metres; inactive slots hold 0."""
    active: Bool[Array, "K"]
    inertia: Float[Array, ""]
    """Weighted sum of squared distances to the nearest active centre (m^2)."""


def _squared_distances(points: Float[Array, "N 3"], centres: Float[Array, "K 3"]) -> Float[Array, "N K"]:
    diff = points[:, None, :] - centres[None, :, :]
    return jnp.sum(diff * diff, axis=-1)


def _kmeans_once(points, weight, k, key, num_slots: int, iterations: int, trim: float | None) -> KMeansResult:
    slots = jnp.arange(num_slots)
    active = slots < k
    big = jnp.asarray(jnp.finfo(points.dtype).max / 4, points.dtype)
    cap = big if trim is None else jnp.asarray(trim * trim, points.dtype)

    def seed(i, state):
        centres, key = state
        key, sub = jax.random.split(key)
        d2 = jnp.where(active & (slots < i), _squared_distances(points, centres), big).min(axis=1)
        # k-means++: the first centre by weight, later ones by weight x squared distance (capped
        # when trimmed, so an isolated outlier is no likelier a seed than any point beyond the cap).
        prob = weight * jnp.where(i == 0, 1.0, jnp.minimum(jnp.minimum(d2, cap), 1e6))
        prob = jnp.where(jnp.sum(prob) > 0, prob, weight)
        choice = jax.random.choice(sub, points.shape[0], p=prob / jnp.maximum(jnp.sum(prob), 1e-30))
        return centres.at[i].set(points[choice]), key

    centres, _ = jax.lax.fori_loop(0, num_slots, seed, (jnp.zeros((num_slots, 3), points.dtype), key))

    def nearest(centres):
        d2 = jnp.where(active[None, :], _squared_distances(points, centres), big)
        return jnp.argmin(d2, axis=1), jnp.min(d2, axis=1)

    def lloyd(_, centres):
        label, d2 = nearest(centres)
        inlier = weight * (d2 < cap)
        member = (label[:, None] == slots[None, :]) * inlier[:, None]  # (N, K)
        total = jnp.sum(member, axis=0)
        mean = jnp.sum(member[:, :, None] * points[:, None, :], axis=0) / jnp.maximum(total, 1e-30)[:, None]
        # An empty cluster keeps its centre.
        return jnp.where((total > 0)[:, None], mean, centres)

    centres = jax.lax.fori_loop(0, iterations, lloyd, centres)
    _, d2 = nearest(centres)
    inertia = jnp.sum(weight * jnp.where(k > 0, jnp.minimum(d2, cap), 0.0))
    if trim is not None:
        # Two centres closer than the trim radius describe one person: keep the first.
        close = (_squared_distances(centres, centres) < cap) & (slots[None, :] < slots[:, None]) & active[None, :]
        active = active & ~jnp.any(close, axis=1)
    return KMeansResult(jnp.where(active[:, None], centres, 0.0), active, inertia)


@partial(jax.jit, static_argnames=("num_slots", "restarts", "iterations", "trim"))
def kmeans(
    points: Float[ArrayLike, "N 3"],
    weight: Float[ArrayLike, "N"],
    k: Int[ArrayLike, ""],
    key: Array,
    num_slots: int,
    restarts: int = 8,
    iterations: int = 20,
    trim: float | None = None,
) -> KMeansResult:
    """Weighted K-Means (k-means++ seeding, Lloyd iterations) of ONE point set, best of ``restarts``.

    ``k`` may be traced (clipped to the ``num_slots`` static slots and to the number of points with
    positive weight); points with weight 0 are ignored. Deterministic given ``key``.

    With ``trim`` (metres) it is a trimmed K-Means: points farther than ``trim`` from every centre
    do not move the centres, the seeding caps squared distances at ``trim**2`` and the inertia
    caps them likewise; centres ending closer than ``trim`` to an earlier one are deactivated (so
    fewer than k may be active). Without it, plain K-Means.
    """
    points, weight = jnp.asarray(points), jnp.asarray(weight, jnp.asarray(points).dtype)
    k = jnp.minimum(jnp.minimum(jnp.asarray(k), num_slots), jnp.sum(weight > 0))
    runs = jax.vmap(lambda key: _kmeans_once(points, weight, k, key, num_slots, iterations, trim))(
        jax.random.split(key, restarts)
    )
    best = jnp.argmin(runs.inertia)
    return jax.tree.map(lambda leaf: leaf[best], runs)


class FrameClusters(NamedTuple):
    """Per-frame persons: centre slots and the candidates' person labels."""

    centres: Float[Array, "F K 3"]
    """K-Means centres of the MidHip candidates (metres); 0 where not ``active``."""
    active: Bool[Array, "F K"]
    label: Int[Array, "F P J C C"]
    """Centre slot of each Joint Cloud candidate, -1 when invalid or outside every joint radius."""


@partial(jax.jit, static_argnames=("config",))
def _cluster_frames(cloud: JointCloud, counts, key, config: ClusterConfig) -> FrameClusters:
    radius = jnp.asarray(config.joint_radius, cloud.point.dtype)

    def one(cloud: JointCloud, k, key):
        hips = cloud.point[:, _MID_HIP].reshape(-1, 3)
        weight = cloud.valid[:, _MID_HIP].reshape(-1).astype(hips.dtype)
        trim = config.joint_radius[_MID_HIP] if config.trimmed_kmeans else None
        result = kmeans(hips, weight, k, key, config.max_people, config.kmeans_restarts, config.kmeans_iterations, trim)
        diff = cloud.point[..., None, :] - result.centres[None, None, None, None]  # (P, J, C, C, K, 3)
        distance = jnp.where(result.active, jnp.sqrt(jnp.sum(diff * diff, axis=-1)), jnp.inf)
        nearest = jnp.argmin(distance, axis=-1)
        close = jnp.min(distance, axis=-1) < radius[None, :, None, None]
        return result.centres, result.active, jnp.where(cloud.valid & close, nearest, -1)

    keys = jax.vmap(lambda f: jax.random.fold_in(key, f))(jnp.arange(counts.shape[0]))
    return FrameClusters(*jax.vmap(one)(cloud, counts, keys))


def cluster_frames(
    cloud: JointCloud, counts: Int[ArrayLike, "F"], key: Array, config: ClusterConfig = ClusterConfig()
) -> FrameClusters:
    """Algorithm 1's CLUSTER for every frame of a Joint Cloud (leaves ``(F, P, J, C, C, ...)``).

    ``counts`` is the number of people per frame (:func:`people_count`); frame f uses the key
    ``fold_in(key, f)``, so results do not depend on how frames are batched.
    """
    counts = jnp.asarray(counts, jnp.int32)
    if counts.shape != cloud.valid.shape[:1]:
        raise ValueError(f"counts must have shape ({cloud.valid.shape[0]},) (one per frame), got {counts.shape}")
    return _cluster_frames(cloud, counts, key, config)


def track_centres(
    centres: Float[ArrayLike, "F K 3"], active: Bool[ArrayLike, "F K"], gate: float
) -> Int[np.ndarray, "F K"]:
    """Link per-frame centre slots into tracks; returns the track id of every slot (-1 inactive).

    Frame by frame, the active centres are matched to the existing tracks (position where each was
    last seen) by the Hungarian algorithm on Euclidean distance; a pair farther than ``gate``
    metres is not a match. Unmatched centres start new tracks, numbered in order of appearance.
    The ids therefore do not depend on the order of the slots (or of the detections).
    """
    centres, active = np.asarray(centres), np.asarray(active, bool)
    track_of = np.full(active.shape, -1, np.int32)
    last_seen: list[np.ndarray] = []
    for f in range(centres.shape[0]):
        slots = np.flatnonzero(active[f])
        if not len(slots):
            continue
        matched: dict[int, int] = {}
        if last_seen:
            cost = np.linalg.norm(centres[f, slots][:, None] - np.asarray(last_seen)[None], axis=-1)
            rows, cols = scipy.optimize.linear_sum_assignment(np.where(cost < gate, cost, 1e6))
            matched = {int(slots[r]): int(c) for r, c in zip(rows, cols) if cost[r, c] < gate}
        # New tracks in slot order of increasing x, so ids do not depend on the slot order.
        for slot in sorted((s for s in slots if s not in matched), key=lambda s: tuple(centres[f, s])):
            matched[int(slot)] = len(last_seen)
            last_seen.append(centres[f, slot])
        for slot, track in matched.items():
            track_of[f, slot] = track
            last_seen[track] = centres[f, slot]
    return track_of


class PersonJointCloud(NamedTuple):
    """The tensor the JCSAT model consumes: per track, frame, view pair, kept candidate and joint type.

    ``points`` is ``(T, F, P, M, J, 3)`` (metres; 0 where not ``mask``): the paper's
    ``N x V-hat x M-hat x I x 3`` per person with the whole sequence on the frame axis; take
    sliding windows of N = 10 frames with :func:`window_frames`. Candidate slot m holds the m-th
    best (by the product of the two detection scores) candidate of that person, view pair and joint.
    """

    points: Float[Array, "T F P M J 3"]
    mask: Bool[Array, "T F P M J"]
    present: Bool[np.ndarray, "T F"]
    """The track has a centre in the frame."""
    centre: Float[np.ndarray, "T F 3"]
    """The track's MidHip K-Means centre (0 where not present)."""


@partial(jax.jit, static_argnames=("num_slots", "per_pair"))
def _top_candidates(cloud: JointCloud, label, num_slots: int, per_pair: int):
    weight = jnp.prod(cloud.score, axis=-1)
    f, p, j, c, _ = label.shape
    flat_label = label.reshape(f, p, j, c * c)
    flat_weight = weight.reshape(f, p, j, c * c)
    flat_point = cloud.point.reshape(f, p, j, c * c, 3)
    slots = jnp.arange(num_slots)
    ranked = jnp.where(flat_label[..., None, :] == slots.reshape(1, 1, 1, -1, 1), flat_weight[..., None, :], -1.0)  # (F,P,J,K,CC)
    top, index = jax.lax.top_k(ranked, min(per_pair, c * c))
    points = jnp.take_along_axis(flat_point[..., None, :, :], index[..., None], axis=-2)  # (F,P,J,K,M,3)
    points = jnp.where((top >= 0)[..., None], points, 0.0)
    return jnp.moveaxis(points, (3, 4), (1, 3)), jnp.moveaxis(top >= 0, (3, 4), (1, 3))  # (F,K,P,M,J,...)


def person_joint_cloud(
    cloud: JointCloud, clusters: FrameClusters, track_of: Int[ArrayLike, "F K"], config: ClusterConfig = ClusterConfig()
) -> PersonJointCloud:
    """Pack each track's clustered candidates into the padded model tensor (see :class:`PersonJointCloud`)."""
    track_of = np.asarray(track_of)
    points, mask = _top_candidates(cloud, clusters.label, track_of.shape[1], config.candidates_per_pair)
    num_tracks = int(track_of.max()) + 1 if track_of.size and track_of.max() >= 0 else 0
    frame_of, slot_of = np.nonzero(track_of >= 0)
    tracks = track_of[frame_of, slot_of]
    shape = (num_tracks, track_of.shape[0])
    out_points = jnp.zeros(shape + points.shape[2:], points.dtype).at[tracks, frame_of].set(points[frame_of, slot_of])
    out_mask = jnp.zeros(shape + mask.shape[2:], bool).at[tracks, frame_of].set(mask[frame_of, slot_of])
    present = np.zeros(shape, bool)
    present[tracks, frame_of] = True
    centre = np.zeros(shape + (3,))
    centre[tracks, frame_of] = np.asarray(clusters.centres)[frame_of, slot_of]
    return PersonJointCloud(out_points, out_mask, present, centre)


def window_frames(num_frames: int, window: int = 10) -> Int[np.ndarray, "F N"]:
    """Frame indices of the causal window ending at each frame, clamped at the first frame.

    Row t is ``[t - N + 1, ..., t]`` with negative indices replaced by 0 (JCSAT inference keeps the
    window's last frame); index a per-frame array with it, e.g. ``points[:, window_frames(F)]``.
    """
    if window < 1:
        raise ValueError(f"window must be >= 1, got {window}")
    return np.maximum(np.arange(num_frames)[:, None] - np.arange(window - 1, -1, -1)[None, :], 0)

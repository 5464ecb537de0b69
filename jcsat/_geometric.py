"""A learning-free baseline on the clustered Joint Cloud: robust consensus, then multi-view re-triangulation.

For each person (centre slot), frame and BODY25 joint type, the candidates assigned to the person
(at most ``GeometricConfig.max_candidates``, the best by the product of their two detection scores)
are reduced to one 3D joint:

1. **Weighted medoid.** The candidate minimising ``sum_m w_m min(|x_i - x_m|, r)`` (``w`` = score
   product, ``r`` = ``consensus_radius``): the densest, best-supported point of the cloud; the
   truncation makes far outliers (cross-person or cross-type pairs) cost a constant.
2. **Consensus views.** The candidates within ``r`` of the medoid vote, with their weight, for the two
   2D detections they were triangulated from; each view keeps its most voted detection, if any.
3. **Re-triangulation** of those 2D detections with the N-view weighted DLT
   (:func:`geometry.triangulate_point`, weights = detection scores). With fewer than two consensus
   views the medoid itself is the answer.
4. **Reprojection check** (``inlier_pixels > 0``): the point is projected into every view; in each
   view the same-type 2D detection nearest to the projection is an inlier if closer than
   ``inlier_pixels`` (undistorted pixels), and the inliers of all views are re-triangulated
   (weights = scores). This recovers views whose pairs failed the Joint Cloud filters and drops
   consensus detections the point does not explain. Kept only if at least two views agree.

A joint far from its own temporal median (over the track's neighbouring frames) is an outlier,
typically a candidate cluster of another person or joint type that won the medoid in one frame, and
is replaced by that median (:func:`reject_temporal_outliers`, a Hampel filter). Joints of a track
that no candidate supports in a frame are filled from the nearest frame where the
same track has them (:func:`fill_missing`); BODY25 is then converted to Shelf15 with the 4D-association
head rule (:func:`geometry.to_shelf15`), the JCSAT convention for BODY25 sources.
"""

from __future__ import annotations

import dataclasses
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

import geometry
from geometry import BODY25, Camera

from ._clustering import FrameClusters
from ._joint_cloud import JointCloud, view_pairs

__all__ = ["GeometricConfig", "GeometricPoses", "consensus_joint", "geometric_poses", "fill_missing",
           "reject_temporal_outliers"]


@dataclasses.dataclass(frozen=True)
class GeometricConfig:
    """The baseline's two knobs."""

    consensus_radius: float = 0.2
    """Metres: candidates closer than this to the medoid support it. 0.2 was chosen on synthetic
    Shelf-rig validation scenes (:func:`~jcsat.synthetic_validation`; 0.05 / 0.1 / 0.2 / 0.3 m)."""
    max_candidates: int = 32
    """Candidates per person, frame and joint type entering the medoid (by score product)."""
    inlier_pixels: float = 0.0
    """Pixels: radius of the reprojection check (step 4 of the module docstring); 0 skips it (the
    default: 10-40 px changed synthetic validation PCP by less than 0.5 points)."""
    min_score: float = 0.2
    """2D detections at or below this score are never reprojection inliers (the Joint Cloud's filter)."""

    def __post_init__(self) -> None:
        if self.consensus_radius <= 0:
            raise ValueError(f"consensus_radius must be positive (metres), got {self.consensus_radius}")
        if self.inlier_pixels < 0:
            raise ValueError(f"inlier_pixels must be >= 0, got {self.inlier_pixels}")
        if self.max_candidates < 1:
            raise ValueError(f"max_candidates must be >= 1, got {self.max_candidates}")


class GeometricPoses(NamedTuple):
    """Baseline output per frame and centre slot (slot k of frame f is track ``track_of[f, k]``)."""

    body25: Float[Array, "F K 25 3"]
    """Metres; 0 where not ``valid``."""
    valid: Bool[Array, "F K 25"]
    num_views: Int[Array, "F K 25"]
    """Views whose detections were re-triangulated (0 when the medoid was kept)."""


def consensus_joint(
    points: Float[Array, "M 3"],
    weight: Float[Array, "M"],
    views: Int[Array, "M 2"],
    detection: Int[Array, "M 2"],
    pixels: Float[Array, "V C 2"],
    score: Float[Array, "V C"],
    projections: Float[Array, "V 3 4"],
    radius: float,
    inlier_pixels: float = 0.0,
    min_score: float = 0.2,
) -> tuple[Float[Array, "3"], Bool[Array, ""], Int[Array, ""]]:
    """ONE joint from its candidates: weighted medoid, consensus votes, N-view re-triangulation.

    Args:
        points: 3D candidates (metres); entries with weight 0 are ignored.
        weight: non-negative candidate weights (the product of the two detection scores).
        views: the two views each candidate was triangulated from.
        detection: the index of its 2D detection in each of those views.
        pixels: undistorted pixels of this joint type's 2D detections, per view.
        score: their detector scores.
        projections: ``K [R | t]`` per view.
        radius: consensus radius in metres.
        inlier_pixels: reprojection-check radius in pixels (0: no check).
        min_score: detections scoring at or below this are never reprojection inliers.

    Returns the point (metres), whether any candidate existed, and the number of re-triangulated views.
    """
    used = weight > 0
    diff = points[:, None, :] - points[None, :, :]
    distance = jnp.sqrt(jnp.sum(diff * diff, axis=-1) + 1e-30)
    cost = jnp.sum(weight[None, :] * jnp.minimum(distance, radius), axis=1)
    medoid = jnp.argmin(jnp.where(used, cost, jnp.inf))
    support = weight * (used & (distance[medoid] < radius))
    votes = jnp.zeros(score.shape, weight.dtype)
    votes = votes.at[views[:, 0], detection[:, 0]].add(support).at[views[:, 1], detection[:, 1]].add(support)
    chosen = jnp.argmax(votes, axis=1)
    view_index = jnp.arange(score.shape[0])
    view_weight = jnp.where(votes[view_index, chosen] > 0, score[view_index, chosen], 0.0)
    tri = geometry.triangulate_point(projections, pixels[view_index, chosen], view_weight)
    retriangulated = tri.valid & (tri.num_views >= 2)
    point = jnp.where(retriangulated, tri.point, points[medoid])
    num_views = jnp.where(retriangulated, tri.num_views, 0)
    if inlier_pixels > 0:
        projected = jnp.sum(projections[:, :, :3] * point[None, None, :], axis=-1) + projections[:, :, 3]  # (V, 3)
        in_front = projected[:, 2] > 1e-6
        image = projected[:, :2] / jnp.where(in_front, projected[:, 2], 1.0)[:, None]
        gap = pixels - image[:, None, :]
        gap = jnp.sqrt(jnp.sum(gap * gap, axis=-1))  # (V, C)
        gap = jnp.where(score > min_score, gap, jnp.inf)
        nearest = jnp.argmin(gap, axis=1)
        inlier = in_front & (gap[view_index, nearest] < inlier_pixels)
        check = geometry.triangulate_point(projections, pixels[view_index, nearest],
                                           jnp.where(inlier, score[view_index, nearest], 0.0))
        accepted = check.valid & (check.num_views >= 2)
        point = jnp.where(accepted, check.point, point)
        num_views = jnp.where(accepted, check.num_views, num_views)
    return point, jnp.any(used), num_views


@partial(jax.jit, static_argnames=("config", "num_slots"))
def _geometric_poses(rig, xy, score, cloud: JointCloud, label, config: GeometricConfig, num_slots: int):
    num_views = xy.shape[1]
    pairs = jnp.asarray(view_pairs(num_views))
    f, p, j, c, _ = label.shape
    grid_pair, grid_a, grid_b = (a.reshape(-1) for a in np.meshgrid(np.arange(p), np.arange(c), np.arange(c), indexing="ij"))
    views = pairs[grid_pair]  # (P*C*C, 2)
    detection = jnp.asarray(np.stack([grid_a, grid_b], axis=-1))
    projections = geometry.projection_matrix(rig)
    pixels = jax.vmap(jax.vmap(partial(geometry.undistort_points, output="pixels")), in_axes=(None, 0))(rig, xy)
    weight = jnp.where(cloud.valid, jnp.prod(cloud.score, axis=-1), 0.0)
    # (F, J, P*C*C): the joint axis before the flattened candidates of all view pairs.
    flat_weight = jnp.moveaxis(weight, 2, 1).reshape(f, j, -1)
    flat_label = jnp.moveaxis(label, 2, 1).reshape(f, j, -1)
    flat_point = jnp.moveaxis(cloud.point, 2, 1).reshape(f, j, -1, 3)
    kept = min(config.max_candidates, p * c * c)

    def one_frame(frame_weight, frame_label, frame_point, frame_pixels, frame_score):
        def one_slot(slot):
            def one_joint(w, lab, pts, px, sc):
                ranked = jnp.where(lab == slot, w, 0.0)
                top, index = jax.lax.top_k(ranked, kept)
                return consensus_joint(pts[index], top, views[index], detection[index], px, sc, projections,
                                       config.consensus_radius, config.inlier_pixels, config.min_score)
            return jax.vmap(one_joint, in_axes=(0, 0, 0, 1, 1))(frame_weight, frame_label, frame_point,
                                                                 frame_pixels, frame_score)
        return jax.vmap(one_slot)(jnp.arange(num_slots))

    point, valid, used_views = jax.lax.map(lambda args: one_frame(*args),
                                           (flat_weight, flat_label, flat_point, pixels, score))
    return GeometricPoses(jnp.where(valid[..., None], point, 0.0), valid, used_views)


def geometric_poses(
    rig: Camera,
    xy: Float[ArrayLike, "F V J C 2"],
    score: Float[ArrayLike, "F V J C"],
    cloud: JointCloud,
    clusters: FrameClusters,
    config: GeometricConfig = GeometricConfig(),
) -> GeometricPoses:
    """BODY25 joints of every clustered person in every frame (see the module docstring; jitted).

    ``xy``/``score`` are the padded detections the ``cloud`` was built from, ``clusters`` its
    :func:`~jcsat.cluster_frames` result.
    """
    xy = jnp.asarray(xy)
    if cloud.point.shape[0] != xy.shape[0] or clusters.label.shape != cloud.valid.shape:
        raise ValueError("detections, cloud and clusters must cover the same frames and grid")
    if xy.shape[2] != BODY25.num_joints:
        raise ValueError(f"the baseline expects BODY25 detections (25 joint types), got {xy.shape[2]}")
    rig = jax.tree.map(lambda leaf: jnp.asarray(leaf, cloud.point.dtype), rig)
    return _geometric_poses(rig, xy.astype(cloud.point.dtype), jnp.asarray(score, cloud.point.dtype), cloud,
                            clusters.label, config, clusters.active.shape[1])


def fill_missing(
    joints: Float[np.ndarray, "F J 3"], valid: Bool[np.ndarray, "F J"], present: Bool[np.ndarray, "F"]
) -> tuple[Float[np.ndarray, "F J 3"], Bool[np.ndarray, "F J"]]:
    """Fill one track's missing joints from the nearest frame (in time) where the track has them.

    Only frames where the track is ``present`` are filled or used; a joint the track never has
    stays invalid (and 0). Ties prefer the earlier frame.
    """
    joints, valid = np.array(joints), np.asarray(valid, bool) & np.asarray(present, bool)[:, None]
    frames = np.arange(joints.shape[0])
    filled = valid.copy()
    for j in range(joints.shape[1]):
        have = np.flatnonzero(valid[:, j])
        if not len(have):
            continue
        need = np.flatnonzero(present & ~valid[:, j])
        nearest = have[np.argmin(np.abs(frames[need, None] - have[None, :]), axis=1)]
        joints[need, j] = joints[nearest, j]
        filled[need, j] = True
    return joints, filled


def reject_temporal_outliers(
    joints: Float[np.ndarray, "F J 3"], valid: Bool[np.ndarray, "F J"], half_window: int, max_deviation: float
) -> Float[np.ndarray, "F J 3"]:
    """Replace each valid joint farther than ``max_deviation`` (metres) from its temporal median by that median.

    The median is per coordinate over the valid frames of a window centred on the frame: ``half_window``
    frames on either side, fewer near the joint's first and last valid frames so that the window stays
    symmetric (a one-sided window's median lags a moving joint, and would flag fast motion as an
    outlier; a centred one equals the frame itself for any steady motion). It is only used where at
    least three and a majority of the window's frames are valid, so that a joint is not judged by one
    or two neighbours. Human joints move a few centimetres per frame, so a joint that jumps far from
    where it was both before and after is a wrong association, not motion. ``half_window = 0`` returns
    ``joints`` unchanged; ``max_deviation = 0`` is a plain (centred) temporal median filter.
    """
    joints = np.asarray(joints, float)
    valid = np.asarray(valid, bool)
    if half_window < 0 or max_deviation < 0:
        raise ValueError(f"need half_window >= 0 and max_deviation >= 0, got {half_window}, {max_deviation}")
    if half_window == 0:
        return joints
    frames = joints.shape[0]
    index = np.arange(frames)[:, None]
    first = np.argmax(valid, axis=0)[None, :]
    last = frames - 1 - np.argmax(valid[::-1], axis=0)[None, :]
    radius = np.clip(np.minimum(index - first, last - index), 0, half_window)  # (F, J)
    offsets = np.arange(-half_window, half_window + 1)
    inside = np.abs(offsets)[None, :, None] <= radius[:, None, :]  # (F, W, J)
    masked = np.where(valid[..., None], joints, np.nan)
    padded = np.pad(masked, ((half_window, half_window), (0, 0), (0, 0)), constant_values=np.nan)
    windows = np.stack([padded[k:k + frames] for k in range(2 * half_window + 1)], axis=1)  # (F, W, J, 3)
    windows = np.where(inside[..., None], windows, np.nan)
    count = np.sum(np.isfinite(windows[..., 0]), axis=1)
    enough = (count >= 3) & (count > radius)
    with np.errstate(all="ignore"):
        median = np.nanmedian(np.where(enough[:, None, :, None], windows, 0.0), axis=1)
    outlier = valid & enough & (np.linalg.norm(joints - median, axis=-1) > max_deviation)
    return np.where(outlier[..., None], median, joints)

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

Each track's poses are then re-solved by Structural Triangulation (Chen et al., ECCV 2022;
:func:`structural_refinement`) on 4D association's 19 joints: the same detections, now subject to the
track's own bone lengths (medians over its well-triangulated frames, :func:`track_bone_lengths`), which
pulls a joint seen by few or disagreeing views back to a plausible distance from its neighbours. A joint
whose every bone is far off those lengths, typically a wrist or an ear triangulated from another person's
or another joint's detections, is distrusted (:func:`bone_outliers`): the solver places it from its bones and
its nearest trusted position in time instead of its detections.

A joint far from its own temporal median (over the track's neighbouring frames) is an outlier,
typically a candidate cluster of another person or joint type that won the medoid in one frame, and
is replaced by that median (:func:`reject_temporal_outliers`, a Hampel filter). Joints of a track
that no candidate supports in a frame are filled from the nearest frame where the
same track has them (:func:`fill_missing`); BODY25 is then converted to Shelf15 with the 4D-association
head rule (:func:`geometry.to_shelf15`), the JCSAT convention for BODY25 sources.
"""

from __future__ import annotations

import dataclasses
import warnings
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

import geometry
import structri
from geometry import BODY25, SKEL19, Camera, Skeleton

from ._clustering import FrameClusters
from ._joint_cloud import JointCloud, view_pairs

__all__ = ["ConsensusJoint", "GeometricConfig", "GeometricPoses", "bone_outliers", "consensus_joint", "fill_missing",
           "filled_centres", "geometric_poses", "reject_temporal_outliers", "structural_refinement",
           "track_bone_lengths"]


@dataclasses.dataclass(frozen=True)
class GeometricConfig:
    """The baseline's two knobs."""

    consensus_radius: float = 0.2
    """Metres: candidates closer than this to the medoid support it. 0.2 was chosen on synthetic
    Shelf-rig validation scenes (:func:`experiments.jcsat_study.synthetic_validation`; 0.05 / 0.1 / 0.2 / 0.3 m)."""
    max_candidates: int = 32
    """Candidates per person, frame and joint type entering the medoid (by score product)."""
    inlier_pixels: float = 0.0
    """Pixels: radius of the reprojection check (step 4 of the module docstring); 0 skips it (the
    default: 10-40 px changed synthetic validation PCP by less than 0.5 points)."""
    min_score: float = 0.2
    """2D detections at or below this score are never reprojection inliers (the Joint Cloud's filter)."""
    structural_steps: int = 9
    """Step Constraint Algorithm steps of the Structural Triangulation refinement with each track's bone
    lengths (:func:`structural_refinement`); 0 skips it. Chosen with ``structural_prior_weight`` on synthetic
    Shelf-rig validation scenes (``python -m experiments.shelf_validate``, VoxelPose protocol; the scores:
    ``docs/jcsat.md``, "How the settings were chosen")."""
    structural_prior_weight: float = 0.01
    """Weight of a joint's current estimate, projected into the views that have no detection of it, in that
    refinement (detections weigh their score, 0.2-1). Chosen by the same validation."""
    max_bone_deviation: float = 0.5
    """Relative deviation of a bone from the track's length (:func:`track_bone_lengths`) beyond which the
    refinement distrusts a joint all of whose bones deviate (:func:`bone_outliers`): its detections are
    dropped and it is solved from its bones and its nearest trusted estimate in time; 0 trusts every joint.
    Chosen on synthetic Shelf-rig validation scenes (``python -m experiments.shelf_validate``, VoxelPose protocol;
    the scores: ``docs/jcsat.md``, "How the settings were chosen")."""

    def __post_init__(self) -> None:
        if self.consensus_radius <= 0:
            raise ValueError(f"consensus_radius must be positive (metres), got {self.consensus_radius}")
        if self.inlier_pixels < 0:
            raise ValueError(f"inlier_pixels must be >= 0, got {self.inlier_pixels}")
        if self.max_candidates < 1:
            raise ValueError(f"max_candidates must be >= 1, got {self.max_candidates}")
        if self.structural_steps < 0:
            raise ValueError(f"structural_steps must be >= 0, got {self.structural_steps}")
        if not (self.max_bone_deviation >= 0 and np.isfinite(self.max_bone_deviation)):
            raise ValueError(f"max_bone_deviation must be a finite ratio >= 0, got {self.max_bone_deviation}")
        if not (self.structural_prior_weight > 0 and np.isfinite(self.structural_prior_weight)):
            raise ValueError("structural_prior_weight must be a positive finite weight, "
                             f"got {self.structural_prior_weight}")


class ConsensusJoint(NamedTuple):
    """One joint of one person in one frame, and the 2D detections it was triangulated from."""

    point: Float[Array, "*b 3"]
    """Metres."""
    supported: Bool[Array, "*b"]
    """Whether any candidate existed."""
    num_views: Int[Array, "*b"]
    """Views whose detections were re-triangulated (0 when the medoid was kept)."""
    pixels: Float[Array, "*b V 2"]
    """Undistorted pixels of the detection used in each view (arbitrary where ``weight`` is 0)."""
    weight: Float[Array, "*b V"]
    """Its triangulation weight (detection score); 0 for views not used."""


class GeometricPoses(NamedTuple):
    """Baseline output per frame and centre slot (slot k of frame f is track ``track_of[f, k]``)."""

    body25: Float[Array, "F K 25 3"]
    """Metres; 0 where not ``valid``."""
    valid: Bool[Array, "F K 25"]
    num_views: Int[Array, "F K 25"]
    """Views whose detections were re-triangulated (0 when the medoid was kept)."""
    pixels: Float[Array, "F K 25 V 2"]
    """:attr:`ConsensusJoint.pixels` of every joint."""
    view_weight: Float[Array, "F K 25 V"]
    """:attr:`ConsensusJoint.weight` of every joint."""


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
) -> ConsensusJoint:
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

    Returns the point, its support and the detections it was re-triangulated from (no batch axes).
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
    used_pixels = pixels[view_index, chosen]
    used_weight = jnp.where(retriangulated, view_weight, 0.0)
    if inlier_pixels > 0:
        projected = jnp.sum(projections[:, :, :3] * point[None, None, :], axis=-1) + projections[:, :, 3]  # (V, 3)
        in_front = projected[:, 2] > 1e-6
        image = projected[:, :2] / jnp.where(in_front, projected[:, 2], 1.0)[:, None]
        gap = pixels - image[:, None, :]
        gap = jnp.sqrt(jnp.sum(gap * gap, axis=-1))  # (V, C)
        gap = jnp.where(score > min_score, gap, jnp.inf)
        nearest = jnp.argmin(gap, axis=1)
        inlier = in_front & (gap[view_index, nearest] < inlier_pixels)
        inlier_weight = jnp.where(inlier, score[view_index, nearest], 0.0)
        check = geometry.triangulate_point(projections, pixels[view_index, nearest], inlier_weight)
        accepted = check.valid & (check.num_views >= 2)
        point = jnp.where(accepted, check.point, point)
        num_views = jnp.where(accepted, check.num_views, num_views)
        used_pixels = jnp.where(accepted, pixels[view_index, nearest], used_pixels)
        used_weight = jnp.where(accepted, inlier_weight, used_weight)
    return ConsensusJoint(point, jnp.any(used), num_views, used_pixels, used_weight)


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

    joint = jax.lax.map(lambda args: one_frame(*args), (flat_weight, flat_label, flat_point, pixels, score))
    return GeometricPoses(jnp.where(joint.supported[..., None], joint.point, 0.0), joint.supported, joint.num_views,
                          joint.pixels, joint.weight)


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
    :func:`~association.cluster_frames` result.
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


def filled_centres(present: Bool[np.ndarray, "T F"], centre: Float[np.ndarray, "T F 3"]) -> Float[np.ndarray, "T F 3"]:
    """Each track's cluster centre in every frame, from its nearest frame (earlier on ties) where it is present."""
    every_frame = np.ones(present.shape[1], bool)
    return np.stack([fill_missing(c[:, None, :], p[:, None], every_frame)[0][:, 0] for p, c in zip(present, centre)])


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


def track_bone_lengths(
    joints: Float[np.ndarray, "F J 3"], num_views: Int[np.ndarray, "F J"], skeleton: Skeleton
) -> Float[np.ndarray, " J-1"]:
    """One track's bone lengths (metres, ``skeleton.bones`` order): per bone the median over the frames
    where both ends were re-triangulated from at least two views, then averaged with its mirror bone (the
    side that was seen alone when only one was; NaN where neither was).

    The median rather than the mean of Structural Triangulation's ST*: a frame where another person's
    candidates won a joint gives one wild length, which the median ignores."""
    parent, child = np.asarray(skeleton.bones).T
    seen = (num_views[:, parent] >= 2) & (num_views[:, child] >= 2)
    lengths = np.where(seen, np.linalg.norm(joints[:, child] - joints[:, parent], axis=-1), np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN slices: bones never seen stay NaN
        median = np.nanmedian(lengths, axis=0)
        return np.nanmean(np.stack([median, median[np.asarray(skeleton.mirror_bones)]]), axis=0)


def bone_outliers(
    joints: Float[np.ndarray, "F J 3"], valid: Bool[np.ndarray, "F J"], lengths: Float[np.ndarray, " J-1"],
    skeleton: Skeleton, max_deviation: float,
) -> Bool[np.ndarray, "F J"]:
    """Joints of one track that disagree with every bone they have: wrong associations, not motion.

    A bone between two valid joints deviates when its length is off ``lengths`` (metres, ``skeleton.bones``
    order) by more than ``max_deviation`` times that length. One wrong joint makes all of its bones deviate,
    so each frame rejects, one at a time, the joint with the most deviating bones among those whose every
    bone to a not-yet-rejected valid joint deviates (ties: the larger summed deviation); the bones of a
    rejected joint stop counting, so a wrong nose does not take its correct ears with it. A joint with no
    bone to a valid neighbour is never rejected, nor any joint of a bone whose length is unknown (NaN).
    """
    joints, valid = np.asarray(joints, float), np.asarray(valid, bool)
    parent, child = np.asarray(skeleton.bones).T
    incidence = np.zeros((len(parent), skeleton.num_joints))
    incidence[np.arange(len(parent)), parent] = incidence[np.arange(len(parent)), child] = 1.0
    with np.errstate(invalid="ignore", divide="ignore"):
        deviation = np.abs(np.linalg.norm(joints[:, child] - joints[:, parent], axis=-1) / lengths - 1.0)
    known = np.isfinite(deviation)
    rejected = np.zeros(valid.shape, bool)
    for _ in range(skeleton.num_joints):
        usable = valid & ~rejected
        measured = usable[:, parent] & usable[:, child] & known
        off = measured & (deviation > max_deviation)
        candidate = usable & (measured @ incidence > 0) & (off @ incidence == measured @ incidence)
        if not candidate.any():
            break
        # tanh keeps the summed deviation below 1, so it only breaks ties in the count of deviating bones.
        summed = np.tanh(np.where(off, deviation, 0.0) @ incidence)
        badness = np.where(candidate, off @ incidence + summed, -np.inf)
        frames = np.flatnonzero(candidate.any(axis=1))
        rejected[frames, np.argmax(badness[frames], axis=1)] = True
    return rejected


_STRUCTURAL_ROWS = 128
"""Frames per chunk of :func:`structri.structural_triangulation`'s batched solver."""


def structural_refinement(
    projections: Float[ArrayLike, "V 3 4"],
    body25: Float[np.ndarray, "T F 25 3"],
    valid: Bool[np.ndarray, "T F 25"],
    num_views: Int[np.ndarray, "T F 25"],
    pixels: Float[np.ndarray, "T F 25 V 2"],
    weight: Float[np.ndarray, "T F 25 V"],
    steps: int,
    prior_weight: float,
    skeleton: Skeleton = SKEL19,
    max_bone_deviation: float = 0.0,
) -> tuple[Float[np.ndarray, "T F 25 3"], Bool[np.ndarray, "T F"]]:
    """Re-solve the ``skeleton`` joints of every track's frames by Structural Triangulation with the track's
    own bone lengths.

    Each frame's pose minimises the weighted reprojection cost of the detections its joints were
    triangulated from (:class:`ConsensusJoint`, weights = scores) subject to the bone lengths of
    :func:`track_bone_lengths` (:func:`structri.structural_triangulation`, ``steps`` SCA steps). A joint
    needs two rays, so in every view without a detection of it the projection of its current estimate (or,
    where the frame has none, the nearest frame's, :func:`fill_missing`) enters with ``prior_weight``: a joint
    seen by fewer than two views keeps its place up to what its bones demand. ``skeleton`` names the BODY25
    joints solved for (default :data:`geometry.SKEL19`, 4D association's tree: BODY25 without the eyes,
    small toes and heels, whose few-centimetre bones the first-order SCA update often cannot meet).
    With ``max_bone_deviation > 0`` the joints of :func:`bone_outliers` are distrusted: their detections are
    dropped, so the solver places them from their bones and the nearest frame where they were trusted.

    Returns the poses (refined where ``refined``, the input elsewhere) and ``refined``: the track has every
    bone length, the frame has some valid joint, and the solver's status is OK or a single ST step.
    Invalid joints, and joints outside ``skeleton``, are left as they are.
    """
    projections = np.asarray(projections, float)
    tracks_frames, views = body25.shape[:2], projections.shape[0]
    expected = {"body25": (body25, (*tracks_frames, 25, 3)), "valid": (valid, (*tracks_frames, 25)),
                "num_views": (num_views, (*tracks_frames, 25)), "pixels": (pixels, (*tracks_frames, 25, views, 2)),
                "weight": (weight, (*tracks_frames, 25, views)), "projections": (projections, (views, 3, 4))}
    for name, (array, shape) in expected.items():
        if np.shape(array) != shape:
            raise ValueError(f"{name} must have shape {shape} (tracks, frames, BODY25 joints, views {views}), "
                             f"got {np.shape(array)}")
    joints = np.array([BODY25.index(name) for name in skeleton.joints])
    body, valid, num_views = body25[:, :, joints], valid[:, :, joints], num_views[:, :, joints]
    num_tracks, num_frames = body.shape[:2]
    rows, observed, observed_weight, lengths = [], [], [], []
    for t in range(num_tracks):
        bone_lengths = track_bone_lengths(body[t], num_views[t], skeleton)
        if not np.all(bone_lengths > 0):
            continue
        trusted = valid[t]
        if max_bone_deviation > 0:
            trusted = trusted & ~bone_outliers(body[t], valid[t], bone_lengths, skeleton, max_bone_deviation)
        estimate, known = fill_missing(body[t], trusted, np.ones(num_frames, bool))
        frames = np.flatnonzero(trusted.any(axis=-1) & known.all(axis=-1))
        homogeneous = np.einsum("vab,fjb->fjva", projections[:, :, :3], estimate[frames]) + projections[:, :, 3]
        in_front = homogeneous[..., 2] > 1e-6
        projected = homogeneous[..., :2] / np.where(in_front, homogeneous[..., 2], 1.0)[..., None]
        detected = (weight[t][frames][:, joints] > 0) & trusted[frames][..., None]
        observed.append(np.where(detected[..., None], pixels[t][frames][:, joints], projected))
        prior = np.where(in_front, prior_weight, 0.0)
        observed_weight.append(np.where(detected, weight[t][frames][:, joints], prior))
        lengths.append(np.broadcast_to(bone_lengths, (len(frames), len(bone_lengths))))
        rows.extend((t, f) for f in frames)
    refined = np.zeros((num_tracks, num_frames), bool)
    if not rows:
        return body25, refined
    track, frame = np.asarray(rows).T
    # Rows padded (repeating the last) to a multiple of the solver's chunk: scenes of similar size share one
    # compilation, at no extra work since the solver pads to whole chunks itself.
    pad = -len(rows) % _STRUCTURAL_ROWS

    def padded(parts):
        joined = np.concatenate(parts)
        return np.concatenate([joined, np.repeat(joined[-1:], pad, axis=0)])

    result = structri.structural_triangulation(
        np.swapaxes(padded(observed), 1, 2), projections, padded(lengths), skeleton,
        np.swapaxes(padded(observed_weight), 1, 2), n_steps=steps)
    status, pose = np.asarray(result.status)[:len(rows)], np.asarray(result.pose)[:len(rows)]
    accepted = status <= structri.Status.SINGLE_STEP
    track, frame = track[accepted], frame[accepted]
    refined[track, frame] = True
    solved = np.where(valid[track, frame][..., None], pose[accepted], body[track, frame])
    out = body25.copy()
    out[track[:, None], frame[:, None], joints[None, :]] = solved
    return out, refined

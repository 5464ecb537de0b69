"""Pose metrics: joint errors, Procrustes alignment, PCK, PCP, bone-length and smoothness metrics.

Every metric takes poses with any leading batch dimensions ``*b`` and returns one value per pose (or
per pose and part), so callers choose how to aggregate (per actor, per sequence, over all frames).
Each function is jitted (skeletons and flags static), so an eager call compiles once per input shape.
Distances are in the unit of the inputs: the project's world unit is metres, so multiply by 1000 for
the millimetres papers report. Optional boolean masks ``(*b, J)`` select the joints that count; a pose
with no selected joint gets NaN (documented, on purpose: ``jnp.nanmean`` over poses then skips it),
never a silently wrong number.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from ._kinematics import bone_lengths
from ._skeleton import Skeleton
from ._vectors import safe_norm

__all__ = [
    "Similarity",
    "mpjpe",
    "mpjpe_root_relative",
    "similarity_procrustes",
    "pa_mpjpe",
    "pck_3d",
    "pck_2d",
    "pcp",
    "mpble",
    "mbls",
    "pib",
    "acceleration_error",
    "JointHits",
    "PrecisionRecall",
    "joint_precision_recall",
    "aggregate_precision_recall",
]


def _same_shape(pred, gt, min_rank: int = 2) -> tuple[Array, Array]:
    pred, gt = jnp.asarray(pred), jnp.asarray(gt)
    if pred.shape != gt.shape or pred.ndim < min_rank:
        raise ValueError(f"pred and gt must have the same shape (..., J, C), got {pred.shape} and {gt.shape}")
    return pred, gt


def _mask_or_ones(mask, shape: tuple[int, ...]) -> Array:
    if mask is None:
        return jnp.ones(shape, dtype=bool)
    mask = jnp.asarray(mask)
    if mask.shape != shape:
        raise ValueError(f"mask must have shape {shape}, got {mask.shape}")
    return mask.astype(bool)


def _masked_mean(values: Float[Array, "*b J"], mask: Bool[Array, "*b J"]) -> Float[Array, "*b"]:
    """Mean over the last axis of the selected entries; NaN where none is selected."""
    count = jnp.sum(mask, axis=-1)
    total = jnp.sum(jnp.where(mask, values, 0.0), axis=-1)
    return jnp.where(count > 0, total / jnp.maximum(count, 1), jnp.nan)


@jax.jit
def mpjpe(
    pred: Float[ArrayLike, "*b J 3"], gt: Float[ArrayLike, "*b J 3"], mask: Bool[ArrayLike, "*b J"] | None = None
) -> Float[Array, "*b"]:
    """Mean per-joint position error without alignment ("MPJPE-ab"), in the input unit."""
    pred, gt = _same_shape(pred, gt)
    return _masked_mean(safe_norm(pred - gt), _mask_or_ones(mask, pred.shape[:-1]))


@partial(jax.jit, static_argnames=("root",))
def mpjpe_root_relative(
    pred: Float[ArrayLike, "*b J 3"],
    gt: Float[ArrayLike, "*b J 3"],
    root: int,
    mask: Bool[ArrayLike, "*b J"] | None = None,
) -> Float[Array, "*b"]:
    """MPJPE after subtracting joint ``root`` from each pose (Human3.6M protocol #1, "MPJPE-re").

    The root itself (error 0) is part of the mean, as in the Structural Triangulation and
    learnable-triangulation code. A pose whose root is masked out gets NaN.
    """
    pred, gt = _same_shape(pred, gt)
    mask = _mask_or_ones(mask, pred.shape[:-1])
    relative_pred = pred - pred[..., root : root + 1, :]
    relative_gt = gt - gt[..., root : root + 1, :]
    return _masked_mean(safe_norm(relative_pred - relative_gt), mask & mask[..., root : root + 1])


class Similarity(NamedTuple):
    """``x -> scale * rotation @ x + translation``."""

    scale: Float[Array, "*b"]
    rotation: Float[Array, "*b 3 3"]
    translation: Float[Array, "*b 3"]

    def apply(self, points: Float[Array, "*b J 3"]) -> Float[Array, "*b J 3"]:
        rotated = jnp.einsum("...ij,...kj->...ki", self.rotation, points)
        return self.scale[..., None, None] * rotated + self.translation[..., None, :]


# jaxlib's CPU LAPACK kernels split a large batch over XLA's intra-op threads and then wait, on a thread of that
# same pool, for the pieces: two such calls at once take both threads of a 2-core machine and never finish (the
# dynamics evaluation hung so, scoring two Procrustes alignments in one computation). A call below about 740 3x3
# matrices runs in place (jaxlib's threshold: 2e5 FLOP, 270 FLOP per 3x3 SVD), so the CPU takes them in slices.
_CPU_SVD_SLICE = 512


def _svd_3x3(matrices: Float[Array, "*b 3 3"]) -> tuple[Array, Array, Array]:
    def sliced(matrices: Array) -> tuple[Array, Array, Array]:
        u, singular, vt = jax.lax.map(jnp.linalg.svd, matrices.reshape(-1, 3, 3), batch_size=_CPU_SVD_SLICE)
        return u.reshape(matrices.shape), singular.reshape(matrices.shape[:-1]), vt.reshape(matrices.shape)

    return jax.lax.platform_dependent(matrices, cpu=sliced, default=lambda matrices: tuple(jnp.linalg.svd(matrices)))


def _det_3x3(matrices: Float[Array, "*b 3 3"]) -> Float[Array, "*b"]:
    """The triple product of the rows (no LAPACK call, see above)."""
    return jnp.sum(matrices[..., 0, :] * jnp.cross(matrices[..., 1, :], matrices[..., 2, :]), axis=-1)


@jax.jit
def similarity_procrustes(
    source: Float[ArrayLike, "*b J 3"],
    target: Float[ArrayLike, "*b J 3"],
    mask: Bool[ArrayLike, "*b J"] | None = None,
) -> Similarity:
    """The similarity (rotation, isotropic scale, translation) that best maps ``source`` onto ``target``.

    Umeyama (1991): least squares over the selected joints, with the reflection fix (the result is a
    proper rotation, det = +1). A source whose selected joints coincide has no defined scale; it
    gets scale 0 (every point maps to the target centroid) rather than NaN.
    """
    source, target = _same_shape(source, target)
    weights = _mask_or_ones(mask, source.shape[:-1]).astype(source.dtype)
    weights = weights / jnp.maximum(jnp.sum(weights, axis=-1, keepdims=True), 1.0)
    mean_source = jnp.sum(weights[..., None] * source, axis=-2)
    mean_target = jnp.sum(weights[..., None] * target, axis=-2)
    centred_source = source - mean_source[..., None, :]
    centred_target = target - mean_target[..., None, :]
    covariance = jnp.einsum("...j,...ja,...jb->...ab", weights, centred_target, centred_source)
    u, singular, vt = _svd_3x3(covariance)
    sign = jnp.where(_det_3x3(u) * _det_3x3(vt) < 0, -1.0, 1.0).astype(source.dtype)
    flip = jnp.stack([jnp.ones_like(sign), jnp.ones_like(sign), sign], axis=-1)
    rotation = jnp.einsum("...ik,...k,...kj->...ij", u, flip, vt)
    variance = jnp.sum(weights * jnp.sum(centred_source**2, axis=-1), axis=-1)
    trace = jnp.sum(singular * flip, axis=-1)
    scale = jnp.where(variance > 0, trace / jnp.where(variance > 0, variance, 1.0), 0.0)
    translation = mean_target - scale[..., None] * jnp.einsum("...ij,...j->...i", rotation, mean_source)
    return Similarity(scale, rotation, translation)


@jax.jit
def pa_mpjpe(
    pred: Float[ArrayLike, "*b J 3"], gt: Float[ArrayLike, "*b J 3"], mask: Bool[ArrayLike, "*b J"] | None = None
) -> Float[Array, "*b"]:
    """MPJPE after aligning each prediction to its ground truth with :func:`similarity_procrustes`
    ("PA-MPJPE", Human3.6M protocol #2). The alignment and the mean use the same joints."""
    pred, gt = _same_shape(pred, gt)
    mask = _mask_or_ones(mask, pred.shape[:-1])
    aligned = similarity_procrustes(pred, gt, mask).apply(pred)
    return _masked_mean(safe_norm(aligned - gt), mask)


@jax.jit
def pck_3d(
    pred: Float[ArrayLike, "*b J 3"],
    gt: Float[ArrayLike, "*b J 3"],
    threshold: Float[ArrayLike, ""],
    mask: Bool[ArrayLike, "*b J"] | None = None,
) -> Float[Array, "*b"]:
    """Fraction of joints with error strictly below ``threshold`` (input unit; 0.15 m for 3DPCK)."""
    pred, gt = _same_shape(pred, gt)
    hit = (safe_norm(pred - gt) < threshold).astype(pred.dtype)
    return _masked_mean(hit, _mask_or_ones(mask, pred.shape[:-1]))


@jax.jit
def pck_2d(
    pred: Float[ArrayLike, "*b J 2"],
    gt: Float[ArrayLike, "*b J 2"],
    threshold_fraction: Float[ArrayLike, ""],
    mask: Bool[ArrayLike, "*b J"] | None = None,
    box_size: Float[ArrayLike, "*b"] | None = None,
) -> Float[Array, "*b"]:
    """Bounding-box PCK: fraction of joints with pixel error strictly below ``threshold_fraction`` times
    ``box_size``, the longer side of the person's box (pixels); without it, of the tight box around the
    selected ground-truth joints.

    The normalisation is mmpose's ``PCKAccuracy(norm_item="bbox")`` (max of box width and height,
    distance ``<`` threshold), usually at 0.2 or 0.05, and the thesis' ``alpha max(h, w)`` (Sect. 5.3.1).
    """
    pred, gt = _same_shape(pred, gt)
    mask = _mask_or_ones(mask, pred.shape[:-1])
    if box_size is None:
        low = jnp.min(jnp.where(mask[..., None], gt, jnp.inf), axis=-2)
        high = jnp.max(jnp.where(mask[..., None], gt, -jnp.inf), axis=-2)
        box_size = jnp.max(high - low, axis=-1)
    box_size = jnp.broadcast_to(jnp.asarray(box_size, pred.dtype), pred.shape[:-2])
    hit = (safe_norm(pred - gt) < threshold_fraction * box_size[..., None]).astype(pred.dtype)
    return _masked_mean(hit, mask)


@partial(jax.jit, static_argnames=("skeleton", "strict", "zero_is_missing"))
def pcp(
    pred: Float[ArrayLike, "*b J 3"],
    gt: Float[ArrayLike, "*b J 3"],
    skeleton: Skeleton,
    alpha: Float[ArrayLike, ""] = 0.5,
    strict: bool = False,
    pred_valid: Bool[ArrayLike, "*b J"] | None = None,
    zero_is_missing: bool = False,
) -> Bool[Array, "*b P"]:
    """Percentage of correct parts, per part of ``skeleton.pcp_parts`` (average the booleans for %).

    Part (s, e) is correct iff ``(|p_s - g_s| + |p_e - g_e|) / 2 <= alpha |g_s - g_e|`` (VoxelPose,
    MVPose), or with ``<`` when ``strict`` (4D Association, EasyMocap, JCSAT; at alpha 0.5 that is
    ``d_s + d_e < |g_s - g_e|``). A part with an endpoint outside ``pred_valid`` is incorrect; with
    ``zero_is_missing`` a predicted joint at exactly (0, 0, 0) counts as missing (JCSAT).

    For SHELF15 the torso starts at joint 14: the 4DA/JCSAT convention when joint 14 is the
    prediction's own pelvis; for VoxelPose/MVPose set the prediction's joint 14 to the mean of its
    joints 2 and 3 first (docs/protocols.md, "Parts and the PCP rule").
    """
    if not skeleton.pcp_parts:
        raise ValueError(f"{skeleton.name} defines no PCP parts")
    pred, gt = _same_shape(pred, gt)
    if pred.shape[-2] != skeleton.num_joints:
        raise ValueError(f"poses have {pred.shape[-2]} joints, {skeleton.name} has {skeleton.num_joints}")
    valid = _mask_or_ones(pred_valid, pred.shape[:-1])
    if zero_is_missing:
        valid = valid & jnp.any(pred != 0, axis=-1)
    start, end = (np.array(ix, dtype=np.int32) for ix in zip(*skeleton.pcp_index))
    errors = safe_norm(pred - gt)
    mean_error = 0.5 * (errors[..., start] + errors[..., end])
    limit = alpha * jnp.linalg.norm(gt[..., start, :] - gt[..., end, :], axis=-1)
    correct = mean_error < limit if strict else mean_error <= limit
    return correct & valid[..., start] & valid[..., end]


def _broadcast_reference(reference_lengths, lengths: Array) -> Array:
    reference = jnp.asarray(reference_lengths, dtype=lengths.dtype)
    if reference.shape[-1:] != lengths.shape[-1:]:
        raise ValueError(f"reference_lengths must end with {lengths.shape[-1]} bones, got {reference.shape}")
    return jnp.broadcast_to(reference, lengths.shape)


@partial(jax.jit, static_argnames=("skeleton",))
def mpble(
    joints: Float[ArrayLike, "*b J 3"], skeleton: Skeleton, reference_lengths: Float[ArrayLike, "*r B"]
) -> Float[Array, "*b"]:
    """Mean per-bone length error, mean over bones of ``|length - L|`` (Structural Triangulation's MPBLE,
    "MEBLE" in its code). ``reference_lengths`` broadcasts against the poses' leading dimensions."""
    lengths = bone_lengths(joints, skeleton)
    return jnp.mean(jnp.abs(lengths - _broadcast_reference(reference_lengths, lengths)), axis=-1)


@partial(jax.jit, static_argnames=("skeleton",))
def mbls(joint_sequence: Float[ArrayLike, "*b T J 3"], skeleton: Skeleton) -> Float[Array, "*b"]:
    """Mean bone-length standard deviation: sqrt of the mean over bones of the variance over frames
    (population variance, ``np.var`` as in Structural Triangulation), in the input unit."""
    lengths = bone_lengths(joint_sequence, skeleton)
    if lengths.ndim < 2:
        raise ValueError("mbls needs a sequence of poses (..., T, J, 3)")
    return jnp.sqrt(jnp.mean(jnp.var(lengths, axis=-2), axis=-1))


@partial(jax.jit, static_argnames=("skeleton",))
def pib(
    joints: Float[ArrayLike, "*b J 3"],
    skeleton: Skeleton,
    reference_lengths: Float[ArrayLike, "*r B"],
    low: Float[ArrayLike, ""] = 0.8,
    high: Float[ArrayLike, ""] = 1.2,
) -> Float[Array, "*b"]:
    """Fraction of inlier bones, ``low L < length < high L`` (strict, as Structural Triangulation's
    code; the paper reports it in %)."""
    lengths = bone_lengths(joints, skeleton)
    reference = _broadcast_reference(reference_lengths, lengths)
    inlier = (lengths > low * reference) & (lengths < high * reference)
    return jnp.mean(inlier.astype(lengths.dtype), axis=-1)


@jax.jit
def acceleration_error(
    pred_sequence: Float[ArrayLike, "*b T J 3"],
    gt_sequence: Float[ArrayLike, "*b T J 3"],
    frame_valid: Bool[ArrayLike, "*b T"] | None = None,
) -> Float[Array, "*b"]:
    """Mean over frames and joints of ``|a_pred - a_gt|``, with ``a_t = x_{t-1} - 2 x_t + x_{t+1}``.

    The HMMR/VIBE convention: second differences per frame, not divided by the frame interval, so
    the unit is (input unit) / frame^2 (mm/frame^2 in those papers). The acceleration at t counts only
    if frames t-1, t and t+1 are all valid. Needs T >= 3.
    """
    pred, gt = _same_shape(pred_sequence, gt_sequence, min_rank=3)
    if pred.shape[-3] < 3:
        raise ValueError(f"acceleration needs at least 3 frames, got {pred.shape[-3]}")
    valid = _mask_or_ones(frame_valid, pred.shape[:-2])

    def second_difference(x):
        return x[..., :-2, :, :] - 2.0 * x[..., 1:-1, :, :] + x[..., 2:, :, :]

    per_frame = jnp.mean(safe_norm(second_difference(pred) - second_difference(gt)), axis=-1)
    return _masked_mean(per_frame, valid[..., :-2] & valid[..., 1:-1] & valid[..., 2:])


class JointHits(NamedTuple):
    """Per-joint outcome of one matched (prediction, ground truth) pair, or a stack of them."""

    detected: Bool[Array, "*b J"]
    """The prediction has the joint (and the ground truth has it too)."""
    correct: Bool[Array, "*b J"]
    """Detected and closer than the threshold."""
    present: Bool[Array, "*b J"]
    """The ground truth has the joint (the recall denominator)."""


class PrecisionRecall(NamedTuple):
    precision: Float[Array, "J"]
    recall: Float[Array, "J"]


@jax.jit
def joint_precision_recall(
    pred: Float[ArrayLike, "*b J 3"],
    gt: Float[ArrayLike, "*b J 3"],
    threshold: Float[ArrayLike, ""] = 0.2,
    pred_detected: Bool[ArrayLike, "*b J"] | None = None,
    gt_present: Bool[ArrayLike, "*b J"] | None = None,
) -> JointHits:
    """Joint detection outcome of matched pairs, JCSAT ``evaluate.py`` semantics (docs/protocols.md):
    a joint is detected if ``pred_detected`` says so, by default if it is not exactly (0, 0, 0);
    correct if detected and ``|p - g| < threshold`` (metres; 0.2 "following 4DA").
    Ground-truth joints outside ``gt_present`` are excluded from both counts."""
    pred, gt = _same_shape(pred, gt)
    present = _mask_or_ones(gt_present, pred.shape[:-1])
    if pred_detected is None:
        detected = jnp.any(pred != 0, axis=-1)
    else:
        detected = _mask_or_ones(pred_detected, pred.shape[:-1])
    detected = detected & present
    correct = detected & (safe_norm(pred - gt) < threshold)
    return JointHits(detected, correct, present)


@jax.jit
def aggregate_precision_recall(hits: JointHits, unmatched_gt: Int[ArrayLike, ""] = 0) -> PrecisionRecall:
    """Per-joint precision ``sum(correct) / sum(detected)`` and recall ``sum(correct) / #annotated``
    over all leading dimensions of ``hits`` (e.g. the frames of one actor).

    ``unmatched_gt`` counts annotated ground-truth instances without a matched prediction (all of
    whose joints are missed); JCSAT adds them to the recall denominator. A joint never detected has
    precision 0, one never annotated recall 0. Average over joints for the reported value.
    """
    def total(x: Array) -> Array:
        return jnp.sum(x.reshape(-1, x.shape[-1]), axis=0)

    correct = total(hits.correct).astype(jnp.result_type(float))
    detected = total(hits.detected)
    annotated = total(hits.present) + unmatched_gt
    return PrecisionRecall(correct / jnp.maximum(detected, 1), correct / jnp.maximum(annotated, 1))

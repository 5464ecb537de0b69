"""The camera-dependent baselines of FLEX's Table 1 and the metrics of the experiment.

FLEX is compared with methods that need the extrinsics (paper Sect. 4, ``docs/flex.md``):
triangulation given the true cameras, given cameras whose extrinsics are off by a relative Gaussian error (3 % and
4 %, "imitating" estimated calibration), and, in the dynamic setting, given a stale calibration of moving cameras.
:func:`triangulation_baseline` runs such a baseline on a :class:`~flex.Batch` and returns what FLEX is scored on:
camera-frame, root-relative :data:`geometry.STRUCTRI17` joints per view and frame (metres), in the frames of
``batch.joints``. :func:`motion_metrics` scores either (or FLEX's FLEX20 output) the same way.

Methods, both weighting each view by the detector's confidence (0 for a missed joint, which drops the view):

- ``"dlt"``: the confidence-weighted DLT per joint and frame (:func:`geometry.triangulate`, rows multiplied by
  the confidence, not normalised: the algebraic triangulation of Iskakov et al.).
- ``"structural"``: Structural Triangulation (:func:`structri.structural_triangulation`, SCA with ``n_steps``).
  Its bone lengths are estimated from the sequence itself through the same calibration: the true lengths are not
  available at test time, and a wrong calibration distorts the estimate as it distorts the poses, so the baseline
  stays honest. Each frame gives LS bone lengths (:func:`structri.estimate_bone_lengths` of that frame alone, left
  and right averaged) and each bone takes their median over the frames that could be used. The paper's ST* takes
  the mean over hand-picked T-pose frames; over all frames of detected 2D, the few frames with a gross detector
  outlier pull a mean far off and the SCA then enforces that wrong length on every frame; the median ignores them.
  A frame whose solution still misses a length by more than half falls back to LS (structri's default
  ``max_length_error``): the first-order SCA update can return bones metres long on gross outliers.

Calibrations (:func:`baseline_cameras`): ``"exact"`` (every frame's true cameras), ``"perturbed"``
(:func:`geometry.perturb_extrinsics_relative`: each extrinsic parameter (rotation vector, translation) times
``1 + scale N(0, 1)``, one draw per sequence and view, the same draw at every frame: moving cameras keep a
relative error of ``scale`` on every frame's parameters, coherent in time, instead of a fresh error per frame that
would add jitter no real calibration has; for static cameras this is perturbing once; with ``per_sequence=False``
one draw serves the whole batch: a fixed rig calibrated once, every sequence seen through the same error), and
``"static"`` (the
first frame's cameras at every frame: what a system calibrated once reports while the cameras move; equal to
``"exact"`` for static cameras).

Evaluation frame. The reconstruction is a world-frame pose; ``frame`` says which rotation takes it to view k's
camera frame at frame t (root-relative, so the translation cancels):

- ``"true"`` (default): the true camera's. Root-relative MPJPE is invariant to one rotation applied to both poses,
  so this is exactly the world-frame, root-relative protocol #1 with which Iskakov et al. (and Structural
  Triangulation) score triangulation, and which FLEX's Table 1 quotes for the perturbed baseline: the error is the
  shape the wrong calibration gives the reconstruction; the world frame itself is taken as known.
- ``"calibration"``: the camera the method was given. This is what the method can report in view k's frame
  with the information it has, and the only option for a deployment that does not know how the world frame
  relates to the true cameras; it adds that camera's own orientation error to the shape error, which can also
  partly cancel it; the two differ little for perturbed extrinsics and much for a stale calibration of moving
  cameras.

Joints that cannot be triangulated (fewer than two views with a positive confidence, or an ill-posed DLT; a DLT
point behind a camera is kept, as the algebraic triangulation has no such check) get
the root-relative offset of the same joint at the nearest earlier frame where it and the root were determined
(else the nearest later one), and the root itself (offset 0) when there is no such frame in the sequence, so the
metrics never see NaN (a frame with an undetermined root thus takes every offset from its neighbours).
Structural Triangulation solves a frame with an undetermined joint as regularised LS (:class:`structri.Status`
``UNDERDETERMINED``, no bone-length constraint); its undetermined joints get the same filling.

Metrics (:func:`motion_metrics`): MPJPE protocol #1 (root-relative, 17 joints, root included as in
:func:`geometry.mpjpe_root_relative`, mm), acceleration error (:func:`geometry.acceleration_error`, second
differences per frame, mm/frame^2) and MBLS (:func:`geometry.mbls`, the bone-length standard deviation over time
on the STRUCTRI17 bones, mm), each per sequence and view, then averaged over both; and the global root position
error (:func:`root_position_error`, mm, the paper's Sect. 4.2) between camera-frame roots in metres: FLEX's estimate,
which is up to scale, made metric with the view's intrinsics (:func:`camera_root`), a baseline's triangulated root
moved to the true camera (:func:`triangulation_baseline` ``with_root``).
"""

from __future__ import annotations

import functools
from typing import Literal, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, PRNGKeyArray

import geometry
import structri
from geometry import FLEX20, STRUCTRI17, Camera, Skeleton

from ._data import Batch

__all__ = ["MotionMetrics", "baseline_cameras", "camera_root", "motion_metrics", "root_position_error",
           "triangulation_baseline"]

_ROOT = STRUCTRI17.index("mid_hip")
_METHODS = ("dlt", "structural")
_CALIBRATIONS = ("exact", "perturbed", "static")
_FRAMES = ("true", "calibration")


def _check_cameras(cameras: Camera) -> tuple[int, int, int]:
    if cameras.K.ndim != 5:
        raise ValueError(f"cameras must have leaves (batch, views, frames, ...), got K of shape {cameras.K.shape}")
    return cameras.K.shape[:3]


def baseline_cameras(
    cameras: Camera,
    calibration: Literal["exact", "perturbed", "static"],
    key: PRNGKeyArray | None = None,
    scale: Float[ArrayLike, ""] | float = 0.03,
    per_sequence: bool = True,
) -> Camera:
    """The calibration a baseline is given (module docstring), leaves ``(batch, views, frames, ...)`` like
    ``cameras`` (a :class:`~flex.Batch`'s). ``key`` (needed for ``"perturbed"`` only) is split over the batch, or,
    with ``per_sequence=False``, used for every sequence (one draw for a fixed rig); ``scale`` is the relative
    standard deviation of the perturbation (0.03 for 3 %)."""
    batch_size, _, _ = _check_cameras(cameras)
    if calibration == "exact":
        return cameras
    if calibration == "static":
        return jax.tree.map(lambda leaf: jnp.broadcast_to(leaf[:, :, :1], leaf.shape), cameras)
    if calibration != "perturbed":
        raise ValueError(f"calibration must be one of {_CALIBRATIONS}, got {calibration!r}")
    if key is None:
        raise ValueError("calibration='perturbed' needs a key")

    def sequence(sequence_key: PRNGKeyArray, rig: Camera) -> Camera:
        # The same key at every frame: perturb_extrinsics_relative splits it over the views, so each view keeps
        # one draw of its multiplicative factors for the whole sequence.
        return jax.vmap(lambda frame: geometry.perturb_extrinsics_relative(sequence_key, frame, scale),
                        in_axes=1, out_axes=1)(rig)

    if per_sequence:
        return jax.vmap(sequence)(jax.random.split(key, batch_size), cameras)
    return jax.vmap(sequence, in_axes=(None, 0))(key, cameras)


def _nearest_determined(
    offsets: Float[Array, "frames joints 3"], determined: Bool[Array, "frames joints"]
) -> Float[Array, "frames joints 3"]:
    """Each undetermined entry replaced by the same joint's nearest earlier determined one, else the nearest later
    one, else 0 (the joint at the root)."""
    frames = offsets.shape[0]
    time = jnp.arange(frames)[:, None]
    earlier = jax.lax.cummax(jnp.where(determined, time, -1), axis=0)
    later = jax.lax.cummin(jnp.where(determined, time, frames), axis=0, reverse=True)
    source = jnp.where(earlier >= 0, earlier, later)
    filled = jnp.take_along_axis(offsets, jnp.minimum(source, frames - 1)[..., None], axis=0)
    return jnp.where((source < frames)[..., None], filled, 0.0)


def _dlt(
    P: Float[Array, "frames views 3 4"], points: Float[Array, "frames views 17 2"],
    weights: Float[Array, "frames views 17"],
) -> tuple[Float[Array, "frames 17 3"], Bool[Array, "frames 17"]]:
    """Confidence-weighted DLT per joint and frame of one sequence, world metres, and which joints it determined."""

    def frame(P_t, points_t, weights_t):
        result = geometry.triangulate(P_t, jnp.swapaxes(points_t, 0, 1), jnp.swapaxes(weights_t, 0, 1),
                                      require_in_front=False)
        return result.point, result.valid

    return jax.vmap(frame)(P, points, weights)


def _structural(
    P: Float[Array, "frames views 3 4"], points: Float[Array, "frames views 17 2"],
    weights: Float[Array, "frames views 17"], n_steps: int,
) -> tuple[Float[Array, "frames 17 3"], Bool[Array, "frames 17"]]:
    """ST + SCA of one sequence with its own (median) bone lengths, world metres, and the joints seen in two views."""
    per_frame = jax.vmap(lambda P_t, x_t, w_t: structri.estimate_bone_lengths(x_t[None], P_t, STRUCTRI17, w_t[None]))(
        P, points, weights)
    # A frame estimate_bone_lengths cannot use gives zeros. When no frame is usable, every frame has an undetermined
    # joint and ST returns LS, so the zero lengths are never applied.
    used = jnp.all(per_frame > 0, axis=-1)
    lengths = jnp.nan_to_num(jnp.nanmedian(jnp.where(used[:, None], per_frame, jnp.nan), axis=0), nan=0.0)
    # Per frame (ST is per frame anyway): structri's projection_matrices is annotated for one rig, so per-frame
    # projection matrices fail the runtime shape check although the solver supports them.
    pose = jax.vmap(lambda P_t, x_t, w_t: structri.structural_triangulation(x_t, P_t, lengths, STRUCTRI17, w_t, n_steps)
                    .pose)(P, points, weights)
    return pose, jnp.sum(weights > 0, axis=1) >= 2


@functools.partial(jax.jit, static_argnames=("method", "n_steps"))
def _triangulate(
    P: Float[Array, "batch views frames 3 4"], points: Float[Array, "batch views frames 17 2"],
    weights: Float[Array, "batch views frames 17"], R: Float[Array, "batch views frames 3 3"],
    true_R: Float[Array, "batch views frames 3 3"], true_t: Float[Array, "batch views frames 3"],
    method: Literal["dlt", "structural"], n_steps: int,
) -> tuple[Float[Array, "batch views frames 17 3"], Float[Array, "batch views frames 3"]]:
    """Triangulate through ``P``, fill the undetermined joints and roots; the root-relative pose rotated by ``R``,
    and the root in the true cameras' frames. One compilation per method and shape, whatever the calibration."""
    # Frames-first per sequence: (B, T, K, ...), the layout the solvers batch over.
    P, points, weights = (jnp.moveaxis(x, 2, 1) for x in (P, points, weights))
    if method == "dlt":
        world, determined = jax.vmap(_dlt)(P, points, weights)
    else:
        world, determined = jax.vmap(lambda *a: _structural(*a, n_steps))(P, points, weights)
    offsets = world - world[..., _ROOT:_ROOT + 1, :]
    offsets = jax.vmap(_nearest_determined)(offsets, determined & determined[..., _ROOT:_ROOT + 1])
    root = jax.vmap(_nearest_determined)(world[..., _ROOT:_ROOT + 1, :], determined[..., _ROOT:_ROOT + 1])[..., 0, :]
    return (jnp.einsum("bktij,btnj->bktni", R, offsets),
            jnp.einsum("bktij,btj->bkti", true_R, root) + true_t)


def triangulation_baseline(
    batch: Batch,
    method: Literal["dlt", "structural"],
    calibration: Literal["exact", "perturbed", "static"] = "exact",
    key: PRNGKeyArray | None = None,
    *,
    scale: Float[ArrayLike, ""] | float = 0.03,
    frame: Literal["true", "calibration"] = "true",
    n_steps: int = 3,
    per_sequence: bool = True,
    with_root: bool = False,
) -> Float[Array, "batch views frames 17 3"] | tuple[Float[Array, "batch views frames 17 3"],
                                                     Float[Array, "batch views frames 3"]]:
    """A triangulation baseline's camera-frame, root-relative STRUCTRI17 joints (metres), like ``batch.joints``.

    Args:
        batch: :func:`~flex.make_batch`'s detections (``points_2d``, ``confidences``) and true ``cameras``
            (undistorted pinhole, as make_batch's; the other fields are not read).
        method: ``"dlt"`` or ``"structural"`` (module docstring).
        calibration: ``"exact"``, ``"perturbed"`` or ``"static"`` (:func:`baseline_cameras`).
        key: the perturbation's key, for ``"perturbed"`` only.
        scale: the perturbation's relative standard deviation (0.03, 0.04 in the paper).
        frame: ``"true"`` or ``"calibration"``: whose rotation takes the world pose to each camera frame
            (module docstring).
        n_steps: SCA steps of the structural method.
        per_sequence: ``"perturbed"``: a draw per sequence (True) or one for the batch (:func:`baseline_cameras`).
        with_root: also return the triangulated root (``mid_hip``) in each view's true camera frame (metres; a
            frame whose root is not determined takes the nearest determined frame's): ``(joints, root)``, the
            global position :func:`camera_root` gives for FLEX.

    Pure and jittable with ``method``, ``calibration``, ``frame`` and ``n_steps`` static.
    """
    joints, root = _baseline(batch, method, calibration, key, scale, frame, n_steps, per_sequence)
    return (joints, root) if with_root else joints


def _baseline(batch, method, calibration, key, scale, frame, n_steps, per_sequence):
    if method not in _METHODS:
        raise ValueError(f"method must be one of {_METHODS}, got {method!r}")
    if frame not in _FRAMES:
        raise ValueError(f"frame must be one of {_FRAMES}, got {frame!r}")
    batch_size, views, frames = _check_cameras(batch.cameras)
    points, weights = jnp.asarray(batch.points_2d), jnp.asarray(batch.confidences)
    if points.shape != (batch_size, views, frames, STRUCTRI17.num_joints, 2) or weights.shape != points.shape[:-1]:
        raise ValueError(f"points_2d {points.shape} and confidences {weights.shape} must be "
                         f"{(batch_size, views, frames, STRUCTRI17.num_joints)} (+ (2,)) like the cameras")
    if views < 2:
        raise ValueError(f"triangulation needs at least 2 views, got {views}")
    if not isinstance(batch.cameras.dist, jax.core.Tracer) and np.any(np.asarray(batch.cameras.dist) != 0):
        raise ValueError("the baselines use linear projections: pass undistorted cameras and pixels")
    given = baseline_cameras(batch.cameras, calibration, key, scale, per_sequence)
    R = (batch.cameras if frame == "true" else given).R
    return _triangulate(geometry.projection_matrix(given), points, weights, jnp.asarray(R), jnp.asarray(batch.cameras.R),
                        jnp.asarray(batch.cameras.t), method, int(n_steps))


def camera_root(
    root_position: Float[ArrayLike, "*b frames 3"], centre: Float[ArrayLike, "*b 2"], scale: Float[ArrayLike, "*b"],
    K: Float[ArrayLike, "*b frames 3 3"],
) -> Float[Array, "*b frames 3"]:
    """A root ``(x d, y d, d)`` in a view's normalised camera (FLEX's ``root_position``, a
    :class:`~flex.Batch`'s) in that view's camera frame, metres: depth ``Z = d f / scale`` (``f`` the mean of the
    focal lengths, as the samples use) and the root's pixel ``x scale + centre`` back-projected through ``K`` at
    that depth. ``centre`` and ``scale`` are the input normalisation's (:func:`~flex.normalise_2d`, FLEX's
    outputs). This is where the intrinsics enter: FLEX itself estimates the root up to the scale ``f / scale``."""
    root_position, centre, scale, K = (jnp.asarray(a) for a in (root_position, centre, scale, K))
    focal = jnp.stack([K[..., 0, 0], K[..., 1, 1]], axis=-1)
    depth = root_position[..., 2] * jnp.mean(focal, axis=-1) / scale[..., None]
    pixels = root_position[..., :2] / root_position[..., 2:] * scale[..., None, None] + centre[..., None, :]
    return jnp.concatenate([(pixels - K[..., :2, 2]) / focal * depth[..., None], depth[..., None]], axis=-1)


def root_position_error(pred: Float[ArrayLike, "*b 3"], gt: Float[ArrayLike, "*b 3"]) -> Float[Array, ""]:
    """Global root position error: the mean distance between predicted and true camera-frame roots, mm."""
    return 1000.0 * jnp.mean(jnp.linalg.norm(jnp.asarray(pred) - jnp.asarray(gt), axis=-1))


class MotionMetrics(NamedTuple):
    """The experiment's numbers, each averaged over sequences and views."""

    mpjpe: Float[Array, ""]
    """Protocol #1 MPJPE (root-relative, 17 joints, no alignment), mm."""
    acceleration_error: Float[Array, ""]
    """Mean joint acceleration error, mm/frame^2 (multiply by fps^2 for mm/s^2)."""
    mbls: Float[Array, ""]
    """Mean bone-length standard deviation over time of the prediction (STRUCTRI17 bones), mm."""


def motion_metrics(
    pred: Float[ArrayLike, "batch views frames joints 3"],
    gt: Float[ArrayLike, "batch views frames 17 3"],
    skeleton: Skeleton = STRUCTRI17,
) -> MotionMetrics:
    """:class:`MotionMetrics` of camera-frame sequences in metres (``gt`` like ``batch.joints``).

    ``pred`` is in ``skeleton``: :data:`geometry.STRUCTRI17`, or :data:`geometry.FLEX20` (FLEX's
    ``joints_relative``), whose duplicates are dropped (spec section 7: the 17-joint protocol). Needs 3 frames.
    """
    if skeleton not in (STRUCTRI17, FLEX20):
        raise ValueError(f"skeleton must be STRUCTRI17 or FLEX20, got {skeleton.name}")
    pred, gt = jnp.asarray(pred), jnp.asarray(gt)
    expected = gt.shape[:3] + (skeleton.num_joints, 3)
    if gt.ndim != 5 or gt.shape[3:] != (STRUCTRI17.num_joints, 3) or pred.shape != expected:
        raise ValueError(f"need gt (batch, views, frames, 17, 3) and pred (batch, views, frames, "
                         f"{skeleton.num_joints}, 3) in {skeleton.name}, got gt {gt.shape} and pred {pred.shape}")
    if gt.shape[2] < 3:
        raise ValueError(f"the acceleration error needs at least 3 frames, got {gt.shape[2]}")
    pred = geometry.remap_joints(pred, skeleton, STRUCTRI17)
    return MotionMetrics(
        mpjpe=1000.0 * jnp.mean(geometry.mpjpe_root_relative(pred, gt, _ROOT)),
        acceleration_error=1000.0 * jnp.mean(geometry.acceleration_error(pred, gt)),
        mbls=1000.0 * jnp.mean(geometry.mbls(pred, STRUCTRI17)),
    )

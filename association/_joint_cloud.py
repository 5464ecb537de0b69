"""The Joint Cloud (JCSAT paper Sec. 3.1, Algorithm 1): every same-type 2D pair, every view pair, triangulated.

For a frame with ``V`` views, ``P = V (V - 1) / 2`` unordered view pairs (``v' < v''``, in
:func:`view_pairs` order), ``J`` joint types and at most ``C`` candidates per view and joint type
(the padding of :func:`mocap.pad_detections`), the cloud is a dense grid

    ``(P, J, C, C)``: view pair p, joint type j, candidate a in view ``pairs[p, 0]``,
    candidate b in view ``pairs[p, 1]``,

so the provenance of every 3D candidate is its grid position plus the per-candidate fields of
:class:`JointCloud` (both scores, the two reprojection errors, the distance between the two
back-projected rays). Padded or filtered entries are kept in the grid with ``valid = False``
(their point is 0). Identity is deliberately ignored: a pair of detections of two different people
yields a (usually filtered, sometimes not) spurious candidate, as in the paper.

:func:`build_joint_cloud` triangulates only the entries whose two candidates pass the score filter
(about 16% of the Shelf grid), one view pair at a time so that the pair's cameras are constants of
the step, and writes the dense grid; :func:`joint_cloud_frame` computes every entry of one frame.
Both give the same numbers.

The filters are those of the official code (``docs/jcsat.md``, "Where the paper is silent"): both detection
scores above ``min_score`` and the two rays closer than ``max_ray_distance`` metres; in addition the
point must be in front of both cameras and the two-view DLT well posed (:func:`geometry.triangulate_point`).
The official code triangulates with a two-view Gauss-Newton; this module uses the two-view DLT of
:mod:`geometry` on undistorted pixels (identical to ``cv2.triangulatePoints``).
"""

from __future__ import annotations

import dataclasses
import itertools
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

import geometry
from geometry import Camera

__all__ = [
    "JointCloudConfig",
    "JointCloud",
    "view_pairs",
    "triangulate_candidate_pair",
    "joint_cloud_frame",
    "build_joint_cloud",
]


@dataclasses.dataclass(frozen=True)
class JointCloudConfig:
    """Filters of the Joint Cloud (the official JCSAT code's values)."""

    min_score: float = 0.2
    """A 2D candidate is used only if its detector score is strictly above this."""
    max_ray_distance: float = 0.1
    """Metres: the two back-projected rays must pass closer than this to each other."""

    def __post_init__(self) -> None:
        if not 0.0 <= self.min_score < 1.0:
            raise ValueError(f"min_score must be in [0, 1), got {self.min_score}")
        if not self.max_ray_distance > 0.0:
            raise ValueError(f"max_ray_distance must be positive (metres), got {self.max_ray_distance}")


class JointCloud(NamedTuple):
    """3D candidates on the grid ``(*frames, pairs, joints, C, C)`` (see the module docstring)."""

    point: Float[Array, "*f P J C C 3"]
    """Triangulated position, metres, world frame; 0 where not ``valid``."""
    valid: Bool[Array, "*f P J C C"]
    """Both candidates exist and pass the score filter, the rays pass the distance filter, the point
    lies in front of both cameras and the DLT is well posed."""
    score: Float[Array, "*f P J C C 2"]
    """Detector scores of the two 2D candidates (first view, second view of the pair)."""
    reprojection_error: Float[Array, "*f P J C C 2"]
    """Pixels (undistorted image) between each 2D candidate and the reprojected point."""
    ray_distance: Float[Array, "*f P J C C"]
    """Metres: shortest distance between the two back-projected rays (lines through the camera centres)."""

    @property
    def num_candidates(self) -> int:
        return self.point.shape[-3]


def view_pairs(num_views: int) -> Int[np.ndarray, "P 2"]:
    """All unordered view pairs ``(v', v'')`` with ``v' < v''``, in lexicographic order (10 for 5 views)."""
    if num_views < 2:
        raise ValueError(f"a Joint Cloud needs at least two views, got {num_views}")
    return np.array(list(itertools.combinations(range(num_views), 2)), dtype=np.int32)


class _Candidate(NamedTuple):
    point: Float[Array, "3"]
    well_posed: Bool[Array, ""]
    reprojection_error: Float[Array, "2"]
    ray_distance: Float[Array, ""]
    in_front: Bool[Array, ""]


def triangulate_candidate_pair(
    projections: Float[Array, "2 3 4"],
    centres: Float[Array, "2 3"],
    pixels: Float[Array, "2 2"],
    rays: Float[Array, "2 3"],
) -> _Candidate:
    """ONE 3D candidate from two undistorted pixel observations in two cameras.

    Args:
        projections: ``K [R | t]`` of the two cameras (world metres to pixels).
        centres: camera centres, metres.
        pixels: undistorted pixels of the two 2D candidates.
        rays: world directions (any length) of the back-projected rays through those pixels.

    Returns the point (metres), the DLT validity, both reprojection errors (pixels), the ray
    distance (metres) and whether the point has positive depth in both cameras.
    """
    tri = geometry.triangulate_point(projections, pixels, jnp.ones(2, pixels.dtype))
    normal = jnp.cross(rays[0], rays[1])
    baseline = centres[1] - centres[0]
    normal_sq = jnp.sum(normal * normal)
    # Parallel rays: the distance between the lines is the baseline's component normal to them.
    along = rays[0] / jnp.sqrt(jnp.sum(rays[0] * rays[0]))
    parallel_distance = jnp.sqrt(jnp.sum(jnp.cross(baseline, along) ** 2))
    skew = normal_sq > 1e-12 * jnp.sum(rays[0] * rays[0]) * jnp.sum(rays[1] * rays[1])
    skew_distance = jnp.abs(jnp.sum(baseline * normal)) / jnp.sqrt(jnp.where(skew, normal_sq, 1.0))
    distance = jnp.where(skew, skew_distance, parallel_distance)
    homogeneous = jnp.concatenate([tri.point, jnp.ones(1, tri.point.dtype)])
    depths = jnp.sum(projections[:, 2, :] * homogeneous[None, :], axis=-1)
    return _Candidate(tri.point, tri.valid, tri.reprojection_error, distance, jnp.all(depths > 0))


class _Views(NamedTuple):
    """Per-view quantities of one frame, computed once and shared by every view pair."""

    undistorted: Float[Array, "V J C 2"]
    """Undistorted pixels."""
    rays: Float[Array, "V J C 3"]
    """World directions of the back-projected rays."""
    projections: Float[Array, "V 3 4"]
    centres: Float[Array, "V 3"]


def _views(rig: Camera, xy: Float[Array, "V J C 2"]) -> _Views:
    undistorted = jax.vmap(partial(geometry.undistort_points, output="pixels"))(rig, xy)
    normalised = jax.vmap(geometry.undistort_points)(rig, xy)
    homogeneous = jnp.concatenate([normalised, jnp.ones_like(normalised[..., :1])], axis=-1)
    # World ray direction R^T x_norm, as a broadcast-sum (tiny matmuls are slow under vmap).
    rays = jnp.sum(rig.R[:, None, None, :, :] * homogeneous[..., :, None], axis=-2)
    return _Views(undistorted, rays, geometry.projection_matrix(rig), geometry.camera_centre(rig))


def joint_cloud_frame(
    rig: Camera,
    xy: Float[Array, "V J C 2"],
    score: Float[Array, "V J C"],
    mask: Bool[Array, "V J C"],
    config: JointCloudConfig = JointCloudConfig(),
) -> JointCloud:
    """The Joint Cloud of ONE frame from padded detections (pixels as observed, i.e. distorted).

    Jittable (``config`` is static); it triangulates every grid entry. :func:`build_joint_cloud`
    gives the same result for many frames and triangulates only the entries that pass the score filter.
    """
    num_views = xy.shape[0]
    pairs = view_pairs(num_views)
    views = _views(rig, xy)
    usable = mask & (score > config.min_score)

    first, second = pairs[:, 0], pairs[:, 1]
    pair_projections = jnp.stack([views.projections[first], views.projections[second]], axis=1)  # (P, 2, 3, 4)
    pair_centres = jnp.stack([views.centres[first], views.centres[second]], axis=1)  # (P, 2, 3)

    def one(proj, cent, px_a, px_b, ray_a, ray_b):
        return triangulate_candidate_pair(proj, cent, jnp.stack([px_a, px_b]), jnp.stack([ray_a, ray_b]))

    over_b = jax.vmap(one, in_axes=(None, None, None, 0, None, 0))
    over_ab = jax.vmap(over_b, in_axes=(None, None, 0, None, 0, None))
    over_joints = jax.vmap(over_ab, in_axes=(None, None, 0, 0, 0, 0))
    over_pairs = jax.vmap(over_joints, in_axes=(0, 0, 0, 0, 0, 0))
    cand = over_pairs(
        pair_projections, pair_centres, views.undistorted[first], views.undistorted[second], views.rays[first], views.rays[second]
    )  # leaves (P, J, C, C, ...)
    both = usable[first][..., :, None] & usable[second][..., None, :]  # (P, J, C, C)
    valid = both & cand.well_posed & cand.in_front & (cand.ray_distance < config.max_ray_distance)
    pair_score = jnp.stack(
        jnp.broadcast_arrays(score[first][..., :, None], score[second][..., None, :]), axis=-1
    )
    zero = jnp.zeros((), xy.dtype)
    return JointCloud(
        point=jnp.where(valid[..., None], cand.point, zero),
        valid=valid,
        score=jnp.where(both[..., None], pair_score, zero),
        reprojection_error=jnp.where(both[..., None], cand.reprojection_error, zero),
        ray_distance=jnp.where(both, cand.ray_distance, zero),
    )


@partial(jax.jit, static_argnames=("config",))
def _joint_cloud_entries(
    rig: Camera,
    xy: Float[Array, "F V J C 2"],
    score: Float[Array, "F V J C"],
    entries: Int[Array, "P K"],
    config: JointCloudConfig,
) -> JointCloud:
    """The Joint Cloud of every frame, triangulating only the listed grid entries of each view pair.

    ``entries[p]`` are flat indices into the ``(F, J, C, C)`` grid of view pair ``p`` of the entries
    that pass the score filter (the others are 0 and invalid in :func:`joint_cloud_frame` too);
    indices past that grid pad the rows to a common, bucketed length and are dropped.
    """
    frames, num_views, num_joints, num_candidates = score.shape
    pairs = view_pairs(num_views)
    pair_grid = (frames, num_joints, num_candidates, num_candidates)
    pair_size = int(np.prod(pair_grid))
    pairs_array = jnp.asarray(pairs)
    views = jax.vmap(_views, in_axes=(None, 0), out_axes=_Views(0, 0, None, None))(rig, xy)

    def one_pair(pair: Array, pair_entries: Array) -> tuple[_Candidate, Array]:
        # One view pair per step: its cameras are constants of the step, not per-entry arrays.
        frame, joint, a, b = jnp.unravel_index(jnp.minimum(pair_entries, pair_size - 1), pair_grid)
        first, second = pairs_array[pair, 0], pairs_array[pair, 1]

        def take(array: Array, view: Array, candidate: Array) -> Array:
            return array[frame, view, joint, candidate]

        pair_projections = jnp.stack([views.projections[first], views.projections[second]])
        pair_centres = jnp.stack([views.centres[first], views.centres[second]])
        cand = jax.vmap(triangulate_candidate_pair, in_axes=(None, None, 0, 0))(
            pair_projections,
            pair_centres,
            jnp.stack([take(views.undistorted, first, a), take(views.undistorted, second, b)], axis=1),
            jnp.stack([take(views.rays, first, a), take(views.rays, second, b)], axis=1),
        )
        return cand, jnp.stack([take(score, first, a), take(score, second, b)], axis=-1)

    cand, pair_score = jax.lax.map(lambda args: one_pair(*args), (jnp.arange(len(pairs)), entries))  # (P, K, ...)
    valid = cand.well_posed & cand.in_front & (cand.ray_distance < config.max_ray_distance)
    # Flat index into the (F, P, J, C, C) grid; past its end (dropped) for the padding.
    frame_size = pair_size // frames
    grid_index = (entries // frame_size * len(pairs) + jnp.arange(len(pairs))[:, None]) * frame_size + entries % frame_size
    grid_index = jnp.where(entries < pair_size, grid_index, len(pairs) * pair_size)
    grid = (frames, len(pairs), num_joints, num_candidates, num_candidates)

    def scatter(values: Array) -> Array:
        dense = jnp.zeros((len(pairs) * pair_size,) + values.shape[2:], values.dtype)
        flat = values.reshape((-1,) + values.shape[2:])
        return dense.at[grid_index.reshape(-1)].set(flat, mode="drop").reshape(grid + values.shape[2:])

    return JointCloud(
        point=scatter(jnp.where(valid[..., None], cand.point, 0)),
        valid=scatter(valid),
        score=scatter(pair_score),
        reprojection_error=scatter(cand.reprojection_error),
        ray_distance=scatter(cand.ray_distance),
    )


def _bucket(count: int) -> int:
    """``count`` rounded up to a multiple of 256 or, above 8192, to one of 16 lengths per power of two (< 7%)."""
    step = 1 << max(count.bit_length() - 5, 8)
    return max(step, -(-count // step) * step)


def build_joint_cloud(
    rig: Camera,
    xy: Float[ArrayLike, "F V J C 2"],
    score: Float[ArrayLike, "F V J C"],
    mask: Bool[ArrayLike, "F V J C"],
    config: JointCloudConfig = JointCloudConfig(),
) -> JointCloud:
    """The Joint Cloud of every frame (leaves ``(F, P, J, C, C, ...)``), equal to
    :func:`joint_cloud_frame` of each frame.

    Takes the fields of :class:`mocap.PaddedDetections` (pixels as observed). Only the grid entries
    whose two candidates pass the score filter are triangulated (about 16% of the Shelf grid), in one
    jitted call for all frames; the score filter runs on the host to size that call. Raises
    ``ValueError`` on inconsistent shapes or NaN in a real candidate.
    """
    xy, score, mask = np.asarray(xy), np.asarray(score), np.asarray(mask, bool)
    if xy.ndim != 5 or xy.shape[-1] != 2:
        raise ValueError(f"xy must have shape (frames, views, joints, candidates, 2), got {xy.shape}")
    if score.shape != xy.shape[:-1] or mask.shape != xy.shape[:-1]:
        raise ValueError(f"score {score.shape} and mask {mask.shape} must have shape {xy.shape[:-1]}")
    if rig.K.ndim != 3 or rig.K.shape[0] != xy.shape[1]:
        raise ValueError(f"rig must be a stacked Camera with {xy.shape[1]} views, got K of shape {rig.K.shape}")
    if not (np.isfinite(xy[mask]).all() and np.isfinite(score[mask]).all()):
        raise ValueError("xy or score contains NaN or inf at a real (unmasked) candidate")
    dtype = jnp.asarray(xy[:0]).dtype  # float64 stays float64 only where jax_enable_x64 is set
    if not jnp.issubdtype(dtype, jnp.floating):
        dtype = np.dtype(np.float32)
    xy, score = xy.astype(dtype), score.astype(dtype)
    frames, num_views, num_joints, num_candidates = mask.shape
    pairs = view_pairs(num_views)
    if frames * len(pairs) * num_joints * num_candidates**2 >= 2**31:
        raise ValueError(f"the Joint Cloud grid of {frames} frames exceeds int32 indexing: pass fewer frames per call")
    # The comparison in the kernel's dtype, as in joint_cloud_frame.
    usable = mask & (score > np.asarray(config.min_score, dtype))
    both = usable[:, pairs[:, 0], :, :, None] & usable[:, pairs[:, 1], :, None, :]  # (F, P, J, C, C)
    per_pair = np.moveaxis(both, 1, 0).reshape(len(pairs), -1)  # (P, F * J * C * C)
    entries = [np.flatnonzero(row) for row in per_pair]
    padded = np.full((len(pairs), _bucket(max(map(len, entries)))), per_pair.shape[1], np.int32)
    for row, pair_entries in zip(padded, entries):
        row[: len(pair_entries)] = pair_entries
    rig = jax.tree.map(lambda leaf: jnp.asarray(leaf, dtype), rig)
    return _joint_cloud_entries(rig, jnp.asarray(xy), jnp.asarray(score), jnp.asarray(padded), config)

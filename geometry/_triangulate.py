"""Weighted N-view linear (DLT) triangulation with a fast closed-form kernel and an SVD reference.

For one point seen in ``views`` cameras with projection matrices ``P_k`` (pixels from world metres) and
undistorted pixels ``(x_k, y_k)``, the DLT stacks the rows ``w_k (x_k P_k[2] - P_k[0])`` and
``w_k (y_k P_k[2] - P_k[1])`` into ``A`` (``2 views x 4``) and returns the unit homogeneous vector ``v``
minimising ``|A v|``. The weight ``w_k`` multiplies the rows (squared residuals carry ``w_k**2``, as in
the classic weighted DLT); weight 0 removes a view. Rows are not normalised by default, so two views
with unit weights give exactly what ``cv2.triangulatePoints`` gives.

Two kernels solve the same problem:

* ``"closed_form"`` (default): ``v`` is the eigenvector of ``M = A^T A`` with the smallest eigenvalue.
  Laguerre's method on the characteristic polynomial gives that eigenvalue ``mu``; then
  ``adj(M - mu I) = sum_i (prod_{j != i} (lambda_j - mu)) v_i v_i^T`` is nearly rank one along the
  eigenvector, so its column with the largest diagonal entry approximates it, and a product with the
  adjugate (inverse iteration without a solve) polishes it. Element-wise arithmetic only: no LAPACK
  call, no tiny matrix product, so ``vmap`` over millions of points stays vectorised, and it is
  differentiable.
* ``"svd"``: the last right-singular vector of ``A`` from ``jnp.linalg.svd`` (slow on CPU: a LAPACK
  call per point), kept as the reference. On a 2-core CPU, keep two large batches of it out of one compiled
  computation: jaxlib's batched LAPACK kernels wait on XLA's intra-op threads, and two at once can deadlock
  (see ``_metrics.py``, where the Procrustes alignment slices its SVDs for that reason).

Public entry points batch over any leading dimensions (points, joints, frames); see :func:`triangulate`
and :func:`triangulate_pixels`.
"""

from __future__ import annotations

from functools import partial
from typing import Literal, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from ._camera import Camera, projection_matrix, undistort_points

__all__ = [
    "Triangulation",
    "triangulate_point",
    "triangulate",
    "triangulate_pixels",
]

Method = Literal["closed_form", "svd"]

_LAGUERRE_STEPS = 5
"""Laguerre steps from 0 towards the smallest eigenvalue (the shift); cubic convergence for a simple
root. Measured against a NumPy SVD (float64, 4-view ring, 1700 points, max |dX|): 3 steps reach the
float64 floor (1e-13 m) up to 6 px noise in millimetres, 20 px noise in millimetres (eigenvalue ratio
lambda_4 / lambda_3 near 1) needs 5: 1.6e-3 m with 3, 2.4e-6 m with 4, 1.7e-13 m with 5."""

_POWER_STEPS = 1
"""Inverse-iteration products with the shifted adjugate after picking its best column (0 steps:
1.3e-7 m in the worst case above)."""


_CONDITIONING_FLOOR = 100.0
"""``conditioning`` below this many machine epsilons means a (numerically) two-dimensional null space."""


class Triangulation(NamedTuple):
    """Result of a triangulation; every leaf has the caller's leading batch dimensions."""

    point: Float[Array, "*batch 3"]
    """Triangulated point in world units (metres); zeros where ``valid`` is False."""
    valid: Bool[Array, "*batch"]
    """At least two views with positive weight whose camera centres differ (a zero baseline determines
    no depth), the point is well determined (not a near-double null space, e.g. consistent rays from
    one centre), finite (``|point| <= max_distance``; a point at infinity from parallel rays fails
    this) and in front of every camera with positive weight (positive depth: a camera cannot have
    seen a point behind it; not checked with ``require_in_front=False``)."""
    reprojection_error: Float[Array, "*batch views"]
    """Distance in pixels between each view's input point and the reprojected point; 0 for views with
    weight 0 and for invalid points."""
    residual: Float[Array, "*batch"]
    """Algebraic residual ``|A v|`` with ``|v| = 1``: the smallest singular value of the weighted DLT
    matrix (0 for noise-free data, and 0 where ``valid`` is False)."""
    conditioning: Float[Array, "*batch"]
    """Scale-free measure of how well the point is determined, ``e3 / (e1 e2)`` of the elementary
    symmetric functions of the eigenvalues of ``A^T A``; between ``lambda_3 / (9 lambda_1)`` and
    ``lambda_3 / lambda_1`` for a small ``lambda_4``. Near 0 when the null space is (nearly) two-dim."""
    num_views: Int[Array, "*batch"]
    """Number of views with positive weight."""


Scalar = Float[Array, ""]
"""One number per point. The kernels below keep vectors and 4x4 matrices as Python lists of scalars:
under ``vmap`` each scalar becomes one contiguous ``(batch,)`` array and XLA emits plain element-wise
loops. Small arrays with stacks and short-axis reductions get the batch axis moved to the front
instead and ran 2-4x slower (20-40 ms instead of 7-10 ms for 100k two-view points, float64, 2 busy
CPU cores)."""
Vector4 = list[Scalar]
Matrix4 = list[list[Scalar]]


class _DltProblem(NamedTuple):
    """The set-up both kernels share."""

    rows: list[Vector4]
    """The ``2 views`` weighted DLT rows of ``A``; zero for masked views."""
    row_scales: list[Scalar]
    """The factor each raw row ``x P[2] - P[0]`` was multiplied by (its weight, over its norm if normalised)."""
    normal: Matrix4
    """``A^T A`` divided by its trace (scale-free, and keeps its adjugate O(1) even in float32)."""
    adjugate: Matrix4
    """``adj(normal)``; symmetric like ``normal``."""
    num_views: Int[Array, ""]


def _adjugate_4x4(a: Matrix4) -> Matrix4:
    """Adjugate of a symmetric 4x4 matrix from its 2x2 minors (Laplace expansion)."""
    s0 = a[0][0] * a[1][1] - a[1][0] * a[0][1]
    s1 = a[0][0] * a[1][2] - a[1][0] * a[0][2]
    s2 = a[0][0] * a[1][3] - a[1][0] * a[0][3]
    s3 = a[0][1] * a[1][2] - a[1][1] * a[0][2]
    s4 = a[0][1] * a[1][3] - a[1][1] * a[0][3]
    s5 = a[0][2] * a[1][3] - a[1][2] * a[0][3]
    c5 = a[2][2] * a[3][3] - a[3][2] * a[2][3]
    c4 = a[2][1] * a[3][3] - a[3][1] * a[2][3]
    c3 = a[2][1] * a[3][2] - a[3][1] * a[2][2]
    c2 = a[2][0] * a[3][3] - a[3][0] * a[2][3]
    c1 = a[2][0] * a[3][2] - a[3][0] * a[2][2]
    b00 = a[1][1] * c5 - a[1][2] * c4 + a[1][3] * c3
    b01 = -a[0][1] * c5 + a[0][2] * c4 - a[0][3] * c3
    b02 = a[3][1] * s5 - a[3][2] * s4 + a[3][3] * s3
    b03 = -a[2][1] * s5 + a[2][2] * s4 - a[2][3] * s3
    b11 = a[0][0] * c5 - a[0][2] * c2 + a[0][3] * c1
    b12 = -a[3][0] * s5 + a[3][2] * s2 - a[3][3] * s1
    b13 = a[2][0] * s5 - a[2][2] * s2 + a[2][3] * s1
    b22 = a[3][0] * s4 - a[3][1] * s2 + a[3][3] * s0
    b23 = -a[2][0] * s4 + a[2][1] * s2 - a[2][3] * s0
    b33 = a[2][0] * s3 - a[2][1] * s1 + a[2][2] * s0
    # The input is symmetric, so is its adjugate: only the upper triangle is computed.
    return [[b00, b01, b02, b03], [b01, b11, b12, b13], [b02, b12, b22, b23], [b03, b13, b23, b33]]


def _dot(a: Vector4, b: Vector4) -> Scalar:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3]


def _normalised(v: Vector4) -> Vector4:
    norm = jnp.sqrt(_dot(v, v))
    safe = jnp.where(norm > 0, norm, 1)
    return [component / safe for component in v]


def _dlt_problem(
    projections: Float[Array, "views 3 4"],
    points: Float[Array, "views 2"],
    weights: Float[Array, "views"],
    normalise_rows: bool,
) -> _DltProblem:
    rows, row_scales = [], []
    for view in range(projections.shape[0]):
        used = weights[view] > 0
        for axis in range(2):
            # Masked views may carry NaN for missing detections; NaN * 0 would still poison the sums.
            coordinate = jnp.where(used, points[view, axis], 0)
            row = [coordinate * projections[view, 2, j] - projections[view, axis, j] for j in range(4)]
            scale = jnp.where(used, weights[view], 0)
            if normalise_rows:
                norm = jnp.sqrt(_dot(row, row))
                scale = scale / jnp.where(norm > 0, norm, 1)
            rows.append([scale * entry for entry in row])
            row_scales.append(scale)
    upper = {(i, j): sum(row[i] * row[j] for row in rows) for i in range(4) for j in range(i, 4)}
    trace = upper[0, 0] + upper[1, 1] + upper[2, 2] + upper[3, 3]
    # One reciprocal, then products: with ten divisions XLA stored each quotient separately and
    # recomputed the rows and the trace for each (68 instead of 59 fused loops, 1.2-1.5x slower).
    inverse_trace = 1 / jnp.where(trace > 0, trace, 1)
    normal = [[upper[min(i, j), max(i, j)] * inverse_trace for j in range(4)] for i in range(4)]
    num_views = jnp.sum((weights > 0).astype(jnp.int32))
    return _DltProblem(rows, row_scales, normal, _adjugate_4x4(normal), num_views)


def _best_adjugate_column(adj: Matrix4) -> Vector4:
    """The column of a (nearly rank-one, PSD) adjugate with the largest diagonal entry: the one
    least spoiled by rounding."""
    column = list(adj[0])
    largest = adj[0][0]
    for i in range(1, 4):
        better = adj[i][i] > largest
        column = [jnp.where(better, adj[i][j], column[j]) for j in range(4)]
        largest = jnp.where(better, adj[i][i], largest)
    return column


@jax.custom_jvp
def _smallest_eigenvector(normal: Matrix4) -> Vector4:
    """Unit eigenvector of the symmetric PSD ``normal`` with the smallest eigenvalue (sign arbitrary).

    1. The smallest eigenvalue ``lambda_4`` by Laguerre's method on the characteristic polynomial from
       0: the polynomial has real roots only, so the iterates rise monotonically towards ``lambda_4``
       and never pass it, whatever the gap to ``lambda_3`` (Newton's method crawls at rate 1/2 when
       the gap is small).
    2. ``adj(M - mu I) = prod_(j != i) (lambda_j - mu) v_i v_i^T`` is then nearly rank one along the
       wanted eigenvector: its best column, polished by inverse iteration (products with the adjugate,
       no solve), each step shrinking the error by ``(lambda_4 - mu) / (lambda_3 - mu)``.
    The shift matters when the eigenvalues are not well separated. Plain inverse iteration on M
    converges like ``(lambda_4 / lambda_3)^k``, and the unnormalised DLT in millimetres with pixel
    noise of a few pixels has ``lambda_4 / lambda_3`` up to 0.65 (4 mm off an SVD after 3 steps).
    The shifted matrix is Jacobi-scaled (``S = diag^-1/2``) before its adjugate, because millimetres
    put ~1e6 between the point columns and the homogeneous one and the unscaled adjugate loses digits;
    ``(M - mu I)^-1 = S (S (M - mu I) S)^-1 S`` keeps the iteration on M's own eigenvector."""
    m = normal
    adj = _adjugate_4x4(m)
    e1 = m[0][0] + m[1][1] + m[2][2] + m[3][3]
    e2 = sum(m[i][i] * m[j][j] - m[i][j] * m[i][j] for i in range(4) for j in range(i + 1, 4))
    e3 = adj[0][0] + adj[1][1] + adj[2][2] + adj[3][3]
    e4 = _dot(m[0], [adj[j][0] for j in range(4)])
    mu = jnp.zeros_like(e1)
    for _ in range(_LAGUERRE_STEPS):
        value = e4 + mu * (-e3 + mu * (e2 + mu * (-e1 + mu)))
        slope = -e3 + mu * (2 * e2 + mu * (-3 * e1 + 4 * mu))
        curvature = 2 * e2 + mu * (-6 * e1 + 12 * mu)
        root = jnp.sqrt(jnp.maximum(9 * slope * slope - 12 * value * curvature, 0))
        denominator = slope - root
        mu = jnp.where(denominator < 0, mu - 4 * value / jnp.where(denominator < 0, denominator, -1), mu)
    shifted = [[m[i][j] - (mu if i == j else 0) for j in range(4)] for i in range(4)]
    scale = [1 / jnp.sqrt(jnp.where(shifted[i][i] > 0, shifted[i][i], 1)) for i in range(4)]
    adj = _adjugate_4x4([[scale[i] * shifted[i][j] * scale[j] for j in range(4)] for i in range(4)])
    column = _best_adjugate_column(adj)
    # Only the direction matters until the end: dividing by trace(S adj S), about its largest
    # eigenvalue, keeps the iterate at a fixed scale without a norm per step (fewer fused loops).
    v = [scale[i] * column[i] for i in range(4)]
    trace = sum(scale[i] * scale[i] * adj[i][i] for i in range(4))
    inverse_trace = 1 / jnp.where(trace > 0, trace, 1)
    for _ in range(_POWER_STEPS):
        scaled = [scale[i] * v[i] for i in range(4)]
        v = [scale[i] * _dot(adj[i], scaled) * inverse_trace for i in range(4)]
    return _normalised(v)


@_smallest_eigenvector.defjvp
def _smallest_eigenvector_jvp(primals: tuple[Matrix4], tangents: tuple[Matrix4]) -> tuple[Vector4, Vector4]:
    """First-order perturbation theory, ``dv = -(M - lambda I)^+ dM v``, instead of differentiating
    the iterations: exact for the eigenvector, and the gradient graph stays small (differentiating
    the power steps made XLA take 13-20 s to compile the gradient of the batched kernel)."""
    (m,), (dm,) = primals, tangents
    v = _smallest_eigenvector(m)
    mv = [_dot(m[i], v) for i in range(4)]
    eigenvalue = _dot(v, mv)
    # M - lambda I + v v^T is invertible (its eigenvalue along v is 1 = trace(M) > lambda_i - lambda
    # scale) and acts as (M - lambda I)^+ on the complement of v.
    shifted = [[m[i][j] - (eigenvalue if i == j else 0) + v[i] * v[j] for j in range(4)] for i in range(4)]
    adj = _adjugate_4x4(shifted)
    det = _dot(shifted[0], [adj[j][0] for j in range(4)])
    dm_v = [_dot(dm[i], v) for i in range(4)]
    along = _dot(v, dm_v)
    projected = [dm_v[i] - along * v[i] for i in range(4)]
    safe_det = jnp.where(det != 0, det, 1)
    return v, [-_dot(adj[i], projected) / safe_det for i in range(4)]


def _null_vector_closed_form(problem: _DltProblem) -> Vector4:
    return _smallest_eigenvector(problem.normal)


def _null_vector_svd(problem: _DltProblem) -> Vector4:
    matrix = jnp.stack([jnp.stack(row) for row in problem.rows])
    _, _, vh = jnp.linalg.svd(matrix, full_matrices=False)
    return [vh[-1, j] for j in range(4)]


_KERNELS = {"closed_form": _null_vector_closed_form, "svd": _null_vector_svd}


def _conditioning(problem: _DltProblem) -> Scalar:
    m, adj = problem.normal, problem.adjugate
    e1 = m[0][0] + m[1][1] + m[2][2] + m[3][3]
    # Sum of principal 2x2 minors: each is >= 0 for a PSD matrix, so no catastrophic cancellation.
    e2 = sum(m[i][i] * m[j][j] - m[i][j] * m[i][j] for i in range(4) for j in range(i + 1, 4))
    e3 = adj[0][0] + adj[1][1] + adj[2][2] + adj[3][3]
    denominator = e1 * e2
    return jnp.where(denominator > 0, e3 / jnp.where(denominator > 0, denominator, 1), 0)


def _reprojection(
    projections: Float[Array, "views 3 4"],
    points: Float[Array, "views 2"],
    problem: _DltProblem,
    used: Bool[Array, "views"],
    v: Vector4,
    point: list[Scalar],
) -> tuple[Float[Array, "views"], Scalar]:
    """Per-view reprojection errors (pixels) and the algebraic residual ``|A v|``, 0 where not ``used``.

    Each DLT row times v is ``-row_scale * v_3 * depth_k * (reprojected - observed)`` along its axis,
    so the residual comes from the reprojection offsets (cheaper than ``A v``: the rows need not be
    kept, and no precision is lost as with ``v^T M v``)."""
    homogeneous = point + [jnp.ones_like(point[0])]
    errors, residual_squared = [], 0
    for view in range(projections.shape[0]):
        projected = [_dot([projections[view, r, j] for j in range(4)], homogeneous) for r in range(3)]
        depth = jnp.where(projected[2] != 0, projected[2], 1)
        offsets = [projected[axis] / depth - points[view, axis] for axis in range(2)]
        # Double where: masked views may hold NaN, and sqrt has an infinite gradient at 0.
        squared = jnp.where(used[view], offsets[0] * offsets[0] + offsets[1] * offsets[1], 1)
        errors.append(jnp.where(used[view], jnp.sqrt(squared), 0))
        for axis in range(2):
            algebraic = problem.row_scales[2 * view + axis] * v[3] * depth * offsets[axis]
            residual_squared = residual_squared + jnp.where(used[view], algebraic * algebraic, 0)
    positive = residual_squared > 0
    residual = jnp.where(positive, jnp.sqrt(jnp.where(positive, residual_squared, 1)), 0)
    return jnp.stack(errors), residual


_BASELINE_FLOOR = 1e3
"""Two camera centres closer than this many machine epsilons of their distances from the world origin
count as one (rounding in ``-M^-1 p`` leaves a few epsilons between equal centres)."""


def _camera_geometry(projections: Float[Array, "views 3 4"]) -> tuple[list[Scalar], list[list[Scalar]]]:
    """Per view, ``det M`` (``P = [M | p]``; its sign turns ``P[2] . [X; 1]`` into a depth sign) and the
    camera centre ``-M^-1 p`` by cofactors (element-wise, like the kernels)."""
    dets, centres = [], []
    for view in range(projections.shape[0]):
        m, p = projections[view, :, :3], projections[view, :, 3]
        cofactor = [[m[(i + 1) % 3, (j + 1) % 3] * m[(i + 2) % 3, (j + 2) % 3]
                     - m[(i + 1) % 3, (j + 2) % 3] * m[(i + 2) % 3, (j + 1) % 3] for j in range(3)] for i in range(3)]
        det = m[0, 0] * cofactor[0][0] + m[0, 1] * cofactor[0][1] + m[0, 2] * cofactor[0][2]
        safe = jnp.where(det != 0, det, 1)
        dets.append(det)
        centres.append([-(cofactor[0][j] * p[0] + cofactor[1][j] * p[1] + cofactor[2][j] * p[2]) / safe
                        for j in range(3)])
    return dets, centres


def _geometry_checks(
    projections: Float[Array, "views 3 4"], used: Bool[Array, "views"], v: Vector4
) -> tuple[Bool[Array, ""], Bool[Array, ""]]:
    """``(in_front, baseline)``: positive depth in every used camera (cheirality), and some two used
    cameras with distinct centres. Flags only: the point itself is left as the kernels found it."""
    dets, centres = _camera_geometry(projections)
    views = projections.shape[0]
    in_front = jnp.array(True)
    for view in range(views):
        w = _dot([projections[view, 2, j] for j in range(4)], v)
        in_front = in_front & (~used[view] | (w * v[3] * dets[view] > 0))
    floor = _BASELINE_FLOOR * jnp.finfo(projections.dtype).eps
    baseline = jnp.array(False)
    for a in range(views):
        for b in range(a + 1, views):
            gap = sum((centres[a][i] - centres[b][i]) ** 2 for i in range(3))
            size = sum(centres[a][i] ** 2 + centres[b][i] ** 2 for i in range(3))
            baseline = baseline | (used[a] & used[b] & (gap > floor * floor * size))
    return in_front, baseline


def triangulate_point(
    projections: Float[Array, "views 3 4"],
    points: Float[Array, "views 2"],
    weights: Float[Array, "views"],
    method: Method = "closed_form",
    normalise_rows: bool = False,
    max_distance: float = 1e4,
    require_in_front: bool = True,
) -> Triangulation:
    """Weighted DLT triangulation of ONE point from ``views`` undistorted pixel observations.

    The kernel for ``jax.vmap``; no input checks (use :func:`triangulate` for checked, batched calls).

    Args:
        projections: ``P_k = K_k [R_k | t_k]``, world metres to pixels.
        points: undistorted pixel coordinates; may be NaN where the weight is 0.
        weights: non-negative per-view weights multiplying the DLT rows; 0 masks a view.
        method: ``"closed_form"`` (fast, element-wise) or ``"svd"`` (LAPACK reference).
        normalise_rows: scale each DLT row to unit norm before weighting (OpenCV does not).
        max_distance: points farther than this from the world origin (metres) are reported invalid.
        require_in_front: report a point behind a used camera invalid (default). False keeps it, as the
            purely algebraic DLT of the papers' baselines does (Structural Triangulation's LEM, FLEX's DLT).

    Returns:
        A :class:`Triangulation` without batch dimensions.
    """
    problem = _dlt_problem(projections, points, weights, normalise_rows)
    v = _KERNELS[method](problem)
    conditioning = _conditioning(problem)
    finite = jnp.abs(v[3]) * max_distance > jnp.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    well_posed = conditioning > _CONDITIONING_FLOOR * jnp.finfo(conditioning.dtype).eps
    in_front, baseline = _geometry_checks(projections, weights > 0, v)
    valid = (problem.num_views >= 2) & finite & well_posed & baseline
    if require_in_front:
        valid = valid & in_front
    w = jnp.where(valid, v[3], 1)
    point = [jnp.where(valid, v[i] / w, 0) for i in range(3)]
    reprojection_error, residual = _reprojection(projections, points, problem, valid & (weights > 0), v, point)
    return Triangulation(jnp.stack(point), valid, reprojection_error, residual, conditioning, problem.num_views)


def _is_traced(*arrays: ArrayLike | None) -> bool:
    return any(isinstance(array, jax.core.Tracer) for array in arrays)


def _check_finite(name: str, array: ArrayLike, where: ArrayLike | None = None) -> None:
    bad = ~np.isfinite(np.asarray(array))
    if where is not None:
        bad &= np.asarray(where)
    if bad.any():
        index = tuple(int(i) for i in np.argwhere(bad)[0])
        raise ValueError(f"{name} contains NaN or inf (first at index {index})")


@jax.jit
def _has_bad_values(
    projections: Float[Array, "views 3 4"],
    points: Float[Array, "*batch views 2"],
    weights: Float[Array, "*batch views"] | None,
) -> Bool[Array, ""]:
    if weights is None:
        return ~jnp.all(jnp.isfinite(projections)) | ~jnp.all(jnp.isfinite(points))
    weighted = weights[..., None] > 0
    return (
        ~jnp.all(jnp.isfinite(projections))
        | ~jnp.all(jnp.isfinite(weights) & (weights >= 0))
        | jnp.any(weighted & ~jnp.isfinite(points))
    )


def _check_inputs(projections: Array, points: Array, weights: ArrayLike | None, method: str) -> Array | None:
    """Checks shapes and dtypes always (shapes are static under jit) and values when concrete (one
    fused pass on the device; the host search for the culprit runs only on failure). Returns the
    weights as an array (None stays None: the kernel then uses ones)."""
    if method not in _KERNELS:
        raise ValueError(f"method must be one of {sorted(_KERNELS)}, got {method!r}")
    if projections.ndim != 3 or projections.shape[1:] != (3, 4):
        raise ValueError(f"projections must have shape (views, 3, 4), got {projections.shape}")
    views = projections.shape[0]
    if views == 0:
        raise ValueError("projections has no cameras (shape (0, 3, 4)): triangulation needs at least two views")
    if points.ndim < 2 or points.shape[-2:] != (views, 2):
        raise ValueError(f"points must have shape (*batch, {views}, 2) for {views} views, got {points.shape}")
    if weights is not None:
        weights = jnp.asarray(weights)
        if weights.shape != points.shape[:-1]:
            raise ValueError(f"weights must have shape {points.shape[:-1]} (points without the last axis), got {weights.shape}")
    for name, array in (("projections", projections), ("points", points), ("weights", weights)):
        if array is not None and not jnp.issubdtype(array.dtype, jnp.floating):
            raise ValueError(f"{name} must be a floating-point array, got dtype {array.dtype}")
    if _is_traced(projections, points, weights) or not bool(_has_bad_values(projections, points, weights)):
        return weights
    weights_or_ones = np.ones(points.shape[:-1]) if weights is None else np.asarray(weights)
    _check_finite("projections", projections)
    _check_finite("weights", weights_or_ones)
    if bool(np.any(weights_or_ones < 0)):
        raise ValueError("weights must be non-negative (0 masks a view)")
    _check_finite("points (where the weight is positive)", points, weights_or_ones[..., None] > 0)
    raise AssertionError("unreachable: _has_bad_values and the host checks disagree")


@partial(jax.jit, static_argnames=("method", "normalise_rows", "max_distance", "require_in_front"))
def _triangulate_flat(
    projections: Float[Array, "views 3 4"],
    points: Float[Array, "n views 2"],
    weights: Float[Array, "n views"] | None,
    method: Method,
    normalise_rows: bool,
    max_distance: float,
    require_in_front: bool,
) -> Triangulation:
    if weights is None:
        weights = jnp.ones(points.shape[:-1], points.dtype)
    kernel = partial(triangulate_point, method=method, normalise_rows=normalise_rows, max_distance=max_distance,
                     require_in_front=require_in_front)
    return jax.vmap(kernel, in_axes=(None, 0, 0))(projections, points, weights)


def _flatten(array: Array, tail: tuple[int, ...]) -> Array:
    # Eager reshapes are dispatched ops: skip them when the batch is already one axis.
    return array if array.ndim == len(tail) + 1 else array.reshape((-1,) + tail)


def _unflatten(result: Triangulation, batch: tuple[int, ...]) -> Triangulation:
    if len(batch) == 1:
        return result
    return jax.tree.map(lambda leaf: leaf.reshape(batch + leaf.shape[1:]), result)


def triangulate(
    projections: Float[ArrayLike, "views 3 4"],
    points: Float[ArrayLike, "*batch views 2"],
    weights: Float[ArrayLike, "*batch views"] | None = None,
    *,
    method: Method = "closed_form",
    normalise_rows: bool = False,
    max_distance: float = 1e4,
    require_in_front: bool = True,
) -> Triangulation:
    """Triangulate points with any leading batch dimensions (points, joints, frames) from shared cameras.

    The batch is flattened before the jitted kernel, so any batch shape with the same number of
    points reuses one compilation.

    Args:
        projections: ``P_k = K_k [R_k | t_k]`` of the ``views`` cameras (world metres to pixels).
        points: undistorted pixels, ``(*batch, views, 2)``; NaN is allowed where the weight is 0
            (missing detections).
        weights: ``(*batch, views)``, non-negative, multiplying each view's DLT rows; 0 masks a view.
            Default: all ones (two views then give exactly ``cv2.triangulatePoints``).
        method: ``"closed_form"`` (fast, element-wise; default) or ``"svd"`` (LAPACK reference).
        normalise_rows: scale each DLT row to unit norm before weighting (OpenCV does not).
        max_distance: points farther than this from the world origin (metres) are reported invalid.
        require_in_front: report a point behind a used camera invalid (default). False keeps it, as the
            purely algebraic DLT of the papers' baselines does (Structural Triangulation's LEM, FLEX's DLT).

    Returns:
        A :class:`Triangulation` whose leaves have the leading shape ``batch``.

    Raises:
        ValueError: on wrong shapes or dtypes, no cameras, an unknown method, negative weights, or NaN/inf in the
            projections, the weights or a positively weighted point (value checks are skipped when
            called on traced values inside ``jax.jit``; shape checks always run).
    """
    projections, points = jnp.asarray(projections), jnp.asarray(points)
    weights = _check_inputs(projections, points, weights, method)
    views = projections.shape[0]
    flat = _triangulate_flat(
        projections, _flatten(points, (views, 2)), None if weights is None else _flatten(weights, (views,)), method,
        normalise_rows, float(max_distance), bool(require_in_front)
    )
    return _unflatten(flat, points.shape[:-2])


@partial(jax.jit, static_argnames=("method", "normalise_rows", "max_distance", "require_in_front"))
def _triangulate_pixels_flat(
    rig: Camera,
    pixels: Float[Array, "n views 2"],
    weights: Float[Array, "n views"] | None,
    method: Method,
    normalise_rows: bool,
    max_distance: float,
    require_in_front: bool,
) -> Triangulation:
    by_view = jnp.moveaxis(pixels, 1, 0)
    undistorted = jax.vmap(partial(undistort_points, output="pixels"))(rig, by_view)
    return _triangulate_flat(
        projection_matrix(rig), jnp.moveaxis(undistorted, 0, 1), weights, method, normalise_rows, max_distance,
        require_in_front
    )


def triangulate_pixels(
    rig: Camera,
    pixels: Float[ArrayLike, "*batch views 2"],
    weights: Float[ArrayLike, "*batch views"] | None = None,
    *,
    method: Method = "closed_form",
    normalise_rows: bool = False,
    max_distance: float = 1e4,
    require_in_front: bool = True,
) -> Triangulation:
    """Like :func:`triangulate`, from a stacked ``Camera`` rig and observed (distorted) pixels.

    The pixels are undistorted with :func:`geometry.undistort_points` and triangulated with
    ``P = K [R | t]`` of each camera; arguments and result as in :func:`triangulate`.
    """
    if rig.K.ndim != 3:
        raise ValueError(f"rig must be a stacked Camera with leaves (views, ...), got K of shape {rig.K.shape}")
    pixels = jnp.asarray(pixels)
    weights = _check_inputs(projection_matrix(rig), pixels, weights, method)
    views = rig.K.shape[0]
    flat = _triangulate_pixels_flat(
        rig, _flatten(pixels, (views, 2)), None if weights is None else _flatten(weights, (views,)), method,
        normalise_rows, float(max_distance), bool(require_in_front)
    )
    return _unflatten(flat, pixels.shape[:-2])

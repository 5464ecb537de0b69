"""Structural Triangulation (Chen, Zhao, Wan, ECCV 2022) and its baselines, batched and jit-compiled.

The cost is the algebraic reprojection error of the official code (``M_ik = w_ik S^T S``, weights w, not
w^2), written per joint as ``1/2 x_i^T D_i x_i - m_i^T x_i``. In bone coordinates ``b`` (``b_k`` =
child minus parent of ``skeleton.bones[k]``) with the root eliminated, it becomes
``1/2 b^T A b - beta^T b``, ``A = (GQ)^T D (GQ)``, ``beta = (GQ)^T m``; the constraint is
``|b_k| = L_k``.

Why the fast path never forms or inverts A: A is the Schur complement of the block-diagonal joint
Hessian expressed in tree coordinates, so its inverse is the bone block of ``G^-1 D^-1 G^-T``, i.e.
``A^-1 = C^T blockdiag(D_i^-1) C`` with C the joint-by-bone incidence matrix (+1 at the child, -1 at
the parent). Applying ``A^-1`` is then a scatter to joints, seventeen 3x3 products and a gather of bone
differences. SCA's accumulated first-order update ``T^i = T^(i-1) - 2 T^(i-1) Lambda_i T^(i-1)`` is
applied matrix-free by recursion (``2^i`` applications of ``A^-1`` at step i), which for the paper's
``n_steps <= 9`` costs less than the dense ``(3n)^3`` products. ``A`` and ``beta`` themselves are built
only where a method needs them (the exact-SCA variant, the Lagrangian baseline, the objective).

Units: pixels for 2D points, any length unit for 3D (the project uses metres); ``bone_lengths`` in that
unit. A is singular iff some joint's rays are all parallel (fewer than two usable views), which the
solver detects per joint and reports through :class:`Status`.
"""

from __future__ import annotations

import enum
import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from geometry import H36M17, Camera, Skeleton, projection_matrix, triangulate_point

__all__ = [
    "Status",
    "StructriResult",
    "structural_triangulation",
    "ls_triangulation",
    "lem_triangulation",
    "lagrangian_triangulation",
    "estimate_bone_lengths",
    "reduced_problem",
    "projection_matrices",
]


class Status(enum.IntEnum):
    """Per-frame outcome codes of :func:`structural_triangulation` (``StructriResult.status``)."""

    OK = 0
    """The requested method ran as specified and its output is finite."""
    SINGLE_STEP = 1
    """Near-degenerate rays (some joint's reciprocal condition below ``degenerate_rcond``, e.g. two
    opposite cameras on a line through the joint): SCA was replaced by one ST step, as the official code
    does for its two-camera ring, because the multi-step update is singular there."""
    FALLBACK_LS = 2
    """The constrained update produced a non-finite or non-solvable multiplier system; the returned
    pose is the unconstrained least-squares solution (LS, ``b0``)."""
    UNDERDETERMINED = 3
    """Some joint has fewer than two independent rays (zero confidences or parallel rays), so A is
    singular: the pose is regularised LS (a tiny Tikhonov term per joint); an unobserved joint lands at
    the point of its ray nearest the world origin (the origin itself when no view sees it)."""


class StructriResult(NamedTuple):
    """Output of the solvers; every leaf has the input's leading frame axes."""

    pose: Float[Array, "*frames joints 3"]
    """Joint positions, same length unit as ``bone_lengths`` / the projection matrices."""
    bones: Float[Array, "*frames bones 3"]
    """Bone vectors in ``skeleton.bones`` order (child minus parent)."""
    status: Int[Array, "*frames"]
    """A :class:`Status` code per frame."""
    multipliers: Float[Array, "*frames bones"]
    """Lagrange multipliers: the accumulated ``sum_i lambda_i`` of SCA (zero for LS/LEM)."""


# ----------------------------------------------------------------------------------------------
# Skeleton structure as static arrays.


class _Tree(NamedTuple):
    root: int
    parent: np.ndarray  # (n,) parent joint of each bone
    child: np.ndarray  # (n,) child joint of each bone
    incidence: np.ndarray  # (J, n): +1 at the child, -1 at the parent
    path: np.ndarray  # (J, n): 1 where bone k lies on the path root -> joint j


@functools.cache
def _tree(skeleton: Skeleton) -> _Tree:
    if not isinstance(skeleton, Skeleton):
        raise TypeError(f"skeleton must be a geometry.Skeleton, got {type(skeleton).__name__}")
    order = skeleton.topological_order  # raises for a cycle or a disconnected joint set
    num_joints, bones = skeleton.num_joints, skeleton.bones
    if len(bones) != num_joints - 1 or len(order) != num_joints:
        raise ValueError(f"{skeleton.name}: parents do not form a tree")
    parent = np.array([p for p, _ in bones])
    child = np.array([c for _, c in bones])
    incidence = np.zeros((num_joints, len(bones)))
    incidence[child, np.arange(len(bones))] = 1.0
    incidence[parent, np.arange(len(bones))] = -1.0
    bone_of_child = {c: k for k, (_, c) in enumerate(bones)}
    path = np.zeros((num_joints, len(bones)))
    for j in order:
        if j != skeleton.root:
            p = skeleton.parents[j]
            path[j] = path[p]
            path[j, bone_of_child[j]] = 1.0
    return _Tree(skeleton.root, parent, child, incidence, path)


# ----------------------------------------------------------------------------------------------
# Per-frame kernels.


def _quadratic_form(
    points_2d: Float[Array, "views joints 2"],
    projections: Float[Array, "views 3 4"],
    weights: Float[Array, "views joints"],
) -> tuple[Float[Array, "joints 3 3"], Float[Array, "joints 3"]]:
    """``D_i = 2 sum_k P3^T M_ik P3`` and ``m_i = -2 sum_k P3^T M_ik t_k`` with ``M = w S^T S``."""
    # S P_k = [P0 - u P2; P1 - v P2]: each row r gives the residual r . [x; 1].
    rows = projections[:, None, :2, :] - points_2d[..., None] * projections[:, None, 2:3, :]  # (V,J,2,4)
    w = 2.0 * weights[..., None, None]
    D = jnp.sum(w[..., None] * rows[..., :3, None] * rows[..., None, :3], axis=(0, 2))
    m = -jnp.sum(w * rows[..., :3] * rows[..., 3:], axis=(0, 2))
    return D, m


def _inverse_3x3(D: Float[Array, "*n 3 3"]) -> tuple[Float[Array, "*n 3 3"], Float[Array, "*n"]]:
    """Inverse of symmetric PSD 3x3 blocks by the adjugate, and a reciprocal-condition estimate.

    ``det / (e2 * trace)`` (e2 the sum of principal 2x2 minors) lies within a factor 9 of
    ``lambda_min / lambda_max``; non-finite or non-positive values give 0."""
    a, b, c = D[..., 0, 0], D[..., 0, 1], D[..., 0, 2]
    d, e, f = D[..., 1, 1], D[..., 1, 2], D[..., 2, 2]
    c00, c01, c02 = d * f - e * e, c * e - b * f, b * e - c * d
    c11, c12, c22 = a * f - c * c, b * c - a * e, a * d - b * b
    det = a * c00 + b * c01 + c * c02
    adj = jnp.stack([jnp.stack([c00, c01, c02], -1), jnp.stack([c01, c11, c12], -1),
                     jnp.stack([c02, c12, c22], -1)], -2)
    e2, trace = c00 + c11 + c22, a + d + f
    rcond = det / (e2 * trace)
    rcond = jnp.where(jnp.isfinite(rcond) & (rcond > 0), rcond, 0.0)
    return adj / det[..., None, None], rcond


def _matvec3(M: Float[Array, "*n 3 3"], v: Float[Array, "*n 3"]) -> Float[Array, "*n 3"]:
    return jnp.sum(M * v[..., None, :], axis=-1)


def _apply_a_inverse(tree: _Tree, D_inv: Float[Array, "joints 3 3"], v: Float[Array, "bones 3 *cols"]):
    """``A^-1 v = C^T blockdiag(D_i^-1) C v`` (see the module docstring), ``v`` of shape (n, 3, ...)."""
    at_joints = jnp.tensordot(jnp.asarray(tree.incidence, v.dtype), v, axes=1)
    z = jnp.sum(D_inv.reshape(D_inv.shape + (1,) * (v.ndim - 2)) * at_joints[:, None], axis=2)
    return z[tree.child] - z[tree.parent]


def _pose_from_bones(tree: _Tree, D, m, bones: Float[Array, "bones 3"]) -> Float[Array, "joints 3"]:
    """Joints from bones with the optimal root ``x0 = (sum D_i)^-1 (sum m_i - sum D_i r_i(b))``."""
    relative = jnp.asarray(tree.path, bones.dtype) @ bones
    S_inv, _ = _inverse_3x3(jnp.sum(D, axis=0))
    rhs = jnp.sum(m, axis=0) - jnp.sum(_matvec3(D, relative), axis=0)
    return _matvec3(S_inv, rhs)[None] + relative


def _target_sq(bones, lengths, step: int, n_steps: int, schedule: str):
    """Squared target lengths ``L^(i)`` of SCA step i (1-based): the code interpolates lengths,
    the paper (Eq. 16) squared lengths; both reach ``lengths`` at the last step."""
    real_sq = jnp.sum(bones**2, axis=-1)
    remaining = n_steps - step
    if schedule == "length":
        return ((remaining * jnp.sqrt(real_sq) + lengths) / (remaining + 1)) ** 2
    return (remaining * real_sq + lengths**2) / (remaining + 1)


def _sca_first_order(tree, D_inv, b0, lengths, n_steps: int, schedule: str):
    """Algorithm 1 with the code's ``T^(i-1)`` in the multiplier system; returns (b, sum lambda, ok)."""
    lambdas: list = []

    def apply_T(level: int, v):
        if level == 0:
            return _apply_a_inverse(tree, D_inv, v)
        u = apply_T(level - 1, v)
        scale = lambdas[level - 1].reshape((-1, 1) + (1,) * (v.ndim - 2))
        return u - 2.0 * apply_T(level - 1, scale * u)

    n = b0.shape[0]
    b, solvable = b0, jnp.array(True)
    for step in range(1, n_steps + 1):
        rhs = jnp.sum(b**2, axis=-1) - _target_sq(b, lengths, step, n_steps, schedule)
        columns = b[:, :, None] * jnp.eye(n, dtype=b.dtype)[:, None, :]  # diag(b) D31, (n, 3, n)
        system = jnp.sum(b[:, :, None] * apply_T(step - 1, columns), axis=1)
        lam = jnp.linalg.solve(system, rhs) / 4.0
        solvable &= jnp.all(jnp.isfinite(lam))
        b = b - 2.0 * apply_T(step - 1, lam[:, None] * b)
        lambdas.append(lam)
    return b, sum(lambdas), solvable


def _sca_exact(A, beta, b0, lengths, n_steps: int, schedule: str, newton_iterations: int = 2):
    """SCA re-solving ``(A + 2 Lambda_total)`` instead of the first-order update.

    The ST multiplier system is one Newton step on ``h(b(lambda)) = L^(i)`` (its matrix is the
    Jacobian up to -4); here each step takes ``newton_iterations`` of them with the exact
    ``b(lambda) = (A + 2 Lambda)^-1 beta``, so the constraints are met to second order."""
    n = b0.shape[0]
    total = jnp.zeros(n, b0.dtype)
    b, solvable = b0, jnp.array(True)
    for step in range(1, n_steps + 1):
        target = _target_sq(b, lengths, step, n_steps, schedule)
        for _ in range(newton_iterations):
            H = A + 2.0 * jnp.diag(jnp.repeat(total, 3))
            T = jnp.linalg.solve(H, jnp.eye(3 * n, dtype=b0.dtype)).reshape(n, 3, n, 3)
            system = jnp.einsum("ka,kalc,lc->kl", b, T, b)
            lam = jnp.linalg.solve(system, jnp.sum(b**2, axis=-1) - target) / 4.0
            solvable &= jnp.all(jnp.isfinite(lam))
            total = total + lam
            b = jnp.linalg.solve(A + 2.0 * jnp.diag(jnp.repeat(total, 3)), beta).reshape(n, 3)
    return b, total, solvable


def reduced_problem(
    points_2d: Float[ArrayLike, "views joints 2"],
    projections: Float[ArrayLike, "views 3 4"],
    skeleton: Skeleton = H36M17,
    confidences: Float[ArrayLike, "views joints"] | None = None,
) -> tuple[Float[Array, "dim dim"], Float[Array, "dim"]]:
    """``A = (GQ)^T D (GQ)`` and ``beta = (GQ)^T m`` of one frame (paper Eq. 8), dense.

    ``GQ`` maps bones to joints with the optimal root: ``X_i = r_i(b) - (sum D)^-1 sum_j D_j r_j(b)``
    (the constant ``p`` term of the official code drops out of beta, see the reference notes)."""
    points_2d, projections = jnp.asarray(points_2d), jnp.asarray(projections)
    weights = _default_weights(points_2d.shape[0], points_2d.shape[1], confidences, points_2d.dtype)
    D, m = _quadratic_form(points_2d, projections, weights)
    return _reduced_from_quadratic(_tree(skeleton), D, m)


def _reduced_from_quadratic(tree, D, m):
    num_joints, n = tree.path.shape
    path = jnp.asarray(tree.path, D.dtype)
    lifted = path[:, None, :, None] * jnp.eye(3, dtype=D.dtype)[None, :, None, :]  # (J,3,n,3)
    S_inv, _ = _inverse_3x3(jnp.sum(D, axis=0))
    subtree = jnp.einsum("jab,jbkc->akc", D, lifted)
    GQ = (lifted - jnp.einsum("ab,bkc->akc", S_inv, subtree)[None]).reshape(num_joints, 3, 3 * n)
    A = jnp.einsum("jak,jab,jbl->kl", GQ, D, GQ)
    beta = jnp.einsum("jak,ja->k", GQ, m)
    return 0.5 * (A + A.T), beta


def _default_weights(views, num_joints, confidences, dtype):
    if confidences is None:
        return jnp.full((views, num_joints), 1.0 / views, dtype)
    return jnp.asarray(confidences, dtype)


def _frame(points_2d, projections, lengths, weights, *, skeleton, method, n_steps, schedule,
           degenerate_rcond, lagrangian):
    tree = _tree(skeleton)
    D, m = _quadratic_form(points_2d, projections, weights)
    D_inv, rcond = _inverse_3x3(D)
    min_rcond = jnp.min(rcond)
    underdetermined = ~(min_rcond > 1e-12)

    # Regularised LS: exact LS where D_i is well conditioned, finite where it is not.
    scale = jnp.trace(jnp.sum(D, axis=0)) / (3.0 * D.shape[0])
    D_reg_inv, _ = _inverse_3x3(D + 1e-12 * scale * jnp.eye(3, dtype=D.dtype)[None])
    ls_pose = _matvec3(jnp.where(underdetermined, D_reg_inv, D_inv), m)
    ls_bones = ls_pose[tree.child] - ls_pose[tree.parent]
    n = ls_bones.shape[0]
    zeros = jnp.zeros(n, D.dtype)

    if method == "ls":
        status = jnp.where(underdetermined, Status.UNDERDETERMINED, Status.OK)
        return StructriResult(ls_pose, ls_bones, status, zeros)

    b0 = ls_bones
    if method == "st":
        b, lam, solvable = _sca_first_order(tree, D_inv, b0, lengths, n_steps, schedule)
        if n_steps > 1:
            b1, lam1, solvable1 = _sca_first_order(tree, D_inv, b0, lengths, 1, schedule)
            single = min_rcond < degenerate_rcond
            b, lam, solvable = (jnp.where(single, b1, b), jnp.where(single, lam1, lam),
                                jnp.where(single, solvable1, solvable))
        else:
            single = jnp.array(False)
    elif method == "st_exact":
        A, beta = _reduced_from_quadratic(tree, D, m)
        b, lam, solvable = _sca_exact(A, beta, b0, lengths, n_steps, schedule)
        single = jnp.array(False)
    else:  # lagrangian
        A, beta = _reduced_from_quadratic(tree, D, m)
        b, lam = _lagrangian(A, beta, b0, lengths, **lagrangian)
        solvable, single = jnp.array(True), jnp.array(False)

    pose = _pose_from_bones(tree, D, m, b)
    finite = solvable & jnp.all(jnp.isfinite(pose)) & jnp.all(jnp.isfinite(lam))
    status = jnp.where(underdetermined, Status.UNDERDETERMINED,
                       jnp.where(~finite, Status.FALLBACK_LS,
                                 jnp.where(single, Status.SINGLE_STEP, Status.OK)))
    use_ls = status >= Status.FALLBACK_LS
    return StructriResult(jnp.where(use_ls, ls_pose, pose), jnp.where(use_ls, ls_bones, b),
                          status.astype(jnp.int32), jnp.where(use_ls, zeros, lam))


def _lagrangian(A, beta, b0, lengths, *, n_iterations, step, dual_step, millimetres_per_unit):
    """The official primal-dual gradient iteration, run in millimetres as its step sizes assume.

    The algebraic cost is depth-weighted, so in another unit ``A`` is unchanged, ``beta`` and the
    bones scale with the unit and the cost with its square; the multipliers are unit-free."""
    s = millimetres_per_unit
    beta_mm, L_mm = beta * s, lengths * s
    n = b0.shape[0]

    def body(_, state):
        b, lam = state
        grad = A @ b - beta_mm + 2.0 * jnp.repeat(lam, 3) * b
        violation = jnp.sum(b.reshape(n, 3) ** 2, axis=1) - L_mm**2
        return b - step * grad, lam + dual_step * violation

    b, lam = jax.lax.fori_loop(0, n_iterations, body, (b0.reshape(-1) * s, jnp.zeros(n, A.dtype)))
    return b.reshape(n, 3) / s, lam


# ----------------------------------------------------------------------------------------------
# Public batched API.


def projection_matrices(cameras: Camera | Float[ArrayLike, "views 3 4"]) -> Float[Array, "views 3 4"]:
    """``K [R | t]`` per camera of a rig (undistorted pinhole; a rig with distortion is refused)."""
    if isinstance(cameras, Camera):
        if cameras.K.ndim != 3:
            raise ValueError(f"expected a rig with a leading views axis, got K of shape {cameras.K.shape}")
        if not isinstance(cameras.dist, jax.core.Tracer) and np.any(np.asarray(cameras.dist) != 0):
            raise ValueError("Structural Triangulation uses linear projections: undistort the 2D points "
                             "and pass a rig with zero distortion (or the 3x4 matrices)")
        return projection_matrix(cameras)
    P = jnp.asarray(cameras)
    if P.shape[-2:] != (3, 4):
        raise ValueError(f"projections must have shape (views, 3, 4), got {P.shape}")
    return P


def _prepare(points_2d, cameras, bone_lengths, skeleton, confidences):
    tree = _tree(skeleton)
    points_2d = jnp.asarray(points_2d)
    if not jnp.issubdtype(points_2d.dtype, jnp.floating):
        points_2d = points_2d.astype(float)
    P = projection_matrices(cameras).astype(points_2d.dtype)
    num_joints, n = tree.path.shape
    if points_2d.ndim < 3 or points_2d.shape[-1] != 2 or points_2d.shape[-2] != num_joints:
        raise ValueError(f"points_2d must have shape (*frames, views, {num_joints}, 2) for "
                         f"{skeleton.name}, got {points_2d.shape}")
    frames, views = points_2d.shape[:-3], points_2d.shape[-3]
    if views < 2:
        raise ValueError(f"need at least 2 views, got {views}")
    if P.shape[-3:] != (views, 3, 4) or P.shape[:-3] not in ((), frames):
        raise ValueError(f"projections have shape {P.shape}; expected ({views}, 3, 4) or "
                         f"{frames + (views, 3, 4)} to match points_2d {points_2d.shape}")
    lengths = jnp.asarray(bone_lengths, points_2d.dtype)
    if lengths.shape[-1:] != (n,) or lengths.shape[:-1] not in ((), frames):
        raise ValueError(f"bone_lengths must have shape ({n},) (one per {skeleton.name} bone, in "
                         f"skeleton.bones order) or {frames + (n,)}, got {lengths.shape}")
    if confidences is None:
        weights = jnp.full(points_2d.shape[:-1], 1.0 / views, points_2d.dtype)
    else:
        weights = jnp.asarray(confidences, points_2d.dtype)
        if weights.shape != points_2d.shape[:-1]:
            raise ValueError(f"confidences must have shape {points_2d.shape[:-1]} (like points_2d "
                             f"without the last axis), got {weights.shape}")
    flat = int(np.prod(frames, dtype=int))
    args = (points_2d.reshape(flat, views, num_joints, 2),
            P.reshape((flat,) * (P.ndim > 3) + (views, 3, 4)),
            lengths.reshape((flat,) * (lengths.ndim > 1) + (n,)),
            weights.reshape(flat, views, num_joints))
    axes = (0, 0 if P.ndim > 3 else None, 0 if lengths.ndim > 1 else None, 0)
    return frames, args, axes


@functools.partial(jax.jit, static_argnames=("axes", "skeleton", "method", "n_steps", "schedule",
                                              "degenerate_rcond", "lagrangian"))
def _solve_flat(points_2d, P, lengths, weights, *, axes, skeleton, method, n_steps, schedule,
                degenerate_rcond, lagrangian):
    kernel = functools.partial(_frame, skeleton=skeleton, method=method, n_steps=n_steps,
                               schedule=schedule, degenerate_rcond=degenerate_rcond,
                               lagrangian=dict(lagrangian) if lagrangian else None)
    return jax.vmap(kernel, in_axes=axes)(points_2d, P, lengths, weights)


def _solve(points_2d, cameras, bone_lengths, skeleton, confidences, method, n_steps=1,
           schedule="length", degenerate_rcond=0.0, lagrangian=()):
    frames, args, axes = _prepare(points_2d, cameras, bone_lengths, skeleton, confidences)
    out = _solve_flat(*args, axes=axes, skeleton=skeleton, method=method, n_steps=n_steps,
                      schedule=schedule, degenerate_rcond=degenerate_rcond, lagrangian=lagrangian)
    return jax.tree.map(lambda x: x.reshape(frames + x.shape[1:]), out)


def structural_triangulation(
    points_2d: Float[ArrayLike, "*frames views joints 2"],
    cameras: Camera | Float[ArrayLike, "*pframes views 3 4"],
    bone_lengths: Float[ArrayLike, "*lframes bones"],
    skeleton: Skeleton = H36M17,
    confidences: Float[ArrayLike, "*frames views joints"] | None = None,
    n_steps: int = 3,
    *,
    schedule: str = "length",
    update: str = "first_order",
    degenerate_rcond: float = 1e-3,
) -> StructriResult:
    """Structural Triangulation with the Step Constraint Algorithm (paper Alg. 1, official code).

    Args:
        points_2d: detections in pixels, ``(views, J, 2)`` for one frame or with leading frame axes.
        cameras: a :class:`geometry.Camera` rig without distortion, or projection matrices
            ``(views, 3, 4)`` (shared) or ``(*frames, views, 3, 4)``.
        bone_lengths: target lengths in ``skeleton.bones`` order, shared or per frame.
        skeleton: any tree; bones are ``skeleton.bones`` (child-index order).
        confidences: weights w per view and joint (default ``1/views``); a zero weight drops a view.
        n_steps: SCA steps N (1 = plain ST). The first-order path traces ``2^N`` applications of
            ``A^-1`` per step, so compile time grows with N (the paper uses N <= 9).
        schedule: ``"length"`` interpolates lengths (official code, default) or ``"squared"`` squared
            lengths (paper Eq. 16).
        update: ``"first_order"`` (Alg. 1's accumulated ``T^i``) or ``"exact"`` (re-solves
            ``A + 2 Lambda`` each step; dense, slower).
        degenerate_rcond: frames whose worst joint has a reciprocal condition number (of its 3x3
            block D_i) below this run a single ST step (:attr:`Status.SINGLE_STEP`); 0 disables it.

    Returns:
        :class:`StructriResult` with ``pose (*frames, J, 3)``, ``bones``, ``status``, ``multipliers``.
    """
    if schedule not in ("length", "squared"):
        raise ValueError(f"schedule must be 'length' or 'squared', got {schedule!r}")
    if update not in ("first_order", "exact"):
        raise ValueError(f"update must be 'first_order' or 'exact', got {update!r}")
    if int(n_steps) < 1:
        raise ValueError(f"n_steps must be >= 1, got {n_steps}")
    method = "st" if update == "first_order" else "st_exact"
    return _solve(points_2d, cameras, bone_lengths, skeleton, confidences, method, int(n_steps),
                  schedule, float(degenerate_rcond))


def ls_triangulation(
    points_2d: Float[ArrayLike, "*frames views joints 2"],
    cameras: Camera | Float[ArrayLike, "*pframes views 3 4"],
    skeleton: Skeleton = H36M17,
    confidences: Float[ArrayLike, "*frames views joints"] | None = None,
) -> StructriResult:
    """Unconstrained weighted linear least squares (the paper's LS, ``b0 = A^-1 beta``), per joint."""
    n = skeleton.num_joints - 1
    return _solve(points_2d, cameras, np.ones(n), skeleton, confidences, "ls")


def lagrangian_triangulation(
    points_2d: Float[ArrayLike, "*frames views joints 2"],
    cameras: Camera | Float[ArrayLike, "*pframes views 3 4"],
    bone_lengths: Float[ArrayLike, "*lframes bones"],
    skeleton: Skeleton = H36M17,
    confidences: Float[ArrayLike, "*frames views joints"] | None = None,
    n_iterations: int = 200,
    *,
    step: float = 2e-9,
    dual_step: float = 0.5,
    millimetres_per_unit: float = 1000.0,
) -> StructriResult:
    """The paper's Lagrangian baseline: primal-dual gradient from ``b0`` with ``lambda = 0``.

    ``step`` and ``dual_step`` are the official values, which assume millimetres and pixels; inputs in
    another unit are rescaled by ``millimetres_per_unit`` (1000 for metres) so the iteration is the same.
    It can diverge (non-finite output is reported as :attr:`Status.FALLBACK_LS`)."""
    options = (("n_iterations", int(n_iterations)), ("step", float(step)), ("dual_step", float(dual_step)),
               ("millimetres_per_unit", float(millimetres_per_unit)))
    return _solve(points_2d, cameras, bone_lengths, skeleton, confidences, "lagrangian", lagrangian=options)


# ----------------------------------------------------------------------------------------------
# LEM: homogeneous DLT per joint, rows multiplied by w, no normalisation (geometry.triangulate_point).


def lem_triangulation(
    points_2d: Float[ArrayLike, "*frames views joints 2"],
    cameras: Camera | Float[ArrayLike, "*pframes views 3 4"],
    skeleton: Skeleton = H36M17,
    confidences: Float[ArrayLike, "*frames views joints"] | None = None,
) -> StructriResult:
    """Linear eigen method (homogeneous DLT per joint, :func:`geometry.triangulate_point`) as in the
    official ``utils.py``: rows multiplied by w (squared residuals weighted by w^2), not normalised.

    A joint whose DLT is not determined (``valid`` False) gets the regularised LS point and
    :attr:`Status.UNDERDETERMINED` for its frame."""
    frames, args, axes = _prepare(points_2d, cameras, np.ones(skeleton.num_joints - 1), skeleton, confidences)
    return jax.tree.map(lambda x: x.reshape(frames + x.shape[1:]),
                        _lem_flat(*args, axes=axes, skeleton=skeleton))


@functools.partial(jax.jit, static_argnames=("axes", "skeleton"))
def _lem_flat(points_2d, P, lengths, weights, *, axes, skeleton):
    tree = _tree(skeleton)

    def frame(points_2d, P, weights):
        dlt = jax.vmap(triangulate_point, in_axes=(None, 1, 1))(P, points_2d, weights)
        pose, ok = dlt.point, dlt.valid
        ls = _frame(points_2d, P, None, weights, skeleton=skeleton, method="ls", n_steps=1,
                    schedule="length", degenerate_rcond=0.0, lagrangian=None)
        pose = jnp.where(ok[:, None], pose, ls.pose)
        status = jnp.where(jnp.all(ok), Status.OK, Status.UNDERDETERMINED).astype(jnp.int32)
        bones = pose[tree.child] - pose[tree.parent]
        return StructriResult(pose, bones, status, jnp.zeros(bones.shape[0], pose.dtype))

    return jax.vmap(frame, in_axes=(axes[0], axes[1], axes[3]))(points_2d, P, weights)


# ----------------------------------------------------------------------------------------------
# Bone lengths.


def estimate_bone_lengths(
    points_2d: Float[ArrayLike, "frames views joints 2"],
    cameras: Camera | Float[ArrayLike, "views 3 4"],
    skeleton: Skeleton = H36M17,
    confidences: Float[ArrayLike, "frames views joints"] | None = None,
    frames: ArrayLike | None = None,
    symmetric: bool = True,
) -> Float[Array, "bones"]:
    """The paper's ST* lengths: mean ``|b0_k|`` (LS bones) over the chosen (T-pose-like) frames.

    ``frames`` selects frame indices (default all). With ``symmetric``, each left bone and its right
    counterpart (``skeleton.mirror`` of the child joint) get their average."""
    points_2d = jnp.asarray(points_2d)
    if points_2d.ndim != 4:
        raise ValueError(f"points_2d must have shape (frames, views, joints, 2), got {points_2d.shape}")
    if frames is not None:
        index = jnp.asarray(frames)
        points_2d = points_2d[index]
        confidences = None if confidences is None else jnp.asarray(confidences)[index]
    ls = ls_triangulation(points_2d, cameras, skeleton, confidences)
    usable = ls.status == Status.OK
    lengths = jnp.linalg.norm(ls.bones, axis=-1)
    mean = jnp.sum(jnp.where(usable[:, None], lengths, 0.0), axis=0) / jnp.maximum(jnp.sum(usable), 1)
    if not symmetric:
        return mean
    tree = _tree(skeleton)
    bone_of_child = {int(c): k for k, c in enumerate(tree.child)}
    mirror_bone = np.array([bone_of_child[skeleton.mirror[int(c)]] for c in tree.child])
    return 0.5 * (mean + mean[mirror_bone])

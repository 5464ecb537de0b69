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
applied matrix-free (``2^(i-1)`` applications of ``A^-1`` at step i: straight-line code for the paper's
default N = 3, a loop whose traced graph is linear in the number of steps beyond), which for the paper's
``n_steps <= 9`` costs less than carrying the dense ``(3n)^3`` products. ``A`` and ``beta`` themselves are built only where a method
needs them (the exact-SCA variant, the Lagrangian baseline, the objective).

The batched path is frames-last: frames are cut into chunks, and within a chunk every array carries
the frames on its last axis, so the 3x3 inverses (adjugates) and the bones x bones multiplier systems
(unrolled elimination) are element-wise arithmetic without LAPACK calls.

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

from geometry import STRUCTRI17, Camera, Skeleton, projection_matrix, triangulate_point

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
    """The constrained update produced a non-finite or non-solvable multiplier system, or bones far from
    their target lengths (``max_length_error``); the returned pose is the unconstrained least-squares solution
    (LS, ``b0``)."""
    UNDERDETERMINED = 3
    """Some joint has fewer than two independent rays (zero confidences or parallel rays), so A is
    singular: the pose is regularised LS (a tiny Tikhonov term per joint); an unobserved joint lands at
    the point of its ray nearest the world origin (the origin itself when no view sees it, so a frame
    whose confidences are all zero returns every joint at the origin, never NaN)."""


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
    path: np.ndarray  # (J, n): 1 where bone k lies on the path root -> joint j
    joint_bones: np.ndarray  # (J, deg): bones touching joint j, padded with n (no bone)
    joint_signs: np.ndarray  # (J, deg): +1 where j is the bone's child, -1 its parent, 0 padding
    via_child: np.ndarray  # (n, n): [child k == child l] - [parent k == child l]
    via_parent: np.ndarray  # (n, n): [parent k == parent l] - [child k == parent l]


@functools.cache
def _tree(skeleton: Skeleton) -> _Tree:
    if not isinstance(skeleton, Skeleton):
        raise TypeError(f"skeleton must be a geometry.Skeleton, got {type(skeleton).__name__}")
    order = skeleton.topological_order  # raises for a cycle or a disconnected joint set
    num_joints, bones = skeleton.num_joints, skeleton.bones
    if len(bones) != num_joints - 1 or len(order) != num_joints:
        raise ValueError(f"{skeleton.name}: parents do not form a tree")
    n = len(bones)
    parent = np.array([p for p, _ in bones])
    child = np.array([c for _, c in bones])
    touching = [[(k, 1.0) for k in range(n) if child[k] == j] + [(k, -1.0) for k in range(n) if parent[k] == j]
                for j in range(num_joints)]
    degree = max(len(t) for t in touching)
    joint_bones = np.full((num_joints, degree), n)
    joint_signs = np.zeros((num_joints, degree))
    for j, t in enumerate(touching):
        joint_bones[j, :len(t)] = [k for k, _ in t]
        joint_signs[j, :len(t)] = [sign for _, sign in t]
    bone_of_child = {c: k for k, (_, c) in enumerate(bones)}
    path = np.zeros((num_joints, n))
    for j in order:
        if j != skeleton.root:
            p = skeleton.parents[j]
            path[j] = path[p]
            path[j, bone_of_child[j]] = 1.0
    via_child = (child[:, None] == child[None]).astype(float) - (parent[:, None] == child[None])
    via_parent = (parent[:, None] == parent[None]).astype(float) - (child[:, None] == parent[None])
    return _Tree(skeleton.root, parent, child, path, joint_bones, joint_signs, via_child, via_parent)


# ----------------------------------------------------------------------------------------------
# Frames-last kernels.
#
# Every array below carries the frames of one chunk on its LAST axis (``... F``), so the 3x3 and
# bones x bones algebra is element-wise arithmetic on contiguous (F,) rows that XLA fuses into plain
# loops. Batched small ``linalg.solve``/``@`` would lower to LAPACK custom calls or batched
# dot_generals that loop over frames on CPU (15x slower end to end).


def _quadratic_form(
    points_2d: Float[Array, "views joints 2 F"],
    projections: Float[Array, "views 3 4 #F"],
    weights: Float[Array, "views joints F"],
) -> tuple[Float[Array, "joints 3 3 F"], Float[Array, "joints 3 F"]]:
    """``D_i = 2 sum_k P3^T M_ik P3`` and ``m_i = -2 sum_k P3^T M_ik t_k`` with ``M = w S^T S``."""
    # S P_k = [P0 - u P2; P1 - v P2]: each row r gives the residual r . [x; 1].
    rows = projections[:, None, :2] - points_2d[:, :, :, None] * projections[:, None, 2:3]  # (V,J,2,4,F)
    w = 2.0 * weights[:, :, None, None]
    lin = rows[:, :, :, :3]
    D = jnp.sum(w[:, :, :, :, None] * lin[:, :, :, :, None] * lin[:, :, :, None], axis=(0, 2))
    m = -jnp.sum(w * lin * rows[:, :, :, 3:], axis=(0, 2))
    return D, m


def _inverse_3x3(D: Float[Array, "*n 3 3 F"]) -> tuple[Float[Array, "*n 3 3 F"], Float[Array, "*n F"]]:
    """Inverse of symmetric PSD 3x3 blocks by the adjugate, and a reciprocal-condition estimate.

    ``det / (e2 * trace)`` (e2 the sum of principal 2x2 minors) lies within a factor 9 of
    ``lambda_min / lambda_max``; non-finite or non-positive values give 0."""
    a, b, c = D[..., 0, 0, :], D[..., 0, 1, :], D[..., 0, 2, :]
    d, e, f = D[..., 1, 1, :], D[..., 1, 2, :], D[..., 2, 2, :]
    c00, c01, c02 = d * f - e * e, c * e - b * f, b * e - c * d
    c11, c12, c22 = a * f - c * c, b * c - a * e, a * d - b * b
    det = a * c00 + b * c01 + c * c02
    adj = jnp.stack([jnp.stack([c00, c01, c02], -2), jnp.stack([c01, c11, c12], -2),
                     jnp.stack([c02, c12, c22], -2)], -3)
    e2, trace = c00 + c11 + c22, a + d + f
    rcond = det / (e2 * trace)
    rcond = jnp.where(jnp.isfinite(rcond) & (rcond > 0), rcond, 0.0)
    return adj / det[..., None, None, :], rcond


def _matvec3(M: Float[Array, "*n 3 3 F"], v: Float[Array, "*n 3 F"]) -> Float[Array, "*n 3 F"]:
    return jnp.sum(M * v[..., None, :, :], axis=-2)


def _apply_a_inverse(tree: _Tree, D_inv: Float[Array, "joints 3 3 F"], v: Float[Array, "bones 3 *cols F"]):
    """``A^-1 v = C^T blockdiag(D_i^-1) C v`` (see the module docstring)."""
    extra = (1,) * (v.ndim - 3)
    padded = jnp.concatenate([v, jnp.zeros_like(v[:1])])  # index n = "no bone"
    signs = jnp.asarray(tree.joint_signs, v.dtype).reshape(tree.joint_signs.shape + (1,) * (v.ndim - 1))
    at_joints = jnp.sum(signs * padded[tree.joint_bones], axis=1)  # C v, (J, 3, *cols, F)
    D_inv = D_inv.reshape(D_inv.shape[:3] + extra + D_inv.shape[3:])
    z = jnp.sum(D_inv * at_joints[:, None], axis=2)
    return z[tree.child] - z[tree.parent]


def _apply_a_inverse_to_bone_columns(tree: _Tree, D_inv: Float[Array, "joints 3 3 F"],
                                     b: Float[Array, "bones 3 F"]) -> Float[Array, "bones 3 bones F"]:
    """``A^-1 diag(b) D31``: column l is ``A^-1`` of the vector holding ``b_l`` at bone l only.

    Such a vector reaches two joints (``+b_l`` at the child, ``-b_l`` at the parent), so column l is
    nonzero only at the bones touching them: two 3x3 products per bone instead of a dense apply."""
    at_child = _matvec3(D_inv[tree.child], b)
    at_parent = _matvec3(D_inv[tree.parent], b)
    via_child = jnp.asarray(tree.via_child, b.dtype)[:, None, :, None]
    via_parent = jnp.asarray(tree.via_parent, b.dtype)[:, None, :, None]
    return via_child * jnp.moveaxis(at_child, 0, 1)[None] + via_parent * jnp.moveaxis(at_parent, 0, 1)[None]


_UNROLLED_LEVELS = 2
"""Levels of ``T^L`` that :func:`_apply_sca_operator` applies as straight-line code (the paper's N = 3 needs
two). Side by side (ST + SCA, N = 3, 4 views, 10k frames, 2 cores) the straight-line recursion ran 1.3x faster
than the loop, whose state selects (``where``) copy every pending ``(bones, 3, bones)`` block per iteration."""


def _apply_sca_operator(tree, D_inv, lambdas: list, first: Float[Array, "bones 3 *cols F"]) -> Float[Array, "bones 3 *cols F"]:
    """``T^L x`` for SCA's accumulated first-order inverse ``T^l = T^(l-1) - 2 T^(l-1) Lambda_l T^(l-1)``
    (``T^0 = A^-1``, ``L = len(lambdas)``), given ``first = A^-1 x`` (bone columns or one bone vector).

    ``T^L`` is a polynomial of degree ``2^L`` in ``A^-1``, and forming it densely costs ``(3n)^3`` per
    level. So it is applied matrix-free: ``2^L - 1`` further applications of ``A^-1``. The lowest
    ``_UNROLLED_LEVELS`` levels recurse in Python (straight-line code); the levels above run depth first over
    the binary recursion tree in a ``fori_loop`` whose body carries one pending partial result per level, so the
    traced graph stays O(L), not O(2^L), for the paper's N up to 9 and beyond."""
    shape = (len(first),) + (1,) * (first.ndim - 2) + first.shape[-1:]
    scales = [lam.reshape(shape) for lam in lambdas]
    unrolled, looped = scales[:_UNROLLED_LEVELS], scales[_UNROLLED_LEVELS:]

    def low_levels(applied, levels):  # T^len(levels) x from applied = A^-1 x
        if not levels:
            return applied
        y = low_levels(applied, levels[:-1])
        return y - 2.0 * low_levels(_apply_a_inverse(tree, D_inv, levels[-1] * y), levels[:-1])

    level = len(looped)
    if level == 0:
        return low_levels(first, unrolled)

    def carry_up(index, r, x, pending):
        # A 0 bit ends the first call of that level (the second call's input is Lambda r);
        # a 1 bit ends the second call (result = first - 2 second).
        done = jnp.array(False)
        pending = list(pending)
        for j in range(level):
            second_call = (jnp.right_shift(index, j) & 1) == 1
            first_ends = ~done & ~second_call
            x = jnp.where(first_ends, looped[j] * r, x)
            r, pending[j] = (jnp.where(~done & second_call, pending[j] - 2.0 * r, r),
                             jnp.where(first_ends, r, pending[j]))
            done = done | first_ends
        return x, tuple(pending), r

    def leaf(index, state):
        x, pending, _ = state
        return carry_up(index, low_levels(_apply_a_inverse(tree, D_inv, x), unrolled), x, pending)

    zeros = jnp.zeros_like(first)
    state = carry_up(0, low_levels(first, unrolled), zeros, (zeros,) * level)
    _, _, result = jax.lax.fori_loop(1, 2**level, leaf, state)
    return result


_UNROLLED_MAX_SIZE = 24
"""Largest system :func:`_solve_symmetric` eliminates unrolled (STRUCTRI17 has 16 bones, BODY25 24)."""

_UNROLLED_MAX_STEPS = 3
"""Most SCA steps whose multiplier systems the first-order path eliminates unrolled. Beyond, the ``2^N - 1``
applications of ``A^-1`` dominate the run time and each unrolled elimination only adds compile time (docs/structri.md,
"Speed": ``experiments.bench_structri --n-steps 9``, compilation 2.1x faster, the same frames per second)."""


def _solve_symmetric(system: Float[Array, "n n F"], rhs: Float[Array, "n *cols F"],
                     unrolled: bool = True) -> Float[Array, "n *cols F"]:
    """Gaussian elimination without pivoting, element-wise over frames.

    The systems are (nearly) symmetric positive definite (``B^T T B`` with T a first-order
    approximation of the SPD ``A^-1``, or ``A + 2 Lambda`` near a constrained minimum), so they need
    no pivoting; a singular one yields non-finite values, which the caller reports. Deliberately no
    LAPACK: jaxlib 0.10's batched LAPACK kernels split their batch over XLA's intra-op thread pool and
    block a pool thread while waiting, so two of them running side by side in one program deadlock a
    2-thread pool (see ``tests/test_structri.py::test_no_lapack_in_batched_solvers``).

    Up to ``_UNROLLED_MAX_SIZE`` unknowns (SCA's bones x bones systems) the elimination is unrolled
    with static slices, each step on the shrinking trailing block only: ST + SCA ran 1.25x faster
    than with the loop (STRUCTRI17, 4 views, 10k frames, side by side). Larger systems (the exact
    variant's 3 bones x 3 bones), and any system with ``unrolled=False``, take :func:`_solve_symmetric_loop`:
    unrolled, the exact variant's compiled for 16 s instead of 2 s."""
    if not unrolled or system.shape[0] > _UNROLLED_MAX_SIZE:
        return _solve_symmetric_loop(system, rhs)
    n = system.shape[0]
    columns = rhs.reshape(n, -1, rhs.shape[-1])
    trailing = jnp.concatenate([system, columns], axis=1)  # (n, n + cols, F)
    pivot_rows = []
    for _ in range(n):
        pivot_row, below = trailing[0], trailing[1:]
        factor = below[:, :1] / pivot_row[None, :1]
        trailing = below[:, 1:] - factor * pivot_row[None, 1:]
        pivot_rows.append(pivot_row)  # pivot_rows[k]: unknowns k.., then the right-hand sides
    solution = columns[:0]  # unknowns k+1.. once unknown k is next
    for k in reversed(range(n)):
        row = pivot_rows[k]
        value = (row[n - k:] - jnp.sum(row[1:n - k, None] * solution, axis=0)) / row[:1]
        solution = jnp.concatenate([value[None], solution])
    return solution.reshape(rhs.shape)


def _solve_symmetric_loop(system: Float[Array, "n n F"], rhs: Float[Array, "n *cols F"]) -> Float[Array, "n *cols F"]:
    """:func:`_solve_symmetric` in ``fori_loop``s over the full matrix (masked below the pivot):
    a traced graph independent of n."""
    n = system.shape[0]
    columns = rhs.reshape(n, -1, rhs.shape[-1])
    augmented = jnp.concatenate([system, columns], axis=1)  # (n, n + cols, F)
    below = jnp.arange(n)

    def eliminate(k, aug):
        pivot_row = jax.lax.dynamic_index_in_dim(aug, k, 0, keepdims=False)
        column = jax.lax.dynamic_index_in_dim(aug, k, 1, keepdims=False)
        pivot = jax.lax.dynamic_index_in_dim(pivot_row, k, 0)
        factor = jnp.where((below > k)[:, None], column / pivot, 0.0)
        return aug - factor[:, None] * pivot_row[None]

    upper = jax.lax.fori_loop(0, n, eliminate, augmented)

    def substitute(j, x):  # x is zero at the unknowns not yet solved for, k and above
        k = n - 1 - j
        row = jax.lax.dynamic_index_in_dim(upper, k, 0, keepdims=False)
        value = (row[n:] - jnp.sum(row[:n, None] * x, axis=0)) / jax.lax.dynamic_index_in_dim(row, k, 0)
        return jax.lax.dynamic_update_index_in_dim(x, value, k, 0)

    return jax.lax.fori_loop(0, n, substitute, jnp.zeros_like(columns)).reshape(rhs.shape)


def _pose_from_bones(tree: _Tree, D, m, bones: Float[Array, "bones 3 F"]) -> Float[Array, "joints 3 F"]:
    """Joints from bones with the optimal root ``x0 = (sum D_i)^-1 (sum m_i - sum D_i r_i(b))``."""
    relative = jnp.tensordot(jnp.asarray(tree.path, bones.dtype), bones, axes=1)
    S_inv, _ = _inverse_3x3(jnp.sum(D, axis=0))
    rhs = jnp.sum(m, axis=0) - jnp.sum(_matvec3(D, relative), axis=0)
    return _matvec3(S_inv, rhs)[None] + relative


def _target_sq(bones, lengths, step: int, n_steps: int, schedule: str):
    """Squared target lengths ``L^(i)`` of SCA step i (1-based): the code interpolates lengths,
    the paper (Eq. 16) squared lengths; both reach ``lengths`` at the last step."""
    real_sq = jnp.sum(bones**2, axis=1)
    remaining = n_steps - step
    if schedule == "length":
        return ((remaining * jnp.sqrt(real_sq) + lengths) / (remaining + 1)) ** 2
    return (remaining * real_sq + lengths**2) / (remaining + 1)


def _sca_first_order(tree, D_inv, b0: Float[Array, "bones 3 F"], lengths: Float[Array, "bones #F"],
                     n_steps: int, schedule: str, multiplier_system: str):
    """Algorithm 1 with ``T^(i-1)`` (the code, ``multiplier_system="current"``) or ``T^0 = A^-1`` (the printed
    line 6, ``"initial"``) in step i's multiplier system; both update ``b^i = T^i beta = b^(i-1) - 2 T^(i-1)
    Lambda_i b^(i-1)``. With ``T^0`` only the update passes through ``T^(i-1)``, applied to one vector
    instead of n columns.

    Returns ``(b, sum lambda, ok)`` of the N-step run and of a single ST step (which shares the
    first step's multiplier system: same ``b0``, final targets)."""
    b, lambdas, solvable = b0, [], jnp.array(True)
    unrolled = n_steps <= _UNROLLED_MAX_STEPS
    for step in range(1, n_steps + 1):
        rhs = jnp.sum(b**2, axis=1) - _target_sq(b, lengths, step, n_steps, schedule)
        columns = _apply_a_inverse_to_bone_columns(tree, D_inv, b)  # A^-1 diag(b) D31, (n, 3, n, F)
        if multiplier_system == "current":
            columns = _apply_sca_operator(tree, D_inv, lambdas, columns)  # T^(step-1) diag(b) D31

        def update(lam):  # T^(step-1) diag(b) D31 lam
            direction = jnp.sum(columns * lam[None, None], axis=2)
            if multiplier_system == "current":
                return direction
            return _apply_sca_operator(tree, D_inv, lambdas, direction)  # columns hold A^-1 diag(b) D31 here

        system = jnp.sum(b[:, :, None] * columns, axis=1)
        system = 0.5 * (system + jnp.swapaxes(system, 0, 1))
        if step == 1:  # one elimination for both right-hand sides
            both = jnp.stack([rhs, jnp.broadcast_to(jnp.sum(b**2, axis=1) - lengths**2, rhs.shape)], axis=1)
            lam, lam_single = jnp.moveaxis(_solve_symmetric(system, both, unrolled) / 4.0, 1, 0)
            single = (b0 - 2.0 * update(lam_single), lam_single, jnp.all(jnp.isfinite(lam_single), axis=0))
        else:
            lam = _solve_symmetric(system, rhs, unrolled) / 4.0
        solvable &= jnp.all(jnp.isfinite(lam), axis=0)
        b = b - 2.0 * update(lam)
        lambdas.append(lam)
    return (b, sum(lambdas), solvable), single


def _sca_exact(A: Float[Array, "k k F"], beta: Float[Array, "k F"], b0: Float[Array, "bones 3 F"],
               lengths: Float[Array, "bones F"], n_steps: int, schedule: str, newton_iterations: int = 2):
    """SCA re-solving ``(A + 2 Lambda_total)`` instead of the first-order update (frames-last, dense).

    The ST multiplier system is one Newton step on ``h(b(lambda)) = L^(i)`` (its matrix is the
    Jacobian up to -4); here each step takes ``newton_iterations`` of them with the exact
    ``b(lambda) = (A + 2 Lambda)^-1 beta``, so the constraints are met to second order."""
    n = b0.shape[0]
    eye = jnp.eye(3 * n, dtype=b0.dtype)[:, :, None]
    bone_columns = jnp.eye(n, dtype=b0.dtype)[:, None, :, None]
    total = jnp.zeros_like(b0[:, 0])
    b, solvable = b0, jnp.array(True)
    for step in range(1, n_steps + 1):
        target = _target_sq(b, lengths, step, n_steps, schedule)
        for _ in range(newton_iterations):
            H = A + 2.0 * eye * jnp.repeat(total, 3, axis=0)[None]
            B = (b[:, :, None] * bone_columns).reshape(3 * n, n, -1)  # diag(b) D31
            system = jnp.sum(B[:, :, None] * _solve_symmetric(H, B)[:, None], axis=0)  # B^T H^-1 B
            lam = _solve_symmetric(system, jnp.sum(b**2, axis=1) - target) / 4.0
            solvable &= jnp.all(jnp.isfinite(lam), axis=0)
            total = total + lam
            H = A + 2.0 * eye * jnp.repeat(total, 3, axis=0)[None]
            b = _solve_symmetric(H, beta).reshape(b0.shape)
    return b, total, solvable


def _lagrangian(A, beta, b0, lengths, *, n_iterations, step, dual_step, millimetres_per_unit):
    """The official primal-dual gradient iteration (one frame), run in millimetres as its step sizes
    assume. The algebraic cost is depth-weighted, so in another unit ``A`` is unchanged, ``beta`` and
    the bones scale with the unit and the cost with its square; the multipliers are unit-free."""
    s = millimetres_per_unit
    beta_mm, L_mm = beta * s, lengths * s
    n = b0.shape[0]

    def body(_, state):
        b, lam = state
        grad = A @ b - beta_mm + 2.0 * jnp.repeat(lam, 3) * b
        violation = jnp.sum(b.reshape(n, 3) ** 2, axis=1) - L_mm**2
        return b - step * grad, lam + dual_step * violation

    b, lam = jax.lax.fori_loop(0, n_iterations, body, (b0.reshape(-1) * s, jnp.zeros(n, A.dtype)))
    return b.reshape(n, 3) / s, lam, jnp.array(True)


def _reduced_from_quadratic(tree, D: Float[Array, "joints 3 3"], m: Float[Array, "joints 3"]):
    """Dense ``A = (GQ)^T D (GQ)`` and ``beta = (GQ)^T m`` of one frame."""
    num_joints, n = tree.path.shape
    path = jnp.asarray(tree.path, D.dtype)
    lifted = path[:, None, :, None] * jnp.eye(3, dtype=D.dtype)[None, :, None, :]  # (J,3,n,3)
    S_inv = _inverse_3x3(jnp.sum(D, axis=0)[..., None])[0][..., 0]
    subtree = jnp.einsum("jab,jbkc->akc", D, lifted)
    GQ = (lifted - jnp.einsum("ab,bkc->akc", S_inv, subtree)[None]).reshape(num_joints, 3, 3 * n)
    A = jnp.einsum("jak,jab,jbl->kl", GQ, D, GQ)
    beta = jnp.einsum("jak,ja->k", GQ, m)
    return 0.5 * (A + A.T), beta


def reduced_problem(
    points_2d: Float[ArrayLike, "views joints 2"],
    projections: Float[ArrayLike, "views 3 4"],
    skeleton: Skeleton = STRUCTRI17,
    confidences: Float[ArrayLike, "views joints"] | None = None,
) -> tuple[Float[Array, "dim dim"], Float[Array, "dim"]]:
    """``A = (GQ)^T D (GQ)`` and ``beta = (GQ)^T m`` of one frame (paper Eq. 8), dense.

    ``GQ`` maps bones to joints with the optimal root: ``X_i = r_i(b) - (sum D)^-1 sum_j D_j r_j(b)``
    (the constant ``p`` term of the official code drops out of beta, see the reference notes)."""
    points_2d, projections = jnp.asarray(points_2d), jnp.asarray(projections)
    weights = _default_weights(points_2d.shape[0], points_2d.shape[1], confidences, points_2d.dtype)
    D, m = _quadratic_form(points_2d[..., None], projections[..., None], weights[..., None])
    return _reduced_from_quadratic(_tree(skeleton), D[..., 0], m[..., 0])


def _default_weights(views, num_joints, confidences, dtype):
    if confidences is None:
        return jnp.full((views, num_joints), 1.0 / views, dtype)
    return jnp.asarray(confidences, dtype)


def _chunk(points_2d: Float[Array, "views joints 2 F"], projections: Float[Array, "views 3 4 #F"],
           lengths: Float[Array, "bones #F"], weights: Float[Array, "views joints F"], *, skeleton, method,
           n_steps, schedule, multiplier_system, degenerate_rcond, max_length_error, lagrangian) -> StructriResult:
    """One chunk of frames, frames on the last axis of every input and output."""
    tree = _tree(skeleton)
    # The barrier materialises D and m once: without it XLA re-derives them from the 2D points inside each of
    # their consumers' fusions, and ST + SCA ran 1.15x slower (N = 3, 4 views, 10k frames, side by side).
    D, m = jax.lax.optimization_barrier(_quadratic_form(points_2d, projections, weights))
    D_inv, rcond = _inverse_3x3(D)
    min_rcond = jnp.min(rcond, axis=0)
    underdetermined = ~(min_rcond > 1e-12)

    # Regularised LS: exact LS where D_i is well conditioned, finite where it is not.
    total = jnp.sum(D, axis=0)
    scale = (total[0, 0] + total[1, 1] + total[2, 2]) / (3.0 * D.shape[0])
    # A frame no view sees (every weight zero) has D = 0: a unit regulariser keeps its LS pose at the origin.
    scale = jnp.where(scale > 0, scale, 1.0)
    D_reg_inv, _ = _inverse_3x3(D + 1e-12 * scale[None, None, None] * jnp.eye(3, dtype=D.dtype)[None, :, :, None])
    ls_pose = _matvec3(jnp.where(underdetermined[None, None, None], D_reg_inv, D_inv), m)
    ls_bones = ls_pose[tree.child] - ls_pose[tree.parent]
    zeros = jnp.zeros(ls_bones.shape[:1] + ls_bones.shape[2:], D.dtype)

    if method == "ls":
        status = jnp.where(underdetermined, Status.UNDERDETERMINED, Status.OK).astype(jnp.int32)
        return StructriResult(ls_pose, ls_bones, status, zeros)

    b0 = ls_bones
    single = jnp.zeros(underdetermined.shape, bool)
    if method == "st":
        (b, lam, solvable), (b1, lam1, solvable1) = _sca_first_order(tree, D_inv, b0, lengths, n_steps, schedule,
                                                                            multiplier_system)
        if n_steps > 1:
            single = min_rcond < degenerate_rcond
            b, lam, solvable = (jnp.where(single[None, None], b1, b), jnp.where(single[None], lam1, lam),
                                jnp.where(single, solvable1, solvable))
    else:
        A, beta = jax.vmap(functools.partial(_reduced_from_quadratic, tree), in_axes=-1, out_axes=-1)(D, m)
        lengths = jnp.broadcast_to(lengths, lengths.shape[:1] + b0.shape[-1:])
        if method == "st_exact":
            b, lam, solvable = _sca_exact(A, beta, b0, lengths, n_steps, schedule)
        else:
            b, lam, solvable = jax.vmap(functools.partial(_lagrangian, **lagrangian), in_axes=-1, out_axes=-1)(
                A, beta, b0, lengths)

    pose = _pose_from_bones(tree, D, m, b)
    meets_lengths = True
    if max_length_error != float("inf"):
        length_error = jnp.abs(jnp.sqrt(jnp.sum(b**2, axis=1)) - lengths)
        meets_lengths = jnp.all(length_error <= max_length_error * lengths, axis=0)
    finite = (solvable & meets_lengths & jnp.all(jnp.isfinite(pose), axis=(0, 1))
              & jnp.all(jnp.isfinite(lam), axis=0))
    status = jnp.where(underdetermined, Status.UNDERDETERMINED,
                       jnp.where(~finite, Status.FALLBACK_LS,
                                 jnp.where(single, Status.SINGLE_STEP, Status.OK)))
    use_ls = status >= Status.FALLBACK_LS
    return StructriResult(jnp.where(use_ls[None, None], ls_pose, pose), jnp.where(use_ls[None, None], ls_bones, b),
                          status.astype(jnp.int32), jnp.where(use_ls[None], zeros, lam))


# ----------------------------------------------------------------------------------------------
# Public batched API.


def projection_matrices(
    cameras: Camera | Float[ArrayLike, "*frames views 3 4"]
) -> Float[Array, "*frames views 3 4"]:
    """``K [R | t]`` per camera of a rig (undistorted pinhole; a rig with distortion is refused), or the given
    matrices, shared or per frame."""
    if isinstance(cameras, Camera):
        if cameras.K.ndim != 3:
            raise ValueError(f"expected a rig with a leading views axis, got K of shape {cameras.K.shape}")
        if not isinstance(cameras.dist, jax.core.Tracer) and np.any(np.asarray(cameras.dist) != 0):
            raise ValueError("Structural Triangulation uses linear projections: undistort the 2D points "
                             "and pass a rig with zero distortion (or the 3x4 matrices)")
        return projection_matrix(cameras)
    P = jnp.asarray(cameras)
    if P.shape[-2:] != (3, 4):
        raise ValueError(f"projections must have shape (*frames, views, 3, 4), got {P.shape}")
    return P


def _check_values(name: str, values: ArrayLike, requirement: str, acceptable) -> None:
    """A one-line ValueError naming the first value outside ``acceptable`` (concrete inputs only: under jit the
    values are not known here, and the kernels stay free of checks)."""
    if isinstance(values, jax.core.Tracer):
        return
    values = np.asarray(values)
    bad = ~acceptable(values)
    if bad.any():
        index = tuple(int(i) for i in np.argwhere(bad)[0])
        raise ValueError(f"{name} {requirement}: got {values[index]} at index {index}")


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
    _check_values("confidences", weights, "must be finite and >= 0 (0 drops a view)", lambda w: np.isfinite(w) & (w >= 0))
    _check_values("bone_lengths", lengths, "must be finite and > 0", lambda L: np.isfinite(L) & (L > 0))
    _check_values("projections", P, "must be finite", np.isfinite)
    if not isinstance(weights, jax.core.Tracer):
        _check_values("points_2d", jnp.where(weights[..., None] > 0, points_2d, 0.0),
                      "must be finite where the confidence is positive (NaN marks a missed joint only with "
                      "confidence 0)", np.isfinite)
    # A missed joint's NaN would still poison the weighted sums (0 * NaN): it enters as 0, which weight 0 drops.
    points_2d = jnp.where(jnp.isfinite(points_2d), points_2d, 0.0)
    flat = int(np.prod(frames, dtype=int))
    args = (points_2d.reshape(flat, views, num_joints, 2),
            P.reshape((flat,) * (P.ndim > 3) + (views, 3, 4)),
            lengths.reshape((flat,) * (lengths.ndim > 1) + (n,)),
            weights.reshape(flat, views, num_joints))
    axes = (0, 0 if P.ndim > 3 else None, 0 if lengths.ndim > 1 else None, 0)
    return frames, args, axes


_CHUNK_FRAMES = 160
"""Frames per chunk of the frames-last kernels, so that each chunk's working set stays in cache (one
of SCA's bones x 3 x bones operators holds 6 KB per frame in float64, about 1 MB per chunk of 160); the
chunks run in a sequential ``lax.map``."""

_STREAMS = 2
"""Chunks solved side by side in each step of that loop, as separate subgraphs: XLA:CPU runs independent
operations concurrently on its threads, while the fusions of one chunk keep 2 cores only partly busy. ST + SCA
(N = 3, 4 views, 10k frames, 2 cores) in microseconds per frame, three runs of ``python -m
experiments.bench_structri --layouts 128x1 160x1 160x2``: 10.7 / 9.4 / 8.5, 13.1 / 10.9 / 12.0, 10.2 / 9.2 / 8.9
(the previous layout, one stream of 160, two). Inputs of fewer than ``_STREAMS`` chunks take one stream, which
compiles one copy of the kernel instead of two."""


@functools.partial(jax.jit, static_argnames=("axes", "skeleton", "method", "n_steps", "schedule", "multiplier_system",
                                              "degenerate_rcond", "max_length_error", "lagrangian", "layout"))
def _solve_flat(points_2d, P, lengths, weights, *, axes, skeleton, method, n_steps, schedule,
                degenerate_rcond, lagrangian, multiplier_system="current", max_length_error=float("inf"),
                layout=(_CHUNK_FRAMES, _STREAMS)):
    """Frames-first flat inputs -> frames-last chunks -> :func:`_chunk` under ``lax.map`` -> frames-first.

    ``layout``: (frames per chunk, streams), the defaults above; other values only change the speed."""
    frames = points_2d.shape[0]
    chunk = max(1, min(frames, layout[0]))
    streams = layout[1] if frames >= layout[1] * chunk else 1
    steps = -(-frames // (streams * chunk))

    def to_chunks(x):  # (steps, streams, ..., chunk)
        x = _pad_frames(x, steps * streams * chunk)
        return jnp.moveaxis(x.reshape((steps, streams, chunk) + x.shape[1:]), 2, -1)

    kernel = functools.partial(_chunk, skeleton=skeleton, method=method, n_steps=n_steps, schedule=schedule,
                               multiplier_system=multiplier_system,
                               degenerate_rcond=degenerate_rcond, max_length_error=max_length_error,
                               lagrangian=dict(lagrangian) if lagrangian else None)
    shared = [x[..., None] if axis is None else None for x, axis in zip((points_2d, P, lengths, weights), axes)]
    batched = [to_chunks(x) if axis is not None else None for x, axis in zip((points_2d, P, lengths, weights), axes)]

    def run(step_args):  # one kernel call per stream, stacked
        outs = [kernel(*[s if s is not None else c[i] for s, c in zip(shared, step_args)]) for i in range(streams)]
        return jax.tree.map(lambda *x: jnp.stack(x), *outs)

    out = jax.lax.map(run, batched)
    return jax.tree.map(lambda x: jnp.moveaxis(x, -1, 2).reshape((steps * streams * chunk,) + x.shape[2:-1])[:frames],
                        out)


def _pad_frames(x: Array, frames: int) -> Array:
    """``x`` (frames first) with its last frame repeated up to ``frames``: finite filler that the callers drop."""
    return jnp.concatenate([x, jnp.repeat(x[-1:], frames - x.shape[0], axis=0)]) if frames > x.shape[0] else x


def _padded_frames(frames: int, layout: tuple[int, int]) -> int:
    """The frame count :func:`_solve` compiles for: a power of two below one round of chunks (``chunk x streams``
    frames), else whole rounds. Inputs of nearby lengths (a tracked person's frames, a clip) share one compilation,
    at most doubling the work of a short input; from one chunk up the chunks, and so each frame's arithmetic, are
    those of the unpadded input."""
    round_frames = layout[0] * layout[1]
    if frames >= round_frames:
        return -(-frames // round_frames) * round_frames
    return min(1 << max(frames - 1, 0).bit_length(), round_frames)


def _solve(points_2d, cameras, bone_lengths, skeleton, confidences, method, n_steps=1,
           schedule="length", degenerate_rcond=0.0, lagrangian=(), max_length_error=float("inf"),
           multiplier_system="current", layout=(_CHUNK_FRAMES, _STREAMS)):
    frames, args, axes = _prepare(points_2d, cameras, bone_lengths, skeleton, confidences)
    flat = args[0].shape[0]
    if flat:
        args = tuple(_pad_frames(x, _padded_frames(flat, layout)) if axis == 0 else x for x, axis in zip(args, axes))
    out = _solve_flat(*args, axes=axes, skeleton=skeleton, method=method, n_steps=n_steps,
                      schedule=schedule, degenerate_rcond=degenerate_rcond, lagrangian=lagrangian,
                      max_length_error=max_length_error, multiplier_system=multiplier_system, layout=layout)
    return jax.tree.map(lambda x: x[:flat].reshape(frames + x.shape[1:]), out)


def structural_triangulation(
    points_2d: Float[ArrayLike, "*frames views joints 2"],
    cameras: Camera | Float[ArrayLike, "*pframes views 3 4"],
    bone_lengths: Float[ArrayLike, "*lframes bones"],
    skeleton: Skeleton = STRUCTRI17,
    confidences: Float[ArrayLike, "*frames views joints"] | None = None,
    n_steps: int = 3,
    *,
    schedule: str = "length",
    multiplier_system: str = "current",
    update: str = "first_order",
    degenerate_rcond: float = 1e-3,
    max_length_error: float = 0.5,
) -> StructriResult:
    """Structural Triangulation with the Step Constraint Algorithm (paper Alg. 1, official code).

    Args:
        points_2d: detections in pixels, ``(views, J, 2)`` for one frame or with leading frame axes; NaN
            only where the confidence is 0 (a missed joint), else a ValueError names the first.
        cameras: a :class:`geometry.Camera` rig without distortion, or projection matrices
            ``(views, 3, 4)`` (shared) or ``(*frames, views, 3, 4)``.
        bone_lengths: target lengths in ``skeleton.bones`` order, shared or per frame.
        skeleton: any tree; bones are ``skeleton.bones`` (child-index order).
        confidences: weights w per view and joint (default ``1/views``); a zero weight drops a view.
        n_steps: SCA steps N (1 = plain ST). The first-order path runs ``2^N - 1`` applications of
            ``A^-1`` in all (its traced graph grows linearly in N; the paper uses N <= 9).
        schedule: ``"length"`` interpolates lengths (official code, default) or ``"squared"`` squared
            lengths (paper Eq. 16).
        multiplier_system: ``"current"`` builds step i's multiplier system with the accumulated ``T^(i-1)``
            (official code, default) or ``"initial"`` with ``T^0 = A^-1`` (the printed Algorithm 1, line 6);
            the update uses ``T^(i-1)`` in both, and they agree for ``n_steps = 1``. The paper's printed
            variant is ``schedule="squared", multiplier_system="initial"``.
        update: ``"first_order"`` (Alg. 1's accumulated ``T^i``) or ``"exact"`` (re-solves
            ``A + 2 Lambda`` each step; dense, slower).
        degenerate_rcond: frames whose worst joint has a reciprocal condition number (of its 3x3
            block D_i) below this run a single ST step (:attr:`Status.SINGLE_STEP`); 0 disables it.
        max_length_error: a frame whose solution misses some target length by more than this fraction of
            it gets the LS pose (:attr:`Status.FALLBACK_LS`); ``inf`` disables the check, as the official
            code has none. The update is a linearisation: with gross 2D outliers, or as the single step along
            nearly parallel rays, it can return finite bones many times their length (``tests/test_structri.py``).

    Returns:
        :class:`StructriResult` with ``pose (*frames, J, 3)``, ``bones``, ``status``, ``multipliers``.
    """
    if schedule not in ("length", "squared"):
        raise ValueError(f"schedule must be 'length' or 'squared', got {schedule!r}")
    if update not in ("first_order", "exact"):
        raise ValueError(f"update must be 'first_order' or 'exact', got {update!r}")
    if multiplier_system not in ("current", "initial"):
        raise ValueError(f"multiplier_system must be 'current' or 'initial', got {multiplier_system!r}")
    if update == "exact" and multiplier_system != "current":
        raise ValueError("multiplier_system='initial' is a variant of the first-order update, not of update='exact'")
    if int(n_steps) < 1:
        raise ValueError(f"n_steps must be >= 1, got {n_steps}")
    if not max_length_error > 0:
        raise ValueError(f"max_length_error must be > 0, got {max_length_error}")
    method = "st" if update == "first_order" else "st_exact"
    return _solve(points_2d, cameras, bone_lengths, skeleton, confidences, method, int(n_steps),
                  schedule, float(degenerate_rcond), max_length_error=float(max_length_error),
                  multiplier_system=multiplier_system)


def ls_triangulation(
    points_2d: Float[ArrayLike, "*frames views joints 2"],
    cameras: Camera | Float[ArrayLike, "*pframes views 3 4"],
    skeleton: Skeleton = STRUCTRI17,
    confidences: Float[ArrayLike, "*frames views joints"] | None = None,
) -> StructriResult:
    """Unconstrained weighted linear least squares (the paper's LS, ``b0 = A^-1 beta``), per joint."""
    n = skeleton.num_joints - 1
    return _solve(points_2d, cameras, np.ones(n), skeleton, confidences, "ls")


def lagrangian_triangulation(
    points_2d: Float[ArrayLike, "*frames views joints 2"],
    cameras: Camera | Float[ArrayLike, "*pframes views 3 4"],
    bone_lengths: Float[ArrayLike, "*lframes bones"],
    skeleton: Skeleton = STRUCTRI17,
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
    skeleton: Skeleton = STRUCTRI17,
    confidences: Float[ArrayLike, "*frames views joints"] | None = None,
    *,
    millimetres_per_unit: float = 1000.0,
) -> StructriResult:
    """Linear eigen method (homogeneous DLT per joint, :func:`geometry.triangulate_point`) as in the
    official ``utils.py``: rows multiplied by w (squared residuals weighted by w^2), not normalised.

    The unnormalised DLT is not unit-invariant: with ``|[X; 1]|`` fixed it minimises the algebraic cost
    divided by ``1 + |X|^2``, which pulls joints away from the world origin far more in millimetres
    than in metres. The official code (and the paper's LEM numbers) work in millimetres, so inputs in
    another unit are run in millimetres (``millimetres_per_unit``, 1000 for metres; 1 keeps the given
    unit) and the result is returned in the input unit.

    A joint whose DLT is not determined (fewer than two views, ill-posed or at infinity) gets the regularised LS
    point and :attr:`Status.UNDERDETERMINED` for its frame; one the DLT puts behind a camera keeps that point, as
    in the official code (``geometry.triangulate_point(..., require_in_front=False)``)."""
    frames, args, axes = _prepare(points_2d, cameras, np.ones(skeleton.num_joints - 1), skeleton, confidences)
    return jax.tree.map(lambda x: x.reshape(frames + x.shape[1:]),
                        _lem_flat(*args, axes=axes, skeleton=skeleton, scale=float(millimetres_per_unit)))


@functools.partial(jax.jit, static_argnames=("axes", "skeleton", "scale"))
def _lem_flat(points_2d, P, lengths, weights, *, axes, skeleton, scale):
    tree = _tree(skeleton)
    P_scaled = P.at[..., 3].multiply(scale)  # P [s X; 1] projects like P [X; 1] with t scaled by s
    # The official DLT has no cheirality check: a joint it puts behind a camera keeps that point.
    dlt = jax.vmap(jax.vmap(functools.partial(triangulate_point, require_in_front=False), in_axes=(None, 1, 1)),
                   in_axes=(axes[1], 0, 0))(P_scaled, points_2d, weights)
    ls = _solve_flat(points_2d, P, lengths, weights, axes=axes, skeleton=skeleton, method="ls", n_steps=1,
                     schedule="length", degenerate_rcond=0.0, lagrangian=())
    pose = jnp.where(dlt.valid[..., None], dlt.point / scale, ls.pose)
    status = jnp.where(jnp.all(dlt.valid, axis=-1), Status.OK, Status.UNDERDETERMINED).astype(jnp.int32)
    bones = pose[:, tree.child] - pose[:, tree.parent]
    return StructriResult(pose, bones, status, jnp.zeros(bones.shape[:2], pose.dtype))


# ----------------------------------------------------------------------------------------------
# Bone lengths.


def estimate_bone_lengths(
    points_2d: Float[ArrayLike, "frames views joints 2"],
    cameras: Camera | Float[ArrayLike, "views 3 4"],
    skeleton: Skeleton = STRUCTRI17,
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
    return 0.5 * (mean + mean[np.asarray(skeleton.mirror_bones)])

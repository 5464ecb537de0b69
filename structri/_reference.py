"""A certified constrained optimum of the Structural Triangulation problem (float64 oracle).

optimistix has no constrained solver (patrick-kidger/optimistix#45), so the reference combines
(1) a globalised first-order stage: the sphere reparameterisation ``b_k = L_k u_k / |u_k|`` minimised
without constraints by ``optx.BFGS``, started from LS and from ST (the lower objective wins), and
(2) Newton polishing of the full KKT system ``(A + 2 Lambda) b = beta, |b_k|^2 = L_k^2`` in ``(b, lambda)``
with ``optx.root_find(optx.Newton)``. The certificate reports the KKT residual and whether the Hessian of
the Lagrangian projected on the constraints' tangent space is positive definite (a strict local
minimum). One frame per call; slow by design.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import optimistix as optx
from jaxtyping import Array, ArrayLike, Bool, Float

from geometry import STRUCTRI17, Camera, Skeleton

from ._solver import (_default_weights, _pose_from_bones, _quadratic_form, _reduced_from_quadratic, _tree,
                      ls_triangulation, projection_matrices, structural_triangulation)

__all__ = ["ReferenceResult", "constrained_reference", "reduced_objective"]


class ReferenceResult(NamedTuple):
    """The reference optimum of one frame and its optimality certificate."""

    pose: Float[Array, "joints 3"]
    bones: Float[Array, "bones 3"]
    multipliers: Float[Array, "bones"]
    objective: Float[Array, ""]
    """``1/2 b^T A b - beta^T b`` at the optimum (same scale as A: pixels^2 per weight)."""
    kkt_residual: Float[Array, ""]
    """Max-norm of the KKT residual, stationarity scaled by ``|beta|``, constraints by ``L^2``."""
    reduced_hessian_min_eigenvalue: Float[Array, ""]
    """Smallest eigenvalue of ``Z^T (A + 2 Lambda) Z``, relative to the largest eigenvalue of A."""
    certified: Bool[Array, ""]
    """KKT residual below 1e-8, reduced Hessian positive definite, and the Newton solve succeeded."""


def reduced_objective(A: Float[ArrayLike, "k k"], beta: Float[ArrayLike, "k"], bones: Float[ArrayLike, "*f n 3"]):
    """``1/2 b^T A b - beta^T b`` (paper Eq. 8 without the constant) for one or many bone sets."""
    bones = jnp.asarray(bones)
    b = bones.reshape(bones.shape[:-2] + (-1,))
    return 0.5 * jnp.einsum("...k,kl,...l->...", b, A, b) - b @ beta


def _sphere_bones(u, lengths):
    return lengths[:, None] * u / jnp.linalg.norm(u, axis=1, keepdims=True)


def _kkt(y, args):
    b, lam = y
    A, beta, lengths = args
    n = lengths.shape[0]
    stationarity = (A @ b.reshape(-1) - beta).reshape(n, 3) + 2.0 * lam[:, None] * b
    return stationarity, jnp.sum(b**2, axis=1) - lengths**2


def constrained_reference(
    points_2d: Float[ArrayLike, "views joints 2"],
    cameras: Camera | Float[ArrayLike, "views 3 4"],
    bone_lengths: Float[ArrayLike, "bones"],
    skeleton: Skeleton = STRUCTRI17,
    confidences: Float[ArrayLike, "views joints"] | None = None,
    max_steps: int = 512,
) -> ReferenceResult:
    """Solve ``min 1/2 b^T A b - beta^T b  s.t. |b_k| = L_k`` for one frame to machine precision.

    Always in float64, whatever ``jax_enable_x64`` says: 64-bit types are enabled for this call only
    (``jax.enable_x64``), so a float32 session gets a float64 result and keeps its own setting."""
    with jax.enable_x64(True):
        points_2d = jnp.asarray(points_2d, jnp.float64)
        if points_2d.ndim != 3:
            raise ValueError(
                f"constrained_reference solves one frame: points_2d (views, joints, 2), got {points_2d.shape}")
        P = projection_matrices(cameras).astype(jnp.float64)
        lengths = jnp.asarray(bone_lengths, jnp.float64)
        weights = _default_weights(points_2d.shape[0], points_2d.shape[1], confidences, jnp.float64)
        starts = jnp.stack([ls_triangulation(points_2d, P, skeleton, weights).bones,
                            structural_triangulation(points_2d, P, lengths, skeleton, weights).bones])
        return _reference(points_2d, P, lengths, weights, starts, skeleton=skeleton, max_steps=max_steps)


@jax.jit(static_argnames=("skeleton", "max_steps"))
def _reference(points_2d, P, lengths, weights, starts, *, skeleton, max_steps):
    tree = _tree(skeleton)
    D, m = _quadratic_form(points_2d[..., None], P[..., None], weights[..., None])  # frames-last, one frame
    A, beta = _reduced_from_quadratic(tree, D[..., 0], m[..., 0])
    scale = jnp.max(jnp.linalg.eigvalsh(A))
    A_s, beta_s = A / scale, beta / scale  # unit-free objective for BFGS tolerances

    def sphere_objective(u, _):
        return reduced_objective(A_s, beta_s, _sphere_bones(u, lengths))

    def first_order(start):
        sol = optx.minimise(sphere_objective, optx.BFGS(rtol=1e-12, atol=1e-12), start, max_steps=max_steps,
                            throw=False)
        bones = _sphere_bones(sol.value, lengths)
        return bones, reduced_objective(A_s, beta_s, bones)

    candidates, values = jax.vmap(first_order)(starts)
    b = candidates[jnp.argmin(values)]
    # Multipliers from stationarity in the least-squares sense, bone by bone.
    gradient = (A_s @ b.reshape(-1) - beta_s).reshape(b.shape)
    lam = -jnp.sum(gradient * b, axis=1) / (2.0 * lengths**2)
    sol = optx.root_find(_kkt, optx.Newton(rtol=1e-13, atol=1e-13), (b, lam), (A_s, beta_s, lengths),
                         max_steps=64, throw=False)
    b, lam = sol.value
    stationarity, violation = _kkt((b, lam), (A_s, beta_s, lengths))
    residual = jnp.maximum(jnp.max(jnp.abs(stationarity)) / jnp.max(jnp.abs(beta_s)),
                           jnp.max(jnp.abs(violation) / lengths**2))
    # Tangent space of |b_k|^2 = L_k^2: two orthonormal directions orthogonal to b_k, per bone, by cross
    # products with the axis least aligned with b_k (closed form: a batched LAPACK eigh here could run
    # beside another LAPACK kernel and deadlock XLA's CPU thread pool, see _solver._solve_symmetric).
    n = lengths.shape[0]
    unit = b / jnp.linalg.norm(b, axis=1, keepdims=True)
    first = jnp.cross(unit, jnp.eye(3)[jnp.argmin(jnp.abs(unit), axis=1)])
    first = first / jnp.linalg.norm(first, axis=1, keepdims=True)
    basis = jnp.stack([first, jnp.cross(unit, first)], axis=-1)  # (n, 3, 2)
    Z = (basis[:, :, None, :] * jnp.eye(n)[:, None, :, None]).reshape(3 * n, 2 * n)
    hessian = A_s + 2.0 * jnp.diag(jnp.repeat(lam, 3))
    min_eig = jnp.min(jnp.linalg.eigvalsh(Z.T @ hessian @ Z))
    certified = (residual < 1e-8) & (min_eig > 0) & (sol.result == optx.RESULTS.successful)
    pose = _pose_from_bones(tree, D, m, b[..., None])[..., 0]
    return ReferenceResult(pose, b, lam * scale, reduced_objective(A, beta, b), residual, min_eig, certified)

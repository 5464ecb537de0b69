"""A plain per-frame NumPy port of Structural Triangulation (the test oracle and the benchmark baseline).

Written directly from the reference formulation (dense matrices, ``np.linalg.solve``, one frame per
call) so that the batched JAX solver, which uses a sparse factorisation of ``A^-1``, is checked against
an independent route. Shapes: ``points_2d (views, J, 2)`` pixels, ``projections (views, 3, 4)``,
``bone_lengths (J-1,)`` metres in ``skeleton.bones`` order; returns joints ``(J, 3)`` metres.
"""

from __future__ import annotations

import numpy as np

from geometry import STRUCTRI17, Skeleton, bones_to_joints_matrix

__all__ = ["numpy_structural_triangulation", "numpy_lem_triangulation", "numpy_structural_triangulation_frames"]


def _quadratic_form(points_2d, projections, weights):
    """D (3J x 3J) block-diagonal and m (3J,) of the algebraic cost 1/2 X^T D X - m^T X."""
    views, num_joints, _ = points_2d.shape
    D = np.zeros((3 * num_joints, 3 * num_joints))
    m = np.zeros(3 * num_joints)
    for i in range(num_joints):
        for k in range(views):
            u, v = points_2d[k, i]
            S = np.array([[1.0, 0.0, -u], [0.0, 1.0, -v]])
            M = weights[k, i] * S.T @ S
            P3, t = projections[k, :, :3], projections[k, :, 3]
            D[3 * i:3 * i + 3, 3 * i:3 * i + 3] += 2 * P3.T @ M @ P3
            m[3 * i:3 * i + 3] -= 2 * P3.T @ M @ t
    return D, m


def numpy_structural_triangulation(
    points_2d: np.ndarray,
    projections: np.ndarray,
    bone_lengths: np.ndarray,
    skeleton: Skeleton = STRUCTRI17,
    confidences: np.ndarray | None = None,
    n_steps: int = 3,
    method: str = "ST",
    schedule: str = "length",
    multiplier_system: str = "current",
) -> np.ndarray:
    """One frame of ST + SCA (``method="ST"``) or of LS (``"LS"``).

    The defaults are the official code: lengths interpolated, ``T^(i-1)`` in the multiplier system.
    ``schedule="squared", multiplier_system="initial"`` is the printed Algorithm 1 (Eq. 16 and ``T^(0)`` in
    line 6)."""
    views, num_joints, _ = points_2d.shape
    n = num_joints - 1
    weights = np.full((views, num_joints), 1.0 / views) if confidences is None else confidences
    D, m = _quadratic_form(points_2d, projections, weights)
    G = bones_to_joints_matrix(skeleton)
    Irow = np.tile(np.eye(3), (1, num_joints))
    TrLam = Irow @ D @ Irow.T
    Q = np.concatenate([-np.linalg.solve(TrLam, Irow @ D @ G[:, 3:]), np.eye(3 * n)], axis=0)
    p = np.concatenate([-np.linalg.solve(TrLam, Irow @ m), np.zeros(3 * n)])
    GQ = G @ Q
    A = GQ.T @ D @ GQ
    beta = p @ G.T @ D @ GQ + m @ GQ
    b = np.linalg.solve(A, beta)
    if method == "ST":
        D31 = np.kron(np.eye(n), np.ones((3, 1)))
        T = T0 = np.linalg.solve(A, np.eye(3 * n))
        for i in range(n_steps):
            start = np.linalg.norm(b.reshape(n, 3), axis=1)
            if schedule == "length":
                target_sq = ((start * (n_steps - i - 1) + bone_lengths) / (n_steps - i)) ** 2
            else:
                target_sq = (start**2 * (n_steps - i - 1) + bone_lengths**2) / (n_steps - i)
            Db = np.diag(b)
            system = T if multiplier_system == "current" else T0
            lam = np.linalg.solve(D31.T @ Db @ system @ Db @ D31, start**2 - target_sq) / 4
            T = (np.eye(3 * n) - 2 * T @ np.diag(np.repeat(lam, 3))) @ T
            b = T @ beta
    elif method != "LS":
        raise ValueError(f"unknown method {method!r}; expected 'ST' or 'LS'")
    x0 = np.linalg.solve(TrLam, Irow @ m - Irow @ D @ G[:, 3:] @ b)
    return (G @ np.concatenate([x0, b])).reshape(num_joints, 3)


def numpy_structural_triangulation_frames(points_2d, projections, bone_lengths, skeleton=STRUCTRI17,
                                          confidences=None, n_steps=3, method="ST", **options) -> np.ndarray:
    """Loop :func:`numpy_structural_triangulation` over frames ``(frames, views, J, 2) -> (frames, J, 3)``."""
    return np.stack([
        numpy_structural_triangulation(points_2d[f], projections, bone_lengths, skeleton,
                                       None if confidences is None else confidences[f], n_steps, method, **options)
        for f in range(points_2d.shape[0])
    ])


def numpy_lem_triangulation(points_2d: np.ndarray, projections: np.ndarray,
                            confidences: np.ndarray | None = None) -> np.ndarray:
    """Homogeneous DLT per joint (rows times w, no normalisation), one frame: ``(views, J, 2) -> (J, 3)``."""
    views, num_joints, _ = points_2d.shape
    weights = np.full((views, num_joints), 1.0 / views) if confidences is None else confidences
    out = np.empty((num_joints, 3))
    for i in range(num_joints):
        rows = []
        for k in range(views):
            u, v = points_2d[k, i]
            P = projections[k]
            rows += [weights[k, i] * (u * P[2] - P[0]), weights[k, i] * (v * P[2] - P[1])]
        A = np.stack(rows)
        eigenvalues, eigenvectors = np.linalg.eigh(A.T @ A)
        X = eigenvectors[:, np.argmin(eigenvalues)]
        out[i] = X[:3] / X[3]
    return out

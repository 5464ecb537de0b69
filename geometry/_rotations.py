"""Rotations: axis-angle, matrices, quaternions, the 6D representation and Euler angles.

Conventions:

* Rotation matrices act on column vectors, ``x' = R @ x``; all angles are in radians.
* Axis-angle (rotation vector) ``r = theta * axis``, as ``cv2.Rodrigues``.
* Quaternions are ``(w, x, y, z)``, scalar FIRST, Hamilton product; ``q`` and ``-q`` are the same
  rotation and functions returning quaternions pick ``w >= 0``.
* The 6D representation (Zhou et al., CVPR 2019) is the first two COLUMNS of the matrix, concatenated:
  ``(R00, R10, R20, R01, R11, R21)``.
* Euler angles follow the BVH/ASF channel convention: for ``order="ZYX"``,
  ``R = Rz(a0) @ Ry(a1) @ Rx(a2)`` (intrinsic rotations, SciPy's upper-case orders).

Every function takes any number of leading batch axes (``*batch``), is jit-compatible, and has finite
gradients everywhere including the identity (series branches behind the double-``where`` trick, so
the unused branch never produces a NaN cotangent).
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ._vectors import safe_norm

__all__ = [
    "axis_angle_to_matrix",
    "matrix_to_axis_angle",
    "quaternion_to_matrix",
    "matrix_to_quaternion",
    "axis_angle_to_quaternion",
    "quaternion_to_axis_angle",
    "quaternion_multiply",
    "quaternion_conjugate",
    "quaternion_inverse",
    "quaternion_slerp",
    "matrix_to_rotation_6d",
    "rotation_6d_to_matrix",
    "euler_to_matrix",
    "matrix_to_euler",
    "relative_rotation",
    "rotation_between",
    "rotation_angle",
    "geodesic_distance",
]

# theta^2 below which the Taylor series replaces sin(theta)/theta-like ratios. At theta = 1e-3 the
# first dropped term (theta^6 / 5040) is ~1e-22, far below float64 rounding.
_SMALL_ANGLE_SQ = 1e-6


def _check_trailing(x: Array, trailing: tuple[int, ...], name: str) -> None:
    if x.ndim < len(trailing) or x.shape[x.ndim - len(trailing):] != trailing:
        raise ValueError(f"{name} must have shape (*batch, {', '.join(map(str, trailing))}), got {x.shape}")


def _as_float(x: ArrayLike) -> Array:
    x = jnp.asarray(x)
    return x if jnp.issubdtype(x.dtype, jnp.floating) else x.astype(float)


def _broadcast_batch(*arrays_and_core_ndims: tuple[Array, int]) -> list[Array]:
    """Broadcast the leading (batch) axes explicitly, so the code runs under rank promotion 'raise'."""
    batch = jnp.broadcast_shapes(*(a.shape[: a.ndim - k] for a, k in arrays_and_core_ndims))
    return [jnp.broadcast_to(a, batch + a.shape[a.ndim - k:]) for a, k in arrays_and_core_ndims]


def _matmul(a: Array, b: Array) -> Array:
    """Batched 3x3 @ 3x3 as broadcast-multiply-sum (tiny ``@`` lowers to a slow batched dot)."""
    a, b = _broadcast_batch((a, 2), (b, 2))
    return jnp.sum(a[..., :, :, None] * b[..., None, :, :], axis=-2)


def _matvec(a: Array, v: Array) -> Array:
    a, v = _broadcast_batch((a, 2), (v, 1))
    return jnp.sum(a * v[..., None, :], axis=-1)


def _transpose(a: Array) -> Array:
    return jnp.swapaxes(a, -1, -2)


def _from_rows(rows: list[list[Array]]) -> Array:
    return jnp.stack([jnp.stack(row, axis=-1) for row in rows], axis=-2)


# --------------------------------------------------------------------------------------------
# Axis-angle and matrices


def axis_angle_to_matrix(rotvec: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch 3 3"]:
    """Rodrigues' formula: rotation vector (radians * unit axis) to rotation matrix, as ``cv2.Rodrigues``.

    ``R = I + a K + b K^2`` with ``K = [r]_x``, ``a = sin(t)/t``, ``b = (1 - cos(t))/t^2``; both use
    their Taylor series near ``t = 0`` so values and gradients are exact there."""
    rotvec = _as_float(rotvec)
    _check_trailing(rotvec, (3,), "rotvec")
    x, y, z = rotvec[..., 0], rotvec[..., 1], rotvec[..., 2]
    theta_sq = x * x + y * y + z * z
    small = theta_sq < _SMALL_ANGLE_SQ
    theta = jnp.sqrt(jnp.where(small, 1.0, theta_sq))
    half = 0.5 * theta
    a = jnp.where(small, 1.0 - theta_sq / 6.0 * (1.0 - theta_sq / 20.0), jnp.sin(theta) / theta)
    # (1 - cos t) / t^2 written with sin(t/2): no cancellation in float32.
    b = jnp.where(small, 0.5 * (1.0 - theta_sq / 12.0 * (1.0 - theta_sq / 30.0)),
                  0.5 * jnp.square(jnp.sin(half) / half))
    return _from_rows([
        [1.0 - b * (y * y + z * z), b * x * y - a * z, b * x * z + a * y],
        [b * x * y + a * z, 1.0 - b * (x * x + z * z), b * y * z - a * x],
        [b * x * z - a * y, b * y * z + a * x, 1.0 - b * (x * x + y * y)],
    ])


def matrix_to_axis_angle(matrix: Float[ArrayLike, "*batch 3 3"]) -> Float[Array, "*batch 3"]:
    """Rotation matrix to rotation vector with angle in [0, pi], as ``cv2.Rodrigues``.

    Goes through :func:`matrix_to_quaternion`, which stays accurate near 0 and near pi (where the
    trace/antisymmetric-part formula loses the axis). At exactly pi, ``r`` and ``-r`` are equal
    rotations and either may be returned."""
    return quaternion_to_axis_angle(matrix_to_quaternion(matrix))


# --------------------------------------------------------------------------------------------
# Quaternions (w, x, y, z)


def _canonical(q: Array) -> Array:
    return jnp.where(q[..., :1] < 0, -q, q)


def quaternion_to_matrix(quaternion: Float[ArrayLike, "*batch 4"]) -> Float[Array, "*batch 3 3"]:
    """(w, x, y, z) quaternion to rotation matrix. Non-unit quaternions are normalised implicitly."""
    q = _as_float(quaternion)
    _check_trailing(q, (4,), "quaternion")
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    s = 2.0 / jnp.sum(q * q, axis=-1)
    return _from_rows([
        [1.0 - s * (y * y + z * z), s * (x * y - w * z), s * (x * z + w * y)],
        [s * (x * y + w * z), 1.0 - s * (x * x + z * z), s * (y * z - w * x)],
        [s * (x * z - w * y), s * (y * z + w * x), 1.0 - s * (x * x + y * y)],
    ])


def matrix_to_quaternion(matrix: Float[ArrayLike, "*batch 3 3"]) -> Float[Array, "*batch 4"]:
    """Rotation matrix to unit (w, x, y, z) quaternion with ``w >= 0`` (Shepperd's method).

    Each of the four classic formulas divides by ``4 q_i`` for one component; using the largest
    component (always >= 1/2) keeps the result accurate for every rotation, including angle pi."""
    m = _as_float(matrix)
    _check_trailing(m, (3, 3), "matrix")
    m00, m01, m02 = m[..., 0, 0], m[..., 0, 1], m[..., 0, 2]
    m10, m11, m12 = m[..., 1, 0], m[..., 1, 1], m[..., 1, 2]
    m20, m21, m22 = m[..., 2, 0], m[..., 2, 1], m[..., 2, 2]
    # 4 q_i^2 for i = w, x, y, z, and the four candidates (each proportional to q).
    four_sq = jnp.stack([1.0 + m00 + m11 + m22, 1.0 + m00 - m11 - m22,
                         1.0 - m00 + m11 - m22, 1.0 - m00 - m11 + m22], axis=-1)
    candidates = jnp.stack([
        jnp.stack([four_sq[..., 0], m21 - m12, m02 - m20, m10 - m01], axis=-1),
        jnp.stack([m21 - m12, four_sq[..., 1], m01 + m10, m02 + m20], axis=-1),
        jnp.stack([m02 - m20, m01 + m10, four_sq[..., 2], m12 + m21], axis=-1),
        jnp.stack([m10 - m01, m02 + m20, m12 + m21, four_sq[..., 3]], axis=-1),
    ], axis=-2)
    # Unselected candidates may have four_sq <= 0; the floor keeps their (discarded) gradients finite.
    candidates = candidates / (2.0 * jnp.sqrt(jnp.maximum(four_sq, 0.1)))[..., None]
    best = jnp.argmax(four_sq, axis=-1)
    q = jnp.take_along_axis(candidates, best[..., None, None], axis=-2)[..., 0, :]
    return _canonical(q / jnp.linalg.norm(q, axis=-1, keepdims=True))


def axis_angle_to_quaternion(rotvec: Float[ArrayLike, "*batch 3"]) -> Float[Array, "*batch 4"]:
    """Rotation vector to unit (w, x, y, z) quaternion: ``(cos(t/2), sin(t/2) * axis)``."""
    rotvec = _as_float(rotvec)
    _check_trailing(rotvec, (3,), "rotvec")
    theta_sq = jnp.sum(rotvec * rotvec, axis=-1)
    small = theta_sq < _SMALL_ANGLE_SQ
    theta = jnp.sqrt(jnp.where(small, 1.0, theta_sq))
    w = jnp.where(small, 1.0 - theta_sq / 8.0 * (1.0 - theta_sq / 48.0), jnp.cos(0.5 * theta))
    # sin(t/2) / t
    scale = jnp.where(small, 0.5 * (1.0 - theta_sq / 24.0 * (1.0 - theta_sq / 80.0)),
                      jnp.sin(0.5 * theta) / theta)
    return _canonical(jnp.concatenate([w[..., None], scale[..., None] * rotvec], axis=-1))


def quaternion_to_axis_angle(quaternion: Float[ArrayLike, "*batch 4"]) -> Float[Array, "*batch 3"]:
    """(w, x, y, z) quaternion (any norm) to rotation vector with angle in [0, pi]."""
    q = _canonical(_as_float(quaternion))
    _check_trailing(q, (4,), "quaternion")
    w, v = q[..., 0], q[..., 1:]
    n_sq = jnp.sum(v * v, axis=-1)
    # n_sq / w^2 = tan^2(t/2); below 1e-8 the series 2 atan(n/w)/n = 2/w (1 - u/3 + u^2/5) is exact.
    small = n_sq < 1e-8 * w * w
    n = jnp.sqrt(jnp.where(small, 1.0, n_sq))
    w_safe = jnp.where(small, w, 1.0)
    u = n_sq / (w_safe * w_safe)
    scale = jnp.where(small, 2.0 / w_safe * (1.0 - u / 3.0 + u * u / 5.0), 2.0 * jnp.arctan2(n, w) / n)
    return scale[..., None] * v


def quaternion_multiply(q1: Float[ArrayLike, "*#batch 4"], q2: Float[ArrayLike, "*#batch 4"]
                        ) -> Float[Array, "*#batch 4"]:
    """Hamilton product ``q1 * q2``: the rotation ``R(q1) @ R(q2)`` (apply q2 first)."""
    q1, q2 = _as_float(q1), _as_float(q2)
    _check_trailing(q1, (4,), "q1")
    _check_trailing(q2, (4,), "q2")
    q1, q2 = _broadcast_batch((q1, 1), (q2, 1))
    w1, x1, y1, z1 = (q1[..., i] for i in range(4))
    w2, x2, y2, z2 = (q2[..., i] for i in range(4))
    return jnp.stack([
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
    ], axis=-1)


def quaternion_conjugate(quaternion: Float[ArrayLike, "*batch 4"]) -> Float[Array, "*batch 4"]:
    """``(w, -x, -y, -z)``: the inverse rotation for unit quaternions."""
    q = _as_float(quaternion)
    _check_trailing(q, (4,), "quaternion")
    return jnp.concatenate([q[..., :1], -q[..., 1:]], axis=-1)


def quaternion_inverse(quaternion: Float[ArrayLike, "*batch 4"]) -> Float[Array, "*batch 4"]:
    """Multiplicative inverse ``conj(q) / |q|^2`` (equals the conjugate for unit quaternions)."""
    q = _as_float(quaternion)
    return quaternion_conjugate(q) / jnp.sum(q * q, axis=-1, keepdims=True)


def quaternion_slerp(q0: Float[ArrayLike, "*#batch 4"], q1: Float[ArrayLike, "*#batch 4"],
                     t: Float[ArrayLike, "*#batch"]) -> Float[Array, "*#batch 4"]:
    """Spherical linear interpolation of unit quaternions along the shorter arc; ``t`` in [0, 1].

    Nearly equal rotations fall back to normalised linear interpolation (the slerp weights are 0/0)."""
    q0, q1, t = _as_float(q0), _as_float(q1), _as_float(t)
    _check_trailing(q0, (4,), "q0")
    _check_trailing(q1, (4,), "q1")
    q0, q1, t = _broadcast_batch((q0, 1), (q1, 1), (t, 0))
    dot = jnp.sum(q0 * q1, axis=-1)
    q1 = jnp.where((dot < 0)[..., None], -q1, q1)
    dot = jnp.abs(dot)
    # 1 - 1e-9 is 1.0 in float32: equal quaternions (dot exactly 1) would divide 0 by 0. Scale to the precision.
    near = dot > 1.0 - max(1e-9, 8 * float(jnp.finfo(dot.dtype).eps))
    omega = jnp.arccos(jnp.where(near, 0.5, jnp.minimum(dot, 1.0)))
    w0 = jnp.where(near, 1.0 - t, jnp.sin((1.0 - t) * omega) / jnp.sin(omega))
    w1 = jnp.where(near, t, jnp.sin(t * omega) / jnp.sin(omega))
    q = w0[..., None] * q0 + w1[..., None] * q1
    return _canonical(q / jnp.linalg.norm(q, axis=-1, keepdims=True))


# --------------------------------------------------------------------------------------------
# 6D representation


def matrix_to_rotation_6d(matrix: Float[ArrayLike, "*batch 3 3"]) -> Float[Array, "*batch 6"]:
    """First two columns of ``R``, concatenated: ``(R00, R10, R20, R01, R11, R21)``."""
    m = _as_float(matrix)
    _check_trailing(m, (3, 3), "matrix")
    return jnp.concatenate([m[..., :, 0], m[..., :, 1]], axis=-1)


def rotation_6d_to_matrix(rot6d: Float[ArrayLike, "*batch 6"]) -> Float[Array, "*batch 3 3"]:
    """Gram-Schmidt on the two 3-vectors of a 6D vector; they become columns 0 and 1 of ``R``.

    Any pair of non-parallel vectors maps to a rotation (the continuity of Zhou et al.)."""
    r = _as_float(rot6d)
    _check_trailing(r, (6,), "rot6d")
    a1, a2 = r[..., :3], r[..., 3:]
    b1 = a1 / jnp.linalg.norm(a1, axis=-1, keepdims=True)
    a2 = a2 - jnp.sum(b1 * a2, axis=-1, keepdims=True) * b1
    b2 = a2 / jnp.linalg.norm(a2, axis=-1, keepdims=True)
    return jnp.stack([b1, b2, jnp.cross(b1, b2)], axis=-1)


# --------------------------------------------------------------------------------------------
# Euler angles

_AXES = "XYZ"


def _parse_order(order: str, *, tait_bryan: bool) -> tuple[int, int, int]:
    if (not isinstance(order, str) or len(order) != 3 or any(c not in _AXES for c in order)
            or order[0] == order[1] or order[1] == order[2]):
        raise ValueError(f"Euler order must be 3 upper-case axes from 'XYZ' with no axis repeated "
                         f"consecutively (e.g. 'ZYX', 'XYZ'), got {order!r}")
    if tait_bryan and order[0] == order[2]:
        raise ValueError(f"only Tait-Bryan orders (three distinct axes) are supported, got {order!r}")
    return tuple(_AXES.index(c) for c in order)  # type: ignore[return-value]


def _axis_rotation(axis: int, angle: Array) -> Array:
    c, s = jnp.cos(angle), jnp.sin(angle)
    one, zero = jnp.ones_like(angle), jnp.zeros_like(angle)
    if axis == 0:
        rows = [[one, zero, zero], [zero, c, -s], [zero, s, c]]
    elif axis == 1:
        rows = [[c, zero, s], [zero, one, zero], [-s, zero, c]]
    else:
        rows = [[c, -s, zero], [s, c, zero], [zero, zero, one]]
    return _from_rows(rows)


def euler_to_matrix(angles: Float[ArrayLike, "*batch 3"], order: str) -> Float[Array, "*batch 3 3"]:
    """Euler angles (radians) to a rotation matrix, ``R = R_{order[0]}(a0) @ R_{order[1]}(a1) @ R_{order[2]}(a2)``.

    This is the BVH convention (channels "Zrotation Yrotation Xrotation" -> ``order="ZYX"``) and
    SciPy's intrinsic ``Rotation.from_euler(order.upper(), angles)``. ``order`` is a static string."""
    axes = _parse_order(order, tait_bryan=False)
    angles = _as_float(angles)
    _check_trailing(angles, (3,), "angles")
    r = _axis_rotation(axes[0], angles[..., 0])
    for i in (1, 2):
        r = _matmul(r, _axis_rotation(axes[i], angles[..., i]))
    return r


def matrix_to_euler(matrix: Float[ArrayLike, "*batch 3 3"], order: str) -> Float[Array, "*batch 3"]:
    """Inverse of :func:`euler_to_matrix` for the six Tait-Bryan orders.

    The middle angle is in [-pi/2, pi/2], the others in (-pi, pi]. At gimbal lock (middle angle
    +-pi/2) only a0 +- a2 is determined; the last angle is then set to 0, as SciPy does."""
    i, j, k = _parse_order(order, tait_bryan=True)
    m = _as_float(matrix)
    _check_trailing(m, (3, 3), "matrix")
    # +1 for cyclic orders (XYZ, YZX, ZXY): then R[i, k] = sin(a1), else R[i, k] = -sin(a1).
    sign = 1.0 if (j - i) % 3 == 1 else -1.0
    cos_middle = jnp.hypot(m[..., i, i], m[..., i, j])
    middle = jnp.arctan2(sign * m[..., i, k], cos_middle)
    locked = cos_middle < 1e-7
    first = jnp.where(locked, jnp.arctan2(sign * m[..., k, j], m[..., j, j]),
                      jnp.arctan2(-sign * m[..., j, k], m[..., k, k]))
    last = jnp.where(locked, 0.0, jnp.arctan2(-sign * m[..., i, j], m[..., i, i]))
    return jnp.stack([first, middle, last], axis=-1)


# --------------------------------------------------------------------------------------------
# Comparing rotations


def relative_rotation(rotation_a: Float[ArrayLike, "*#batch 3 3"], rotation_b: Float[ArrayLike, "*#batch 3 3"]
                      ) -> Float[Array, "*#batch 3 3"]:
    """``R_a^T @ R_b``: the rotation from frame a to frame b expressed in frame a, so ``R_b = R_a @ rel``.

    (E.g. a joint's local rotation from its parent's and its own global rotations.)"""
    a, b = _as_float(rotation_a), _as_float(rotation_b)
    _check_trailing(a, (3, 3), "rotation_a")
    _check_trailing(b, (3, 3), "rotation_b")
    return _matmul(_transpose(a), b)


def rotation_between(a: Float[ArrayLike, "*#batch 3"], b: Float[ArrayLike, "*#batch 3"]) -> Float[Array, "*#batch 3 3"]:
    """The smallest rotation taking the direction of ``a`` to that of ``b`` (no twist about either).

    Opposite directions get half a turn about an axis normal to ``a``; a zero vector gives the identity."""
    a, b = _as_float(a), _as_float(b)
    _check_trailing(a, (3,), "a")
    _check_trailing(b, (3,), "b")
    a, b = jnp.broadcast_arrays(a / jnp.maximum(safe_norm(a), 1e-30)[..., None],
                                b / jnp.maximum(safe_norm(b), 1e-30)[..., None])
    cross = jnp.cross(a, b)
    sine, cosine = jnp.linalg.norm(cross, axis=-1), jnp.sum(a * b, axis=-1)
    opposite = (sine < 1e-9) & (cosine < 0)
    unit_x, unit_y = jnp.eye(3, dtype=a.dtype)[:2]
    fallback = jnp.cross(a, jnp.where(jnp.abs(a[..., :1]) < 0.9, unit_x, unit_y))
    fallback = fallback / jnp.maximum(safe_norm(fallback), 1e-12)[..., None]
    axis = jnp.where(opposite[..., None], fallback, cross / jnp.maximum(sine, 1e-30)[..., None])
    angle = jnp.arctan2(sine, cosine)
    # sin(angle) ~ angle near 0, so cross ~ axis * angle there: no 0 / 0.
    rotvec = jnp.where((sine < 1e-9)[..., None] & ~opposite[..., None], cross, axis * angle[..., None])
    return axis_angle_to_matrix(rotvec)


def rotation_angle(matrix: Float[ArrayLike, "*batch 3 3"]) -> Float[Array, "*batch"]:
    """Rotation angle in [0, pi] (radians), from ``atan2(|vee(R - R^T)| / 2, (tr R - 1) / 2)``.

    The atan2 form is accurate at both ends, where ``arccos`` of the trace loses half the digits."""
    m = _as_float(matrix)
    _check_trailing(m, (3, 3), "matrix")
    vee = jnp.stack([m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]], -1)
    cos = 0.5 * (m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2] - 1.0)
    return jnp.arctan2(0.5 * safe_norm(vee), cos)


def geodesic_distance(rotation_a: Float[ArrayLike, "*#batch 3 3"], rotation_b: Float[ArrayLike, "*#batch 3 3"]
                      ) -> Float[Array, "*#batch"]:
    """Angle (radians, in [0, pi]) of the rotation between two rotations: the geodesic distance on SO(3)."""
    return rotation_angle(relative_rotation(rotation_a, rotation_b))

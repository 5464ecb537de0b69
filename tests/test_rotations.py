"""Rotations against OpenCV and SciPy, round-trip properties, and gradients at the identity."""

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose
from scipy.spatial.transform import Rotation, Slerp

import geometry as g

TAIT_BRYAN = ("XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX")
PROPERTY = settings(max_examples=25, deadline=None)


class _Jitted:
    """``jg.f`` is ``jax.jit(geometry.f)``: one compile per shape instead of one per primitive (eager
    first calls cost ~1 s each); :func:`test_jit_equals_eager` checks the two agree."""

    def __getattr__(self, name):
        return jax.jit(getattr(g, name), static_argnames=("order",) if "euler" in name else ())


jg = _Jitted()


def _rotvecs(rng: np.random.Generator, n: int) -> np.ndarray:
    """Random axes with angles spanning tiny, ordinary and nearly-pi rotations."""
    axes = rng.normal(size=(n, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = np.concatenate([10.0 ** rng.uniform(-12, -2, n // 4), rng.uniform(0, np.pi, n - n // 2),
                             np.pi - 10.0 ** rng.uniform(-9, -2, n // 4)])
    return axes * angles[:, None]


def _random_matrices(rng: np.random.Generator, n: int) -> np.ndarray:
    return Rotation.random(n, random_state=rng).as_matrix()


def _assert_rotation(m, atol=1e-12):
    m = np.asarray(m)
    assert_allclose(np.swapaxes(m, -1, -2) @ m, np.broadcast_to(np.eye(3), m.shape), atol=atol)
    assert_allclose(np.linalg.det(m), 1.0, atol=atol)


rotvec_strategy = st.tuples(
    st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1), st.floats(0, np.pi - 1e-6)
).filter(lambda v: np.linalg.norm(v[:3]) > 1e-3).map(
    lambda v: np.array(v[:3]) / np.linalg.norm(v[:3]) * v[3])
six_d_strategy = st.lists(st.floats(-10, 10), min_size=6, max_size=6).map(np.array).filter(
    lambda v: np.linalg.norm(np.cross(v[:3], v[3:])) > 1e-2 * np.linalg.norm(v[:3]) * np.linalg.norm(v[3:]) + 1e-6)


# ---------------------------------------------------------------------------------------------- OpenCV


def test_axis_angle_to_matrix_matches_cv2_rodrigues():
    r = _rotvecs(np.random.default_rng(0), 200)
    ours = np.asarray(jg.axis_angle_to_matrix(r))
    ref = np.stack([cv2.Rodrigues(v)[0] for v in r])
    assert_allclose(ours, ref, atol=1e-14)
    _assert_rotation(ours)


def test_matrix_to_axis_angle_matches_cv2_rodrigues():
    r = _rotvecs(np.random.default_rng(1), 200)
    matrices = np.stack([cv2.Rodrigues(v)[0] for v in r])
    ours = np.asarray(jg.matrix_to_axis_angle(matrices))
    ref = np.stack([cv2.Rodrigues(m)[0][:, 0] for m in matrices])
    assert_allclose(ours, r, atol=1e-8, rtol=0)  # the input vectors themselves, including near pi
    # cv2 returns 0 below ~1e-5 rad and loses digits near pi; compare in its accurate range.
    ok = (np.linalg.norm(r, axis=1) > 1e-4) & (np.linalg.norm(r, axis=1) < np.pi - 1e-3)
    assert ok.sum() > 100
    assert_allclose(ours[ok], ref[ok], atol=1e-12)


def test_matrix_to_axis_angle_exactly_pi_and_identity():
    axes = np.array([[1.0, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [1, -2, 3]])
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    r = np.pi * axes
    out = np.asarray(jg.matrix_to_axis_angle(jg.axis_angle_to_matrix(r)))
    assert_allclose(np.linalg.norm(out, axis=1), np.pi, atol=1e-12)
    assert_allclose(np.abs(np.sum(out * axes, axis=1)), np.pi, atol=1e-12)  # axis up to sign
    assert_allclose(np.asarray(jg.matrix_to_axis_angle(np.eye(3))), np.zeros(3), atol=0)


# ----------------------------------------------------------------------------------------------- SciPy


def test_quaternions_match_scipy():
    rng = np.random.default_rng(2)
    rot = Rotation.random(100, random_state=rng)
    ref_wxyz = rot.as_quat(canonical=True)[:, [3, 0, 1, 2]]
    assert_allclose(np.asarray(jg.matrix_to_quaternion(rot.as_matrix())), ref_wxyz, atol=1e-14)
    assert_allclose(np.asarray(jg.quaternion_to_matrix(ref_wxyz)), rot.as_matrix(), atol=1e-14)
    assert_allclose(np.asarray(jg.axis_angle_to_quaternion(rot.as_rotvec())), ref_wxyz, atol=1e-14)
    assert_allclose(np.asarray(jg.quaternion_to_axis_angle(ref_wxyz)), rot.as_rotvec(), atol=1e-13)
    # Any sign and norm of the quaternion is the same rotation.
    assert_allclose(np.asarray(jg.quaternion_to_matrix(-2.5 * ref_wxyz)), rot.as_matrix(), atol=1e-14)
    assert_allclose(np.asarray(jg.quaternion_to_axis_angle(-0.3 * ref_wxyz)), rot.as_rotvec(), atol=1e-13)


def test_quaternion_multiply_and_inverse_match_scipy():
    rng = np.random.default_rng(3)
    a, b = Rotation.random(50, random_state=rng), Rotation.random(50, random_state=rng)
    qa, qb = (r.as_quat()[:, [3, 0, 1, 2]] for r in (a, b))
    product = np.asarray(jg.quaternion_multiply(qa, qb))
    assert_allclose(np.asarray(jg.quaternion_to_matrix(product)), (a * b).as_matrix(), atol=1e-14)
    assert_allclose(np.asarray(jg.quaternion_to_matrix(product)), a.as_matrix() @ b.as_matrix(), atol=1e-14)
    assert_allclose(np.asarray(jg.quaternion_conjugate(qa)), a.inv().as_quat()[:, [3, 0, 1, 2]], atol=1e-15)
    identity = np.asarray(jg.quaternion_multiply(3.0 * qa, jg.quaternion_inverse(3.0 * qa)))
    assert_allclose(identity, np.broadcast_to([1.0, 0, 0, 0], identity.shape), atol=1e-14)
    # Broadcasting: one quaternion times a batch.
    assert_allclose(np.asarray(jg.quaternion_multiply(qa[0], qb)), np.asarray(jg.quaternion_multiply(
        np.broadcast_to(qa[0], qb.shape), qb)), atol=0)


def test_slerp_matches_scipy():
    rng = np.random.default_rng(4)
    keys = Rotation.random(2, random_state=rng)
    times = np.linspace(0.0, 1.0, 11)
    ref = Slerp([0.0, 1.0], keys)(times).as_matrix()
    q = keys.as_quat()[:, [3, 0, 1, 2]]
    ours = jg.quaternion_to_matrix(jg.quaternion_slerp(q[0], -q[1], times))  # sign of q1 must not matter
    assert_allclose(np.asarray(ours), ref, atol=1e-13)
    same = np.asarray(jg.quaternion_slerp(q[0], q[0], times))
    assert_allclose(same, np.broadcast_to(jg.matrix_to_quaternion(keys[0].as_matrix()), same.shape), atol=1e-15)
    # In float32 too (equal quaternions once gave 0/0 there: mocap.resample_motion at 120 -> 25 Hz).
    single = np.asarray(jg.quaternion_slerp(q[0].astype(np.float32), q[0].astype(np.float32), times.astype(np.float32)))
    assert single.dtype == np.float32
    assert_allclose(single, np.broadcast_to(q[0] * np.sign(q[0][0]), single.shape), atol=1e-6)


@pytest.mark.parametrize("order", TAIT_BRYAN + ("ZXZ", "XYX"))
def test_euler_to_matrix_matches_scipy_intrinsic(order):
    angles = np.random.default_rng(5).uniform(-np.pi, np.pi, size=(50, 3))
    assert_allclose(np.asarray(jg.euler_to_matrix(angles, order)),
                    Rotation.from_euler(order, angles).as_matrix(), atol=1e-14)


def test_euler_to_matrix_is_the_bvh_channel_product():
    a, b, c = 0.3, -1.1, 2.0
    rz, ry, rx = (jg.euler_to_matrix(np.array(v), "XYZ")
                  for v in ([0.0, 0.0, a], [0.0, b, 0.0], [c, 0.0, 0.0]))
    assert_allclose(np.asarray(jg.euler_to_matrix(np.array([a, b, c]), "ZYX")),
                    np.asarray(rz) @ np.asarray(ry) @ np.asarray(rx), atol=1e-15)
    assert_allclose(np.asarray(rz), Rotation.from_rotvec([0, 0, a]).as_matrix(), atol=1e-15)


@pytest.mark.parametrize("order", TAIT_BRYAN)
def test_matrix_to_euler_matches_scipy(order):
    matrices = _random_matrices(np.random.default_rng(6), 100)
    ours = np.asarray(jg.matrix_to_euler(matrices, order))
    assert_allclose(ours, Rotation.from_matrix(matrices).as_euler(order), atol=1e-12)
    assert_allclose(np.asarray(jg.euler_to_matrix(ours, order)), matrices, atol=1e-14)


@pytest.mark.parametrize("order", TAIT_BRYAN)
@pytest.mark.parametrize("middle", [np.pi / 2, -np.pi / 2])
def test_matrix_to_euler_at_gimbal_lock_reconstructs_the_matrix(order, middle):
    matrix = np.asarray(jg.euler_to_matrix(np.array([0.7, middle, -0.4]), order))
    angles = np.asarray(jg.matrix_to_euler(matrix, order))
    assert np.isfinite(angles).all() and angles[2] == 0.0
    assert_allclose(np.asarray(jg.euler_to_matrix(angles, order)), matrix, atol=1e-12)


@pytest.mark.parametrize("bad", ["ZZX", "zyx", "XY", "XYW", "XYZX"])
def test_bad_euler_order_raises(bad):
    with pytest.raises(ValueError, match="Euler order"):
        jg.euler_to_matrix(np.zeros(3), bad)


def test_matrix_to_euler_refuses_proper_euler_orders():
    with pytest.raises(ValueError, match="Tait-Bryan"):
        jg.matrix_to_euler(np.eye(3), "ZXZ")


def test_relative_rotation_and_geodesic_distance_match_scipy():
    rng = np.random.default_rng(7)
    a, b = Rotation.random(50, random_state=rng), Rotation.random(50, random_state=rng)
    rel = np.asarray(jg.relative_rotation(a.as_matrix(), b.as_matrix()))
    assert_allclose(a.as_matrix() @ rel, b.as_matrix(), atol=1e-14)
    assert_allclose(np.asarray(jg.geodesic_distance(a.as_matrix(), b.as_matrix())),
                    (a.inv() * b).magnitude(), atol=1e-12)
    # Broadcast one rotation against a batch.
    assert_allclose(np.asarray(jg.geodesic_distance(np.eye(3), b.as_matrix())), b.magnitude(), atol=1e-12)


def test_rotation_angle_is_accurate_at_both_ends():
    angles = np.array([0.0, 1e-12, 1e-8, 1e-4, 1.0, np.pi - 1e-8, np.pi])
    matrices = jg.axis_angle_to_matrix(angles[:, None] * np.array([0.0, 0.6, 0.8]))
    assert_allclose(np.asarray(jg.rotation_angle(matrices)), angles, rtol=1e-12, atol=1e-15)


# -------------------------------------------------------------------------------------- round trips


@PROPERTY
@given(rotvec_strategy)
def test_round_trips_through_every_representation(rotvec):
    matrix = np.asarray(jg.axis_angle_to_matrix(rotvec))
    _assert_rotation(matrix)
    assert_allclose(np.asarray(jg.matrix_to_axis_angle(matrix)), rotvec, atol=1e-9)
    quat = jg.matrix_to_quaternion(matrix)
    assert_allclose(float(jnp.linalg.norm(quat)), 1.0, atol=1e-15)
    assert_allclose(np.asarray(jg.quaternion_to_matrix(quat)), matrix, atol=1e-14)
    assert_allclose(np.asarray(jg.quaternion_to_axis_angle(jg.axis_angle_to_quaternion(rotvec))), rotvec, atol=1e-12)
    assert_allclose(np.asarray(jg.rotation_6d_to_matrix(jg.matrix_to_rotation_6d(matrix))), matrix, atol=1e-14)
    for order in TAIT_BRYAN:
        assert_allclose(np.asarray(jg.euler_to_matrix(jg.matrix_to_euler(matrix, order), order)), matrix, atol=1e-12)


@PROPERTY
@given(six_d_strategy)
def test_any_6d_vector_maps_to_a_rotation_keeping_its_first_column_direction(rot6d):
    matrix = np.asarray(jg.rotation_6d_to_matrix(rot6d))
    _assert_rotation(matrix)
    assert_allclose(matrix[:, 0], rot6d[:3] / np.linalg.norm(rot6d[:3]), atol=1e-14)
    assert np.dot(matrix[:, 1], rot6d[3:]) > 0  # second column in the half-plane of the second vector


vector_pair_strategy = st.lists(st.floats(-10, 10), min_size=6, max_size=6).map(np.array).filter(
    lambda v: np.linalg.norm(v[:3]) > 1e-3 and np.linalg.norm(v[3:]) > 1e-3)


@PROPERTY
@given(vector_pair_strategy)
def test_rotation_between_takes_a_to_b_without_twist(v):
    a, b = v[:3], v[3:]
    matrix = np.asarray(jg.rotation_between(a, b))
    _assert_rotation(matrix)
    assert_allclose(matrix @ (a / np.linalg.norm(a)), b / np.linalg.norm(b), atol=1e-12)
    # No twist: the rotation angle is the angle between the vectors.
    angle = np.arctan2(np.linalg.norm(np.cross(a, b)), a @ b)
    assert_allclose(float(jg.rotation_angle(matrix)), angle, atol=1e-7)


def test_rotation_between_opposite_and_equal_directions():
    a = np.array([0.3, -1.2, 0.5])
    half_turn = np.asarray(jg.rotation_between(a, -2 * a))
    _assert_rotation(half_turn)
    assert_allclose(half_turn @ a, -a, atol=1e-12)
    assert_allclose(np.asarray(jg.rotation_between(a, 3 * a)), np.eye(3), atol=1e-14)


def test_6d_is_the_first_two_columns():
    matrix = _random_matrices(np.random.default_rng(8), 1)[0]
    assert_allclose(np.asarray(jg.matrix_to_rotation_6d(matrix)), np.concatenate([matrix[:, 0], matrix[:, 1]]))


def test_float32_stays_orthonormal():
    r = _rotvecs(np.random.default_rng(9), 40).astype(np.float32)
    matrix = jg.axis_angle_to_matrix(r)
    assert matrix.dtype == jnp.float32
    _assert_rotation(matrix, atol=2e-6)
    # Near pi the float32 axis may flip sign (r and -r are the same rotation there): compare matrices.
    assert_allclose(np.asarray(jg.axis_angle_to_matrix(jg.matrix_to_axis_angle(matrix))), matrix, atol=2e-6)


# -------------------------------------------------------------------------------------- gradients, jit


def test_gradient_of_rodrigues_at_exactly_zero_is_the_generator():
    weights = np.random.default_rng(10).normal(size=(3, 3))
    grad = np.asarray(jax.grad(lambda r: jnp.sum(weights * jg.axis_angle_to_matrix(r)))(jnp.zeros(3)))
    # dR/dr_i at 0 is the cross-product matrix [e_i]_x.
    generators = np.stack([_skew(e) for e in np.eye(3)])
    assert_allclose(grad, np.einsum("ij,kij->k", weights, generators), atol=1e-15)


def _skew(v):
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


@pytest.mark.parametrize("scale", [0.0, 1e-4, 0.999e-3, 1.001e-3, 0.5])
def test_rodrigues_jacobian_matches_finite_differences_across_the_series_switch(scale):
    r = scale * np.array([0.48, -0.6, 0.64])
    jac = np.asarray(jax.jacfwd(jg.axis_angle_to_matrix)(r))
    eps = 1e-6
    fd = np.stack([(cv2.Rodrigues(r + eps * e)[0] - cv2.Rodrigues(r - eps * e)[0]) / (2 * eps)
                   for e in np.eye(3)], axis=-1)
    assert_allclose(jac, fd, atol=1e-8)


def test_gradients_are_finite_at_the_identity():
    def all_maps(r):
        matrix = g.axis_angle_to_matrix(r)
        quat = g.matrix_to_quaternion(matrix)
        return (jnp.sum(g.matrix_to_axis_angle(matrix)) + jnp.sum(g.quaternion_to_axis_angle(quat))
                + jnp.sum(g.axis_angle_to_quaternion(r)) + g.rotation_angle(matrix)
                + jnp.sum(g.matrix_to_euler(matrix, "ZYX"))
                + jnp.sum(g.rotation_6d_to_matrix(g.matrix_to_rotation_6d(matrix)))
                + jnp.sum(g.quaternion_slerp(quat, quat, 0.3)))
    grad = np.asarray(jax.jit(jax.grad(all_maps))(jnp.zeros(3)))
    assert np.isfinite(grad).all()
    # log(exp(r)) = r: the Jacobian of the round trip at the identity is I.
    jac = np.asarray(jax.jit(jax.jacfwd(lambda r: g.matrix_to_axis_angle(g.axis_angle_to_matrix(r))))(jnp.zeros(3)))
    assert_allclose(jac, np.eye(3), atol=1e-15)


def test_jit_equals_eager():
    rng = np.random.default_rng(11)
    r = _rotvecs(rng, 8).reshape(2, 4, 3)
    q = np.asarray(g.axis_angle_to_quaternion(r))
    cases = [
        (lambda x: g.matrix_to_axis_angle(g.axis_angle_to_matrix(x)), (r,)),
        (lambda x: g.matrix_to_euler(g.euler_to_matrix(x, "YXZ"), "YXZ"), (r,)),
        (lambda a, b: g.quaternion_slerp(g.quaternion_multiply(a, b), b, 0.25), (q, q[::-1])),
        (lambda x: g.geodesic_distance(g.rotation_6d_to_matrix(g.matrix_to_rotation_6d(g.quaternion_to_matrix(x))),
                                       np.eye(3)), (q,)),
    ]
    for fn, args in cases:
        assert_allclose(np.asarray(jax.jit(fn)(*args)), np.asarray(fn(*args)), atol=1e-14)


def test_wrong_shapes_raise():
    for fn, bad in [(g.axis_angle_to_matrix, np.zeros((5, 4))), (g.matrix_to_quaternion, np.zeros((3, 4))),
                    (g.quaternion_to_matrix, np.zeros(3)), (g.rotation_6d_to_matrix, np.zeros(5))]:
        with pytest.raises((ValueError, TypeError), match="shape|Type-check"):
            fn(bad)

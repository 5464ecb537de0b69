"""Camera kernels against OpenCV (projection, undistortion) and NumPy (frames, P matrices)."""

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from jaxtyping import TypeCheckError
from numpy.testing import assert_allclose

from geometry import (
    Camera,
    camera_centre,
    camera_from_projection,
    depth,
    look_at,
    point_depth,
    project,
    project_pinhole,
    project_point,
    project_to_views,
    projection_matrix,
    to_camera_frame,
    undistort_points,
)
from geometry._camera import _check_last_axis, _distort, _distortion_jacobian

REALISTIC_DIST = np.array([-0.3, 0.1, 1e-3, -1e-3, 0.02])
seeds = given(st.integers(0, 2**32 - 1))
few = settings(max_examples=25, deadline=None)


def random_camera(rng, *, skew=0.0, dist=None) -> Camera:
    K = np.array([[rng.uniform(500, 1500), skew, rng.uniform(400, 600)],
                  [0.0, rng.uniform(500, 1500), rng.uniform(300, 500)],
                  [0.0, 0.0, 1.0]])
    R = cv2.Rodrigues(rng.normal(size=3))[0]
    dist = rng.normal(size=5) * np.array([0.1, 0.05, 1e-3, 1e-3, 0.01]) if dist is None else dist
    return Camera.create(K, R, rng.normal(size=3), dist, (1000.0, 800.0))


def points_in_front(rng, camera: Camera, n: int) -> np.ndarray:
    """World points whose normalised coordinates lie within +-0.6 at depths 1-6 m."""
    z = rng.uniform(1.0, 6.0, n)
    x_cam = np.stack([rng.uniform(-0.6, 0.6, n) * z, rng.uniform(-0.6, 0.6, n) * z, z], axis=-1)
    R, t = np.asarray(camera.R), np.asarray(camera.t)
    return (x_cam - t) @ R


def cv2_project(camera: Camera, points: np.ndarray) -> np.ndarray:
    rvec = cv2.Rodrigues(np.asarray(camera.R))[0]
    px, _ = cv2.projectPoints(points, rvec, np.asarray(camera.t), np.asarray(camera.K), np.asarray(camera.dist))
    return px[:, 0]


@few
@seeds
def test_project_matches_cv2(seed):
    rng = np.random.default_rng(seed)
    camera = random_camera(rng)
    points = points_in_front(rng, camera, 200)
    assert_allclose(project(camera, points), cv2_project(camera, points), atol=1e-6, rtol=0)


@few
@seeds
def test_project_honours_skew(seed):
    rng = np.random.default_rng(seed)
    camera = random_camera(rng, skew=rng.uniform(-5, 5))
    points = points_in_front(rng, camera, 50)
    # OpenCV ignores skew: get distorted normalised coordinates from it with K = I, apply K here.
    unit = camera._replace(K=jnp.eye(3))
    distorted = np.concatenate([cv2_project(unit, points), np.ones((50, 1))], axis=-1)
    expected = (distorted @ np.asarray(camera.K).T)[:, :2]
    assert_allclose(project(camera, points), expected, atol=1e-6, rtol=0)


def test_project_leading_axes_and_jit():
    rng = np.random.default_rng(1)
    camera = random_camera(rng, skew=0.3)
    points = points_in_front(rng, camera, 24).reshape(2, 3, 4, 3)
    out = project(camera, points)
    assert out.shape == (2, 3, 4, 2)
    assert_allclose(out.reshape(-1, 2), project(camera, points.reshape(-1, 3)), rtol=1e-14)
    assert_allclose(jax.jit(project)(camera, points), out, rtol=1e-12, atol=1e-9)
    assert project(camera, points[0, 0, 0]).shape == (2,)
    assert_allclose(project(camera, points[0, 0, 0]), project_point(camera, points[0, 0, 0]), rtol=1e-14)


def test_project_to_views_matches_per_view_cv2():
    rng = np.random.default_rng(2)
    cams = [random_camera(rng) for _ in range(4)]
    rig = jax.tree.map(lambda *leaves: jnp.stack(leaves), *cams)
    points = rng.normal(size=(5, 7, 3)) * 0.3
    # t = (0, 0, 8) puts every camera 8 m from the origin looking at it, so the points are in front.
    rig = rig._replace(t=jnp.broadcast_to(jnp.array([0.0, 0.0, 8.0]), rig.t.shape))
    out = project_to_views(rig, points)
    assert out.shape == (4, 5, 7, 2)
    for v in range(4):
        assert_allclose(out[v].reshape(-1, 2), cv2_project(rig.select(v), points.reshape(-1, 3)), atol=1e-6, rtol=0)
    assert_allclose(jax.jit(project_to_views)(rig, points), out, rtol=1e-12, atol=1e-9)


def test_project_pinhole_matches_cv2_and_batches_per_frame():
    rng = np.random.default_rng(5)
    K = np.array([[[300.0, 0, 160], [0, 310, 120], [0, 0, 1]], [[500.0, 0, 320], [0, 500, 240], [0, 0, 1]]])
    points = rng.normal(size=(2, 6, 3)) * 0.4 + np.array([[[0.0, 0.0, 4.0]]])
    out = project_pinhole(K, points)
    for frame in range(2):
        expected, _ = cv2.projectPoints(points[frame], np.zeros(3), np.zeros(3), K[frame], None)
        assert_allclose(out[frame], expected[:, 0], atol=1e-9)
    assert_allclose(jax.jit(project_pinhole)(K, points), out, rtol=1e-14)


def test_camera_frame_and_depth():
    rng = np.random.default_rng(3)
    camera = random_camera(rng)
    points = rng.normal(size=(6, 3))
    expected = points @ np.asarray(camera.R).T + np.asarray(camera.t)
    assert_allclose(jax.vmap(to_camera_frame, in_axes=(None, 0))(camera, points), expected, rtol=1e-12)
    assert_allclose(depth(camera, points.reshape(2, 3, 3)), expected[:, 2].reshape(2, 3), rtol=1e-12)
    assert_allclose(point_depth(camera, points[0]), expected[0, 2], rtol=1e-12)
    behind = np.asarray(camera_centre(camera)) - 2.0 * np.asarray(camera.R[2])
    assert float(point_depth(camera, behind)) == pytest.approx(-2.0)


def test_camera_centre_and_projection_matrix():
    rng = np.random.default_rng(4)
    camera = random_camera(rng, skew=1.5, dist=np.zeros(5))
    centre = np.asarray(camera_centre(camera))
    assert_allclose(np.asarray(camera.R) @ centre + np.asarray(camera.t), 0.0, atol=1e-12)
    P = np.asarray(projection_matrix(camera))
    points = points_in_front(rng, camera, 20)
    homogeneous = np.concatenate([points, np.ones((20, 1))], axis=-1) @ P.T
    assert_allclose(project(camera, points), homogeneous[:, :2] / homogeneous[:, 2:], atol=1e-9)
    rig = jax.tree.map(lambda *leaves: jnp.stack(leaves), camera, random_camera(rng))
    assert projection_matrix(rig).shape == (2, 3, 4)
    assert_allclose(camera_centre(rig)[0], centre, rtol=1e-12)


@few
@seeds
def test_camera_from_projection_round_trip(seed):
    rng = np.random.default_rng(seed)
    camera = random_camera(rng, skew=rng.uniform(-2, 2), dist=np.zeros(5))
    scale = rng.uniform(0.01, 100) * rng.choice([-1.0, 1.0])
    recovered = camera_from_projection(scale * projection_matrix(camera), image_size=(1000.0, 800.0))
    assert_allclose(recovered.K, camera.K, rtol=1e-9, atol=1e-9)
    assert_allclose(recovered.R, camera.R, atol=1e-12)
    assert_allclose(recovered.t, camera.t, atol=1e-9)
    assert float(jnp.linalg.det(recovered.R)) == pytest.approx(1.0)
    assert_allclose(recovered.image_size, camera.image_size)


def test_camera_from_projection_jit_and_dist():
    rng = np.random.default_rng(5)
    camera = random_camera(rng)
    P = projection_matrix(camera)
    eager = camera_from_projection(P, image_size=(1000.0, 800.0), dist=camera.dist)
    jitted = jax.jit(lambda P, d: camera_from_projection(P, image_size=(1000.0, 800.0), dist=d))(P, camera.dist)
    for a, b, c in zip(eager, jitted, camera):
        assert_allclose(a, b, rtol=1e-12, atol=1e-12)
        assert_allclose(a, c, rtol=1e-9, atol=1e-9)


def image_grid(camera: Camera, n: int = 15) -> np.ndarray:
    width, height = np.asarray(camera.image_size)
    u, v = np.meshgrid(np.linspace(0, width - 1, n), np.linspace(0, height - 1, n))
    return np.stack([u.ravel(), v.ravel()], axis=-1)


def realistic_camera() -> Camera:
    K = np.array([[900.0, 0.0, 510.0], [0.0, 905.0, 390.0], [0.0, 0.0, 1.0]])
    return Camera.create(K, np.eye(3), np.zeros(3), REALISTIC_DIST, (1000, 800))


def test_undistort_matches_cv2_default_iteration():
    camera = realistic_camera()
    pixels = image_grid(camera)
    K, dist = np.asarray(camera.K), np.asarray(camera.dist)
    ours = undistort_points(camera, pixels, newton_iterations=0)
    assert_allclose(ours, cv2.undistortPoints(pixels, K, dist)[:, 0], atol=1e-12)


def test_undistort_converges_to_cv2_fixed_point():
    camera = realistic_camera()
    pixels = image_grid(camera)
    K, dist = np.asarray(camera.K), np.asarray(camera.dist)
    converged = (cv2.TERM_CRITERIA_COUNT, 300, 0.0)
    normalised = undistort_points(camera, pixels)
    assert_allclose(normalised, cv2.undistortPoints(pixels, K, dist, criteria=converged)[:, 0], atol=1e-12)
    ideal = undistort_points(camera, pixels, output="pixels")
    assert_allclose(ideal, cv2.undistortPoints(pixels, K, dist, P=K, criteria=converged)[:, 0], atol=1e-9)
    # The default is much closer to the true inverse than OpenCV's default of 5 fixed-point steps.
    cv2_default = cv2.undistortPoints(pixels, K, dist)[:, 0]
    assert np.abs(cv2_default - normalised).max() > 1e-5


@few
@seeds
def test_undistort_inverts_projection(seed):
    rng = np.random.default_rng(seed)
    camera = random_camera(rng, skew=rng.uniform(-2, 2))
    points = points_in_front(rng, camera, 100)
    pixels = project(camera, points)
    x_cam = points @ np.asarray(camera.R).T + np.asarray(camera.t)
    assert_allclose(undistort_points(camera, pixels), x_cam[:, :2] / x_cam[:, 2:], atol=1e-11)
    undistorted_camera = camera._replace(dist=jnp.zeros(5))
    assert_allclose(undistort_points(camera, pixels, output="pixels"), project(undistorted_camera, points), atol=1e-8)


def test_undistort_leading_axes_jit_and_gradient():
    camera = realistic_camera()
    pixels = image_grid(camera, 4).reshape(2, 8, 2)
    eager = undistort_points(camera, pixels)
    assert eager.shape == (2, 8, 2)
    assert_allclose(jax.jit(undistort_points)(camera, pixels), eager, rtol=1e-12, atol=1e-14)
    # The derivative of the inverse is the inverse of the projection Jacobian.
    pixel = jnp.array([100.0, 700.0])
    jac_undistort = jax.jit(jax.jacfwd(lambda p: undistort_points(camera, p)))(pixel)
    xy = undistort_points(camera, pixel)
    jac_project = jax.jit(jax.jacfwd(lambda q: project_point(camera, jnp.concatenate([q, jnp.ones(1)]))))(xy)
    assert_allclose(jac_undistort @ jac_project, np.eye(2), atol=1e-10)


def test_project_gradient_matches_finite_differences():
    rng = np.random.default_rng(6)
    camera = random_camera(rng, skew=0.7)
    point = jnp.asarray(points_in_front(rng, camera, 1)[0])
    jac = jax.jit(jax.jacfwd(project_point, argnums=1))(camera, point)
    eps = 1e-6
    fd = np.stack([(project_point(camera, point + eps * e) - project_point(camera, point - eps * e)) / (2 * eps)
                   for e in np.eye(3)], axis=-1)
    assert_allclose(jac, fd, rtol=1e-6, atol=1e-4)
    grads = jax.jit(jax.grad(lambda cam: jnp.sum(project(cam, point[None, :]))))(camera)
    assert all(bool(jnp.all(jnp.isfinite(g))) for g in grads)
    assert float(jnp.abs(grads.dist).min()) > 0.0


def test_distortion_jacobian_matches_autodiff():
    xy = jnp.array([0.4, -0.3])
    assert_allclose(_distortion_jacobian(jnp.asarray(REALISTIC_DIST), xy),
                    jax.jacfwd(_distort, argnums=1)(jnp.asarray(REALISTIC_DIST), xy), rtol=1e-13)


def test_look_at_aims_camera_upright():
    eye, target = np.array([3.0, -2.0, 1.5]), np.array([0.2, 0.5, 1.0])
    R = np.asarray(look_at(eye, target))
    assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    K = np.array([[800.0, 0.0, 400.0], [0.0, 800.0, 300.0], [0.0, 0.0, 1.0]])
    camera = Camera.create(K, R, -R @ eye)
    assert_allclose(project_point(camera, target), [400.0, 300.0], atol=1e-9)
    assert float(point_depth(camera, target)) == pytest.approx(np.linalg.norm(target - eye))
    # A point above the target appears higher in the image (smaller v).
    assert float(project_point(camera, target + np.array([0, 0, 0.5]))[1]) < 300.0


def test_bad_inputs_raise():
    camera = realistic_camera()
    rig = jax.tree.map(lambda *leaves: jnp.stack(leaves), camera, camera)
    # Under the test suite's runtime annotation checks jaxtyping catches the shape first.
    with pytest.raises((ValueError, TypeCheckError)):
        project(camera, np.zeros((4, 2)))
    with pytest.raises(ValueError, match=r"last axis of size 3, got shape \(4, 2\)"):
        _check_last_axis(np.zeros((4, 2)), 3, "points")
    with pytest.raises(ValueError, match="one camera"):
        project(rig, np.zeros((4, 3)))
    with pytest.raises(ValueError, match="stacked rig"):
        project_to_views(camera, np.zeros((4, 3)))
    with pytest.raises((ValueError, TypeCheckError)):
        undistort_points(camera, np.zeros((4, 2)), output="metres")
    with pytest.raises((ValueError, TypeCheckError)):
        camera_from_projection(np.zeros((3, 3)))
    with pytest.raises(ValueError, match="NaN"):
        Camera.create(np.eye(3), np.eye(3), np.array([0.0, np.nan, 0.0]))

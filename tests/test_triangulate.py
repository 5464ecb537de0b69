"""Triangulation against OpenCV and a NumPy SVD reference, plus its properties and failure modes."""

import json
import logging

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from experiments import bench_geometry
from geometry import Camera, Triangulation, triangulate, triangulate_pixels, triangulate_point

METHODS = ("closed_form", "svd")
N = 32  # one batch size throughout, so most tests reuse a compilation
K = np.array([[900.0, 0.0, 640.0], [0.0, 880.0, 360.0], [0.0, 0.0, 1.0]])


def rotation(vector) -> np.ndarray:
    return cv2.Rodrigues(np.asarray(vector, np.float64))[0]


def ring_cameras(num_views: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cameras on a 6 m ring around (0, 0, 6) looking inwards: rotations (v,3,3), translations (v,3), P (v,3,4)."""
    rng = np.random.default_rng(seed)
    rotations, translations = [], []
    for view in range(num_views):
        yaw = np.deg2rad(-50 + 100 * view / max(num_views - 1, 1))
        R = rotation([rng.normal(0, 0.05), yaw, rng.normal(0, 0.05)])
        centre = np.array([6 * np.sin(yaw), rng.normal(0, 0.3), 6 - 6 * np.cos(yaw)])
        rotations.append(R)
        translations.append(-R @ centre)
    rotations, translations = np.stack(rotations), np.stack(translations)
    projections = K @ np.concatenate([rotations, translations[:, :, None]], axis=-1)
    return rotations, translations, projections


def project(projections: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(v,3,4) x (..., 3) -> (..., v, 2) pixels."""
    homogeneous = np.einsum("vij,...j->...vi", projections, np.concatenate([points, np.ones(points.shape[:-1] + (1,))], -1))
    return homogeneous[..., :2] / homogeneous[..., 2:]


def scene(num_views: int, noise: float, seed: int = 0, num_points: int = N):
    rng = np.random.default_rng(seed)
    _, _, projections = ring_cameras(num_views, seed)
    points = rng.uniform([-1.5, -1.0, 3.0], [1.5, 1.0, 9.0], (num_points, 3))
    pixels = project(projections, points) + rng.normal(0, noise, (num_points, num_views, 2))
    return projections, points, pixels


def numpy_dlt(projections: np.ndarray, pixels: np.ndarray, weights: np.ndarray, normalise_rows: bool = False) -> np.ndarray:
    """Independent reference: weighted DLT with one np.linalg.svd per point."""
    out = []
    for observed, weight in zip(pixels.reshape(-1, *pixels.shape[-2:]), weights.reshape(-1, weights.shape[-1])):
        rows = observed[:, :, None] * projections[:, 2:3, :] - projections[:, :2, :]
        if normalise_rows:
            rows = rows / np.linalg.norm(rows, axis=-1, keepdims=True)
        v = np.linalg.svd((weight[:, None, None] * rows).reshape(-1, 4))[2][-1]
        out.append(v[:3] / v[3])
    return np.array(out).reshape(pixels.shape[:-2] + (3,))


def opencv_two_view(projections: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    homogeneous = cv2.triangulatePoints(projections[0], projections[1], pixels[:, 0].T.copy(), pixels[:, 1].T.copy())
    return (homogeneous[:3] / homogeneous[3]).T


@pytest.mark.parametrize("method", METHODS)
def test_two_views_match_opencv(method):
    projections, _, pixels = scene(2, noise=0.5)
    result = triangulate(projections, pixels, method=method)
    assert bool(result.valid.all())
    np.testing.assert_allclose(result.point, opencv_two_view(projections, pixels), rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("method, normalise_rows", [("closed_form", False), ("svd", False), ("closed_form", True)])
def test_five_weighted_views_match_numpy_svd(method, normalise_rows):
    projections, _, pixels = scene(5, noise=1.0, seed=1)
    weights = np.random.default_rng(2).uniform(0.2, 2.0, (N, 5))
    result = triangulate(projections, pixels, weights, method=method, normalise_rows=normalise_rows)
    expected = numpy_dlt(projections, pixels, weights, normalise_rows)
    np.testing.assert_allclose(result.point, expected, rtol=1e-9, atol=1e-9)
    assert result.num_views.tolist() == [5] * N
    rows = pixels[..., None] * projections[:, 2:3, :] - projections[:, :2, :]
    if normalise_rows:
        rows = rows / np.linalg.norm(rows, axis=-1, keepdims=True)
    smallest_singular_value = np.linalg.svd((weights[:, :, None, None] * rows).reshape(N, -1, 4))[1][:, -1]
    np.testing.assert_allclose(result.residual, smallest_singular_value, rtol=1e-7)


def test_millimetres_and_heavy_noise_match_numpy_svd():
    """The unnormalised DLT is not unit-invariant: in millimetres with 20 px noise the two smallest
    eigenvalues of its normal matrix nearly coincide (ratio up to ~0.9), where inverse iteration
    without a shift stalls (it left up to 4 mm against an SVD). The shifted kernel must not."""
    projections, _, pixels = scene(4, noise=20.0, seed=3)
    projections_mm = projections.copy()
    projections_mm[:, :, 3] *= 1000.0
    weights = np.full((N, 4), 0.25)
    result = triangulate(projections_mm, pixels, weights, max_distance=1e7)
    expected = numpy_dlt(projections_mm, pixels, weights)
    np.testing.assert_allclose(result.point, expected, rtol=0, atol=1e-8)


def test_batch_dimensions_are_preserved():
    projections, _, pixels = scene(3, noise=0.5)
    weights = np.random.default_rng(0).uniform(0.5, 1.0, (N, 3))
    flat = triangulate(projections, pixels, weights)
    batched = triangulate(projections, pixels.reshape(2, 4, 4, 3, 2), weights.reshape(2, 4, 4, 3))
    for leaf_flat, leaf_batched in zip(flat, batched):
        assert leaf_batched.shape == (2, 4, 4) + leaf_flat.shape[1:]
        np.testing.assert_array_equal(np.asarray(leaf_batched).reshape(leaf_flat.shape), leaf_flat)
    single = triangulate(projections[:2], pixels[5, :2])
    assert single.point.shape == (3,) and single.reprojection_error.shape == (2,) and single.valid.shape == ()
    np.testing.assert_allclose(single.point, opencv_two_view(projections[:2], pixels[5:6, :2])[0], rtol=1e-9)


@pytest.mark.parametrize("method", METHODS)
def test_noise_free_points_are_exact(method):
    projections, points, pixels = scene(5, noise=0.0)
    result = triangulate(projections, pixels, method=method)
    np.testing.assert_allclose(result.point, points, rtol=0, atol=1e-10)
    assert float(result.reprojection_error.max()) < 1e-8
    assert float(result.residual.max()) < 1e-6 * float(np.abs(projections).max())


def test_reprojection_error_matches_numpy():
    projections, _, pixels = scene(3, noise=2.0)
    result = triangulate(projections, pixels)
    expected = np.linalg.norm(project(projections, np.asarray(result.point)) - pixels, axis=-1)
    np.testing.assert_allclose(result.reprojection_error, expected, rtol=1e-9)
    assert float(expected.min()) > 0.01


@pytest.mark.parametrize("method", METHODS)
def test_masked_view_equals_dropped_view(method):
    projections, _, pixels = scene(3, noise=0.8, seed=3)
    weights = np.random.default_rng(4).uniform(0.5, 1.5, (N, 3))
    weights[:, 1] = 0.0
    pixels[::2, 1] = np.nan  # missing detections are allowed where the weight is 0
    masked = triangulate(projections, pixels, weights, method=method)
    keep = [0, 2]
    dropped = triangulate(projections[keep], pixels[:, keep], weights[:, keep], method=method)
    np.testing.assert_allclose(masked.point, dropped.point, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(masked.reprojection_error[:, keep], dropped.reprojection_error, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(masked.residual, dropped.residual, rtol=1e-7, atol=1e-12)
    assert float(jnp.abs(masked.reprojection_error[:, 1]).max()) == 0.0
    assert masked.num_views.tolist() == [2] * N


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("weights", [[0.0, 0.0, 0.0], [0.0, 2.0, 0.0], [1.0, 0.0, 0.0]])
def test_fewer_than_two_views_is_invalid_and_finite(method, weights):
    projections, _, pixels = scene(3, noise=0.5)
    pixels[:, [i for i, w in enumerate(weights) if w == 0]] = np.nan
    result = triangulate(projections, pixels, np.broadcast_to(weights, (N, 3)), method=method)
    assert not bool(result.valid.any())
    for leaf in (result.point, result.reprojection_error, result.residual, result.conditioning):
        assert bool(jnp.isfinite(leaf).all())
    assert float(jnp.abs(result.point).max()) == 0.0
    assert float(jnp.abs(result.reprojection_error).max()) == 0.0


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_degenerate_geometry_is_invalid(method, dtype):
    eye = np.eye(3)
    target = np.array([0.3, -0.2, 5.0])

    def camera(R, centre):
        return K @ np.hstack([R, (-R @ centre)[:, None]])

    # Same centre, different orientation: every point on the ray fits, the null space is 2-dimensional.
    same_center = np.stack([camera(eye, np.zeros(3)), camera(rotation([0, 0.3, 0]), np.zeros(3))])
    # Identical pixels in two translated, parallel cameras: the rays meet at infinity.
    parallel = np.stack([camera(eye, np.zeros(3)), camera(eye, np.array([0.5, 0.0, 0.0]))])
    direction = K @ np.array([0.1, 0.05, 1.0])
    cases = {
        "same centre": (same_center, project(same_center, target)),
        "parallel rays": (parallel, np.stack([direction[:2] / direction[2]] * 2)),
        "good": (parallel, project(parallel, target)),
    }
    for name, (projections, pixels) in cases.items():
        result = triangulate(projections.astype(dtype), pixels.astype(dtype), method=method)
        assert bool(result.valid) == (name == "good"), name
        assert bool(jnp.isfinite(result.point).all()), name
    tolerance = 1e-9 if dtype == np.float64 else 1e-4
    np.testing.assert_allclose(result.point, target, rtol=tolerance)


def similarity(rng_values) -> tuple[np.ndarray, np.ndarray, float]:
    rotation_vector, translation, log_scale = rng_values
    return rotation(rotation_vector), np.asarray(translation), float(np.exp(log_scale))


vectors = st.lists(st.floats(-3, 3), min_size=3, max_size=3)


@settings(max_examples=25, deadline=None)
@given(
    rotation_vector=vectors,
    translation=st.lists(st.floats(-20, 20), min_size=3, max_size=3),
    log_scale=st.floats(-2.5, 2.5),
    seed=st.integers(0, 2**16),
)
def test_commutes_with_similarity_transforms(rotation_vector, translation, log_scale, seed):
    """Moving the world by X' = s Q X + d and the cameras consistently (R' = R Q^T, t' = s t - R' d,
    so the pixels do not change) moves the triangulated point the same way.

    The DLT minimises |A v| over |v| = 1; a similarity acts on v by a 4x4 matrix that is orthogonal
    only for a pure rotation, so with noisy pixels the property is exact for rotations, and for
    translations and scalings it holds exactly on noise-free pixels."""
    Q, d, s = similarity((rotation_vector, translation, log_scale))
    rotations, translations, projections = ring_cameras(3, seed)
    rng = np.random.default_rng(seed)
    points = rng.uniform([-1.5, -1.0, 3.0], [1.5, 1.0, 9.0], (N, 3))
    exact = project(projections, points)
    noisy = exact + rng.normal(0, 1.0, exact.shape)
    weights = rng.uniform(0.5, 2.0, (N, 3))

    def moved_projections(Q, d, s):
        R_new = rotations @ Q.T
        t_new = s * translations - np.einsum("vij,j->vi", R_new, d)
        return K @ np.concatenate([R_new, t_new[:, :, None]], axis=-1)

    def moved(X, Q, d, s):
        return s * X @ Q.T + d

    for method in METHODS:
        original = np.asarray(triangulate(projections, exact, weights, method=method).point)
        transformed = triangulate(moved_projections(Q, d, s), exact, weights, method=method)
        assert bool(transformed.valid.all())
        np.testing.assert_allclose(transformed.point, moved(original, Q, d, s), rtol=1e-7, atol=1e-7 * s)

        original = np.asarray(triangulate(projections, noisy, weights, method=method).point)
        rotated = triangulate(moved_projections(Q, np.zeros(3), 1.0), noisy, weights, method=method).point
        np.testing.assert_allclose(rotated, moved(original, Q, np.zeros(3), 1.0), rtol=1e-7, atol=1e-9)


def test_jit_equals_eager():
    projections, _, pixels = scene(3, noise=0.5)
    weights = np.random.default_rng(0).uniform(0.0, 1.0, (N, 3))
    for method in METHODS:
        jitted = triangulate(projections, pixels, weights, method=method)
        with jax.disable_jit():
            eager = triangulate(projections, pixels, weights, method=method)
        for a, b in zip(jitted, eager):
            np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-12)


def test_gradients_are_finite_and_match_finite_differences():
    projections, _, pixels = scene(3, noise=0.5)
    weights = np.ones((N, 3))
    weights[0, 1] = 0.0

    def loss(pixels, projections, weights):
        result = triangulate(projections, pixels, weights)
        return jnp.sum(result.point**2) + jnp.sum(result.reprojection_error)

    grads = jax.grad(loss, argnums=(0, 1, 2))(pixels, projections, weights)
    for grad in grads:
        assert bool(jnp.isfinite(grad).all())
    assert float(jnp.abs(grads[0][0, 1]).max()) == 0.0  # the masked view does not matter
    for argument, index in ((0, (2, 0, 1)), (1, (1, 0, 3)), (2, (4, 2))):
        values = [np.array(pixels), np.array(projections), np.array(weights)]
        step = 1e-6 * max(1.0, abs(values[argument][index]))
        values[argument][index] += step
        upper = loss(*values)
        values[argument][index] -= 2 * step
        lower = loss(*values)
        np.testing.assert_allclose(grads[argument][index], (upper - lower) / (2 * step), rtol=1e-5, atol=1e-9)


def test_batched_path_compiles_once(caplog):
    """Repeated calls with the same shapes reuse one compilation (``jax.log_compiles``)."""
    projections, _, pixels = scene(2, noise=0.5, num_points=37)  # a batch size no other test uses

    def compiles():
        return sum(record.getMessage().startswith("Compiling jit(_triangulate_flat)") for record in caplog.records)

    with jax.log_compiles(), caplog.at_level(logging.WARNING):
        for offset in range(3):
            triangulate(projections, pixels + offset)
        triangulate(projections, pixels.reshape(37, 1, 2, 2))  # same number of points, other batch shape
        assert compiles() == 1
        triangulate(projections, pixels[:36])
        assert compiles() == 2


def test_triangulate_pixels_matches_opencv_undistortion():
    rotations, translations, projections = ring_cameras(2)
    dist = np.array([[-0.25, 0.08, 1e-3, -5e-4, -0.01], [0.1, -0.05, -2e-3, 1e-3, 0.0]])
    rig = Camera.create(np.stack([K, K]), rotations, translations, dist, image_size=(1280.0, 720.0))
    rng = np.random.default_rng(5)
    points = rng.uniform([-1.5, -1.0, 3.0], [1.5, 1.0, 9.0], (N, 3))
    pixels = np.stack(
        [cv2.projectPoints(points, cv2.Rodrigues(R)[0], t, K, d)[0][:, 0] for R, t, d in zip(rotations, translations, dist)],
        axis=1,
    )
    pixels = pixels + rng.normal(0, 0.5, pixels.shape)
    result = triangulate_pixels(rig, pixels)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-15)
    undistorted = np.stack(
        [cv2.undistortPoints(np.ascontiguousarray(pixels[:, v]), K, dist[v], None, None, K, criteria)[:, 0] for v in range(2)], axis=1
    )
    np.testing.assert_allclose(result.point, opencv_two_view(projections, undistorted), rtol=1e-7, atol=1e-7)
    assert bool(result.valid.all()) and float(result.reprojection_error.max()) < 5.0


def test_float32_is_close_to_float64():
    projections, _, pixels = scene(3, noise=0.5)
    single = triangulate(projections.astype(np.float32), pixels.astype(np.float32))
    assert single.point.dtype == jnp.float32 and bool(single.valid.all())
    np.testing.assert_allclose(single.point, triangulate(projections, pixels).point, atol=2e-3)


@pytest.mark.parametrize(
    "arguments, match",
    [
        (dict(projections=np.zeros((2, 4, 3))), "projections"),
        (dict(points=np.zeros((10, 3, 2))), "points"),
        (dict(points=np.zeros((10, 2, 3))), "points"),
        (dict(weights=np.ones((10, 3))), "weights"),
        (dict(weights=-np.ones((10, 2))), "non-negative"),
        (dict(weights=np.full((10, 2), np.nan)), "weights contains NaN"),
        (dict(points=np.full((10, 2, 2), np.nan)), "points .*NaN"),
        (dict(method="lstsq"), "method"),
    ],
)
def test_bad_input_raises_a_clear_error(arguments, match):
    projections, _, pixels = scene(2, noise=0.5, num_points=10)
    call = dict(projections=projections, points=pixels, weights=np.ones((10, 2))) | arguments
    method = call.pop("method", "closed_form")
    # Shape errors may be caught first by the jaxtyping hook of the test run (a TypeError naming the argument).
    with pytest.raises((ValueError, TypeError), match=match):
        triangulate(**call, method=method)


def test_triangulate_point_kernel_is_the_building_block():
    projections, _, pixels = scene(3, noise=0.5, num_points=3)
    result = jax.vmap(triangulate_point, in_axes=(None, 0, 0))(jnp.asarray(projections), jnp.asarray(pixels), jnp.ones((3, 3)))
    assert isinstance(result, Triangulation)
    np.testing.assert_allclose(result.point, numpy_dlt(projections, pixels, np.ones((3, 3))), rtol=1e-9)


def test_benchmark_smoke(capsys):
    bench_geometry.main(bench_geometry.Config(json=True, points=N, repeats=1))
    result = json.loads(capsys.readouterr().out)
    assert result["points"] == N and result["dtype"] == "float64"
    assert result["2view_closed_form_max_abs_diff_m"] < 1e-9
    assert result["5view_closed_form_max_abs_diff_m"] < 1e-9
    assert result["2view_closed_form_points_per_s"] > 0


# ----------------------------------------------------------------------------------------------
# Bad input ("Trustworthy runs"): geometry that cannot have produced the observations is never `valid`.


def _camera(R, centre):
    return K @ np.hstack([R, (-R @ np.asarray(centre, float))[:, None]])


@pytest.mark.parametrize("method", METHODS)
def test_point_behind_the_cameras_is_invalid(method):
    projections, points, _ = scene(2, noise=0.0, num_points=4)
    # Points far behind the ring (the cameras look towards +z): the pixels they project to are consistent
    # (the DLT finds the point exactly) but no camera can have seen it.
    behind = points * [0.2, 1.0, -1.0] - [0.0, 0.0, 3.0]
    for depths in np.einsum("vj,nj->nv", projections[:, 2, :3], behind) + projections[:, 2, 3]:
        assert np.all(depths < 0)
    result = triangulate(projections, project(projections, behind), method=method)
    assert not np.asarray(result.valid).any()
    assert np.all(np.asarray(result.point) == 0)
    # The papers' algebraic baselines have no such check: require_in_front=False keeps the DLT's point.
    kept = triangulate(projections, project(projections, behind), method=method, require_in_front=False)
    assert np.asarray(kept.valid).all()
    np.testing.assert_allclose(np.asarray(kept.point), behind, atol=1e-6)
    in_front = triangulate(projections, project(projections, points), method=method)
    assert np.asarray(in_front.valid).all()
    # Behind one used camera only is refused too; a view with weight 0 does not count.
    third = np.concatenate([projections, _camera(np.eye(3), points[0] + [0.0, 0.0, 1.0])[None]])
    pixels = np.concatenate([project(projections, points[:1]), np.zeros((1, 1, 2))], axis=1)
    assert not bool(triangulate(third, pixels, np.array([[1.0, 1.0, 1.0]]), method=method).valid[0])
    assert bool(triangulate(third, pixels, np.array([[1.0, 1.0, 0.0]]), method=method).valid[0])


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_zero_baseline_is_invalid(method, dtype):
    # Two cameras at one centre seeing different pixels: their rays meet only at the centre, which the DLT
    # returns as a well-posed, finite point (depth 0, rounded either way).
    target = np.array([0.3, -0.2, 5.0])
    coincident = np.stack([_camera(np.eye(3), [1.0, 2.0, -1.0]), _camera(rotation([0.0, 0.3, 0.0]), [1.0, 2.0, -1.0])])
    pixels = project(coincident, target) + np.array([[0.0, 0.0], [25.0, -10.0]])
    result = triangulate(coincident.astype(dtype), pixels.astype(dtype), method=method)
    assert not bool(result.valid)
    # A third camera elsewhere gives a baseline again.
    rig = np.concatenate([coincident, _camera(np.eye(3), [0.0, 0.0, 0.0])[None]])
    assert bool(triangulate(rig.astype(dtype), project(rig, target).astype(dtype), method=method).valid)


def test_no_cameras_is_a_one_line_error():
    with pytest.raises(ValueError, match="no cameras"):
        triangulate(np.zeros((0, 3, 4)), np.zeros((5, 0, 2)))
    rig = Camera.create(np.zeros((0, 3, 3)), np.zeros((0, 3, 3)), np.zeros((0, 3)))
    with pytest.raises(ValueError, match="no cameras"):
        triangulate_pixels(rig, np.zeros((5, 0, 2)))

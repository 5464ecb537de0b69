"""The camera-dependent triangulation baselines and the metrics of the FLEX experiment (flex/_baselines.py)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

import geometry
import mocap
import structri
from geometry import FLEX20, STRUCTRI17
from flex import (DataConfig, baseline_cameras, camera_root, make_batch, motion_metrics, normalise_2d,
                  root_position_error, triangulation_baseline)

# Every batch has the same shapes (2 sequences, 4 views, 16 frames), so each kernel compiles once.
STATIC = DataConfig(views=4, frames=16)
DYNAMIC = DataConfig(views=4, frames=16, camera_motion="dynamic")
ROOT = STRUCTRI17.index("mid_hip")
KEY = jax.random.key(7)


@pytest.fixture(scope="module")
def perfect():
    return make_batch(jax.random.key(0), DataConfig(views=4, frames=16, detector=mocap.PERFECT_DETECTOR), 2)


@pytest.fixture(scope="module")
def noisy():
    return make_batch(jax.random.key(1), STATIC, 2)


@pytest.fixture(scope="module")
def dynamic():
    return make_batch(jax.random.key(2), DYNAMIC, 2)


def _mpjpe(pred, batch) -> float:
    return float(motion_metrics(pred, batch.joints).mpjpe)


def test_dlt_with_exact_cameras_and_a_perfect_detector_recovers_the_ground_truth(perfect):
    assert np.all(perfect.confidences > 0)
    pred = triangulation_baseline(perfect, "dlt")
    assert pred.shape == perfect.joints.shape
    assert_allclose(pred, perfect.joints, atol=1e-6)
    # A stale calibration of static cameras is the exact one.
    assert_array_equal(triangulation_baseline(perfect, "dlt", "static"), pred)


def test_wrong_calibrations_cost_accuracy(noisy, dynamic):
    exact = _mpjpe(triangulation_baseline(noisy, "dlt"), noisy)
    for scale in (0.03, 0.04):
        for frame in ("true", "calibration"):
            perturbed = triangulation_baseline(noisy, "dlt", "perturbed", KEY, scale=scale, frame=frame)
            assert _mpjpe(perturbed, noisy) > exact
    # Moving cameras: the first frame's calibration is exact at frame 0 only (where no joint is filled in from
    # a later frame).
    exact = triangulation_baseline(dynamic, "dlt")
    stale = triangulation_baseline(dynamic, "dlt", "static")
    seen = np.sum(dynamic.confidences[:, :, 0] > 0, axis=1) >= 2  # (B, 17)
    seen = (seen & seen[:, ROOT:ROOT + 1])[:, None, :, None]
    assert_allclose(np.where(seen, stale[:, :, 0], 0.0), np.where(seen, exact[:, :, 0], 0.0), atol=1e-12)
    assert _mpjpe(stale, dynamic) > _mpjpe(exact, dynamic)


def test_perturbation_is_one_draw_per_sequence_and_view(dynamic):
    cameras = jax.tree.map(jnp.asarray, dynamic.cameras)
    perturbed = baseline_cameras(cameras, "perturbed", KEY, 0.03)
    ratio = np.asarray(perturbed.t / cameras.t)  # each translation component times 1 + 0.03 N(0, 1)
    assert_allclose(ratio, np.broadcast_to(ratio[:, :, :1], ratio.shape), rtol=1e-12)
    first = ratio[:, :, 0].reshape(-1, 3)
    assert len(np.unique(first.round(12), axis=0)) == first.shape[0]  # independent over sequences and views
    assert 0.0 < np.std(first - 1.0) < 0.1
    assert_array_equal(perturbed.K, cameras.K)
    with pytest.raises(ValueError, match="key"):
        baseline_cameras(cameras, "perturbed")


def test_a_fixed_rig_is_perturbed_once_for_every_sequence():
    batch = make_batch(jax.random.key(3), DataConfig(views=4, frames=16, rig="h36m_ring"), 2)
    cameras = jax.tree.map(jnp.asarray, batch.cameras)
    ratio = np.asarray(baseline_cameras(cameras, "perturbed", KEY, 0.03, per_sequence=False).t / cameras.t)
    assert_allclose(ratio, np.broadcast_to(ratio[:1, :, :1], ratio.shape), rtol=1e-12)  # one draw per view
    assert len(np.unique(ratio[0, :, 0].round(12), axis=0)) == 4
    shared = triangulation_baseline(batch, "dlt", "perturbed", KEY, per_sequence=False)
    assert not np.allclose(shared, triangulation_baseline(batch, "dlt", "perturbed", KEY))


def _true_root(batch):
    normalised = normalise_2d(batch.points_2d, batch.confidences, ROOT)
    return camera_root(batch.root_position, normalised.centre, normalised.scale, batch.cameras.K)


def test_the_metric_root_of_the_ground_truth_is_where_exact_triangulation_puts_it(perfect, noisy):
    """Two independent routes to the camera-frame root: the samples' normalised ``root_position`` made metric with
    the intrinsics, and the DLT through the exact cameras of exact 2D."""
    joints, root = triangulation_baseline(perfect, "dlt", with_root=True)
    assert_allclose(_true_root(perfect), root, atol=1e-6)
    assert_array_equal(joints, triangulation_baseline(perfect, "dlt"))
    truth = _true_root(noisy)
    exact = float(root_position_error(triangulation_baseline(noisy, "structural", with_root=True)[1], truth))
    perturbed = float(root_position_error(triangulation_baseline(
        noisy, "structural", "perturbed", KEY, scale=0.04, frame="calibration", with_root=True)[1], truth))
    assert 0 < exact < perturbed
    assert_allclose(root_position_error(np.asarray(truth) + [0.003, 0.0, 0.004], truth), 5.0, rtol=1e-6)


def test_structural_triangulation_keeps_bones_steadier_than_dlt(noisy):
    dlt = motion_metrics(triangulation_baseline(noisy, "dlt"), noisy.joints)
    structural = motion_metrics(triangulation_baseline(noisy, "structural"), noisy.joints)
    assert structural.mbls < 0.5 * dlt.mbls
    assert structural.mpjpe < dlt.mpjpe
    assert all(np.isfinite(value) for value in (*dlt, *structural))


def test_structural_baseline_is_structri_with_lengths_estimated_through_its_cameras(noisy):
    pred = triangulation_baseline(noisy, "structural", "perturbed", KEY, frame="calibration")
    given = baseline_cameras(noisy.cameras, "perturbed", KEY, 0.03)
    for b in range(2):
        P = geometry.projection_matrix(jax.tree.map(lambda leaf: leaf[b, :, 0], given))  # static: frame 0's
        points, weights = np.swapaxes(noisy.points_2d[b], 0, 1), np.swapaxes(noisy.confidences[b], 0, 1)
        per_frame = np.stack([structri.estimate_bone_lengths(points[t:t + 1], P, STRUCTRI17, weights[t:t + 1])
                              for t in range(points.shape[0])])
        lengths = np.median(per_frame[np.all(per_frame > 0, axis=1)], axis=0)
        pose = structri.structural_triangulation(points, P, lengths, STRUCTRI17, weights).pose
        expected = np.einsum("ktij,tnj->ktni", given.R[b], pose - pose[:, ROOT:ROOT + 1])
        determined = np.sum(weights > 0, axis=1) >= 2  # (T, 17)
        determined = (determined & determined[:, ROOT:ROOT + 1])[None, :, :, None]  # not filled
        assert determined.mean() > 0.85
        assert_allclose(np.where(determined, pred[b], 0.0), np.where(determined, expected, 0.0), atol=1e-9)


def test_structural_bone_lengths_ignore_a_few_outlier_frames(perfect):
    """Gross detector outliers at 3 of 16 frames: a mean of the per-frame lengths would put a wrong shin on every
    frame; with the median the clean frames keep the solution without outliers."""
    ankle, outliers = STRUCTRI17.index("l_ankle"), [2, 7, 11]
    points = np.array(perfect.points_2d)
    points[:, 0, outliers, ankle] += 400.0  # pixels, in view 0
    pred = np.asarray(triangulation_baseline(perfect._replace(points_2d=points), "structural"))
    without = np.asarray(triangulation_baseline(perfect, "structural"))
    clean = np.setdiff1d(np.arange(points.shape[2]), outliers)
    assert_allclose(pred[:, :, clean], without[:, :, clean], atol=1e-3)
    assert np.max(np.abs(pred[:, :, outliers] - without[:, :, outliers])) > 0.01


@pytest.mark.parametrize("method", ["dlt", "structural"])
def test_joints_seen_in_fewer_than_two_views_take_the_nearest_determined_offset(perfect, method):
    wrist, head = STRUCTRI17.index("l_wrist"), STRUCTRI17.index("head")
    confidences = np.array(perfect.confidences)
    confidences[:, 1:, [0, 5, 6], wrist] = 0.0  # one view left at frames 0, 5 and 6
    confidences[:, :, :, head] = 0.0  # never seen
    pred = np.asarray(triangulation_baseline(perfect._replace(confidences=confidences), method))
    assert np.all(np.isfinite(pred))
    assert_array_equal(pred[:, :, 0, wrist], pred[:, :, 1, wrist])  # the later frame (no earlier one)
    assert_array_equal(pred[:, :, 5, wrist], pred[:, :, 4, wrist])  # static cameras: the same offset
    assert_array_equal(pred[:, :, 6, wrist], pred[:, :, 4, wrist])
    assert_array_equal(pred[..., head, :], 0.0)  # at the root
    assert np.all(np.isfinite(motion_metrics(pred, perfect.joints)))


def test_jit_equals_eager(noisy):
    jitted = jax.jit(triangulation_baseline, static_argnames=("method", "calibration", "frame", "n_steps"))
    eager = triangulation_baseline(noisy, "dlt", "perturbed", KEY, scale=0.04, frame="calibration")
    assert_allclose(jitted(noisy, "dlt", "perturbed", KEY, scale=0.04, frame="calibration"), eager, atol=1e-12)


def test_metrics_equal_a_hand_computation():
    rng = np.random.default_rng(0)
    gt = rng.normal(size=(1, 2, 4, 17, 3))
    offsets = rng.normal(size=(4, 3))  # joint 3 (l_hip) of view 1 moves by offsets[t] at frame t
    pred = gt.copy()
    pred[0, 1, :, 3] += offsets
    metrics = motion_metrics(pred, gt)
    # MPJPE: the root is exact, so each frame of view 1 has one joint off; view 0 is exact.
    assert_allclose(metrics.mpjpe, 1000 * np.mean(np.linalg.norm(offsets, axis=-1) / 17) / 2, rtol=1e-12)
    acceleration = offsets[:-2] - 2 * offsets[1:-1] + offsets[2:]
    assert_allclose(metrics.acceleration_error, 1000 * np.mean(np.linalg.norm(acceleration, axis=-1) / 17) / 2,
                    rtol=1e-12)
    parents, children = np.array(STRUCTRI17.bones).T
    lengths = np.linalg.norm(pred[..., children, :] - pred[..., parents, :], axis=-1)  # (1, 2, 4, 16)
    assert_allclose(metrics.mbls, 1000 * np.mean(np.sqrt(np.mean(np.var(lengths, axis=2), axis=-1))), rtol=1e-12)
    # FLEX's FLEX20 output is scored on its 17 STRUCTRI17 joints.
    flex20 = motion_metrics(geometry.flex20_from_structri17(pred), gt, FLEX20)
    for value, expected in zip(flex20, metrics):
        assert_allclose(value, expected, rtol=1e-12)
    assert_array_equal(motion_metrics(gt, gt)[:2], (0.0, 0.0))


def test_shape_and_argument_errors_are_clear(perfect):
    gt = np.zeros((1, 2, 4, 17, 3))
    with pytest.raises((ValueError, TypeError), match="pred|shape"):
        motion_metrics(np.zeros((1, 2, 4, 16, 3)), gt)
    with pytest.raises((ValueError, TypeError), match="gt|shape"):
        motion_metrics(gt[0], gt[0])
    with pytest.raises(ValueError, match="3 frames"):
        motion_metrics(gt[:, :, :2], gt[:, :, :2])
    with pytest.raises((ValueError, TypeError), match="method|dlt"):
        triangulation_baseline(perfect, "svd")
    with pytest.raises((ValueError, TypeError), match="calibration|exact"):
        triangulation_baseline(perfect, "dlt", "estimated")
    with pytest.raises(ValueError, match="2 views"):
        triangulation_baseline(jax.tree.map(lambda leaf: leaf[:, :1], perfect), "dlt")
    with pytest.raises(ValueError, match="points_2d"):
        triangulation_baseline(perfect._replace(points_2d=perfect.points_2d[:, :, :-1]), "dlt")

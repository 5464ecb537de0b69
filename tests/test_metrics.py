"""Pose metrics against hand-computed cases, NumPy/SciPy references of the published formulas, and
invariances (hypothesis)."""

import re
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose
from scipy.linalg import orthogonal_procrustes
from scipy.spatial.transform import Rotation

from geometry import (SHELF15, STRUCTRI17, Skeleton, acceleration_error, aggregate_precision_recall, bone_lengths,
                      joint_precision_recall, mbls, mpble, mpjpe, mpjpe_root_relative, pa_mpjpe, pck_2d, pck_3d,
                      pcp, pib, safe_norm, similarity_procrustes)

SEEDS = st.integers(0, 2**32 - 1)
FEW = settings(max_examples=25, deadline=None)


def poses(seed, *batch, joints=17):
    return np.random.default_rng(seed).normal(size=(*batch, joints, 3))


def random_similarity(seed):
    rng = np.random.default_rng(seed)
    return np.exp(rng.uniform(-1, 1)), Rotation.random(random_state=rng).as_matrix(), rng.normal(size=3) * 5


def numpy_similarity_align(source, target):
    """HMR/SPIN ``compute_similarity_transform`` (Umeyama with reflection fix), NumPy, one pose."""
    mu_s, mu_t = source.mean(0), target.mean(0)
    s0, t0 = source - mu_s, target - mu_t
    u, sing, vt = np.linalg.svd(s0.T @ t0)
    z = np.eye(3)
    z[2, 2] = np.sign(np.linalg.det(u @ vt))
    rot = vt.T @ z @ u.T
    scale = np.trace(rot @ s0.T @ t0) / np.sum(s0**2)
    return scale * source @ rot.T + (mu_t - scale * rot @ mu_s)


# --- MPJPE family --------------------------------------------------------------------------------


def test_mpjpe_hand_computed_with_mask():
    gt = np.zeros((2, 3, 3))
    pred = np.array([[[3.0, 4, 0], [0, 0, 1], [0, 0, 0]], [[0, 0, 2], [0, 0, 0], [1, 0, 0]]])
    assert_allclose(mpjpe(pred, gt), [2.0, 1.0])
    mask = np.array([[True, False, True], [False, False, False]])
    result = np.asarray(mpjpe(pred, gt, mask))
    assert result[0] == 2.5 and np.isnan(result[1])  # no selected joint: NaN by contract


def test_metrics_have_finite_gradients_at_a_perfect_prediction():
    gt = jnp.asarray(poses(18, 2))
    for loss in (mpjpe, pa_mpjpe, lambda p, g: mpjpe_root_relative(p, g, 0)):
        grad = jax.grad(lambda p, loss=loss: jnp.sum(loss(p, gt)))(gt)
        assert np.all(np.isfinite(grad))


def test_safe_norm_is_numpys_norm_with_a_zero_gradient_at_the_zero_vector():
    vectors = np.random.default_rng(3).normal(size=(4, 5, 3))
    vectors[1, 2] = 0.0
    assert_allclose(safe_norm(vectors), np.linalg.norm(vectors, axis=-1), rtol=1e-6)
    grad = np.asarray(jax.grad(lambda v: jnp.sum(safe_norm(v)))(jnp.asarray(vectors)))
    assert_allclose(grad[1, 2], 0.0)
    unit = vectors / np.maximum(np.linalg.norm(vectors, axis=-1, keepdims=True), 1e-30)
    assert_allclose(grad, unit, rtol=1e-5, atol=1e-6)


def test_mpjpe_matches_numpy():
    pred, gt = poses(1, 4, 5), poses(2, 4, 5)
    assert_allclose(mpjpe(pred, gt), np.linalg.norm(pred - gt, axis=-1).mean(-1))


def test_root_relative_hand_computed():
    gt = np.array([[0.0, 0, 0], [1, 0, 0]])
    pred = np.array([[10.0, 0, 0], [11, 1, 0]])  # shifted by 10, second joint off by 1
    assert_allclose(mpjpe_root_relative(pred, gt, root=0), 0.5)  # root error 0 is part of the mean
    assert np.isnan(mpjpe_root_relative(pred, gt, 0, mask=np.array([False, True])))


@FEW
@given(SEEDS)
def test_root_relative_is_translation_invariant(seed):
    pred, gt = poses(seed, 3), poses(seed + 1, 3)
    shift = np.random.default_rng(seed).normal(size=(3, 1, 3)) * 10
    assert_allclose(mpjpe_root_relative(pred + shift, gt, 9), mpjpe_root_relative(pred, gt, 9), atol=1e-10)
    assert not np.allclose(mpjpe(pred + shift, gt), mpjpe(pred, gt))


def test_pa_mpjpe_matches_hmr_numpy_reference():
    pred, gt = poses(3, 6), poses(4, 6)
    expected = [np.linalg.norm(numpy_similarity_align(p, g) - g, axis=-1).mean() for p, g in zip(pred, gt)]
    assert_allclose(pa_mpjpe(pred, gt), expected, rtol=1e-10)


def test_similarity_rotation_matches_scipy_orthogonal_procrustes():
    gt = poses(5)
    scale, rot, trans = random_similarity(5)
    pred = (gt @ rot.T) * scale + trans + 0.01 * poses(6)  # near-similar: no reflection ambiguity
    fit = similarity_procrustes(pred, gt)
    centred_p, centred_g = pred - pred.mean(0), gt - gt.mean(0)
    scipy_r, _ = orthogonal_procrustes(centred_p, centred_g)  # minimises |P R - G|, so our R = R_scipy^T
    assert_allclose(fit.rotation, scipy_r.T, atol=1e-10)
    assert_allclose(fit.scale, 1 / scale, rtol=1e-2)
    assert_allclose(np.linalg.det(fit.rotation), 1.0)


def test_procrustes_fixes_reflections():
    gt = poses(7)
    mirrored = gt * np.array([1.0, 1.0, -1.0])  # the best orthogonal map is a reflection
    fit = similarity_procrustes(mirrored, gt)
    assert_allclose(np.linalg.det(fit.rotation), 1.0)
    assert_allclose(pa_mpjpe(mirrored, gt), np.linalg.norm(numpy_similarity_align(mirrored, gt) - gt, axis=-1).mean())
    assert pa_mpjpe(mirrored, gt) > 0.1


@FEW
@given(SEEDS)
def test_pa_mpjpe_is_invariant_to_a_similarity_of_the_prediction(seed):
    pred, gt = poses(seed), poses(seed + 1)
    scale, rot, trans = random_similarity(seed)
    moved = scale * pred @ rot.T + trans
    assert_allclose(pa_mpjpe(moved, gt), pa_mpjpe(pred, gt), rtol=1e-8)
    assert_allclose(pa_mpjpe(scale * gt @ rot.T + trans, gt), 0.0, atol=1e-9)
    assert pa_mpjpe(pred, gt) <= mpjpe(pred, gt) + 1e-12


@FEW
@given(SEEDS)
def test_pa_mpjpe_alignment_is_optimal(seed):
    """No perturbed similarity beats the returned one on the least-squares objective."""
    pred, gt = poses(seed), poses(seed + 1)
    fit = similarity_procrustes(pred, gt)
    best = np.sum((np.asarray(fit.apply(jnp.asarray(pred))) - gt) ** 2)
    rng = np.random.default_rng(seed)
    for _ in range(5):
        rot = Rotation.from_rotvec(0.05 * rng.normal(size=3)).as_matrix() @ np.asarray(fit.rotation)
        scale = float(fit.scale) * (1 + 0.05 * rng.normal())
        trans = np.asarray(fit.translation) + 0.05 * rng.normal(size=3)
        assert np.sum((scale * pred @ rot.T + trans - gt) ** 2) >= best


def test_pa_mpjpe_mask_ignores_masked_joints():
    pred, gt = poses(8), poses(9)
    mask = np.arange(17) < 12
    garbage = pred.copy()
    garbage[~mask] = 1e6
    assert_allclose(pa_mpjpe(garbage, gt, mask), pa_mpjpe(pred[:12], gt[:12]), rtol=1e-10)


def test_procrustes_of_a_collapsed_prediction_is_finite():
    gt = poses(10)
    assert_allclose(pa_mpjpe(np.ones((17, 3)), gt), np.linalg.norm(gt - gt.mean(0), axis=-1).mean())


def test_procrustes_of_many_poses_calls_lapack_in_small_slices():
    """jaxlib's CPU LAPACK kernels spread a batch of more than ~740 3x3 SVDs over XLA's intra-op threads and wait
    for the pieces on one of them; two such calls at once deadlock a 2-core machine (the dynamics evaluation hung
    so, scoring two Procrustes alignments in one computation). The alignment slices its SVDs below that size and
    computes the determinants without LAPACK; the sliced result equals the alignments one pose at a time."""
    pred = np.random.default_rng(11).normal(size=(1200, 17, 3))
    gt = np.random.default_rng(12).normal(size=(1200, 17, 3))
    lowered = jax.jit(lambda p, g: pa_mpjpe(p, g) + pa_mpjpe(g, p)).lower(pred, gt).as_text()
    batches = [int(match) for match in re.findall(r"custom_call @lapack_\w+\(.*?tensor<(\d+)x3x3x", lowered)]
    assert batches and max(batches) <= 512
    assert "getrf" not in lowered
    assert_allclose(pa_mpjpe(pred, gt)[::97], [pa_mpjpe(p, g) for p, g in zip(pred[::97], gt[::97])], rtol=1e-10)


# --- PCK -----------------------------------------------------------------------------------------


def test_pck_3d_hand_computed_strict_threshold():
    gt = np.zeros((4, 3))
    pred = np.array([[0.1, 0, 0], [0.15, 0, 0], [0.2, 0, 0], [0, 0, 0]])
    assert_allclose(pck_3d(pred, gt, 0.15), 0.5)  # 0.15 itself is not below 0.15
    assert_allclose(pck_3d(pred, gt, 0.15, mask=np.array([False, True, True, False])), 0.0)


def test_pck_2d_uses_the_longer_side_of_the_gt_box():
    gt = np.array([[0.0, 0], [100, 0], [100, 40], [0, 40]])  # box 100 x 40
    pred = gt + np.array([[19.0, 0], [0, 21], [0, 0], [15, 15]])
    assert_allclose(pck_2d(pred, gt, 0.2), 0.5)  # threshold 20 px: errors 19, 21, 0, 21.2
    # Masking the right-hand joints shrinks the box to 0 x 40: threshold 8 px.
    mask = np.array([True, False, False, True])
    assert_allclose(pck_2d(pred, gt, 0.2, mask), 0.0)
    # The thesis' PCK: alpha times the longer side of the person's own box, here 200 px: threshold 10 px.
    assert_allclose(pck_2d(pred, gt, 0.05, box_size=200.0), 0.25)
    assert_allclose(pck_2d(np.stack([pred, gt]), np.stack([gt, gt]), 0.05, box_size=np.array([200.0, 1.0])),
                    [0.25, 1.0])


# --- PCP -----------------------------------------------------------------------------------------

TWO_JOINTS = Skeleton("two", ("a", "b"), (-1, 0), pcp_parts=(("ab", "a", "b"),))


def numpy_pcp_strict(pred, gt, parts):
    """4D Association ``Evaluate``: ``da + db < l`` per part."""
    return np.array([np.linalg.norm(pred[s] - gt[s]) + np.linalg.norm(pred[e] - gt[e]) < np.linalg.norm(gt[s] - gt[e])
                     for s, e in parts])


def test_pcp_boundary_separates_voxelpose_and_4da_forms():
    gt = np.array([[0.0, 0, 0], [0, 0, 2]])
    pred = np.array([[1.0, 0, 0], [0, 0, 3]])  # mean error exactly 1 = 0.5 * length
    assert bool(pcp(pred, gt, TWO_JOINTS)[0]) is True
    assert bool(pcp(pred, gt, TWO_JOINTS, strict=True)[0]) is False
    assert bool(pcp(pred * 0.999, gt, TWO_JOINTS, strict=True)[0]) is True
    assert bool(pcp(pred, gt, TWO_JOINTS, alpha=0.4)[0]) is False


def test_pcp_matches_4da_reference_near_the_boundary():
    rng = np.random.default_rng(11)
    gt = 1.0 * (np.arange(3) == 2) + 0.3 * rng.normal(size=(200, 15, 3))
    pred = gt + 0.12 * rng.normal(size=gt.shape)
    ours = np.asarray(pcp(pred, gt, SHELF15, strict=True))
    expected = np.stack([numpy_pcp_strict(p, g, SHELF15.pcp_index) for p, g in zip(pred, gt)])
    np.testing.assert_array_equal(ours, expected)
    assert 0.2 < ours.mean() < 0.95  # the sample straddles the threshold


def test_pcp_missing_predicted_joints():
    gt = poses(12, joints=15)
    pred = gt.copy()
    pred[SHELF15.index("l_elbow")] = 0.0
    parts = [name for name, _, _ in SHELF15.pcp_parts]
    affected = {"l_upper_arm", "l_lower_arm"}
    hit = np.asarray(pcp(pred, gt, SHELF15, zero_is_missing=True))
    assert {p for p, ok in zip(parts, hit) if not ok} == affected
    valid = np.ones(15, bool)
    valid[SHELF15.index("head_top")] = False
    hit = np.asarray(pcp(gt, gt, SHELF15, pred_valid=valid))
    assert {p for p, ok in zip(parts, hit) if not ok} == {"head"}


@FEW
@given(SEEDS)
def test_pcp_symmetries(seed):
    """A rigid motion of both poses changes nothing; mirroring both poses swaps left and right parts."""
    rng = np.random.default_rng(seed)
    gt = 1.0 * (np.arange(3) == 2) + 0.3 * rng.normal(size=(15, 3))
    pred = gt + 0.1 * rng.normal(size=gt.shape)
    base = np.asarray(pcp(pred, gt, SHELF15))
    _, rot, trans = random_similarity(seed)
    np.testing.assert_array_equal(pcp(pred @ rot.T + trans, gt @ rot.T + trans, SHELF15), base)
    mirror = list(SHELF15.mirror)
    mirrored = np.asarray(pcp(pred[mirror], gt[mirror], SHELF15))
    names = [name for name, _, _ in SHELF15.pcp_parts]
    swap = [names.index({"l": "r_", "r": "l_"}.get(n[0], "") + n[2:] if n[1] == "_" else n) for n in names]
    np.testing.assert_array_equal(mirrored, base[swap])


def test_pcp_needs_parts_and_the_right_joint_count():
    bare = Skeleton("bare", ("a", "b"), (-1, 0))
    with pytest.raises(ValueError, match="no PCP parts"):
        pcp(np.zeros((2, 3)), np.zeros((2, 3)), bare)
    with pytest.raises(ValueError, match="SHELF15 has 15"):
        pcp(np.zeros((14, 3)), np.zeros((14, 3)), SHELF15)


# --- bone metrics --------------------------------------------------------------------------------


def test_bone_metrics_hand_computed():
    chain = Skeleton("chain", ("a", "b", "c"), (-1, 0, 1))
    frames = np.array([[[0.0, 0, 0], [1, 0, 0], [1, 2, 0]], [[0, 0, 0], [3, 0, 0], [3, 2, 0]]])  # lengths (1,2), (3,2)
    assert_allclose(bone_lengths(frames, chain), [[1, 2], [3, 2]])
    assert_allclose(mpble(frames, chain, np.array([1.0, 2.5])), [0.25, 1.25])
    assert_allclose(mbls(frames, chain), np.sqrt((1.0 + 0.0) / 2))  # var(1, 3) = 1, var(2, 2) = 0
    assert_allclose(pib(frames, chain, np.array([1.0, 2.5])), [0.5, 0.0])  # 2 is exactly 0.8 * 2.5: not inside


def test_bone_metrics_match_structural_triangulation_formulas():
    """The formulas of Structural Triangulation's test.py (MEBLE, MBLS with np.var, PIB strict)."""
    rng = np.random.default_rng(13)
    seq = rng.normal(size=(30, 17, 3))
    parents = STRUCTRI17.parents
    lengths = np.stack([np.linalg.norm(seq[:, k + 1] - seq[:, parents[k + 1]], axis=-1) for k in range(16)], -1)
    reference = lengths.mean(0) * rng.uniform(0.8, 1.2, size=16)
    assert_allclose(np.mean(mpble(seq, STRUCTRI17, reference)), np.mean(np.abs(lengths - reference)))
    assert_allclose(mbls(seq, STRUCTRI17), np.sqrt(np.mean(np.var(lengths, axis=0))))
    inlier = (lengths > 0.8 * reference) & (lengths < 1.2 * reference)
    assert_allclose(np.mean(pib(seq, STRUCTRI17, reference)), inlier.sum() / (30 * 16))


def test_bone_metric_shape_errors():
    with pytest.raises(ValueError, match="17, 3"):
        bone_lengths(np.zeros((15, 3)), STRUCTRI17)
    with pytest.raises(ValueError, match="16 bones"):
        mpble(np.zeros((17, 3)), STRUCTRI17, np.ones(15))


# --- acceleration --------------------------------------------------------------------------------


def numpy_accel_error(pred, gt, vis):
    """HMMR ``compute_error_accel``: per-frame mean over joints, frames with an invisible neighbour dropped."""
    accel_gt = gt[:-2] - 2 * gt[1:-1] + gt[2:]
    accel_pred = pred[:-2] - 2 * pred[1:-1] + pred[2:]
    normed = np.linalg.norm(accel_pred - accel_gt, axis=2)
    invis = ~vis
    new_vis = ~(invis | np.roll(invis, -1) | np.roll(invis, -2))[:-2]
    return np.mean(normed[new_vis], axis=1).mean()


def test_acceleration_error_hand_computed():
    gt = np.zeros((4, 1, 3))
    pred = np.zeros((4, 1, 3))
    pred[1, 0, 0] = 1.0  # second differences: -2 at t=1, +1 at t=2
    assert_allclose(acceleration_error(pred, gt), 1.5)
    assert_allclose(acceleration_error(pred + np.arange(4)[:, None, None], gt), 1.5)  # constant velocity: none


def test_acceleration_error_matches_hmmr_with_visibility():
    rng = np.random.default_rng(14)
    pred, gt = rng.normal(size=(20, 17, 3)), rng.normal(size=(20, 17, 3))
    vis = rng.random(20) > 0.2
    vis[[0, 10]] = True
    assert_allclose(acceleration_error(pred, gt, vis), numpy_accel_error(pred, gt, vis))


def test_acceleration_needs_three_frames():
    with pytest.raises(ValueError, match="3 frames"):
        acceleration_error(np.zeros((2, 17, 3)), np.zeros((2, 17, 3)))


# --- precision / recall --------------------------------------------------------------------------


def test_joint_precision_recall_hand_computed():
    gt = np.ones((2, 3, 3))
    pred = gt.copy()
    pred[0, 0] = 0.0  # not detected (JCSAT: exactly zero)
    pred[0, 1] += 0.3  # detected, wrong
    pred[1, 2] += 0.1  # detected, right
    hits = joint_precision_recall(pred, gt, 0.2)
    np.testing.assert_array_equal(hits.detected, [[False, True, True], [True, True, True]])
    np.testing.assert_array_equal(hits.correct, [[False, False, True], [True, True, True]])
    pr = aggregate_precision_recall(hits, unmatched_gt=2)
    assert_allclose(pr.precision, [1.0, 0.5, 1.0])
    assert_allclose(pr.recall, [1 / 4, 1 / 4, 2 / 4])
    present = np.array([[True, True, False], [True, True, True]])
    pr = aggregate_precision_recall(joint_precision_recall(pred, gt, 0.2, gt_present=present))
    assert_allclose(pr.recall, [1 / 2, 1 / 2, 1.0])
    detected = np.zeros((2, 3), bool)
    pr = aggregate_precision_recall(joint_precision_recall(pred, gt, 0.2, pred_detected=detected))
    assert_allclose(pr.precision, 0.0) and assert_allclose(pr.recall, 0.0)


# --- input checks, jit ---------------------------------------------------------------------------


def test_mismatched_shapes_raise():
    with pytest.raises((ValueError, TypeError), match="shape|Type-check"):  # TypeError: jaxtyping in tests
        mpjpe(np.zeros((17, 3)), np.zeros((15, 3)))
    with pytest.raises((ValueError, TypeError), match="mask must have shape|Type-check"):
        mpjpe(np.zeros((2, 17, 3)), np.zeros((2, 17, 3)), np.ones((1, 17), bool))


def test_jit_equals_eager():
    """The public metrics are jitted, so every reference test above checks compiled code; this one
    also runs the reduction-heavy kernels op by op (slow: a compile per op) and compares."""
    pred, gt = poses(15, 4, 8), poses(16, 4, 8)
    mask = np.random.default_rng(17).random((4, 8, 17)) > 0.2
    cases = [
        (pa_mpjpe, (pred, gt, mask)),
        (partial(pcp, skeleton=STRUCTRI17, strict=True), (pred, gt)),
        (lambda p: mbls(p, STRUCTRI17), (pred,)),
        (acceleration_error, (pred, gt, mask[..., 0])),
        (lambda p, g: aggregate_precision_recall(joint_precision_recall(p, g, 1.5)), (pred, gt)),
    ]
    for fn, args in cases:
        with jax.disable_jit():  # the metrics are jitted internally: compare with op-by-op execution
            eager = fn(*args)
        jitted = jax.jit(fn)(*args)
        jax.tree.map(lambda a, b: assert_allclose(a, b, rtol=1e-10, atol=1e-12), eager, jitted)
    # Leading batch dimensions are independent items.
    assert_allclose(pa_mpjpe(pred, gt, mask)[2, 5], pa_mpjpe(pred[2, 5], gt[2, 5], mask[2, 5]))

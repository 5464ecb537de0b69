"""PHD+T's data plumbing, model, losses and metrics (dynamics/_data.py, _phdt.py, _losses.py, _evaluate.py)."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx
from jaxtyping import TypeCheckError
from numpy.testing import assert_allclose

import geometry
import mocap
from dynamics import (PHDT, TEST_MULTI_PERSON_CLIPS, TEST_SINGLE_PERSON_CLIPS, TRAIN_CLIPS, FrameTargets, Frames,
                      LossWeights, PHDTConfig, SMPLParams, crop_square, frame_losses, frame_metrics, gather_windows,
                      params_to_joints, square_boxes, window_starts, zero_motion)

BODY = geometry.stand_in_body_model()
CONFIG = PHDTConfig(feature_dim=128, joint_dim=128, hmr_hidden=64)
K = np.array([[300.0, 0, 160], [0, 300, 120], [0, 0, 1]])


def random_rotations(rng, shape):
    return np.array(geometry.axis_angle_to_matrix(rng.normal(scale=0.4, size=shape + (3,))))


def true_frames(rng, length: int, tracks: int = 1) -> Frames:
    """Rows of ``tracks`` tracks of a random body walking in front of the camera, with consistent ground truth."""
    count = length * tracks
    rotations = random_rotations(rng, (count, 24))
    rotations[:, 0] = np.diag([1.0, -1.0, -1.0])  # upright, facing the camera
    betas = rng.normal(size=(count, 3))
    root = np.stack([np.linspace(-0.5, 0.5, count), np.full(count, 0.2), np.full(count, 5.0)], axis=1)
    joints = np.asarray(jax.vmap(geometry.body_joints, in_axes=(None, 0, 0, None))(BODY, rotations, betas, np.zeros(3)))
    joints = joints - joints[:, :1] + root[:, None]
    pixels = joints @ K.T
    pixels = pixels[..., :2] / pixels[..., 2:]
    tight = np.concatenate([pixels.min(axis=1), pixels.max(axis=1)], axis=1)
    ids = np.arange(count)
    return Frames(np.zeros((count, 8, 8, 3), np.uint8), square_boxes(tight, 1.2), np.broadcast_to(K, (count, 3, 3)),
                  rotations, betas, root, joints, pixels, tight, ids // length, ids // length, np.zeros(count, int),
                  np.zeros(count, int), ids % length)


def true_params(frames: Frames) -> SMPLParams:
    return SMPLParams(jnp.asarray(geometry.matrix_to_rotation_6d(frames.rotations)), jnp.asarray(frames.betas),
                      jnp.zeros(frames.betas.shape[:-1] + (3,)))


def test_crop_square_maps_the_box_onto_the_crop():
    image = np.zeros((120, 160, 3), np.uint8)
    image[40:60, 70:90] = 255  # a 20 px square centred on (79.5, 49.5)
    crop = crop_square(image, np.array([59.5, 29.5, 99.5, 69.5]), 16)  # the 40 px box around it
    assert crop.shape == (16, 16, 3)
    assert np.all(crop[5:11, 5:11] == 255) and np.all(crop[:3] == 0) and np.all(crop[:, -3:] == 0)
    with pytest.raises(ValueError, match="no area"):
        crop_square(image, np.array([10.0, 10, 10, 20]), 16)


def test_square_boxes_are_centred_squares_of_the_longer_side():
    assert_allclose(square_boxes(np.array([[10.0, 20, 50, 100]]), 1.5), [[-30.0, 0, 90, 120]])


def test_windows_never_cross_a_track():
    frames = true_frames(np.random.default_rng(0), 6, tracks=3)
    starts = window_starts(frames, 4, stride=1)
    assert_allclose(starts, [0, 1, 2, 6, 7, 8, 12, 13, 14])
    windows = gather_windows(frames, starts, 4)
    assert windows.joints3d.shape == (9, 4, 24, 3)
    assert np.all(windows.track == windows.track[:, :1])
    assert_allclose(windows.frame[:, 0], [0, 1, 2] * 3)
    assert len(window_starts(frames, 7)) == 0


def test_single_person_test_subjects_never_train_and_no_test_take_trains():
    subjects = lambda names: {trial.split("_")[0] for name in names for trial in mocap.load_clip(name).trials}  # noqa: E731
    takes = lambda names: {trial for name in names for trial in mocap.load_clip(name).trials}  # noqa: E731
    assert subjects(TEST_SINGLE_PERSON_CLIPS) == {"01", "03"}
    assert not subjects(TEST_SINGLE_PERSON_CLIPS) & subjects(TRAIN_CLIPS)
    # The only two-person recordings are two takes of subjects 60 and 61: the pair's test take is unseen, its subjects not.
    assert not takes(TEST_MULTI_PERSON_CLIPS) & takes(TRAIN_CLIPS)


def test_the_ground_truth_scores_perfectly_and_a_shift_moves_only_root_pck_and_depth():
    frames = true_frames(np.random.default_rng(1), 5)
    params = true_params(frames)
    metrics = frame_metrics(BODY, params, jnp.asarray(frames.root), frames, 0.05)
    assert_allclose(metrics["mpjpe"], 0.0, atol=1e-9)
    assert_allclose(metrics["pa_mpjpe"], 0.0, atol=1e-5)
    assert_allclose(metrics["root"], 0.0, atol=1e-9)
    assert_allclose(metrics["pck"], 100.0)
    assert_allclose(metrics["depth_ratio"], 1.0, rtol=1e-6)
    shifted = frame_metrics(BODY, params, jnp.asarray(frames.root) + jnp.array([[0.3, 0, 0]]), frames, 0.05)
    assert_allclose(shifted["mpjpe"], 0.0, atol=1e-9)
    assert_allclose(shifted["root"], 300.0, rtol=1e-9)
    assert_allclose(shifted["depth_ratio"], 1.0, rtol=1e-6)
    assert np.all(np.asarray(shifted["pck"]) < 50.0)
    nearer = frame_metrics(BODY, params, jnp.asarray(frames.root) * 0.8, frames, 0.05)  # along the viewing ray
    assert_allclose(nearer["depth_ratio"], 0.8, rtol=1e-6)


def test_losses_vanish_at_the_truth_except_the_shape_prior():
    frames = true_frames(np.random.default_rng(2), 4)
    targets = FrameTargets(frames.rotations, frames.betas, frames.joints3d, frames.joints2d, frames.boxes, frames.K)
    terms = frame_losses(BODY, true_params(frames), jnp.asarray(frames.root), targets, None, LossWeights())
    assert set(terms) == {"smpl", "joints_3d", "shape_prior", "keypoints_2d"}
    for name in ("smpl", "joints_3d", "keypoints_2d"):
        assert_allclose(terms[name], 0.0, atol=1e-9)
    assert terms["shape_prior"] > 0
    moved = frame_losses(BODY, true_params(frames), jnp.asarray(frames.root) + 0.1, targets, None, LossWeights())
    assert moved["keypoints_2d"] > 0.1


def test_the_joint_distance_loss_is_the_mean_joint_distance_with_finite_gradients_at_the_truth():
    """``joints_3d_error="distance"``: 60 x the mean over frames and joints of each joint's Euclidean distance
    (pelvises aligned), against a NumPy reference; where every joint is exactly on target the term vanishes with a
    finite gradient (a norm's is NaN at 0)."""
    frames = true_frames(np.random.default_rng(4), 3)
    targets = FrameTargets(frames.rotations, frames.betas, frames.joints3d, None, None, None)
    weights = dataclasses.replace(LossWeights(), joints_3d_error="distance")
    params = true_params(frames)
    moved = params._replace(rot6d=params.rot6d + 0.05 * jnp.asarray(np.random.default_rng(5).normal(
        size=params.rot6d.shape)))
    joints = np.asarray(params_to_joints(BODY, moved, jnp.zeros_like(moved.camera)))
    truth = frames.joints3d - frames.joints3d[..., :1, :]
    reference = 60.0 * np.mean(np.linalg.norm(joints - truth, axis=-1))
    assert reference > 1.0  # a few centimetres off, not a vanishing case
    terms = frame_losses(BODY, moved, None, targets, None, weights)
    assert_allclose(terms["joints_3d"], reference, rtol=1e-9)
    squared = frame_losses(BODY, moved, None, targets, None, LossWeights())["joints_3d"]
    assert_allclose(squared, 30.0 * np.mean((joints - truth) ** 2), rtol=1e-9)
    for name in ("smpl", "shape_prior"):  # only the 3D-joint term changes
        assert_allclose(terms[name], frame_losses(BODY, moved, None, targets, None, LossWeights())[name], rtol=1e-12)
    exact = targets._replace(joints3d=params_to_joints(BODY, params, jnp.zeros_like(params.camera)))
    at_truth = lambda rot6d: frame_losses(BODY, params._replace(rot6d=rot6d), None, exact, None,  # noqa: E731
                                          weights)["joints_3d"]
    assert at_truth(params.rot6d) == 0.0
    assert np.all(np.isfinite(np.asarray(jax.grad(at_truth)(params.rot6d))))
    # The test session's type checker refuses it first; without it, LossWeights' own check does.
    with pytest.raises((ValueError, TypeCheckError), match="joints_3d_error"):
        LossWeights(joints_3d_error="l1")


def test_observation_is_causal_and_rollout_is_jittable():
    model = PHDT(CONFIG, rngs=nnx.Rngs(0))
    rng = np.random.default_rng(3)
    features = rng.normal(size=(2, 20, CONFIG.feature_dim))
    boxes = np.broadcast_to(np.array([100.0, 60, 180, 140]), (2, 20, 4))
    Ks = np.broadcast_to(K, (2, 20, 3, 3))
    observed = model.observe(BODY, features, boxes, Ks)
    changed = features.copy()
    changed[:, 15:] += 1.0
    later = model.observe(BODY, changed, boxes, Ks)
    assert_allclose(later.params.rot6d[:, :15], observed.params.rot6d[:, :15], atol=1e-12)
    assert_allclose(later.root[:, :15], observed.root[:, :15], atol=1e-12)
    assert not np.allclose(later.params.rot6d[:, 15:], observed.params.rot6d[:, 15:])

    eager = model.rollout(BODY, observed, 6)
    graphdef, state = nnx.split(model)
    jitted = jax.jit(lambda state, observed: nnx.merge(graphdef, state).rollout(BODY, observed, 6))(state, observed)
    assert eager.params.rot6d.shape == (2, 6, 24, 6) and eager.root.shape == (2, 6, 3)
    for a, b in zip(jax.tree.leaves(eager), jax.tree.leaves(jitted)):
        assert_allclose(a, b, rtol=1e-9, atol=1e-9)
    # An untrained translation head predicts no motion.
    assert_allclose(eager.root, np.broadcast_to(observed.root[:, -1:], (2, 6, 3)), atol=1e-12)
    # The rollout is a rolled loop: its program does not grow with the horizon (unrolled, every predicted frame was
    # compiled apart and a 25-frame training step took minutes to compile).
    program = lambda horizon: jax.jit(  # noqa: E731
        lambda state, observed: nnx.merge(graphdef, state).rollout(BODY, observed, horizon)).lower(state, observed)
    assert len(program(24).as_text()) < 1.1 * len(program(6).as_text())
    with pytest.raises(ValueError, match=f"need features \\(\\*b, T, {CONFIG.feature_dim}\\)"):
        model.observe(BODY, features[..., :-1], boxes, Ks)
    with pytest.raises(ValueError, match="at least 13 observed frames"):
        model.rollout(BODY, jax.tree.map(lambda x: x[:, :12], observed), 3)


def test_zero_motion_repeats_the_last_observed_frame():
    model = PHDT(CONFIG, rngs=nnx.Rngs(1))
    features = np.random.default_rng(4).normal(size=(1, 14, CONFIG.feature_dim))
    observed = model.observe(BODY, features, np.broadcast_to(np.array([100.0, 60, 180, 140]), (1, 14, 4)),
                             np.broadcast_to(K, (1, 14, 3, 3)))
    repeated = zero_motion(observed, 4)
    for predicted, last in ((repeated.params.rot6d, observed.params.rot6d[:, -1]), (repeated.root, observed.root[:, -1]),
                            (repeated.params.betas, observed.params.betas[:, -1])):
        assert predicted.shape[1] == 4
        assert_allclose(predicted, np.repeat(np.asarray(last)[:, None], 4, axis=1))


@pytest.mark.parametrize(("option", "value", "message"), [
    ("horizon", 29, "the horizon must reach 30 frames"),
    ("observed", 0, "observed must be >= 1 frame"),
    ("stride", 0, "stride must be >= 1"),
    ("pck_alpha", 0.0, r"pck_alpha must be in \(0, 1\]"),
])
def test_a_bad_evaluation_option_is_refused_by_name(option, value, message):
    from dynamics import EvalConfig

    with pytest.raises(ValueError, match=message):
        EvalConfig(**{option: value})

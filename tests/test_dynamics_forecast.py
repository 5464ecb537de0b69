"""3D forecasting from observed poses (dynamics/_poses.py, _forecast.py, _train_forecast.py): the window frame, the
baselines, the forecasters' interface, the ablation's starting point, the data split, the motion of a real file and
a training run resumed after a kill."""

import dataclasses
import shutil
import unittest.mock

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp
import pytest
from flax import nnx
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose, assert_array_equal
from scipy.spatial.transform import Rotation

import dynamics
import geometry
import mocap
import training
from _training_harness import Killed, assert_same_parameters, kill_at

BODY = geometry.stand_in_body_model()
TINY_JAT = dynamics.JATConfig(feature_dim=16, temporal_dim=16, joint_dim=8, hmr_hidden=16, hmr_dropout=0.0,
                              bias_hidden=8)
TINY_PHDT = dynamics.PHDTConfig(feature_dim=16, joint_dim=16, channels_per_group=16, hmr_hidden=16, hmr_dropout=0.0,
                                delta_offsets=())


def _world_window(seed: int, frames: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """A walking-like window in the z-up world: small random local rotations, the body upright and turned about
    z, moving forward; joints posed by the body model."""
    rng = np.random.default_rng(seed)
    local = geometry.axis_angle_to_matrix(jnp.asarray(rng.normal(0.0, 0.2, (frames, 24, 3))))
    upright = geometry.axis_angle_to_matrix(jnp.asarray([np.pi / 2, 0.0, 0.0]))  # body y up -> world z up
    heading = geometry.axis_angle_to_matrix(jnp.asarray([[0.0, 0.0, a] for a in rng.uniform(-np.pi, np.pi, frames)]))
    rotations = local.at[:, 0].set(heading @ upright @ local[:, 0])
    translation = np.cumsum(rng.normal(0.0, 0.05, (frames, 3)), axis=0) + [0.0, 0.0, 0.9]
    pose = jax.vmap(geometry.body_joints, in_axes=(None, 0, None, 0))
    joints = pose(BODY, rotations, jnp.zeros(BODY.num_shapes), jnp.asarray(translation))
    return np.asarray(rotations), np.asarray(joints)


def _two_people(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Rotations (2, L, 24, 3, 3) and joints (2, L, 24, 3) of two people a metre or so apart."""
    (r0, j0), (r1, j1) = _world_window(seed), _world_window(seed + 1)
    return np.stack([r0, r1]), np.stack([j0, j1 + [1.0, 0.5, 0.0]])


def _yaw(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_mirrored_frames_are_posed_by_their_rotations_and_mirror_back():
    rotations, joints = _world_window(3)
    frames = dynamics.PoseFrames(rotations, np.zeros((6, 3), np.float32), joints, *[np.zeros(6, np.int32)] * 4)
    mirrored = dynamics.mirror_frames(frames, BODY)
    pose = jax.vmap(geometry.body_joints, in_axes=(None, 0, None, None))
    posed = np.asarray(pose(BODY, jnp.asarray(mirrored.rotations), jnp.zeros(3), jnp.zeros(3)))
    assert_allclose(posed - posed[:, :1], mirrored.joints3d - mirrored.joints3d[:, :1], atol=1e-5)
    assert_allclose(mirrored.joints3d[:, 1, 0], -joints[:, 2, 0], atol=1e-6)  # the left hip where the right one was
    twice = dynamics.mirror_frames(mirrored, BODY)
    assert_allclose(twice.rotations, rotations, atol=1e-6)
    assert_allclose(twice.joints3d, joints, atol=1e-6)


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 10_000), angle=st.floats(-np.pi, np.pi), shift=st.tuples(*[st.floats(-5.0, 5.0)] * 3))
def test_canonical_window_forgets_heading_and_place(seed, angle, shift):
    rotations, joints = _two_people(seed)  # a scene of two people: both move with the first's frame
    canonical = dynamics.canonical_window(jnp.asarray(rotations), jnp.asarray(joints), 3)
    turn = _yaw(angle)
    moved = (rotations.copy(), joints @ turn.T + np.asarray(shift))
    moved[0][:, :, 0] = turn @ rotations[:, :, 0]
    again = dynamics.canonical_window(jnp.asarray(moved[0]), jnp.asarray(moved[1]), 3)
    for ours, theirs in zip(canonical, again):
        assert_allclose(np.asarray(theirs), np.asarray(ours), atol=1e-9)


def test_canonical_window_is_the_virtual_camera_of_the_last_observed_frame():
    rotations, joints = _two_people(3)
    canonical_rotations, canonical_joints = map(np.asarray, dynamics.canonical_window(jnp.asarray(rotations),
                                                                                      jnp.asarray(joints), 4))
    last = canonical_joints[0, 4]
    assert_allclose(last[0], 0.0, atol=1e-12)  # the pelvis at the origin
    hips = last[1] - last[2]  # left minus right hip: along +x, level in the camera's x-z plane
    assert hips[0] > 0 and abs(hips[2]) < 1e-9
    assert np.all(canonical_joints[..., 15, 1] < canonical_joints[..., 0, 1])  # the head above the pelvis: y down
    # One rigid motion for the whole scene: every distance, within a person and between the two, is kept.
    points = lambda j: j.transpose(1, 0, 2, 3).reshape(j.shape[1], -1, 3)  # noqa: E731  (frames, 48 joints, 3)
    distances = lambda p: np.linalg.norm(p[:, :, None] - p[:, None, :], axis=-1)  # noqa: E731
    assert_allclose(distances(points(canonical_joints)), distances(points(joints)), atol=1e-9)
    # Rotations and joints moved together: posing the body with the new rotations gives the new joints.
    posed = jax.vmap(jax.vmap(geometry.body_joints, in_axes=(None, 0, None, None)), in_axes=(None, 0, None, None))(
        BODY, jnp.asarray(canonical_rotations), jnp.zeros(BODY.num_shapes), jnp.zeros(3))
    posed = np.asarray(posed) - np.asarray(posed)[..., :1, :] + canonical_joints[..., :1, :]
    assert_allclose(posed, canonical_joints, atol=1e-9)
    assert_array_equal(canonical_rotations[..., 1:, :, :], rotations[..., 1:, :, :])  # local rotations unchanged


def test_pose_features_layout():
    rotations, joints = _world_window(5, frames=2)
    features = np.asarray(dynamics.pose_features(jnp.asarray(rotations), jnp.asarray(joints)))
    assert features.shape == (2, dynamics.POSE_FEATURES)
    assert_allclose(features[:, :144].reshape(2, 24, 6), np.asarray(geometry.matrix_to_rotation_6d(rotations)))
    assert_allclose(features[:, 144:216].reshape(2, 24, 3), joints - joints[:, :1])
    assert_allclose(features[:, 216:], joints[:, 0])


def test_baselines():
    start, step = np.random.default_rng(0).normal(size=(2, 24, 3))
    observed = start + np.arange(5)[:, None, None] * step  # constant velocity
    ahead = start + np.arange(5, 9)[:, None, None] * step
    assert_allclose(np.asarray(dynamics.constant_velocity_forecast(observed, 4)), ahead, atol=1e-12)
    zero = np.asarray(dynamics.zero_motion_forecast(observed[None], 3))
    assert zero.shape == (1, 3, 24, 3) and np.all(zero == observed[-1])
    with pytest.raises(ValueError, match="constant velocity needs at least 2 observed frames, got 1"):
        dynamics.constant_velocity_forecast(observed[:1], 2)


@pytest.mark.parametrize("model", [dict(jat=TINY_JAT), dict(phdt=TINY_PHDT)], ids=["JAT", "PHD+T"])
def test_forecasters_take_scenes_and_refuse_bad_shapes(model):
    forecaster = dynamics.PoseForecaster(dynamics.ForecasterConfig(**model), rngs=nnx.Rngs(0))
    rotations, joints = _world_window(1, frames=14)
    rotations, joints = dynamics.canonical_window(jnp.asarray(rotations[None]), jnp.asarray(joints[None]), 13)
    scene = lambda x: jnp.broadcast_to(x, (2,) + x.shape)  # noqa: E731  (2 windows of 1 person)
    betas = jnp.zeros((2, 1, 14, 3))
    forecast = lambda model, *inputs: dynamics.forecast_joints(model, BODY, *inputs, 4)  # noqa: E731
    if "jat" in model:  # op by op, JAT's rollout took twice its compilation; PHD+T's unrolled one the other way
        forecast = nnx.jit(forecast)
    predicted = forecast(forecaster, scene(rotations), betas, scene(joints))
    assert predicted.shape == (2, 1, 4, 24, 3) and bool(jnp.all(jnp.isfinite(predicted)))
    with pytest.raises(ValueError, match=r"need rotations \(\*b, N, T, 24, 3, 3\), betas \(\*b, N, T, 3\) and joints"):
        forecaster.observe(scene(rotations), jnp.zeros((2, 1, 14, 5)), scene(joints))  # 5 shape coefficients
    with pytest.raises(ValueError, match="exactly one of phdt and jat"):
        dynamics.ForecasterConfig()
    with pytest.raises(ValueError, match="extrapolation is a fraction of the last step"):
        dataclasses.replace(next(iter(model.values())), extrapolation=1.5)
    if "jat" in model:  # one observed frame has no last step to move on by (PHD+T needs 13 frames anyway)
        extrapolating = dynamics.PoseForecaster(dynamics.ForecasterConfig(
            jat=dataclasses.replace(TINY_JAT, decode_from="extrapolated")), rngs=nnx.Rngs(0))
        last = lambda x: scene(x)[:, :, -1:]  # noqa: E731
        with pytest.raises(ValueError, match="the extrapolated pose needs at least 2 observed frames, got 1"):
            dynamics.forecast_joints(extrapolating, BODY, last(rotations), betas[:, :, -1:], last(joints), 2)


EVERY_START = (("previous", 1.0), ("extrapolated", 1.0), ("mean", 1.0), ("extrapolated", 1 / 3))


# JAT (its rollout op by op takes a while) with two starts: its carry's order of the two previous frames shows in both.
@pytest.mark.parametrize(("model", "starts"), [(dict(jat=TINY_JAT), EVERY_START[::3]),
                                               (dict(phdt=TINY_PHDT), EVERY_START)], ids=["JAT", "PHD+T"])
def test_a_silent_decoder_repeats_or_extrapolates_the_last_pose(model, starts):
    """f_HMR refines the previous frame's pose, plain or moved on by its last step: with its decoder silent (and
    f_transl untrained, zero-initialised), every predicted frame is the last observed one, as ZeroMotion's, or the
    last rotations turned on by their last step at every predicted frame, or the first by a third of it; decoding
    from the mean pose it is none of these."""
    rotations, joints = _world_window(2, frames=14)
    rotations, joints = dynamics.canonical_window(jnp.asarray(rotations[None]), jnp.asarray(joints[None]), 13)
    scene = lambda x: x[None]  # noqa: E731
    betas = jnp.zeros((1, 1, 14, 3))
    zero = np.asarray(dynamics.zero_motion_forecast(joints[0], 3))
    step = np.asarray(rotations[0, -1] @ jnp.swapaxes(rotations[0, -2], -1, -2))  # R_t R_{t-1}^T per joint
    turned = [np.asarray(rotations[0, -1])]
    for _ in range(3):
        turned.append(step @ turned[-1])
    pose = jax.vmap(geometry.body_joints, in_axes=(None, 0, None, None))
    extrapolated = np.array(pose(BODY, jnp.asarray(np.stack(turned[1:])), jnp.zeros(3), jnp.zeros(3)))
    extrapolated += np.asarray(joints[0, -1, 0]) - extrapolated[:, :1]  # the pelvis stays (f_transl is silent)
    # A third of the last step (SciPy's rotation vectors): the first predicted frame only.
    third = Rotation.from_rotvec(Rotation.from_matrix(step.reshape(-1, 3, 3)).as_rotvec() / 3.0).as_matrix()
    slowed = np.array(pose(BODY, jnp.asarray(third.reshape(1, 24, 3, 3) @ turned[0]), jnp.zeros(3), jnp.zeros(3)))[0]
    slowed += np.asarray(joints[0, -1, 0]) - slowed[:1]
    config = next(iter(model.values()))
    for decode_from, extrapolation in starts:
        models = {name: dataclasses.replace(config, decode_from=decode_from, extrapolation=extrapolation)
                  for name in model}
        forecaster = dynamics.PoseForecaster(dynamics.ForecasterConfig(**models), rngs=nnx.Rngs(0))
        head = forecaster.model.hmr
        head.decoder.kernel[...] = jnp.zeros_like(head.decoder.kernel[...])
        head.decoder.bias[...] = jnp.zeros_like(head.decoder.bias[...])
        predicted = np.asarray(dynamics.forecast_joints(forecaster, BODY, scene(rotations), betas, scene(joints), 3))
        constant = decode_from == "extrapolated" and extrapolation == 1.0
        assert np.allclose(predicted[0, 0], zero, atol=1e-5) == (decode_from == "previous"), decode_from
        assert np.allclose(predicted[0, 0], extrapolated, atol=1e-4) == constant, decode_from
        assert np.allclose(predicted[0, 0, 0], slowed, atol=1e-4) == (extrapolation != 1.0), decode_from


def test_widened_forecasters():
    phdt = dynamics.FORECASTERS["PHD+T"]
    wide = phdt.widened(2).phdt
    video = dynamics.PHDTConfig()  # the video PHD+T's sizes
    assert (wide.feature_dim, wide.joint_dim, wide.hmr_hidden, wide.channels_per_group) == (
        video.feature_dim, video.joint_dim, video.hmr_hidden, video.channels_per_group)
    assert (wide.decode_from, wide.extrapolation, wide.tcn_blocks) == (
        phdt.phdt.decode_from, phdt.phdt.extrapolation, phdt.phdt.tcn_blocks)
    assert phdt.widened(1) == phdt
    jat = dynamics.FORECASTERS["JAT"].widened(3).jat
    widths = (jat.feature_dim, jat.temporal_dim, jat.joint_dim, jat.hmr_hidden, jat.bias_hidden)
    assert widths == (384, 384, 192, 768, 192)
    count = lambda config: sum(p.size for p in jax.tree.leaves(nnx.state(  # noqa: E731
        dynamics.initial_forecaster(config, 0), nnx.Param)))
    assert count(phdt.widened(2)) > 3 * count(phdt)
    with pytest.raises(ValueError, match="width factor must be >= 1, got 0"):
        phdt.widened(0)


def test_the_bias_ablation_starts_where_jat_starts():
    jat = dynamics.initial_forecaster(dynamics.FORECASTERS["JAT"], 0)
    ablation = dynamics.initial_forecaster(dynamics.FORECASTERS["JAT w/o bias"], 0)
    jat_params = dict(nnx.to_flat_state(nnx.state(jat, nnx.Param)))
    ablation_params = dict(nnx.to_flat_state(nnx.state(ablation, nnx.Param)))
    assert set(ablation_params) < set(jat_params)
    assert {path[1] for path in set(jat_params) - set(ablation_params)} == {"bias_self"}
    for path, variable in ablation_params.items():
        assert_array_equal(np.asarray(variable[...]), np.asarray(jat_params[path][...]), err_msg=str(path))
    # Built on its own from the same seed, the ablation would not start there (its RNG stream skips the bias).
    alone = dict(nnx.to_flat_state(nnx.state(dynamics.PoseForecaster(dynamics.FORECASTERS["JAT w/o bias"],
                                                                      rngs=nnx.Rngs(0)), nnx.Param)))
    assert any(not np.array_equal(np.asarray(alone[p][...]), np.asarray(jat_params[p][...])) for p in alone)


def test_forecast_split_keeps_one_file_per_action_for_validation(data_root):
    training_files, validation_files = dynamics.forecast_split(data_root)
    every = {str(f.resolve()) for f in mocap.cmu_expmap_files(data_root, "train")}
    assert set(training_files) | set(validation_files) == every and not set(training_files) & set(validation_files)
    actions = [f.split("/")[-2] for f in validation_files]
    assert sorted(actions) == sorted(set(actions)) == sorted({f.split("/")[-2] for f in every})
    assert any(f.endswith("walking_extra/walking_52.txt") for f in validation_files)  # the highest number
    test_file = str(mocap.cmu_expmap_files(data_root, "test")[0])
    with pytest.raises(ValueError, match="is in the benchmark's test split"):
        dynamics.ForecastTrainConfig(training_files + (test_file,), validation_files)
    with pytest.raises(ValueError, match="is both a training and a validation file"):
        dynamics.ForecastTrainConfig(training_files, validation_files + training_files[:1])
    with pytest.raises(ValueError, match="speeds must be positive"):
        dynamics.ForecastTrainConfig(training_files, validation_files, speeds=())


def test_pose_frames_of_a_real_file(data_root, tmp_path):
    file = data_root / "cmu_expmap" / "test" / "walking" / "walking_1.txt"
    frames = dynamics.pose_frames([file], BODY, cache_dir=tmp_path)
    lines = len(file.read_text().splitlines())
    assert frames.num_frames == int(np.floor((lines - 1) / 120.0 * 25.0 + 1e-9)) + 1
    assert np.isfinite(frames.joints3d).all() and np.all(frames.track == 0)
    parents = geometry.SMPL24.parents
    bones = np.linalg.norm(frames.joints3d[:, 1:] - frames.joints3d[:, list(parents[1:])], axis=-1)
    assert np.ptp(bones, axis=0).max() < 1e-5  # a rigid skeleton: the body model's bones
    speed = np.median(np.linalg.norm(np.diff(frames.joints3d[:, 0, :2], axis=0), axis=-1)) * 25.0
    assert 0.8 < speed < 2.0  # a walk, metres per second
    cached = list(tmp_path.glob("pose_frames_*.npz"))
    assert len(cached) == 1
    again = dynamics.pose_frames([file], BODY, cache_dir=tmp_path)
    for ours, theirs in zip(frames, again):
        assert_array_equal(theirs, ours)


def test_pose_frames_of_people_captured_together(data_root):
    pair = "+".join(str(data_root / "cmu_mocap" / f"{subject}_05_scaled.bvh") for subject in (60, 61))
    frames = dynamics.pose_frames([pair], BODY)
    assert set(np.unique(frames.person)) == {0, 1} and np.all(frames.video == 0)
    assert_array_equal(frames.frame[frames.person == 0], frames.frame[frames.person == 1])
    scenes, present = dynamics.scene_windows(frames, 50, stride=25, people=2)
    assert len(scenes) > 0 and present.all()
    apart = np.linalg.norm(frames.joints3d[frames.person == 0, 0] - frames.joints3d[frames.person == 1, 0], axis=-1)
    assert 0.2 < np.median(apart) < 2.0  # dance partners, metres between pelvises
    with pytest.raises(ValueError, match="is a shipped clip"):
        dynamics.pose_frames(["02_01_walk"], BODY)


def _short_files(data_root, tmp_path) -> list[str]:
    """Three short actions (the first two train, the last validates), copied under a folder of their own (a user's
    files, outside the benchmark's split)."""
    files = []
    for action in ("walking", "jumping", "soccer"):
        source = data_root / "cmu_expmap" / "train" / action / f"{action}_1.txt"
        target = tmp_path / "motion" / f"{action}_1.txt"
        target.parent.mkdir(exist_ok=True)
        target.write_text("\n".join(source.read_text().splitlines()[:400]) + "\n")
        files.append(str(target))
    return files


def test_training_resumes_after_a_kill_bit_identically(data_root, tmp_path):
    files = _short_files(data_root, tmp_path)
    # Decoding from the extrapolated pose, the motion at two speeds and mirrored (the augmentations).
    model = dynamics.ForecasterConfig(phdt=dataclasses.replace(TINY_PHDT, decode_from="extrapolated", tcn_blocks=1))
    config = dynamics.ForecastTrainConfig(
        tuple(files[:2]), tuple(files[2:]), model=model, speeds=(1.0, 1.25), mirror=True,
        stage=dynamics.StageConfig(steps=4, batch_size=2, learning_rate=1e-3, warmup_steps=1), observed=6,
        horizon=3, checkpoint_interval=2, validation_interval=4, log_interval=1, cache_dir=str(tmp_path / "cache"))
    full = dynamics.train_forecaster(config, tmp_path / "full", BODY, resume=False, progress=False)
    assert len(list((tmp_path / "cache").glob("pose_frames_*.npz"))) == 3  # training at 2 speeds, validation
    with pytest.raises(Killed):
        dynamics.train_forecaster(config, tmp_path / "run", BODY, resume=False, log=kill_at(3), progress=False)
    resumed = dynamics.train_forecaster(config, tmp_path / "run", BODY, resume=True, progress=False)
    assert_same_parameters(resumed, full)
    shutil.copytree(tmp_path / "full" / "model", tmp_path / "models" / "phdt")
    loaded = dynamics.load_forecasters(tmp_path / "models")
    assert list(loaded) == ["PHD+T"]
    assert_same_parameters(loaded["PHD+T"], full)
    with pytest.raises(FileNotFoundError, match="holds none of the forecasters"):
        dynamics.load_forecasters(tmp_path / "full")


def test_clipping_scales_the_gradient_down_before_adam(data_root, tmp_path):
    """Adam's first step moves a parameter by about the learning rate whatever its gradient's scale, unless the
    gradient is below Adam's epsilon (1e-8): clipped to a norm of 1e-12 the step moves no parameter by more than 1e-4
    times the learning rate, unclipped it moves some by the learning rate. Both runs log the norm before clipping."""
    files = _short_files(data_root, tmp_path)
    model = dynamics.ForecasterConfig(phdt=dataclasses.replace(TINY_PHDT, tcn_blocks=1))
    stage = dynamics.StageConfig(steps=1, batch_size=2, learning_rate=1e-3, warmup_steps=0)
    start = nnx.state(dynamics.initial_forecaster(model, 0), nnx.Param)
    moved, logged = {}, {}
    for clip_norm in (None, 1e-12):
        config = dynamics.ForecastTrainConfig(
            tuple(files[:2]), tuple(files[2:]), model=model, speeds=(1.0,), mirror=False, observed=6, horizon=3,
            stage=dataclasses.replace(stage, clip_norm=clip_norm), log_interval=1, cache_dir=str(tmp_path / "cache"))
        records = []
        trained = dynamics.train_forecaster(config, tmp_path / f"clip_{clip_norm}", BODY, resume=False,
                                            log=records.append, progress=False)
        moved[clip_norm] = max(float(jnp.max(jnp.abs(a - b))) for a, b in zip(
            jax.tree.leaves(nnx.state(trained, nnx.Param)), jax.tree.leaves(start)))
        logged[clip_norm] = records[0]["grad_norm"]
    assert moved[None] > 0.5 * stage.learning_rate and moved[1e-12] < 1e-3 * stage.learning_rate
    assert logged[None] == logged[1e-12] > 1e-3


def test_the_moving_average_is_what_the_stage_validates_returns_and_resumes(data_root, tmp_path):
    """With ``average_decay`` d the stage returns a <- d a + (1 - d) p from the initial parameters, computed here from
    the unaveraged run's parameters (the same steps: the average does not change training); its validation is
    logged as ``val_*`` and the parameters' as ``raw_val_*``. A run killed after its first checkpoint resumes to the
    same average, and the unaveraged run's checkpoints keep their fields."""
    files = _short_files(data_root, tmp_path)
    model = dynamics.ForecasterConfig(phdt=dataclasses.replace(TINY_PHDT, tcn_blocks=1))
    stage = dynamics.StageConfig(steps=2, batch_size=2, learning_rate=1e-3, warmup_steps=0)
    config = lambda **changes: dynamics.ForecastTrainConfig(  # noqa: E731
        tuple(files[:2]), tuple(files[2:]), model=model, speeds=(1.0,), mirror=False, observed=6, horizon=3,
        stage=dataclasses.replace(stage, **changes), log_interval=1, validation_interval=1, checkpoint_interval=1,
        cache_dir=str(tmp_path / "cache"))
    decay = 0.75
    dynamics.train_forecaster(config(), tmp_path / "plain", BODY, resume=False, progress=False)
    checkpoints = tmp_path / "plain" / "forecast" / "checkpoints"
    params = [jax.tree.leaves(nnx.state(dynamics.initial_forecaster(model, 0), nnx.Param))] + [  # after steps 0, 1, 2
        jax.tree.leaves(ocp.StandardCheckpointer().restore(checkpoints / str(step) / "default")["params"])
        for step in (1, 2)]
    assert "average" not in ocp.StandardCheckpointer().restore(checkpoints / "2" / "default")
    expected = [decay ** 2 * p0 + decay * (1 - decay) * p1 + (1 - decay) * p2 for p0, p1, p2 in zip(*params)]
    records = []
    averaged = dynamics.train_forecaster(config(average_decay=decay), tmp_path / "averaged", BODY, resume=False,
                                         log=records.append, progress=False)
    for got, want in zip(jax.tree.leaves(nnx.state(averaged, nnx.Param)), expected, strict=True):
        np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=1e-5, atol=1e-7)
    assert {"val_future_mpjpe_mm", "raw_val_future_mpjpe_mm"} <= set(records[-1])
    assert records[-1]["val_future_mpjpe_mm"] != records[-1]["raw_val_future_mpjpe_mm"]
    shutil.rmtree(tmp_path / "averaged" / "forecast" / "checkpoints" / "2")  # killed after step 1's checkpoint
    resumed = dynamics.train_forecaster(config(average_decay=decay), tmp_path / "averaged", BODY, resume=True,
                                        progress=False)
    assert_same_parameters(resumed, averaged)


def _frames(video, person, frame) -> dynamics.PoseFrames:
    """Rows of the given recordings, people and frames (their poses at zero; tracks numbered per person)."""
    video, person, frame = (np.asarray(x, np.int32) for x in (video, person, frame))
    rows = len(video)
    track = np.unique(np.stack([video, person], 1), axis=0, return_inverse=True)[1].reshape(-1).astype(np.int32)
    return dynamics.PoseFrames(np.broadcast_to(np.eye(3, dtype=np.float32), (rows, 24, 3, 3)),
                               np.zeros((rows, 3), np.float32), np.zeros((rows, 24, 3), np.float32), track, video,
                               person, frame)


def test_scene_rows_and_the_validation_tail():
    # Recording 0: one person, 8 frames; recording 1: two people, 10 frames each.
    frames = _frames([0] * 8 + [1] * 20, [0] * 8 + [0] * 10 + [1] * 10, list(range(8)) + list(range(10)) * 2)
    single = dynamics.scene_rows(frames, 4, stride=3)
    assert_array_equal(single[:, 0, 0], [0, 3, 8, 11, 14, 18, 21, 24])  # every person's own windows
    assert_array_equal(single[1, 0], [3, 4, 5, 6])
    pairs = dynamics.scene_rows(frames, 4, people=2, stride=3)
    assert pairs.shape == (3, 2, 4)  # the single-person recording gives none
    assert_array_equal(pairs[0], [[8, 9, 10, 11], [18, 19, 20, 21]])
    assert_array_equal(frames.frame[pairs[:, 0]], frames.frame[pairs[:, 1]])
    early, tail = dynamics._train_forecast._split_tail(frames, 0.3)
    assert_array_equal(tail.frame, [5, 6, 7, 7, 8, 9, 7, 8, 9])  # the last 30 %: from floor(0.7 x 8), 0.7 x 10
    assert early.num_frames + tail.num_frames == frames.num_frames and early.frame.max() < 7
    assert_array_equal(dynamics.scene_rows(tail, 3, people=2)[0], [[3, 4, 5], [6, 7, 8]])


def _save(tmp_path, name: str, config: dynamics.ForecasterConfig, seed: int = 3):
    folder = tmp_path / name
    training.save_model(folder, config, nnx.state(dynamics.PoseForecaster(config, rngs=nnx.Rngs(seed))))
    return folder


def test_the_pair_models_start_from_a_trained_jat(tmp_path):
    jat = _save(tmp_path, "jat", dynamics.ForecasterConfig(jat=TINY_JAT))
    trained = dict(nnx.to_flat_state(nnx.state(dynamics.load_forecaster(jat), nnx.Param)))
    mpjat = dynamics.initial_forecaster(dynamics.ForecasterConfig(
        jat=dataclasses.replace(TINY_JAT, agent_aware=True)), 0, jat)
    counterpart = {"query_other": "query", "key_other": "key", "bias_other": "bias_self"}
    for path, variable in nnx.to_flat_state(nnx.state(mpjat, nnx.Param)):
        source = tuple(counterpart.get(part, part) for part in path)
        assert_array_equal(np.asarray(variable[...]), np.asarray(trained[source][...]), err_msg=str(path))
    again = dynamics.initial_forecaster(dynamics.ForecasterConfig(jat=TINY_JAT), 0, jat)
    assert_same_parameters(again, dynamics.load_forecaster(jat))
    phdt = _save(tmp_path, "phdt", dynamics.ForecasterConfig(phdt=TINY_PHDT))
    for start, model in ((phdt, dynamics.ForecasterConfig(jat=TINY_JAT)),
                         (jat, dynamics.ForecasterConfig(jat=dataclasses.replace(TINY_JAT, temporal_dim=32)))):
        with pytest.raises(ValueError, match="not a JAT that .* can start from"):
            dynamics.initial_forecaster(model, 0, start)


def test_pair_forecasters_train_with_the_interpenetration_term_and_score_it(data_root, tmp_path):
    training_pair, test_pair = dynamics.pair_split(data_root)
    assert training_pair.endswith("60_03_scaled.bvh+" + str(data_root / "cmu_mocap" / "61_03_scaled.bvh"))
    start = _save(tmp_path, "jat", dynamics.ForecasterConfig(jat=TINY_JAT))
    config = dynamics.ForecastTrainConfig(
        (training_pair,), people=2, validation_tail=0.3, start_from=str(start), speeds=(1.0,), mirror=False,
        stage=dynamics.StageConfig(steps=1, batch_size=2, learning_rate=1e-3, warmup_steps=0), observed=6,
        horizon=3, checkpoint_interval=1, validation_interval=1, log_interval=1, cache_dir=str(tmp_path / "cache"))
    # Each pair forecaster's run: its model, two people, its interpenetration weight (MPJAT's ablation: none).
    runs = {}
    with unittest.mock.patch.object(dynamics._train_forecast, "_train_table", lambda config, workdir, body, table,
                                    *rest: runs.update(table) or {}):
        dynamics.train_pair_forecasters(config, tmp_path / "runs", BODY, resume=False)
    assert {name: (run.model.jat.agent_aware, run.losses.interpenetration, run.people) for name, run in runs.items()} \
        == {"JAT": (False, 1.0, 2), "MPJAT": (True, 1.0, 2), "MPJAT w/o interpenetration": (True, 0.0, 2)}
    # The run's objective on a batch it draws, the body model traced as the training step traces it (the
    # interpenetration term's constants closed over); compiled without the gradient, which costs a minute more.
    stage = {}

    def run_stage(name, run, stage_config, workdir, model, trainable, objective, sample, validate, *args, **kwargs):
        stage.update(objective=objective, sample=sample, validate=validate)
        return model

    with unittest.mock.patch.object(dynamics._train_forecast, "_run_stage", run_stage):
        mpjat = dynamics.train_forecaster(dataclasses.replace(config, model=dynamics.ForecasterConfig(
            jat=dataclasses.replace(TINY_JAT, agent_aware=True))), tmp_path / "run", BODY, resume=False,
            progress=False)
    rows = stage["sample"](jax.random.key(0))
    assert rows.joints3d.shape == (2, 2, 9, 24, 3) and np.all(rows.video[:, 0] == rows.video[:, 1])
    assert_array_equal(rows.frame[:, 0], rows.frame[:, 1])  # both people over the same frames
    graphdef, state = nnx.split(mpjat)
    objective = lambda state, body, rows: stage["objective"](  # noqa: E731
        config, body, nnx.merge(graphdef, state), rows, jax.random.key(1), None)[1]
    terms = jax.jit(objective)(state, BODY, rows)
    assert "interpenetration" in terms and all(np.isfinite(float(value)) for value in terms.values())
    with pytest.raises(ValueError, match="set people=2 and start_from"):
        dynamics.train_pair_forecasters(dataclasses.replace(config, start_from=None), tmp_path / "x", BODY,
                                        resume=False)
    for options, message in (({"validation_tail": 0.0}, "give exactly one"), ({"people": 3}, "people must be 1 or 2"),
                             ({"validation_files": ("a.txt",)}, "give exactly one")):
        with pytest.raises(ValueError, match=message):
            dataclasses.replace(config, **options)

    # The study of two-person scenes (a forecaster's interpenetration is pinned in tests/test_headline_results.py).
    from experiments.dynamics_study import run_forecast_study
    summary = run_forecast_study(tmp_path / "study", {}, BODY, [test_pair], people=2, observed=6, stride=40,
                                 horizons_ms=(80, 120), cache_dir=tmp_path / "cache", progress=False)
    assert summary["windows"] == {"60_05_scaled+61_05_scaled": 9}
    assert set(summary["penetration_mm"]) == {"ZeroMotion", "ground truth"}  # constant velocity: no body
    assert all(value >= 0 for values in summary["penetration_mm"].values() for value in values)
    # The windows start at the pair's frames 0, 40, ...: ZeroMotion's error is how far each person moved from frame 5.
    frames = dynamics.pose_frames([test_pair], BODY, cache_dir=tmp_path / "cache")
    joints = frames.joints3d.reshape(2, -1, 24, 3)
    last = np.arange(9) * 40 + 5
    moved = [joints[:, last + k] - joints[:, last] for k in (2, 3)]
    expected = [1000.0 * np.mean(np.linalg.norm(m - m[..., :1, :], axis=-1)) for m in moved]  # pelvis aligned
    assert_allclose(summary["mpjpe_mm"]["ZeroMotion"]["average"], expected, rtol=1e-4)
    markdown = (tmp_path / "study" / "results.md").read_text()
    assert "## Average over pairs (9 windows)" in markdown and "## Interpenetration" in markdown


def test_command_refuses_a_missing_data_folder(tmp_path, capsys):
    from experiments import dynamics_forecast
    with pytest.raises(SystemExit) as exit_:
        dynamics_forecast._cli.run(dynamics_forecast.main, dynamics_forecast.Config,
                                   argv=["--out", str(tmp_path / "out"), "--data-root", str(tmp_path)])
    assert exit_.value.code == 2
    assert f"data folder {tmp_path} holds no cmu_expmap" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
    # The pairs need the salsa files, not the benchmark's.
    with pytest.raises(ValueError, match=f"data folder {tmp_path} holds no cmu_mocap"):
        dynamics_forecast.Config(out=tmp_path / "out", data_root=tmp_path, pairs=True)
    (tmp_path / "cmu_mocap").mkdir()
    assert dynamics_forecast.Config(out=tmp_path / "out", data_root=tmp_path, pairs=True).pairs


def test_command_line_training_options(data_root, tmp_path):
    from experiments import dynamics_forecast
    config = dynamics_forecast.Config(out=tmp_path, data_root=data_root, train=True, train_steps=4000,
                                      train_batch=64, train_names=("PHD+T",), train_speeds=(0.9, 1.1),
                                      train_mirror=True)
    train = config.train_config(("a.txt",), ("b.txt",))
    assert (train.stage.steps, train.stage.batch_size) == (4000, 64)
    assert train.speeds == (0.9, 1.1) and train.mirror
    assert train.stage.learning_rate == dynamics.ForecastTrainConfig(("a",), ("b",)).stage.learning_rate
    assert dynamics_forecast.Config(out=tmp_path, data_root=data_root, train_lr=1e-4).train_config(
        ("a.txt",), ("b.txt",)).stage.learning_rate == 1e-4
    assert train.stage.clip_norm == dynamics.ForecastTrainConfig(("a",), ("b",)).stage.clip_norm == 500.0
    for option, clip_norm in ((10.0, 10.0), (0.0, None)):  # 0: unclipped
        assert dynamics_forecast.Config(out=tmp_path, data_root=data_root, train_clip_norm=option).train_config(
            ("a.txt",), ("b.txt",)).stage.clip_norm == clip_norm
    assert train.stage.average_decay == dynamics.ForecastTrainConfig(("a",), ("b",)).stage.average_decay == 0.995
    for option, decay in ((0.99, 0.99), (0.0, None)):  # 0: no average
        assert dynamics_forecast.Config(out=tmp_path, data_root=data_root, train_average_decay=option).train_config(
            ("a.txt",), ("b.txt",)).stage.average_decay == decay
    assert train.losses.joints_3d_error == dynamics.ForecastTrainConfig(("a",), ("b",)).losses.joints_3d_error
    assert train.losses.joints_3d_error == "distance" and dynamics.LossWeights().joints_3d_error == "squared"
    for option in ("distance", "squared"):
        assert dynamics_forecast.Config(out=tmp_path, data_root=data_root, train_joint_error=option).train_config(
            ("a.txt",), ("b.txt",)).losses == dataclasses.replace(dynamics.LossWeights(), joints_3d_error=option)
    assert dynamics_forecast.Config(out=tmp_path, data_root=data_root, pairs=True, train_joint_error="distance"
                                    ).train_config(("a+b",), ()).losses.joints_3d_error == "distance"
    with unittest.mock.patch.object(dynamics_forecast, "train_forecasters", side_effect=KeyboardInterrupt) as train:
        with pytest.raises(KeyboardInterrupt):
            dynamics_forecast.main(dynamics_forecast.Config(out=tmp_path / "wide", data_root=data_root, train=True,
                                                            train_width=2, train_extrapolation=0.75))
    assert train.call_args.kwargs["width"] == 2
    assert train.call_args.kwargs["model_changes"] == {"extrapolation": 0.75}
    for options, message in (({"train_steps": 0}, "--train-steps must be >= 1"),
                             ({"train_width": 0}, "--train-width must be >= 1"),
                             ({"train_lr": 0.0}, "--train-lr must be positive"),
                             ({"train_clip_norm": -1.0}, "--train-clip-norm must be >= 0"),
                             ({"train_average_decay": 1.0}, r"--train-average-decay must be in \[0, 1\)"),
                             ({"train_joint_error": "l1"}, "--train-joint-error must be squared or distance"),
                             ({"train_batch": 0}, "--train-batch must be >= 1"),
                             ({"train_speeds": (1.0, 0.0)}, "--train-speeds must be positive"),
                             ({"train_names": ("GPT",)}, "--train-names must name forecasters of")):
        with pytest.raises(ValueError, match=message):
            dynamics_forecast.Config(out=tmp_path, data_root=data_root, **options)
    pairs = dynamics_forecast.Config(out=tmp_path, data_root=data_root, pairs=True, train=True)
    assert pairs.names == tuple(dynamics.PAIR_FORECASTERS) and pairs.models == dynamics.SHIPPED_FORECASTERS / "pairs"
    train = pairs.train_config(("a+b",), ())
    assert (train.people, train.validation_tail, train.start_from) == (2, 0.3, str(pairs.start_from.resolve()))
    assert train.stage.clip_norm is None and train.stage.average_decay is None  # fine-tuned unclipped, unaveraged
    assert train.losses == dynamics.ForecastTrainConfig(("a",), ("b",)).losses  # on the joints' distances
    with pytest.raises(ValueError, match="--train-names must name forecasters of"):
        dynamics_forecast.Config(out=tmp_path, data_root=data_root, pairs=True, train_names=("PHD+T",))
    for change in ({"train_extrapolation": 0.3}, {"train_width": 2}):
        with pytest.raises(ValueError, match="the pair forecasters are the JAT they start from"):
            dynamics_forecast.Config(out=tmp_path, data_root=data_root, pairs=True, **change)
    with pytest.raises(ValueError, match="--start-from .* is not a folder"):
        dynamics_forecast.Config(out=tmp_path, data_root=data_root, pairs=True, start_from=tmp_path / "none")

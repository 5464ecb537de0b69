"""FLEX training: the generator and discriminator step, resume, the saved model, the late-fusion variant and data
parallelism (two forced CPU devices)."""

import dataclasses
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx
from jaxtyping import TypeCheckError
from numpy.testing import assert_allclose, assert_array_equal

import flex
import geometry
import mocap
import training
from flex import _train
from _training_harness import Killed, assert_same_parameters, kill_at, run_on_two_devices

# One bone stage of two convolutions (the default has 2 x 3): every piece of the model, a fifth less to compile.
TINY = dataclasses.replace(flex.CONFIGS["cpu"], channels=8, heads=2, discriminator_channels=4, dropout=0.0,
                           bone_stages=1, bone_kernels=(3, 1))
DATA = flex.DataConfig(views=2, frames=16, clips=("02_01_walk", "60_03_61_03_salsa"))
VALIDATION = flex.DataConfig(views=2, frames=16, clips=flex.VALIDATION_CLIPS, camera_motion="dynamic")


def _config(cache_dir, **overrides) -> flex.TrainConfig:
    base = flex.TrainConfig(model=dataclasses.replace(TINY, views=2), data=DATA, validation_data=VALIDATION,
                            pool_size=8, validation_size=4, batch_size=4, steps=4, warmup_steps=1,
                            generator_lr=1e-2, discriminator_lr=1e-2, checkpoint_interval=2, validation_interval=2,
                            log_interval=1, cache_dir=str(cache_dir))
    return dataclasses.replace(base, **overrides)


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("flex_cache")


def _fixed_batch_steps(config: flex.TrainConfig, num_steps: int):
    """``num_steps`` steps on the first ``batch_size`` pool samples, sharded over all local devices."""
    model_config = config.model_config
    rngs = nnx.Rngs(config.seed)
    graphdef, params, rest = nnx.split(flex.Flex(model_config, rngs=rngs), nnx.Param, ...)
    discriminator_graphdef, discriminator = nnx.split(flex.Discriminator(model_config, rngs=rngs))
    state = flex.TrainState(params, rest, discriminator, _train._AMSGRAD.init(params),
                            _train._AMSGRAD.init(discriminator), jnp.asarray(0, jnp.int32), jax.random.key(0))
    replicated, sharded = training.data_parallel_shardings(config.batch_size)
    pool = flex.build_pool(config.data, config.batch_size, 0, config.cache_dir, progress=False)
    batch = jax.device_put(pool, sharded)
    state = jax.device_put(state, replicated)
    losses = []
    for i in range(num_steps):
        state, metrics = flex.train_step(graphdef, discriminator_graphdef, config.losses, replicated, state, batch,
                                         jax.random.key(i), *config.learning_rates(i))
        losses.append({k: float(v) for k, v in metrics.items()})
    return state, losses


def test_steps_fit_a_fixed_batch_and_train_the_discriminator(cache_dir):
    # Another schedule than the runs below, the same compiled step: the rates are arguments.
    config = _config(cache_dir, steps=30, warmup_steps=1)
    state, losses = _fixed_batch_steps(config, 30)
    assert all(np.isfinite(list(m.values())).all() for m in losses)
    assert losses[-1]["position"] < 0.5 * losses[0]["position"], [m["position"] for m in losses]
    assert losses[-1]["discriminator"] < losses[0]["discriminator"]
    assert int(state.step) == 30


def test_the_step_moves_at_the_rates_it_is_given(cache_dir):
    """Zero rates (the same compiled step as the runs here) keep both networks' starting parameters."""
    config = _config(cache_dir, generator_lr=0.0, discriminator_lr=0.0)
    state, _ = _fixed_batch_steps(config, 2)
    rngs = nnx.Rngs(config.seed)
    generator = nnx.state(flex.Flex(config.model_config, rngs=rngs), nnx.Param)
    discriminator = nnx.state(flex.Discriminator(config.model_config, rngs=rngs))
    for trained, fresh in ((state.params, generator), (state.discriminator, discriminator)):
        for a, b in zip(jax.tree.leaves(trained), jax.tree.leaves(fresh), strict=True):
            assert_array_equal(np.asarray(a), np.asarray(b))


def test_pool_is_cached_and_float32(cache_dir):
    first = flex.build_pool(DATA, 2, 100, cache_dir, progress=False)
    again = flex.build_pool(DATA, 2, 100, cache_dir, progress=False)
    assert first.cameras is None and first.points_2d.dtype == np.float32
    for a, b in zip(first[:-1], again[:-1]):
        assert_array_equal(a, b)
    assert len(list(Path(cache_dir).glob("flex_pool_*.npz"))) >= 1


def test_pool_rotations_are_relative_to_the_models_rest_pose(cache_dir, monkeypatch):
    """The discriminator's real rotations: a T-pose model's pool holds them relative to the T-pose (the elbows' differ
    from the totem's, the knees' do not), cached apart, and training builds its pools with the model's rest pose."""
    totem = flex.build_pool(DATA, 2, 100, cache_dir, progress=False)
    tpose = flex.build_pool(DATA, 2, 100, cache_dir, progress=False, rest_pose="tpose")
    assert_array_equal(tpose.points_2d, totem.points_2d)
    assert_allclose(tpose.rotations[0], flex.make_sample(100, DATA, "tpose").rotations, atol=1e-6)
    knees, elbows = ([geometry.FLEX20_ROTATING.index(geometry.FLEX20.index(f"{side}_{joint}")) for side in "lr"]
                     for joint in ("knee", "elbow"))
    assert_allclose(tpose.rotations[..., knees, :], totem.rotations[..., knees, :], atol=1e-6)
    assert not np.allclose(tpose.rotations[..., elbows, :], totem.rotations[..., elbows, :], atol=1e-3)
    asked = []
    monkeypatch.setattr(_train, "build_pool", lambda *args: asked.append(args[-1]) or totem)
    config = _config(cache_dir, model=dataclasses.replace(TINY, views=2, rest_pose="tpose"))
    _train._training_pool(config, cache_dir, False, 1)
    assert asked and set(asked) == {"tpose"}


def test_pool_built_in_chunks_for_workers_is_the_one_process_pool(monkeypatch):
    """The chunks the worker processes build, concatenated, are the one-process pool (the chunks are built here:
    training.process_map's processes are tested with JCSAT's scene building)."""
    jobs = []
    monkeypatch.setattr(training, "process_map", lambda fn, args, workers: jobs.extend(args) or [fn(*a) for a in args])
    one = flex.build_pool(DATA, 3, 100, progress=False)
    two = flex.build_pool(DATA, 3, 100, progress=False, workers=2)
    assert [(first, end, rest_pose) for _, first, end, rest_pose in jobs] == [
        (100, 101, "totem"), (101, 102, "totem"), (102, 103, "totem")]
    for a, b in zip(one[:-1], two[:-1]):
        assert_array_equal(a, b)


@pytest.fixture(scope="module")
def full_run(cache_dir, tmp_path_factory):
    workdir = tmp_path_factory.mktemp("flex_full")
    config = _config(cache_dir)
    return config, workdir, flex.train(config, workdir, resume=False, progress=False)


def test_resume_is_bit_identical_and_the_model_loads(full_run, tmp_path):
    config, full_dir, full_model = full_run
    with pytest.raises(Killed):
        flex.train(config, tmp_path, resume=False, log=kill_at(3), progress=False)
    resumed = flex.train(config, tmp_path, resume=True, progress=False)
    assert_same_parameters(full_model, resumed)
    records = [json.loads(line) for line in (full_dir / "log.jsonl").read_text().splitlines()]
    assert [r["step"] for r in records] == [1, 2, 3, 4]
    assert {"loss", "position", "skeleton", "adversarial", "root", "contact", "contact_velocity", "discriminator",
            "lr"} <= set(records[0])
    assert records[1]["val_mpjpe_mm"] > 0
    assert records[0]["lr"] == 0.0 and records[1]["lr"] == pytest.approx(config.generator_lr)  # one warm-up step
    loaded = flex.load_flex(full_dir / "model")
    assert_same_parameters(full_model, loaded)
    pool = flex.build_pool(VALIDATION, 2, 7, config.cache_dir, progress=False)
    joints = nnx.jit(lambda model: model(pool.points_2d, pool.confidences).joints)  # one compile, not one per op
    assert_allclose(np.asarray(joints(loaded)), np.asarray(joints(full_model)), rtol=1e-6)


def test_validation_mpjpe_is_the_figure_training_logs(full_run, tmp_path):
    """A shipped model is compared with a new run by validation_mpjpe: it must be the last val_mpjpe_mm of the log,
    on the same windows, for a model read back from its folder and without the run's cache."""
    config, full_dir, _ = full_run
    logged = [json.loads(line) for line in (full_dir / "log.jsonl").read_text().splitlines()][-1]["val_mpjpe_mm"]
    loaded = flex.load_flex(full_dir / "model")
    assert flex.validation_mpjpe(loaded, config) == pytest.approx(logged, rel=1e-5)
    assert flex.validation_mpjpe(loaded, config, tmp_path) == pytest.approx(logged, rel=1e-5)
    other_views = dataclasses.replace(config, model=dataclasses.replace(TINY, views=3),
                                      data=dataclasses.replace(DATA, views=3),
                                      validation_data=dataclasses.replace(VALIDATION, views=3))
    with pytest.raises(ValueError, match="the model has 2 views, the validation windows 3"):
        flex.validation_mpjpe(loaded, other_views)


def test_the_experiment_resumes_a_killed_run_and_reuses_only_the_same_finished_one(full_run, tmp_path, monkeypatch):
    """train_models, which `flex_synthetic --train` runs once per command: run again after a kill, it resumes to the
    uninterrupted model; run again once finished, it reuses the model; asked for another run, it refuses."""
    from experiments.flex_study import _synthetic
    config, _, full_model = full_run
    monkeypatch.setattr(_synthetic, "train_config", lambda name, steps, *args, **kwargs: dataclasses.replace(
        config, steps=steps))
    run = lambda steps, **options: _synthetic.train_models(  # noqa: E731
        tmp_path, steps, names=("flex_1view",), progress=False, **options)["flex_1view"]
    with pytest.raises(Killed):
        run(config.steps, log=kill_at(3))
    assert_same_parameters(full_model, run(config.steps))
    assert_same_parameters(full_model, run(config.steps, log=kill_at(1)))  # reused: no step is run, none logged
    with pytest.raises(ValueError, match=r"config\.json records a run of another config \(it differs in steps\)"):
        run(config.steps + 1)


def test_config_errors(cache_dir):
    with pytest.raises(ValueError, match="share clips"):
        _config(cache_dir, validation_data=DATA)
    with pytest.raises(ValueError, match="the model has 2 views"):
        _config(cache_dir, data=dataclasses.replace(DATA, views=3))
    with pytest.raises(ValueError, match="shorter than the model"):
        _config(cache_dir, data=dataclasses.replace(DATA, frames=8))
    with pytest.raises(ValueError, match=r"held-out test motion \['02_05_punch'\]"):
        _config(cache_dir, data=dataclasses.replace(DATA, clips=("02_01_walk", "02_05_punch")))


def test_training_refuses_the_cmu_expmap_test_split(cache_dir, data_root):
    test_file = str(mocap.cmu_expmap_files(data_root, "test")[0])
    with pytest.raises(ValueError, match="held-out test motion"):
        _config(cache_dir, data=dataclasses.replace(DATA, clips=("02_01_walk", test_file)))


def test_late_fusion_runs_each_view_alone_before_fusing():
    config = dataclasses.replace(TINY, views=3, fusion="late")
    model = flex.Flex(config, rngs=nnx.Rngs(0))
    points = jax.random.normal(jax.random.key(0), (2, 3, 16, 17, 2)) * 50 + 500
    confidences = jnp.ones((2, 3, 16, 17))
    out = model(points, confidences)
    assert out.joints.shape == (2, 3, 16, 20, 3) and np.isfinite(np.asarray(out.joints)).all()
    assert model.rotation_branch.multi_view[0].layer.kernel.shape[1] == 1  # no mixing of views before the fusion
    with pytest.raises((ValueError, TypeCheckError), match="fusion"):
        dataclasses.replace(TINY, fusion="middle")


def _outputs_after_steps(config: flex.TrainConfig, num_steps: int) -> tuple[list[float], np.ndarray]:
    """The step losses and the trained model's output joints on the training batch, normalised with the batch's
    statistics (``TINY`` has no dropout): the running averages lag behind the noisy biases described below."""
    state, losses = _fixed_batch_steps(config, num_steps)
    graphdef = nnx.graphdef(flex.Flex(config.model_config, rngs=nnx.Rngs(0)))
    pool = flex.build_pool(config.data, config.batch_size, 0, config.cache_dir, progress=False)

    @jax.jit  # one compilation instead of one per operation run eagerly
    def joints(params, rest, points_2d, confidences):
        return nnx.merge(graphdef, params, rest)(points_2d, confidences, key=jax.random.key(0)).joints

    return [m["loss"] for m in losses], np.asarray(joints(state.params, state.rest, pool.points_2d, pool.confidences))


def test_two_devices_match_one(cache_dir, tmp_path):
    """Each batch split over 2 (forced CPU) devices gives the 1-device losses and model. Compared through the
    model's output, not its parameters: the biases in front of batch norm get pure rounding noise as gradients,
    which Adam's first steps scale up to full-size updates, but batch norm removes them again."""
    config = _config(cache_dir)
    out = run_on_two_devices("""
        from test_flex_train import _outputs_after_steps
        losses, joints = _outputs_after_steps(config, 3)
        np.savez(OUT, losses=losses, joints=joints)
    """, config, tmp_path)
    losses, joints = _outputs_after_steps(config, 3)
    with np.load(out) as stored:
        assert_allclose(stored["losses"], losses, rtol=1e-5)
        assert_allclose(stored["joints"], joints, rtol=1e-4, atol=1e-5)

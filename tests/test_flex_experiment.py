"""FLEX's experiment (experiments/flex_study, experiments/flex_synthetic.py) on tiny untrained models."""

import dataclasses
from pathlib import Path

import jax
import numpy as np
import pytest
from flax import nnx
from numpy.testing import assert_allclose

import mocap
from experiments import _cli, flex_synthetic
from experiments.flex_study import ExperimentConfig, train_config
from experiments.flex_study._synthetic import mean_and_spread
from flex import (CONFIGS, MODELS, RIG_MODELS, SKELETON_MODELS, VALIDATION_CLIPS, DataConfig, Flex, averaged_monocular,
                  load_models, make_batch, predict)

FRAMES = 24


def tiny(views: int, fusion: str = "early", seed: int = 0) -> Flex:
    model = Flex(dataclasses.replace(CONFIGS["cpu"], views=views, fusion=fusion), rngs=nnx.Rngs(seed))
    for layer in (model.rotation_branch.shrink, model.rotation_branch.view_head):  # zero-initialised
        layer.kernel[...] = 0.1 * jax.random.normal(jax.random.key(seed), layer.kernel.shape, layer.kernel.dtype)
    return model


@pytest.fixture(scope="module")
def batch():
    return make_batch(jax.random.key(0), DataConfig(views=4, frames=FRAMES, camera_motion="dynamic"), 2)


def test_averaged_monocular_of_identical_views_is_the_monocular_prediction(batch):
    model = tiny(1)
    # As many views as the batch: the fusion compiles the one-view model once (flex.predict), every call reuses it.
    same = batch._replace(points_2d=np.repeat(batch.points_2d[:, :1], 4, axis=1),
                          confidences=np.repeat(batch.confidences[:, :1], 4, axis=1))
    fused = averaged_monocular(model, same)
    alone = predict(model, batch.points_2d[:, :1], batch.confidences[:, :1]).joints_relative
    assert fused.shape == (2, 4, FRAMES, 20, 3)
    for view in range(4):
        assert_allclose(fused[:, view], alone[:, 0], atol=1e-6)
    differs = averaged_monocular(model, batch)
    assert np.abs(np.asarray(differs[:, 1]) - np.asarray(alone[:, 0])).max() > 1e-3
    with pytest.raises(ValueError, match="1-view model"):
        averaged_monocular(tiny(2), batch)


def test_help_explains_every_option(capsys):
    with pytest.raises(SystemExit):
        _cli.parse(flex_synthetic.Config, ["--help"], prog="flex_synthetic")
    text = capsys.readouterr().out
    for option in ("--out", "--quick", "--train", "--train-steps", "--model-dir", "--seed", "--sequences", "--frames",
                   "--train-names", "--train-expmap", "--validate-expmap", "--test-expmap", "--rigs",
                   "--perturbation-draws", "--noise-correlation", "--train-batch", "--train-pool", "--data-workers",
                   "--train-model-config"):
        assert option in text
    assert ExperimentConfig().sequences == 16


@pytest.mark.parametrize(("option", "value", "message"), [
    ("sequences", 0, "sequences must be >= 1"),
    ("frames", 2, "frames must be >= 3"),
    ("clips", (), "clips must name at least one clip"),
    ("perturbations", (0.03, -0.01), "perturbations must be relative scales > 0"),
    ("n_steps", -1, "n_steps must be >= 0"),
    ("plot_views", (0, 0), "plot_views must be distinct views of 0..3"),
    ("plot_views", (4,), "plot_views must be distinct views of 0..3"),
    ("plot_frames", 0, "plot_frames must be in 1..frames=64"),
    ("rigs", ("h36m_ring", "h36m_ring"), "rigs must be distinct names"),
    ("rigs", ("nowhere",), "rigs must be distinct names"),
    ("perturbation_draws", 1, "perturbation_draws must be >= 2"),
    ("noise_correlation", 1.0, "noise_correlation must be in"),
])
def test_a_bad_option_is_refused_by_name(option, value, message):
    with pytest.raises(ValueError, match=message):
        ExperimentConfig(**{option: value})


@pytest.mark.parametrize(("options", "message"), [
    ({"train_names": ("flex_9views",)}, "--train-names must name models of"),
    ({"train_expmap": True}, "--train-expmap needs --train"),
    ({"train": True, "validate_expmap": True}, "--validate-expmap needs --train-expmap"),
    ({"train_batch": 0}, "--train-batch must be >= 1"),
    ({"train_pool": 0}, "--train-pool must be >= 1"),
    ({"data_workers": 0}, "--data-workers must be >= 1"),
    ({"test_expmap": True, "experiment": ExperimentConfig(clips=("02_01_walk",))},
     "--test-expmap and --clips exclude each other"),
])
def test_a_bad_command_line_is_refused_before_any_work(tmp_path, options, message):
    with pytest.raises(ValueError, match=message):
        flex_synthetic.Config(out=tmp_path, **options)


def test_a_model_folder_without_the_main_model_is_named(tmp_path):
    with pytest.raises(FileNotFoundError, match=f"{tmp_path} has no saved main model flex_4views"):
        load_models(tmp_path)


def test_every_experiment_model_is_shipped():
    models = load_models()
    assert set(models) == set(MODELS) | {"flex_4views_h36m_ring"} and set(RIG_MODELS) >= {"flex_4views_h36m_ring"}
    for name, (views, fusion) in MODELS.items():
        assert (models[name].config.views, models[name].config.fusion) == (views, fusion)


def test_the_duplicate_joint_ablation_trains_its_rig_model_with_the_tpose(tmp_path):
    """The ablation's pair differs from each other only by the duplicate joints and from the rig model only by the
    skeleton: the same samples (data config) and schedule."""
    rig_run = train_config("flex_4views_h36m_ring", 1000, 0, tmp_path)
    for name, (rig, duplicate_joints) in SKELETON_MODELS.items():
        run = train_config(name, 1000, 0, tmp_path)
        assert run.data == rig_run.data and run.data.rig == rig
        assert run.model == dataclasses.replace(rig_run.model, rest_pose="tpose", duplicate_joints=duplicate_joints)
        assert dataclasses.replace(run, model=rig_run.model) == rig_run


def test_the_model_config_sizes_every_trained_model_and_nothing_else(tmp_path):
    for name in ("flex_4views", "flex_4views_h36m_ring", "flex_4views_h36m_ring_no_duplicates"):
        small, paper = (train_config(name, 1000, 0, tmp_path, model_config=size) for size in ("small", "paper"))
        per_model = {field: getattr(small.model, field)
                     for field in ("views", "fusion", "rest_pose", "duplicate_joints")}
        assert small.model == dataclasses.replace(CONFIGS["small"], **per_model)
        assert paper.model == dataclasses.replace(CONFIGS["paper"], **per_model)
        assert dataclasses.replace(paper, model=small.model) == small
    with pytest.raises(ValueError, match=r"model_config must be one of \['cpu', 'paper', 'small'\], got 'huge'"):
        train_config("flex_4views", 1000, 0, tmp_path, model_config="huge")


def test_validate_expmap_moves_the_benchmark_validation_files_from_training_to_validation(tmp_path, data_root):
    command = flex_synthetic.Config(out=tmp_path, train=True, train_expmap=True, data_root=data_root)
    validated = dataclasses.replace(command, validate_expmap=True)
    files = {str(f.resolve()) for f in mocap.cmu_expmap_validation_files(data_root)}
    assert set(validated.validation_clips()) == files and len(files) == 8
    assert set(validated.train_clips()) == set(command.train_clips()) - files and command.validation_clips() == ()
    for name in ("flex_4views", "flex_4views_h36m_ring"):
        shipped = train_config(name, 1500, 0, tmp_path, command.train_clips())
        run = train_config(name, 1500, 0, tmp_path, validated.train_clips(),
                           validation_clips=validated.validation_clips())
        assert shipped.validation_data.clip_names == VALIDATION_CLIPS
        assert run.validation_data.clip_names == VALIDATION_CLIPS + validated.validation_clips()
        assert not set(run.data.clip_names) & set(run.validation_data.clip_names)
        assert dataclasses.replace(run, data=shipped.data, validation_data=shipped.validation_data) == shipped


def test_every_step_count_the_command_takes_makes_a_run():
    """--quick trains 100 steps and --train-steps takes any count >= 1: the warm-up shrinks with a short run, and runs
    of 1000 steps or more (every shipped model's) keep the default."""
    for name in ("flex_4views", "flex_4views_h36m_ring"):
        assert [train_config(name, steps, 0, Path("cache")).warmup_steps
                for steps in (1, 4, flex_synthetic.QUICK_TRAIN_STEPS, 1000, 3000)] == [0, 0, 10, 100, 100]


def test_mean_and_spread_of_calibration_draws():
    """Each metric's mean and sample standard deviation over the draws, and the draws' MPJPE."""
    draws = [{"mpjpe_mm": 2.0, "mbls_mm": 1.0}, {"mpjpe_mm": 4.0, "mbls_mm": 1.0}, {"mpjpe_mm": 9.0, "mbls_mm": 4.0}]
    summary = mean_and_spread(draws)
    assert summary.pop("draws_mpjpe_mm") == [2.0, 4.0, 9.0]
    assert summary == pytest.approx({"mpjpe_mm": 5.0, "mpjpe_mm_sd": np.std([2, 4, 9], ddof=1), "mbls_mm": 2.0,
                                     "mbls_mm_sd": np.sqrt(3.0)})

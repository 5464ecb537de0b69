"""PHD+T training (dynamics/_train.py): three resumable stages on a tiny rendered clip, resume after a kill in a
later stage, the saved model, and data parallelism (two forced CPU devices).

The cost is compiling: every run of :func:`dynamics.train` traces and compiles its three train steps afresh (they
close over the run's config), about a minute for the first run on a 2-core CPU. The module keeps a persistent
compilation cache, so later runs in this process load most programs instead, and the 2-device subprocess runs in
the background while the 1-device run compiles."""

import concurrent.futures
import dataclasses
import json
import shutil
from pathlib import Path

import jax
import numpy as np
import pytest
from flax import nnx
from numpy.testing import assert_allclose

import dynamics
import geometry
import mocap
import training
from _training_harness import Killed, assert_same_parameters, run_on_two_devices

BODY = geometry.stand_in_body_model()
STAGES = ("image", "movie", "ar")

# One 44-frame clip rendered once, small: two variants (the second mirrored) of one track for training, fresh
# renders of the same clip for validation (another seed, as TrainConfig requires).
VIDEO = mocap.VideoConfig(image_size=(96, 72), focal=90.0)
DATA = dynamics.DataConfig(clips=("02_03_run",), renders=1, augmented_epochs=2, crop_size=16, video=VIDEO)
VALIDATION = dataclasses.replace(DATA, augmented_epochs=1, jitter=False, flip=False, seed=1_000)


def _stage() -> dynamics.StageConfig:
    return dynamics.StageConfig(steps=4, batch_size=2, learning_rate=1e-3, warmup_steps=1)


def _config(cache_dir, **overrides) -> dynamics.TrainConfig:
    base = dynamics.TrainConfig(
        data=DATA, validation=VALIDATION,
        backbone=dynamics.BackboneConfig(widths=(4, 8), feature_dim=16, crop_size=DATA.crop_size),
        model=dynamics.PHDTConfig(feature_dim=16, joint_dim=16, channels_per_group=16, hmr_hidden=16),
        image=_stage(), movie=_stage(), ar=_stage(), observed=13, horizon=3, checkpoint_interval=2,
        validation_interval=2, log_interval=1, cache_dir=str(cache_dir))
    return dataclasses.replace(base, **overrides)


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory) -> Path:
    """The rendered frames of DATA and VALIDATION (and features), shared by every run of this module."""
    path = tmp_path_factory.mktemp("dynamics_cache")
    for data in (DATA, VALIDATION):
        dynamics.build_frames(data, BODY, path, progress=False)
    return path


def test_renders_do_not_depend_on_the_order_they_are_made_in(monkeypatch):
    """Each render draws from its own generator, so worker processes (which finish in any order) give the frames
    of one process: here the jobs run last to first."""
    data = dataclasses.replace(DATA, renders=2)
    in_order = dynamics.build_frames(data, BODY, progress=False)

    def backwards(fn, jobs, workers, progress=None):
        return [fn(*job) for job in jobs[::-1]][::-1]

    monkeypatch.setattr(training, "process_map", backwards)
    for column, expected in zip(dynamics.build_frames(data, BODY, progress=False), in_order):
        np.testing.assert_array_equal(column, expected)


def test_redrawn_flips_change_only_the_mirrored_variants_crops():
    """DataConfig.redraw_flips renders the mirrored variant anew (mocap.flip_video's redraw, tested in
    test_video.py): the same rows and ground truth, the same crops of the unmirrored variant, other crops of the
    mirrored one."""
    pixels, redrawn = (dynamics.build_frames(dataclasses.replace(DATA, redraw_flips=redraw), BODY, progress=False)
                       for redraw in (False, True))
    for field, a, b in zip(dynamics.Frames._fields, redrawn, pixels):
        if field != "crops":
            np.testing.assert_array_equal(a, b, err_msg=field)
    mirrored = pixels.video == 1
    assert mirrored.any() and (~mirrored).any()
    np.testing.assert_array_equal(redrawn.crops[~mirrored], pixels.crops[~mirrored])
    assert np.mean(redrawn.crops[mirrored] != pixels.crops[mirrored]) > 0.01

def _records(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def _untimed(records: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if k != "seconds_per_step"} for r in records]


def _kill_at_record(count: int):
    """A ``log`` callback that kills the run at its ``count``-th record over all stages."""
    seen = []

    def log(record: dict) -> None:
        seen.append(record)
        if len(seen) == count:
            raise Killed

    return log


@pytest.fixture(scope="module")
def full_run(cache_dir, tmp_path_factory):
    """An uninterrupted run (1 device): every stage 4 steps, checkpoints every 2."""
    workdir = tmp_path_factory.mktemp("dynamics_full")
    config = _config(cache_dir)
    logged = []
    backbone, phdt = dynamics.train(config, workdir, BODY, resume=False, log=logged.append, progress=False)
    return config, workdir, backbone, phdt, logged


_IMAGE_STAGE_ON_TWO_DEVICES = """
    from pathlib import Path
    import dynamics
    from _training_harness import Killed
    from test_dynamics_train import BODY, _kill_at_record
    try:  # the image stage only: its 4 records, then killed
        dynamics.train(config, Path(OUT).parent / "run", BODY, resume=False, log=_kill_at_record(4), progress=False)
    except Killed:
        np.savez(OUT)
"""


@pytest.fixture(scope="module")
def two_devices(cache_dir, tmp_path_factory):
    """The 1-device run's image stage on 2 forced CPU devices, in a subprocess started in the background: it
    overlaps the 1-device runs (each compiles on one core, mostly). Its own copy of the rendered frames keeps its
    files apart."""
    folder = tmp_path_factory.mktemp("dynamics_two_devices")
    (folder / "cache").mkdir()
    for path in cache_dir.glob("dynamics_frames_*.npz"):
        shutil.copy(path, folder / "cache" / path.name)
    with concurrent.futures.ThreadPoolExecutor(1) as executor:
        yield folder, executor.submit(run_on_two_devices, _IMAGE_STAGE_ON_TWO_DEVICES, _config(folder / "cache"),
                                      folder)


def test_two_devices_match_one(two_devices, full_run):
    """The image stage with every batch split over 2 (forced CPU) devices logs the 1-device run's metrics: the
    losses and gradient norms of every step (the model's outputs on the training batch after 0-3 updates) and
    the validation MPJPE after 2 and 4. Compared through outputs, not parameters: the biases in front of GroupNorm
    may get rounding noise as gradients in the directions GroupNorm removes, which Adam scales up to full-size
    updates. (Stage 1 only, to keep the cost down: the later stages shard their batches the same way.)

    First in the module: its fixture starts the 2-device run before ``full_run`` starts the 1-device one."""
    folder, future = two_devices
    _, full_dir, _, _, _ = full_run
    future.result()
    assert not (folder / "run" / "movie").exists()
    one, two = (_untimed(_records(workdir / "image" / "log.jsonl")) for workdir in (full_dir, folder / "run"))
    assert [list(r) for r in one] == [list(r) for r in two] and len(one) == 4
    assert "val_mpjpe_mm" in one[3]
    for a, b in zip(one, two):
        assert_allclose([b[k] for k in a], [a[k] for k in a], rtol=1e-5, err_msg=f"step {a['step']}")


def test_a_run_writes_every_stage(full_run):
    config, workdir, _, _, logged = full_run
    per_stage = {stage: _records(workdir / stage / "log.jsonl") for stage in STAGES}
    assert logged == [r for stage in STAGES for r in per_stage[stage]]
    for stage, records in per_stage.items():
        assert [r["step"] for r in records] == [1, 2, 3, 4], stage
        assert all(np.isfinite(list(r.values())).all() for r in records), stage
        assert records[0]["lr"] == 0.0 and records[1]["lr"] == pytest.approx(1e-3), stage
        assert sorted(int(p.name) for p in (workdir / stage / "checkpoints").iterdir() if p.name.isdigit()) == [2, 4]
        recorded = json.loads((workdir / stage / "config.json").read_text())
        assert recorded["seed"] == config.seed
        # A stage records the stages up to it, not those after (a change there keeps it and the stages before).
        assert tuple(name for name in STAGES if name in recorded) == STAGES[:STAGES.index(stage) + 1], stage
    image, movie, ar = (per_stage[stage] for stage in STAGES)
    frame_terms = {"loss", "smpl", "joints_3d", "keypoints_2d", "shape_prior", "adversarial", "discriminator",
                   "grad_norm"}
    assert frame_terms <= set(image[0]) and "val_mpjpe_mm" not in image[2]
    assert {"val_mpjpe_mm", "val_root_mm", "val_depth_ratio"} <= set(image[1])
    assert frame_terms | {"delta-5", "delta-10", "shape_consistency"} <= set(movie[0]) and movie[3]["val_mpjpe_mm"] > 0
    assert frame_terms | {"temporal", "translation", "shape_consistency"} <= set(ar[0])
    assert ar[3]["val_future_mpjpe_mm"] > 0 and ar[3]["val_future_root_mm"] > 0
    # One feature file per DataConfig, for this run's backbone.
    assert len(list(Path(config.cache_dir).glob("dynamics_features_*.npy"))) == 2


def test_the_conditioning_stage_alone_is_train_s_first_and_its_metrics_match_a_per_frame_reference(
        full_run, cache_dir):
    config, full_dir, full_backbone, _, _ = full_run
    # On train's folder it restores train's finished first stage (the same stage and folder), training nothing.
    image_log = (full_dir / "image" / "log.jsonl").read_bytes()
    logged = []
    model = dynamics.train_conditioning(config, full_dir, BODY, resume=True, log=logged.append, progress=False)
    assert not logged and (full_dir / "image" / "log.jsonl").read_bytes() == image_log
    assert_same_parameters(model.backbone, full_backbone)

    rows = dynamics.build_frames(config.validation, BODY, cache_dir, progress=False)
    metrics = dynamics.conditioning_metrics(BODY, model, rows, batch_size=5)  # batches of 5 and a remainder
    params = model.hmr(model.backbone(jax.numpy.asarray(rows.crops, np.float32) / 255.0))
    joints = np.asarray(dynamics.params_to_joints(BODY, params, jax.numpy.zeros_like(params.camera)))
    relative = lambda j: j - j[:, :1]  # noqa: E731
    mpjpe = np.linalg.norm(relative(joints) - relative(rows.joints3d), axis=-1).mean()
    roots = np.array([geometry.crop_camera_to_translation(camera, box, K)
                      for camera, box, K in zip(np.asarray(params.camera), rows.boxes, rows.K)])
    assert metrics["mpjpe_mm"] == pytest.approx(1000 * mpjpe, rel=1e-4)
    assert metrics["root_mm"] == pytest.approx(1000 * np.linalg.norm(roots - rows.root, axis=-1).mean(), rel=1e-4)
    assert metrics["depth_ratio"] == pytest.approx(np.mean(roots[:, 2] / rows.root[:, 2]), rel=1e-4)
    pa = [geometry.pa_mpjpe(one, truth) for one, truth in zip(joints, rows.joints3d)]  # geometry's: checked by SciPy
    assert metrics["pa_mpjpe_mm"] == pytest.approx(1000 * np.mean(pa), rel=1e-4)
    assert metrics["pa_mpjpe_mm"] < metrics["mpjpe_mm"]
    from scipy.spatial.transform import Rotation
    regressed = np.asarray(geometry.rotation_6d_to_matrix(params.rot6d[:, 0]), np.float64)
    angles = Rotation.from_matrix(np.swapaxes(regressed, -1, -2) @ rows.rotations[:, 0]).magnitude()
    assert metrics["orientation_deg"] == pytest.approx(np.degrees(angles).mean(), rel=1e-4)
    # The regressed local pose and shape under the true root rotation, posed frame by frame from the matrices.
    local = np.asarray(geometry.rotation_6d_to_matrix(params.rot6d)).copy()
    local[:, 0] = rows.rotations[:, 0]
    posed = np.array([geometry.body_joints(BODY, r, b, np.zeros(3, np.float32)) for r, b in zip(local, params.betas)])
    true_rotation_mpjpe = np.linalg.norm(relative(posed) - relative(rows.joints3d), axis=-1).mean()
    assert metrics["true_rotation_mpjpe_mm"] == pytest.approx(1000 * true_rotation_mpjpe, rel=1e-4)


def test_the_mean_local_pose_is_scipy_s_chordal_mean_of_each_joint_s_rotations():
    from scipy.spatial.transform import Rotation
    rng = np.random.default_rng(0)
    spread = Rotation.from_rotvec(rng.normal(0.0, 0.6, (50 * 24, 3))).as_matrix().reshape(50, 24, 3, 3)
    rotations = Rotation.from_rotvec(rng.normal(0.0, 1.0, (24, 3))).as_matrix() @ spread
    pose = dynamics.mean_local_pose(rotations.astype(np.float32))
    expected = np.stack([Rotation.from_matrix(rotations[:, j]).mean().as_matrix() for j in range(24)])
    assert_allclose(pose, expected, atol=2e-5)
    assert_allclose(np.linalg.det(pose), 1.0, atol=1e-5)
    half_turns = np.stack([np.diag([1.0, -1.0, -1.0]), np.diag([-1.0, 1.0, -1.0]), np.diag([-1.0, -1.0, 1.0])])
    assert_allclose(np.linalg.det(dynamics.mean_local_pose(np.repeat(half_turns[:, None], 24, axis=1))), 1.0, atol=1e-6)  # mean: -I / 3
    with pytest.raises(ValueError, match=r"rotations of shape \(frames >= 1, 24, 3, 3\), got \(0, 24, 3, 3\)"):
        dynamics.mean_local_pose(np.zeros((0, 24, 3, 3)))  # no frames: NaN before


def test_the_mean_pose_reference_is_zero_on_its_own_pose_and_matches_a_per_frame_reference(cache_dir):
    rows = dynamics.build_frames(VALIDATION, BODY, cache_dir, progress=False)
    pose = dynamics.mean_local_pose(rows.rotations)
    metrics = dynamics.mean_pose_metrics(BODY, pose, rows, batch_size=7)  # batches of 7 and a remainder
    assert all(isinstance(value, np.float64) for value in metrics.values())  # summed in float64; JSON takes them
    posed = np.broadcast_to(pose, rows.rotations.shape).copy()
    posed[:, 0] = rows.rotations[:, 0]  # the true root rotation
    joints = np.stack([geometry.body_forward(BODY, r, b, np.zeros(3)).joints for r, b in zip(posed, rows.betas)])
    relative = lambda j: j - j[:, :1]  # noqa: E731
    assert metrics["mpjpe_mm"] == pytest.approx(
        1000 * np.linalg.norm(relative(joints) - relative(rows.joints3d), axis=-1).mean(), rel=1e-4)
    assert metrics["pa_mpjpe_mm"] == pytest.approx(
        1000 * np.mean([geometry.pa_mpjpe(j, t) for j, t in zip(joints, rows.joints3d)]), rel=1e-4)
    still = rows._replace(rotations=posed, joints3d=joints.astype(np.float32))
    assert dynamics.mean_pose_metrics(BODY, pose, still)["mpjpe_mm"] < 1e-3
    with pytest.raises(ValueError, match="no frames to score"):
        dynamics.mean_pose_metrics(BODY, pose, jax.tree.map(lambda column: column[:0], rows))


def test_resume_after_a_kill_in_a_later_stage_is_bit_identical(full_run, tmp_path):
    config, full_dir, full_backbone, full_phdt, _ = full_run
    with pytest.raises(Killed):  # 4 records per stage: the 11th is step 3 of ar, one step after its checkpoint
        dynamics.train(config, tmp_path, BODY, resume=False, log=_kill_at_record(11), progress=False)
    assert [r["step"] for r in _records(tmp_path / "ar" / "log.jsonl")] == [1, 2, 3]
    assert sorted(p.name for p in (tmp_path / "ar" / "checkpoints").iterdir() if p.name.isdigit()) == ["2"]
    assert not (tmp_path / "model").exists()
    with pytest.raises(ValueError, match="already has checkpoints"):
        dynamics.train(config, tmp_path, BODY, resume=False, progress=False)
    finished = {stage: (tmp_path / stage / "log.jsonl").read_bytes() for stage in ("image", "movie")}

    logged = []
    backbone, phdt = dynamics.train(config, tmp_path, BODY, resume=True, log=logged.append, progress=False)
    # The finished stages are restored, not retrained: only ar's lost steps run again, and the finished stages'
    # logs keep even their timings.
    assert [r["step"] for r in logged] == [3, 4] and "translation" in logged[0]
    for stage, text in finished.items():
        assert (tmp_path / stage / "log.jsonl").read_bytes() == text, stage
    for stage in STAGES:
        assert _untimed(_records(tmp_path / stage / "log.jsonl")) == _untimed(_records(full_dir / stage / "log.jsonl"))
    assert_same_parameters(backbone, full_backbone)
    assert_same_parameters(phdt, full_phdt)
    for workdir in (full_dir, tmp_path):
        loaded_backbone, loaded_phdt = dynamics.load_trained(workdir / "model")
        assert_same_parameters(loaded_backbone, full_backbone)
        assert_same_parameters(loaded_phdt, full_phdt)
        assert loaded_phdt.config == config.model and loaded_backbone.crop_size == 16
    # Saved before the backbone's config held its crop size: the shipped backbone takes the default 64 px.
    assert dynamics.load_trained(dynamics.SHIPPED_MODEL)[0].crop_size == 64


def test_a_backbone_saved_before_the_pooling_option_loads_as_the_mean(tmp_path):
    """The recipe flattens the last map; a backbone whose config.json predates ``BackboneConfig.pooling`` was
    built with ResNet's mean (the field's default) and loads so, with its own weights."""
    assert dynamics.TrainConfig().backbone.pooling == "flatten" and dynamics.BackboneConfig().pooling == "mean"
    config = dynamics.BackboneConfig(widths=(4, 8), feature_dim=16, crop_size=16)
    saved = dynamics.ResNetBackbone(config.widths, feature_dim=16, crop_size=16, rngs=nnx.Rngs(1))
    shutil.copytree(dynamics.SHIPPED_MODEL / "phdt", tmp_path / "phdt")  # load_trained reads both networks
    training.save_model(tmp_path / "backbone", config, nnx.state(saved))
    stored = json.loads((tmp_path / "backbone" / "config.json").read_text())
    assert stored.pop("pooling") == "mean"
    (tmp_path / "backbone" / "config.json").write_text(json.dumps(stored))
    loaded, _ = dynamics.load_trained(tmp_path)
    assert loaded.pooling == "mean"
    assert_same_parameters(loaded, saved)


def test_batch_size_must_divide_by_devices(cache_dir, monkeypatch, tmp_path):
    monkeypatch.setattr(jax, "local_devices", lambda: [object(), object()])
    config = _config(cache_dir, image=dataclasses.replace(_stage(), batch_size=3))
    with pytest.raises(ValueError, match="multiple of the 2 local devices"):
        dynamics.train(config, tmp_path, BODY, resume=False, progress=False)


def test_config_errors(cache_dir):
    with pytest.raises(ValueError, match="must use another seed"):
        _config(cache_dir, validation=dataclasses.replace(VALIDATION, seed=DATA.seed))
    with pytest.raises(ValueError, match="the backbone gives 32 features"):
        _config(cache_dir, backbone=dynamics.BackboneConfig(widths=(4, 8), feature_dim=32, crop_size=16))
    with pytest.raises(ValueError, match="data.crop_size is 16, the backbone takes 64 px crops"):
        _config(cache_dir, backbone=dynamics.BackboneConfig(widths=(4, 8), feature_dim=16))
    with pytest.raises(ValueError, match="observe at least one receptive field"):
        _config(cache_dir, observed=12)
    with pytest.raises(ValueError, match="batch_size must be >= 1"):
        dynamics.StageConfig(steps=4, batch_size=0, learning_rate=1e-3)
    with pytest.raises(ValueError, match="warmup_steps must be in"):
        dynamics.StageConfig(steps=4, batch_size=2, learning_rate=1e-3, warmup_steps=4)
    with pytest.raises(ValueError, match="clip_norm must be positive"):
        dynamics.StageConfig(steps=4, batch_size=2, learning_rate=1e-3, warmup_steps=1, clip_norm=0.0)
    for decay in (0.0, 1.0):
        with pytest.raises(ValueError, match=r"average_decay must be in \(0, 1\)"):
            dynamics.StageConfig(steps=4, batch_size=2, learning_rate=1e-3, warmup_steps=1, average_decay=decay)

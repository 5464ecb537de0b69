"""JCSAT training: windows from a synthetic scene, the losses of Eq. 11-15, the train loop, resume and data parallelism."""

import dataclasses
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx
from jaxtyping import TypeCheckError
from numpy.testing import assert_allclose, assert_array_equal

import geometry
import mocap
from geometry import SHELF15
from jcsat import (
    CONFIGS, JCSAT, TRAIN_CONFIGS, VALIDATION_CLIPS, Batch, DataConfig, JCSATConfig, TrainConfig, bone_losses,
    build_dataset, init_state, jcsat_loss, learning_rate_schedule, load_model, make_optimiser, pcp_hinge_loss,
    project_normalised, projection_loss, reconstruction_loss, sample_batch, train, train_step, validate, window_batch,
)
import training
from _training_harness import Killed, assert_same_parameters, kill_at, run_on_two_devices


# One tiny scene for training, one for validation (held-out clips, other seed); same shapes, so
# the pipeline compiles once.
TRAIN_DATA = DataConfig(num_scenes=1, num_frames=24, num_people=3, first_seed=0)
VALIDATION_DATA = DataConfig(clips=VALIDATION_CLIPS, num_scenes=1, num_frames=24, num_people=3, first_seed=500)


# A few thousand parameters: every piece of the real network, compiled in seconds.
TINY = JCSATConfig(dim=8, depth=1, heads=2, head_dim=4, mlp_dim=8, out_dim=8, view_dim=8, view_depth=1,
                   view_heads=2, view_head_dim=4, view_mlp_dim=8, otap_iterations=3)


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("jcsat_cache")


@pytest.fixture(scope="module")
def scene() -> mocap.Scene:
    return mocap.synthesise_scene(jax.random.key(TRAIN_DATA.first_seed), mocap.shelf_cameras(),
                                  num_people=TRAIN_DATA.num_people, num_frames=TRAIN_DATA.num_frames,
                                  clips=[mocap.load_clip(c) for c in TRAIN_DATA.clips])


@pytest.fixture(scope="module")
def dataset(scene, cache_dir):
    return build_dataset(TRAIN_DATA, cache_dir)


def _config(**overrides) -> TrainConfig:
    base = TrainConfig(model=TINY, batch_size=2, steps=4, peak_lr=1e-2, warmup_steps=1, end_lr=3e-3,
                       checkpoint_interval=2, validation_interval=2, log_interval=1, validation_windows=6,
                       data=TRAIN_DATA, validation_data=VALIDATION_DATA)
    return dataclasses.replace(base, **overrides)


# ---------------------------------------------------------------- losses


def _skeleton(num_frames: int = 3) -> np.ndarray:
    """A plausible Shelf15 pose (metres), the same in every frame: (1, N, 15, 3)."""
    pose = np.array([
        [-0.15, 0, 0.1], [-0.15, 0, 0.5], [-0.15, 0, 0.95], [0.15, 0, 0.95], [0.15, 0, 0.5], [0.15, 0, 0.1],
        [-0.45, 0, 1.1], [-0.35, 0, 1.3], [-0.2, 0, 1.45], [0.2, 0, 1.45], [0.35, 0, 1.3], [0.45, 0, 1.1],
        [0, 0, 1.55], [0, 0, 1.75], [0, 0, 0.95],
    ])
    return np.broadcast_to(pose, (1, num_frames, 15, 3)).copy()


def _camera_batch(target: np.ndarray, valid: np.ndarray) -> Batch:
    """Two cameras 5 m away looking along +y and -x; f = 500 px, 1000 x 800 images."""
    K = np.array([[500.0, 0, 500], [0, 500, 400], [0, 0, 1]])
    R1 = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # camera z = world y
    R2 = np.array([[0.0, 1, 0], [0, 0, -1], [-1, 0, 0]])  # camera z = -world x
    P = np.stack([K @ np.concatenate([R, np.array([[0], [-1], [5]])], axis=1) for R in (R1, R2)])
    size = np.array([[1000.0, 800.0], [1000.0, 800.0]])
    points = np.zeros((1, target.shape[1], 10, 4, 25, 3), np.float32)
    mask = np.zeros(points.shape[:-1], bool)
    return Batch(jnp.asarray(points), jnp.asarray(mask), jnp.asarray(target), jnp.asarray(valid),
                 jnp.asarray(P[None]), jnp.asarray(size[None]))


def test_losses_zero_for_exact_prediction_with_finite_gradients():
    target = _skeleton()
    batch = _camera_batch(target, np.ones((1, 3), bool))
    total, terms = jax.jit(jcsat_loss)(jnp.asarray(target), batch)
    for name, value in terms.items():
        assert float(value) == pytest.approx(0.0, abs=1e-12), name
    assert float(total) == pytest.approx(0.0, abs=1e-12)
    # Finite at the kinks (distances of 0). Not necessarily 0: under jit the projected prediction and
    # target may differ in the last bit, and a distance's gradient there is a unit vector.
    grad = jax.jit(jax.grad(lambda p: jcsat_loss(p, batch)[0]))(jnp.asarray(target))
    assert np.all(np.isfinite(grad))


def test_reconstruction_and_projection_by_hand():
    target = _skeleton(2)
    pred = target.copy()
    pred[0, 0, :, 0] += 0.1  # frame 0: every joint 0.1 m along x
    pred[0, 1] += 7.0  # frame 1 is invalid: must not count
    valid = np.array([[True, False]])
    batch = _camera_batch(target, valid)
    assert float(reconstruction_loss(jnp.asarray(pred), batch.target, batch.target_valid)) == pytest.approx(0.01)
    # Camera 1 sees x at depth 5 (y = 0): a 0.1 m shift is 500 * 0.1 / 5 = 10 px = 0.01 widths.
    # Camera 2 looks along -x from x = 5: the shift brings each joint 0.1 m closer, scaling its
    # vertical offset from the principal point, 500 (z + 1) / (5 - x) px, by (5 - x) / (4.9 - x).
    x, z = target[0, 0, :, 0], target[0, 0, :, 2]
    offset = 500 * (z + 1) / (5 - x)
    camera2 = np.mean(offset * ((5 - x) / (4.9 - x) - 1)) / 800
    pred_2d = project_normalised(batch.projections, batch.image_size, jnp.asarray(pred), 0.1)
    target_2d = project_normalised(batch.projections, batch.image_size, batch.target, 0.1)
    assert float(projection_loss(pred_2d, target_2d, batch.target_valid)) == pytest.approx(0.01 + camera2, rel=1e-9)


def test_projection_behind_camera_is_finite():
    target = _skeleton(1)
    pred = target.copy()
    pred[0, 0, 3, 1] = -7.0  # 2 m behind camera 1 (which sits at y = -5)
    batch = _camera_batch(target, np.ones((1, 1), bool))
    loss, grad = jax.jit(jax.value_and_grad(lambda p: jcsat_loss(p, batch)[0]))(jnp.asarray(pred))
    assert np.isfinite(float(loss)) and np.all(np.isfinite(grad))


def test_pcp_hinge_by_hand():
    target = _skeleton(2)
    pred = target.copy()
    pred[0, 0, 13, 2] += 0.5  # head top 0.5 m up: head part (length 0.2 m) exceeds by 0.3 m
    pred[0, 0, 0, 0] += 0.1  # right ankle 0.1 m: within the lower leg's hinge (0.4 m)
    valid = np.array([[True, True]])
    loss = pcp_hinge_loss(jnp.asarray(pred), jnp.asarray(target), jnp.asarray(valid))
    assert float(loss) == pytest.approx(0.3 / (2 * 10))
    # The same error on an invalid frame does not count.
    assert float(pcp_hinge_loss(jnp.asarray(pred), jnp.asarray(target), jnp.asarray([[False, True]]))) == 0.0


def test_bone_terms():
    rigid = _skeleton(3)
    angle = np.array([0.0, 0.4, 1.3])  # rigid motions of a constant skeleton
    c, s = np.cos(angle), np.sin(angle)
    rotation = np.stack([np.stack([c, -s, 0 * c], -1), np.stack([s, c, 0 * c], -1), np.stack([0 * c, 0 * c, 1 + 0 * c], -1)], -2)
    moved = np.einsum("nij,bnkj->bnki", rotation, rigid) + np.array([1.0, 2.0, 0.0]).reshape(1, 1, 1, 3)
    temporal, symmetry = bone_losses(jnp.asarray(moved))
    assert float(temporal) == pytest.approx(0.0, abs=1e-14) and float(symmetry) == pytest.approx(0.0, abs=1e-14)
    # Lengthen the left upper arm (shoulder -> elbow, 0.212 m) by 0.1 m in frame 1 only.
    pred = rigid.copy()
    shoulder, elbow, wrist = (SHELF15.index(n) for n in ("l_shoulder", "l_elbow", "l_wrist"))
    direction = (pred[0, 1, elbow] - pred[0, 1, shoulder]) / np.linalg.norm(pred[0, 1, elbow] - pred[0, 1, shoulder])
    pred[0, 1, elbow] += 0.1 * direction
    pred[0, 1, wrist] += 0.1 * direction
    temporal, symmetry = bone_losses(jnp.asarray(pred))
    # Two frame changes of 0.1 m over 2 x 8 (change, limb) entries; one pair differing by 0.1 in 3 x 4.
    assert float(temporal) == pytest.approx(2 * 0.01 / 16)
    assert float(symmetry) == pytest.approx(0.01 / 12)


# ---------------------------------------------------------------- data


def test_batch_from_scene(scene, dataset, cache_dir):
    # `dataset` was built (and cached) from the `scene` fixture's seed: the pixel check below needs that.
    start = time.perf_counter()
    cached = build_dataset(TRAIN_DATA, cache_dir)
    assert time.perf_counter() - start < 1.0
    for name in cached._fields:
        assert_array_equal(getattr(cached, name), getattr(dataset, name), err_msg=name)
    assert dataset.num_windows > 10 and set(np.unique(dataset.person)) >= {0, 1, 2}

    batch = sample_batch(dataset, jax.random.key(3), 5, TRAIN_DATA.window)
    again = sample_batch(dataset, jax.random.key(3), 5, TRAIN_DATA.window)
    for a, b in zip(batch, again):
        assert_array_equal(a, b)
    n, p, m, j = TRAIN_DATA.window, 10, TRAIN_DATA.cluster.candidates_per_pair, 25
    assert batch.points.shape == (5, n, p, m, j, 3) and batch.points.dtype == jnp.float32
    assert batch.mask.shape == (5, n, p, m, j) and batch.mask.dtype == bool
    assert batch.target.shape == (5, n, 15, 3) and batch.target_valid.shape == (5, n)
    assert batch.projections.shape == (5, 5, 3, 4) and batch.image_size.shape == (5, 5, 2)
    assert np.all(np.asarray(batch.points)[~np.asarray(batch.mask)] == 0) and np.asarray(batch.mask).any()
    assert np.all(np.asarray(batch.target_valid)[:, 0])  # every window starts on a labelled frame
    assert np.all(np.asarray(batch.target)[~np.asarray(batch.target_valid)] == 0)

    # Projecting the model-frame target with the composed matrices gives the scene's 2D ground truth.
    index = np.arange(0, dataset.num_windows, 3)
    angle = np.linspace(0.0, 6.0, len(index))
    batch = window_batch(dataset, index, angle, TRAIN_DATA.window)
    rows = dataset.window_start[index][:, None] + np.arange(TRAIN_DATA.window)
    homogeneous = np.concatenate([np.asarray(batch.target), np.ones(batch.target.shape[:-1] + (1,))], axis=-1)
    image = np.einsum("bvij,bnkj->bvnki", np.asarray(batch.projections), homogeneous)
    pixels = image[..., :2] / image[..., 2:]
    truth = np.moveaxis(scene.shelf15_pixels[dataset.frame[rows], :, dataset.person[rows[:, :1]]], 2, 1)
    valid = np.broadcast_to(np.asarray(batch.target_valid)[:, None, :, None, None], truth.shape)
    assert_allclose(pixels[valid], truth[valid], atol=1e-6)
    # The window is centred on its first frame's cluster centre, which lies near the person's mid-hip.
    first_hip = np.asarray(batch.target)[:, 0, SHELF15.index("mid_hip")]
    assert np.all(np.linalg.norm(first_hip, axis=-1) < TRAIN_DATA.match_radius)


def test_head_rule_changes_only_the_head_labels(scene, dataset, cache_dir):
    four_da = build_dataset(dataclasses.replace(TRAIN_DATA, head_rule="4da"), cache_dir)
    for name in four_da._fields:
        if name != "target":
            assert_array_equal(getattr(four_da, name), getattr(dataset, name), err_msg=name)
    head = [SHELF15.index("head_bottom"), SHELF15.index("head_top")]
    rest = np.setdiff1d(np.arange(15), head)
    labelled = dataset.person >= 0
    # The clips store both skeletons in millimetres, so the shared joints agree to their quantisation.
    assert_allclose(four_da.target[:, rest], dataset.target[:, rest], atol=1.5e-3)
    expected = np.asarray(geometry.to_shelf15(scene.body25, geometry.BODY25, "4da"))[
        dataset.frame[labelled], dataset.person[labelled]]
    assert_allclose(four_da.target[labelled][:, head], expected[:, head], atol=1e-12)
    moved = np.linalg.norm(four_da.target[labelled][:, head] - dataset.target[labelled][:, head], axis=-1)
    assert np.median(moved[:, 1]) > 0.05  # the two rules put the top of the head in different places
    assert np.all(four_da.target[~labelled] == 0)
    with pytest.raises((ValueError, TypeCheckError), match="head_rule"):  # beartype checks the Literal first in tests
        DataConfig(head_rule="ears")


# ---------------------------------------------------------------- training


def _fixed_batch_steps(config: TrainConfig, dataset, num_steps: int):
    """``num_steps`` train steps on one fixed batch of ``config.batch_size`` windows (all local devices)."""
    model = JCSAT(config.model, rngs=nnx.Rngs(config.seed))
    graphdef, params, rest = nnx.split(model, nnx.Param, ...)
    replicated, sharded = training.data_parallel_shardings(config.batch_size)
    state = jax.device_put(init_state(config, params, rest), replicated)
    batch = jax.device_put(sample_batch(dataset, jax.random.key(1), config.batch_size, config.data.window), sharded)
    optimiser, schedule = make_optimiser(config.weight_decay, config.grad_clip), learning_rate_schedule(config)
    losses = []
    for i in range(num_steps):
        state, metrics = train_step(graphdef, config.losses, optimiser, replicated, state, batch, jax.random.key(i),
                                    schedule(i))
        losses.append(float(metrics["loss"]))
    return state, losses


def test_parallel_scene_build_matches_one_process(dataset):
    two = build_dataset(dataclasses.replace(TRAIN_DATA, num_scenes=2), workers=2)
    first = two.scene == 0
    assert set(np.unique(two.scene)) == {0, 1} and two.projections.shape[0] == 2
    for name in ("points", "mask", "centre", "target", "person", "frame"):
        assert_array_equal(getattr(two, name)[first], getattr(dataset, name), err_msg=name)
    assert_array_equal(two.window_start[: dataset.num_windows], dataset.window_start)
    with pytest.raises(ValueError, match="workers"):
        build_dataset(TRAIN_DATA, workers=0)


def test_steps_reduce_loss_on_a_fixed_batch(dataset, cache_dir):
    # The model, losses and optimiser settings of the runs below: the step compiled here is reused by them (the
    # zero-rate run of test_init_model_starts_the_run too: rates are arguments).
    state, losses = _fixed_batch_steps(_config(cache_dir=str(cache_dir)), dataset, 12)
    assert all(np.isfinite(losses)) and losses[-1] < 0.7 * losses[0], losses
    assert int(state.step) == 12


@pytest.fixture(scope="module")
def full_run(dataset, cache_dir, tmp_path_factory):
    """An uninterrupted 4-step run (1 device), with checkpoints every 2 steps."""
    workdir = tmp_path_factory.mktemp("full")
    config = _config(cache_dir=str(cache_dir))
    return config, workdir, train(config, workdir, resume=False, progress=False)


def test_resume_is_bit_identical(full_run, tmp_path):
    config, full_dir, full_model = full_run
    with pytest.raises(Killed):
        train(config, tmp_path, resume=False, log=kill_at(2), progress=False)  # just after a checkpoint
    with pytest.raises(ValueError, match="already has checkpoints"):
        train(config, tmp_path, resume=False, progress=False)
    resumed = train(config, tmp_path, resume=True, progress=False)
    assert_same_parameters(full_model, resumed)

    def records(path):
        return [{k: v for k, v in json.loads(line).items() if k != "seconds_per_step"}
                for line in (path / "log.jsonl").read_text().splitlines()]

    full_log = records(full_dir)
    assert records(tmp_path) == full_log
    assert [r["step"] for r in full_log] == [1, 2, 3, 4]
    assert {"loss", "rec", "proj", "pcp", "pcp_proj", "bone_temporal", "bone_symmetry", "lr"} <= set(full_log[0])
    assert 0.0 < full_log[3]["val_mpjpe_mm"] and 0.0 <= full_log[3]["val_pcp"] <= 100.0
    assert sorted(int(p.name) for p in (tmp_path / "checkpoints").iterdir() if p.name.isdigit()) == [2, 4]
    # The shipped model file loads back into the same parameters.
    loaded = load_model(full_dir / "model")
    assert_same_parameters(full_model, loaded)


def test_validate_matches_the_log_and_a_hand_computation(full_run, cache_dir):
    config, full_dir, full_model = full_run
    data = build_dataset(config.validation_data, cache_dir)
    last = json.loads((full_dir / "log.jsonl").read_text().splitlines()[-1])
    # The run validated 6 windows in batches of 2; 4 pads the second batch, whose padding must weigh nothing.
    figures = validate(full_model, data, windows=config.validation_windows, batch_size=4)
    assert figures["val_frames"] == last["val_frames"]
    assert_allclose([figures["val_mpjpe_mm"], figures["val_pcp"]], [last["val_mpjpe_mm"], last["val_pcp"]], rtol=1e-6)
    batch = window_batch(data, np.arange(config.validation_windows), np.zeros(config.validation_windows), TINY.frames)
    pred = np.asarray(nnx.jit(lambda model, points, mask: model(points, mask))(full_model, batch.points, batch.mask),
                      np.float64)  # compiled: eagerly, this tiny model's Sinkhorn iterations took seconds
    error = np.linalg.norm(pred - np.asarray(batch.target), axis=-1).mean(-1)[np.asarray(batch.target_valid)]
    assert_allclose(figures["val_mpjpe_mm"], 1000 * error.mean(), rtol=1e-5)
    with pytest.raises(ValueError, match="windows must be >= 1"):
        validate(full_model, data, windows=0)


def test_warmup_leaves_a_decay_step():
    with pytest.raises(ValueError, match=r"warmup_steps must be in \[0, steps=4\)"):
        _config(warmup_steps=4)
    from experiments import shelf_jcsat  # --steps below a run's warm-up keeps one decay step
    assert shelf_jcsat.train_config(shelf_jcsat.Config(train=True, config="gpu_medium", steps=30)).warmup_steps == 29


def test_init_model_starts_the_run(full_run, tmp_path):
    config, full_dir, full_model = full_run
    # A zero learning rate (and so no weight decay either) keeps the starting parameters through the steps.
    frozen = dataclasses.replace(config, peak_lr=0.0, end_lr=0.0, init_model=str(full_dir / "model"))
    assert_same_parameters(train(frozen, tmp_path / "fine", resume=False, progress=False), full_model)
    # ... which are not the seed's fresh initialisation (what the frozen run would keep without init_model).
    with pytest.raises(AssertionError):
        assert_same_parameters(JCSAT(config.model, rngs=nnx.Rngs(config.seed)), full_model)
    wider = dataclasses.replace(frozen, model=dataclasses.replace(TINY, dim=16))
    with pytest.raises(ValueError, match="init_model"):
        train(wider, tmp_path / "wider", resume=False, progress=False)


def test_named_runs_start_from_shipped_models():
    for name, config in TRAIN_CONFIGS.items():
        if config.init_model is not None:
            assert load_model(config.init_model).config == CONFIGS[config.model], name


def test_batch_size_must_divide_by_devices(monkeypatch, tmp_path):
    monkeypatch.setattr(jax, "local_devices", lambda: [object(), object()])
    with pytest.raises(ValueError, match="multiple of the 2 local devices"):
        train(_config(batch_size=3), tmp_path, resume=False, progress=False)


def test_two_devices_match_one(dataset, cache_dir, tmp_path):
    """The train step with each batch split over 2 (forced CPU) devices gives the 1-device result."""
    config = _config(cache_dir=str(cache_dir))
    out = run_on_two_devices("""
        from test_jcsat_train import _fixed_batch_steps
        from jcsat._data import build_dataset
        state, losses = _fixed_batch_steps(config, build_dataset(config.data, config.cache_dir), 2)
        np.savez(OUT, losses, *[np.asarray(x) for x in jax.tree.leaves(state.params)])
    """, config, tmp_path)
    state, losses = _fixed_batch_steps(config, dataset, 2)
    with np.load(out) as stored:
        two = [stored[f"arr_{i}"] for i in range(len(stored.files))]
    assert_allclose(two[0], losses, rtol=1e-6)
    one = [np.asarray(x) for x in jax.tree.leaves(state.params)]
    assert len(one) == len(two) - 1
    for a, b in zip(one, two[1:]):
        assert_allclose(a, b, rtol=1e-5, atol=1e-6)

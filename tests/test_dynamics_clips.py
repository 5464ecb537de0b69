"""The dynamics evaluation on any clip: motion files and salsa pairs as clips (dynamics/_data.py, mocap.clip_files),
``python -m experiments.dynamics --clips`` and the strip's titles (experiments/dynamics_study/_evaluation.py)."""

import dataclasses
import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

import dynamics._data
import mocap
import training
from dynamics import TRAIN_CLIPS, DataConfig
from dynamics._data import _cache_file
from experiments.dynamics_study import STRIP_FRAMES, STRIP_SIZE
from experiments.dynamics_study._evaluation import _frame_title, _titled

REPO = Path(__file__).resolve().parents[1]


def _expmap_file(path: Path, frames: int = 40, bend: float = 0.0) -> Path:
    """A CMU exp-map file of ``frames`` frames at 120 Hz: the rest pose walking along x, one joint bent by ``bend``."""
    values = np.zeros((frames, 3 + 3 * len(mocap.CMU_EXPMAP_NODES)))
    values[:, 0] = np.linspace(0.0, 5.0, frames)
    values[:, 3 + 3 * 2] = bend
    path.write_text("".join(",".join(f"{v:.6f}" for v in row) + "\n" for row in values))
    return path


def test_a_data_config_takes_motion_files_and_pairs_of_them_and_refuses_the_rest(tmp_path):
    walk, partner = _expmap_file(tmp_path / "walk.txt"), _expmap_file(tmp_path / "partner.txt", bend=0.5)
    pair = f"{walk}+{partner}"
    assert DataConfig(clips=("02_01_walk", str(walk), pair)).clips == ("02_01_walk", str(walk), pair)
    clip = mocap.load_clip_file(pair)
    assert clip.num_people == 2 and clip.num_frames == 10 and clip.sources == ("walk.txt", "partner.txt")
    np.testing.assert_allclose(clip.body25[0], mocap.load_clip_file(walk).body25[0])  # each person as on their own
    assert mocap.clip_files(pair) == (walk, partner) and mocap.clip_files("02_01_walk") == ()
    with pytest.raises(ValueError, match=r"'no_such\.txt' is neither a shipped clip \(01_01_jumps, .*\) nor a file"):
        DataConfig(clips=("no_such.txt",))
    with pytest.raises(ValueError, match=r"'no_such\.txt' of '.*walk\.txt\+no_such\.txt' is not a file"):
        DataConfig(clips=(f"{walk}+no_such.txt",))
    with pytest.raises(ValueError, match="joins 3 people; the models take one or two"):
        DataConfig(clips=(f"{pair}+{walk}",))
    with pytest.raises(ValueError, match="people of one clip need the same frame count"):
        mocap.load_clip_file(f"{walk}+{_expmap_file(tmp_path / 'short.txt', frames=20)}")


def test_the_cache_key_tells_motion_files_rendering_versions_and_xla_flags_apart(tmp_path, monkeypatch):
    path = _expmap_file(tmp_path / "walk.txt")
    config = DataConfig(clips=(str(path),))
    first = _cache_file(config, [mocap.load_clip_file(path)], tmp_path)
    _expmap_file(path, bend=0.5)  # another motion at the same path
    assert _cache_file(config, [mocap.load_clip_file(path)], tmp_path) != first
    shipped = DataConfig(clips=("02_01_walk",))
    walk = [mocap.load_clip("02_01_walk")]
    monkeypatch.setenv("XLA_FLAGS", "--b --a")
    key = hashlib.sha1((f"rendering 2 jax {jax.__version__} XLA_FLAGS --a --b "
                        + json.dumps(training.to_jsonable(shipped), sort_keys=True)).encode())
    assert _cache_file(shipped, walk, tmp_path).name == f"dynamics_frames_{key.hexdigest()[:16]}.npz"
    monkeypatch.setenv("XLA_FLAGS", "--a --b")  # the same flags in another order: the same renders
    assert _cache_file(shipped, walk, tmp_path).name == f"dynamics_frames_{key.hexdigest()[:16]}.npz"
    monkeypatch.setenv("XLA_FLAGS", "--a")  # another compilation (a notebook without the fusion flag): other rounding
    assert _cache_file(shipped, walk, tmp_path).name != f"dynamics_frames_{key.hexdigest()[:16]}.npz"
    monkeypatch.setenv("XLA_FLAGS", "--a --b")
    monkeypatch.setattr(jax, "__version__", "0.0.1")  # another jax
    assert _cache_file(shipped, walk, tmp_path).name != f"dynamics_frames_{key.hexdigest()[:16]}.npz"
    monkeypatch.undo()
    before = _cache_file(shipped, walk, tmp_path)
    monkeypatch.setattr(dynamics._data, "_RENDERING_VERSION", 3)  # rendering changed: the old renders are not reused
    assert _cache_file(shipped, walk, tmp_path) != before


@pytest.mark.data
def test_a_salsa_pair_of_files_is_the_shipped_salsa_clip(data_root):
    pair = mocap.load_clip_file("cmu_mocap/60_05_scaled.bvh+cmu_mocap/61_05_scaled.bvh", data_root)
    shipped = mocap.load_clip("60_05_61_05_salsa")
    assert pair.num_people == 2 and pair.trials == shipped.trials and pair.sources == shipped.sources
    np.testing.assert_allclose(pair.body25, shipped.body25, atol=6e-4)  # shipped: rounded to 1 mm
    np.testing.assert_allclose(pair.structri17, shipped.structri17, atol=6e-4)


def test_the_command_refuses_a_missing_clip_file_on_one_line(tmp_path):
    env = {key: value for key, value in os.environ.items() if key != "MVMOCAP_DATA_ROOT"}
    run = subprocess.run([sys.executable, "-m", "experiments.dynamics", "--out", str(tmp_path / "out"),
                          "--clips", "03_01_uneven", "missing.bvh"], cwd=REPO, env={**env, "PYTHONPATH": str(REPO)},
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 2 and len(run.stderr.strip().splitlines()) == 1, run.stderr
    assert "error: --clips 'missing.bvh' is neither a shipped clip" in run.stderr, run.stderr
    assert "(relative paths need --data-root)" in run.stderr and not (tmp_path / "out").exists()


@pytest.mark.parametrize(("options", "message"), [
    (["--clips", "missing.bvh"], "--clips 'missing.bvh' is neither a shipped clip"),
    (["--clips"], "--clips names no clip"),
    (["--recipe", "huge"], "--recipe must be one of ('small', 'large'), got 'huge'"),
    (["--data-workers", "0"], "--data-workers must be >= 1, got 0"),
    (["--train", "--renders", "0"], "--renders must be >= 1, got 0"),
    (["--train", "--train-ar-clip-norm", "0"], "--train-ar-clip-norm must be positive, got 0.0"),
    (["--train", "--recipe", "large"], "no data folder: pass data_root (--data-root on the command line)"),
])
def test_the_options_refuse_bad_values_before_any_work(options, message, capsys, monkeypatch):
    from experiments import _cli, dynamics

    monkeypatch.delenv("MVMOCAP_DATA_ROOT", raising=False)  # the large recipe finds no data folder
    with pytest.raises(SystemExit) as exit_info:
        _cli.parse(dynamics.Config, ["--out", "x", *options], prog="dynamics")
    error = capsys.readouterr().err
    assert exit_info.value.code == 2 and error.count("\n") == 1 and message in error, error


@pytest.mark.data
@pytest.mark.parametrize("quick", [False, True])
def test_the_large_recipe_is_consistent_and_renders_the_benchmark_train_split(data_root, quick):
    """Its crops, backbone and data agree (each config validates itself), and it renders every training clip plus
    the CMU-Mocap benchmark's train files (none in --quick, which renders two clips); the small recipe is the
    defaults the shipped models were trained with."""
    from experiments import _cli, dynamics

    small = dynamics.training_configs("small", 0, False, data_root)
    assert small == (dynamics.TrainConfig(), dynamics.TransformerTrainConfig())
    phdt, transformers = dynamics.training_configs("large", 3, quick, data_root)
    assert phdt.seed == transformers.seed == 3 and phdt.data == transformers.data
    assert phdt.backbone.crop_size == phdt.data.crop_size == transformers.validation.crop_size == 128
    assert small[0].backbone.pooling == phdt.backbone.pooling == "flatten"  # chosen on validation, docs/dynamics.md
    expmap = _cli.expmap_clips(data_root, "train")
    expected = dynamics.QUICK_CLIPS if quick else TRAIN_CLIPS + expmap
    assert phdt.data.clips == expected and len(expmap) == 72
    assert small[0].data.renders == 16 and phdt.data.renders == (1 if quick else 2)


def test_renders_per_clip_reach_both_trainings_and_quick_renders_once():
    from experiments import dynamics

    phdt, transformers = dynamics.training_configs("small", 0, False, None, renders=4)
    assert phdt.data.renders == transformers.data.renders == 4 and phdt.data == transformers.data
    assert dynamics.training_configs("small", 0, True, None, renders=4)[0].data.renders == 1


def test_the_ar_clip_norm_reaches_the_autoregressive_stages_of_both_trainings_only():
    from experiments import _cli, dynamics

    config = _cli.parse(dynamics.Config, ["--out", "x", "--train", "--train-ar-clip-norm", "800"], prog="dynamics")
    phdt, transformers = config.training()
    small = dynamics.training_configs("small", 0, False, None)
    assert phdt.ar.clip_norm == transformers.ar.clip_norm == 800.0 and small[0].ar.clip_norm is None
    assert (dataclasses.replace(phdt, ar=small[0].ar), dataclasses.replace(transformers, ar=small[1].ar)) == small


def test_the_strip_titles_its_rows_and_columns():
    titles = [_frame_title(t, 25) for t in STRIP_FRAMES]
    assert titles == ["observed t-12", "observed t", "predicted t+1", "predicted t+5", "predicted t+10",
                      "predicted t+20", "predicted t+30"]
    rows = ["video", "PHD+T", "JAT w/o bias", "ZeroMotion"]
    cells = [[np.full((STRIP_SIZE, STRIP_SIZE, 3), 40 * r + c, np.uint8) for c in range(len(titles))]
             for r in range(len(rows))]
    image = _titled(cells, rows, titles)
    top, left = image.shape[0] - STRIP_SIZE * len(rows), image.shape[1] - STRIP_SIZE * len(titles)
    assert 10 < top < 60 and 50 < left < 200, (top, left)
    np.testing.assert_array_equal(image[top:, left:], np.concatenate([np.concatenate(r, axis=1) for r in cells]))
    ink = image.min(axis=2) < 128
    for column in range(len(titles)):  # each title within its own column, none empty
        band = ink[:top, left + column * STRIP_SIZE: left + (column + 1) * STRIP_SIZE]
        assert band.any() and not band[:, 0].any() and not band[:, -1].any(), titles[column]
    for row in range(len(rows)):
        assert ink[top + row * STRIP_SIZE: top + (row + 1) * STRIP_SIZE, :left].any(), rows[row]
    assert not ink[:top, :left].any()  # the corner stays blank

"""The shared training infrastructure: the resumable loop, the model store, dropout (model-specific runs are
tested with their models: tests/test_jcsat_train.py, tests/test_flex_train.py)."""

import dataclasses
import json
import os
import re
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx
from numpy.testing import assert_array_equal

import training
from _training_harness import Killed, kill_at


@dataclasses.dataclass(frozen=True)
class _Config:
    rate: float = 0.5


class _State(NamedTuple):
    value: jax.Array
    step: jax.Array


def _step(state: _State, i: int):
    noise = jax.random.normal(jax.random.fold_in(jax.random.key(0), i), (3,))
    return _State(state.value * 0.5 + noise, state.step + 1), {"loss": jnp.sum(state.value ** 2)}


def _run(workdir, config=_Config(), steps=5, resume=False, log=lambda record: None):
    replicated, _ = training.data_parallel_shardings(1)
    return training.run_training(
        workdir, config, _State(jnp.ones(3), jnp.asarray(0, jnp.int32)), _step, steps=steps, resume=resume,
        log_interval=1, checkpoint_interval=2, validation_interval=5, validate=lambda s: {"val": float(s.value[0])},
        replicated=replicated, learning_rate=lambda i: 0.1 * i, log=log, progress=False)


@dataclasses.dataclass(frozen=True)
class _Stage:
    rate: float = 0.5
    clip: float | None = None  # "added after the run started": None keeps the old program


@dataclasses.dataclass(frozen=True)
class _Nested:
    stage: _Stage = _Stage(clip=2.0)
    name: str = "a"


def test_resume_takes_a_field_added_since_at_its_default_and_names_what_differs(tmp_path):
    with pytest.raises(Killed):
        _run(tmp_path, config=_Nested(stage=_Stage()), log=kill_at(3))
    stored = json.loads((tmp_path / "config.json").read_text())
    del stored["stage"]["clip"]  # as a run written before the field existed stores it
    (tmp_path / "config.json").write_text(json.dumps(stored))
    for config, names in ((_Nested(), "stage.clip"), (_Nested(stage=_Stage(rate=0.1, clip=None), name="b"),
                                                      "stage.rate, name")):
        with pytest.raises(ValueError, match=rf"config\.json records a run of another config \(it differs in "
                                             rf"{names}\): resume only"):
            _run(tmp_path, config=config, resume=True)
    (tmp_path / "config.json").write_text(json.dumps({**stored, "removed": 1}))
    with pytest.raises(ValueError, match=r"differs in removed\):"):
        _run(tmp_path, config=_Nested(stage=_Stage()), resume=True)
    (tmp_path / "config.json").write_text(json.dumps(stored))
    assert int(_run(tmp_path, config=_Nested(stage=_Stage()), resume=True).step) == 5
    assert json.loads((tmp_path / "config.json").read_text())["stage"]["clip"] is None  # rewritten in full


def test_fields_a_run_is_independent_of_are_not_recorded_and_may_change(tmp_path):
    def run(config, **options):
        replicated, _ = training.data_parallel_shardings(1)
        return training.run_training(
            tmp_path, config, _State(jnp.ones(3), jnp.asarray(0, jnp.int32)), _step, steps=4, log_interval=1,
            checkpoint_interval=2, validation_interval=4, validate=lambda state: {}, replicated=replicated,
            independent_of=("name",), progress=False, **options)

    with pytest.raises(Killed):
        run(_Nested(), resume=False, log=kill_at(3))
    assert "name" not in json.loads((tmp_path / "config.json").read_text())
    (tmp_path / "config.json").write_text(json.dumps({**json.loads((tmp_path / "config.json").read_text()),
                                                      "name": "as an older run recorded it"}))
    with pytest.raises(ValueError, match=r"differs in stage\.rate\):"):
        run(_Nested(stage=_Stage(rate=0.1, clip=2.0), name="b"), resume=True)
    assert int(run(_Nested(name="b"), resume=True).step) == 4
    with pytest.raises(ValueError, match=r"independent_of names \['nmae'\], which _Config has no fields for"):
        training.run_training(tmp_path / "x", _Config(), _State(jnp.ones(3), jnp.asarray(0, jnp.int32)), _step,
                              steps=1, resume=False, log_interval=1, checkpoint_interval=1, validation_interval=1,
                              validate=dict, replicated=training.data_parallel_shardings(1)[0],
                              independent_of=("nmae",))


def test_loop_resumes_bit_identically_and_refuses_misuse(tmp_path):
    full = _run(tmp_path / "full")
    with pytest.raises(Killed):
        _run(tmp_path / "run", log=kill_at(3))  # after the checkpoint at 2: step 3 is lost and redone
    with pytest.raises(ValueError, match="already has checkpoints"):
        _run(tmp_path / "run")
    with pytest.raises(ValueError, match="records a run of another config"):
        _run(tmp_path / "run", config=_Config(rate=0.1), resume=True)
    resumed = _run(tmp_path / "run", resume=True)
    assert_array_equal(np.asarray(resumed.value), np.asarray(full.value))
    assert int(resumed.step) == 5

    def records(path):
        return [{k: v for k, v in json.loads(line).items() if k != "seconds_per_step"}
                for line in (path / "log.jsonl").read_text().splitlines()]

    assert records(tmp_path / "run") == records(tmp_path / "full")
    assert [r["step"] for r in records(tmp_path / "full")] == [1, 2, 3, 4, 5]
    assert "val" in records(tmp_path / "full")[-1] and records(tmp_path / "full")[2]["lr"] == pytest.approx(0.2)
    run_json = json.loads((tmp_path / "full" / "run.json").read_text())  # what made the run (training.provenance)
    assert {"versions", "git", "argv", "device", "started"} <= set(run_json) and run_json["versions"]["jax"]
    with pytest.raises(ValueError, match="log_interval must be >= 1"):
        training.run_training(tmp_path / "x", _Config(), full, _step, steps=1, resume=False, log_interval=0,
                              checkpoint_interval=1, validation_interval=1, validate=dict,
                              replicated=training.data_parallel_shardings(1)[0])


def test_model_store_round_trip_and_mismatch(tmp_path):
    model = nnx.Linear(3, 2, rngs=nnx.Rngs(1))
    training.save_model(tmp_path / "m", {"in_features": 3, "out_features": 2}, nnx.state(model))
    loaded = training.load_model_state(tmp_path / "m", lambda f: nnx.Linear(f["in_features"], f["out_features"],
                                                                             rngs=nnx.Rngs(7)))
    assert_array_equal(np.asarray(loaded.kernel[...]), np.asarray(model.kernel[...]))
    with pytest.raises(ValueError, match="does not match"):
        training.load_model_state(tmp_path / "m", lambda f: nnx.LayerNorm(3, rngs=nnx.Rngs(0)))
    with pytest.raises(FileNotFoundError, match="no config.json, state.npz"):
        training.load_model_state(tmp_path / "empty", lambda f: model)


def test_models_stored_in_float16_load_in_the_models_precision(tmp_path):
    model = nnx.Linear(3, 2, rngs=nnx.Rngs(1))
    config = {"in_features": 3, "out_features": 2}
    training.save_model(tmp_path / "full", config, nnx.state(model))
    training.save_model(tmp_path / "half", config, nnx.state(model), dtype="float16")
    assert {array.dtype for array in training.read_model_arrays(tmp_path / "half").values()} == {np.dtype(np.float16)}
    loaded = training.load_model_state(tmp_path / "half", _linear)
    assert loaded.kernel[...].dtype == jnp.float32
    half_kernel = np.asarray(model.kernel[...]).astype(np.float16).astype(np.float32)
    assert_array_equal(np.asarray(loaded.kernel[...]), half_kernel)
    assert not np.array_equal(half_kernel, np.asarray(model.kernel[...]))  # the cast happened

    # A float32 model folder rewritten in place: the same files as saving in float16, the config kept.
    training.store_model_as(tmp_path / "full", "float16")
    for name in ("config.json", "state.npz"):
        assert (tmp_path / "full" / name).read_bytes() == (tmp_path / "half" / name).read_bytes()
    assert sorted(p.name for p in (tmp_path / "full").iterdir()) == ["config.json", "state.npz"]

    big = nnx.Linear(3, 2, rngs=nnx.Rngs(1))
    big.kernel[...] = big.kernel[...].at[0, 0].set(1e5)
    with pytest.raises(ValueError, match=r"array .*kernel.* does not fit in float16 \(largest magnitude 1e\+05\)"):
        training.save_model(tmp_path / "big", config, nnx.state(big), dtype="float16")
    with pytest.raises(ValueError, match="storage dtype must be one of float32, float16, got 'int8'"):
        training.store_model_as(tmp_path / "full", "int8")
    with pytest.raises(FileNotFoundError, match="nothing is not a saved model folder: no config.json, state.npz"):
        training.store_model_as(tmp_path / "nothing", "float16")


def test_dropout():
    x = jnp.ones((20_000,))
    assert training.dropout(x, 0.25, None) is x
    dropped = np.asarray(training.dropout(x, 0.25, jax.random.key(0)))
    assert np.allclose(np.unique(dropped), [0.0, 1 / 0.75])
    assert abs(np.mean(dropped == 0.0) - 0.25) < 0.02 and abs(dropped.mean() - 1.0) < 0.03


# ----------------------------------------------------------------------------------------------
# Bad input ("Trustworthy runs"): damaged run folders and model files.


def _records(workdir):
    return [{k: v for k, v in json.loads(line).items() if k != "seconds_per_step"}
            for line in (workdir / "log.jsonl").read_text().splitlines()]


def test_resume_drops_a_torn_last_log_line(tmp_path):
    full = _run(tmp_path / "full")
    with pytest.raises(Killed):
        _run(tmp_path / "run", log=kill_at(3))  # checkpoint at 2
    with (tmp_path / "run" / "log.jsonl").open("a") as log:
        log.write('{"step": 4, "loss": 0.12')  # killed mid-write
    with pytest.warns(UserWarning, match=r"log.jsonl:4: dropped a torn last line"):
        resumed = _run(tmp_path / "run", resume=True)
    assert_array_equal(np.asarray(resumed.value), np.asarray(full.value))
    assert _records(tmp_path / "run") == _records(tmp_path / "full")
    (tmp_path / "run" / "log.jsonl").write_text('{"step": 1}\n{"step": 2\n{"step": 3}\n')
    with pytest.raises(ValueError, match=r"log.jsonl:2 is not a JSON record"):
        _run(tmp_path / "run", resume=True)


def test_resume_skips_a_corrupt_latest_checkpoint(tmp_path):
    full = _run(tmp_path / "full")
    with pytest.raises(Killed):
        _run(tmp_path / "run", log=kill_at(4))  # checkpoints at 2 and 4
    checkpoints = tmp_path / "run" / "checkpoints"
    assert sorted(p.name for p in checkpoints.iterdir()) == ["2", "4"]
    for file in (checkpoints / "4" / "default").rglob("*"):
        if file.is_file():
            file.write_bytes(file.read_bytes()[: file.stat().st_size // 2])
    with pytest.warns(UserWarning, match=r"resuming from checkpoint step 2: skipped step 4 .* does not restore"):
        resumed = _run(tmp_path / "run", resume=True)
    assert_array_equal(np.asarray(resumed.value), np.asarray(full.value))
    assert int(resumed.step) == 5
    assert _records(tmp_path / "run") == _records(tmp_path / "full")
    # With no checkpoint that restores, resuming is refused (and nothing is deleted).
    for file in checkpoints.rglob("*"):
        if file.is_file() and "default" in file.parts:
            file.write_bytes(b"")
    with pytest.raises(ValueError, match=r"no checkpoint in .* restores; the latest \(step 5\)"):
        _run(tmp_path / "run", resume=True)
    assert sorted(p.name for p in checkpoints.iterdir()) == ["4", "5"]


def _linear(fields):
    return nnx.Linear(fields["in_features"], fields["out_features"], rngs=nnx.Rngs(7))


def test_state_archives_hold_floats_as_byte_planes_and_archives_of_plain_arrays_load(tmp_path):
    model = nnx.Linear(128, 128, rngs=nnx.Rngs(1))
    config = {"in_features": 128, "out_features": 128}
    training.save_model(tmp_path / "m", config, nnx.state(model), dtype="float16")
    half = np.asarray(model.kernel[...]).astype(np.float16)
    with np.load(tmp_path / "m" / "state.npz") as stored:
        assert sorted(stored.files) == ["['bias'].value|byte planes of float16",
                                       "['kernel'].value|byte planes of float16"]
        planes = stored["['kernel'].value|byte planes of float16"]
    assert planes.dtype == np.uint8 and planes.shape == (2, 128, 128)
    assert_array_equal(planes[1], half.view(np.uint16) >> 8)  # the high bytes (sign, exponent) together
    plain = tmp_path / "plain.npz"
    np.savez_compressed(plain, **{"['kernel'].value": half,
                                 "['bias'].value": np.asarray(model.bias[...]).astype(np.float16)})
    # Initial weights gain as trained ones do (7 % at this size; the shipped models 14 %, experiments.store_models).
    assert (tmp_path / "m" / "state.npz").stat().st_size < 0.95 * plain.stat().st_size
    loaded = training.load_model_state(tmp_path / "m", _linear)
    assert_array_equal(np.asarray(loaded.kernel[...]), half.astype(np.float32))

    (tmp_path / "old").mkdir()  # archives written before byte planes hold the arrays as they are
    (tmp_path / "old" / "config.json").write_text(json.dumps(config))
    os.replace(plain, tmp_path / "old" / "state.npz")
    loaded = training.load_model_state(tmp_path / "old", _linear)
    assert_array_equal(np.asarray(loaded.kernel[...]), half.astype(np.float32))

    np.savez(tmp_path / "old" / "state.npz", **{"['kernel'].value|byte planes of float16": planes[:1],
                                                  "['bias'].value": np.zeros(128, np.float16)})
    with pytest.raises(ValueError, match=r"state.npz: entry \['kernel'\]\.value\|byte planes of float16 is not "
                                         r"the byte planes of a float16 array \(stored: uint8\[1, 128, 128\]\)"):
        training.load_model_state(tmp_path / "old", _linear)


def test_model_files_are_written_atomically(tmp_path, monkeypatch):
    model = nnx.Linear(3, 2, rngs=nnx.Rngs(1))
    training.save_model(tmp_path / "m", {"in_features": 3, "out_features": 2}, nnx.state(model))
    before = {name: (tmp_path / "m" / name).read_bytes() for name in ("config.json", "state.npz")}

    savez = np.savez_compressed

    def killed(file, **arrays):  # a run killed half-way through writing the arrays
        savez(file, **arrays)
        if isinstance(file, (str, os.PathLike)):  # a path (how the old, non-atomic save_model called it)
            size = os.path.getsize(file)
            os.truncate(file, size // 2)
        else:
            file.truncate(file.tell() // 2)
        raise KeyboardInterrupt

    monkeypatch.setattr(np, "savez_compressed", killed)
    with pytest.raises(KeyboardInterrupt):
        training.save_model(tmp_path / "m", {"in_features": 3, "out_features": 2, "note": "second"},
                            nnx.state(nnx.Linear(3, 2, rngs=nnx.Rngs(2))))
    assert sorted(p.name for p in (tmp_path / "m").iterdir()) == ["config.json", "state.npz"]  # no leftovers
    assert {name: (tmp_path / "m" / name).read_bytes() for name in before} == before


def test_damaged_model_files_name_the_file_and_array(tmp_path):
    model = nnx.Linear(3, 2, rngs=nnx.Rngs(1))
    folder = tmp_path / "m"
    training.save_model(folder, {"in_features": 3, "out_features": 2}, nnx.state(model))
    state, config = (folder / "state.npz").read_bytes(), (folder / "config.json").read_text()
    arrays = training.read_model_arrays(folder)
    kernel = next(name for name in arrays if "kernel" in name)

    np.savez(folder / "state.npz", **arrays | {kernel: arrays[kernel][:, :1]})  # wrong shape
    with pytest.raises(ValueError, match=rf"state.npz does not match .* array {re.escape(kernel)} is float32\[3, 1\], "
                                         r"the model expects float32\[3, 2\]"):
        training.load_model_state(folder, _linear)
    np.savez(folder / "state.npz", **arrays | {kernel: arrays[kernel].astype(np.int32)})  # wrong dtype
    with pytest.raises(ValueError, match=rf"array {re.escape(kernel)} is int32\[3, 2\]"):
        training.load_model_state(folder, _linear)
    (folder / "state.npz").write_bytes(state[: len(state) // 2])
    with pytest.raises(ValueError, match=rf"{re.escape(str(folder / 'state.npz'))} cannot be read \(truncated"):
        training.load_model_state(folder, _linear)
    (folder / "state.npz").write_bytes(state)
    (folder / "config.json").write_text(config[: len(config) // 2])
    with pytest.raises(ValueError, match=rf"{re.escape(str(folder / 'config.json'))} is not valid JSON \(truncated"):
        training.load_model_state(folder, _linear)
    (folder / "config.json").write_text(config)
    loaded = training.load_model_state(folder, _linear)
    assert_array_equal(np.asarray(loaded.kernel[...]), np.asarray(model.kernel[...]))


def test_store_models_command(tmp_path, capsys):
    from experiments import store_models

    model = nnx.Linear(3, 2, rngs=nnx.Rngs(1))
    training.save_model(tmp_path / "m", {"in_features": 3, "out_features": 2}, nnx.state(model))
    # The work itself through main: _cli.run would switch jax_enable_x64 off for the rest of this test process.
    store_models.main(store_models.Config(models=(tmp_path / "m",)))
    assert "(float16)" in capsys.readouterr().out
    assert {array.dtype for array in training.read_model_arrays(tmp_path / "m").values()} == {np.dtype(np.float16)}
    with pytest.raises(SystemExit) as exit_:  # every folder is checked (when parsing) before any is rewritten
        store_models._cli.run(store_models.main, store_models.Config, argv=[str(tmp_path / "m"), str(tmp_path)])
    assert exit_.value.code == 2
    assert f"{tmp_path} is not a saved model folder: no config.json, state.npz" in capsys.readouterr().err

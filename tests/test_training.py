"""The shared training infrastructure: the resumable loop, the model store, dropout (model-specific runs are
tested with their models: tests/test_jcsat_train.py, tests/test_flex_train.py)."""

import dataclasses
import json
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


def test_loop_resumes_bit_identically_and_refuses_misuse(tmp_path):
    full = _run(tmp_path / "full")
    with pytest.raises(Killed):
        _run(tmp_path / "run", log=kill_at(3))  # after the checkpoint at 2: step 3 is lost and redone
    with pytest.raises(ValueError, match="already has checkpoints"):
        _run(tmp_path / "run")
    with pytest.raises(ValueError, match="differs from the config"):
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


def test_dropout():
    x = jnp.ones((20_000,))
    assert training.dropout(x, 0.25, None) is x
    dropped = np.asarray(training.dropout(x, 0.25, jax.random.key(0)))
    assert np.allclose(np.unique(dropped), [0.0, 1 / 0.75])
    assert abs(np.mean(dropped == 0.0) - 0.25) < 0.02 and abs(dropped.mean() - 1.0) < 0.03

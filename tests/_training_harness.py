"""Shared by the training tests: interrupt a run at a logged step, compare models' parameters, and run a
snippet on two forced CPU devices."""

import os
import pickle
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import numpy as np
from flax import nnx
from numpy.testing import assert_array_equal

TESTS = Path(__file__).resolve().parent

_TWO_DEVICE_PROLOGUE = """
import pickle, sys
import geometry  # before jax computes (XLA flags)
import jax
import numpy as np
jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_rank_promotion", "raise")
assert jax.local_device_count() == 2, jax.local_devices()
sys.path.insert(0, sys.argv[3])
config = pickle.loads(open(sys.argv[1], "rb").read())
OUT = sys.argv[2]
"""


class Killed(Exception):
    """Raised from a run's ``log`` callback: the run stops as a killed process would."""


def kill_at(step: int):
    """A ``log`` callback that kills the run when it logs ``step``."""

    def log(record: dict) -> None:
        if record["step"] == step:
            raise Killed

    return log


def assert_same_parameters(model_a, model_b) -> None:
    leaves_a, leaves_b = (jax.tree.leaves(nnx.state(m, nnx.Param)) for m in (model_a, model_b))
    assert len(leaves_a) == len(leaves_b)
    for a, b in zip(leaves_a, leaves_b):
        assert_array_equal(np.asarray(a), np.asarray(b))


def run_on_two_devices(body: str, config, tmp_path: Path) -> Path:
    """Run ``body`` in a fresh process with 2 forced CPU devices, the tests folder importable, ``config``
    unpickled as ``config``, and ``OUT`` the path of the ``.npz`` it must write; returns that path."""
    (tmp_path / "config.pkl").write_bytes(pickle.dumps(config))
    out = tmp_path / "two_devices.npz"
    # Added to the flags conftest set (the fusion switch), which the child must run with as this process does.
    flags = f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count=2".strip()
    env = {**os.environ, "XLA_FLAGS": flags, "JAX_PLATFORMS": "cpu"}
    if "JAX_COMPILATION_CACHE_DIR" in env:
        # A cache of its own: it may run beside this process (tests/test_dynamics_train.py), whose one-device
        # programs have the same cache keys, and jax writes an entry in place without a lock (tests/conftest.py).
        env["JAX_COMPILATION_CACHE_DIR"] = os.path.join(env["JAX_COMPILATION_CACHE_DIR"], "two_devices")
    subprocess.run([sys.executable, "-c", _TWO_DEVICE_PROLOGUE + textwrap.dedent(body), str(tmp_path / "config.pkl"),
                    str(out), str(TESTS)], check=True, env=env, cwd=TESTS.parent, timeout=300)
    return out

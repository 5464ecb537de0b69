"""Shared by the training tests: interrupt a run at a logged step, and compare models' parameters."""

import jax
import numpy as np
from flax import nnx
from numpy.testing import assert_array_equal


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

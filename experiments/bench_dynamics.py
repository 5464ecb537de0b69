"""MPJAT's autoregressive rollout: frames per second with the key/value cache against a naive rollout.

    .venv/bin/python -m experiments.bench_dynamics --json

A two-person scene (the shipped MPJAT, :data:`dynamics.SHIPPED_TRANSFORMERS`, on random features and fixed boxes;
``--untrained`` for a freshly initialised one of the default size) observes ``--observed`` frames and rolls out
``--horizon``. Contenders, both one jitted call of :meth:`dynamics.JAT.rollout` on the same observation:

- ``cached``: each step computes the newest frame's keys and values and attends over the stored ones;
- ``naive``: each step re-encodes every frame (input encoder, keys, values) and attends (``cached=False``).

Both also regress each predicted frame's parameters and joints (the Joint-Aware Bias needs them), which the cache
cannot save. Reports predicted frames per second (``horizon`` x people / time, best of ``--repeats`` interleaved
rounds after the compiling call), ``speedup_vs_naive`` and the largest difference of the two predictions.
"""

from __future__ import annotations

import dataclasses
import json
import os
import platform
import time

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx

import geometry
from dynamics import JAT, SHIPPED_TRANSFORMERS, JATConfig, load_transformers
from experiments import _cli
from experiments.bench_geometry import interleaved_times


@dataclasses.dataclass(frozen=True)
class Config:
    observed: int = 25
    """Observed frames."""
    horizon: int = 30
    """Predicted frames."""
    people: int = 2
    """People in the scene."""
    repeats: int = 5
    """Timed rounds; the best is kept."""
    untrained: bool = False
    """A freshly initialised MPJAT, not the shipped one."""
    json: bool = False
    """Print one JSON object instead of lines."""

    def __post_init__(self) -> None:
        for name in ("observed", "horizon", "people", "repeats"):
            if getattr(self, name) < 1:
                raise ValueError(f"--{name} must be >= 1, got {getattr(self, name)}")


def main(config: Config) -> None:
    body = geometry.stand_in_body_model()
    model = (JAT(JATConfig(agent_aware=True), rngs=nnx.Rngs(0)) if config.untrained
             else load_transformers(SHIPPED_TRANSFORMERS)["MPJAT"])
    rng = np.random.default_rng(0)
    scene = (1, config.people, config.observed)
    features = jnp.asarray(rng.normal(size=scene + (model.config.feature_dim,)), jnp.float32)
    boxes = jnp.asarray(np.array([100.0, 60, 180, 140]) + rng.normal(scale=2.0, size=scene + (4,)), jnp.float32)
    K = jnp.broadcast_to(jnp.asarray([[300.0, 0, 160], [0, 300, 120], [0, 0, 1]], jnp.float32), scene + (3, 3))
    observed = nnx.jit(lambda model: model.observe(body, features, boxes, K))(model)
    graphdef, state = nnx.split(model)
    rollouts = {name: jax.jit(lambda state, observed, cached=cached: nnx.merge(graphdef, state).rollout(
        body, observed, config.horizon, cached=cached)) for name, cached in (("cached", True), ("naive", False))}
    outputs, compile_seconds = {}, {}
    for name, fn in rollouts.items():
        start = time.perf_counter()
        outputs[name] = jax.block_until_ready(fn(state, observed))
        compile_seconds[name] = time.perf_counter() - start
    difference = max(float(jnp.max(jnp.abs(a - b))) for a, b in zip(jax.tree.leaves(outputs["cached"]),
                                                                    jax.tree.leaves(outputs["naive"])))
    best, _ = interleaved_times({name: (lambda fn=fn: fn(state, observed)) for name, fn in rollouts.items()},
                                    config.repeats)
    frames = config.horizon * config.people
    result = {
        "people": config.people, "observed": config.observed, "horizon": config.horizon,
        "model": "untrained" if config.untrained else "shipped MPJAT",
        "frames_per_second": {name: frames / seconds for name, seconds in best.items()},
        "ms_per_rollout": {name: 1000.0 * seconds for name, seconds in best.items()},
        "compile_seconds": {name: compile_seconds[name] - best[name] for name in best},
        "speedup_vs_naive": best["naive"] / best["cached"],
        "max_abs_diff": difference,
        "machine": {"node": platform.node(), "processor": platform.processor() or platform.machine(),
                    "platform": platform.platform(), "cpus": os.cpu_count(), "jax": jax.__version__,
                    "device": str(jax.devices()[0])},
    }
    if config.json:
        print(json.dumps(result))
    else:
        for key, value in result.items():
            print(f"{key}: {value}")


if __name__ == "__main__":
    _cli.run(main, Config, description=__doc__)

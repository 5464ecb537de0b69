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

import argparse
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
from experiments.bench_geometry import interleaved_times


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--observed", type=int, default=25, help="observed frames (default 25)")
    parser.add_argument("--horizon", type=int, default=30, help="predicted frames (default 30)")
    parser.add_argument("--people", type=int, default=2, help="people in the scene (default 2)")
    parser.add_argument("--repeats", type=int, default=5, help="timed rounds (default 5)")
    parser.add_argument("--untrained", action="store_true", help="a freshly initialised MPJAT, not the shipped one")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of lines")
    args = parser.parse_args(argv)

    body = geometry.stand_in_body_model()
    model = (JAT(JATConfig(agent_aware=True), rngs=nnx.Rngs(0)) if args.untrained
             else load_transformers(SHIPPED_TRANSFORMERS)["MPJAT"])
    rng = np.random.default_rng(0)
    scene = (1, args.people, args.observed)
    features = jnp.asarray(rng.normal(size=scene + (model.config.feature_dim,)), jnp.float32)
    boxes = jnp.asarray(np.array([100.0, 60, 180, 140]) + rng.normal(scale=2.0, size=scene + (4,)), jnp.float32)
    K = jnp.broadcast_to(jnp.asarray([[300.0, 0, 160], [0, 300, 120], [0, 0, 1]], jnp.float32), scene + (3, 3))
    observed = nnx.jit(lambda model: model.observe(body, features, boxes, K))(model)
    graphdef, state = nnx.split(model)
    rollouts = {name: jax.jit(lambda state, observed, cached=cached: nnx.merge(graphdef, state).rollout(
        body, observed, args.horizon, cached=cached)) for name, cached in (("cached", True), ("naive", False))}
    outputs, compile_seconds = {}, {}
    for name, fn in rollouts.items():
        start = time.perf_counter()
        outputs[name] = jax.block_until_ready(fn(state, observed))
        compile_seconds[name] = time.perf_counter() - start
    difference = max(float(jnp.max(jnp.abs(a - b))) for a, b in zip(jax.tree.leaves(outputs["cached"]),
                                                                    jax.tree.leaves(outputs["naive"])))
    best, _ = interleaved_times({name: (lambda fn=fn: fn(state, observed)) for name, fn in rollouts.items()},
                                    args.repeats)
    frames = args.horizon * args.people
    result = {
        "people": args.people, "observed": args.observed, "horizon": args.horizon,
        "model": "untrained" if args.untrained else "shipped MPJAT",
        "frames_per_second": {name: frames / seconds for name, seconds in best.items()},
        "ms_per_rollout": {name: 1000.0 * seconds for name, seconds in best.items()},
        "compile_seconds": {name: compile_seconds[name] - best[name] for name in best},
        "speedup_vs_naive": best["naive"] / best["cached"],
        "max_abs_diff": difference,
        "machine": {"node": platform.node(), "processor": platform.processor() or platform.machine(),
                    "platform": platform.platform(), "cpus": os.cpu_count(), "jax": jax.__version__,
                    "device": str(jax.devices()[0])},
    }
    if args.json:
        print(json.dumps(result))
    else:
        for key, value in result.items():
            print(f"{key}: {value}")


if __name__ == "__main__":
    main()

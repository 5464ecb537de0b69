"""OTAP throughput: our jitted ``sinkhorn_plan`` / ``otap`` against ott-jax's Sinkhorn on the same problems.

    .venv/bin/python -m experiments.bench_otap --json

Prints one JSON object (or a table without ``--json``). Two JCSAT-shaped cases, each a batch of
``--batch`` padded sequences of ``d = --features`` tokens (tokens ~ N(0, 1), reference ~ U(-1/sqrt(p),
1/sqrt(p)), the OTK init; each sequence has 1 to n valid tokens, uniformly drawn):

- ``t``: T-OTAP, n = 40 tokens (10 frames x 4 candidates) -> p = 10;
- ``s``: S-OTAP, n = 100 tokens (25 joints x 4 candidates) -> p = 25.

Contenders, all ``jit(vmap(.))`` with ``--iterations`` fixed log-domain iterations (epsilon 0.1):
the plan alone (``plan``: ours vs ott-jax's ``Sinkhorn`` with ``min_iterations = max_iterations``,
``inner_iterations=1``, ``threshold=0``, ``a`` uniform over the valid tokens, ``b = 1/p``, times p), and
the whole pooling (``otap``: similarity, plan and weighted average, the same wrapped around ott).
Times are ms per batch, best of ``--repeats`` interleaved rounds after the compiling call (compile
time, first call minus best, reported separately). ``plan_max_abs_diff`` compares the plans with ott
in that configuration (it updates columns first, OTK rows first, so it reflects convergence);
``plan_max_abs_diff_same_order`` poses ott the transposed problem, whose iterates equal ours.
``otap_max_abs_diff`` compares the pooled outputs (ott in the first configuration). With d = 128 the
similarities span about +-60 epsilon, so 100 iterations do not converge fully: expect the first and
third differences to be O(0.1-1) and the same-order one at float32 rounding (1e-5).
About 30 s on 2 CPU cores. ott-jax (a test extra) is imported here only.
"""

from __future__ import annotations

import dataclasses
import json
import os
import platform
from functools import partial
from typing import Literal

import jax
import jax.numpy as jnp
import numpy as np

from experiments import _cli
from experiments.bench_geometry import interleaved_times
from jcsat import otap, sinkhorn_plan

CASES = {"t": (40, 10), "s": (100, 25)}
"""Case name -> (tokens n, outputs p)."""
EPSILON = 0.1


def make_batch(batch: int, n: int, p: int, features: int, dtype: str, seed: int):
    """tokens (batch, n, d), mask (batch, n) with 1..n valid tokens each, reference (p, d)."""
    rng = np.random.default_rng(seed)
    tokens = rng.normal(size=(batch, n, features))
    valid = rng.integers(1, n + 1, size=batch)
    mask = np.arange(n)[None, :] < valid[:, None]
    reference = rng.uniform(-1, 1, size=(p, features)) / np.sqrt(p)
    return jnp.asarray(tokens, dtype), jnp.asarray(mask), jnp.asarray(reference, dtype)


def ott_plan(similarity: jax.Array, mask: jax.Array, iterations: int, same_order: bool = False) -> jax.Array:
    """``p * P_ott`` for one sequence (see the module docstring for the two configurations)."""
    from ott.geometry import geometry
    from ott.problems.linear import linear_problem
    from ott.solvers.linear import sinkhorn

    p = similarity.shape[1]
    a = jnp.where(mask, 1.0 / jnp.sum(mask), 0.0).astype(similarity.dtype)
    b = jnp.full(p, 1.0 / p, similarity.dtype)
    cost, rows, columns = (-similarity.T, b, a) if same_order else (-similarity, a, b)
    solver = sinkhorn.Sinkhorn(
        min_iterations=iterations, max_iterations=iterations, inner_iterations=1, implicit_diff=None, threshold=0.0
    )
    plan = solver(linear_problem.LinearProblem(geometry.Geometry(cost_matrix=cost, epsilon=EPSILON), rows, columns)).matrix
    return p * (plan.T if same_order else plan)


def ott_otap(tokens: jax.Array, mask: jax.Array, reference: jax.Array, iterations: int) -> jax.Array:
    """The same pooling as :func:`jcsat.otap` (no filter), with ott-jax's plan."""
    tokens = jnp.where(mask[:, None], tokens, 0.0)
    return ott_plan(tokens @ reference.T, mask, iterations).T @ tokens


def run(batch: int = 400, features: int = 128, iterations: int = 100, repeats: int = 10, dtype: str = "float32", seed: int = 0) -> dict:
    """All measurements as one flat dict (ms per batch, speedups, max abs plan differences)."""
    result: dict = {
        "node": platform.node(),
        "processor": platform.processor() or platform.machine(),
        "platform": platform.platform(),
        "cpu_count": os.cpu_count(),
        "jax": jax.__version__,
        "ott_jax": __import__("ott").__version__,
        "backend": jax.default_backend(),
        "device": jax.devices()[0].device_kind,
        "dtype": dtype,
        "batch": batch,
        "features": features,
        "iterations": iterations,
        "epsilon": EPSILON,
        "repeats": repeats,
        "seed": seed,
    }
    for case, (n, p) in CASES.items():
        tokens, mask, reference = make_batch(batch, n, p, features, dtype, seed)
        similarity = jnp.einsum("bnd,pd->bnp", jnp.where(mask[..., None], tokens, 0.0), reference)
        fns = {
            "plan_ours": jax.jit(jax.vmap(partial(sinkhorn_plan, epsilon=EPSILON, iterations=iterations))),
            "plan_ott": jax.jit(jax.vmap(partial(ott_plan, iterations=iterations))),
            "otap_ours": jax.jit(jax.vmap(partial(otap, epsilon=EPSILON, iterations=iterations), in_axes=(0, 0, None))),
            "otap_ott": jax.jit(jax.vmap(partial(ott_otap, iterations=iterations), in_axes=(0, 0, None))),
        }
        args = {"plan": (similarity, mask), "otap": (tokens, mask, reference)}
        calls = {name: partial(fn, *args[name.split("_")[0]]) for name, fn in fns.items()}
        seconds, first = interleaved_times(calls, repeats)
        prefix = f"{case}_n{n}_p{p}"
        for name in calls:
            result[f"{prefix}_{name}_ms"] = 1e3 * seconds[name]
            result[f"{prefix}_{name}_compile_s"] = first[name] - seconds[name]
        for kind in ("plan", "otap"):
            result[f"{prefix}_{kind}_speedup_vs_ott"] = seconds[f"{kind}_ott"] / seconds[f"{kind}_ours"]
        ours = np.asarray(calls["plan_ours"]())
        same_order = jax.jit(jax.vmap(partial(ott_plan, iterations=iterations, same_order=True)))(similarity, mask)
        result[f"{prefix}_plan_max_abs_diff"] = float(np.abs(ours - np.asarray(calls["plan_ott"]())).max())
        result[f"{prefix}_plan_max_abs_diff_same_order"] = float(np.abs(ours - np.asarray(same_order)).max())
        result[f"{prefix}_otap_max_abs_diff"] = float(np.abs(np.asarray(calls["otap_ours"]()) - np.asarray(calls["otap_ott"]())).max())
    return result


@dataclasses.dataclass(frozen=True)
class Config:
    json: bool = False
    """Print one JSON object instead of a table."""
    batch: int = 400
    """Sequences per call."""
    features: int = 128
    """Token dimension d."""
    iterations: int = 100
    """Fixed Sinkhorn iterations (as JCSAT)."""
    repeats: int = 10
    """Timed rounds; the best is kept."""
    dtype: Literal["float32", "float64"] = "float32"
    """Dtype of every contender (float32 is the model's)."""
    seed: int = 0
    """Seed of the synthetic tokens, masks and reference."""

    def __post_init__(self) -> None:
        for name in ("batch", "features", "iterations", "repeats"):
            if getattr(self, name) < 1:
                raise ValueError(f"--{name} must be >= 1, got {getattr(self, name)}")


def main(config: Config) -> None:
    result = run(config.batch, config.features, config.iterations, config.repeats, config.dtype, config.seed)
    if config.json:
        print(json.dumps(result))
    else:
        width = max(map(len, result))
        print("\n".join(f"{key:<{width}}  {value:.4g}" if isinstance(value, float) else f"{key:<{width}}  {value}" for key, value in result.items()))


if __name__ == "__main__":
    _cli.run(main, Config, description=__doc__, float64=lambda config: config.dtype == "float64")

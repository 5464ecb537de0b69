"""Mean and spread over training seeds: several ``python -m experiments.dynamics`` runs of one evaluation (their
``results.json``), cell by cell, and each forecaster's paired difference to ZeroMotion.

The difference to ZeroMotion is taken within each run before it is averaged: the runs share the test renders, so
its spread is the seeds' effect on the comparison, not the test samples' (issue 26: "below ZeroMotion by more than
the spread over seeds")."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import jax
import numpy as np

from dynamics import HORIZONS
from experiments._stats import mean_and_sd

from ._report import digits

__all__ = ["seeds_markdown", "seeds_summary"]

_BASELINE = "ZeroMotion"
_GROUP_TITLES = {"single_person": "single-person samples", "two_person": "two-person samples", "all": "all samples"}
_CONDITIONING = {"mpjpe": "MPJPE (mm)", "pa_mpjpe": "PA-MPJPE (mm)", "root": "root (mm)",
                 "depth_ratio": "depth / true depth"}
_PREDICTION = {"mpjpe": "MPJPE (mm) ↓", "pa_mpjpe": "PA-MPJPE (mm) ↓", "root": "root (mm) ↓"}


def _per_frame(value) -> bool:
    return isinstance(value, list)  # one number per future frame: a cell, not a pytree node


def seeds_summary(results: Sequence[Mapping]) -> dict:
    """Per sample group of the runs' ``summary``: every cell's mean and sample standard deviation over the runs
    (``{"mean", "sd"}`` in place of each number or per-frame list), and ``below_zero_motion``: each forecaster's
    MPJPE minus ZeroMotion's in the same run, per future frame, as mean and sd.

    The runs must have evaluated the same way (equal ``config``: clips, test seed, windows); a spread needs two."""
    if len(results) < 2:
        raise ValueError(f"a spread over seeds needs at least two runs, got {len(results)}")
    for index, result in enumerate(results[1:], start=2):
        if result["config"] != results[0]["config"]:
            raise ValueError(f"run {index} evaluated differently from run 1 (its results.json config differs): "
                             "runs of one evaluation only")
        if jax.tree.structure(result["summary"]) != jax.tree.structure(results[0]["summary"]):
            raise ValueError(f"run {index} scored other groups or methods than run 1")
    summaries = [result["summary"] for result in results]
    out = {}
    for group in summaries[0]:
        runs = [summary[group] for summary in summaries]
        out[group] = {name: (runs[0][name] if name == "samples"
                             else jax.tree.map(mean_and_sd, *(run[name] for run in runs), is_leaf=_per_frame))
                      for name in runs[0]}
        out[group]["below_zero_motion"] = {
            method: mean_and_sd(*(np.subtract(run["prediction"][method]["mpjpe"],
                                               run["prediction"][_BASELINE]["mpjpe"]).tolist() for run in runs))
            for method in runs[0]["prediction"] if method != _BASELINE}
    return out


def mean_sd_cell(value: Mapping, frame: int | None = None, digits: int = 1) -> str:
    """``"mean ± sd"`` of a ``{"mean", "sd"}`` cell (at index ``frame`` of per-frame lists)."""
    mean, sd = (value["mean"], value["sd"]) if frame is None else (value["mean"][frame], value["sd"][frame])
    return f"{mean:.{digits}f} ± {sd:.{digits}f}"


def seeds_markdown(summary: Mapping[str, dict], runs: Sequence[str]) -> str:
    """Tables of :func:`seeds_summary`: conditioning, prediction at :data:`~dynamics.HORIZONS`, the difference to
    ZeroMotion and, for two-person samples, interpenetration, each cell ``mean ± sd`` over the runs."""
    horizon_header = ["| method | " + " | ".join(f"@{k}" for k in HORIZONS) + " |", "|---|" + "---|" * len(HORIZONS)]
    lines = [f"# Mean ± sample standard deviation over {len(runs)} training seeds", "",
             "Runs: " + ", ".join(f"`{run}`" for run in runs) + ".", ""]
    for group, result in summary.items():
        lines += [f"## {_GROUP_TITLES[group]} ({result['samples']} samples)", "", "### Conditioning", "",
                  "| method | " + " | ".join(_CONDITIONING.values()) + " |", "|---|" + "---|" * len(_CONDITIONING)]
        lines += [f"| {method} | " + " | ".join(mean_sd_cell(metrics[m], digits=digits(m))
                                                     for m in _CONDITIONING) + " |"
                  for method, metrics in result["conditioning"].items()]
        tables = [(f"Prediction: {title} at future frame", {method: metrics[metric]
                                                            for method, metrics in result["prediction"].items()}, 1)
                  for metric, title in _PREDICTION.items()]
        tables.append((f"MPJPE minus {_BASELINE}'s in the same run (mm; below zero: better than {_BASELINE})",
                       result["below_zero_motion"], 1))
        if "penetration" in result:
            tables.append(("Interpenetration: mean depth of a person's sampled vertices inside the other (mm) ↓",
                           result["penetration"], 2))
        for title, rows, decimals in tables:
            lines += ["", f"### {title}", "", *horizon_header]
            lines += [f"| {method} | " + " | ".join(mean_sd_cell(value, k - 1, decimals) for k in HORIZONS) + " |"
                      for method, value in rows.items()]
        lines.append("")
    return "\n".join(lines)

"""Mean and spread over training seeds: several runs of one evaluation (their ``results.json``), cell by cell, and
each forecaster's paired difference to ZeroMotion. :func:`seeds_summary` takes ``python -m experiments.dynamics``
runs (video), :func:`forecast_seeds_summary` ``python -m experiments.dynamics_forecast`` runs (3D).

The difference to ZeroMotion is taken within each run before it is averaged: the runs share the test renders (or
windows), so its spread is the seeds' effect on the comparison, not the test samples' (issue 26: "below ZeroMotion by
more than the spread over seeds")."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import jax
import numpy as np

from dynamics import HORIZONS
from experiments._stats import mean_and_sd

from ._forecast import BASELINES
from ._report import GROUP_TITLES, PENETRATION_TITLE, digits, markdown_table

__all__ = ["forecast_seeds_markdown", "forecast_seeds_summary", "seeds_markdown", "seeds_summary"]

_BASELINE = "ZeroMotion"
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
    _check_complete(results, "experiments.dynamics", lambda result: [
        f"summary.{group}.{part}" for group, summary in result["summary"].items()
        for part in ("samples", "conditioning", "prediction") if part not in summary] + [
        f"summary.{group}.prediction.{_BASELINE}.mpjpe" for group, summary in result["summary"].items()
        if "mpjpe" not in summary.get("prediction", {}).get(_BASELINE, {})])
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


def _check_complete(results: Sequence[Mapping], command: str, missing: Callable[[Mapping], list[str]]) -> None:
    """Refuse a run whose ``results.json`` lacks what the summary reads (``missing(result)``: the absent keys,
    dotted), by its number and the first keys, instead of a ``KeyError`` from inside (a file edited by hand, or
    written by an older version)."""
    for index, result in enumerate(results, start=1):
        absent = missing(result)
        if absent:
            raise ValueError(f"run {index}'s results.json lacks {', '.join(absent[:3])}: not as {command} writes it")


def mean_sd_cell(value: Mapping, frame: int | None = None, digits: int = 1) -> str:
    """``"mean ± sd"`` of a ``{"mean", "sd"}`` cell (at index ``frame`` of per-frame lists)."""
    mean, sd = (value["mean"], value["sd"]) if frame is None else (value["mean"][frame], value["sd"][frame])
    return f"{mean:.{digits}f} ± {sd:.{digits}f}"


def seeds_markdown(summary: Mapping[str, dict], runs: Sequence[str]) -> str:
    """Tables of :func:`seeds_summary`: conditioning, prediction at :data:`~dynamics.HORIZONS`, the difference to
    ZeroMotion and, for two-person samples, interpenetration, each cell ``mean ± sd`` over the runs."""
    lines = [f"# Mean ± sample standard deviation over {len(runs)} training seeds", "",
             "Runs: " + ", ".join(f"`{run}`" for run in runs) + ".", ""]
    for group, result in summary.items():
        lines.append(f"## {GROUP_TITLES[group]} ({result['samples']} samples)")
        lines += markdown_table("Conditioning", list(_CONDITIONING.values()), {
            method: [mean_sd_cell(metrics[m], digits=digits(m)) for m in _CONDITIONING]
            for method, metrics in result["conditioning"].items()}, level=3)
        tables = [(f"Prediction: {title} at future frame", {method: metrics[metric]
                                                            for method, metrics in result["prediction"].items()}, 1)
                  for metric, title in _PREDICTION.items()]
        tables.append((f"MPJPE minus {_BASELINE}'s in the same run (mm; below zero: better than {_BASELINE})",
                       result["below_zero_motion"], 1))
        if "penetration" in result:
            tables.append((f"{PENETRATION_TITLE} ↓", result["penetration"], 2))
        for title, rows, decimals in tables:
            lines += markdown_table(title, [f"@{k}" for k in HORIZONS], {
                method: [mean_sd_cell(value, k - 1, decimals) for k in HORIZONS] for method, value in rows.items()},
                level=3)
        lines.append("")
    return "\n".join(lines)


_FORECAST_PROTOCOL = ("fps", "observed_frames", "horizons_ms", "horizon_frames", "stride", "people", "windows")


def _file_names(result: Mapping) -> list[str]:
    """The scored files by name (a pair's two joined by ``+``): the same files read from another data folder are
    the same evaluation."""
    return ["+".join(Path(part).name for part in entry.split("+")) for entry in result["files"]]


def forecast_seeds_summary(results: Sequence[Mapping]) -> dict:
    """Of ``experiments.dynamics_forecast`` runs' ``results.json``, each a ``{"mean", "sd"}`` over the runs:
    ``mpjpe_mm`` (method, then action or pair, or ``"average"``: one value per horizon), ``mean_of_horizons_mm``
    (each method's average over actions, then over the horizons), ``below_zero_motion_percent`` (each forecaster's
    average MPJPE below ZeroMotion's in the same run, in % of ZeroMotion's, per horizon), ``differences_mm``
    (``"B - A"`` for every two forecasters, A first in the runs' order: B's average MPJPE minus A's in the same run,
    per horizon: an ablation's paired effect) and, for two-person runs, ``penetration_mm``; with the evaluation's
    protocol (frame rate, observed frames, horizons, windows).

    The runs must have scored the same files and windows with the same methods; a spread needs two."""
    if len(results) < 2:
        raise ValueError(f"a spread over seeds needs at least two runs, got {len(results)}")
    _check_complete(results, "experiments.dynamics_forecast", lambda result: [
        key for key in (*_FORECAST_PROTOCOL, "files", "mpjpe_mm") if key not in result] + [
        f"mpjpe_mm.{method}.average" for method, table in result.get("mpjpe_mm", {}).items()
        if "average" not in table] + ([f"mpjpe_mm.{_BASELINE}"] if _BASELINE not in result.get("mpjpe_mm", {}) else []))
    for index, result in enumerate(results[1:], start=2):
        differs = [key for key in _FORECAST_PROTOCOL if result[key] != results[0][key]]
        differs += ["files"] if _file_names(result) != _file_names(results[0]) else []
        if differs:
            raise ValueError(f"run {index} evaluated differently from run 1 ({', '.join(differs)} differ): runs of "
                             "one evaluation only")
        if list(result["mpjpe_mm"]) != list(results[0]["mpjpe_mm"]):
            raise ValueError(f"run {index} scored other methods than run 1 ({', '.join(result['mpjpe_mm'])} against "
                             f"{', '.join(results[0]['mpjpe_mm'])})")
    tables = [result["mpjpe_mm"] for result in results]
    methods = list(tables[0])
    summary = {key: results[0][key] for key in _FORECAST_PROTOCOL}
    summary["mpjpe_mm"] = {method: {group: mean_and_sd(*(table[method][group] for table in tables))
                                    for group in tables[0][method]} for method in methods}
    summary["mean_of_horizons_mm"] = {method: mean_and_sd(*(float(np.mean(table[method]["average"]))
                                                            for table in tables)) for method in methods}
    forecasters = [method for method in methods if method not in BASELINES]
    summary["below_zero_motion_percent"] = {
        method: mean_and_sd(*(100.0 * (1.0 - np.divide(table[method]["average"], table[_BASELINE]["average"]))
                              for table in tables))
        for method in forecasters}
    summary["differences_mm"] = {
        f"{second} - {first}": mean_and_sd(*(np.subtract(table[second]["average"], table[first]["average"])
                                             for table in tables))
        for index, first in enumerate(forecasters) for second in forecasters[index + 1:]}
    if "penetration_mm" in results[0]:
        summary["penetration_mm"] = {method: mean_and_sd(*(result["penetration_mm"][method] for result in results))
                                     for method in results[0]["penetration_mm"]}
    return summary


def forecast_seeds_markdown(summary: Mapping, runs: Sequence[str]) -> str:
    """Tables of :func:`forecast_seeds_summary`, each cell ``mean ± sd`` over the runs: the average over actions
    (pairs) with the mean of the horizons, the percentage below ZeroMotion, the differences between forecasters, every
    action (pair), interpenetration."""
    horizons = [f"{ms} ms" for ms in summary["horizons_ms"]]
    scores = summary["mpjpe_mm"]
    groups = "actions" if summary["people"] == 1 else "pairs"
    lines = [f"# Mean ± sample standard deviation over {len(runs)} training seeds", "",
             "Runs: " + ", ".join(f"`{run}`" for run in runs) + ".", "",
             f"MPJPE (mm, 24 body joints, pelvis aligned) at {summary['fps']:g} Hz after {summary['observed_frames']} "
             f"observed frames; windows every {summary['stride']} frames."]
    cells = lambda rows, decimals=1: {  # noqa: E731
        name: [mean_sd_cell(cell, k, decimals) for k in range(len(horizons))] for name, cell in rows.items()}
    average = cells({method: table["average"] for method, table in scores.items()})
    lines += markdown_table(f"Average over {groups} ({sum(summary['windows'].values())} windows)",
                            [*horizons, "mean of the horizons"],
                            {method: [*row, mean_sd_cell(summary["mean_of_horizons_mm"][method])]
                             for method, row in average.items()})
    lines += markdown_table(f"Below {_BASELINE} (%, of its MPJPE in the same run)", horizons,
                            cells(summary["below_zero_motion_percent"]))
    if summary["differences_mm"]:
        lines += markdown_table("Between forecasters (mm, one's MPJPE minus the other's in the same run)", horizons,
                                cells(summary["differences_mm"]))
    for group, count in summary["windows"].items():
        if count:
            lines += markdown_table(f"{group} ({count} windows)", horizons,
                                    cells({method: table[group] for method, table in scores.items()}))
    if "penetration_mm" in summary:
        lines += markdown_table(PENETRATION_TITLE, horizons, cells(summary["penetration_mm"], 2))
    return "\n".join(lines) + "\n"

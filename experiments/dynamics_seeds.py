"""Mean and spread over training seeds of ``python -m experiments.dynamics`` runs (video) or of ``python -m
experiments.dynamics_forecast`` runs (3D forecasting; issue 26: every table with at least three seeds).

    python -m experiments.dynamics --train --seed 1 --out runs/dynamics_s1   # one run per seed, then
    python -m experiments.dynamics_seeds --runs runs/dynamics_s0 runs/dynamics_s1 runs/dynamics_s2 --out runs/seeds

Reads each run's ``results.json`` (the runs must have evaluated alike: the same clips, test renders and windows, or
the same files and windows) and writes OUT/seeds.json, seeds.md and run.json, replacing OUT's previous outputs as a
whole: every cell as mean and sample standard deviation over the runs, and each forecaster's MPJPE against
ZeroMotion's taken within each run (video: the difference in mm; 3D: the percentage below it). Logic:
:mod:`experiments.dynamics_study`.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

from experiments import _cli
from experiments.dynamics_study import (forecast_seeds_markdown, forecast_seeds_summary, seeds_markdown,
                                       seeds_summary)


@dataclasses.dataclass(frozen=True)
class Config:
    runs: tuple[Path, ...]
    """Output folders of `python -m experiments.dynamics` or of `python -m experiments.dynamics_forecast` (all of
    one), one per training seed, each with its results.json."""
    out: Path
    """Output folder."""

    def __post_init__(self) -> None:
        if len(self.runs) < 2:
            raise ValueError(f"--runs needs at least two runs for a spread, got {len(self.runs)}")
        for run in self.runs:
            if not (run / "results.json").is_file():
                raise ValueError(f"--runs {run} holds no results.json (not an output folder of experiments.dynamics "
                                 "or experiments.dynamics_forecast)")


def main(config: Config) -> None:
    results = []
    for run in config.runs:
        try:
            results.append(json.loads((run / "results.json").read_text()))
        except json.JSONDecodeError as error:
            raise ValueError(f"{run / 'results.json'} is not JSON: {error}") from None
    kinds = [_kind(result, run) for result, run in zip(results, config.runs)]
    other = next((index for index, kind in enumerate(kinds) if kind != kinds[0]), None)
    if other is not None:
        raise ValueError(f"--runs mixes experiments.dynamics and experiments.dynamics_forecast runs ({kinds[0]}: "
                         f"{config.runs[0]}, {kinds[other]}: {config.runs[other]})")
    runs = [str(run) for run in config.runs]
    if kinds[0] == "forecast":
        summary = forecast_seeds_summary(results)
        written, report = {"runs": runs, "summary": summary}, forecast_seeds_markdown(summary, runs)
    else:
        summary = seeds_summary(results)
        written = {"runs": runs, "config": results[0]["config"], "summary": summary}
        report = seeds_markdown(summary, runs)
    with _cli.run_folder(config.out) as out:
        (out / "seeds.json").write_text(json.dumps(written, indent=1) + "\n")
        (out / "seeds.md").write_text(report)
    print(report)
    print(f"wrote {config.out}/seeds.json, seeds.md")


def _kind(result: dict, run: Path) -> str:
    """Which command wrote a ``results.json``: ``"video"`` (experiments.dynamics) or ``"forecast"``."""
    if "summary" in result and "config" in result:
        return "video"
    if "mpjpe_mm" in result and "horizons_ms" in result:
        return "forecast"
    raise ValueError(f"{run / 'results.json'} was written by neither experiments.dynamics nor "
                     "experiments.dynamics_forecast")


if __name__ == "__main__":
    _cli.run(main, Config, description=__doc__)

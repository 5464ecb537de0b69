"""Mean and spread over training seeds of ``python -m experiments.dynamics`` runs (issue 26: every table with at
least three seeds).

    python -m experiments.dynamics --train --seed 1 --out runs/dynamics_s1   # one run per seed, then
    python -m experiments.dynamics_seeds --runs runs/dynamics_s0 runs/dynamics_s1 runs/dynamics_s2 --out runs/seeds

Reads each run's ``results.json`` (the runs must have evaluated alike: the same clips, test renders and windows)
and writes OUT/seeds.json, seeds.md and run.json, replacing OUT's previous outputs as a whole: every cell as mean and
sample standard deviation over the runs, and each forecaster's MPJPE minus ZeroMotion's taken within each run.
Logic: :mod:`experiments.dynamics_study`.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

from experiments import _cli
from experiments.dynamics_study import seeds_markdown, seeds_summary


@dataclasses.dataclass(frozen=True)
class Config:
    runs: tuple[Path, ...]
    """Output folders of `python -m experiments.dynamics`, one per training seed, each with its results.json."""
    out: Path
    """Output folder."""

    def __post_init__(self) -> None:
        if len(self.runs) < 2:
            raise ValueError(f"--runs needs at least two runs for a spread, got {len(self.runs)}")
        for run in self.runs:
            if not (run / "results.json").is_file():
                raise ValueError(f"--runs {run} holds no results.json (not an experiments.dynamics output folder)")


def main(config: Config) -> None:
    results = []
    for run in config.runs:
        try:
            results.append(json.loads((run / "results.json").read_text()))
        except json.JSONDecodeError as error:
            raise ValueError(f"{run / 'results.json'} is not JSON: {error}") from None
    summary = seeds_summary(results)
    runs = [str(run) for run in config.runs]
    with _cli.run_folder(config.out) as out:
        (out / "seeds.json").write_text(json.dumps({"runs": runs, "config": results[0]["config"],
                                                    "summary": summary}, indent=1) + "\n")
        report = seeds_markdown(summary, runs)
        (out / "seeds.md").write_text(report)
    print(report)
    print(f"wrote {config.out}/seeds.json, seeds.md")


if __name__ == "__main__":
    _cli.run(main, Config, description=__doc__)

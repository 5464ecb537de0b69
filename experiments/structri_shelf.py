"""Structural Triangulation on the real Shelf detections: LS, LEM, Lagrangian, ST and ST* per camera count.

The learning-free pipeline's 5-view tracks re-triangulated from the OpenPose detections its consensus used, with
every combination of 2, 3, 4 and 5 of the views, scored against actorsGT on the test frames 300..600 (MPJPE, PCP,
bone-length error and spread, left/right symmetry, coverage, fallback rate); the protocol is in
:mod:`experiments.structri_study._shelf`. Needs the data folder (``--data-root`` or ``$MVMOCAP_DATA_ROOT`` holding
``shelf/``). About 1.5 minutes on 2 CPU cores, half of it the association; ``--quick``: frames 300..359 and 2 or
5 views, under a minute. Writes OUT/config.json, log.jsonl, results.json, results.md and run.json, replacing OUT's
previous outputs as a whole, and prints results.md. Logic: :mod:`experiments.structri_study`.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import mocap
from experiments import _cli
from experiments.structri_study import ShelfConfig, run_shelf

QUICK = dict(frames=60, view_counts=(2, 5))
"""What --quick changes."""


@dataclasses.dataclass(frozen=True)
class Config:
    out: Path
    """Output folder."""
    data_root: Path | None = None
    """Folder holding shelf/ (calibration, OpenPose detections, actorsGT; default: $MVMOCAP_DATA_ROOT)."""
    quick: bool = False
    """Frames 300..359 and camera counts 2 and 5 only."""

    def __post_init__(self) -> None:
        self.experiment()  # refuses a missing data folder or input file before the run starts

    def experiment(self) -> ShelfConfig:
        """The table's settings: the paper's, on the data folder found (:func:`mocap.find_data_root`)."""
        data_root = mocap.find_data_root(self.data_root, "shelf")
        if data_root is None:
            raise ValueError("no data folder: pass --data-root or set $MVMOCAP_DATA_ROOT (a folder with shelf/)")
        return ShelfConfig(str(data_root), **(QUICK if self.quick else {}))


def main(config: Config) -> None:
    with _cli.run_folder(config.out) as out:
        run_shelf(config.experiment(), out)
    print((config.out / "results.md").read_text())


if __name__ == "__main__":
    _cli.run(main, Config, description=__doc__, float64=True)

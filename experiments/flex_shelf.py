"""FLEX on the real Shelf detections, without extrinsics, beside DLT and Structural Triangulation with the exact
and with perturbed calibrations of the same detections (issue 25, item 3).

    python -m experiments.flex_shelf --data-root ../shared/data --out runs/flex_shelf

The people and their 2D per view come from the learning-free association (all 5 views, exact calibration, as
``experiments.structri_shelf`` runs it); every method then reconstructs the first four cameras' 2D of the matched
actor-frames of the test frames 300..600, scored against actorsGT after root alignment (MPJPE, PCP, limb lengths).
The protocol is in :mod:`experiments.flex_study._shelf`. The FLEX models are every 4-view early-fusion model of
``--model-dir`` (default: the shipped flex/assets): the random-rig ``flex_4views``, the fixed-rig models and
``flex_4views_shelf_detected`` where present. About 2 minutes on 2 CPU cores; ``--quick``: frames 300..359 and 2
perturbation draws. Writes OUT/config.json, results.json, results.md, log.jsonl and run.json, replacing OUT's
previous outputs as a whole, and prints results.md.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import mocap
from experiments import _cli
from experiments.flex_study import FlexShelfConfig, run_flex_shelf
from flex import DETECTION_MODELS, MAIN_MODEL, RIG_MODELS, SHIPPED_MODELS, load_models

QUICK = dict(frames=60, perturbation_draws=2)
"""What --quick changes."""
FLEX_MODELS = (MAIN_MODEL, *RIG_MODELS, *DETECTION_MODELS)
"""The 4-view early-fusion models the table reads, where --model-dir has them."""


@dataclasses.dataclass(frozen=True)
class Config:
    out: Path
    """Output folder."""
    data_root: Path | None = None
    """Folder holding shelf/ (calibration, OpenPose detections, actorsGT; default: $MVMOCAP_DATA_ROOT)."""
    model_dir: Path = SHIPPED_MODELS
    """Folder with one saved FLEX model per name (default: the shipped flex/assets)."""
    quick: bool = False
    """Frames 300..359 and 2 perturbation draws."""
    perturbation: float = 0.03
    """Relative standard deviation of the baselines' perturbed extrinsics (0.03: 3 %)."""
    seed: int = 0
    """Seed of the perturbation draws."""

    def __post_init__(self) -> None:
        if not self.model_dir.is_dir():
            raise ValueError(f"--model-dir {self.model_dir} is not a folder")
        self.experiment()  # refuses a missing data folder or input file, and bad options, before the run

    def experiment(self) -> FlexShelfConfig:
        data_root = mocap.find_data_root(self.data_root, "shelf")
        if data_root is None:
            raise ValueError("no data folder: pass --data-root or set $MVMOCAP_DATA_ROOT (a folder with shelf/)")
        return FlexShelfConfig(str(data_root), perturbation=self.perturbation, seed=self.seed,
                               **(QUICK if self.quick else {}))


def main(config: Config) -> None:
    experiment = config.experiment()
    models = {name: model for name, model in load_models(config.model_dir).items() if name in FLEX_MODELS}
    with _cli.run_folder(config.out) as out:
        (out / "config.json").write_text(json.dumps(dataclasses.asdict(experiment), indent=1))
        run_flex_shelf(experiment, models, out, log=_cli.jsonl_log(out))
    print((config.out / "results.md").read_text())


if __name__ == "__main__":
    _cli.run(main, Config, description=__doc__, float64=True)

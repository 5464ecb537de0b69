"""The JCSAT paper's ablations (Tables 6, 7 and 8) on synthetic validation scenes and on Shelf, as one table.

    python -m experiments.jcsat_ablations --data-root ../shared/data --out runs/ablations [--train]

Table 6: the views kept (5, 4, 3), candidate masking and the kinematic losses on and off; Table 7: the OTAP against
the non-selective aggregations (masked means) and the encoder size; Table 8: perturbed cameras (0-3, up to 0.25 cm
and 2.5 degrees). Every row gives PCP (%, VoxelPose / JCSAT protocol) of the model and of the learning-free
geometric baseline under the same setting on synthetic scenes of the held-out validation clips (one per --seeds),
and, with Shelf data, on the test frames 300-600 beside the 4D-association output.

The test-time rows (views, perturbed cameras) run the shipped model. The training rows need ``--train``: each
variant is trained from scratch as the ``--train-config`` run of ``jcsat.TRAIN_CONFIGS`` changed in one respect
(``jcsat_study.VARIANTS``), same seed, scenes and steps, into OUT/train (resumable: run the same command again after
a kill; a variant already trained is reused). On the 2-core CPU the ``cpu`` run takes about 36 minutes per variant,
so the full table is GPU work (``--train-config gpu --data-workers 16``). Writes OUT/ablations.md, ablations.json,
log.jsonl and run.json, replacing OUT's previous outputs as a whole (OUT/train is kept). Logic:
:func:`jcsat_study.run_ablations`.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Literal

import jcsat
import mocap
from experiments import _cli, jcsat_study

QUICK_TRAIN = dict(batch_size=2, steps=4, warmup_steps=1, checkpoint_interval=2, validation_interval=4, log_interval=2,
                   validation_windows=4)
"""--quick's training: a smoke run of every variant (2 scenes of 20 frames)."""


@dataclasses.dataclass(frozen=True)
class Config:
    out: Path = Path("runs/jcsat_ablations")
    """Output folder."""
    data_root: str | None = None
    """Folder with shelf/ (default: $MVMOCAP_DATA_ROOT); without one, only the synthetic columns."""
    tables: tuple[Literal["6", "7", "8"], ...] = ("6", "7", "8")
    """The paper's tables to run."""
    train: bool = False
    """Train the variants of the training rows (else those rows are left out and listed as not run)."""
    train_config: Literal[tuple(sorted(jcsat.TRAIN_CONFIGS))] = "cpu"  # type: ignore[valid-type]
    """The base run of the training rows (jcsat.TRAIN_CONFIGS)."""
    steps: int | None = None
    """Optimisation steps of every variant (default: the base run's)."""
    data_workers: int = 1
    """Processes that build the training scenes when they are not cached."""
    seeds: tuple[int, ...] = (101, 102, 103)
    """One synthetic validation scene per seed (clips jcsat.VALIDATION_CLIPS; 150 frames of 4 people)."""
    quick: bool = False
    """Synthetic scenes of 40 frames of 3 people, the first 60 Shelf frames, 4 training steps on 2 small scenes."""
    seed: int = 0
    """Training seed of every variant."""

    def __post_init__(self) -> None:
        if not self.tables:
            raise ValueError("--tables names no table")
        if not self.seeds:
            raise ValueError("--seeds needs at least one seed")
        if self.steps is not None and self.steps < 2:
            raise ValueError(f"--steps must be >= 2 (a warm-up step and a decay step), got {self.steps}")
        if self.data_workers < 1:
            raise ValueError(f"--data-workers must be >= 1, got {self.data_workers}")
        if self.data_root is not None and mocap.find_data_root(self.data_root, "shelf") is None:
            raise ValueError(f"--data-root {self.data_root} holds no shelf/")

    def base_run(self) -> jcsat.TrainConfig:
        """The training rows' base run from scratch (no ``init_model``) with the command's seed, --steps and --quick."""
        base = dataclasses.replace(jcsat.TRAIN_CONFIGS[self.train_config], seed=self.seed, init_model=None)
        if self.quick:
            small = dict(num_scenes=2, num_frames=20)
            base = dataclasses.replace(base, **QUICK_TRAIN, data=dataclasses.replace(base.data, **small),
                                       validation_data=dataclasses.replace(base.validation_data, num_scenes=1,
                                                                           num_frames=20))
        if self.steps is not None:
            base = base.with_steps(self.steps)
        return base


def main(config: Config) -> None:
    data_root = mocap.find_data_root(config.data_root, "shelf")
    chosen = [row for row in jcsat_study.ABLATION_ROWS if row.table in config.tables]
    rows = tuple(row for row in chosen if config.train or row.variant == jcsat_study.SHIPPED)
    left_out = [row.name for row in chosen if row not in rows]
    with (_cli.run_folder(config.out, keep=("train",)) as out,
          _cli.stages(out, "jcsat_ablations", [row.name for row in rows]) as (log, progress)):
        study = jcsat_study.run_ablations(rows, out, workdir=config.out / "train", base=config.base_run(),
                                          data_root=None if data_root is None else str(data_root), seeds=config.seeds,
                                          quick=config.quick, data_workers=config.data_workers, log=log,
                                          progress=progress)
        study["not_run"] = left_out
        table = jcsat_study.ablation_table(study)
        if left_out:
            table += f"\nNot run (they need --train): {', '.join(left_out)}.\n"
        (out / "ablations.json").write_text(json.dumps(study, indent=1) + "\n")
        (out / "ablations.md").write_text(table)
    print(table)
    print(f"wrote {config.out}/ablations.md, ablations.json")


if __name__ == "__main__":
    _cli.run(main, Config, description=__doc__, float64=True)

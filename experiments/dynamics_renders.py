"""Which motion to render (``DataConfig.clips``), how many videos per training clip (``DataConfig.renders``), how to
mirror them (``DataConfig.redraw_flips``), how the backbone pools its last map (``BackboneConfig.pooling``), how much
dropout the HMR head trains with (``PHDTConfig.hmr_dropout``) and how many steps to train the conditioning stage
(``TrainConfig.image.steps``), chosen on validation: the conditioning stage (the crop backbone and HMR head, the first
stage of ``python -m experiments.dynamics --train``, whose networks give the conditioning error and the root) trained
for each candidate (motion, renders, mirrors, pooling, head dropout, steps) with each seed, and scored per clip on fresh
validation renders of training clips (new cameras and shapes; never a test clip) and, with ``--data-root``, on renders
of held-out motion (the CMU-Mocap benchmark's validation files, ``dynamics.forecast_split``, which no candidate trains
on).

    python -m experiments.dynamics_renders --out runs/dynamics_renders --data-workers 2
    python -m experiments.dynamics_renders --out runs/dynamics_steps --renders 16 --steps 2000 8000 --data-workers 2
    python -m experiments.dynamics_renders --out runs/dynamics_motion --motion shipped benchmark --renders 16 4 \\
        --data-root ../shared/data --data-workers 2
    python -m experiments.dynamics_renders --out runs/dynamics_flips --renders 16 --flips pixels redraw \\
        --data-root ../shared/data --data-workers 2
    python -m experiments.dynamics_renders --out runs/dynamics_pooling --renders 16 --pooling mean flatten \\
        --data-root ../shared/data --data-workers 2
    python -m experiments.dynamics_renders --out runs/dynamics_dropout --renders 16 --hmr-dropout 0.5 0 \\
        --data-root ../shared/data --data-workers 2

Writes OUT/results.json, results.md, log.jsonl and run.json, replacing OUT's previous outputs as a whole; the
trainings are resumable in OUT/train (run the same command again after a kill). Logic:
:mod:`experiments.dynamics_study`.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Literal

import geometry
from dynamics import VALIDATION_DATA, Pooling, TrainConfig, forecast_split
from experiments import _cli
from experiments.dynamics import training_configs
from experiments.dynamics_study import Flips, run_renders_study


@dataclasses.dataclass(frozen=True)
class Config:
    out: Path
    """Output folder."""
    motion: tuple[Literal["shipped", "benchmark"], ...] = ("shipped",)
    """Candidate training motion: shipped, the shipped training clips (dynamics.TRAIN_CLIPS, about 1250 frames at 30
    Hz); benchmark, those and the CMU-Mocap benchmark's training files (dynamics.forecast_split, about 11 000 frames
    more; needs --data-root)."""
    renders: tuple[int, ...] = (2, 4, 8)
    """Candidate videos per training clip (the shipped models: 16, chosen by this study; 8 and 2 before). With
    several motions, one count per motion, in order (a motion's videos per clip, not a grid)."""
    flips: tuple[Flips, ...] | None = None
    """Candidate ways of making the mirrored training variants: redraw, the mirrored people rendered anew, so that the
    renders' left and right part colours follow the mirrored labels (the recipe since 2026-12-07,
    dynamics.DataConfig.redraw_flips); pixels, the rendered frames mirrored (the recipe before). Default: the
    recipe's."""
    pooling: tuple[Pooling, ...] | None = None
    """Candidate ways for the backbone to turn its last feature map into features: flatten, the whole map, which keeps
    where in the crop each feature fired (the recipe since 2026-12-07, dynamics.TrainConfig().backbone); mean, the
    average over positions (ResNet's, the recipe before). Default: the recipe's."""
    hmr_dropout: tuple[float, ...] | None = None
    """Candidate dropout rates of the HMR head's two hidden layers in training (dynamics.PHDTConfig.hmr_dropout).
    Default: the recipe's (0.5, HMR's)."""
    steps: tuple[int, ...] | None = None
    """Candidate steps of the conditioning stage (default: the recipe's, dynamics.TrainConfig().image.steps)."""
    seeds: tuple[int, ...] = (0, 1, 2)
    """Training seeds per candidate."""
    validation_renders: int = 3
    """Fresh videos per validation clip (dynamics.VALIDATION_DATA's clips and seed): the camera distances scored;
    one per held-out file."""
    data_root: Path | None = None
    """Folder holding cmu_expmap/ (the CMU-Mocap benchmark): the benchmark motion and the held-out validation."""
    quick: bool = False
    """A smoke run: the quick training of experiments.dynamics (a few steps, two clips), one validation render."""
    data_workers: int = 1
    """CPU processes that render the videos (the same frames as one)."""
    progress: bool = True
    """Progress bars."""

    def __post_init__(self) -> None:
        for option, values in (("--motion", self.motion), ("--renders", self.renders), ("--flips", self.flips),
                               ("--pooling", self.pooling), ("--hmr-dropout", self.hmr_dropout),
                               ("--steps", self.steps), ("--seeds", self.seeds)):
            if values is not None and (not values or len(set(values)) != len(values)):
                raise ValueError(f"{option} needs distinct values, got {list(values)}")
        if min(self.renders) < 1 or self.validation_renders < 1 or self.data_workers < 1:
            raise ValueError("--renders, --validation-renders and --data-workers must be >= 1")
        if len(self.motion) > 1 and len(self.renders) != len(self.motion):
            raise ValueError(f"--motion {' '.join(self.motion)} needs one --renders count per motion, got "
                             f"{list(self.renders)}")
        if "benchmark" in self.motion and self.data_root is None:
            raise ValueError("--motion benchmark needs --data-root (the folder holding cmu_expmap/)")
        warmup = TrainConfig().image.warmup_steps
        if self.hmr_dropout and not all(0 <= rate < 1 for rate in self.hmr_dropout):
            raise ValueError(f"--hmr-dropout rates must be in [0, 1), got {list(self.hmr_dropout)}")
        if self.steps and min(self.steps) <= warmup:
            raise ValueError(f"--steps must exceed the stage's {warmup} warm-up steps, got {list(self.steps)}")


def main(config: Config) -> None:
    base, _ = training_configs("small", 0, config.quick, None)
    validation = dataclasses.replace(VALIDATION_DATA, renders=1 if config.quick else config.validation_renders)
    held_out, motions = None, {"shipped": base.data.clips}
    if config.data_root is not None:
        training_files, validation_files = forecast_split(config.data_root)
        held_out = dataclasses.replace(validation, clips=validation_files[:1] if config.quick else validation_files,
                                       renders=1)
        motions["benchmark"] = base.data.clips + (training_files[:1] if config.quick else training_files)
    candidates = ([(config.motion[0], count) for count in config.renders] if len(config.motion) == 1
                  else list(zip(config.motion, config.renders)))  # one renders count per motion
    workdir = config.out / "train"  # in place, not staged: a killed run resumes from its checkpoints
    with _cli.run_folder(config.out, keep=("train",)) as out:
        results = run_renders_study(out, workdir, base, {m: motions[m] for m in config.motion}, candidates,
                                    config.steps or (base.image.steps,), config.seeds, validation,
                                    geometry.stand_in_body_model(), held_out=held_out, flips=config.flips,
                                    poolings=config.pooling, dropouts=config.hmr_dropout, log=_cli.jsonl_log(out),
                                    progress=config.progress, data_workers=config.data_workers)
        report = (out / "results.md").read_text()
    print(report)
    print(f"wrote {config.out}/results.json, results.md ({results['seconds']} s)")


if __name__ == "__main__":
    _cli.run(main, Config, description=__doc__)

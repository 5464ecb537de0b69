"""3D forecasting on the CMU-Mocap benchmark's motion: the thesis' autoregressive models (PHD+T's f_JE/f_AR path,
JAT, JAT without the Joint-Aware Bias) conditioned on observed 3D poses, against ZeroMotion and constant velocity.

    python -m experiments.dynamics_forecast --data-root ../shared/data --out runs/forecast

Motion: ``<data-root>/cmu_expmap`` at 25 Hz on the body model's 24 joints (:mod:`dynamics._poses`); 25 frames
observed (1 s), 25 predicted, scored at 80, 160, 320, 400 and 1000 ms per action. ``--split test`` (default)
scores the benchmark's test files; ``--split validation`` the training files kept out of training (one per
action), where every choice is made. Without ``--train`` it evaluates the models shipped in
``dynamics/assets/forecasters`` (or ``--model-dir``); ``--train`` first trains the three into ``OUT/train`` on the
rest of the train split (resumable: run the same command again after a kill), which is how the shipped ones were
made. Writes OUT/results.json, results.md, forecast.png, log.jsonl and run.json, replacing OUT's previous outputs
as a whole (``OUT/train`` is kept). Logic: :mod:`experiments.dynamics_study`.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Literal

import geometry
import mocap
from dynamics import (FORECASTERS, SHIPPED_FORECASTERS, ForecastTrainConfig, StageConfig, forecast_split,
                      load_forecasters, train_forecasters)
from experiments import _cli
from experiments.dynamics_study import run_forecast_study

QUICK_STRIDE = 25
QUICK_TRAIN = dict(stage=StageConfig(steps=10, batch_size=4, learning_rate=5e-4, warmup_steps=2), speeds=(1.0,),
                   checkpoint_interval=5, validation_interval=10, log_interval=5)


@dataclasses.dataclass(frozen=True)
class Config:
    out: Path
    """Output folder."""
    data_root: Path | None = None
    """Folder holding cmu_expmap/ (default: $MVMOCAP_DATA_ROOT)."""
    split: Literal["test", "validation"] = "test"
    """test: the benchmark's test files; validation: one training file per action, never trained on."""
    train: bool = False
    """Train the three forecasters into OUT/train (resumable) instead of using the shipped ones."""
    train_steps: int | None = None
    """With --train: steps per model (default: dynamics.ForecastTrainConfig's 1000)."""
    train_batch: int | None = None
    """With --train: windows per step (default: dynamics.ForecastTrainConfig's 32)."""
    train_names: tuple[str, ...] = tuple(FORECASTERS)
    """With --train: the forecasters to train and score (default: all of dynamics.FORECASTERS)."""
    train_speeds: tuple[float, ...] = ForecastTrainConfig.speeds
    """With --train: playback speeds of the training motion (augmentation; 1: as recorded)."""
    train_mirror: bool = ForecastTrainConfig.mirror
    """With --train: also train on the mirrored motion (left and right swapped; augmentation)."""
    train_decode_from: Literal["previous", "extrapolated"] | None = None
    """With --train: where f_HMR starts each predicted frame, the previous pose or the previous pose moved on by
    its last step (default: each forecaster's own in dynamics.FORECASTERS)."""
    train_extrapolation: float | None = None
    """With --train: the fraction of its last step the previous pose is moved on by when decoding from the
    extrapolated pose, in [0, 1] (default: each forecaster's own)."""
    model_dir: Path = SHIPPED_FORECASTERS
    """Folder with the forecasters (default: the shipped dynamics/assets/forecasters)."""
    quick: bool = False
    """Windows every 25 frames instead of every 10; with --train, 10 steps per model on the motion at its recorded
    speed (a smoke run)."""
    seed: int = 0
    """Training seed (with --train)."""
    progress: bool = True
    """Progress bars."""

    def __post_init__(self) -> None:
        if mocap.find_data_root(self.data_root, "cmu_expmap") is None:
            raise ValueError("no data folder: pass --data-root or set $MVMOCAP_DATA_ROOT (a folder with cmu_expmap/)")
        if not self.train and not self.model_dir.is_dir():
            raise ValueError(f"--model-dir {self.model_dir} is not a folder")
        for name in ("train_steps", "train_batch"):
            if getattr(self, name) is not None and getattr(self, name) < 1:
                raise ValueError(f"--{name.replace('_', '-')} must be >= 1, got {getattr(self, name)}")
        if self.train_extrapolation is not None and not 0.0 <= self.train_extrapolation <= 1.0:
            raise ValueError(f"--train-extrapolation must be in [0, 1], got {self.train_extrapolation}")
        if not self.train_speeds or min(self.train_speeds) <= 0:
            raise ValueError(f"--train-speeds must be positive, got {self.train_speeds}")
        unknown = sorted(set(self.train_names) - set(FORECASTERS))
        if unknown or not self.train_names:
            raise ValueError(f"--train-names must name forecasters of {sorted(FORECASTERS)}, got {unknown}")

    def train_config(self, files: tuple[str, ...], validation_files: tuple[str, ...]) -> ForecastTrainConfig:
        """The training run --train makes (before each forecaster's ``model`` is set)."""
        config = ForecastTrainConfig(files, validation_files, speeds=self.train_speeds, mirror=self.train_mirror,
                                     seed=self.seed)
        if self.quick:
            return dataclasses.replace(config, **QUICK_TRAIN)
        stage = dataclasses.replace(config.stage, **{name: value for name, value in (
            ("steps", self.train_steps), ("batch_size", self.train_batch)) if value is not None})
        return dataclasses.replace(config, stage=stage)

    def model_changes(self) -> dict:
        """What --train changes in every forecaster's model config."""
        return {name: value for name, value in (("decode_from", self.train_decode_from),
                                                ("extrapolation", self.train_extrapolation)) if value is not None}


def main(config: Config) -> None:
    body = geometry.stand_in_body_model()
    training_files, validation_files = forecast_split(config.data_root)
    files = (validation_files if config.split == "validation"
             else tuple(str(f) for f in mocap.cmu_expmap_files(config.data_root, "test")))
    workdir = config.out / "train"  # in place, not staged: a killed run resumes from its checkpoints
    with _cli.run_folder(config.out, keep=("train",)) as out:
        log = _cli.jsonl_log(out)
        if config.train:
            models = train_forecasters(config.train_config(training_files, validation_files), workdir, body,
                                       names=config.train_names, model_changes=config.model_changes(),
                                       resume=True, log=log, progress=config.progress)
        else:
            models = load_forecasters(config.model_dir)
        summary = run_forecast_study(out, models, body, files, stride=QUICK_STRIDE if config.quick else 10,
                                     cache_dir=workdir / "data_cache" if config.train else None, log=log,
                                     progress=config.progress)
        report = (out / "results.md").read_text()
    print(report)
    print(f"wrote {config.out}/results.json, results.md, forecast.png ({summary['seconds']} s)")


if __name__ == "__main__":
    _cli.run(main, Config, description=__doc__)

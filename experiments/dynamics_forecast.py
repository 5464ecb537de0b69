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

``--pairs``: scenes of two people, the CMU salsa pairs of ``<data-root>/cmu_mocap`` (``dynamics.pair_split``):
JAT, MPJAT and MPJAT without the interpenetration loss (``dynamics.PAIR_FORECASTERS``, shipped in
``dynamics/assets/forecasters/pairs``) and the single-person JAT they start from (``--start-from``), scored on the
test pair 60_05+61_05 (``--split test``) or on the last 30 % of the training pair 60_03+61_03 (``--split
validation``), with the interpenetration of every forecast. ``--train`` fine-tunes the three from ``--start-from``
on the rest of the training pair.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Literal

import geometry
import mocap
from dynamics import (FORECASTERS, PAIR_FORECASTERS, SHIPPED_FORECASTERS, ForecastTrainConfig,
                      StageConfig, forecast_split, load_forecaster, load_forecasters, pair_split, train_forecasters,
                      train_pair_forecasters)
from experiments import _cli
from experiments.dynamics_study import run_forecast_study

QUICK_STRIDE = 25
PAIR_TRAIN = dict(people=2, validation_tail=0.3,
                  stage=StageConfig(steps=300, batch_size=16, learning_rate=1e-4, warmup_steps=30),
                  checkpoint_interval=50, validation_interval=50, log_interval=10)
"""The pair forecasters' fine-tuning (``--pairs --train``): from a trained JAT, at a fifth of its learning rate,
unclipped and unaveraged, with ``ForecastTrainConfig``'s losses (the 3D-joint term on distances, chosen for the pairs
on the training pair's validation tail on 2026-12-03: docs/dynamics.md, "The pair fine-tuning on distances")."""
QUICK_TRAIN = dict(stage=StageConfig(steps=10, batch_size=4, learning_rate=5e-4, warmup_steps=2), speeds=(1.0,),
                   checkpoint_interval=5, validation_interval=10, log_interval=5)


@dataclasses.dataclass(frozen=True)
class Config:
    out: Path
    """Output folder."""
    data_root: Path | None = None
    """Folder holding cmu_expmap/ (default: $MVMOCAP_DATA_ROOT)."""
    split: Literal["test", "validation"] = "test"
    """test: the benchmark's test files; validation: one training file per action, never trained on (with --pairs:
    the test pair; the training pair's last 30 %)."""
    pairs: bool = False
    """Scenes of two people: the salsa pairs and the pair forecasters (module docstring)."""
    train: bool = False
    """Train the three forecasters into OUT/train (resumable) instead of using the shipped ones."""
    train_steps: int | None = None
    """With --train: steps per model (default: dynamics.ForecastTrainConfig's 2000; with --pairs 300)."""
    train_batch: int | None = None
    """With --train: windows per step (default: dynamics.ForecastTrainConfig's 32; with --pairs 16)."""
    train_lr: float | None = None
    """With --train: the peak learning rate (default: dynamics.ForecastTrainConfig's 5e-4; with --pairs 1e-4)."""
    train_clip_norm: float | None = None
    """With --train: clip the gradients to this global norm before Adam, 0: not at all (dynamics.StageConfig.clip_norm;
    default: dynamics.ForecastTrainConfig's 500, with --pairs none)."""
    train_average_decay: float | None = None
    """With --train: validate and keep a moving average of the parameters with this decay per step, in (0, 1), 0: the
    parameters themselves (dynamics.StageConfig.average_decay; default: dynamics.ForecastTrainConfig's 0.995, with
    --pairs none)."""
    train_joint_error: Literal["squared", "distance"] | None = None
    """With --train: the 3D-joint loss on half the squared error of every coordinate, or on every joint's distance
    (MPJPE; dynamics.LossWeights.joints_3d_error; default: dynamics.ForecastTrainConfig's distance, with --pairs
    too)."""
    train_width: int = 1
    """With --train: every width of the forecasters' networks this many times larger (dynamics.ForecasterConfig.widened;
    2 gives PHD+T the video model's sizes)."""
    train_names: tuple[str, ...] | None = None
    """With --train: the forecasters to train and score (default: all of dynamics.FORECASTERS, with --pairs of
    dynamics.PAIR_FORECASTERS)."""
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
    model_dir: Path | None = None
    """Folder with the forecasters (default: the shipped dynamics/assets/forecasters, with --pairs its pairs/)."""
    start_from: Path = SHIPPED_FORECASTERS / "jat"
    """With --pairs: the single-person JAT the pair forecasters start from (--train) and that is scored beside
    them."""
    quick: bool = False
    """Windows every 25 frames instead of every 10; with --train, 10 steps per model on the motion at its recorded
    speed (a smoke run)."""
    seed: int = 0
    """Training seed (with --train)."""
    progress: bool = True
    """Progress bars."""

    def __post_init__(self) -> None:
        needs = "cmu_mocap" if self.pairs else "cmu_expmap"  # the salsa pairs, or the benchmark's motion
        if mocap.find_data_root(self.data_root, needs) is None:
            raise ValueError(f"no data folder: pass --data-root or set $MVMOCAP_DATA_ROOT (a folder with {needs}/)")
        if not self.train and not self.models.is_dir():
            raise ValueError(f"--model-dir {self.models} is not a folder")
        if self.pairs and (self.model_changes() or self.train_width != 1):
            raise ValueError("--train-decode-from, --train-extrapolation and --train-width change the single-person "
                             "forecasters; the pair forecasters are the JAT they start from")
        if self.pairs and not self.start_from.is_dir():
            raise ValueError(f"--start-from {self.start_from} is not a folder")
        if self.train_lr is not None and not self.train_lr > 0:
            raise ValueError(f"--train-lr must be positive, got {self.train_lr}")
        if self.train_clip_norm is not None and not self.train_clip_norm >= 0:
            raise ValueError(f"--train-clip-norm must be >= 0 (0: no clipping), got {self.train_clip_norm}")
        if self.train_joint_error not in (None, "squared", "distance"):
            raise ValueError(f"--train-joint-error must be squared or distance, got {self.train_joint_error!r}")
        if self.train_average_decay is not None and not 0 <= self.train_average_decay < 1:
            raise ValueError(f"--train-average-decay must be in [0, 1) (0: no average), got {self.train_average_decay}")
        for name in ("train_steps", "train_batch", "train_width"):
            if getattr(self, name) is not None and getattr(self, name) < 1:
                raise ValueError(f"--{name.replace('_', '-')} must be >= 1, got {getattr(self, name)}")
        if self.train_extrapolation is not None and not 0.0 <= self.train_extrapolation <= 1.0:
            raise ValueError(f"--train-extrapolation must be in [0, 1], got {self.train_extrapolation}")
        if not self.train_speeds or min(self.train_speeds) <= 0:
            raise ValueError(f"--train-speeds must be positive, got {self.train_speeds}")
        unknown = sorted(set(self.names) - set(self.table))
        if unknown or not self.names:
            raise ValueError(f"--train-names must name forecasters of {sorted(self.table)}, got {unknown}")

    @property
    def table(self) -> dict:
        """The forecasters this run trains or loads, by name."""
        return PAIR_FORECASTERS if self.pairs else FORECASTERS

    @property
    def names(self) -> tuple[str, ...]:
        """The forecasters --train trains."""
        return tuple(self.table) if self.train_names is None else self.train_names

    @property
    def models(self) -> Path:
        """The folder the forecasters are loaded from."""
        if self.model_dir is not None:
            return self.model_dir
        return SHIPPED_FORECASTERS / "pairs" if self.pairs else SHIPPED_FORECASTERS

    def train_config(self, files: tuple[str, ...], validation_files: tuple[str, ...]) -> ForecastTrainConfig:
        """The training run --train makes (before each forecaster's ``model`` is set); with --pairs, ``files`` is
        the training pair and ``validation_files`` empty."""
        config = ForecastTrainConfig(files, validation_files, speeds=self.train_speeds, mirror=self.train_mirror,
                                     seed=self.seed, **(PAIR_TRAIN if self.pairs else {}))
        if self.pairs:
            config = dataclasses.replace(config, start_from=str(self.start_from.resolve()))
        if self.train_joint_error is not None:
            config = dataclasses.replace(config, losses=dataclasses.replace(config.losses,
                                                                            joints_3d_error=self.train_joint_error))
        if self.quick:
            return dataclasses.replace(config, **QUICK_TRAIN)
        changes = {name: value for name, value in (
            ("steps", self.train_steps), ("batch_size", self.train_batch), ("learning_rate", self.train_lr),
            ("clip_norm", self.train_clip_norm), ("average_decay", self.train_average_decay)) if value is not None}
        for name in ("clip_norm", "average_decay"):
            if changes.get(name) == 0:  # the option's 0, StageConfig's None
                changes[name] = None
        return dataclasses.replace(config, stage=dataclasses.replace(config.stage, **changes))

    def model_changes(self) -> dict:
        """What --train changes in every forecaster's model config."""
        return {name: value for name, value in (("decode_from", self.train_decode_from),
                                                ("extrapolation", self.train_extrapolation)) if value is not None}


def main(config: Config) -> None:
    body = geometry.stand_in_body_model()
    workdir = config.out / "train"  # in place, not staged: a killed run resumes from its checkpoints
    if config.pairs:
        training_pair, test_pair = pair_split(config.data_root)
        training_files, validation_files = (training_pair,), ()
        scored = (training_pair,) if config.split == "validation" else (test_pair,)
    else:
        training_files, validation_files = forecast_split(config.data_root)
        scored = (validation_files if config.split == "validation"
                  else tuple(str(f) for f in mocap.cmu_expmap_files(config.data_root, "test")))
    with _cli.run_folder(config.out, keep=("train",)) as out:
        log = _cli.jsonl_log(out)
        train = train_pair_forecasters if config.pairs else train_forecasters
        if config.train:
            models = train(config.train_config(training_files, validation_files), workdir, body,
                           names=config.names, resume=True, log=log, progress=config.progress,
                           **({} if config.pairs else {"model_changes": config.model_changes(),
                                                       "width": config.train_width}))
        else:
            models = load_forecasters(config.models, config.table)
        if config.pairs:
            models = {"JAT (one person)": load_forecaster(config.start_from)} | models
        summary = run_forecast_study(out, models, body, scored, people=2 if config.pairs else 1,
                                     stride=QUICK_STRIDE if config.quick else 10,
                                     cache_dir=workdir / "data_cache" if config.train else None, log=log,
                                     progress=config.progress)
        report = (out / "results.md").read_text()
    print(report)
    print(f"wrote {config.out}/results.json, results.md, forecast.png ({summary['seconds']} s)")


if __name__ == "__main__":
    _cli.run(main, Config, description=__doc__)

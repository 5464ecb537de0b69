"""Multi-person 3D pose on Shelf with JCSAT (the project's main job).

With no options it runs the shipped JCSAT model (``jcsat/assets/shelf_wide_4da``, trained only on synthetic
scenes) beside the learning-free geometric baseline. With Shelf data (``--data-root`` or ``$MVMOCAP_DATA_ROOT``
holding ``shelf/``) it infers on the real test frames 300..600 with sliding windows of N = 10 frames
(``--aggregate``) and prints PCP (VoxelPose, JCSAT and 4D-association protocols), precision/recall and MPJPE
next to the 4D-association output scored by the same evaluator; without data it runs on a seeded synthetic
Shelf-rig scene and says so. Writes ``config.json``, ``log.jsonl``, ``predictions.jsonl`` (``mocap``
prediction format, ``python -m experiments.shelf_eval --pred``), ``predictions_geometric.jsonl``,
``metrics.json``, ``frame.png`` and ``run.json`` to ``--out``, replacing its previous outputs as a whole.

``--train`` first trains a model on synthetic scenes (:func:`jcsat.train`: from scratch, or from the run's
``init_model``; workdir ``OUT/train``, kept in place; ``--resume`` continues a killed run from its last
checkpoint) and then evaluates it. The old short options ``--structural-steps``, ``--max-bone-deviation``,
``--outlier-half-window`` and ``--outlier-distance`` still work (see ``--baseline.*``).
Logic: :func:`jcsat_study.run_shelf_experiment`, :func:`jcsat.train`.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Literal

import jcsat
import mocap
from experiments import _cli, jcsat_study

_STAGES = ("data", "method", "evaluation", "plot")

ALIASES = {"--structural-steps": "--baseline.geometric.structural-steps",
           "--max-bone-deviation": "--baseline.geometric.max-bone-deviation",
           "--outlier-half-window": "--baseline.outlier-half-window",
           "--outlier-distance": "--baseline.outlier-distance"}
"""Options of the hand-written command line that live in the baseline's config now."""


@dataclasses.dataclass(frozen=True)
class Config(jcsat_study.ShelfExperimentConfig):
    """The experiment's options (:class:`jcsat_study.ShelfExperimentConfig`) and the run's."""

    out: Path = Path("runs/shelf_jcsat")
    """Output folder."""
    train: bool = False
    """Train a model into OUT/train on synthetic scenes (from scratch, or from the --config run's init_model),
    then evaluate it."""
    resume: bool = False
    """With --train: continue from OUT/train's last checkpoint."""
    config: Literal[tuple(sorted(jcsat.TRAIN_CONFIGS))] = "cpu"  # type: ignore[valid-type]
    """With --train: the named run in jcsat.TRAIN_CONFIGS. cpu: the 'cpu' model, 2400 steps of 8 windows on 16
    scenes (the 2-core CPU's run); gpu: the 'cpu_wide' model, 6000 steps of 64 windows on 48 scenes;
    cpu_head_4da: the shipped model's second stage, 500 steps of 16 windows fine-tuning the gpu run's model on
    labels with the 4D-association head rule; gpu_expmap: the shipped model continued for 3000 steps of 64 windows
    on 96 scenes (with --train-expmap); gpu_medium: the paper's Medium model from scratch, 40000 steps of 8
    windows on 96 scenes."""
    steps: int | None = None
    """With --train: optimisation steps (default: the --config run's)."""
    data_workers: int = 1
    """With --train: processes that build the synthetic scenes when they are not cached."""
    train_expmap: bool = False
    """With --train: the scenes also draw people from the CMU-Mocap benchmark's train split (DATA/cmu_expmap/train,
    8 actions, in the data folder of --data-root) beside the --config run's clips; its test split never enters
    training."""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.model is not None and not Path(self.model).is_dir():
            raise ValueError(f"--model {self.model} is not a folder")
        if self.train and self.model is not None:
            raise ValueError("--model and --train exclude each other: --train evaluates the model it trains")
        if self.resume and not self.train:
            raise ValueError("--resume needs --train")
        if self.steps is not None and self.steps < 1:
            raise ValueError(f"--steps must be >= 1, got {self.steps}")
        if self.data_workers < 1:
            raise ValueError(f"--data-workers must be >= 1, got {self.data_workers}")
        if self.train_expmap and not self.train:
            raise ValueError("--train-expmap needs --train")
        if self.train_expmap:
            self.expmap_clips()  # a missing cmu_expmap folder is refused before any work
        mocap.find_data_root(self.data_root, "shelf")


    def expmap_clips(self) -> tuple[str, ...]:
        """The CMU-Mocap benchmark's train files (absolute paths, so the dataset cache key does not depend on the
        working folder)."""
        return _cli.expmap_clips(self.data_root, "train")


def train_config(config: Config) -> jcsat.TrainConfig:
    """The run ``--train`` makes: the --config run with the command's seed, clips, --quick and --steps."""
    train_config = dataclasses.replace(jcsat.TRAIN_CONFIGS[config.config], seed=config.seed)
    if config.train_expmap:
        data = train_config.data
        train_config = dataclasses.replace(train_config, data=dataclasses.replace(
            data, clips=data.clips + config.expmap_clips()))
    if config.quick:
        train_config = dataclasses.replace(train_config, steps=300, warmup_steps=30, checkpoint_interval=100,
                                           validation_interval=100,
                                           data=dataclasses.replace(train_config.data, num_scenes=4))
    if config.steps is not None:
        train_config = train_config.with_steps(config.steps)
    return train_config


def _train(config: Config) -> Path:
    workdir = config.out / "train"  # in place, not staged: a killed run resumes from its checkpoints
    jcsat.train(train_config(config), workdir, resume=config.resume, data_workers=config.data_workers)
    return workdir / "model"


def experiment_config(config: Config, model: Path | str | None) -> jcsat_study.ShelfExperimentConfig:
    """The experiment's part of ``config``, with the data folder found (:func:`mocap.find_data_root`) and
    ``model`` (None: the shipped one)."""
    data_root = mocap.find_data_root(config.data_root, "shelf")
    return jcsat_study.ShelfExperimentConfig(**{
        **{field.name: getattr(config, field.name) for field in dataclasses.fields(jcsat_study.ShelfExperimentConfig)},
        "model": None if model is None else str(model), "data_root": None if data_root is None else str(data_root)})


def main(config: Config) -> None:
    jcsat_study.check_input_files(experiment_config(config, None if config.train else config.model))  # before training
    experiment = experiment_config(config, _train(config) if config.train else config.model)
    stages = [s for s in _STAGES if s != "plot" or experiment.plot]
    with (_cli.run_folder(config.out, keep=("train",)) as out,
          _cli.stages(out, "shelf_jcsat", stages) as (log, progress)):
        result = jcsat_study.run_shelf_experiment(experiment, out, log=log, progress=progress)
    print(result.table)
    print(f"outputs in {config.out}/; total {result.metrics['total_seconds']:.1f} s")


if __name__ == "__main__":
    _cli.run(main, Config, description=__doc__, float64=True, aliases=ALIASES)

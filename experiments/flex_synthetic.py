"""FLEX on held-out synthetic CMU clips against camera-dependent triangulation (paper Tables 1, 3 and 5).

Without ``--train`` it evaluates the models shipped in ``flex/assets`` (or ``--model-dir``); ``--train`` first
trains them in ``OUT/models/<name>`` (kept in place, resumable: run the same command again after a kill), which
is how the shipped ones were made. The test motion comes from the held-out clips shipped in mocap/assets (no data
folder), or from ``--clips``: shipped clip names or any CMU motion files of one person (exp-map ``.txt`` of the
CMU-Mocap benchmark, ``.amc`` beside its ``.asf``, ``.bvh`` in CMU's units), relative paths under ``--data-root``.
Writes OUT/results.json, results.md, skeletons.png, mpjpe.png, log.jsonl and run.json, replacing OUT's previous
outputs as a whole. Logic: :mod:`experiments.flex_study`.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Annotated

import tyro

from experiments import _cli
from experiments.flex_study import ExperimentConfig, run_experiment, train_models
from flex import SHIPPED_MODELS, load_models

QUICK = dict(sequences=4)
"""What --quick changes (where the option is not given another value)."""
TRAIN_STEPS = 1500
QUICK_TRAIN_STEPS = 100


@dataclasses.dataclass(frozen=True)
class Config:
    out: Path
    """Output folder."""
    quick: bool = False
    """Fewer test sequences (4); with --train, 100 training steps per model."""
    train: bool = False
    """Train the models (flex.MODELS) into OUT/models instead of using the shipped ones."""
    train_steps: int | None = None
    """Training steps per model with --train (default 1500, --quick 100)."""
    model_dir: Path = SHIPPED_MODELS
    """Folder with one saved model per name (default: the shipped flex/assets)."""
    data_root: Path | None = None
    """Folder that relative --clips paths are looked up in (default: $MVMOCAP_DATA_ROOT; not needed otherwise)."""
    experiment: Annotated[ExperimentConfig, tyro.conf.OmitArgPrefixes] = ExperimentConfig()
    """The experiment."""

    def __post_init__(self) -> None:
        if not self.train and not self.model_dir.is_dir():
            raise ValueError(f"--model-dir {self.model_dir} is not a folder")
        if self.train_steps is not None and self.train_steps < 1:
            raise ValueError(f"--train-steps must be >= 1, got {self.train_steps}")
        self.test_clips()  # refuses a clip that is neither shipped nor a file before any work

    def test_clips(self) -> tuple[str, ...]:
        """``--clips`` with each file as a path that exists (relative ones found under the data folder)."""
        return _cli.clips_option(self.experiment.clips, self.data_root)


def main(config: Config) -> None:
    default = ExperimentConfig()
    experiment = dataclasses.replace(config.experiment, clips=config.test_clips(), **{
        name: value for name, value in (QUICK if config.quick else {}).items()
        if getattr(config.experiment, name) == getattr(default, name)})
    with _cli.run_folder(config.out, keep=("models",)) as out:
        log = _cli.jsonl_log(out)
        if config.train:
            steps = config.train_steps or (QUICK_TRAIN_STEPS if config.quick else TRAIN_STEPS)
            models = train_models(config.out / "models", steps, seed=experiment.seed, log=log)
        else:
            models = load_models(config.model_dir)
        results = run_experiment(experiment, models, out, log=log)
        report = (out / "results.md").read_text()
    print(report)
    print(f"wrote {config.out}/results.json, results.md, skeletons.png, mpjpe.png ({results['seconds']} s)")


if __name__ == "__main__":
    _cli.run(main, Config, description=__doc__)

"""FLEX on held-out synthetic CMU clips against camera-dependent triangulation (paper Tables 1, 3 and 5).

Without ``--train`` it evaluates the models shipped in ``flex/assets`` (or ``--model-dir``); ``--train`` first
trains them in ``OUT/models/<name>`` (kept in place, resumable: run the same command again after a kill), which
is how the shipped ones were made. The test motion comes from the held-out clips shipped in mocap/assets (no data
folder), or from ``--clips``: shipped clip names or any CMU motion files of one person (exp-map ``.txt`` of the
CMU-Mocap benchmark, ``.amc`` beside its ``.asf``, ``.bvh`` in CMU's units), relative paths under ``--data-root``,
or ``--test-expmap``: the benchmark's whole test split. Besides random rigs it evaluates the fixed rigs (``--rigs``,
the paper's protocol) with the rig models where they exist, and the duplicate-joint ablation's pair
(``flex.SKELETON_MODELS``) where it exists. Writes OUT/results.json, results.md, skeletons.png,
mpjpe.png, rigs.png, log.jsonl and run.json, replacing OUT's previous outputs as a whole. Logic:
:mod:`experiments.flex_study`.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Annotated, Literal

import tyro

import mocap
from experiments import _cli
from experiments.flex_study import ExperimentConfig, run_experiment, train_models
from flex import (CONFIGS, DETECTION_MODELS, MAIN_MODEL, MODELS, RIG_MODELS, SHIPPED_MODELS, SKELETON_MODELS,
                  load_models)

QUICK = dict(sequences=4, rigs=("h36m_ring",), perturbation_draws=2)
"""What --quick changes (where the option is not given another value)."""
TRAIN_STEPS = 1500
QUICK_TRAIN_STEPS = 100


@dataclasses.dataclass(frozen=True)
class Config:
    out: Path
    """Output folder."""
    quick: bool = False
    """Fewer test sequences (4), one fixed rig (h36m_ring) with 2 perturbation draws; with --train, 100 training
    steps per model."""
    train: bool = False
    """Train the models of --train-names into OUT/models (resumably) and use them instead of --model-dir's."""
    train_names: tuple[str, ...] = tuple(MODELS)
    """With --train: the models to train, names of flex.MODELS (default: all of them), flex.RIG_MODELS
    (flex_4views_h36m_ring, flex_4views_shelf), flex.DETECTION_MODELS (flex_4views_shelf_detected, for
    experiments.flex_shelf) or flex.SKELETON_MODELS (flex_4views_h36m_ring_tpose, flex_4views_h36m_ring_no_duplicates:
    the duplicate-joint ablation); the others come from --model-dir."""
    train_steps: int | None = None
    """Training steps per model with --train (default 1500, --quick 100)."""
    train_model_config: Literal[tuple(sorted(CONFIGS))] = "small"  # type: ignore[valid-type]
    """With --train: the models' configuration (flex.CONFIGS): small, the shipped CPU models (1.3 M generator
    parameters); paper, Table 6's (about 84 M, for a GPU); cpu, a tiny one for smoke runs."""
    train_batch: int = 16
    """With --train: windows per training step."""
    train_pool: int | None = None
    """With --train: training windows drawn once and cached (default: 4096 for a rig model, else 2048)."""
    data_workers: int = 1
    """With --train: processes that build the training windows."""
    train_expmap: bool = False
    """With --train: the training windows also come from the CMU-Mocap benchmark's train split
    (DATA/cmu_expmap/train, in the data folder of --data-root); its test split never enters training."""
    validate_expmap: bool = False
    """With --train-expmap: the last file of each action of the train split (mocap.cmu_expmap_validation_files)
    leaves training and validates beside 03_01_uneven, so that the training log's validation MPJPE includes the
    benchmark's motion."""
    test_expmap: bool = False
    """Test motion: the CMU-Mocap benchmark's test split (DATA/cmu_expmap/test, 24 files) instead of --clips."""
    model_dir: Path = SHIPPED_MODELS
    """Folder with one saved model per name (default: the shipped flex/assets)."""
    data_root: Path | None = None
    """Data folder of --train-expmap, --test-expmap and relative --clips paths (default: $MVMOCAP_DATA_ROOT)."""
    experiment: Annotated[ExperimentConfig, tyro.conf.OmitArgPrefixes] = ExperimentConfig()
    """The experiment."""

    def __post_init__(self) -> None:
        if not self.train and not self.model_dir.is_dir():
            raise ValueError(f"--model-dir {self.model_dir} is not a folder")
        for name in ("train_steps", "train_pool"):
            if getattr(self, name) is not None and getattr(self, name) < 1:
                raise ValueError(f"--{name.replace('_', '-')} must be >= 1, got {getattr(self, name)}")
        for name in ("train_batch", "data_workers"):
            if getattr(self, name) < 1:
                raise ValueError(f"--{name.replace('_', '-')} must be >= 1, got {getattr(self, name)}")
        known = [*MODELS, *RIG_MODELS, *DETECTION_MODELS, *SKELETON_MODELS]
        unknown = sorted(set(self.train_names) - set(known))
        if unknown or not self.train_names:
            raise ValueError(f"--train-names must name models of {known}, got {unknown}")
        if self.train_expmap and not self.train:
            raise ValueError("--train-expmap needs --train")
        if self.validate_expmap and not self.train_expmap:
            raise ValueError("--validate-expmap needs --train-expmap")
        if self.test_expmap and self.experiment.clips != ExperimentConfig().clips:
            raise ValueError("--test-expmap and --clips exclude each other")
        self.train_clips(), self.test_clips()  # missing files or data folders are refused before any work

    def test_clips(self) -> tuple[str, ...]:
        """The test motion: ``--clips`` with each file as a path that exists (relative ones found under the data
        folder), or the benchmark's test split."""
        if self.test_expmap:
            return _cli.expmap_clips(self.data_root, "test")
        return _cli.clips_option(self.experiment.clips, self.data_root)

    def train_clips(self) -> tuple[str, ...]:
        """The motion files --train adds to the shipped training clips (absolute paths, so that the sample pools'
        cache keys do not depend on the working folder)."""
        if not self.train_expmap:
            return ()
        validation = set(self.validation_clips())
        return tuple(clip for clip in _cli.expmap_clips(self.data_root, "train") if clip not in validation)

    def validation_clips(self) -> tuple[str, ...]:
        """The motion files --train validates on beside the shipped validation clip (absolute paths)."""
        if not self.validate_expmap:
            return ()
        return tuple(str(path.resolve()) for path in mocap.cmu_expmap_validation_files(self.data_root))


def main(config: Config) -> None:
    default = ExperimentConfig()
    experiment = dataclasses.replace(config.experiment, clips=config.test_clips(), **{
        name: value for name, value in (QUICK if config.quick else {}).items()
        if getattr(config.experiment, name) == getattr(default, name)})
    with _cli.run_folder(config.out, keep=("models",)) as out:
        log = _cli.jsonl_log(out)
        models = {}
        if not (config.train and MAIN_MODEL in config.train_names):
            models = load_models(config.model_dir)
        if config.train:
            steps = config.train_steps or (QUICK_TRAIN_STEPS if config.quick else TRAIN_STEPS)
            models |= train_models(config.out / "models", steps, seed=experiment.seed, names=config.train_names,
                                   extra_clips=config.train_clips(), validation_clips=config.validation_clips(),
                                   batch_size=config.train_batch, pool_size=config.train_pool,
                                   model_config=config.train_model_config, data_workers=config.data_workers, log=log)
        results = run_experiment(experiment, models, out, log=log)
        report = (out / "results.md").read_text()
    print(report)
    print(f"wrote {config.out}/results.json, results.md, skeletons.png, mpjpe.png ({results['seconds']} s)")


if __name__ == "__main__":
    _cli.run(main, Config, description=__doc__)

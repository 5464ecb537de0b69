"""PHD+T, JAT, MPJAT (with the ablations of Tables 5.5 and 5.9) and ZeroMotion on held-out synthetic videos
(thesis Sect. 5.3: Tables 5.2-5.11's metrics, Fig. 5.1, and an interpenetration measure).

The test videos are rendered from the held-out clips shipped in mocap/assets (no data folder), or from ``--clips``:
shipped clip names, CMU motion files of one person (exp-map ``.txt`` of the CMU-Mocap benchmark, ``.amc`` beside its
``.asf``, ``.bvh`` in CMU's units) or the files of two people captured together joined by ``+`` (a salsa pair:
``cmu_mocap/60_03_scaled.bvh+cmu_mocap/61_03_scaled.bvh``), relative paths under ``--data-root``. A one-person clip
gives single-person samples, a pair two-person ones.

Without ``--train`` it evaluates the models shipped in ``dynamics/assets/phdt`` and ``dynamics/assets/transformers``;
``--train`` first trains a backbone and PHD+T in ``OUT/train`` (three resumable stages), then the four
transformers on that backbone's features in ``OUT/train/transformers`` (two resumable stages each): run the same
command again after a kill (``OUT/train`` is kept in place). That is how the shipped models were made. Writes
OUT/results.json, results.md, prediction_*.png, strip.png, log.jsonl and run.json, replacing OUT's previous
outputs as a whole. Logic: :mod:`experiments.dynamics_study`.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import geometry
from dynamics import (SHIPPED_MODEL, SHIPPED_TRANSFORMERS, EvalConfig, StageConfig, TrainConfig, TransformerTrainConfig,
                      load_trained, load_transformers, train, train_all)
from experiments import _cli
from experiments.dynamics_study import run_experiment

QUICK_EVAL = dict(stride=15)
QUICK_CLIPS = ("02_01_walk", "60_03_61_03_salsa")
QUICK_TRAIN = dict(
    image=StageConfig(steps=40, batch_size=16, learning_rate=1e-3, warmup_steps=5),
    movie=StageConfig(steps=20, batch_size=8, learning_rate=3e-4, warmup_steps=5),
    ar=StageConfig(steps=20, batch_size=8, learning_rate=3e-4, warmup_steps=5),
    checkpoint_interval=20, validation_interval=20, log_interval=10)
QUICK_TRANSFORMERS = dict(
    movie=StageConfig(steps=10, batch_size=4, learning_rate=3e-4, warmup_steps=2),
    multi_person_movie=StageConfig(steps=5, batch_size=4, learning_rate=1e-4, warmup_steps=1),
    ar=StageConfig(steps=5, batch_size=4, learning_rate=3e-4, warmup_steps=1),
    checkpoint_interval=5, validation_interval=5, log_interval=5)

RECIPES = ("small", "large")
"""``small``: the shipped models, sized for a CPU; ``large``: sized for one GPU (issue 26's larger crops and
backbone, more rendered motion)."""


def training_configs(recipe: str, seed: int, quick: bool, data_root: str | Path | None, renders: int | None = None,
                     ar_clip_norm: float | None = None) -> tuple[TrainConfig, TransformerTrainConfig]:
    """The backbone and PHD+T run, and the transformers' (JAT's, as :func:`dynamics.train_all` takes it), of
    ``recipe``; ``quick``: a few steps per stage on two clips of its data, rendered once (a smoke run); ``renders``:
    videos per training clip instead of the recipe's; ``ar_clip_norm``: the autoregressive stages' gradients
    (PHD+T's and the transformers') clipped to that global norm (the recipes do not clip).

    ``small`` is the defaults of :class:`~dynamics.TrainConfig` and :class:`~dynamics.TransformerTrainConfig` (16
    renders per clip, 8000 conditioning steps). ``large`` takes 128 px crops and a ResNet twice as wide with two
    blocks per stage, renders every training clip and every file of the CMU-Mocap benchmark's train split
    (``<data_root>/cmu_expmap/train``, single-person motion of subjects the test clips' subjects are not known to be
    among) twice with four variants each (its variety is the benchmark's motion; 16 renders of it would not fit in
    memory), and trains ten times as many steps with larger batches."""
    phdt, transformers = TrainConfig(seed=seed), TransformerTrainConfig(seed=seed)
    if recipe == "large":
        crop = 128
        extra = () if quick else _cli.expmap_clips(data_root, "train")
        data = dataclasses.replace(phdt.data, clips=phdt.data.clips + extra, crop_size=crop, renders=2)
        # The conditioning and prediction stages of PHD+T and of the transformers train alike.
        movie = StageConfig(steps=6_000, batch_size=32, learning_rate=3e-4, warmup_steps=300)
        ar = StageConfig(steps=3_000, batch_size=32, learning_rate=3e-4, warmup_steps=150)
        phdt = dataclasses.replace(
            phdt, data=data, validation=dataclasses.replace(phdt.validation, crop_size=crop),
            backbone=dataclasses.replace(phdt.backbone, widths=(32, 64, 128, 256), blocks_per_stage=2, crop_size=crop),
            image=StageConfig(steps=20_000, batch_size=64, learning_rate=1e-3, warmup_steps=500),
            movie=movie, ar=ar, checkpoint_interval=500, validation_interval=1_000)
        transformers = dataclasses.replace(
            transformers, data=data, validation=dataclasses.replace(transformers.validation, crop_size=crop),
            movie=movie, ar=ar,
            multi_person_movie=StageConfig(steps=1_500, batch_size=32, learning_rate=1e-4, warmup_steps=150),
            checkpoint_interval=500, validation_interval=500)
    if renders is not None:
        data = dataclasses.replace(phdt.data, renders=renders)
        phdt, transformers = dataclasses.replace(phdt, data=data), dataclasses.replace(transformers, data=data)
    if quick:
        data = dataclasses.replace(phdt.data, clips=QUICK_CLIPS, renders=1, augmented_epochs=2)
        phdt = dataclasses.replace(phdt, data=data, **QUICK_TRAIN)
        transformers = dataclasses.replace(transformers, data=data, **QUICK_TRANSFORMERS)
    if ar_clip_norm is not None:
        phdt, transformers = (dataclasses.replace(config, ar=dataclasses.replace(config.ar, clip_norm=ar_clip_norm))
                              for config in (phdt, transformers))
    return phdt, transformers


@dataclasses.dataclass(frozen=True)
class Config:
    out: Path
    """Output folder."""
    quick: bool = False
    """Test windows every 15 frames instead of every EvalConfig.stride; with --train, a few steps per stage on two
    clips (a smoke run)."""
    train: bool = False
    """Train the backbone and PHD+T into OUT/train (resumable) instead of using the shipped ones."""
    train_transformers: bool = False
    """Train only the four transformers into OUT/train/transformers (resumable), on the backbone and PHD+T of
    --model-dir: how the shipped transformers were made."""
    model_dir: Path = SHIPPED_MODEL
    """Folder with backbone/ and phdt/ (default: the shipped dynamics/assets/phdt)."""
    transformer_dir: Path = SHIPPED_TRANSFORMERS
    """Folder with the four transformers (default: the shipped dynamics/assets/transformers)."""
    body_model: Path | None = None
    """Official SMPL model file (.pkl or .npz) instead of the generated stand-in body; the shipped models were
    trained on the stand-in, so use it with --train."""
    data_root: Path | None = None
    """Folder that relative --clips paths are looked up in (default: $MVMOCAP_DATA_ROOT; not needed otherwise)."""
    clips: tuple[str, ...] = EvalConfig().data.clips
    """Test clips (default: the held-out shipped ones): shipped clip names, CMU motion files of one person (exp-map
    .txt, .amc beside its .asf, .bvh in CMU's units), or the files of two people captured together joined by '+'
    (cmu_mocap/60_03_scaled.bvh+cmu_mocap/61_03_scaled.bvh, the salsa pair's files); relative paths under
    --data-root. One-person clips give the single-person results, pairs the two-person ones."""
    recipe: str = "small"
    """Training recipe (with --train or --train-transformers): 'small', the shipped models, sized for a CPU;
    'large', sized for one GPU: 128 px crops, a wider and deeper ResNet, the CMU-Mocap benchmark's train split
    rendered as extra motion (needs --data-root), ten times the steps."""
    renders: int | None = None
    """Videos rendered per training clip (with --train or --train-transformers; default: the recipe's, 16 for
    'small' as the shipped models, chosen on validation by `python -m experiments.dynamics_renders`; 2 for
    'large')."""
    seed: int = 0
    """Training seed (with --train or --train-transformers)."""
    train_ar_clip_norm: float | None = None
    """Clip the gradients of the autoregressive stages (PHD+T's, each transformer's) to this global norm (with
    --train or --train-transformers; default: unclipped, as the shipped models; untested for the video models). The
    stages before them do not record it: to retrain only those stages, delete OUT/train/ar and
    OUT/train/transformers/*/ar of a finished run and run it again."""
    data_workers: int = 1
    """CPU processes that render the training videos (the same frames as one)."""
    progress: bool = True
    """Progress bars."""

    def __post_init__(self) -> None:
        for option, folder, used in (("--model-dir", self.model_dir, not self.train),
                                     ("--transformer-dir", self.transformer_dir,
                                      not (self.train or self.train_transformers))):
            if used and not folder.is_dir():
                raise ValueError(f"{option} {folder} is not a folder")
        if self.body_model is not None and not self.body_model.is_file():
            raise ValueError(f"--body-model {self.body_model} is not a file")
        if not self.clips:
            raise ValueError("--clips names no clip")
        if self.recipe not in RECIPES:
            raise ValueError(f"--recipe must be one of {RECIPES}, got {self.recipe!r}")
        if self.data_workers < 1:
            raise ValueError(f"--data-workers must be >= 1, got {self.data_workers}")
        if self.renders is not None and self.renders < 1:
            raise ValueError(f"--renders must be >= 1, got {self.renders}")
        if self.train_ar_clip_norm is not None and not self.train_ar_clip_norm > 0:
            raise ValueError(f"--train-ar-clip-norm must be positive, got {self.train_ar_clip_norm}")
        self.evaluation()  # refuses a clip that is neither shipped nor files before any work
        if self.train or self.train_transformers:
            self.training()  # refuses the large recipe without the benchmark's files before any work

    def training(self) -> tuple[TrainConfig, TransformerTrainConfig]:
        """The training runs of --recipe (:func:`training_configs`)."""
        return training_configs(self.recipe, self.seed, self.quick, self.data_root, self.renders,
                                self.train_ar_clip_norm)

    def evaluation(self) -> EvalConfig:
        """The held-out evaluation on --clips (each file as a path that exists, relative ones found under the data
        folder), with --quick's windows."""
        clips = _cli.clips_option(self.clips, self.data_root)
        default = EvalConfig()
        return dataclasses.replace(default, data=dataclasses.replace(default.data, clips=clips),
                                   **(QUICK_EVAL if self.quick else {}))


def main(config: Config) -> None:
    body = (geometry.load_body_model(config.body_model, num_shapes=3) if config.body_model
            else geometry.stand_in_body_model())
    evaluation = config.evaluation()
    workdir = config.out / "train"  # in place, not staged: a killed run resumes from its checkpoints
    with _cli.run_folder(config.out, keep=("train",)) as out:
        log = _cli.jsonl_log(out)
        train_config, transformer_config = config.training()
        if config.train:
            backbone, phdt = train(train_config, workdir, body, resume=True, log=log, progress=config.progress,
                                   data_workers=config.data_workers)
        else:
            backbone, phdt = load_trained(config.model_dir)
        # The test videos are cropped at the size the backbone was trained on.
        evaluation = dataclasses.replace(evaluation, data=dataclasses.replace(evaluation.data,
                                                                              crop_size=backbone.crop_size))
        if config.train or config.train_transformers:
            # PHD+T's renders are the transformers' too (the same training data): one cache.
            transformer_config = dataclasses.replace(transformer_config,
                                                     cache_dir=str((workdir / "data_cache").resolve()))
            transformers = train_all(transformer_config, workdir / "transformers", body, backbone, phdt.hmr,
                                     resume=True, log=log, progress=config.progress, data_workers=config.data_workers)
        else:
            transformers = load_transformers(config.transformer_dir)
        results = run_experiment(out, backbone, {"PHD+T": phdt, **transformers}, body, evaluation, log=log,
                                 progress=config.progress)
        report = (out / "results.md").read_text()
    print(report)
    print(f"wrote {config.out}/results.json, results.md, prediction_*.png, strip.png ({results['seconds']} s)")


if __name__ == "__main__":
    _cli.run(main, Config, description=__doc__)

"""Multi-person 3D pose on Shelf with JCSAT (the project's main job).

    .venv/bin/python -m experiments.shelf_jcsat [--data-root PATH] [--out DIR] [--quick] [--method jcsat|geometric]
        [--model DIR] [--views 0 1 2 ...] [--perturb-cameras K] [--aggregate mean|last] [--window-stride S]
        [--structural-steps N] [--max-bone-deviation R] [--outlier-half-window W] [--outlier-distance M]
        [--train [--config cpu|gpu|cpu_head_4da] [--resume] [--steps S] [--data-workers W]] [--seed S]

With no arguments it runs the shipped JCSAT model (``jcsat/assets/shelf_wide_4da``, trained only on
synthetic scenes) beside the learning-free geometric baseline. With Shelf data (``--data-root`` or
``MVMOCAP_DATA_ROOT`` holding ``shelf/``) it infers on the real test frames 300..600 with sliding windows
of N = 10 frames (``--aggregate``) and prints PCP (VoxelPose, JCSAT and 4D-association protocols), precision/recall
and MPJPE next to the 4D-association output scored by the same evaluator; without data it runs on a
seeded synthetic Shelf-rig scene and says so. Writes ``config.json``, ``log.jsonl``,
``predictions.jsonl`` (``mocap`` prediction format, ``python -m experiments.shelf_eval --pred``),
``predictions_geometric.jsonl``, ``metrics.json`` and ``frame.png`` to ``--out``.

``--train`` first trains a model on synthetic scenes (:func:`jcsat.train`: from scratch, or from the run's
``init_model``; workdir ``--out/train``; ``--resume`` continues a killed run from its last checkpoint) and
then evaluates it.
Logic: :func:`experiments.jcsat_study.run_shelf_experiment`, :func:`jcsat.train`.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
from pathlib import Path

os.environ.setdefault("XLA_FLAGS", "--xla_cpu_experimental_ynn_fusion_type=")

import jax  # noqa: E402
from tqdm import tqdm  # noqa: E402

import association  # noqa: E402
import jcsat  # noqa: E402
from experiments import jcsat_study  # noqa: E402

_STAGES = ("data", "geometric", "jcsat", "evaluation", "plot")


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m experiments.shelf_jcsat", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--method", choices=jcsat_study.METHODS, default="jcsat",
                        help="jcsat: the model on the baseline's tracks, scored beside the baseline (default); "
                             "geometric: Joint Cloud -> K-Means persons -> weighted medoid + re-triangulation only")
    parser.add_argument("--model", type=Path, default=None,
                        help="a model folder written by training (<workdir>/model); default: the shipped "
                             "jcsat/assets/shelf_wide_4da")
    parser.add_argument("--data-root", type=Path, default=os.environ.get("MVMOCAP_DATA_ROOT"),
                        help="folder containing shelf/ (actorsGT.mat, the OpenPose detections, 4d_association/); "
                             "default $MVMOCAP_DATA_ROOT; without it a synthetic Shelf-rig scene is used and the "
                             "output says SYNTHETIC")
    parser.add_argument("--out", type=Path, default=Path("runs/shelf_jcsat"),
                        help="output folder (default: %(default)s)")
    parser.add_argument("--quick", action="store_true",
                        help="smoke run: real data, the first 60 test frames; synthetic, 40 frames of 3 people; "
                             "with --train, 300 steps on 4 scenes")
    parser.add_argument("--views", type=int, nargs="+", default=None,
                        help="cameras to keep, 0-based (paper Table 6); the others' detections are dropped")
    parser.add_argument("--perturb-cameras", type=int, default=0, metavar="K",
                        help="perturb the calibration of the first K kept cameras by up to 0.25 cm and 2.5 degrees "
                             "(paper Table 8) before building the Joint Cloud (default: %(default)s)")
    parser.add_argument("--perturb-seed", type=int, default=0, help="seed of that perturbation (default: %(default)s)")
    parser.add_argument("--train", action="store_true",
                        help="train a model into OUT/train on synthetic scenes (from scratch, or from the --config run's "
                             "init_model), then evaluate it")
    parser.add_argument("--resume", action="store_true", help="with --train: continue from OUT/train's last checkpoint")
    parser.add_argument("--config", choices=sorted(jcsat.TRAIN_CONFIGS), default="cpu",
                        help="with --train: the named run in jcsat.TRAIN_CONFIGS; cpu: the 'cpu' model, 2400 steps "
                             "of 8 windows on 16 scenes (the 2-core CPU's run); gpu: the 'cpu_wide' model, 6000 "
                             "steps of 64 windows on 48 scenes; cpu_head_4da: the shipped model's second stage, 500 steps "
                             "of 16 windows fine-tuning the gpu run's model on labels with the 4D-association head "
                             "rule (default: %(default)s)")
    parser.add_argument("--steps", type=int, default=None,
                        help="with --train: optimisation steps (default: the --config run's)")
    parser.add_argument("--data-workers", type=int, default=1,
                        help="with --train: processes that build the synthetic scenes when they are not cached "
                             "(default: %(default)s)")
    parser.add_argument("--seed", type=int, default=0,
                        help="seed of the synthetic scene, the K-Means restarts and training (default: %(default)s)")
    parser.add_argument("--aggregate", choices=jcsat.AGGREGATES, default=jcsat_study.ShelfExperimentConfig.aggregate,
                        help="mean: each frame's pose is the mean over every window that contains it (offline; chosen "
                             "on synthetic validation, experiments.shelf_validate --jcsat); last: the causal window's "
                             "last frame (online) (default: %(default)s)")
    parser.add_argument("--window-stride", type=int, default=jcsat_study.ShelfExperimentConfig.window_stride,
                        help="with --aggregate mean: average the windows ending on every this many frames "
                             "(default: %(default)s)")
    parser.add_argument("--structural-steps", type=int, default=association.GeometricConfig.structural_steps,
                        metavar="N",
                        help="Step Constraint Algorithm steps of the baseline's Structural Triangulation refinement "
                             "with each track's bone lengths; 0 turns it off (default: %(default)s, chosen on "
                             "synthetic validation, experiments.shelf_validate)")
    parser.add_argument("--max-bone-deviation", type=float, default=association.GeometricConfig.max_bone_deviation,
                        metavar="R",
                        help="that refinement distrusts the detections of a joint all of whose bones are off the "
                             "track's lengths by more than R times their length; 0 trusts every joint (default: "
                             "%(default)s, chosen on synthetic validation)")
    parser.add_argument("--outlier-half-window", type=int, default=association.BaselineConfig.outlier_half_window,
                        metavar="W",
                        help="the baseline's temporal filter: frames on either side of each joint's median; 0 turns "
                             "it off (default: %(default)s, chosen on synthetic validation)")
    parser.add_argument("--outlier-distance", type=float, default=association.BaselineConfig.outlier_distance,
                        metavar="M",
                        help="metres from that median beyond which a joint is replaced by it; 0 replaces every joint, "
                             "a plain median filter (default: %(default)s, chosen on synthetic validation)")
    parser.add_argument("--no-plot", action="store_true", help="skip frame.png")
    return parser.parse_args(argv)


def experiment_config(args: argparse.Namespace, model: Path | None) -> jcsat_study.ShelfExperimentConfig:
    """The run's :class:`experiments.jcsat_study.ShelfExperimentConfig` from the parsed options (``model``: None for the shipped one)."""
    return jcsat_study.ShelfExperimentConfig(
        method=args.method, model=None if model is None else str(model),
        data_root=None if args.data_root is None else str(args.data_root),
        quick=args.quick, seed=args.seed, plot=not args.no_plot,
        baseline=dataclasses.replace(
            association.BaselineConfig(), seed=args.seed, outlier_half_window=args.outlier_half_window,
            outlier_distance=args.outlier_distance, geometric=dataclasses.replace(
                association.GeometricConfig(), structural_steps=args.structural_steps,
                max_bone_deviation=args.max_bone_deviation)),
        views=None if args.views is None else tuple(args.views),
        perturb_cameras=args.perturb_cameras, perturb_seed=args.perturb_seed, aggregate=args.aggregate,
        window_stride=args.window_stride,
    )


def _train(args: argparse.Namespace) -> Path:
    config = dataclasses.replace(jcsat.TRAIN_CONFIGS[args.config], seed=args.seed)
    if args.quick:
        config = dataclasses.replace(config, steps=300, warmup_steps=30, checkpoint_interval=100,
                                     validation_interval=100, data=dataclasses.replace(config.data, num_scenes=4))
    if args.steps is not None:
        config = dataclasses.replace(config, steps=args.steps, warmup_steps=min(config.warmup_steps, args.steps))
    workdir = args.out / "train"
    jcsat.train(config, workdir, resume=args.resume, data_workers=args.data_workers)
    return workdir / "model"


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    jax.config.update("jax_enable_x64", True)
    args.out.mkdir(parents=True, exist_ok=True)
    model = _train(args) if args.train else args.model
    config = experiment_config(args, model)
    log_path = args.out / "log.jsonl"
    log_path.write_text("")
    stages = [s for s in _STAGES if (s != "plot" or config.plot) and (s != "jcsat" or config.method == "jcsat")]
    bar = tqdm(total=len(stages), desc="shelf_jcsat", unit="stage")

    def log(event: dict) -> None:
        with log_path.open("a") as stream:
            stream.write(json.dumps(event) + "\n")

    def progress(stage: str) -> None:
        if stage != "data":
            bar.update(1)
        bar.set_postfix_str(stage)

    result = jcsat_study.run_shelf_experiment(config, args.out, log=log, progress=progress)
    bar.update(1)
    bar.close()
    print(result.table)
    print(f"outputs in {args.out}/; total {result.metrics['total_seconds']:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

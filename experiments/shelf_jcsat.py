"""Multi-person 3D pose on Shelf from the Joint Cloud (the project's main job).

    .venv/bin/python -m experiments.shelf_jcsat [--method geometric] [--data-root PATH] [--out DIR] [--quick] [--seed S]

The only method so far is ``geometric``, a learning-free baseline on the JCSAT Joint Cloud (JCSAT's
transformer is a later issue; the output says so). With ``--data-root`` holding ``shelf/`` it runs on
the real Shelf test frames 300..600 and prints PCP under the VoxelPose, JCSAT and 4D-association
matching protocols next to the 4D-association output scored by the same evaluator. Without it, it
runs on a seeded synthetic Shelf-rig scene and says so. Writes ``config.json``, ``log.jsonl``,
``predictions.jsonl`` (``mocap`` prediction format, ``python -m experiments.shelf_eval --pred``),
``metrics.json`` and ``frame.png`` to ``--out``. Logic: :func:`jcsat.run_shelf_experiment`.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import jax
from tqdm import tqdm

import jcsat

_STAGES = ("data", "geometric", "evaluation", "plot")


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="python -m experiments.shelf_jcsat",
        description="Shelf multi-person 3D pose from the JCSAT Joint Cloud. Default method: the geometric "
                    "(learning-free) baseline; JCSAT itself is not implemented yet.",
    )
    parser.add_argument("--method", choices=jcsat.METHODS, default="geometric",
                        help="geometric: Joint Cloud -> trimmed K-Means persons -> weighted medoid + "
                             "multi-view re-triangulation (default and only choice for now)")
    parser.add_argument("--data-root", type=Path, default=None,
                        help="folder containing shelf/ (actorsGT.mat, 4d_association/); without it a "
                             "synthetic Shelf-rig scene is used and the output says SYNTHETIC")
    parser.add_argument("--out", type=Path, default=Path("runs/shelf_jcsat"),
                        help="output folder for config.json, log.jsonl, predictions.jsonl, metrics.json, "
                             "frame.png (default: %(default)s)")
    parser.add_argument("--quick", action="store_true",
                        help="smoke run under a minute: real data, the first 60 test frames; synthetic, "
                             "40 frames of 3 people")
    parser.add_argument("--seed", type=int, default=0,
                        help="seed of the synthetic scene and of the K-Means restarts (default: %(default)s)")
    parser.add_argument("--no-plot", action="store_true", help="skip frame.png")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    jax.config.update("jax_enable_x64", True)
    config = jcsat.ShelfExperimentConfig(
        method=args.method, data_root=None if args.data_root is None else str(args.data_root),
        quick=args.quick, seed=args.seed, plot=not args.no_plot,
        baseline=dataclasses.replace(jcsat.BaselineConfig(), seed=args.seed),
    )
    args.out.mkdir(parents=True, exist_ok=True)
    log_path = args.out / "log.jsonl"
    log_path.write_text("")
    bar = tqdm(total=len(_STAGES) - (0 if config.plot else 1), desc="shelf_jcsat", unit="stage")

    def log(event: dict) -> None:
        with log_path.open("a") as stream:
            stream.write(json.dumps(event) + "\n")

    def progress(stage: str) -> None:
        if stage != "data":
            bar.update(1)
        bar.set_postfix_str(stage)

    result = jcsat.run_shelf_experiment(config, args.out, log=log, progress=progress)
    bar.update(1)
    bar.close()
    print(result.table)
    print(f"outputs in {args.out}/ (predictions.jsonl, metrics.json, config.json, log.jsonl"
          f"{', frame.png' if config.plot else ''}); total {result.metrics['total_seconds']:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

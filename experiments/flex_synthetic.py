"""FLEX on held-out synthetic CMU clips against camera-dependent triangulation (paper Tables 1, 3 and 5).

Run: ``.venv/bin/python -m experiments.flex_synthetic --out runs/flex_synthetic [--quick] [--train]``.
Without ``--train`` it evaluates the models shipped in ``flex/assets``; ``--train`` first trains them in
``DIR/models/<name>`` (resumable: run the same command again after a kill), which is how the shipped ones were
made. Writes DIR/results.json, DIR/results.md, DIR/skeletons.png, DIR/mpjpe.png and DIR/log.jsonl.
Logic: :mod:`experiments.flex_study`.
"""

import argparse
import dataclasses
import json
from pathlib import Path

from experiments.flex_study import ExperimentConfig, run_experiment, train_models
from flex import MODELS, SHIPPED_MODELS, load_models

QUICK = dict(sequences=4)
TRAIN_STEPS = 1500
QUICK_TRAIN_STEPS = 100


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", required=True, help="output folder (created)")
    parser.add_argument("--quick", action="store_true",
                        help=f"fewer test sequences {QUICK}; with --train, {QUICK_TRAIN_STEPS} training steps per model")
    parser.add_argument("--train", action="store_true",
                        help=f"train the models ({', '.join(MODELS)}) into OUT/models instead of using the shipped ones")
    parser.add_argument("--train-steps", type=int, default=None,
                        help=f"training steps per model with --train (default {TRAIN_STEPS}, --quick {QUICK_TRAIN_STEPS})")
    parser.add_argument("--model-dir", default=str(SHIPPED_MODELS),
                        help="folder with one saved model per name (default: the shipped flex/assets)")
    parser.add_argument("--data-root", default=None,
                        help="unused: the motion comes from the clips shipped in mocap/assets (kept for a uniform CLI)")
    for field in dataclasses.fields(ExperimentConfig):
        if field.type in ("int", int):
            parser.add_argument(f"--{field.name.replace('_', '-')}", type=int, default=None,
                                help=f"{field.name} (default {field.default})")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    overrides = {f.name: getattr(args, f.name) for f in dataclasses.fields(ExperimentConfig)
                 if getattr(args, f.name, None) is not None}
    config = dataclasses.replace(ExperimentConfig(), **{**(QUICK if args.quick else {}), **overrides})

    with open(out / "log.jsonl", "a") as log_file:
        def log(record: dict) -> None:
            log_file.write(json.dumps(record) + "\n")
            log_file.flush()

        if args.train:
            steps = args.train_steps or (QUICK_TRAIN_STEPS if args.quick else TRAIN_STEPS)
            models = train_models(out / "models", steps, seed=config.seed, log=log)
        else:
            models = load_models(args.model_dir)
        results = run_experiment(config, models, out, log=log)
    print((out / "results.md").read_text())
    print(f"wrote {out}/results.json, results.md, skeletons.png, mpjpe.png ({results['seconds']} s)")


if __name__ == "__main__":
    main()

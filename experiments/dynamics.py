"""PHD+T, JAT, MPJAT (with the ablations of Tables 5.5 and 5.9) and ZeroMotion on held-out synthetic videos
(thesis Sect. 5.3: Tables 5.2-5.11's metrics, Fig. 5.1, and an interpenetration measure).

Run: ``.venv/bin/python -m experiments.dynamics --out runs/dynamics [--quick] [--train]``.
Without ``--train`` it evaluates the models shipped in ``dynamics/assets/phdt`` and ``dynamics/assets/transformers``;
``--train`` first trains a backbone and PHD+T in ``OUT/train`` (three resumable stages), then the four
transformers on that backbone's features in ``OUT/train/transformers`` (two resumable stages each): run the same
command again after a kill. That is how the shipped models were made. Writes OUT/results.json, OUT/results.md,
OUT/prediction_*.png, OUT/strip.png and OUT/log.jsonl. Logic: :mod:`experiments.dynamics_study`.
"""

import argparse
import dataclasses
import json
from pathlib import Path

import geometry
from dynamics import (SHIPPED_MODEL, SHIPPED_TRANSFORMERS, DataConfig, EvalConfig, StageConfig, TrainConfig,
                      TransformerTrainConfig, load_trained, load_transformers, train, train_all)
from experiments.dynamics_study import run_experiment

QUICK_EVAL = dict(stride=15)
QUICK_TRAIN = dict(
    data=DataConfig(clips=("02_01_walk", "60_03_61_03_salsa"), renders=1, augmented_epochs=2),
    image=StageConfig(steps=40, batch_size=16, learning_rate=1e-3, warmup_steps=5),
    movie=StageConfig(steps=20, batch_size=8, learning_rate=3e-4, warmup_steps=5),
    ar=StageConfig(steps=20, batch_size=8, learning_rate=3e-4, warmup_steps=5),
    checkpoint_interval=20, validation_interval=20, log_interval=10)
QUICK_TRANSFORMERS = dict(
    data=QUICK_TRAIN["data"],
    movie=StageConfig(steps=10, batch_size=4, learning_rate=3e-4, warmup_steps=2),
    multi_person_movie=StageConfig(steps=5, batch_size=4, learning_rate=1e-4, warmup_steps=1),
    ar=StageConfig(steps=5, batch_size=4, learning_rate=3e-4, warmup_steps=1),
    checkpoint_interval=5, validation_interval=5, log_interval=5)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", required=True, help="output folder (created)")
    parser.add_argument("--quick", action="store_true",
                        help=f"test windows every {QUICK_EVAL['stride']} frames instead of every "
                             f"{EvalConfig.stride}; with --train, a few steps per stage on two clips (a smoke run)")
    parser.add_argument("--train", action="store_true",
                        help="train the backbone and PHD+T into OUT/train (resumable) instead of using the shipped ones")
    parser.add_argument("--train-transformers", action="store_true",
                        help="train only the four transformers into OUT/train/transformers (resumable), on the "
                             "backbone and PHD+T of --model-dir: how the shipped transformers were made")
    parser.add_argument("--model-dir", default=str(SHIPPED_MODEL),
                        help="folder with backbone/ and phdt/ (default: the shipped dynamics/assets/phdt)")
    parser.add_argument("--transformer-dir", default=str(SHIPPED_TRANSFORMERS),
                        help="folder with the four transformers (default: the shipped dynamics/assets/transformers)")
    parser.add_argument("--body-model", default=None,
                        help="official SMPL model file (.pkl or .npz) instead of the generated stand-in body; the "
                             "shipped models were trained on the stand-in, so use it with --train")
    parser.add_argument("--seed", type=int, default=0, help="training seed (with --train)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    body = (geometry.load_body_model(args.body_model, num_shapes=3) if args.body_model
            else geometry.stand_in_body_model())
    evaluation = dataclasses.replace(EvalConfig(), **(QUICK_EVAL if args.quick else {}))

    with open(out / "log.jsonl", "a") as log_file:
        def log(record: dict) -> None:
            log_file.write(json.dumps(record) + "\n")
            log_file.flush()

        if args.train:
            config = dataclasses.replace(TrainConfig(seed=args.seed), **(QUICK_TRAIN if args.quick else {}))
            backbone, phdt = train(config, out / "train", body, resume=True, log=log, progress=not args.no_progress)
        else:
            backbone, phdt = load_trained(args.model_dir)
        if args.train or args.train_transformers:
            transformer_config = dataclasses.replace(TransformerTrainConfig(seed=args.seed),
                                                     **(QUICK_TRANSFORMERS if args.quick else {}))
            transformers = train_all(transformer_config, out / "train" / "transformers", body, backbone, phdt.hmr,
                                     resume=True, log=log, progress=not args.no_progress)
        else:
            transformers = load_transformers(args.transformer_dir)
        results = run_experiment(out, backbone, {"PHD+T": phdt, **transformers}, body, evaluation, log=log,
                                 progress=not args.no_progress)
    print((out / "results.md").read_text())
    print(f"wrote {out}/results.json, results.md, prediction_*.png, strip.png ({results['seconds']} s)")


if __name__ == "__main__":
    main()

"""Score a Shelf prediction file (``mocap`` JSON-lines format) against the Shelf ground truth.

    .venv/bin/python -m experiments.shelf_eval --pred run.jsonl [--protocol all] [--json]

Prints, per matching protocol (``docs/protocols.md``), the per-actor PCP with part counts
and VoxelPose bone groups, joint precision / recall at 0.2 m, MPJPE and Recall@500mm, averaged over
actors 1-3. The 4D-association output converted with ``mocap.predictions_from_4dassoc`` gives A1-A3
PCP 99.7 / 91.4 / 97.7 (avg 96.27) under every protocol.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import mocap

_DEFAULT_DATA_ROOT = Path(__file__).resolve().parents[2] / "shared" / "data"


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="python -m experiments.shelf_eval",
        description="Score 3D pose predictions on the Shelf test frames (actorsGT 300..600) under the "
                    "VoxelPose, JCSAT and 4D-association matching protocols.",
    )
    parser.add_argument("--pred", required=True, type=Path,
                        help="prediction file: JSON lines, a header line then one "
                             '{"frame", "person", "joints": 15x3 SHELF15 metres} object per person and frame '
                             "(frame = actorsGT index); see mocap/_predictions.py")
    parser.add_argument("--data-root", type=Path,
                        default=Path(os.environ.get("MVMOCAP_DATA_ROOT", _DEFAULT_DATA_ROOT)),
                        help="folder holding shelf/actorsGT.mat and shelf/4d_association/gt.txt "
                             "(default: $MVMOCAP_DATA_ROOT or %(default)s)")
    parser.add_argument("--protocol", choices=[*mocap.EVALUATION_PROTOCOLS, "all"], default="all",
                        help="matching convention: voxelpose (nearest by 14-joint MPJPE, <=, torso from "
                             "predicted hips), jcsat (0.5 m gate, first prediction wins, misses score 0, "
                             "strict), 4dassoc (Hungarian, unmatched GT not counted, strict), or all "
                             "(default)")
    parser.add_argument("--ground-truth", choices=["actorsGT", "4dassoc"], default="actorsGT",
                        help="actorsGT: shelf/actorsGT.mat (default); 4dassoc: the same GT from "
                             "shelf/4d_association/gt.txt, as JCSAT evaluates")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object {ground_truth, prediction_file, scores: [...]} instead "
                             "of the table")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        predictions = mocap.read_predictions(args.pred)
        ground_truth = mocap.shelf_evaluation_ground_truth(args.data_root, args.ground_truth)
        protocols = mocap.EVALUATION_PROTOCOLS if args.protocol == "all" else (args.protocol,)
        scores = [mocap.evaluate_shelf(predictions, ground_truth, p) for p in protocols]
    except (OSError, ValueError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps({"ground_truth": args.ground_truth, "prediction_file": str(args.pred),
                          "scores": [s.to_dict() for s in scores]}))
    else:
        print(f"{args.pred}: {predictions.num_predictions} predictions, ground truth {args.ground_truth}, "
              f"{len(ground_truth.frames)} frames")
        print(mocap.format_shelf_scores(scores))
    return 0


if __name__ == "__main__":
    sys.exit(main())

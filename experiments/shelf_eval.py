"""Score a Shelf prediction file (``mocap`` JSON-lines format) against the Shelf ground truth.

Prints, per matching protocol (``docs/protocols.md``), the per-actor PCP with part counts and
VoxelPose bone groups, joint precision / recall at 0.2 m, MPJPE and Recall@500mm, averaged over actors 1-3,
on the Shelf test frames (actorsGT 300..600). The 4D-association output converted with
``mocap.predictions_from_4dassoc`` gives A1-A3 PCP 99.7 / 91.4 / 97.7 (avg 96.27) under every protocol.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Literal

import mocap
from experiments import _cli


@dataclasses.dataclass(frozen=True)
class Config:
    pred: Path
    """Prediction file: JSON lines, a header line then one {"frame", "person", "joints": 15x3 SHELF15 metres}
    object per person and frame (frame = actorsGT index); see mocap/_predictions.py."""
    data_root: Path | None = None
    """Folder holding shelf/actorsGT.mat and shelf/4d_association/gt.txt (default: $MVMOCAP_DATA_ROOT)."""
    protocol: Literal[(*mocap.EVALUATION_PROTOCOLS, "all")] = "all"  # type: ignore[valid-type]
    """Matching convention: voxelpose (nearest by 14-joint MPJPE, <=, torso from predicted hips), jcsat (0.5 m
    gate, first prediction wins, misses score 0, strict), 4dassoc (Hungarian, unmatched GT not counted,
    strict), or all."""
    ground_truth: Literal["actorsGT", "4dassoc"] = "actorsGT"
    """actorsGT: shelf/actorsGT.mat; 4dassoc: the same GT from shelf/4d_association/gt.txt, as JCSAT evaluates."""
    json: bool = False
    """Print one JSON object {ground_truth, prediction_file, scores: [...]} instead of the table."""

    def __post_init__(self) -> None:
        if not self.pred.is_file():
            raise ValueError(f"--pred {self.pred} is not a file")
        if mocap.find_data_root(self.data_root, "shelf") is None:
            raise ValueError("no data folder: pass --data-root or set $MVMOCAP_DATA_ROOT (a folder with shelf/)")


def main(config: Config) -> None:
    predictions = mocap.read_predictions(config.pred)
    ground_truth = mocap.shelf_evaluation_ground_truth(mocap.find_data_root(config.data_root, "shelf"),
                                                       config.ground_truth)
    protocols = mocap.EVALUATION_PROTOCOLS if config.protocol == "all" else (config.protocol,)
    scores = [mocap.evaluate_shelf(predictions, ground_truth, p) for p in protocols]
    if config.json:
        print(json.dumps({"ground_truth": config.ground_truth, "prediction_file": str(config.pred),
                          "scores": [s.to_dict() for s in scores]}))
    else:
        print(f"{config.pred}: {predictions.num_predictions} predictions, ground truth {config.ground_truth}, "
              f"{len(ground_truth.frames)} frames")
        print(mocap.format_shelf_scores(scores))


if __name__ == "__main__":
    _cli.run(main, Config, description=__doc__)

"""Write the real Shelf test frames as a user's own recording would come: calibration and per-view detection files.

    python -m experiments.export_shelf --data-root ../shared/data --out runs/shelf_files

Writes OUT/calibration (the Shelf calibration, in --calibration-format: EasyMocap's intri.yml + extri.yml by
default, or calibration.toml or calibration.json in that folder) and OUT/keypoints (the real OpenPose detections of
actorsGT frames 300..600, --quick: 300..359, of the 5 cameras, in --keypoint-format: OpenPose JSON folders OUT/keypoints/<camera>/<frame>_keypoints.json by default,
or COCO keypoint results OUT/keypoints/<camera>.json), camera names "0".."4", files named by actorsGT frame.
``python -m experiments.reconstruct --calibration OUT/calibration --detections OUT/keypoints`` then runs the
pipeline on them as on any recording, and ``python -m experiments.shelf_eval --pred`` scores its predictions.
The OpenPose export holds every detection (the Shelf files have no zero-confidence candidate) but not the
part affinities, which the pipeline does not use; the COCO export drops the feet and rebuilds neck and mid-hip.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Literal

import geometry
import mocap
from experiments import _cli

_QUICK_FRAMES = 60
_CALIBRATION_FILE = {"easymocap": ".", "anipose": "calibration.toml", "voxelpose": "calibration.json",
                     "4dassociation": "calibration.json"}
"""Where in OUT/calibration each format's file goes (EasyMocap: the folder itself holds intri.yml and extri.yml)."""


@dataclasses.dataclass(frozen=True)
class Config:
    out: Path
    """Output folder (replaced as a whole)."""
    data_root: Path | None = None
    """Folder holding shelf/ (default: $MVMOCAP_DATA_ROOT)."""
    calibration_format: Literal[geometry.CALIBRATION_FORMATS] = "easymocap"  # type: ignore[valid-type]
    """Calibration file format (geometry.CALIBRATION_FORMATS): easymocap, anipose (translations in metres),
    voxelpose or 4dassociation (no distortion: refused for Shelf, whose cameras have some)."""
    keypoint_format: Literal["openpose", "coco"] = "openpose"
    """openpose: BODY25 OpenPose JSON per frame and camera; coco: COCO17 keypoint results per camera."""
    quick: bool = False
    """Frames 300..359 only."""

    def __post_init__(self) -> None:
        if mocap.find_data_root(self.data_root, "shelf") is None:
            raise ValueError("no data folder: pass --data-root or set $MVMOCAP_DATA_ROOT (a folder with shelf/)")


def main(config: Config) -> None:
    data_root = mocap.find_data_root(config.data_root, "shelf")
    rig = mocap.shelf_cameras(data_root)
    detections, frames = mocap.load_shelf_detections(data_root)
    if config.quick:
        detections, frames = detections[:_QUICK_FRAMES], frames[:_QUICK_FRAMES]
    cameras = tuple(str(view) for view in range(len(detections[0])))
    calibration = Path("calibration") / _CALIBRATION_FILE[config.calibration_format]
    with _cli.run_folder(config.out) as out:
        geometry.save_calibration(out / calibration, geometry.Calibration(rig, cameras), config.calibration_format)
        write = mocap.write_openpose_keypoints if config.keypoint_format == "openpose" else mocap.write_coco_keypoints
        write(out / "keypoints", detections, cameras, frame_numbers=frames)
    print(f"Shelf frames {frames[0]}..{frames[-1]}, {len(cameras)} cameras; reconstruct them with\n"
          f"python -m experiments.reconstruct --calibration {config.out / calibration} "
          f"--detections {config.out / 'keypoints'} --out DIR")


if __name__ == "__main__":
    _cli.run(main, Config, description=__doc__, float64=True)  # the calibration written to full precision

"""Reconstruct the people of your own multi-view recording in 3D: calibration and 2D detection files in, motion out.

    python -m experiments.reconstruct --calibration CALIB --detections KEYPOINTS --out DIR

CALIB is EasyMocap's intri.yml + extri.yml folder, anipose's calibration.toml, a VoxelPose or 4D-association
JSON or a folder of TUM P<i>.txt; KEYPOINTS a folder with one subfolder of OpenPose *_keypoints.json per camera
(BODY25 or COCO18) or one COCO-style keypoint results file <camera>.json per camera (mmpose, RTMPose: COCO17),
camera names as in the calibration. Runs the learning-free multi-person pipeline (Joint Cloud, people, tracks)
and the shipped JCSAT model on its tracks (--method geometric: the pipeline alone), with a progress bar, and
writes to DIR (replacing its previous outputs as a whole): predictions.jsonl, keypoints3d/<frame>.json, one
bvh/person_<id>.bvh per tracked person, viewer.html (open it in a browser; it needs no network), scene.gif,
frame.png, summary.json, config.json, log.jsonl and run.json. Installed as the console script
``mvmocap-reconstruct``. Logic: :mod:`experiments.reconstruct_study`.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from experiments import _cli
from experiments.reconstruct_study import ReconstructConfig, run_reconstruction

_STAGES = ("read", "method", "outputs")


@dataclasses.dataclass(frozen=True)
class Config(ReconstructConfig):
    """The reconstruction's options (:class:`experiments.reconstruct_study.ReconstructConfig`) and the run's."""

    out: Path = Path("runs/reconstruct")
    """Output folder."""


def main(config: Config) -> None:
    with _cli.run_folder(config.out) as out, _cli.stages(out, "reconstruct", _STAGES) as (log, progress):
        summary = run_reconstruction(ReconstructConfig(**{
            field.name: getattr(config, field.name) for field in dataclasses.fields(ReconstructConfig)}),
            out, log=log, progress=progress)
    people = ", ".join(f"{person} ({span['frames']} frames)" for person, span in summary["people"].items())
    print(f"{len(summary['people'])} people over {summary['frames']['count']} frames: {people or 'none'}")
    print(f"outputs in {config.out}/ (open {config.out}/viewer.html); total {summary['total_seconds']:.1f} s")


def cli() -> None:
    """The console script ``mvmocap-reconstruct``."""
    _cli.run(main, Config, description=__doc__, float64=True)


if __name__ == "__main__":
    cli()

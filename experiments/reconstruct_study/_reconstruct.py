"""The multi-person pipeline on a user's own recording: calibration and 2D detection files in, motion files out.

:func:`run_reconstruction` reads the calibration (:func:`geometry.load_calibration`: EasyMocap YAML, anipose TOML,
VoxelPose or 4D-association JSON, TUM P matrices) and the detections (:func:`mocap.load_keypoint_detections`:
OpenPose JSON folders per view, BODY25 or COCO18, or COCO-style keypoint results per view, COCO17), with the
detection views matched to the calibration's camera names; runs :func:`jcsat.reconstruct` (the learning-free
tracks, then the shipped or a given JCSAT model, or the geometric baseline alone) and writes, for every output
person (a track of the pipeline), in :data:`geometry.SHELF15` joints, metres, world z up:

- ``predictions.jsonl``: the project's prediction format (:func:`mocap.write_predictions`), which
  ``python -m experiments.shelf_eval --pred`` scores;
- ``keypoints3d/<frame>.json``: one file per frame in EasyMocap's ``keypoints3d`` layout, a list of
  ``{"id": person, "keypoints3d": [[x, y, z, c] x 15]}`` with c = 1 for a reconstructed joint, 0 for a missing one;
- ``bvh/person_<id>.bvh``: the person's joint rotations with fixed bone lengths (:func:`mocap.motion_from_joints`)
  over the frames from their first to their last appearance, in metres, y up, for Blender and other tools;
- ``viewer.html``: a self-contained interactive 3D view (skeletons over time, cameras as frusta);
- ``scene.gif`` (or ``.mp4``): the 3D scene over time; ``frame.png``: the frame with the most people, in 3D and
  reprojected into the views, with a legend;
- ``summary.json`` (inputs, people, frames, timings), ``config.json`` and ``log.jsonl``.

Frame numbers: :attr:`mocap.KeypointDetections.frame_numbers`, the integer in each frame's file name when every name
has one and they increase (OpenPose's ``000300_keypoints.json`` is frame 300; a COCO ``image_id``), else the
position 0, 1, ...
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Literal

import numpy as np

import geometry
import jcsat
import mocap
from association import BaselineConfig
from experiments.jcsat_study import plot_frame

__all__ = ["ReconstructConfig", "run_reconstruction"]


@dataclasses.dataclass(frozen=True)
class ReconstructConfig:
    """Everything that determines a reconstruction (saved as ``config.json``)."""

    calibration: Path
    """Calibration: a folder with EasyMocap's intri.yml and extri.yml, anipose's calibration.toml (or a folder
    holding it), a VoxelPose or 4D-association JSON file, or a folder of TUM P<i>.txt files."""
    detections: Path
    """2D keypoints: a folder with one subfolder of OpenPose *_keypoints.json files per camera (named as in the
    calibration), or a folder with one COCO-style keypoint results file <camera>.json per camera."""
    method: Literal["jcsat", "geometric"] = "jcsat"
    """jcsat: the JCSAT model on the learning-free pipeline's tracks; geometric: the learning-free pipeline alone."""
    model: Path | None = None
    """With --method jcsat: a model folder written by jcsat.train (default: the shipped model)."""
    keypoint_format: Literal["auto", "body25", "coco18", "coco17"] = "auto"
    """The detections' keypoint layout: auto recognises it from the keypoint count (75, 54 or 51 numbers)."""
    frames: Literal["index", "name"] = "index"
    """How the views' files are aligned into frames: index, the k-th file (natural order) of every view; name, the
    frame number in the file name (COCO: the image_id), keeping the frames every view has."""
    image_size: tuple[int, int] | None = None
    """Image width and height in pixels, for calibration formats that lack them (VoxelPose JSON, TUM P matrices)."""
    calibration_unit: float = 1.0
    """Metres per unit of the calibration's translations where the format leaves the unit open (anipose: the
    board's unit; 0.001 for millimetres)."""
    fps: float = 25.0
    """Frame rate of the recording (BVH frame time, viewer and animation speed)."""
    animation_frames: int = 150
    """Frames drawn into scene.gif, evenly spread over the recording (0: no animation)."""
    animation_format: Literal["gif", "mp4"] = "gif"
    """scene.gif (Pillow) or scene.mp4 (needs ffmpeg on the PATH)."""
    baseline: BaselineConfig = BaselineConfig()
    """The learning-free pipeline (Joint Cloud, people, tracks), as in the main job."""
    aggregate: str = jcsat.DEFAULT_AGGREGATE
    """With --method jcsat: how the model's windows become one pose per frame (jcsat.AGGREGATES)."""
    window_stride: int = jcsat.DEFAULT_WINDOW_STRIDE
    """With --method jcsat and aggregate mean: the window grid."""

    def __post_init__(self) -> None:
        if not Path(self.calibration).exists():
            raise ValueError(f"--calibration {self.calibration} does not exist")
        if not Path(self.detections).is_dir():
            raise ValueError(f"--detections {self.detections} is not a folder")
        if self.model is not None and self.method != "jcsat":
            raise ValueError("--model needs --method jcsat")
        if self.model is not None and not Path(self.model).is_dir():
            raise ValueError(f"--model {self.model} is not a folder")
        if self.image_size is not None and min(self.image_size) <= 0:
            raise ValueError(f"--image-size must be two positive pixel counts, got {self.image_size}")
        if not (self.calibration_unit > 0 and np.isfinite(self.calibration_unit)):
            raise ValueError(f"--calibration-unit must be a positive number of metres, got {self.calibration_unit}")
        if not (self.fps > 0 and np.isfinite(self.fps)):
            raise ValueError(f"--fps must be positive, got {self.fps}")
        if self.animation_frames < 0:
            raise ValueError(f"--animation-frames must be >= 0, got {self.animation_frames}")
        if self.aggregate not in jcsat.AGGREGATES:
            raise ValueError(f"--aggregate must be one of {jcsat.AGGREGATES}, got {self.aggregate!r}")
        if self.window_stride < 1:
            raise ValueError(f"--window-stride must be >= 1, got {self.window_stride}")


def write_keypoints3d(folder: Path, frames: np.ndarray, persons: np.ndarray, joints: np.ndarray,
                      present: np.ndarray) -> None:
    """One EasyMocap-style ``keypoints3d`` JSON file per frame (module docstring); joints (P, F, 15, 3) in metres."""
    folder.mkdir()
    reconstructed = np.any(joints != 0, axis=-1, keepdims=True)
    with_confidence = np.concatenate([joints, reconstructed.astype(float)], axis=-1).round(6)
    for f, frame in enumerate(frames):
        people = [{"id": int(persons[p]), "keypoints3d": with_confidence[p, f].tolist()}
                  for p in np.flatnonzero(present[:, f])]
        (folder / f"{int(frame):06d}.json").write_text(json.dumps(people) + "\n")


def write_person_bvh(folder: Path, persons: np.ndarray, joints: np.ndarray, present: np.ndarray,
                     fps: float) -> dict[int, dict]:
    """``person_<id>.bvh`` per person over their first..last frame; returns per person that span and the largest
    distance between a joint and the BVH's (the bone-length normalisation, :func:`mocap.motion_from_joints`)."""
    folder.mkdir()
    spans = {}
    for p, person in enumerate(persons):
        seen = np.flatnonzero(present[p])
        span = slice(int(seen[0]), int(seen[-1]) + 1)
        valid = present[p, span, None] & np.any(joints[p, span] != 0, axis=-1)  # (0, 0, 0): a missing joint
        motion = mocap.motion_from_joints(joints[p, span], geometry.SHELF15, fps=fps, valid=valid,
                                          name=f"person {person}")
        mocap.write_bvh(folder / f"person_{person}.bvh", motion.joint_names, motion.parents, motion.offsets,
                        motion.local_rotations, motion.root_positions, fps=fps, metres_per_unit=1.0)
        gap = np.linalg.norm(motion.positions[:, :geometry.SHELF15.num_joints] - joints[p, span], axis=-1)[valid]
        spans[int(person)] = {"first_frame": span.start, "frames": span.stop - span.start,
                              "max_joint_change_m": round(float(gap.max(initial=0.0)), 6)}
    return spans


def _plot(path: Path, config: ReconstructConfig, rig: geometry.Camera, detections: list[list[mocap.Detections]],
          run: jcsat.Reconstruction, frames: np.ndarray, persons: np.ndarray, joints: np.ndarray,
          present: np.ndarray) -> None:
    """``frame.png``: the first frame with the most people, in 3D and reprojected into the views."""
    frame = int(np.argmax(present.sum(axis=0)))
    track_poses = np.zeros((run.baseline.present.shape[0], geometry.SHELF15.num_joints, 3))
    track_poses[persons] = joints[:, frame]
    plot_frame(path, rig, mocap.pad_detections(detections, config.baseline.max_candidates), run.baseline, frame,
               None, title=f"{config.method}, frame {int(frames[frame])}", track_poses=track_poses)


def run_reconstruction(
    config: ReconstructConfig,
    out_dir: str | Path,
    log: Callable[[dict], None] = lambda event: None,
    progress: Callable[[str], None] = lambda stage: None,
) -> dict:
    """Run ``config`` and write its outputs (module docstring) to ``out_dir``; returns ``summary.json``'s content.
    ``log`` receives one JSON-ready dict per stage, ``progress`` each stage's name as it starts."""
    out = Path(out_dir)
    started = time.perf_counter()
    seconds: dict[str, float] = {}

    def stage(name: str, **fields) -> None:
        log({"stage": name, "elapsed_s": round(time.perf_counter() - started, 3), **fields})

    progress("read")
    tick = time.perf_counter()
    calibration = geometry.load_calibration(config.calibration, image_size=config.image_size,
                                            metres_per_unit=config.calibration_unit)
    keypoints = mocap.load_keypoint_detections(config.detections, views=calibration.names,
                                               keypoint_format=config.keypoint_format, frames=config.frames)
    frames = keypoints.frame_numbers
    model = (jcsat.load_model(jcsat.SHIPPED_MODEL if config.model is None else config.model)
             if config.method == "jcsat" else None)
    seconds["read"] = time.perf_counter() - tick
    stage("read", cameras=list(calibration.names), frames=len(frames), keypoint_format=keypoints.keypoint_format)
    (out / "config.json").write_text(json.dumps(dataclasses.asdict(config), indent=2, default=str) + "\n")

    progress(config.method)
    tick = time.perf_counter()
    run = jcsat.reconstruct(calibration.rig, keypoints.detections, frames, model, baseline=config.baseline,
                            aggregate=config.aggregate, stride=config.window_stride)
    seconds["reconstruct"] = time.perf_counter() - tick
    persons, joints, present = run.predictions.by_person(frames)
    stage(config.method, people=len(persons), rows=int(run.predictions.num_predictions),
          seconds={k: round(v, 3) for k, v in run.seconds.items()})

    progress("outputs")
    tick = time.perf_counter()
    mocap.write_predictions(out / "predictions.jsonl", run.predictions)
    write_keypoints3d(out / "keypoints3d", frames, persons, joints, present)
    bvh = write_person_bvh(out / "bvh", persons, joints, present, config.fps)
    labels = [f"person {person}" for person in persons]
    mocap.write_scene_html(out / "viewer.html", joints, present, geometry.SHELF15, calibration.rig, names=labels,
                           camera_names=calibration.names, fps=config.fps,
                           title=f"{config.method}: {config.detections}")
    if config.animation_frames:
        mocap.write_scene_animation(out / f"scene.{config.animation_format}", joints, present, geometry.SHELF15,
                                    calibration.rig, fps=config.fps, names=labels,
                                    max_frames=config.animation_frames)
    if len(persons):
        _plot(out / "frame.png", config, calibration.rig, keypoints.detections, run, frames, persons, joints, present)
    seconds["outputs"] = time.perf_counter() - tick
    summary = {
        "method": config.method, "model": None if model is None else str(config.model or jcsat.SHIPPED_MODEL),
        "cameras": list(calibration.names), "keypoint_format": keypoints.keypoint_format,
        "frames": {"count": len(frames), "first": int(frames[0]), "last": int(frames[-1])},
        "joints": list(geometry.SHELF15.joints), "people": bvh,
        "seconds": {k: round(v, 3) for k, v in {**run.seconds, **seconds}.items()},
        "total_seconds": round(time.perf_counter() - started, 3),
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    stage("done", total_seconds=summary["total_seconds"])
    return summary

"""JCSAT inference throughput: the shipped model and the paper's Medium configuration, side by side.

Runs the test-time pipeline (Joint Cloud, K-Means persons, tracks: :func:`association.run_geometric_baseline`)
on ``--frames`` Shelf frames (the real OpenPose detections with a data folder, ``--data-root`` or
``$MVMOCAP_DATA_ROOT``, else a synthetic 4-person Shelf-rig scene), then times the model on every (track, frame) window the main job
predicts, with :func:`jcsat.predict_shelf15`, after one compiling call,
best of ``--repeats``. Reports windows/s and frames/s (windows per frame = tracks output per frame)
for the shipped model with the main job's aggregate and window stride (``shipped``; ``"mean"`` runs the
full outputs of about 1/stride windows per frame) and with the causal ``"last"`` (``shipped_causal``), and for a randomly initialised Medium
model (``"last"``, same input, ``--medium-frames`` frames: it was about 500 times slower on CPU here), the
pipeline's own per-frame seconds (Joint Cloud, clustering, tracking, model tensor; second run), and the
end-to-end frames/s of the shipped configuration.
"""

from __future__ import annotations

import dataclasses
import json
import os
import platform
from pathlib import Path

import jax
import numpy as np
from flax import nnx

import association
import jcsat
import mocap
from experiments import _cli, jcsat_study
from experiments.bench_geometry import best_time


@dataclasses.dataclass(frozen=True)
class Config:
    json: bool = False
    """Print one JSON object instead of a text summary."""
    frames: int = 100
    """Shelf frames timed for the shipped model."""
    medium_frames: int = 4
    """Frames timed for Medium."""
    repeats: int = 3
    """Timed calls after compilation; the best counts."""
    model: Path = jcsat.SHIPPED_MODEL
    """The model folder (default: the shipped one)."""
    data_root: Path | None = None
    """Folder with shelf/ (default: $MVMOCAP_DATA_ROOT; without either, a synthetic scene)."""

    def __post_init__(self) -> None:
        for name in ("frames", "medium_frames", "repeats"):
            if getattr(self, name) < 1:
                raise ValueError(f"--{name.replace('_', '-')} must be >= 1, got {getattr(self, name)}")
        missing = [name for name in ("config.json", "state.npz") if not (self.model / name).is_file()]
        if missing:
            raise ValueError(f"--model {self.model} is not a saved model folder (no {' or '.join(missing)})")
        mocap.find_data_root(self.data_root, "shelf")


def main(config: Config) -> None:
    data_root = mocap.find_data_root(config.data_root, "shelf")
    if data_root is not None:
        detections, frame_indices = mocap.load_shelf_detections(data_root)
        rig, source = mocap.shelf_cameras(data_root), "real Shelf OpenPose detections"
        detections, frame_indices = detections[:config.frames], frame_indices[:config.frames]
    else:
        scene = mocap.synthesise_scene(jax.random.key(0), mocap.shelf_cameras(), num_people=4, num_frames=config.frames)
        detections, rig, frame_indices = scene.detections, scene.rig, np.arange(config.frames)
        source = "synthetic 4-person Shelf-rig scene"
    association.run_geometric_baseline(rig, detections, frame_indices)  # compiles; the second run is timed
    baseline = association.run_geometric_baseline(rig, detections, frame_indices)
    rows = baseline.predictions
    position = np.searchsorted(frame_indices, rows.frame)
    frames = len(frame_indices)

    result: dict = {
        "platform": platform.platform(), "processor": platform.processor(), "cpu_count": os.cpu_count(),
        "jax": jax.__version__, "backend": jax.default_backend(), "source": source, "frames": frames,
        "windows_per_frame": round(len(position) / frames, 3),
    }
    shipped = jcsat.load_model(config.model)
    default = jcsat_study.ShelfExperimentConfig()
    runs = {"shipped": (shipped, frames, default.aggregate, default.window_stride),
            "shipped_causal": (shipped, frames, "last", 1),
            "medium": (jcsat.JCSAT(jcsat.CONFIGS["medium"], rngs=nnx.Rngs(0)), min(config.medium_frames, frames), "last", 1)}
    result["shipped_aggregate"], result["shipped_window_stride"] = default.aggregate, default.window_stride
    for name, (model, timed_frames, aggregate, stride) in runs.items():
        chosen = position < timed_frames
        seconds = best_time(lambda: jcsat.predict_shelf15(model, baseline.person_cloud, rows.person[chosen],
                                                              position[chosen], aggregate=aggregate, stride=stride),
                            config.repeats)
        result[f"{name}_parameters"] = jcsat.parameter_count(model)
        result[f"{name}_windows_per_s"] = round(int(chosen.sum()) / seconds, 2)
        result[f"{name}_frames_per_s"] = round(timed_frames / seconds, 2)
    pipeline = sum(v for k, v in baseline.seconds.items() if k not in ("geometric", "assemble")) / frames
    result["pipeline_s_per_frame"] = round(pipeline, 4)
    result["shipped_end_to_end_frames_per_s"] = round(1.0 / (pipeline + 1.0 / result["shipped_frames_per_s"]), 2)
    if config.json:
        print(json.dumps(result))
    else:
        for key, value in result.items():
            print(f"{key:>40}: {value}")


if __name__ == "__main__":
    _cli.run(main, Config, description=__doc__, float64=True)

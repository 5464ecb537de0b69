"""Joint Cloud construction speed: the jitted, vmapped kernel against a plain NumPy/OpenCV loop.

Builds the Joint Cloud of ``--frames`` Shelf frames (five views, all 10 view pairs, 25 BODY25 joint
types; the real OpenPose detections with a data folder, ``--data-root`` or ``$MVMOCAP_DATA_ROOT``, else a
synthetic 4-person Shelf-rig scene) in one jitted call and reports the amortised time per frame (best of ``--repeats``, after the
compiling call; ``compile_s`` is that call's time minus the best call's), next to :func:`association.numpy_reference.numpy_joint_cloud_frame`
(a loop over pairs, joints and candidates with ``cv2.triangulatePoints``) timed on a few frames.
"""

from __future__ import annotations

import dataclasses
import json
import os
import platform
import time
from pathlib import Path

import jax
import numpy as np

import association
import mocap
from association.numpy_reference import numpy_joint_cloud_frame
from experiments import _cli


@dataclasses.dataclass(frozen=True)
class Config:
    json: bool = False
    """Print one JSON object instead of a text summary."""
    frames: int = 300
    """Frames per jitted call."""
    repeats: int = 5
    """Timed calls after compilation; the best counts."""
    numpy_frames: int = 3
    """Frames timed for the NumPy loop."""
    float32: bool = False
    """Run the kernel in float32 (default float64)."""
    data_root: Path | None = None
    """Folder with shelf/ (default: $MVMOCAP_DATA_ROOT; without either, a synthetic scene)."""

    def __post_init__(self) -> None:
        for name in ("frames", "repeats", "numpy_frames"):
            if getattr(self, name) < 1:
                raise ValueError(f"--{name.replace('_', '-')} must be >= 1, got {getattr(self, name)}")
        mocap.find_data_root(self.data_root, "shelf")


def main(config: Config) -> None:
    data_root = mocap.find_data_root(config.data_root, "shelf")
    if data_root is not None:
        detections, _ = mocap.load_shelf_detections(data_root)
        rig, source = mocap.shelf_cameras(data_root), "real Shelf OpenPose detections"
    else:
        scene = mocap.synthesise_scene(jax.random.key(0), mocap.shelf_cameras(), num_people=4, num_frames=config.frames)
        detections, rig, source = scene.detections, scene.rig, "synthetic 4-person Shelf-rig scene"
    detections = (detections * (config.frames // len(detections) + 1))[: config.frames]
    padded = mocap.pad_detections(detections)
    dtype = np.float32 if config.float32 else np.float64
    xy, score = padded.xy.astype(dtype), padded.score.astype(dtype)

    start = time.perf_counter()
    jax.block_until_ready(association.build_joint_cloud(rig, xy, score, padded.mask))
    compile_s = time.perf_counter() - start
    times = []
    for _ in range(config.repeats):
        start = time.perf_counter()
        cloud = jax.block_until_ready(association.build_joint_cloud(rig, xy, score, padded.mask))
        times.append(time.perf_counter() - start)
    jax_ms = 1000 * min(times) / config.frames

    start = time.perf_counter()
    for f in range(config.numpy_frames):
        numpy_joint_cloud_frame(rig, padded.xy[f], padded.score[f], padded.mask[f])
    numpy_ms = 1000 * (time.perf_counter() - start) / config.numpy_frames

    result = {
        "benchmark": "joint_cloud_construction",
        "source": source,
        "frames": config.frames,
        "views": int(xy.shape[1]),
        "view_pairs": int(cloud.valid.shape[1]),
        "padded_candidates_per_joint": int(xy.shape[3]),
        "mean_2d_candidates_per_view": float(padded.mask.sum() / (xy.shape[0] * xy.shape[1])),
        "grid_entries_per_frame": int(np.prod(cloud.valid.shape[1:])),
        "mean_valid_candidates_per_frame": float(np.asarray(cloud.valid).sum() / config.frames),
        "dtype": np.dtype(dtype).name,
        "compile_plus_first_call_s": round(compile_s, 3),
        "compile_s": round(compile_s - min(times), 3),
        "jax_ms_per_frame": round(jax_ms, 4),
        "numpy_loop_ms_per_frame": round(numpy_ms, 2),
        "speedup_vs_numpy": round(numpy_ms / jax_ms, 1),
        "devices": [str(d) for d in jax.devices()],
        "cpu_count": os.cpu_count(),
        "machine": platform.machine(),
    }
    if config.json:
        print(json.dumps(result, indent=2))
    else:
        for key, value in result.items():
            print(f"{key:>32}: {value}")


if __name__ == "__main__":
    _cli.run(main, Config, description=__doc__, float64=lambda config: not config.float32)

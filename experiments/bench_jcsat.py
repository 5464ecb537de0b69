"""JCSAT inference throughput: the shipped model and the paper's Medium configuration, side by side.

    .venv/bin/python -m experiments.bench_jcsat [--json] [--frames N] [--data-root PATH]

Runs the test-time pipeline (Joint Cloud, K-Means persons, tracks: :func:`association.run_geometric_baseline`)
on ``--frames`` Shelf frames (the real OpenPose detections when the data folder exists, else a
synthetic 4-person Shelf-rig scene), then times the model on every (track, frame) window the main job
predicts, with :func:`jcsat.predict_shelf15`, after one compiling call,
best of ``--repeats``. Reports windows/s and frames/s (windows per frame = tracks output per frame)
for the shipped model with the main job's aggregate and window stride (``shipped``; ``"mean"`` runs the
full outputs of about 1/stride windows per frame) and with the causal ``"last"`` (``shipped_causal``), and for a randomly initialised Medium
model (``"last"``, same input, ``--medium-frames`` frames: it was about 500 times slower on CPU here), the
pipeline's own per-frame seconds (Joint Cloud, clustering, tracking, model tensor; second run), and the
end-to-end frames/s of the shipped configuration.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

os.environ.setdefault("XLA_FLAGS", "--xla_cpu_experimental_ynn_fusion_type=")

import jax  # noqa: E402
import numpy as np  # noqa: E402
from flax import nnx  # noqa: E402

import association  # noqa: E402
import jcsat  # noqa: E402
from experiments import jcsat_study  # noqa: E402
import mocap  # noqa: E402
from experiments.bench_geometry import best_time  # noqa: E402

_DEFAULT_DATA_ROOT = Path(__file__).resolve().parents[2] / "shared" / "data"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m experiments.bench_jcsat", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of a text summary")
    parser.add_argument("--frames", type=int, default=100, help="Shelf frames timed for the shipped model "
                        "(default: %(default)s)")
    parser.add_argument("--medium-frames", type=int, default=4, help="frames timed for Medium (default: %(default)s)")
    parser.add_argument("--repeats", type=int, default=3, help="timed calls after compilation; the best counts")
    parser.add_argument("--model", type=Path, default=jcsat.SHIPPED_MODEL, help="the model folder (default: shipped)")
    parser.add_argument("--data-root", type=Path, default=Path(os.environ.get("MVMOCAP_DATA_ROOT", _DEFAULT_DATA_ROOT)),
                        help="folder with shelf/ (falls back to a synthetic scene without it)")
    args = parser.parse_args(argv)
    jax.config.update("jax_enable_x64", True)

    if (args.data_root / "shelf").is_dir():
        detections, frame_indices = mocap.load_shelf_detections(args.data_root)
        rig, source = mocap.shelf_cameras(args.data_root), "real Shelf OpenPose detections"
        detections, frame_indices = detections[:args.frames], frame_indices[:args.frames]
    else:
        scene = mocap.synthesize_scene(jax.random.key(0), mocap.shelf_cameras(), num_people=4, num_frames=args.frames)
        detections, rig, frame_indices = scene.detections, scene.rig, np.arange(args.frames)
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
    shipped = jcsat.load_model(args.model)
    default = jcsat_study.ShelfExperimentConfig()
    runs = {"shipped": (shipped, frames, default.aggregate, default.window_stride),
            "shipped_causal": (shipped, frames, "last", 1),
            "medium": (jcsat.JCSAT(jcsat.CONFIGS["medium"], rngs=nnx.Rngs(0)), min(args.medium_frames, frames), "last", 1)}
    result["shipped_aggregate"], result["shipped_window_stride"] = default.aggregate, default.window_stride
    for name, (model, timed_frames, aggregate, stride) in runs.items():
        chosen = position < timed_frames
        seconds = best_time(lambda: jcsat.predict_shelf15(model, baseline.person_cloud, rows.person[chosen],
                                                              position[chosen], aggregate=aggregate, stride=stride),
                            args.repeats)
        result[f"{name}_parameters"] = jcsat.parameter_count(model)
        result[f"{name}_windows_per_s"] = round(int(chosen.sum()) / seconds, 2)
        result[f"{name}_frames_per_s"] = round(timed_frames / seconds, 2)
    pipeline = sum(v for k, v in baseline.seconds.items() if k not in ("geometric", "assemble")) / frames
    result["pipeline_s_per_frame"] = round(pipeline, 4)
    result["shipped_end_to_end_frames_per_s"] = round(1.0 / (pipeline + 1.0 / result["shipped_frames_per_s"]), 2)
    if args.json:
        print(json.dumps(result))
    else:
        for key, value in result.items():
            print(f"{key:>40}: {value}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

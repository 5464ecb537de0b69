"""Joint Cloud construction speed: the jitted, vmapped kernel against a plain NumPy/OpenCV loop.

    .venv/bin/python -m experiments.bench_joint_cloud [--json] [--frames N] [--data-root PATH]

Builds the Joint Cloud of ``--frames`` Shelf frames (five views, all 10 view pairs, 25 BODY25 joint
types; the real OpenPose detections when the data folder exists, else a synthetic 4-person Shelf-rig
scene) in one jitted call and reports the amortised time per frame (best of ``--repeats``, after the
compiling call; ``compile_s`` is that call's time minus the best call's), next to
:func:`association.numpy_reference.numpy_joint_cloud_frame` (a loop over pairs, joints and candidates with
``cv2.triangulatePoints``) timed on a few frames.
"""

from __future__ import annotations

import os

_FLAG = "--xla_cpu_experimental_ynn_fusion_type="
if _FLAG not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = f"{os.environ.get('XLA_FLAGS', '')} {_FLAG}".strip()

import argparse  # noqa: E402
import json  # noqa: E402
import platform  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import jax  # noqa: E402
import numpy as np  # noqa: E402

import association  # noqa: E402
import mocap  # noqa: E402
from association.numpy_reference import numpy_joint_cloud_frame  # noqa: E402

_DEFAULT_DATA_ROOT = Path(__file__).resolve().parents[2] / "shared" / "data"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m experiments.bench_joint_cloud", description=__doc__.split("\n")[0])
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of a text summary")
    parser.add_argument("--frames", type=int, default=300, help="frames per jitted call (default: %(default)s)")
    parser.add_argument("--repeats", type=int, default=5, help="timed calls after compilation; the best counts")
    parser.add_argument("--numpy-frames", type=int, default=3, help="frames timed for the NumPy loop")
    parser.add_argument("--float32", action="store_true", help="run the kernel in float32 (default float64)")
    parser.add_argument("--data-root", type=Path, default=Path(os.environ.get("MVMOCAP_DATA_ROOT", _DEFAULT_DATA_ROOT)),
                        help="folder with shelf/ (falls back to a synthetic scene without it)")
    args = parser.parse_args(argv)
    jax.config.update("jax_enable_x64", not args.float32)

    if (args.data_root / "shelf").is_dir():
        detections, _ = mocap.load_shelf_detections(args.data_root)
        rig, source = mocap.shelf_cameras(args.data_root), "real Shelf OpenPose detections"
    else:
        scene = mocap.synthesize_scene(jax.random.key(0), mocap.shelf_cameras(), num_people=4, num_frames=args.frames)
        detections, rig, source = scene.detections, scene.rig, "synthetic 4-person Shelf-rig scene"
    detections = (detections * (args.frames // len(detections) + 1))[: args.frames]
    padded = mocap.pad_detections(detections)
    dtype = np.float32 if args.float32 else np.float64
    xy, score = padded.xy.astype(dtype), padded.score.astype(dtype)

    start = time.perf_counter()
    jax.block_until_ready(association.build_joint_cloud(rig, xy, score, padded.mask))
    compile_s = time.perf_counter() - start
    times = []
    for _ in range(args.repeats):
        start = time.perf_counter()
        cloud = jax.block_until_ready(association.build_joint_cloud(rig, xy, score, padded.mask))
        times.append(time.perf_counter() - start)
    jax_ms = 1000 * min(times) / args.frames

    start = time.perf_counter()
    for f in range(args.numpy_frames):
        numpy_joint_cloud_frame(rig, padded.xy[f], padded.score[f], padded.mask[f])
    numpy_ms = 1000 * (time.perf_counter() - start) / args.numpy_frames

    result = {
        "benchmark": "joint_cloud_construction",
        "source": source,
        "frames": args.frames,
        "views": int(xy.shape[1]),
        "view_pairs": int(cloud.valid.shape[1]),
        "padded_candidates_per_joint": int(xy.shape[3]),
        "mean_2d_candidates_per_view": float(padded.mask.sum() / (xy.shape[0] * xy.shape[1])),
        "grid_entries_per_frame": int(np.prod(cloud.valid.shape[1:])),
        "mean_valid_candidates_per_frame": float(np.asarray(cloud.valid).sum() / args.frames),
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
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        for key, value in result.items():
            print(f"{key:>32}: {value}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

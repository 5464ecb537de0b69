"""3D forecasting on the CMU-Mocap benchmark (``python -m experiments.dynamics_forecast``): the 3D forecasters,
ZeroMotion and constant velocity on every window of the evaluated files, per action and horizon.

A window is ``observed`` frames in and ``horizon`` frames predicted at :data:`~dynamics.FORECAST_FPS`, starting
every ``stride`` frames of a file (files shorter than a window give none), in the virtual camera frame of its
last observed frame (:func:`~dynamics.canonical_windows`). The score of a method at a horizon is the MPJPE (mm,
the body model's 24 joints after aligning the pelvises) at that predicted frame, averaged over the windows of an
action; "average" is the mean over the actions that have windows (as the benchmark's papers average them).
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import tqdm
from flax import nnx
from matplotlib.figure import Figure

import geometry
import training
from dynamics import (FORECAST_FPS, FORECAST_HORIZONS_MS, PoseForecaster, canonical_windows,
                      constant_velocity_forecast, forecast_joints, pose_frames, window_starts,
                      zero_motion_forecast)

__all__ = ["BASELINES", "forecast_markdown", "plot_forecast", "run_forecast_study"]

BASELINES: dict[str, Callable] = {"ZeroMotion": zero_motion_forecast, "Constant velocity": constant_velocity_forecast}
_CHUNK = 64
"""Windows per jitted forecast (the last chunk padded, so one compilation serves every chunk)."""


def _frames_of(milliseconds: int, fps: float) -> int:
    frames = milliseconds * fps / 1000.0
    if abs(frames - round(frames)) > 1e-9:
        raise ValueError(f"{milliseconds} ms is not a whole number of frames at {fps:g} Hz")
    return round(frames)


def _model_forecast(model: PoseForecaster, body: geometry.BodyModel, windows, observed: int, horizon: int
                    ) -> np.ndarray:
    @nnx.jit
    def run(model, rotations, betas, joints):
        return forecast_joints(model, body, rotations, betas, joints, horizon)

    past = jax.tree.map(lambda x: x[:, :, :observed], windows)
    chunks = []
    for first in range(0, len(past.joints3d), _CHUNK):
        chunk = jax.tree.map(lambda x: x[first: first + _CHUNK], past)
        size = len(chunk.joints3d)
        padded = jax.tree.map(lambda x: np.concatenate([x, np.repeat(x[-1:], _CHUNK - size, axis=0)]), chunk)
        chunks.append(np.asarray(run(model, padded.rotations, padded.betas, padded.joints3d))[:size])
    return np.concatenate(chunks)


def run_forecast_study(out: str | Path, models: Mapping[str, PoseForecaster], body: geometry.BodyModel,
                       files: Sequence[str | Path], *, observed: int = 25, stride: int = 10,
                       horizons_ms: Sequence[int] = FORECAST_HORIZONS_MS, fps: float = FORECAST_FPS,
                       cache_dir: str | Path | None = None, log: Callable[[dict], None] = lambda record: None,
                       progress: bool = True) -> dict:
    """Score ``models`` and :data:`BASELINES` on ``files`` (module docstring) and write ``out/results.json``,
    ``results.md`` and ``forecast.png``; returns the summary."""
    started = time.perf_counter()
    out = Path(out)
    horizon_frames = [_frames_of(ms, fps) for ms in horizons_ms]
    horizon = max(horizon_frames)
    files = [Path(file) for file in files]
    frames = pose_frames(files, body, fps, cache_dir, progress)
    starts = window_starts(frames, observed + horizon, stride)
    windows = canonical_windows(frames, starts, observed + horizon, observed)
    actions = np.asarray([files[track].parent.name for track in frames.track[starts]])
    truth = windows.joints3d[:, 0, observed:]
    predictions = {name: np.asarray(baseline(windows.joints3d[:, 0, :observed], horizon))
                   for name, baseline in BASELINES.items()}
    for name, model in tqdm.tqdm(models.items(), desc="forecasters", disable=not progress):
        predictions[name] = _model_forecast(model, body, windows, observed, horizon)[:, 0]
    errors = {name: 1000.0 * np.asarray(geometry.mpjpe_root_relative(jnp.asarray(p), jnp.asarray(truth), 0))
              for name, p in predictions.items()}  # (windows, horizon) mm
    every_action = sorted({file.parent.name for file in files})
    scored = [action for action in every_action if np.any(actions == action)]
    per_action = {name: {action: [float(np.mean(error[actions == action, k - 1])) for k in horizon_frames]
                         for action in scored} for name, error in errors.items()}
    summary = {
        "fps": fps, "observed_frames": observed, "horizons_ms": list(horizons_ms), "horizon_frames": horizon_frames,
        "stride": stride, "files": [str(file) for file in files],
        "windows": {action: int(np.sum(actions == action)) for action in every_action},
        "mpjpe_mm": {name: {**table, "average": np.mean(list(table.values()), axis=0).tolist()}
                     for name, table in per_action.items()},
        "mpjpe_mm_by_frame": {name: np.mean(error, axis=0).tolist() for name, error in errors.items()},
        "seconds": round(time.perf_counter() - started, 1),
    }
    log({"event": "forecast", "windows": len(starts), "seconds": summary["seconds"]})
    training.write_atomically(out / "results.json", lambda file: file.write(json.dumps(summary, indent=2).encode()))
    (out / "results.md").write_text(forecast_markdown(summary))
    plot_forecast(summary, out / "forecast.png")
    return summary


def forecast_markdown(summary: Mapping) -> str:
    """The average over actions, then one table per action: MPJPE (mm) of every method at every horizon."""
    header = ["| method | " + " | ".join(f"{ms} ms" for ms in summary["horizons_ms"]) + " |",
              "|---|" + "---|" * len(summary["horizons_ms"])]
    unscored = [action for action, count in summary["windows"].items() if count == 0]
    tables = {"average": "Average over actions"} | {action: action for action in summary["windows"]
                                                     if action not in unscored}
    lines = [f"MPJPE (mm, 24 body joints, pelvis aligned) at {summary['fps']:g} Hz after {summary['observed_frames']} "
             f"observed frames; windows every {summary['stride']} frames."]
    if unscored:
        lines.append(f"No window (file shorter than {summary['observed_frames'] + max(summary['horizon_frames'])} "
                     f"frames): {', '.join(unscored)}.")
    for key, title in tables.items():
        count = sum(summary["windows"].values()) if key == "average" else summary["windows"][key]
        lines += ["", f"## {title} ({count} windows)", "", *header]
        for method, table in summary["mpjpe_mm"].items():
            lines.append(f"| {method} | " + " | ".join(f"{value:.1f}" for value in table[key]) + " |")
    return "\n".join(lines) + "\n"


def plot_forecast(summary: Mapping, path: str | Path) -> None:
    """MPJPE against the prediction time, every window of every action, one line per method."""
    figure = Figure(figsize=(6, 3.8))
    axis = figure.subplots()
    for method, values in summary["mpjpe_mm_by_frame"].items():
        times = 1000.0 * np.arange(1, len(values) + 1) / summary["fps"]
        axis.plot(times, values, label=method, linestyle="--" if method in BASELINES else "-")
    axis.set_xlabel("prediction time (ms)")
    axis.set_ylabel("MPJPE (mm)")
    axis.set_title(f"3D forecasting after {summary['observed_frames']} observed frames ({summary['fps']:g} Hz)")
    axis.grid(alpha=0.3)
    axis.legend()
    figure.tight_layout()
    figure.savefig(path, dpi=100)

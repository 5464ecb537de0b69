"""3D forecasting on the CMU-Mocap benchmark (``python -m experiments.dynamics_forecast``): the 3D forecasters,
ZeroMotion and constant velocity on every window of the evaluated files, per action and horizon; or, on scenes of
two people (the CMU salsa pairs), per pair, with the interpenetration of every method's forecast.

A window is ``observed`` frames in and ``horizon`` frames predicted at :data:`~dynamics.FORECAST_FPS`, starting
every ``stride`` frames of a file (files shorter than a window give none), in the virtual camera frame of its
(first person's) last observed frame (:func:`~dynamics.canonical_scenes`). The score of a method at a horizon is
the MPJPE (mm, the body model's 24 joints after aligning the pelvises) at that predicted frame, averaged over the
windows (and people) of an action or pair; "average" is the mean over the actions that have windows (as the
benchmark's papers average them). Interpenetration (two people): the mean depth (mm) of a person's sampled
vertices inside the other's body capsules (:func:`~dynamics.penetration_mm`), averaged over people and windows, for
the forecasters, ZeroMotion (the last observed pose repeated) and the ground truth; constant velocity moves joints,
not a body, and has none.
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
import mocap
import training
from dynamics import (FORECAST_FPS, FORECAST_HORIZONS_MS, PoseForecaster, SMPLParams, canonical_scenes,
                      constant_velocity_forecast, params_to_joints, penetration_mm, pose_frames, scene_rows,
                      zero_motion_forecast)

from ._report import PENETRATION_TITLE, markdown_table

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
                    ) -> tuple[np.ndarray, np.ndarray | None]:
    """The joints ``(W, N, horizon, 24, 3)`` ``model`` predicts for the windows, and with two or more people their
    interpenetration ``(W, N, horizon)`` (mm)."""
    people = windows.joints3d.shape[1]

    @nnx.jit
    def run(model, rotations, betas, joints):
        rollout = model.rollout(body, model.observe(rotations, betas, joints), horizon)
        depths = penetration_mm(body, rollout.params, rollout.root) if people > 1 else None
        return params_to_joints(body, rollout.params, rollout.root), depths

    past = jax.tree.map(lambda x: x[:, :, :observed], windows)
    chunks = []
    for first in range(0, len(past.joints3d), _CHUNK):
        chunk = jax.tree.map(lambda x: x[first: first + _CHUNK], past)
        size = len(chunk.joints3d)
        padded = jax.tree.map(lambda x: np.concatenate([x, np.repeat(x[-1:], _CHUNK - size, axis=0)]), chunk)
        chunks.append(jax.tree.map(lambda x: np.asarray(x)[:size],
                                   run(model, padded.rotations, padded.betas, padded.joints3d)))
    joints, depths = zip(*chunks)
    return np.concatenate(joints), None if people == 1 else np.concatenate(depths)


def _baseline_depths(body: geometry.BodyModel, windows, observed: int, horizon: int) -> dict[str, np.ndarray]:
    """The interpenetration (mm, ``(W, N, horizon)``) of the true future and of ZeroMotion's."""
    params = SMPLParams(geometry.matrix_to_rotation_6d(jnp.asarray(windows.rotations)), jnp.asarray(windows.betas),
                        jnp.zeros(windows.joints3d.shape[:-2], jnp.float32))
    root = jnp.asarray(windows.joints3d[..., 0, :])
    future = lambda x: x[:, :, observed:observed + horizon]  # noqa: E731
    last = lambda x: jnp.repeat(x[:, :, observed - 1:observed], horizon, axis=2)  # noqa: E731
    depths = jax.jit(lambda params, root: penetration_mm(body, params, root))
    return {"ZeroMotion": np.asarray(depths(jax.tree.map(last, params), last(root))),
            "ground truth": np.asarray(depths(jax.tree.map(future, params), future(root)))}


def _group_of(source: str | Path, people: int) -> str:
    """The table a recording's windows are averaged in: its action (the folder of a benchmark file), or the pair."""
    files = mocap.clip_files(str(source)) or (Path(source),)
    return files[0].parent.name if people == 1 else "+".join(file.stem for file in files)


def run_forecast_study(out: str | Path, models: Mapping[str, PoseForecaster], body: geometry.BodyModel,
                       files: Sequence[str | Path], *, people: int = 1, observed: int = 25, stride: int = 10,
                       horizons_ms: Sequence[int] = FORECAST_HORIZONS_MS, fps: float = FORECAST_FPS,
                       cache_dir: str | Path | None = None, log: Callable[[dict], None] = lambda record: None,
                       progress: bool = True) -> dict:
    """Score ``models`` and :data:`BASELINES` on ``files`` (module docstring; with ``people=2``, recordings of two
    people captured together, their files joined by ``+``) and write ``out/results.json``, ``results.md`` and
    ``forecast.png``; returns the summary."""
    started = time.perf_counter()
    out = Path(out)
    horizon_frames = [_frames_of(ms, fps) for ms in horizons_ms]
    horizon = max(horizon_frames)
    frames = pose_frames(files, body, fps, cache_dir, progress)
    rows = scene_rows(frames, observed + horizon, people, stride)
    windows = canonical_scenes(frames, rows, observed)
    labels = [_group_of(file, people) for file in files]
    groups = np.asarray([labels[video] for video in frames.video[rows[:, 0, 0]]])
    truth = windows.joints3d[:, :, observed:]
    predictions = {name: np.asarray(baseline(windows.joints3d[:, :, :observed], horizon))
                   for name, baseline in BASELINES.items()}
    depths = _baseline_depths(body, windows, observed, horizon) if people > 1 else {}
    for name, model in tqdm.tqdm(models.items(), desc="forecasters", disable=not progress):
        predictions[name], depth = _model_forecast(model, body, windows, observed, horizon)
        if depth is not None:
            depths[name] = depth
    errors = {name: 1000.0 * np.mean(np.asarray(geometry.mpjpe_root_relative(jnp.asarray(p), jnp.asarray(truth), 0)),
                                     axis=1) for name, p in predictions.items()}  # (windows, horizon) mm
    every_group = sorted(set(labels))
    scored = [group for group in every_group if np.any(groups == group)]
    per_group = {name: {group: [float(np.mean(error[groups == group, k - 1])) for k in horizon_frames]
                        for group in scored} for name, error in errors.items()}
    summary = {
        "fps": fps, "observed_frames": observed, "horizons_ms": list(horizons_ms), "horizon_frames": horizon_frames,
        "stride": stride, "people": people, "files": [str(file) for file in files],
        "windows": {group: int(np.sum(groups == group)) for group in every_group},
        "mpjpe_mm": {name: {**table, "average": np.mean(list(table.values()), axis=0).tolist()}
                     for name, table in per_group.items()},
        "mpjpe_mm_by_frame": {name: np.mean(error, axis=0).tolist() for name, error in errors.items()},
    }
    if depths:
        summary["penetration_mm"] = {name: [float(np.mean(depth[:, :, k - 1])) for k in horizon_frames]
                                     for name, depth in depths.items()}
    summary["seconds"] = round(time.perf_counter() - started, 1)
    log({"event": "forecast", "windows": len(rows), "seconds": summary["seconds"]})
    training.write_atomically(out / "results.json", lambda file: file.write(json.dumps(summary, indent=2).encode()))
    (out / "results.md").write_text(forecast_markdown(summary))
    plot_forecast(summary, out / "forecast.png")
    return summary


def forecast_markdown(summary: Mapping) -> str:
    """The average over actions (pairs), then one table per action (pair): MPJPE (mm) of every method at every
    horizon; then the interpenetration of two-person scenes."""
    horizons = [f"{ms} ms" for ms in summary["horizons_ms"]]
    unscored = [action for action, count in summary["windows"].items() if count == 0]
    groups = "actions" if summary["people"] == 1 else "pairs"
    tables = {"average": f"Average over {groups}"} | {group: group for group in summary["windows"]
                                                      if group not in unscored}
    lines = [f"MPJPE (mm, 24 body joints, pelvis aligned) at {summary['fps']:g} Hz after {summary['observed_frames']} "
             f"observed frames; windows every {summary['stride']} frames."]
    if unscored:
        lines.append(f"No window (file shorter than {summary['observed_frames'] + max(summary['horizon_frames'])} "
                     f"frames): {', '.join(unscored)}.")
    for key, title in tables.items():
        count = sum(summary["windows"].values()) if key == "average" else summary["windows"][key]
        lines += markdown_table(f"{title} ({count} windows)", horizons, {
            method: [f"{value:.1f}" for value in table[key]] for method, table in summary["mpjpe_mm"].items()})
    if "penetration_mm" in summary:
        lines += markdown_table(PENETRATION_TITLE, horizons, {
            method: [f"{value:.2f}" for value in values] for method, values in summary["penetration_mm"].items()})
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
    scenes = "" if summary["people"] == 1 else f", scenes of {summary['people']} people"
    axis.set_title(f"3D forecasting after {summary['observed_frames']} observed frames ({summary['fps']:g} Hz{scenes})")
    axis.grid(alpha=0.3)
    axis.legend()
    figure.tight_layout()
    figure.savefig(path, dpi=100)

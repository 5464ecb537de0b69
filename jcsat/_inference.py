"""JCSAT inference on tracked people: windows of N frames per output frame (paper Sect. 4.1.3).

For track k and frame t the model sees the window of frames ``t - N + 1 .. t`` (clamped at the first
frame, :func:`~association.window_frames`), centred on the track's cluster centre in the window's first
frame, as in training (:func:`~jcsat.window_batch`, without the rotation). ``aggregate="last"``
(causal, online): the prediction of the window's last frame, plus that centre, is the pose at t.
``aggregate="mean"`` (offline): the pose at t is the mean of frame t's predictions by the windows of the
track that contain t (ending at t .. t + N - 1), end on the grid of every ``stride``-th frame counted back
from the last, and end at a frame where the track is present; t's own causal window if there is none.
A stride s runs about 1/s of the windows, each for all N frames. A track absent from a window's first frame (it starts later, or a gap was bridged)
takes the centre of its nearest frame with one.

:func:`reconstruct` is the whole multi-person pipeline on arrays: the learning-free tracks of
:func:`association.run_geometric_baseline`, then (with a model) the model on every output row of those tracks.
"""

from __future__ import annotations

import time
from functools import partial
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx
from jaxtyping import Array, Float, Int

import mocap
from association import (
    BaselineConfig,
    BaselineResult,
    PersonJointCloud,
    filled_centres,
    run_geometric_baseline,
    window_frames,
)
from geometry import Camera

from ._model import JCSAT

__all__ = ["AGGREGATES", "DEFAULT_AGGREGATE", "DEFAULT_WINDOW_STRIDE", "Reconstruction", "predict_shelf15",
           "reconstruct"]

AGGREGATES: tuple[str, ...] = ("last", "mean")
"""How :func:`predict_shelf15` turns window predictions into one pose per frame (see the module docstring)."""
DEFAULT_AGGREGATE = "mean"
"""The main job's aggregate: ``"mean"`` (offline) scores better than ``"last"`` (causal, online) on synthetic
validation (``python -m experiments.shelf_validate --jcsat``; ``docs/jcsat.md``)."""
DEFAULT_WINDOW_STRIDE = 3
"""The main job's window grid for ``"mean"``: strides 1, 2 and 3 score alike on synthetic validation
(``shelf_validate --jcsat``; ``docs/jcsat.md``), and 3 runs a third of the windows, for the frame rate
(``bench_jcsat``)."""


@partial(jax.jit, static_argnames=("graphdef", "last_frame_only"))
def _predict(graphdef: nnx.GraphDef, state: Any, points: Array, mask: Array, last_frame_only: bool) -> Array:
    return nnx.merge(graphdef, state)(points, mask, last_frame_only=last_frame_only)


def predict_shelf15(
    model: JCSAT,
    tracks: PersonJointCloud,
    track: Int[np.ndarray, " R"],
    frame: Int[np.ndarray, " R"],
    *,
    batch_size: int = 64,
    aggregate: str = "last",
    stride: int = 1,
) -> Float[np.ndarray, "R 15 3"]:
    """Shelf15 world joints (metres) of track ``track[r]`` at frame ``frame[r]`` (frame positions 0..F-1).

    ``aggregate``: one of :data:`AGGREGATES`; ``stride``: the window grid of ``"mean"`` (module docstring).
    Windows are run ``batch_size`` at a time (the last batch padded), so every call compiles once.
    """
    track, frame = np.asarray(track, np.int64), np.asarray(frame, np.int64)
    if track.shape != frame.shape or track.ndim != 1:
        raise ValueError(f"track and frame must be equal-length vectors, got {track.shape} and {frame.shape}")
    if aggregate not in AGGREGATES:
        raise ValueError(f"aggregate must be one of {AGGREGATES}, got {aggregate!r}")
    if not 1 <= stride <= model.config.frames:
        raise ValueError(f"stride must be in [1, {model.config.frames}] (the window length), got {stride}")
    num_tracks, num_frames = tracks.present.shape
    if len(track) and (track.min() < 0 or track.max() >= num_tracks or frame.min() < 0 or frame.max() >= num_frames):
        raise ValueError(f"rows outside the {num_tracks} tracks x {num_frames} frames")
    if aggregate == "last":
        return _window_predictions(model, tracks, track, frame, batch_size, last_frame_only=True)[:, -1]
    window = model.config.frames
    # The window ending at frame + lag predicts `frame` at position N - 1 - lag.
    lag = np.arange(window)
    end = frame[:, None] + lag[None, :]  # (R, N)
    present = np.asarray(tracks.present)[track[:, None], np.minimum(end, num_frames - 1)]
    usable = (end < num_frames) & ((num_frames - 1 - end) % stride == 0) & present
    usable[:, 0] |= ~usable.any(axis=1)
    keys = np.unique(np.stack([np.repeat(track, window)[usable.ravel()], end.ravel()[usable.ravel()]], axis=1), axis=0)
    predictions = _window_predictions(model, tracks, keys[:, 0], keys[:, 1], batch_size, last_frame_only=False)
    index = {(int(k), int(t)): i for i, (k, t) in enumerate(keys)}
    poses = np.zeros((len(track), 15, 3))
    for r in range(len(track)):
        lags = lag[usable[r]]
        rows = [index[(int(track[r]), int(frame[r] + d))] for d in lags]
        poses[r] = predictions[rows, window - 1 - lags].mean(axis=0)
    return poses


def _window_predictions(
    model: JCSAT, tracks: PersonJointCloud, track: np.ndarray, frame: np.ndarray, batch_size: int, last_frame_only: bool
) -> Float[np.ndarray, "R n 15 3"]:
    """World Shelf15 predictions of the causal windows ending at ``frame`` of ``track``: every frame's, or with
    ``last_frame_only`` the last frame's alone (N = 1 in the output)."""
    window = model.config.frames
    rows = window_frames(tracks.present.shape[1], window)[frame]  # (R, N)
    centre = filled_centres(tracks.present, tracks.centre)[track, rows[:, 0]]  # (R, 3)
    points, mask = np.asarray(tracks.points), np.asarray(tracks.mask)
    graphdef, state = nnx.split(model)
    out = np.zeros((len(track), 1 if last_frame_only else window, 15, 3))
    for start in range(0, len(track), batch_size):
        chunk = slice(start, start + batch_size)
        count = len(track[chunk])
        pad = batch_size - count
        window_mask = mask[track[chunk, None], rows[chunk]]  # (b, N, P, M, J)
        window_points = points[track[chunk, None], rows[chunk]] - centre[chunk, None, None, None, None, :]
        window_points = np.where(window_mask[..., None], window_points, 0.0).astype(np.float32)
        window_points = np.concatenate([window_points, np.zeros((pad,) + window_points.shape[1:], np.float32)])
        window_mask = np.concatenate([window_mask, np.zeros((pad,) + window_mask.shape[1:], bool)])
        predicted = _predict(graphdef, state, jnp.asarray(window_points), jnp.asarray(window_mask), last_frame_only)
        out[chunk] = np.asarray(predicted, float)[:count] + centre[chunk, None, None, :]
    return out


class Reconstruction(NamedTuple):
    """What :func:`reconstruct` returns."""

    predictions: mocap.PosePredictions
    """The method's Shelf15 poses (metres), one row per output track and frame: the baseline's rows, re-posed by
    the model when there is one."""
    baseline: BaselineResult
    """The learning-free pipeline's result: its tracks, Joint Cloud and its own predictions."""
    seconds: dict[str, float]
    """Wall time of each stage, the model's as ``"jcsat"`` (compilation included on the first call)."""


def reconstruct(
    rig: Camera,
    detections: list[list[mocap.Detections]],
    frame_indices: Int[np.ndarray, " F"],
    model: JCSAT | None = None,
    *,
    baseline: BaselineConfig = BaselineConfig(),
    aggregate: str = DEFAULT_AGGREGATE,
    stride: int = DEFAULT_WINDOW_STRIDE,
) -> Reconstruction:
    """People in 3D from calibrated multi-view BODY25 detections ``detections[frame][view]`` seen by ``rig``.

    The learning-free pipeline (:func:`association.run_geometric_baseline` with ``baseline``) finds the people,
    tracks them and poses them; with a ``model`` (:func:`load_model`), the model then re-poses every output row
    from its track's Joint Cloud windows (:func:`predict_shelf15` with ``aggregate`` and ``stride``), keeping the
    baseline's rows, ranks and supports. ``frame_indices[f]`` is the frame number written into the predictions.
    """
    if model is not None:  # before the baseline's work
        if aggregate not in AGGREGATES:
            raise ValueError(f"aggregate must be one of {AGGREGATES}, got {aggregate!r}")
        if not 1 <= stride <= model.config.frames:
            raise ValueError(f"stride must be in [1, {model.config.frames}] (the window length), got {stride}")
    result = run_geometric_baseline(rig, detections, frame_indices, baseline)
    seconds = dict(result.seconds)
    if model is None:
        return Reconstruction(result.predictions, result, seconds)
    rows = result.predictions
    position = np.searchsorted(np.asarray(frame_indices), rows.frame)
    start = time.perf_counter()
    poses = predict_shelf15(model, result.person_cloud, rows.person, position, aggregate=aggregate, stride=stride)
    seconds["jcsat"] = time.perf_counter() - start
    return Reconstruction(mocap.PosePredictions.create(rows.frame, rows.person, poses, score=rows.score), result,
                          seconds)

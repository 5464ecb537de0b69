"""JCSAT inference on tracked people: a causal window of N frames per output frame (paper Sect. 4.1.3).

For track k and frame t the model sees the window of frames ``t - N + 1 .. t`` (clamped at the first
frame, :func:`~jcsat.window_frames`), centred on the track's cluster centre in the window's first
frame, as in training (:func:`~jcsat.window_batch`, without the rotation); the prediction of the
window's last frame, plus that centre, is the pose at t. A track absent from the window's first frame
(it starts later, or a gap was bridged) takes the centre of its nearest frame with one.
"""

from __future__ import annotations

from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx
from jaxtyping import Array, Bool, Float, Int

from ._clustering import PersonJointCloud, window_frames
from ._geometric import fill_missing
from ._model import JCSAT

__all__ = ["filled_centres", "predict_shelf15"]


def filled_centres(present: Bool[np.ndarray, "T F"], centre: Float[np.ndarray, "T F 3"]) -> Float[np.ndarray, "T F 3"]:
    """Each track's cluster centre in every frame, taken from its nearest frame (earlier on ties) where it is present."""
    every_frame = np.ones(present.shape[1], bool)
    return np.stack([fill_missing(c[:, None, :], p[:, None], every_frame)[0][:, 0] for p, c in zip(present, centre)])


@partial(jax.jit, static_argnames=("graphdef",))
def _last_frame(graphdef: nnx.GraphDef, state: Any, points: Array, mask: Array) -> Array:
    return nnx.merge(graphdef, state)(points, mask, last_frame_only=True)[:, -1]


def predict_shelf15(
    model: JCSAT,
    tracks: PersonJointCloud,
    track: Int[np.ndarray, " R"],
    frame: Int[np.ndarray, " R"],
    *,
    batch_size: int = 64,
) -> Float[np.ndarray, "R 15 3"]:
    """Shelf15 world joints (metres) of track ``track[r]`` at frame ``frame[r]`` (frame positions 0..F-1).

    Windows are run ``batch_size`` at a time (the last batch padded), so every call compiles once.
    """
    track, frame = np.asarray(track, np.int64), np.asarray(frame, np.int64)
    if track.shape != frame.shape or track.ndim != 1:
        raise ValueError(f"track and frame must be equal-length vectors, got {track.shape} and {frame.shape}")
    num_tracks, num_frames = tracks.present.shape
    if len(track) and (track.min() < 0 or track.max() >= num_tracks or frame.min() < 0 or frame.max() >= num_frames):
        raise ValueError(f"rows outside the {num_tracks} tracks x {num_frames} frames")
    window = model.config.frames
    rows = window_frames(num_frames, window)[frame]  # (R, N)
    centre = filled_centres(tracks.present, tracks.centre)[track, rows[:, 0]]  # (R, 3)
    points, mask = np.asarray(tracks.points), np.asarray(tracks.mask)
    graphdef, state = nnx.split(model)
    out = np.zeros((len(track), 15, 3))
    for start in range(0, len(track), batch_size):
        chunk = slice(start, start + batch_size)
        count = len(track[chunk])
        pad = batch_size - count
        window_mask = mask[track[chunk, None], rows[chunk]]  # (b, N, P, M, J)
        window_points = points[track[chunk, None], rows[chunk]] - centre[chunk, None, None, None, None, :]
        window_points = np.where(window_mask[..., None], window_points, 0.0).astype(np.float32)
        window_points = np.concatenate([window_points, np.zeros((pad,) + window_points.shape[1:], np.float32)])
        window_mask = np.concatenate([window_mask, np.zeros((pad,) + window_mask.shape[1:], bool)])
        last = _last_frame(graphdef, state, jnp.asarray(window_points), jnp.asarray(window_mask))
        out[chunk] = np.asarray(last, float)[:count] + centre[chunk, None, :]
    return out

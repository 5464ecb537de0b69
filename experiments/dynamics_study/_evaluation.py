"""The dynamics experiment (``python -m experiments.dynamics``): the models and ZeroMotion on held-out synthetic videos.

:func:`run_experiment` renders the test clips (:class:`~dynamics.EvalConfig`: the held-out shipped clips, or any
clips and motion files), computes the backbone features of their crops, scores every window
(:func:`~dynamics.predict_windows`; a clip's samples are two-person ones when it holds two people) and writes to
``out``: ``results.json`` (the configuration, the summary at every future frame, the timings), ``results.md`` (the
tables), ``prediction_<group>.png`` (Fig. 5.1 per sample group) and ``strip.png`` (the first window of the first
two-person clip, else of the first clip, freshly rendered: a row per method, titled on the left - the video, each
model's meshes and ZeroMotion's over it - and a column per frame of :data:`STRIP_FRAMES`, titled above by its place
relative to the last observed frame t: ``observed t-12``, ``observed t``, ``predicted t+1``, ...).
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import cv2
import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx
from jaxtyping import Array, Float

import geometry
import mocap
import training
from dynamics import (EvalConfig, build_frames, check_crop_sizes, compute_features, crop_square, forecast_scenes,
                      predict_windows, square_boxes, summarise, video_tracks, zero_motion)

from ._report import overlay_meshes, plot_prediction, results_markdown

__all__ = ["STRIP_FRAMES", "STRIP_SIZE", "run_experiment", "write_strip"]

STRIP_FRAMES: tuple[int, ...] = (12, 24, 25, 29, 34, 44, 54)
"""Window frames shown in the strip: two observed, then future frames 1, 5, 10, 20 and 30."""
STRIP_SIZE = 240
"""Pixels per strip image: the region around the people, enlarged."""
_TITLE_FONT = (cv2.FONT_HERSHEY_SIMPLEX, 0.6, 1)
"""Face, scale and thickness of the strip's titles: about 11 pixels a character, a 14-character title in a column."""
_TITLE_PAD = 8
"""Pixels of white around a title."""


def run_experiment(out: str | Path, backbone, models: Mapping[str, nnx.Module], body: geometry.BodyModel,
                   config: EvalConfig, *, log: Callable[[dict], None] = lambda record: None,
                   progress: bool = True) -> dict:
    """Evaluate ``models`` (name -> PHD+T or a transformer; ZeroMotion repeats the first one's last observed
    frame) and write the outputs listed in the module docstring; returns the ``results.json`` content."""
    check_crop_sizes(backbone.crop_size, data=config.data)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    frames = build_frames(config.data, body, progress=progress)
    features = compute_features(backbone, frames.crops, progress=progress)
    windows = predict_windows(body, models, features, frames, config)
    summary = summarise(windows)
    seconds = round(time.perf_counter() - start, 1)
    results = {"config": training.to_jsonable(dataclasses.asdict(config)), "summary": summary, "seconds": seconds}
    (out / "results.json").write_text(json.dumps(results, indent=1) + "\n")
    (out / "results.md").write_text(results_markdown(summary))
    for group in summary:
        plot_prediction(summary, group, out / f"prediction_{group}.png")
    # The strip shows the first clip with the most people of those long enough for a window (some are: windows were
    # scored).
    long_enough = [c for c in range(len(config.data.clips))
                   if np.max(frames.frame[frames.clip == c]) + 1 >= config.length]
    shown = max(long_enough, key=lambda c: np.max(frames.person[frames.clip == c]))
    strip = write_strip(backbone, models, body, config, mocap.shared_clip(config.data.clips[shown]))
    cv2.imwrite(str(out / "strip.png"), strip[..., ::-1])
    log({"event": "dynamics_experiment", "seconds": seconds})
    return results


def write_strip(backbone, models: Mapping[str, nnx.Module], body: geometry.BodyModel, config: EvalConfig,
                clip: mocap.Clip) -> np.ndarray:
    """Rows: the video, then each model's meshes over it, then ZeroMotion's (from the first model); columns:
    :data:`STRIP_FRAMES` of the first window of ``clip`` freshly rendered, each cropped to the people. Each row is
    titled on its left (``video``, the model's name, ``ZeroMotion``), each column above it (the frame relative to
    the last observed one, t). RGB uint8."""
    rng = np.random.default_rng(config.data.seed)
    motion = mocap.retarget_clip(clip, body, rng.normal(0.0, config.data.shape_std, (clip.num_people, body.num_shapes)))
    motion = motion._replace(rotations=motion.rotations[:, :config.length],
                             translation=motion.translation[:, :config.length])
    video = mocap.synthesise_video(motion, body, config.data.video, rng)
    tracks = video_tracks(video, config.data, rng)
    scene = (1, clip.num_people, config.length)
    features = np.asarray(compute_features(backbone, tracks.crops)).reshape(*scene, -1)
    rows = jax.tree.map(lambda x: np.asarray(x).reshape(*scene, *x.shape[1:]),
                        tracks._replace(crops=np.zeros(tracks.num_frames, np.uint8)))
    T = config.observed
    shown = video.boxes[:, list(STRIP_FRAMES)]
    region = square_boxes(np.concatenate([shown[..., :2].min(axis=(0, 1)), shown[..., 2:].max(axis=(0, 1))]), 1.2)
    zoom = lambda image: crop_square(image, region, STRIP_SIZE)  # noqa: E731  (the people, not the empty scene)
    strip = [[zoom(video.frames[t]) for t in STRIP_FRAMES]]
    present = np.ones(scene[:2], bool)
    predictions = [forecast_scenes(model, body, features, rows.boxes, rows.K, present, T, config.horizon)
                   for model in models.values()]
    predictions.append((predictions[0][0], zero_motion(predictions[0][0], config.horizon)))
    for seen, rollout in predictions:
        # Scene arrays are (1, N, frames, ...): join observed and predicted frames on axis 2.
        params = jax.tree.map(lambda past, future: np.concatenate([past, future], axis=2)[0], seen.params,
                              rollout.params)
        roots = np.concatenate([seen.root, rollout.root], axis=2)[0]
        shown_frames = np.asarray(STRIP_FRAMES)
        meshes = np.asarray(_meshes(body, params.rot6d[:, shown_frames], params.betas[:, shown_frames],
                                    roots[:, shown_frames]))  # (people, shown frames, vertices, 3)
        strip.append([zoom(overlay_meshes(video.frames[t], np.asarray(video.camera.K[t]), list(meshes[:, column]), body))
                      for column, t in enumerate(STRIP_FRAMES)])
    return _titled(strip, ["video", *models, "ZeroMotion"], [_frame_title(t, T) for t in STRIP_FRAMES])


def _frame_title(frame: int, observed: int) -> str:
    """Window frame ``frame`` named by its place relative to the last of the ``observed`` frames, t."""
    offset = frame - (observed - 1)
    return f"observed t{offset:+d}" if offset < 0 else "observed t" if offset == 0 else f"predicted t{offset:+d}"


def _titled(cells: Sequence[Sequence[np.ndarray]], row_titles: Sequence[str], column_titles: Sequence[str]
            ) -> np.ndarray:
    """The equal-sized RGB ``cells`` (rows of columns) as one image with a white margin on the left and on top:
    each row's title left of it, each column's centred above it."""
    face, scale, thickness = _TITLE_FONT

    def size(title: str) -> tuple[int, int, int]:
        (width, rise), descent = cv2.getTextSize(title, face, scale, thickness)
        return width, rise, descent

    def put(title: str, x: int, baseline: int) -> None:
        cv2.putText(image, title, (x, baseline), face, scale, (0, 0, 0), thickness, cv2.LINE_AA)

    height, width = cells[0][0].shape[:2]
    left = max(size(title)[0] for title in row_titles) + 2 * _TITLE_PAD
    rise = max(size(title)[1] for title in column_titles)
    top = rise + max(size(title)[2] for title in column_titles) + 2 * _TITLE_PAD
    image = np.full((top + height * len(cells), left + width * len(cells[0]), 3), 255, np.uint8)
    image[top:, left:] = np.concatenate([np.concatenate(row, axis=1) for row in cells], axis=0)
    for row, title in enumerate(row_titles):
        put(title, _TITLE_PAD, top + row * height + (height + size(title)[1]) // 2)
    for column, title in enumerate(column_titles):
        put(title, left + column * width + (width - size(title)[0]) // 2, _TITLE_PAD + rise)
    return image


@jax.jit
def _meshes(body: geometry.BodyModel, rot6d: Float[Array, "people frames joints 6"],
            betas: Float[Array, "people frames shapes"], roots: Float[Array, "people frames 3"]
            ) -> Float[Array, "people frames vertices 3"]:
    """Posed vertices (metres, camera frame) of every person and frame, each placed by its root joint."""
    def one(rot6d, betas, root):
        posed = geometry.body_forward(body, geometry.rotation_6d_to_matrix(rot6d), betas, jnp.zeros(3, betas.dtype))
        return posed.vertices - posed.joints[:1] + root[None]

    return jax.vmap(jax.vmap(one))(rot6d, betas, roots)

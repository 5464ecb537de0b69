"""Conditioning and prediction metrics of the thesis (Sect. 5.3) on held-out clips, and the ZeroMotion baseline.

A test sample is a window of one person track: ``observed`` = 25 frames in, ``horizon`` = 30 frames predicted.
Two-person samples come from the two-person clips (:data:`~dynamics.TEST_MULTI_PERSON_CLIPS`), single-person
samples from the others; PHD+T treats each person on their own, so a two-person window is scored per person.

Metrics per frame, averaged over samples (:data:`METRICS`):

- ``pa_mpjpe`` and ``mpjpe``: mm over the 24 body joints, after aligning the pelvises (MPJPE) and after a
  similarity Procrustes alignment (PA-MPJPE), :mod:`geometry`'s metrics;
- ``pck``: percentage of 2D joints within ``alpha`` (0.05) times the longer side of the person's tight box, with
  the predicted joints projected through the predicted root, so it scores where the person is, too;
- ``root``: mm between predicted and true pelvis in the camera frame; the thesis' metrics ignore where people go
  beyond PCK, so we add it.

Conditioning is scored on the observed frames every method reconstructs: from the 13th (PHD+T's receptive field).
Prediction is scored at future frames 1, 5, 10, 20 and 30 (:data:`HORIZONS`) and, for the plot, at every one.
ZeroMotion (Sect. 5.3) repeats the last observed reconstruction of PHD+T's conditioning networks.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx
from jaxtyping import Array, Float

import geometry

from ._data import TEST_MULTI_PERSON_CLIPS, TEST_SINGLE_PERSON_CLIPS, DataConfig, Frames, gather_windows, \
    window_starts, without_crops
from ._hmr import SMPLParams
from ._phdt import PHDT, Observation, Rollout, params_to_joints

__all__ = ["EvalConfig", "HORIZONS", "METRICS", "frame_metrics", "predict_windows", "summarise", "zero_motion"]

HORIZONS: tuple[int, ...] = (1, 5, 10, 20, 30)
METRICS: tuple[str, ...] = ("pa_mpjpe", "mpjpe", "pck", "root")


@dataclasses.dataclass(frozen=True)
class EvalConfig:
    data: DataConfig = DataConfig(clips=TEST_SINGLE_PERSON_CLIPS + TEST_MULTI_PERSON_CLIPS, renders=1,
                                  augmented_epochs=1, jitter=False, flip=False, seed=2_000)
    """The held-out clips, rendered once with tight boxes (new cameras and shapes: seed 2000)."""
    observed: int = 25
    horizon: int = 30
    stride: int = 5
    """Frames between the starts of consecutive windows of a track."""
    pck_alpha: float = 0.05

    def __post_init__(self) -> None:
        if max(HORIZONS) > self.horizon:
            raise ValueError(f"the horizon must reach {max(HORIZONS)} frames, got {self.horizon}")

    @property
    def length(self) -> int:
        return self.observed + self.horizon


def zero_motion(observed: Observation, horizon: int) -> Rollout:
    """ZeroMotion: the last observed frame, repeated ``horizon`` times."""
    repeat = lambda x: jnp.repeat(x[..., -1:, :], horizon, axis=-2)  # noqa: E731
    params = SMPLParams(jnp.repeat(observed.params.rot6d[..., -1:, :, :], horizon, axis=-3),
                        repeat(observed.params.betas), repeat(observed.params.camera))
    return Rollout(repeat(observed.temporal), repeat(observed.joint_features), params, repeat(observed.root))


def frame_metrics(body: geometry.BodyModel, params: SMPLParams, root: Float[Array, "*b 3"], rows: Frames,
                  pck_alpha: float) -> dict[str, Array]:
    """The :data:`METRICS` of each frame (``*b``): mm, mm, percent, mm."""
    joints = params_to_joints(body, params, root)
    truth = jnp.asarray(rows.joints3d)
    pixels = geometry.project_pinhole(jnp.asarray(rows.K), joints)
    box_size = jnp.max(jnp.asarray(rows.tight_boxes)[..., 2:] - jnp.asarray(rows.tight_boxes)[..., :2], axis=-1)
    return {
        "pa_mpjpe": 1000.0 * geometry.pa_mpjpe(joints, truth),
        "mpjpe": 1000.0 * geometry.mpjpe_root_relative(joints, truth, 0),
        "pck": 100.0 * geometry.pck_2d(pixels, jnp.asarray(rows.joints2d), pck_alpha, box_size=box_size),
        "root": 1000.0 * jnp.linalg.norm(root - jnp.asarray(rows.root), axis=-1),
    }


def predict_windows(body: geometry.BodyModel, model: PHDT, features: np.ndarray, frames: Frames,
                    config: EvalConfig, batch_size: int = 64) -> dict[str, object]:
    """Every test window's per-frame metrics for PHD+T and ZeroMotion.

    Returns ``{"starts": (N,), "two_person": (N,) bool, "conditioning": {method: {metric: (N, T - 12)}},
    "prediction": {method: {metric: (N, horizon)}}}``."""
    starts = window_starts(frames, config.length, config.stride)
    if len(starts) == 0:
        raise ValueError(f"no track is {config.length} frames long")
    graphdef, state = nnx.split(model)
    T = config.observed

    @jax.jit
    def run(state, features, rows):
        model = nnx.merge(graphdef, state)
        observed = model.observe(body, features[:, :T], rows.boxes[:, :T], rows.K[:, :T])
        first = model.receptive_field - 1
        past = jax.tree.map(lambda x: x[:, first:T], rows)
        conditioning = frame_metrics(body, jax.tree.map(lambda x: x[:, first:], observed.params),
                                     observed.root[:, first:], past, config.pck_alpha)
        future = jax.tree.map(lambda x: x[:, T:], rows)
        prediction = {name: frame_metrics(body, rollout.params, rollout.root, future, config.pck_alpha)
                      for name, rollout in (("PHD+T", model.rollout(observed, config.horizon)),
                                            ("ZeroMotion", zero_motion(observed, config.horizon)))}
        return conditioning, prediction

    columns = (features, without_crops(frames))
    results = []
    for first in range(0, len(starts), batch_size):
        chunk = starts[first: first + batch_size]
        padded = np.concatenate([chunk, np.full(batch_size - len(chunk), chunk[0])])
        window_features, rows = gather_windows(columns, padded, config.length)
        outputs = jax.device_get(run(state, jnp.asarray(window_features), rows))
        results.append(jax.tree.map(lambda x: x[: len(chunk)], outputs))
    conditioning, prediction = jax.tree.map(lambda *parts: np.concatenate(parts), *results)
    multi = {config.data.clips.index(c) for c in TEST_MULTI_PERSON_CLIPS if c in config.data.clips}
    return {"starts": starts, "two_person": np.isin(frames.clip[starts], list(multi)),
            # ZeroMotion reconstructs the observed frames with PHD+T's networks: one conditioning row for both.
            "conditioning": {"PHD+T": conditioning, "ZeroMotion": conditioning}, "prediction": prediction}


def summarise(windows: Mapping[str, object]) -> dict[str, dict]:
    """Mean metrics per sample group (``single_person``, ``two_person``, ``all``), method and task; prediction
    at every future frame (index k - 1 for frame k)."""
    groups = {"single_person": ~windows["two_person"], "two_person": windows["two_person"],
              "all": np.ones_like(windows["two_person"])}
    summary = {}
    for group, selected in groups.items():
        if not np.any(selected):
            continue
        summary[group] = {"samples": int(np.sum(selected)), "conditioning": {}, "prediction": {}}
        for task in ("conditioning", "prediction"):
            for method, metrics in windows[task].items():
                summary[group][task][method] = {
                    name: (float(np.mean(values[selected])) if task == "conditioning"
                           else np.mean(values[selected], axis=0).tolist())
                    for name, values in metrics.items()}
    return summary

"""Conditioning and prediction metrics of the thesis (Sect. 5.3) on held-out clips, and the ZeroMotion baseline.

A test window is a scene: every person of a rendered video over the same ``observed`` = 25 frames in and
``horizon`` = 30 frames predicted (:func:`~dynamics.scene_windows`). A sample is one person of one window:
two-person samples come from the two-person clips (:data:`~dynamics.TEST_MULTI_PERSON_CLIPS`), single-person
samples from the others. Every model sees the whole scene; PHD+T and JAT treat each person on their own, MPJAT
attends across people.

Metrics per frame, averaged over samples (:data:`METRICS`):

- ``pa_mpjpe`` and ``mpjpe``: mm over the 24 body joints, after aligning the pelvises (MPJPE) and after a
  similarity Procrustes alignment (PA-MPJPE), :mod:`geometry`'s metrics;
- ``pck``: percentage of 2D joints within ``alpha`` (0.05) times the longer side of the person's tight box, with
  the predicted joints projected through the predicted root, so it scores where the person is, too;
- ``root``: mm between predicted and true pelvis in the camera frame; the thesis' metrics ignore where people go
  beyond PCK, so we add it;
- ``depth_ratio``: the predicted pelvis' depth over the true one (below 1: people placed too near the camera),
  the part of the root error a monocular crop camera gets least right.

Conditioning is scored on the observed frames every method reconstructs: from the 13th (PHD+T's receptive field).
Prediction is scored at future frames 1, 5, 10, 20 and 30 (:data:`HORIZONS`) and, for the plot, at every one.
ZeroMotion (Sect. 5.3) repeats the last observed reconstruction of PHD+T's conditioning networks.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx
from jaxtyping import Array, ArrayLike, Bool, Float

import geometry

from ._data import TEST_MULTI_PERSON_CLIPS, TEST_SINGLE_PERSON_CLIPS, DataConfig, Frames, scene_windows, \
    without_crops
from ._hmr import SMPLParams
from ._losses import penetration_depths
from ._phdt import Observation, PHDTConfig, Rollout, params_to_joints

PHDT_RECEPTIVE_FIELD = PHDTConfig().tcn_blocks * 2 * (PHDTConfig().tcn_kernel - 1) + 1
"""13: conditioning is scored from this frame on, the first PHD+T reconstructs with a full receptive field."""

__all__ = ["EvalConfig", "HORIZONS", "METRICS", "SCENE_BATCH", "forecast_scenes", "frame_metrics", "penetration_mm",
           "predict_windows", "summarise", "zero_motion"]

HORIZONS: tuple[int, ...] = (1, 5, 10, 20, 30)
METRICS: tuple[str, ...] = ("pa_mpjpe", "mpjpe", "pck", "root", "depth_ratio")


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
        if self.observed < 1:
            raise ValueError(f"observed must be >= 1 frame, got {self.observed}")
        if self.stride < 1:
            raise ValueError(f"stride must be >= 1, got {self.stride}")
        if not 0 < self.pck_alpha <= 1:
            raise ValueError(f"pck_alpha must be in (0, 1], got {self.pck_alpha}")

    @property
    def length(self) -> int:
        return self.observed + self.horizon


@partial(jax.jit, static_argnums=1)
def zero_motion(observed: Observation, horizon: int) -> Rollout:
    """ZeroMotion: the last observed frame, repeated ``horizon`` times."""
    repeat = lambda x: jnp.repeat(x[..., -1:, :], horizon, axis=-2)  # noqa: E731
    params = SMPLParams(jnp.repeat(observed.params.rot6d[..., -1:, :, :], horizon, axis=-3),
                        repeat(observed.params.betas), repeat(observed.params.camera))
    return Rollout(repeat(observed.temporal), repeat(observed.joint_features), params, repeat(observed.root))


def frame_metrics(body: geometry.BodyModel, params: SMPLParams, root: Float[Array, "*b 3"], rows: Frames,
                  pck_alpha: float) -> dict[str, Array]:
    """The :data:`METRICS` of each frame (``*b``): mm, mm, percent, mm, a ratio."""
    joints = params_to_joints(body, params, root)
    truth = jnp.asarray(rows.joints3d)
    pixels = geometry.project_pinhole(jnp.asarray(rows.K), joints)
    box_size = jnp.max(jnp.asarray(rows.tight_boxes)[..., 2:] - jnp.asarray(rows.tight_boxes)[..., :2], axis=-1)
    return {
        "pa_mpjpe": 1000.0 * geometry.pa_mpjpe(joints, truth),
        "mpjpe": 1000.0 * geometry.mpjpe_root_relative(joints, truth, 0),
        "pck": 100.0 * geometry.pck_2d(pixels, jnp.asarray(rows.joints2d), pck_alpha, box_size=box_size),
        "root": 1000.0 * jnp.linalg.norm(root - jnp.asarray(rows.root), axis=-1),
        "depth_ratio": root[..., 2] / jnp.asarray(rows.root)[..., 2],
    }


def penetration_mm(body: geometry.BodyModel, params: SMPLParams, root: Float[Array, "*b N T 3"]
                   ) -> Float[Array, "*b N T"]:
    """The interpenetration measure of each person and frame: :func:`penetration_depths` averaged over the sampled
    vertices, mm."""
    return 1000.0 * jnp.mean(penetration_depths(body, params, root), axis=-1)


SCENE_BATCH = 16
"""Scenes per call of a model's compiled forecast (:func:`forecast_scenes`; the last batch padded)."""


@partial(jax.jit, static_argnums=(0, 3, 4))
def _observe_and_roll_out(graphdef: nnx.GraphDef, state, body: geometry.BodyModel, observed: int,
                          horizon: int, features, boxes, K, present) -> tuple[Observation, Rollout]:
    model = nnx.merge(graphdef, state)
    seen = model.observe(body, features[:, :, :observed], boxes[:, :, :observed], K[:, :, :observed], present)
    return seen, model.rollout(body, seen, horizon, present)


def forecast_scenes(model: nnx.Module, body: geometry.BodyModel, features: Float[ArrayLike, "S N T D"],
                    boxes: Float[ArrayLike, "S N T 4"], K: Float[ArrayLike, "S N T 3 3"],
                    present: Bool[ArrayLike, "S N"], observed: int, horizon: int) -> tuple[Observation, Rollout]:
    """``model``'s (PHD+T or a transformer) reconstruction of the first ``observed`` frames of each scene and its
    ``horizon`` frames after them (NumPy arrays), in batches of :data:`SCENE_BATCH` scenes through one compilation
    per model and scene shape (the evaluation's windows and the strip of ``experiments.dynamics`` share it).

    The batches are padded and the outputs cut and joined in NumPy: done with jax arrays, each of those small
    operations compiled a program of its own for every new shape."""
    graphdef, state = nnx.split(model)
    features, boxes, K, present = (np.asarray(x) for x in (features, boxes, K, present))
    parts = []
    for first in range(0, len(features), SCENE_BATCH):
        size = min(SCENE_BATCH, len(features) - first)
        pad = lambda x, fill: np.concatenate(  # noqa: E731  (the batch's first scene repeated, or fill)
            [x[first:first + size], np.repeat(x[first:first + 1] if fill is None else np.full_like(
                x[first:first + 1], fill), SCENE_BATCH - size, axis=0)])
        outputs = _observe_and_roll_out(graphdef, state, body, observed, horizon, pad(features, None),
                                        pad(boxes, None), pad(K, None), pad(present, False))
        parts.append(jax.tree.map(lambda x: np.asarray(x)[:size], outputs))
    return jax.tree.map(lambda *x: np.concatenate(x), *parts)


def predict_windows(body: geometry.BodyModel, models: Mapping[str, nnx.Module], features: np.ndarray,
                    frames: Frames, config: EvalConfig) -> dict[str, object]:
    """Every test sample's per-frame metrics for each of ``models`` (name -> :class:`~dynamics.PHDT` or
    :class:`~dynamics.JAT`) and ZeroMotion, which repeats the last frame of the first model's conditioning.

    The test windows are scenes (:func:`~dynamics.scene_windows`: every person of a video over the same
    frames, single-person videos padded to two people); a sample is one person of one window. Returns
    ``{"two_person": (S,) bool, "conditioning": {method: {metric: (S, T - 12)}}, "prediction": {method:
    {metric: (S, horizon)}}, "penetration": {method: (S, horizon)}}``, the last in mm for the two-person samples
    (:func:`penetration_mm`), with the ground truth's as ``"ground truth"``."""
    scenes, present = scene_windows(frames, config.length, config.stride, people=2)
    if len(scenes) == 0:
        raise ValueError(f"no video is {config.length} frames long")
    T = config.observed
    first = PHDT_RECEPTIVE_FIELD - 1
    window_features, rows = jax.tree.map(lambda column: column[scenes], (features, without_crops(frames)))
    past = jax.tree.map(lambda x: x[:, :, first:T], rows)
    future = jax.tree.map(lambda x: x[:, :, T:], rows)

    @jax.jit
    def score(seen: Observation, rollout: Rollout, past: Frames, future: Frames):
        tail = jax.tree.map(lambda x: x[:, :, first:], seen)
        return (frame_metrics(body, tail.params, tail.root, past, config.pck_alpha),
                frame_metrics(body, rollout.params, rollout.root, future, config.pck_alpha),
                penetration_mm(body, rollout.params, rollout.root))

    @jax.jit
    def truth(rows: Frames):
        params = SMPLParams(geometry.matrix_to_rotation_6d(rows.rotations), rows.betas, jnp.zeros_like(rows.root))
        return penetration_mm(body, params, rows.root)

    conditioning, prediction, penetration = {}, {}, {}
    for index, (name, model) in enumerate(models.items()):
        seen, rollout = forecast_scenes(model, body, window_features, rows.boxes, rows.K, present, T,
                                        config.horizon)
        conditioning[name], prediction[name], penetration[name] = score(seen, rollout, past, future)
        if index == 0:  # ZeroMotion repeats the first model's last observed frame and shares its conditioning
            _, prediction["ZeroMotion"], penetration["ZeroMotion"] = score(seen, zero_motion(seen, config.horizon),
                                                                           past, future)
            conditioning["ZeroMotion"] = conditioning[name]
    penetration["ground truth"] = truth(future)
    samples = present.reshape(-1)
    flatten = lambda x: np.asarray(x).reshape(-1, *x.shape[2:])[samples]  # noqa: E731  (present (window, person))
    two_person = np.repeat(present.sum(axis=1) > 1, present.shape[1])[samples]
    return {"two_person": two_person,
            "conditioning": jax.tree.map(flatten, conditioning),
            "prediction": jax.tree.map(flatten, prediction),
            "penetration": jax.tree.map(flatten, penetration)}


def summarise(windows: Mapping[str, object]) -> dict[str, dict]:
    """Mean metrics per sample group (``single_person``, ``two_person``, ``all``), method and task; prediction
    at every future frame (index k - 1 for frame k); the two-person group also has each method's mean
    ``penetration`` (mm) at every future frame."""
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
    if "two_person" in summary:
        summary["two_person"]["penetration"] = {method: np.mean(values[windows["two_person"]], axis=0).tolist()
                                                for method, values in windows["penetration"].items()}
    return summary

"""Training the 3D forecasters (:class:`~dynamics.PoseForecaster`) on the train split of the CMU-Mocap benchmark.

One resumable stage of the project loop (the stage runner of :mod:`dynamics._train`, with the adversarial prior
trained alongside), all parts at once: the observed poses are exact, so there is no conditioning network to
pre-train and freeze as in the video setting (a stated deviation from the thesis' two stages). Each step draws
``batch_size`` windows of ``observed + horizon`` frames from the training motion at several playback speeds and
mirrored (:attr:`ForecastTrainConfig.speeds`, :attr:`ForecastTrainConfig.mirror`: the augmentations), each in the
virtual camera frame of its last observed frame (:func:`~dynamics.canonical_window`); the objective is Eq. 4.12's
on the predicted frames (``L_t``'s SMPL, 3D-joint and adversarial terms, there is no image, and ``lambda_transl``
on the predicted pelvis against the true one) plus ``L_t`` of ``f_HMR`` decoding every observed frame's ``Phi_t``
(what the video models' first stage asks of it), from the observed frames before it as the rollout decodes
(:func:`~dynamics.decoding_start`).

Validation (every choice of the study is made on it) is one training file of each action kept out of training:
:func:`forecast_split`. :data:`FORECASTERS` are trained from one seed with the same steps and data; "JAT w/o
bias" differs from "JAT" only by the bias (same initial parameters for every part they share).
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Iterable, Mapping
from functools import partial
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx

import geometry
import mocap
import training

from ._data import gather_windows, window_starts
from ._forecast import ForecasterConfig, PoseForecaster, forecast_joints
from ._hmr import decoding_start
from ._jat import JATConfig
from ._losses import FrameTargets, LossWeights, frame_losses
from ._phdt import PHDTConfig
from ._poses import FORECAST_FPS, PoseFrames, canonical_window, mirror_frames, pose_frames
from ._train import StageConfig, _run_stage

__all__ = ["FORECASTERS", "ForecastTrainConfig", "canonical_windows", "forecast_split", "initial_forecaster",
           "load_forecasters", "train_forecaster", "train_forecasters"]

# Each predicted frame decoded from the previous one moved on by half its last step: chosen on the validation files
# (docs/dynamics.md) over the previous pose as it is and over the whole step.
_DECODING = dict(decode_from="extrapolated", extrapolation=0.5)
_SMALL_JAT = JATConfig(feature_dim=128, temporal_dim=128, joint_dim=64, hmr_hidden=256, hmr_dropout=0.0,
                       bias_hidden=64, **_DECODING)
FORECASTERS: dict[str, ForecasterConfig] = {
    # No delta predictors: they supervise f_movie from the past frames of a video; here the past is observed.
    "PHD+T": ForecasterConfig(phdt=PHDTConfig(feature_dim=128, joint_dim=64, hmr_hidden=256, hmr_dropout=0.0,
                                              channels_per_group=64, delta_offsets=(), **_DECODING)),
    "JAT": ForecasterConfig(jat=_SMALL_JAT),
    "JAT w/o bias": ForecasterConfig(jat=dataclasses.replace(_SMALL_JAT, joint_aware_bias=False)),
}
"""The trained 3D forecasters, as the tables name them (CPU-sized: a few hundred thousand parameters each)."""


@dataclasses.dataclass(frozen=True)
class ForecastTrainConfig:
    """Everything that determines one forecaster's training (written to ``config.json``)."""

    files: tuple[str, ...]
    """Training motion files (CMU-Mocap exp-map ``.txt``; the benchmark's test split is refused)."""
    validation_files: tuple[str, ...]
    model: ForecasterConfig = FORECASTERS["JAT"]
    losses: LossWeights = LossWeights()
    stage: StageConfig = StageConfig(steps=1000, batch_size=32, learning_rate=5e-4, warmup_steps=50)
    observed: int = 25
    """Frames observed (1 s at 25 Hz, the thesis' 25)."""
    horizon: int = 25
    """Frames predicted in training (1 s: the benchmark's longest horizon)."""
    fps: float = FORECAST_FPS
    speeds: tuple[float, ...] = (0.8, 0.9, 1.0, 1.1, 1.2)
    """Playback speeds of the training motion (an augmentation): each file resampled ``speed`` times faster, one set
    of windows per speed. Validation is at speed 1."""
    mirror: bool = True
    """Also train on the mirrored motion (:func:`~dynamics.mirror_frames`: left and right swapped), an augmentation."""
    seed: int = 0
    checkpoint_interval: int = 250
    validation_interval: int = 250
    log_interval: int = 50
    cache_dir: str | None = None
    """Where the retargeted motion is cached; None: ``<workdir>/data_cache``."""

    def __post_init__(self) -> None:
        if not self.files or not self.validation_files:
            raise ValueError("need training and validation files")
        held_out = [f for f in self.files + self.validation_files if mocap.cmu_expmap_split(f) == "test"]
        if held_out:
            raise ValueError(f"{held_out[0]} is in the benchmark's test split: it never enters training or validation")
        shared = sorted(set(map(os.path.abspath, self.files)) & set(map(os.path.abspath, self.validation_files)))
        if shared:
            raise ValueError(f"{shared[0]} is both a training and a validation file")
        if not self.speeds or min(self.speeds) <= 0:
            raise ValueError(f"speeds must be positive, got {self.speeds}")
        if self.observed < 2 or self.horizon < 1:
            raise ValueError(f"need observed >= 2 and horizon >= 1, got {self.observed} and {self.horizon}")


def forecast_split(data_root: str | os.PathLike | None = None) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """The benchmark's train split as (training files, validation files): the last file of each action
    validates, the rest train. Absolute paths."""
    files = [f.resolve() for f in mocap.cmu_expmap_files(data_root, "train")]
    actions: dict[str, list[Path]] = {}
    for file in files:
        actions.setdefault(file.parent.name, []).append(file)
    last = {max(group, key=lambda f: int(f.stem.rsplit("_", 1)[1])) for group in actions.values()}
    return tuple(str(f) for f in files if f not in last), tuple(str(f) for f in files if f in last)


@partial(jax.jit, static_argnums=2)
def _canonical(rotations, joints, last_observed: int):
    return jax.vmap(canonical_window, in_axes=(0, 0, None))(rotations, joints, last_observed)


def canonical_windows(frames: PoseFrames, starts: np.ndarray, length: int, observed: int) -> PoseFrames:
    """The single-person windows of ``length`` frames at ``starts`` in their last observed frame's virtual camera
    frame (:func:`~dynamics.canonical_window`): every array ``(W, 1 person, length, ...)``."""
    windows = jax.tree.map(lambda column: column[:, None], gather_windows(frames, starts, length))
    rotations, joints = _canonical(jnp.asarray(windows.rotations), jnp.asarray(windows.joints3d), observed - 1)
    return windows._replace(rotations=np.asarray(rotations), joints3d=np.asarray(joints))


def _joined(parts: list[PoseFrames]) -> PoseFrames:
    """The rows of ``parts`` one after the other, each part's tracks numbered after the previous parts'."""
    offsets = np.cumsum([0] + [int(part.track.max()) + 1 for part in parts[:-1]])
    parts = [part._replace(track=part.track + offset) for part, offset in zip(parts, offsets)]
    return PoseFrames(*(np.concatenate(column) for column in zip(*parts)))


def _targets(rows: PoseFrames) -> FrameTargets:
    return FrameTargets(rows.rotations, rows.betas, rows.joints3d, None, None, None)


def _forecast_objective(config: ForecastTrainConfig, body, model: PoseForecaster, rows: PoseFrames, key, prior):
    T, H = config.observed, config.horizon
    frames = lambda start, stop: jax.tree.map(lambda x: x[:, :, start:stop], rows)  # noqa: E731
    past, future = frames(0, T), frames(T, T + H)
    observed = model.observe(past.rotations, past.betas, past.joints3d)
    # f_HMR decodes every observed frame as the rollout decodes a predicted one: from the mean pose, or from the frames
    # before it (the first one or two frames have too few of them).
    decode_from = config.model.model.decode_from
    first = {"mean": 0, "previous": 1, "extrapolated": 2}[decode_from]
    before = lambda back: jax.tree.map(lambda x: x[:, :, first - back:T - back], observed.params)  # noqa: E731
    start = None if first == 0 else decoding_start(decode_from, before(min(2, first)), before(1),
                                                   config.model.model.extrapolation)
    decoded, shown = model.decode(observed.temporal[:, :, first:], start, key), frames(first, T)
    decoded = frame_losses(body, decoded, None, _targets(shown), None, config.losses)
    rollout = model.rollout(body, observed, H)
    terms = frame_losses(body, rollout.params, None, _targets(future), prior, config.losses)
    terms |= {f"observed_{name}": value for name, value in decoded.items()}
    terms["translation"] = config.losses.translation * jnp.mean(
        jnp.sum((rollout.root - future.joints3d[..., 0, :]) ** 2, axis=-1))
    return sum(terms.values()), terms, rollout.params


def _future_errors(body, model: PoseForecaster, rows: PoseFrames, observed: int) -> dict[str, jax.Array]:
    past = jax.tree.map(lambda x: x[:, :, :observed], rows)
    truth = rows.joints3d[:, :, observed:]
    predicted = forecast_joints(model, body, past.rotations, past.betas, past.joints3d, truth.shape[2])
    error = geometry.mpjpe_root_relative(predicted, truth, 0)  # (W, 1, H)
    root = jnp.linalg.norm(predicted[..., 0, :] - truth[..., 0, :], axis=-1)
    return {"val_future_mpjpe_mm": 1000.0 * jnp.mean(error), "val_future_root_mm": 1000.0 * jnp.mean(root)}


def initial_forecaster(config: ForecasterConfig, seed: int) -> PoseForecaster:
    """The parameters a forecaster starts from: those of JAT (with the bias) from ``seed`` for every part the
    config shares with it, so that an ablation differs from JAT only in what it removes; the rest from ``seed``."""
    model = PoseForecaster(config, rngs=nnx.Rngs(seed))
    if config.jat is not None and config.jat != FORECASTERS["JAT"].jat:
        reference = PoseForecaster(dataclasses.replace(config, jat=dataclasses.replace(
            config.jat, joint_aware_bias=True)), rngs=nnx.Rngs(seed))
        shared = dict(nnx.to_flat_state(nnx.state(reference, nnx.Param)))
        nnx.update(model, nnx.from_flat_state({path: shared[path] for path, _ in
                                               nnx.to_flat_state(nnx.state(model, nnx.Param)) if path in shared}))
    return model


def train_forecaster(config: ForecastTrainConfig, workdir: str | Path, body: geometry.BodyModel, *, resume: bool,
                     log: Callable[[dict], None] = lambda record: None, progress: bool = True) -> PoseForecaster:
    """Train ``config.model`` in ``workdir`` from :func:`initial_forecaster` (module docstring); the model is also
    written to ``workdir/model``."""
    workdir = Path(workdir).resolve()
    cache_dir = workdir / "data_cache" if config.cache_dir is None else Path(config.cache_dir)
    length = config.observed + config.horizon
    frames = _joined([pose_frames(config.files, body, config.fps / speed, cache_dir, progress)
                      for speed in config.speeds])
    if config.mirror:
        frames = _joined([frames, mirror_frames(frames, body)])
    validation = pose_frames(config.validation_files, body, config.fps, cache_dir, progress)
    starts = window_starts(frames, length)
    validation_windows = canonical_windows(validation, window_starts(validation, length, stride=10), length,
                                           config.observed)

    def sample(key: jax.Array) -> PoseFrames:
        chosen = starts[np.asarray(jax.random.randint(key, (config.stage.batch_size,), 0, len(starts)))]
        return canonical_windows(frames, chosen, length, config.observed)

    @nnx.jit
    def errors(model, rows):
        return _future_errors(body, model, rows, config.observed)

    def validate(model: PoseForecaster) -> dict[str, float]:
        return {name: float(value) for name, value in errors(model, validation_windows).items()}

    model = initial_forecaster(config.model, config.seed)
    model = _run_stage("forecast", config, config.stage, workdir, model, nnx.Param, _forecast_objective, sample,
                       validate, body, resume=resume, log=log, progress=progress)
    training.save_model(workdir / "model", config.model, nnx.state(model))
    return model


def train_forecasters(config: ForecastTrainConfig, workdir: str | Path, body: geometry.BodyModel, *, resume: bool,
                      names: Iterable[str] = tuple(FORECASTERS), model_changes: Mapping[str, object] | None = None,
                      log: Callable[[dict], None] = lambda record: None, progress: bool = True
                      ) -> dict[str, PoseForecaster]:
    """Each of :data:`FORECASTERS` named in ``names`` trained as ``config`` says (its ``model`` replaced, with
    ``model_changes`` to its model's config, e.g. ``decode_from``), in ``workdir/<name>/``, the data cached once for
    all; the models are copied to ``workdir/models/<name>``."""
    workdir = Path(workdir)
    if config.cache_dir is None:
        config = dataclasses.replace(config, cache_dir=str((workdir / "data_cache").resolve()))
    models = {}
    for name in names:
        model = FORECASTERS[name].replace_model(**(model_changes or {}))
        models[name] = train_forecaster(dataclasses.replace(config, model=model), workdir / _folder(name), body,
                                        resume=resume, log=lambda record, name=name: log({"model": name, **record}),
                                        progress=progress)
        training.save_model(workdir / "models" / _folder(name), model, nnx.state(models[name]))
    return models


def _folder(name: str) -> str:
    return name.lower().replace(" w/o ", "_without_").replace("+", "").replace(" ", "_")


def load_forecasters(path: str | Path) -> dict[str, PoseForecaster]:
    """The models :func:`train_forecasters` wrote to ``<workdir>/models`` (or a shipped copy), by table name: those
    of :data:`FORECASTERS` whose folder exists."""
    folders = {name: Path(path) / _folder(name) for name in FORECASTERS}
    if not any(folder.is_dir() for folder in folders.values()):
        raise FileNotFoundError(f"{path} holds none of the forecasters {[f.name for f in folders.values()]}")
    build = lambda fields: PoseForecaster(ForecasterConfig.from_fields(fields), rngs=nnx.Rngs(0))  # noqa: E731
    return {name: training.load_model_state(folder, build) for name, folder in folders.items() if folder.is_dir()}

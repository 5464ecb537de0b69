"""Training PHD+T on the synthetic videos, in three stages (thesis Sect. 4.2.2 and 5.2), each a resumable run of
the project's loop (:func:`training.run_training`) in its own folder of the work directory.

1. ``image/``: the crop backbone (:class:`~dynamics.ResNetBackbone`) and an HMR head on single frames, ``L_t``
   (Eq. 4.10). The thesis starts from HMR's pretrained ResNet-50 and keeps it frozen; we have no pretrained
   weights, so this stage trains ours. Then the backbone's features of every crop of every augmented variant
   are computed once and cached (``features_*.npy``), as the thesis caches eight augmented epochs.
2. ``movie/``: ``f_movie``, ``f_HMR`` (initialised from stage 1's head) and the delta predictors on windows of
   ``T + H`` = 50 cached feature frames, Eq. 4.9: ``L_t`` on every frame from the 13th (the first with a full
   receptive field), the delta predictors' losses at ``t + delta`` (their 3D terms: the crop box of another
   frame is not observable from ``Phi_t``, so they get no 2D term), the shape consistency.
3. ``ar/``: ``f_AR``, ``f_JE`` and ``f_transl`` with ``f_movie`` and ``f_HMR`` frozen, Eq. 4.12: observe 25 frames,
   roll out 25 without teacher forcing, ``L_t`` on every predicted frame (2D through the predicted root) plus
   ``lambda_temp |Phi~ - Phi^|^2`` and ``lambda_transl |gamma~ - gamma^|^2`` against the frozen conditioning
   networks' estimates of the future frames, and the shape consistency.

Each stage also trains the adversarial prior (:class:`~dynamics.PosePrior`, LSGAN) against the batch's ground
truth poses (our "mocap" data) and the stage's predictions. Adam with a linear warm-up and a cosine decay, the
gradients optionally clipped first (:attr:`StageConfig.clip_norm`); the thesis' rates (Tables C.2-C.3: 2e-5 and
below) are for fine-tuning pretrained networks over many GPU epochs, ours start from scratch in minutes on a CPU,
so they are larger (:class:`StageConfig`). Step i draws its
batch and dropout from ``fold_in(key(seed), i)``: a resumed stage repeats an uninterrupted one exactly, and a
finished stage is skipped when the run is resumed. Data parallel over the local devices (batches sharded,
parameters replicated) as :func:`training.data_parallel_shardings` says.

Outputs: ``config.json``, per stage ``log.jsonl`` and ``checkpoints/``, and the trained models
``model/backbone`` and ``model/phdt`` (read back by :func:`load_trained`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
import tqdm
from flax import nnx
from jax.sharding import NamedSharding
from jax.typing import ArrayLike
from jaxtyping import Array, Float

import geometry
import training

from ._backbone import Pooling, ResNetBackbone
from ._data import (VALIDATION_DATA, DataConfig, Frames, build_frames, check_validation_apart, gather_windows,
                    window_starts, without_crops)
from ._hmr import HMRHead, SMPLParams, mean_params
from ._losses import FrameTargets, LossWeights, frame_losses, interpenetration, shape_consistency
from ._phdt import PHDT, PHDTConfig, crop_roots, params_to_joints
from ._prior import PosePrior, lsgan_discriminator_loss

__all__ = ["BackboneConfig", "ImageRegressor", "StageConfig", "TrainConfig", "cached_features", "check_crop_sizes",
           "compute_features", "conditioning_metrics", "load_trained", "mean_local_pose", "mean_pose_metrics", "train",
           "train_conditioning"]


@dataclasses.dataclass(frozen=True)
class BackboneConfig:
    widths: tuple[int, ...] = (16, 32, 64, 128)
    blocks_per_stage: int = 1
    feature_dim: int = 256
    crop_size: int = 64
    """Side of the crops it takes, pixels (saved with it: an evaluation crops at the trained size)."""
    pooling: Pooling = "mean"
    """How the last feature map becomes the features (:data:`dynamics.Pooling`)."""


@dataclasses.dataclass(frozen=True)
class StageConfig:
    steps: int
    batch_size: int
    learning_rate: float
    discriminator_lr: float = 1e-4
    warmup_steps: int = 100
    end_lr_fraction: float = 0.05
    clip_norm: float | None = None
    """The trained parameters' gradients are scaled down to this global norm when larger, before Adam (None: never
    clipped). The prior's are not. The logged ``grad_norm`` is the norm before clipping, so spikes stay visible."""
    average_decay: float | None = None
    """Keep an exponential moving average of the trained parameters, ``a <- d a + (1 - d) p`` after every step from
    the initial parameters (Polyak averaging), and validate and return it instead of the parameters (None: no
    average). The parameters' own validation is logged beside it (each name prefixed ``raw_``); the checkpoints hold
    both."""

    def __post_init__(self) -> None:
        if self.steps < 1 or self.batch_size < 1:
            raise ValueError(f"steps and batch_size must be >= 1, got {self.steps} and {self.batch_size}")
        if not 0 <= self.warmup_steps < self.steps:
            raise ValueError(f"warmup_steps must be in [0, steps={self.steps}), got {self.warmup_steps}")
        if self.clip_norm is not None and not self.clip_norm > 0:
            raise ValueError(f"clip_norm must be positive (or None), got {self.clip_norm}")
        if self.average_decay is not None and not 0 < self.average_decay < 1:
            raise ValueError(f"average_decay must be in (0, 1) (or None), got {self.average_decay}")

    def schedule(self, peak: float) -> optax.Schedule:
        return optax.warmup_cosine_decay_schedule(0.0, peak, self.warmup_steps, self.steps, peak * self.end_lr_fraction)


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Everything that determines a training run (written to ``config.json``)."""

    data: DataConfig = DataConfig()
    validation: DataConfig = VALIDATION_DATA
    backbone: BackboneConfig = BackboneConfig(pooling="flatten")
    """The last map flattened since 2026-12-07, chosen on validation (docs/dynamics.md); BackboneConfig's own
    default stays ResNet's mean, what the backbones saved before the option were built with."""
    model: PHDTConfig = PHDTConfig()
    losses: LossWeights = LossWeights()
    image: StageConfig = StageConfig(steps=8000, batch_size=32, learning_rate=1e-3)
    """The conditioning stage (backbone and HMR head on single crops): 8000 steps, chosen on validation over 2000 by
    ``python -m experiments.dynamics_renders --renders 16 --steps 2000 8000`` (docs/dynamics.md)."""
    movie: StageConfig = StageConfig(steps=600, batch_size=16, learning_rate=3e-4)
    ar: StageConfig = StageConfig(steps=300, batch_size=16, learning_rate=3e-4, warmup_steps=30)
    observed: int = 25
    """T: observed frames."""
    horizon: int = 25
    """H: predicted frames in training (the test predicts 30)."""
    seed: int = 0
    checkpoint_interval: int = 100
    validation_interval: int = 300
    log_interval: int = 50
    cache_dir: str | None = None
    """Where rendered frames and features are cached; None: ``<workdir>/data_cache``."""

    def __post_init__(self) -> None:
        if self.model.feature_dim != self.backbone.feature_dim:
            raise ValueError(f"the backbone gives {self.backbone.feature_dim} features, the model takes "
                             f"{self.model.feature_dim}")
        check_crop_sizes(self.backbone.crop_size, data=self.data, validation=self.validation)
        if self.observed < self.model.tcn_blocks * 2 * (self.model.tcn_kernel - 1) + 1:
            raise ValueError(f"observe at least one receptive field of frames, got {self.observed}")
        check_validation_apart(self.data, self.validation)


class TrainState(NamedTuple):
    """Everything a step changes, plus the run's key: exactly what a checkpoint holds."""

    params: Any
    """The stage's trainable parameters."""
    prior: Any
    """The adversarial prior's parameters."""
    opt: optax.OptState
    prior_opt: optax.OptState
    step: jax.Array
    key: jax.Array
    average: Any = None
    """The moving average of ``params`` (:attr:`StageConfig.average_decay`), or None (then not checkpointed)."""


def check_crop_sizes(crop_size: int, **data: DataConfig) -> None:
    """Refuse data cropped at another size than the backbone's ``crop_size`` (before any rendering)."""
    for name, config in data.items():
        if config.crop_size != crop_size:
            raise ValueError(f"{name}.crop_size is {config.crop_size}, the backbone takes {crop_size} px crops")


def _backbone_from_config(config: BackboneConfig, rngs: nnx.Rngs) -> ResNetBackbone:
    return ResNetBackbone(tuple(config.widths), config.blocks_per_stage, config.feature_dim, crop_size=config.crop_size,
                          pooling=config.pooling, rngs=rngs)


class ImageRegressor(nnx.Module):
    """Stage 1's network: crops -> backbone features -> HMR head."""

    def __init__(self, backbone: BackboneConfig, model: PHDTConfig, *, rngs: nnx.Rngs):
        self.backbone = _backbone_from_config(backbone, rngs)
        self.hmr = HMRHead(backbone.feature_dim, mean_params(model.num_shapes), hidden=model.hmr_hidden,
                           iterations=model.hmr_iterations, dropout=model.hmr_dropout, rngs=rngs)


def _targets(rows: Frames) -> FrameTargets:
    return FrameTargets(rows.rotations, rows.betas, rows.joints3d, rows.joints2d, rows.boxes, rows.K)


def _crops(rows: Frames) -> jax.Array:
    return jnp.asarray(rows.crops, jnp.float32) / 255.0


def _total(terms: dict[str, jax.Array]) -> jax.Array:
    return sum(terms.values())


# ----------------------------------------------------------------------------------------------
# The three objectives: (model, batch, key, prior, weights, body) -> (loss, terms, (fake rotations, fake betas)).

def _image_objective(config: TrainConfig, body, model: ImageRegressor, rows: Frames, key, prior):
    params = model.hmr(model.backbone(_crops(rows)), key=key)
    terms = frame_losses(body, params, crop_roots(params, rows.boxes, rows.K), _targets(rows), prior, config.losses)
    return _total(terms), terms, params


def _movie_objective(config: TrainConfig, body, model: PHDT, batch: tuple[jax.Array, Frames], key, prior):
    features, rows = batch
    first = model.receptive_field - 1
    head_key, delta_key = jax.random.split(key)
    temporal = model.condition(features)[:, first:]
    params = model.regress(temporal, head_key)
    tail = jax.tree.map(lambda x: x[:, first:], rows)
    terms = frame_losses(body, params, crop_roots(params, tail.boxes, tail.K), _targets(tail), prior, config.losses)
    for offset, predicted in zip(config.model.delta_offsets, model.regress_deltas(temporal, params, delta_key)):
        past = jax.tree.map(lambda x: x[:, first + offset: x.shape[1] + offset], rows)
        delta_terms = frame_losses(body, predicted, None, _targets(past), None, config.losses)
        terms[f"delta{offset}"] = config.losses.delta * _total(delta_terms)
    terms["shape_consistency"] = shape_consistency(params.betas, config.losses)
    return _total(terms), terms, params


def _ar_objective(config, body, model, batch: tuple[jax.Array, Frames], key, prior, surfaces=None):
    """Eq. 4.12, and Eq. 4.44's interpenetration term when the batch holds scenes of several people: features
    ``(B, T + H, D)`` (tracks) or ``(B, N, T + H, D)`` (scenes), ``rows`` alike; ``surfaces``: the body's
    :func:`~dynamics.penetration_surfaces` (the body model is traced here), for scenes."""
    features, rows = batch
    T, H = config.observed, config.horizon
    frames = lambda tree, start, stop: jax.tree.map(  # noqa: E731  (the frame axis follows the batch axes)
        lambda x: jax.lax.slice_in_dim(x, start, stop, axis=features.ndim - 2), tree)
    frozen = jax.lax.stop_gradient
    past = frames(rows, 0, T)
    observed = model.observe(body, features[..., :T, :], past.boxes, past.K)
    # f_movie and f_HMR are frozen in this stage (Sect. 4.2.2): stop the gradient on their outputs, the
    # conditioning Phi^, Theta^ and gamma^, only. Gamma^ = f_JE(J^) stays on the gradient path: f_JE trains here
    # (Table C.3 gives it a prediction-stage rate), and it is PHD+T's only path, as its rollout stays in feature
    # space (Sect. 4.2.1 re-encodes the predicted joints; the shipped model's predictions would change). Stopping
    # the whole observation left f_JE at its initialisation (issue 26).
    observed = observed._replace(temporal=frozen(observed.temporal), params=jax.tree.map(frozen, observed.params),
                                 root=frozen(observed.root))
    # The conditioning networks' estimate of the future frames: the targets of lambda_temp and lambda_transl.
    reference = jax.tree.map(frozen, model.observe(body, features, rows.boxes, rows.K))
    rollout = model.rollout(body, observed, H)
    terms = frame_losses(body, rollout.params, rollout.root, _targets(frames(rows, T, T + H)), prior, config.losses)
    terms["temporal"] = config.losses.temporal * jnp.mean((rollout.features - reference.temporal[..., T:, :]) ** 2)
    terms["translation"] = config.losses.translation * jnp.mean(
        jnp.sum((rollout.root - reference.root[..., T:, :]) ** 2, axis=-1))
    terms["shape_consistency"] = shape_consistency(rollout.params.betas, config.losses)
    if features.ndim == 4 and features.shape[1] > 1 and config.losses.interpenetration:
        terms["interpenetration"] = config.losses.interpenetration * jnp.mean(
            interpenetration(body, rollout.params, rollout.root, surfaces))
    return _total(terms), terms, rollout.params


# ----------------------------------------------------------------------------------------------
# One stage.

_ADAM = optax.scale_by_adam()
"""Adam less its step size, for the trained parts and for the prior: the step takes its rates as values."""


@partial(jax.jit, static_argnums=(0, 1, 2, 3, 4, 5, 6))
def _train_step(graphdef: nnx.GraphDef, prior_graphdef: nnx.GraphDef, objective: Callable, config: Any,
                replicated: NamedSharding, clip_norm: float | None, average_decay: float | None, rest: Any,
                body: geometry.BodyModel, state: TrainState, batch: Any, key: jax.Array, learning_rate: ArrayLike,
                discriminator_lr: ArrayLike) -> tuple[TrainState, dict[str, jax.Array]]:
    """One Adam step of the trained parameters on ``objective`` (their gradients clipped to ``clip_norm``,
    :attr:`StageConfig.clip_norm`; their moving average, if ``state`` keeps one, moved on by ``average_decay``) and
    one of the prior on its LSGAN loss. A module-level function of hashable static arguments, so the runs of one
    setting share one compilation."""
    prior = nnx.merge(prior_graphdef, state.prior)

    def loss(params):
        total, terms, fake = objective(config, body, nnx.merge(graphdef, params, rest), batch, key, prior)
        return total, (terms, fake)

    (total, (terms, fake)), grads = jax.value_and_grad(loss, has_aux=True)(state.params)
    # Clipping is a stateless transform applied before Adam, so a stage's optimiser state (and its checkpoints) has
    # one structure with or without it; unclipped, the step's program is the one it always was.
    clipped = grads if clip_norm is None else optax.clip_by_global_norm(clip_norm).update(grads, optax.EmptyState())[0]
    direction, opt = _ADAM.update(clipped, state.opt, state.params)
    targets = batch if hasattr(batch, "rotations") else batch[1]  # rows, or (features, rows)
    fake_rotations = jax.lax.stop_gradient(geometry.rotation_6d_to_matrix(fake.rot6d)).reshape(-1, 24, 3, 3)
    fake_betas = jax.lax.stop_gradient(fake.betas).reshape(-1, fake.betas.shape[-1])

    def prior_loss(prior_params):
        prior = nnx.merge(prior_graphdef, prior_params)
        real = prior(targets.rotations.reshape(-1, 24, 3, 3), targets.betas.reshape(-1, targets.betas.shape[-1]))
        return lsgan_discriminator_loss(real, prior(fake_rotations, fake_betas))

    d_loss, d_grads = jax.value_and_grad(prior_loss)(state.prior)
    d_direction, prior_opt = _ADAM.update(d_grads, state.prior_opt, state.prior)
    params = optax.apply_updates(state.params, optax.tree.scale(-learning_rate, direction))
    average = None if state.average is None else optax.incremental_update(params, state.average, 1.0 - average_decay)
    new_state = TrainState(params, optax.apply_updates(state.prior, optax.tree.scale(-discriminator_lr, d_direction)),
                           opt, prior_opt, state.step + 1, state.key, average)
    metrics = {"loss": total, **terms, "discriminator": d_loss, "grad_norm": optax.tree.norm(grads)}
    return jax.lax.with_sharding_constraint((new_state, metrics), replicated)


def _run_stage(name: str, config: Any, stage: StageConfig, workdir: Path, model: nnx.Module,
               trainable: Any, objective: Callable, sample: Callable[[jax.Array], Any],
               validate: Callable[[nnx.Module], dict[str, float]], body: geometry.BodyModel, *, resume: bool,
               log: Callable[[dict], None], progress: bool, later: tuple[str, ...] = ()) -> nnx.Module:
    """Train the ``trainable`` part of ``model`` on ``objective`` (module docstring) and return the model.
    ``config``: the run's frozen config (:class:`TrainConfig`, or the transformers' or forecasters' own), whose
    ``model.num_shapes``, ``seed`` and intervals this reads and which ``objective`` receives; ``later``: its fields
    of the stages after this one, which the stage's ``config.json`` leaves out, so that a run changed in a later
    stage resumes with the stages before it restored."""
    replicated, batch_sharding = training.data_parallel_shardings(stage.batch_size)
    graphdef, params, rest = nnx.split(model, trainable, ...)
    prior_graphdef, prior_params = nnx.split(PosePrior(config.model.num_shapes, rngs=nnx.Rngs(config.seed + 1)))
    average = None if stage.average_decay is None else jax.tree.map(jnp.copy, params)
    state = TrainState(params, prior_params, _ADAM.init(params), _ADAM.init(prior_params), jnp.asarray(0, jnp.int32),
                       jax.random.key(config.seed), average)
    learning_rate, discriminator_lr = stage.schedule(stage.learning_rate), stage.schedule(stage.discriminator_lr)
    rest, body = jax.device_put((rest, body), replicated)

    def step(state: TrainState, i: int):
        sample_key, dropout_key = jax.random.split(jax.random.fold_in(state.key, i))
        batch = jax.device_put(sample(sample_key), batch_sharding)
        return _train_step(graphdef, prior_graphdef, objective, config, replicated, stage.clip_norm,
                           stage.average_decay, rest, body, state, batch, dropout_key, learning_rate(i),
                           discriminator_lr(i))

    def kept(state: TrainState) -> nnx.Module:
        """The stage's model: the moving average where the stage keeps one, else the parameters."""
        return nnx.merge(graphdef, state.params if state.average is None else state.average, rest)

    def validate_state(state: TrainState) -> dict[str, float]:
        metrics = validate(kept(state))
        if state.average is not None:
            metrics |= {f"raw_{k}": v for k, v in validate(nnx.merge(graphdef, state.params, rest)).items()}
        return metrics

    state = training.run_training(
        workdir / name, config, state, step, steps=stage.steps, resume=resume, log_interval=config.log_interval,
        checkpoint_interval=config.checkpoint_interval, validation_interval=config.validation_interval,
        validate=validate_state, replicated=replicated, learning_rate=learning_rate, independent_of=later, log=log,
        progress=progress, description=f"dynamics {name}")
    return kept(state)


# ----------------------------------------------------------------------------------------------
# Features, validation, the whole run.

def compute_features(backbone: ResNetBackbone, crops: np.ndarray, batch_size: int = 256,
                     progress: bool = False) -> np.ndarray:
    """Backbone features (float32) of uint8 crops ``(F, size, size, 3)``."""
    graphdef, state = nnx.split(backbone)

    @jax.jit
    def run(state, crops):
        return nnx.merge(graphdef, state)(crops.astype(jnp.float32) / 255.0)

    chunks = []
    for first in tqdm.trange(0, len(crops), batch_size, disable=not progress, desc="crop features"):
        chunk = crops[first: first + batch_size]
        padded = np.concatenate([chunk, np.zeros((batch_size - len(chunk),) + chunk.shape[1:], chunk.dtype)])
        chunks.append(np.asarray(run(state, padded))[: len(chunk)])
    return np.concatenate(chunks).astype(np.float32)


def _mpjpe_mm(body, params: SMPLParams, rows: Frames) -> jax.Array:
    joints = params_to_joints(body, params, jnp.zeros_like(params.camera))
    return 1000.0 * jnp.mean(geometry.mpjpe_root_relative(joints, jnp.asarray(rows.joints3d), 0))


def _floats(metrics: dict[str, jax.Array]) -> dict[str, float]:
    return {name: float(value) for name, value in metrics.items()}


def load_trained(path: str | Path) -> tuple[ResNetBackbone, PHDT]:
    """The backbone and PHD+T written by :func:`train` to ``<workdir>/model`` (or a shipped copy of it)."""
    path = Path(path)
    # Backbones saved before BackboneConfig.crop_size took the default 64 px crops, and those saved before
    # BackboneConfig.pooling averaged their last map (the field's default).
    backbone = training.load_model_state(path / "backbone",
                                         lambda fields: _backbone_from_config(BackboneConfig(**fields), nnx.Rngs(0)))
    phdt = training.load_model_state(path / "phdt", lambda fields: PHDT(PHDTConfig(**fields), rngs=nnx.Rngs(0)))
    return backbone, phdt


@partial(jax.jit, static_argnums=0)
def _conditioning_sums(graphdef: nnx.GraphDef, state, body: geometry.BodyModel, rows: Frames) -> jax.Array:
    """Sums over ``rows`` of :func:`conditioning_metrics`' six per-frame values (metres, metres, metres, a ratio,
    degrees, metres)."""
    model = nnx.merge(graphdef, state)
    params = model.hmr(model.backbone(_crops(rows)))
    joints = params_to_joints(body, params, jnp.zeros_like(params.camera))
    root = crop_roots(params, rows.boxes, rows.K)
    orientation = geometry.geodesic_distance(geometry.rotation_6d_to_matrix(params.rot6d[:, 0]), rows.rotations[:, 0])
    true_rotation = params._replace(rot6d=params.rot6d.at[:, 0].set(
        geometry.matrix_to_rotation_6d(rows.rotations[:, 0]).astype(params.rot6d.dtype)))
    local_error = geometry.mpjpe_root_relative(params_to_joints(body, true_rotation, jnp.zeros_like(params.camera)),
                                               rows.joints3d, 0)
    return jnp.concatenate([_pose_error_sums(joints, rows), jnp.stack([
        jnp.sum(jnp.linalg.norm(root - rows.root, axis=-1)), jnp.sum(root[:, 2] / rows.root[:, 2]),
        jnp.sum(jnp.degrees(orientation)), jnp.sum(local_error)])])


def _pose_error_sums(joints: Float[Array, "B 24 3"], rows: Frames) -> Float[Array, "2"]:
    """Sums over ``rows`` of root-relative MPJPE and PA-MPJPE (metres)."""
    return jnp.stack([jnp.sum(geometry.mpjpe_root_relative(joints, rows.joints3d, 0)),
                      jnp.sum(geometry.pa_mpjpe(joints, rows.joints3d))])


def _batched_means(sums: Callable[[Frames], jax.Array], frames: Frames, batch_size: int) -> np.ndarray:
    """The per-frame means of ``sums(rows)`` over ``frames``, ``batch_size`` rows at a time."""
    if frames.num_frames == 0:
        raise ValueError("no frames to score: the frames are empty")
    total = 0.0
    for first in range(0, frames.num_frames, batch_size):
        total = total + np.asarray(sums(jax.tree.map(lambda column: jnp.asarray(column[first: first + batch_size]),
                                                     frames)), np.float64)  # summed in float64
    return total / frames.num_frames


def conditioning_metrics(body: geometry.BodyModel, model: ImageRegressor, frames: Frames,
                         batch_size: int = 256) -> dict[str, float]:
    """Stage 1's network on single frames (``batch_size`` at a time, one compilation per batch shape):
    root-relative MPJPE (``mpjpe_mm``), PA-MPJPE (``pa_mpjpe_mm``), the error of the pelvis its crop camera places
    (``root_mm``), the mean ratio of that pelvis' depth to the true one (``depth_ratio``; below 1: people placed
    too near the camera), the angle between the regressed and the true root rotation in the camera frame
    (``orientation_deg``, the body's facing and lean), and the root-relative MPJPE with the true root rotation in
    place of the regressed one (``true_rotation_mpjpe_mm``: the error of the regressed local pose and shape alone,
    what :func:`mean_pose_metrics`' constant pose, given the true root rotation, is to be compared with; the
    difference to ``mpjpe_mm`` is what a perfect root rotation would save)."""
    graphdef, state = nnx.split(model)
    mpjpe, pa_mpjpe, root, ratio, orientation, true_rotation_mpjpe = _batched_means(
        partial(_conditioning_sums, graphdef, state, body), frames, batch_size)
    return {"mpjpe_mm": 1000.0 * mpjpe, "pa_mpjpe_mm": 1000.0 * pa_mpjpe, "root_mm": 1000.0 * root,
            "depth_ratio": ratio, "orientation_deg": orientation,
            "true_rotation_mpjpe_mm": 1000.0 * true_rotation_mpjpe}


def mean_local_pose(rotations: Float[ArrayLike, "F 24 3 3"]) -> Float[np.ndarray, "24 3 3"]:
    """The chordal mean of each joint's local rotation over frames (the nearest rotation to the mean matrix)."""
    rotations = np.asarray(rotations, np.float64)
    if rotations.ndim != 4 or rotations.shape[1:] != (24, 3, 3) or len(rotations) == 0:
        raise ValueError(f"mean_local_pose takes rotations of shape (frames >= 1, 24, 3, 3), got {rotations.shape}")
    u, _, vt = np.linalg.svd(np.mean(rotations, axis=0))
    fix = np.where(np.linalg.det(u @ vt) < 0, -1.0, 1.0)  # a reflection's last axis flipped back
    u[..., -1] *= fix[..., None]
    return (u @ vt).astype(np.float32)


@jax.jit
def _mean_pose_sums(body: geometry.BodyModel, pose: Float[Array, "24 3 3"], rows: Frames) -> jax.Array:
    rotations = jnp.broadcast_to(pose, rows.rotations.shape).at[:, 0].set(rows.rotations[:, 0])
    joints = jax.vmap(lambda r, b: geometry.body_forward(body, r, b, jnp.zeros(3, r.dtype)).joints)(
        rotations, rows.betas)
    return _pose_error_sums(joints, rows)


def mean_pose_metrics(body: geometry.BodyModel, pose: Float[ArrayLike, "24 3 3"], frames: Frames,
                      batch_size: int = 256) -> dict[str, float]:
    """A reference for :func:`conditioning_metrics`: one constant body pose (e.g. the :func:`mean_local_pose` of
    the training frames) given each frame's true root rotation and shape, scored alike (``mpjpe_mm``,
    ``pa_mpjpe_mm``). A conditioning network that sees nothing of the pose beyond its training mean scores about
    this, or worse by its root rotation's error."""
    mpjpe, pa_mpjpe = _batched_means(partial(_mean_pose_sums, body, jnp.asarray(pose, jnp.float32)),
                                     without_crops(frames), batch_size)
    return {"mpjpe_mm": 1000.0 * mpjpe, "pa_mpjpe_mm": 1000.0 * pa_mpjpe}


def _training_frames(config: TrainConfig, workdir: Path, body: geometry.BodyModel, progress: bool,
                     data_workers: int) -> tuple[Path, Frames, Frames]:
    """The render cache folder, the training frames and the validation frames of ``config``."""
    cache_dir = workdir / "data_cache" if config.cache_dir is None else Path(config.cache_dir)
    return (cache_dir, build_frames(config.data, body, cache_dir, progress, data_workers),
            build_frames(config.validation, body, cache_dir, progress, data_workers))


def _train_image(config: TrainConfig, workdir: Path, body: geometry.BodyModel, frames: Frames, validation: Frames,
                 rngs: nnx.Rngs, *, resume: bool, log: Callable[[dict], None], progress: bool) -> ImageRegressor:
    image_model = ImageRegressor(config.backbone, config.model, rngs=rngs)

    def sample_rows(key):
        index = np.asarray(jax.random.randint(key, (config.image.batch_size,), 0, frames.num_frames))
        return jax.tree.map(lambda column: column[index], frames)

    def validate_image(model: ImageRegressor) -> dict[str, float]:
        metrics = conditioning_metrics(body, model, jax.tree.map(lambda column: column[::4], validation))
        return {f"val_{name}": value for name, value in metrics.items()}

    return _run_stage("image", config, config.image, workdir, image_model, nnx.Param, _image_objective, sample_rows,
                      validate_image, body, resume=resume, log=log, progress=progress, later=("movie", "ar"))


def train_conditioning(config: TrainConfig, workdir: str | Path, body: geometry.BodyModel, *, resume: bool,
                       log: Callable[[dict], None] = lambda record: None, progress: bool = True,
                       data_workers: int = 1) -> ImageRegressor:
    """Only the first of :func:`train`'s stages, in the same folders (:func:`train` on ``workdir`` continues from
    it): the backbone and HMR head on single frames, for choices about the data that this stage sees first (score
    them with :func:`conditioning_metrics` on validation frames)."""
    workdir = Path(workdir).resolve()
    _, frames, validation = _training_frames(config, workdir, body, progress, data_workers)
    return _train_image(config, workdir, body, frames, validation, nnx.Rngs(config.seed), resume=resume, log=log,
                        progress=progress)


def train(config: TrainConfig, workdir: str | Path, body: geometry.BodyModel, *, resume: bool,
          log: Callable[[dict], None] = lambda record: None, progress: bool = True,
          data_workers: int = 1) -> tuple[ResNetBackbone, PHDT]:
    """Run the three stages of the module docstring in ``workdir`` and return the trained backbone and PHD+T.

    ``resume=True`` continues a killed run (finished stages are restored, not retrained); a stage does not record
    the stages after it, so a run whose later stage changed (delete that stage's folder) restores the stages before
    it. ``data_workers`` CPU processes render the videos (the same frames as one)."""
    workdir = Path(workdir).resolve()
    cache_dir, frames, validation = _training_frames(config, workdir, body, progress, data_workers)
    rngs = nnx.Rngs(config.seed)
    image_model = _train_image(config, workdir, body, frames, validation, rngs, resume=resume, log=log,
                               progress=progress)

    features = cached_features(image_model.backbone, frames, config.data, cache_dir, progress)
    validation_features = cached_features(image_model.backbone, validation, config.validation, cache_dir, progress)
    length = config.observed + config.horizon
    starts = window_starts(frames, length)
    validation_starts = window_starts(validation, length, stride=10)

    def sample_windows(key):
        chosen = starts[np.asarray(jax.random.randint(key, (config.movie.batch_size,), 0, len(starts)))]
        return gather_windows((features, without_crops(frames)), chosen, length)

    validation_windows = gather_windows((validation_features, without_crops(validation)), validation_starts, length)

    phdt = PHDT(config.model, rngs=rngs)
    nnx.update(phdt.hmr, nnx.state(image_model.hmr))

    @nnx.jit
    def movie_metrics(model, features, rows):
        params = model.regress(model.condition(features))
        first = model.receptive_field - 1
        return {"val_mpjpe_mm": _mpjpe_mm(body, jax.tree.map(lambda x: x[:, first:], params),
                                          jax.tree.map(lambda x: x[:, first:], rows))}

    def validate_movie(model: PHDT) -> dict[str, float]:
        return _floats(movie_metrics(model, *validation_windows))

    movie_parts = nnx.All(nnx.Param, nnx.Any(nnx.PathContains("movie"), nnx.PathContains("hmr"),
                                              nnx.PathContains("deltas")))
    phdt = _run_stage("movie", config, config.movie, workdir, phdt, movie_parts, _movie_objective, sample_windows,
                      validate_movie, body, resume=resume, log=log, progress=progress, later=("ar",))

    @nnx.jit
    def ar_metrics(model, features, rows):
        T = config.observed
        observed = model.observe(body, features[:, :T], rows.boxes[:, :T], rows.K[:, :T])
        rollout = model.rollout(body, observed, config.horizon)
        future = jax.tree.map(lambda x: x[:, T:], rows)
        return {"val_future_mpjpe_mm": _mpjpe_mm(body, rollout.params, future),
                "val_future_root_mm": 1000.0 * jnp.mean(jnp.linalg.norm(rollout.root - future.root, axis=-1))}

    def validate_ar(model: PHDT) -> dict[str, float]:
        return _floats(ar_metrics(model, *validation_windows))

    ar_parts = nnx.All(nnx.Param, nnx.Any(nnx.PathContains("ar"), nnx.PathContains("joint_encoder"),
                                           nnx.PathContains("translation")))
    phdt = _run_stage("ar", config, config.ar, workdir, phdt, ar_parts, _ar_objective, sample_windows, validate_ar,
                      body, resume=resume, log=log, progress=progress)

    training.save_model(workdir / "model" / "backbone", config.backbone, nnx.state(image_model.backbone))
    training.save_model(workdir / "model" / "phdt", config.model, nnx.state(phdt))
    return image_model.backbone, phdt


def cached_features(backbone: ResNetBackbone, frames: Frames, data: DataConfig, cache_dir: Path,
                    progress: bool = False) -> np.ndarray:
    """:func:`compute_features` of ``frames`` (made from ``data``), cached in ``cache_dir`` under a hash of ``data``
    and the backbone's parameters: features belong to one trained backbone."""
    digest = hashlib.sha1(json.dumps(training.to_jsonable(data), sort_keys=True).encode())
    for leaf in jax.tree.leaves(nnx.state(backbone, nnx.Param)):
        digest.update(np.asarray(leaf).tobytes())
    path = Path(cache_dir) / f"dynamics_features_{digest.hexdigest()[:16]}.npy"
    if path.is_file():
        return np.load(path)
    features = compute_features(backbone, frames.crops, progress=progress)
    training.write_atomically(path, lambda file: np.save(file, features))
    return features

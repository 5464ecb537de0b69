"""Training FLEX on synthetic CMU motion (paper Sec. 3.1 and 4; the project's shared loop, :mod:`training`).

The data is a pool of samples (:func:`~flex.make_sample`) drawn once from consecutive seeds and cached in
``cache_dir`` (a file named by a hash of its config): a ``static_fraction`` of them with static cameras, the
rest with moving ones (the paper's dynamic setting), from the training clips only; whole clips
(:data:`TEST_CLIPS`) are held out. Step i draws its batch indices, dropout and nothing else from
``fold_in(key(seed), i)``, so a resumed run repeats an uninterrupted one exactly.

A step updates the generator (F_Q, E_Q, F_S, E_S) on Eq. 9, whose adversarial term reaches E_Q through the
discriminator, and then the discriminator on its LSGAN loss against the step's (detached) predictions. Two
Adam optimisers (the official trainer's AMSGrad; ``generator_lr`` and ``discriminator_lr``), here with a
warm-up and a cosine decay because CPU runs are short.

Outputs in ``workdir``: ``config.json``, ``log.jsonl`` (losses; at validation steps MPJPE protocol #1 in mm
on held-out samples), ``checkpoints/`` (orbax, atomic) and ``model/`` (the generator, read back by
:func:`load_flex`). Data parallel over the local devices as :func:`training.data_parallel_shardings` says.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any, Literal, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
import tqdm
from flax import nnx
from jax.sharding import NamedSharding
from jax.typing import ArrayLike

import geometry
import mocap
import training
from geometry import FLEX20, STRUCTRI17

from ._clips import TEST_CLIPS, TRAIN_CLIPS, VALIDATION_CLIPS
from ._data import Batch, DataConfig, make_sample
from ._losses import LossWeights, discriminator_loss, generator_loss
from ._model import CONFIGS, Discriminator, Flex, FlexConfig

__all__ = ["TrainConfig", "TrainState", "build_pool", "load_flex", "train", "train_step", "validation_mpjpe"]



@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Everything that determines a FLEX training run (written to ``config.json``)."""

    model: str | FlexConfig = "cpu"
    """A name in :data:`~flex.CONFIGS` or a :class:`~flex.FlexConfig`; its ``views`` must be ``data.views``."""
    data: DataConfig = DataConfig(views=4, frames=64, clips=TRAIN_CLIPS)
    validation_data: DataConfig = DataConfig(views=4, frames=64, clips=VALIDATION_CLIPS, camera_motion="dynamic")
    pool_size: int = 2048
    """Training samples drawn once (seeds 0 ...) and cached."""
    static_fraction: float = 0.5
    """Share of the pool with static cameras; the rest move (``camera_motion="dynamic"``)."""
    validation_size: int = 64
    batch_size: int = 16
    steps: int = 3000
    generator_lr: float = 1e-3
    """The official trainer's Adam rate for the generator (AMSGrad)."""
    discriminator_lr: float = 1e-4
    warmup_steps: int = 100
    end_lr_fraction: float = 0.01
    """The cosine decay ends at this fraction of each peak rate."""
    losses: LossWeights = LossWeights(adversarial=0.05)
    """Eq. 9's weights, except lambda_Q: the paper's 1 on the sum over the 14 + K discriminators outweighed the
    position loss so much that the generator could not even fit a fixed batch; 0.05 is about 1 on their mean."""
    seed: int = 0
    checkpoint_interval: int = 250
    validation_interval: int = 500
    log_interval: int = 50
    cache_dir: str | None = None
    """Where sample pools are cached; None: ``<workdir>/data_cache``."""

    def __post_init__(self) -> None:
        for name in ("pool_size", "validation_size", "batch_size", "steps"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if not 0 <= self.warmup_steps < self.steps:
            raise ValueError(f"warmup_steps must be in [0, steps={self.steps}), got {self.warmup_steps}")
        if not 0.0 <= self.static_fraction <= 1.0:
            raise ValueError(f"static_fraction must be in [0, 1], got {self.static_fraction}")
        if isinstance(self.model, str) and self.model not in CONFIGS:
            raise ValueError(f"model must be one of {sorted(CONFIGS)} or a FlexConfig, got {self.model!r}")
        model = self.model_config
        if not model.views == self.data.views == self.validation_data.views:
            raise ValueError(f"the model has {model.views} views, the data {self.data.views} and "
                             f"{self.validation_data.views}")
        for data in (self.data, self.validation_data):
            if data.frames < model.min_frames:
                raise ValueError(f"windows of {data.frames} frames are shorter than the model's {model.min_frames}")
        shared = set(self.data.clip_names) & set(self.validation_data.clip_names)
        if shared:
            raise ValueError(f"training and validation share clips {sorted(shared)}")
        held_out = sorted(c for c in self.data.clip_names if c in TEST_CLIPS or mocap.cmu_expmap_split(c) == "test")
        if held_out:
            raise ValueError(f"training clips include held-out test motion {held_out}")

    @property
    def model_config(self) -> FlexConfig:
        return CONFIGS[self.model] if isinstance(self.model, str) else self.model

    def learning_rates(self, step: int) -> tuple[float, float]:
        """The generator's and the discriminator's rate at ``step`` (steps taken before it): a linear warm-up to
        each peak, then a cosine decay to ``end_lr_fraction`` of it at the last step."""
        return tuple(float(optax.warmup_cosine_decay_schedule(0.0, peak, self.warmup_steps, self.steps,
                                                              peak * self.end_lr_fraction)(step))
                     for peak in (self.generator_lr, self.discriminator_lr))


class TrainState(NamedTuple):
    """Everything a step changes, plus the run's key: exactly what a checkpoint holds."""

    params: Any
    """The generator's parameters."""
    rest: Any
    """The generator's other state (batch-norm running averages)."""
    discriminator: Any
    """The discriminator's parameters."""
    generator_opt: optax.OptState
    discriminator_opt: optax.OptState
    step: jax.Array
    key: jax.Array
    """``key(seed)``: step i uses ``fold_in(key, i)``."""


_VALIDATION_SEED = 1_000_000
"""First seed of the validation windows: far from the training pool's seeds (0 ... pool_size - 1)."""

_AMSGRAD = optax.scale_by_amsgrad()
"""The official trainer's AMSGrad, for the generator and for the discriminator, less its step size: train_step takes
the step's rates as values, so runs that differ only in their schedules share one compiled step."""


def _pool_file(config: DataConfig, count: int, first_seed: int, rest_pose: str, cache_dir: Path) -> Path:
    name = json.dumps([training.to_jsonable(config), count, first_seed, rest_pose], sort_keys=True)
    return cache_dir / f"flex_pool_{hashlib.sha1(name.encode()).hexdigest()[:16]}.npz"


def build_pool(config: DataConfig, count: int, first_seed: int, cache_dir: str | Path | None = None,
               progress: bool = True, workers: int = 1, rest_pose: Literal["totem", "tpose"] = "totem") -> Batch:
    """``count`` samples of ``config`` from seeds ``first_seed ...``, stacked (float32, cameras dropped: training
    needs none), cached in ``cache_dir`` when given. ``workers > 1`` builds them in that many CPU-only processes
    (:func:`training.process_map`), the same samples in the same order. ``rest_pose`` must be the model's: the
    real rotations that the discriminator sees are relative to it (:func:`~flex.make_sample`)."""
    path = None if cache_dir is None else _pool_file(config, count, first_seed, rest_pose, Path(cache_dir))
    if path is not None and path.is_file():
        with np.load(path) as stored:
            return Batch(**{name: stored[name] for name in stored.files}, cameras=None)
    if workers == 1:
        samples = [make_sample(seed, config, rest_pose)._replace(cameras=None)
                   for seed in tqdm.trange(first_seed, first_seed + count, disable=not progress, desc="flex samples")]
        pool = _stack(samples)
    else:
        bounds = np.linspace(first_seed, first_seed + count, min(count, 8 * workers) + 1).astype(int)
        pool = _concatenate(training.process_map(
            _sample_range, [(config, int(a), int(b), rest_pose) for a, b in zip(bounds[:-1], bounds[1:])], workers))
    if path is not None:
        arrays = {name: value for name, value in pool._asdict().items() if value is not None}
        training.write_atomically(path, lambda file: np.savez(file, **arrays))
    return pool


def _stack(samples: list[Batch]) -> Batch:
    return jax.tree.map(lambda *leaves: np.stack(leaves).astype(np.float32), *samples)


def _concatenate(parts: list[Batch]) -> Batch:
    return jax.tree.map(lambda *leaves: np.concatenate(leaves), *parts)


def _sample_range(config: DataConfig, first_seed: int, end_seed: int, rest_pose: str) -> Batch:
    return _stack([make_sample(seed, config, rest_pose)._replace(cameras=None) for seed in range(first_seed, end_seed)])


def _training_pool(config: TrainConfig, cache_dir: Path, progress: bool, workers: int) -> Batch:
    static = round(config.static_fraction * config.pool_size)
    return _concatenate([
        build_pool(dataclasses.replace(config.data, camera_motion=motion), count, first, cache_dir, progress, workers,
                   config.model_config.rest_pose)
        for motion, count, first in (("static", static, 0), ("dynamic", config.pool_size - static, static))
        if count])


@partial(jax.jit, static_argnums=(0, 1, 2, 3))
def train_step(
    graphdef: nnx.GraphDef, discriminator_graphdef: nnx.GraphDef, losses: LossWeights, replicated: NamedSharding,
    state: TrainState, batch: Batch, key: jax.Array, generator_lr: ArrayLike, discriminator_lr: ArrayLike,
) -> tuple[TrainState, dict[str, jax.Array]]:
    """One generator step on Eq. 9 and one discriminator step on its LSGAN loss (pure; see the module docstring),
    at the step's rates (:meth:`TrainConfig.learning_rates`)."""
    discriminator = nnx.merge(discriminator_graphdef, state.discriminator)

    def generator_objective(params):
        model = nnx.merge(graphdef, params, state.rest, copy=True)
        outputs = model(batch.points_2d, batch.confidences, key=key)
        total, terms = generator_loss(outputs, batch, discriminator, losses)
        return total, (terms, outputs, nnx.state(model, nnx.Not(nnx.Param)))

    (total, (terms, outputs, rest)), grads = jax.value_and_grad(generator_objective, has_aux=True)(state.params)
    direction, generator_opt = _AMSGRAD.update(grads, state.generator_opt, state.params)
    params = optax.apply_updates(state.params, optax.tree.scale(-generator_lr, direction))

    def discriminator_objective(discriminator_params):
        return discriminator_loss(nnx.merge(discriminator_graphdef, discriminator_params), outputs, batch)

    d_loss, d_grads = jax.value_and_grad(discriminator_objective)(state.discriminator)
    d_direction, discriminator_opt = _AMSGRAD.update(d_grads, state.discriminator_opt, state.discriminator)
    new_state = TrainState(params, rest,
                           optax.apply_updates(state.discriminator, optax.tree.scale(-discriminator_lr, d_direction)),
                           generator_opt, discriminator_opt, state.step + 1, state.key)
    metrics = {"loss": total, **terms, "discriminator": d_loss, "grad_norm": optax.tree.norm(grads)}
    return jax.lax.with_sharding_constraint((new_state, metrics), replicated)


@partial(jax.jit, static_argnums=0)
def _validation_errors(graphdef: nnx.GraphDef, params: Any, rest: Any, batch: Batch) -> jax.Array:
    """Per sample and view the MPJPE (metres, protocol #1, the 17 H36M joints) of the deterministic model."""
    outputs = nnx.merge(graphdef, params, rest)(batch.points_2d, batch.confidences)
    predicted = geometry.remap_joints(outputs.joints_relative, FLEX20, STRUCTRI17)
    return jnp.mean(geometry.mpjpe_root_relative(predicted, batch.joints.astype(predicted.dtype),
                                                 STRUCTRI17.index("mid_hip")), axis=-1)


def _mean_validation_mpjpe(graphdef: nnx.GraphDef, params: Any, rest: Any, pool: Batch, batch_size: int) -> float:
    errors = [_validation_errors(graphdef, params, rest, jax.tree.map(lambda x: x[i: i + batch_size], pool))
              for i in range(0, pool.points_2d.shape[0], batch_size)]
    return 1000.0 * float(jnp.mean(jnp.concatenate(errors)))


def _validation_pool(config: TrainConfig, cache_dir: Path | None, progress: bool, workers: int) -> Batch:
    return build_pool(config.validation_data, config.validation_size, _VALIDATION_SEED, cache_dir, progress, workers,
                      config.model_config.rest_pose)


def validation_mpjpe(model: Flex, config: TrainConfig, cache_dir: str | Path | None = None, *,
                     progress: bool = False) -> float:
    """MPJPE (mm, protocol #1, deterministic model) of ``model`` on the validation windows of ``config``: the
    figure :func:`train` logs as ``val_mpjpe_mm``, so that a shipped model can be compared with a new run on the same
    windows (cached in ``cache_dir`` when given)."""
    if model.config.views != config.validation_data.views:
        raise ValueError(f"the model has {model.config.views} views, the validation windows "
                         f"{config.validation_data.views}")
    if model.config.rest_pose != config.model_config.rest_pose:
        raise ValueError(f"the model's rest pose is {model.config.rest_pose!r}, the config's "
                         f"{config.model_config.rest_pose!r}")
    pool = _validation_pool(config, None if cache_dir is None else Path(cache_dir), progress, 1)
    graphdef, params, rest = nnx.split(model, nnx.Param, ...)
    return _mean_validation_mpjpe(graphdef, params, rest, pool, config.batch_size)


def load_flex(path: str | Path) -> Flex:
    """The generator written by :func:`train` to ``<workdir>/model`` (deterministic use: call it without a key)."""
    return training.load_model_state(path, lambda fields: Flex(FlexConfig(**fields), rngs=nnx.Rngs(0)))


def train(
    config: TrainConfig,
    workdir: str | Path,
    *,
    resume: bool,
    log: Callable[[dict], None] = lambda record: None,
    progress: bool = True,
    data_workers: int = 1,
) -> Flex:
    """Train per ``config`` in ``workdir`` and return the generator (see the module docstring for the files).

    ``resume=True`` continues from the latest checkpoint (refusing a different config); ``resume=False``
    refuses a ``workdir`` that already has checkpoints. ``log`` receives every logged record; ``data_workers``
    processes build the sample pools (:func:`build_pool`)."""
    replicated, batch_sharding = training.data_parallel_shardings(config.batch_size)
    workdir = Path(workdir).resolve()
    cache_dir = workdir / "data_cache" if config.cache_dir is None else Path(config.cache_dir)
    pool = _training_pool(config, cache_dir, progress, data_workers)
    validation = _validation_pool(config, cache_dir, progress, data_workers)

    model_config = config.model_config
    rngs = nnx.Rngs(config.seed)
    graphdef, params, rest = nnx.split(Flex(model_config, rngs=rngs), nnx.Param, ...)
    discriminator_graphdef, discriminator = nnx.split(Discriminator(model_config, rngs=rngs))
    state = TrainState(params, rest, discriminator, _AMSGRAD.init(params), _AMSGRAD.init(discriminator),
                       jnp.asarray(0, jnp.int32), jax.random.key(config.seed))

    def step(state: TrainState, i: int) -> tuple[TrainState, dict[str, jax.Array]]:
        sample_key, dropout_key = jax.random.split(jax.random.fold_in(state.key, i))
        index = np.asarray(jax.random.randint(sample_key, (config.batch_size,), 0, config.pool_size))
        batch = jax.device_put(jax.tree.map(lambda x: x[index], pool), batch_sharding)
        return train_step(graphdef, discriminator_graphdef, config.losses, replicated, state, batch, dropout_key,
                          *config.learning_rates(i))

    state = training.run_training(
        workdir, config, state, step, steps=config.steps, resume=resume, log_interval=config.log_interval,
        checkpoint_interval=config.checkpoint_interval, validation_interval=config.validation_interval,
        validate=lambda state: {"val_mpjpe_mm": _mean_validation_mpjpe(graphdef, state.params, state.rest, validation,
                                                                       config.batch_size)},
        replicated=replicated,
        learning_rate=lambda i: config.learning_rates(i)[0],
        log=log, progress=progress, description="flex train")
    training.save_model(workdir / "model", model_config, nnx.merge_state(state.params, state.rest))
    return nnx.merge(graphdef, state.params, state.rest)

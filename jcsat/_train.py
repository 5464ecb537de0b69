"""Training the JCSAT model on synthetic Shelf-rig windows (paper Sec. 4.1.3; reference section 4).

:func:`train` builds (or loads from the cache) the training and validation windows
(:func:`~jcsat.build_dataset`), splits the Flax NNX model into a graph definition and pure state,
and runs one jitted, data-parallel step per iteration: AdamW (weight decay on matrices only) with a
linear warm-up and a cosine decay, on the losses of Eq. 15. Step s draws its batch, rotations and
candidate masking from ``fold_in(key(seed), s)`` and nothing else, so a run resumed from a checkpoint
continues exactly as an uninterrupted one.

Outputs in ``workdir``: ``config.json``; ``log.jsonl`` (one JSON object per logged step: losses, lr,
seconds per step, and at validation steps MPJPE in mm and PCP in % on held-out synthetic windows);
``checkpoints/<step>/`` (orbax, atomic, the last two kept); ``model/`` (``config.json`` and
``state.npz``, the final parameters, read back by :func:`~jcsat.load_model`).

Data parallelism: a one-axis mesh ``"data"`` over the local devices shards every batch along its
first axis and replicates parameters and optimiser state; ``batch_size`` must be a multiple of the
device count. On CPU, ``XLA_FLAGS=--xla_force_host_platform_device_count=N`` (set before jax starts)
gives N devices.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from functools import cache, partial
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import nnx
from jax.sharding import NamedSharding
from jax.typing import ArrayLike

import geometry
import mocap
import training
from geometry import SHELF15

from ._data import VALIDATION_CLIPS, Batch, DataConfig, WindowDataset, build_dataset, sample_batch, window_batch
from ._losses import LossConfig, jcsat_loss
from ._model import CONFIGS, JCSAT, JCSATConfig, load_model

__all__ = [
    "TrainConfig", "TrainState", "init_state", "learning_rate_schedule", "make_optimiser", "train_step", "train",
    "TRAIN_CONFIGS", "validate",
]


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Everything that determines a training run (written to ``config.json``)."""

    model: str | JCSATConfig = "cpu"
    """A name in :data:`~jcsat.CONFIGS` or a :class:`~jcsat.JCSATConfig`."""
    batch_size: int = 8
    steps: int = 2_400
    peak_lr: float = 1e-3
    warmup_steps: int = 100
    """Linear warm-up from 0 to ``peak_lr``; a cosine decay to ``end_lr`` follows until ``steps``.
    These defaults are the ``"cpu"`` run of :data:`TRAIN_CONFIGS` (36 minutes on 2 CPU cores): a short
    schedule with the usual small-transformer rate. The official code trains 'medium' with 1.5e-4 for 500
    epochs (the paper's "beginning with 1e-5" is the cosine's end), a GPU-scale budget."""
    end_lr: float = 1e-5
    weight_decay: float = 0.05
    """AdamW decoupled weight decay, applied to parameters with at least 2 dimensions only (no biases,
    LayerNorm scales or other vectors)."""
    grad_clip: float | None = None
    """Global-norm gradient clipping; None: off (paper and code)."""
    seed: int = 0
    """Model initialisation and every step's randomness (``fold_in(key(seed), step)``)."""
    checkpoint_interval: int = 200
    validation_interval: int = 400
    log_interval: int = 50
    validation_windows: int = 512
    """Validation uses the first this many validation windows (fewer if there are fewer), unrotated."""
    losses: LossConfig = LossConfig()
    data: DataConfig = DataConfig()
    validation_data: DataConfig = DataConfig(clips=VALIDATION_CLIPS, num_scenes=4, first_seed=10_000)
    cache_dir: str | None = None
    """Where built datasets are cached; None: ``<workdir>/data_cache``."""
    init_model: str | None = None
    """A model folder (:func:`~jcsat.load_model`) whose parameters start the run (fine-tuning); its config must be
    ``model``'s. None: a fresh initialisation from ``seed``."""

    @property
    def model_config(self) -> JCSATConfig:
        """``model`` as a configuration (a name looked up in :data:`~jcsat.CONFIGS`)."""
        return CONFIGS[self.model] if isinstance(self.model, str) else self.model

    def with_steps(self, steps: int) -> TrainConfig:
        """This run with ``steps`` optimisation steps, its warm-up cut to leave at least one step of decay."""
        return dataclasses.replace(self, steps=steps, warmup_steps=min(self.warmup_steps, steps - 1))

    def __post_init__(self) -> None:
        for name in ("batch_size", "steps", "checkpoint_interval", "validation_interval", "log_interval",
                     "validation_windows"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if not 0 <= self.warmup_steps < self.steps:  # the cosine after the warm-up needs at least one step
            raise ValueError(f"warmup_steps must be in [0, steps={self.steps}), got {self.warmup_steps}")
        if isinstance(self.model, str) and self.model not in CONFIGS:
            raise ValueError(f"model must be one of {sorted(CONFIGS)} or a JCSATConfig, got {self.model!r}")
        model_window = self.model_config.frames
        if not self.data.window == self.validation_data.window == model_window:
            raise ValueError(f"training and validation windows must have the model's length {model_window}")
        shared_seeds = set(self.data.seeds) & set(self.validation_data.seeds)
        if shared_seeds:
            raise ValueError(f"training and validation scenes share seeds {sorted(shared_seeds)[:5]}")
        held_out = [clip for clip in self.data.clips if clip in set(VALIDATION_CLIPS) | set(self.validation_data.clips)
                    or any(mocap.cmu_expmap_split(part) == "test" for part in mocap.clip_files(clip))]
        if held_out:
            raise ValueError(f"training clips {held_out[:3]} are held out (validation clips or the CMU-Mocap "
                             "benchmark's test split)")


_VALIDATION_4DA = DataConfig(clips=VALIDATION_CLIPS, num_scenes=4, first_seed=10_000, head_rule="4da")
"""The default validation scenes labelled with the 4D-association head rule."""

TRAIN_CONFIGS: dict[str, TrainConfig] = {
    "cpu": TrainConfig(),
    # The shipped model's run: the wider model, 3x the scenes, 8x the batch, 2.5x the steps (5 minutes of steps on
    # one H100, jcsat/assets/README.md; the scenes are built in parallel processes with ``--data-workers``).
    "gpu": TrainConfig(
        model="cpu_wide", batch_size=64, steps=6_000, warmup_steps=300, checkpoint_interval=1_000,
        validation_interval=1_000, log_interval=100, data=DataConfig(num_scenes=48),
    ),
    # The shipped model's second stage: the "gpu" run's model fine-tuned on the 2-core CPU (38 minutes) on labels
    # whose head follows the 4D-association rule, the rule of JCSAT's official code (DataConfig.head_rule).
    "cpu_head_4da": TrainConfig(
        model="cpu_wide", batch_size=16, steps=500, peak_lr=2e-4, warmup_steps=50, checkpoint_interval=100,
        validation_interval=250, log_interval=25, data=DataConfig(head_rule="4da"),
        validation_data=_VALIDATION_4DA,
        init_model=str(Path(__file__).parent / "assets" / "shelf_wide"),
    ),
    # The shipped model continued on one GPU with twice the scenes, labelled by the 4D-association head rule; run with
    # --train-expmap so that the scenes also draw people from the CMU-Mocap benchmark's train split.
    "gpu_expmap": TrainConfig(
        model="cpu_wide", batch_size=64, steps=3_000, peak_lr=3e-4, warmup_steps=150, checkpoint_interval=500,
        validation_interval=500, log_interval=100, data=DataConfig(num_scenes=96, head_rule="4da"),
        validation_data=_VALIDATION_4DA,
        init_model=str(Path(__file__).parent / "assets" / "shelf_wide_4da"),
    ),
    # The paper's Medium model from scratch at the official code's rate. 8 windows per step took 70 GB of an H200
    # and 0.15 s per step (jcsat/assets/README.md): the 40,000 steps are about 1.7 hours of one such GPU.
    "gpu_medium": TrainConfig(
        model="medium", batch_size=8, steps=40_000, peak_lr=1.5e-4, warmup_steps=1_000, checkpoint_interval=1_000,
        validation_interval=1_000, log_interval=10, data=DataConfig(num_scenes=96, head_rule="4da"),
        validation_data=_VALIDATION_4DA,
    ),
}
"""Named training runs (``python -m experiments.shelf_jcsat --train --config NAME``)."""


class TrainState(NamedTuple):
    """Everything a step changes, plus the run's key: exactly what a checkpoint holds."""

    params: Any
    rest: Any
    """The model's non-parameter state (fixed random features, RNG counters, ...)."""
    opt_state: optax.OptState
    step: jax.Array
    """Number of steps taken."""
    key: jax.Array
    """``key(seed)``: step s uses ``fold_in(key, s)``."""


def init_state(config: TrainConfig, params: Any, rest: Any) -> TrainState:
    """Step 0: fresh optimiser state for ``params`` and the run's key ``key(config.seed)``."""
    opt_state = make_optimiser(config.weight_decay, config.grad_clip).init(params)
    return TrainState(params, rest, opt_state, jnp.asarray(0, jnp.int32), jax.random.key(config.seed))


_sample = jax.jit(sample_batch, static_argnums=(2, 3))
_window_batch = jax.jit(window_batch, static_argnums=3)


def learning_rate_schedule(config: TrainConfig) -> optax.Schedule:
    """Linear warm-up from 0 to ``peak_lr`` over ``warmup_steps``, then cosine decay to ``end_lr`` at ``steps``."""
    return optax.warmup_cosine_decay_schedule(0.0, config.peak_lr, config.warmup_steps, config.steps, config.end_lr)


def _matrices(params: Any) -> Any:
    return jax.tree.map(lambda p: p.ndim >= 2, params)


@cache
def make_optimiser(weight_decay: float, grad_clip: float | None = None) -> optax.GradientTransformation:
    """AdamW (beta 0.9, 0.999) less its step size, decaying only parameters with ndim >= 2, after global-norm
    clipping to ``grad_clip`` (None: none). :func:`train_step` scales by the step's learning rate, a value, so
    runs that differ only in their schedule share one compiled step; equal settings give the same (cached)
    object, a static argument of the step."""
    adamw = optax.chain(optax.scale_by_adam(b1=0.9, b2=0.999), optax.add_decayed_weights(weight_decay, _matrices))
    return adamw if grad_clip is None else optax.chain(optax.clip_by_global_norm(grad_clip), adamw)


@partial(jax.jit, static_argnums=(0, 1, 2, 3))
def train_step(
    graphdef: nnx.GraphDef, losses: LossConfig, optimiser: optax.GradientTransformation, replicated: NamedSharding,
    state: TrainState, batch: Batch, key: jax.Array, learning_rate: ArrayLike,
) -> tuple[TrainState, dict[str, jax.Array]]:
    """One AdamW step on ``batch`` (Eq. 15) at ``learning_rate``; ``key`` drives the model's candidate masking and
    dropout; ``optimiser`` is :func:`make_optimiser`'s.

    Pure: the new state and the step's metrics (each loss term, the total, the gradient norm). With
    the batch sharded along its first axis, each device computes its part of the batch and the
    gradient is reduced across devices; the new state is constrained to ``replicated``. The static
    arguments are hashable, so every :func:`train` call with the same model, losses and optimiser settings
    reuses one compilation, whatever its schedule.
    """

    def loss_fn(params):
        model = nnx.merge(graphdef, params, state.rest)
        pred = model(batch.points, batch.mask, key=key)
        total, terms = jcsat_loss(pred, batch, losses)
        return total, (terms, nnx.state(model, nnx.Not(nnx.Param)))

    (total, (terms, rest)), grads = jax.value_and_grad(loss_fn, has_aux=True)(state.params)
    direction, opt_state = optimiser.update(grads, state.opt_state, state.params)
    params = optax.apply_updates(state.params, optax.tree.scale(-learning_rate, direction))
    new_state = TrainState(params, rest, opt_state, state.step + 1, state.key)
    metrics = {"loss": total, **terms, "grad_norm": optax.tree.norm(grads)}
    return jax.lax.with_sharding_constraint((new_state, metrics), replicated)


@partial(jax.jit, static_argnums=0)
def _eval_step(graphdef: nnx.GraphDef, params: Any, rest: Any, batch: Batch, weight: jax.Array):
    """Per-batch sums for MPJPE and PCP over the valid frames of the windows with ``weight`` 1."""
    model = nnx.merge(graphdef, params, rest)
    pred = model(batch.points, batch.mask).astype(batch.target.dtype)
    valid = batch.target_valid & (weight[:, None] > 0)
    error = geometry.mpjpe(pred, batch.target)  # (B, N), metres
    correct = geometry.pcp(pred, batch.target, SHELF15, strict=True)  # (B, N, 10)
    return {
        "error_sum": jnp.sum(jnp.where(valid, error, 0.0)),
        "correct_sum": jnp.sum(jnp.where(valid[..., None], correct, False)),
        "frames": jnp.sum(valid),
    }


def _validate(graphdef: nnx.GraphDef, params: Any, rest: Any, data: WindowDataset, windows: int,
              batch_size: int, window: int, batch_sharding) -> dict[str, float]:
    """MPJPE (mm) and strict PCP (%) of the model over the valid frames of the first ``windows`` windows."""
    count = min(windows, data.num_windows)
    sums = {"error_sum": 0.0, "correct_sum": 0.0, "frames": 0.0}
    for first in range(0, count, batch_size):
        index = np.arange(first, first + batch_size)
        weight = (index < count).astype(np.float32)
        batch = _window_batch(data, np.minimum(index, count - 1), np.zeros(batch_size), window)
        out = _eval_step(graphdef, params, rest, jax.device_put(batch, batch_sharding),
                         jax.device_put(weight, batch_sharding))
        sums = {k: sums[k] + float(v) for k, v in out.items()}
    frames = max(sums["frames"], 1.0)
    return {"val_mpjpe_mm": 1000.0 * sums["error_sum"] / frames,
            "val_pcp": 100.0 * sums["correct_sum"] / (frames * len(SHELF15.pcp_parts)),
            "val_frames": int(sums["frames"])}


def validate(model: JCSAT, data: WindowDataset, *, windows: int = 512, batch_size: int = 16) -> dict[str, float]:
    """The training run's validation figures for ``model`` on the first ``windows`` windows of ``data`` (unrotated):
    ``val_mpjpe_mm`` and strict PCP ``val_pcp`` (%) over the valid frames, and ``val_frames``. Does not depend on
    ``batch_size`` beyond the order of a float sum; it must be a multiple of the local device count."""
    if windows < 1:
        raise ValueError(f"windows must be >= 1, got {windows}")
    graphdef, params, rest = nnx.split(model, nnx.Param, ...)
    _, batch_sharding = training.data_parallel_shardings(batch_size)
    return _validate(graphdef, params, rest, data, windows, batch_size, model.config.frames, batch_sharding)


def train(
    config: TrainConfig,
    workdir: str | Path,
    *,
    resume: bool,
    log: Callable[[dict], None] = lambda record: None,
    progress: bool = True,
    data_workers: int = 1,
) -> JCSAT:
    """Train per ``config`` in ``workdir`` and return the final model (see the module docstring for the files).

    ``resume=True`` continues from the latest checkpoint in ``workdir`` (refusing a different
    config); ``resume=False`` refuses a ``workdir`` that already has checkpoints. ``log`` receives
    every record written to ``log.jsonl``; ``progress`` shows a tqdm bar; ``data_workers`` processes build
    the scenes of a dataset that is not cached yet (the windows do not depend on it).
    """
    replicated, batch_sharding = training.data_parallel_shardings(config.batch_size)
    workdir = Path(workdir).resolve()
    cache_dir = workdir / "data_cache" if config.cache_dir is None else Path(config.cache_dir)
    train_data = jax.device_put(build_dataset(config.data, cache_dir, workers=data_workers), replicated)
    validation_data = jax.device_put(build_dataset(config.validation_data, cache_dir, workers=data_workers),
                                     replicated)
    if train_data.num_windows == 0 or validation_data.num_windows == 0:
        raise ValueError("no training or validation windows: more scenes or frames are needed")

    model_config = config.model_config
    model = JCSAT(model_config, rngs=nnx.Rngs(config.seed))
    if config.init_model is not None:
        start = load_model(config.init_model)
        if start.config != model_config:
            raise ValueError(f"init_model {config.init_model} is a {start.config} model, not the run's {model_config}")
        nnx.update(model, nnx.state(start, nnx.Param))
    graphdef, params, rest = nnx.split(model, nnx.Param, ...)
    optimiser, schedule = make_optimiser(config.weight_decay, config.grad_clip), learning_rate_schedule(config)

    def step(state: TrainState, i: int) -> tuple[TrainState, dict[str, jax.Array]]:
        sample_key, mask_key = jax.random.split(jax.random.fold_in(state.key, i))
        batch = _sample(train_data, sample_key, config.batch_size, config.data.window)
        return train_step(graphdef, config.losses, optimiser, replicated, state, jax.device_put(batch, batch_sharding),
                          mask_key, schedule(i))

    state = training.run_training(
        workdir, config, init_state(config, params, rest), step, steps=config.steps, resume=resume,
        log_interval=config.log_interval, checkpoint_interval=config.checkpoint_interval,
        validation_interval=config.validation_interval,
        validate=lambda state: _validate(graphdef, state.params, state.rest, validation_data,
                                        config.validation_windows, config.batch_size, config.data.window,
                                        batch_sharding),
        replicated=replicated, learning_rate=schedule, log=log, progress=progress,
        description="jcsat train")
    training.save_model(workdir / "model", model_config, nnx.merge_state(state.params, state.rest))
    return nnx.merge(graphdef, state.params, state.rest)

"""Training JAT and MPJAT (thesis Sect. 4.3.3, 4.4.4) on the cached crop features of a trained backbone.

Both stages are resumable runs of the project loop (:func:`training.run_training`) through the same stage runner
as PHD+T's (:mod:`dynamics._train`), with the prior trained alongside:

1. ``movie/``: ``f_movie`` and ``f_HMR`` on windows of ``T + H`` frames, Eq. 4.28 (Eq. 4.43 with the
   interpenetration term ``P_t`` for scenes of two people): ``L_t`` on every frame and the shape consistency.
2. ``ar/``: ``f_AR``, ``f_JE``, ``f_transl`` and the Joint-Aware Bias encoders with ``f_movie`` and ``f_HMR``
   frozen, Eq. 4.12 (4.44): observe 25 frames, roll out ``H`` without teacher forcing (the objective is PHD+T's,
   :func:`dynamics._train._ar_objective`, on scenes).

JAT trains on single tracks (``N = 1``); MPJAT's batches are two-person scenes or single-person tracks, drawn
with probability ``two_person_fraction`` per step (two shapes, two compilations, no padding). :func:`train_all`
runs the four models of the evaluation: JAT; JAT without the Joint-Aware Bias (Table 5.5), which starts where
JAT's ``ar/`` stage starts (JAT's trained conditioning networks, frozen in that stage, and JAT's initial ``f_AR``,
``f_JE`` and ``f_transl``) and trains its own for JAT's steps, so the bias is the only difference; MPJAT,
initialised from JAT with the agent-aware sub-modules duplicated from their single-person counterparts
(``docs/dynamics.md``); and MPJAT without the interpenetration loss (Table 5.9), MPJAT's run from the same start
with that loss's weight at 0.
"""

from __future__ import annotations

import dataclasses
from functools import partial
from collections.abc import Callable
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx

import geometry
import training

from ._backbone import ResNetBackbone
from ._data import (VALIDATION_DATA, DataConfig, Frames, build_frames, check_validation_apart, scene_windows,
                    window_starts, without_crops)
from ._jat import JAT, JATConfig
from ._losses import LossWeights, frame_losses, interpenetration, penetration_surfaces, shape_consistency
from ._phdt import crop_roots, params_to_joints
from ._train import StageConfig, _ar_objective, _run_stage, _targets, cached_features, check_crop_sizes

__all__ = ["TRANSFORMERS", "TransformerTrainConfig", "as_multi_person", "load_transformers", "train_all",
           "train_transformer"]

TRANSFORMERS: tuple[str, ...] = ("JAT", "JAT w/o bias", "MPJAT", "MPJAT w/o P")
"""The trained transformers of :func:`train_all`, as the tables name them."""

_CONDITIONING = nnx.All(nnx.Param, nnx.Any(*(nnx.PathContains(p) for p in ("movie_encoder", "movie", "hmr"))))
"""The ``movie/`` stage's trained parts: f_movie and f_HMR."""
_AR_PARTS = nnx.All(nnx.Param, nnx.Any(*(nnx.PathContains(p) for p in (
    "ar_encoder", "ar", "ar_output", "bias_self", "bias_other", "joint_encoder", "translation"))))
"""The ``ar/`` stage's trained parts: f_AR, the Joint-Aware Bias encoders, f_JE and f_transl."""


@dataclasses.dataclass(frozen=True)
class TransformerTrainConfig:
    """Everything that determines one transformer's training (written to ``config.json``)."""

    data: DataConfig = DataConfig()
    validation: DataConfig = VALIDATION_DATA
    model: JATConfig = JATConfig()
    losses: LossWeights = LossWeights()
    movie: StageConfig | None = StageConfig(steps=600, batch_size=16, learning_rate=3e-4)
    """None: keep the conditioning networks of the model it starts from."""
    ar: StageConfig = StageConfig(steps=300, batch_size=16, learning_rate=3e-4, warmup_steps=30)
    multi_person_movie: StageConfig = StageConfig(steps=150, batch_size=16, learning_rate=1e-4, warmup_steps=30)
    """:func:`train_all`: MPJAT's conditioning stage, fine-tuning JAT's on scenes (shorter and slower than
    ``movie``: it starts trained)."""
    observed: int = 25
    horizon: int = 30
    """H in training: the test's 30, so every position code the test uses was trained."""
    two_person_fraction: float = 0.5
    """MPJAT: the share of steps on two-person scenes (the rest on single-person tracks)."""
    seed: int = 0
    checkpoint_interval: int = 100
    validation_interval: int = 150
    log_interval: int = 25
    cache_dir: str | None = None
    """Where rendered frames and features are cached; None: ``<workdir>/data_cache``."""

    def __post_init__(self) -> None:
        if self.observed < 1 or self.horizon < 1:
            raise ValueError(f"observed and horizon must be >= 1, got {self.observed} and {self.horizon}")
        if not 0.0 <= self.two_person_fraction <= 1.0:
            raise ValueError(f"two_person_fraction must be in [0, 1], got {self.two_person_fraction}")
        check_validation_apart(self.data, self.validation)


def as_multi_person(model: JAT, config: JATConfig) -> JAT:
    """An MPJAT (``config.agent_aware``) holding ``model``'s weights, each agent-aware sub-module (the 'other'
    query and key projections, ``f_JABO``) a copy of its single-person counterpart."""
    if not config.agent_aware:
        raise ValueError("as_multi_person builds an agent-aware model: pass a config with agent_aware=True")
    multi = JAT(config, rngs=nnx.Rngs(0))
    source = dict(nnx.to_flat_state(nnx.state(model, nnx.Param)))
    counterpart = {"query_other": "query", "key_other": "key", "bias_other": "bias_self"}
    updated = {}
    for path, variable in nnx.to_flat_state(nnx.state(multi, nnx.Param)):
        origin = tuple(counterpart.get(part, part) for part in path)
        if origin not in source:
            raise ValueError(f"{'.'.join(map(str, origin))} has no weights in the single-person model")
        updated[path] = source[origin]
    nnx.update(multi, nnx.from_flat_state(updated))
    return multi


def _scene_movie_objective(config: TransformerTrainConfig, body, model: JAT, batch: tuple[jax.Array, Frames], key,
                           prior, surfaces=None):
    features, rows = batch
    present = jnp.ones(features.shape[:-2], bool)
    params = model.hmr(model.condition(features, rows.boxes, rows.K, present), key=key)
    roots = crop_roots(params, rows.boxes, rows.K)
    terms = frame_losses(body, params, roots, _targets(rows), prior, config.losses)
    terms["shape_consistency"] = shape_consistency(params.betas, config.losses)
    if features.shape[-3] > 1 and config.losses.interpenetration:
        terms["interpenetration"] = config.losses.interpenetration * jnp.mean(
            interpenetration(body, params, roots, surfaces))
    return sum(terms.values()), terms, params


def _future_errors(body, model: JAT, features, rows: Frames, present, observed: int) -> dict[str, jax.Array]:
    """Validation: mean future MPJPE and root error (mm) of the people present."""
    seen = model.observe(body, features[..., :observed, :], rows.boxes[..., :observed, :],
                         rows.K[..., :observed, :, :], present)
    rollout = model.rollout(body, seen, features.shape[-2] - observed, present)
    future = jax.tree.map(lambda x: x[:, :, observed:], rows)
    joints = params_to_joints(body, rollout.params, jnp.zeros_like(rollout.root))
    error = geometry.mpjpe_root_relative(joints, jnp.asarray(future.joints3d), 0).mean(axis=-1)
    root = jnp.linalg.norm(rollout.root - jnp.asarray(future.root), axis=-1).mean(axis=-1)
    weights = present / jnp.sum(present)
    return {"val_future_mpjpe_mm": 1000.0 * jnp.sum(weights * error),
            "val_future_root_mm": 1000.0 * jnp.sum(weights * root)}


def train_transformer(config: TransformerTrainConfig, workdir: str | Path, body: geometry.BodyModel,
                      backbone: ResNetBackbone, init: JAT | None = None, *, resume: bool,
                      log: Callable[[dict], None] = lambda record: None, progress: bool = True,
                      data_workers: int = 1) -> JAT:
    """Train one JAT or MPJAT (``config.model``) in ``workdir`` on ``backbone``'s features (module docstring),
    starting from ``init`` (its weights are copied; required when ``config.movie`` is None); ``data_workers`` CPU
    processes render the videos."""
    if config.movie is None and init is None:
        raise ValueError("config.movie is None (keep the conditioning networks): pass the model to start from")
    if init is not None and init.config != config.model:
        raise ValueError(f"init has config {init.config}, the run trains {config.model}")
    check_crop_sizes(backbone.crop_size, data=config.data, validation=config.validation)
    workdir = Path(workdir).resolve()
    cache_dir = workdir / "data_cache" if config.cache_dir is None else Path(config.cache_dir)
    frames = build_frames(config.data, body, cache_dir, progress, data_workers)
    validation = build_frames(config.validation, body, cache_dir, progress, data_workers)
    features = cached_features(backbone, frames, config.data, cache_dir, progress)
    validation_features = cached_features(backbone, validation, config.validation, cache_dir, progress)
    columns = (features, without_crops(frames))
    length = config.observed + config.horizon

    scenes, present = scene_windows(frames, length, people=2)
    two_person = scenes[present.all(axis=1)]
    shared_videos = np.unique(frames.video[two_person[:, 0, 0]]) if len(two_person) else np.zeros(0, int)
    tracks = window_starts(frames, length)
    if config.model.agent_aware:  # MPJAT's single-person batches come from single-person videos
        tracks = tracks[~np.isin(frames.video[tracks], shared_videos)]
        if len(two_person) == 0 and config.two_person_fraction > 0:
            raise ValueError("MPJAT needs two-person scenes: the training clips have none")
    tracks = tracks[:, None, None] + np.arange(length)  # (windows, 1 person, frames)

    def sampler(stage: StageConfig) -> Callable[[jax.Array], tuple[np.ndarray, Frames]]:
        def sample(key):
            choose, draw = jax.random.split(key)
            scenes_now = config.model.agent_aware and bool(jax.random.bernoulli(choose, config.two_person_fraction))
            pool = two_person if scenes_now else tracks
            index = pool[np.asarray(jax.random.randint(draw, (stage.batch_size,), 0, len(pool)))]
            return jax.tree.map(lambda column: column[index], columns)
        return sample

    val_scenes, val_present = scene_windows(validation, length, stride=10, people=2)
    val_features, val_rows = jax.tree.map(lambda column: column[val_scenes], (validation_features,
                                                                              without_crops(validation)))

    @nnx.jit
    def errors(model, features, rows, present):
        return _future_errors(body, model, features, rows, present, config.observed)

    def validate(model: JAT) -> dict[str, float]:
        values = errors(model, jnp.asarray(val_features), jax.tree.map(jnp.asarray, val_rows), jnp.asarray(val_present))
        return {name: float(value) for name, value in values.items()}

    model = JAT(config.model, rngs=nnx.Rngs(config.seed))
    if init is not None:
        nnx.update(model, nnx.state(init, nnx.Param))
    movie_objective, ar_objective = _scene_movie_objective, _ar_objective
    if config.model.agent_aware:  # scenes of two people: the interpenetration term's body constants, closed over
        surfaces = penetration_surfaces(body)
        movie_objective, ar_objective = (partial(objective, surfaces=surfaces)
                                         for objective in (_scene_movie_objective, _ar_objective))
    if config.movie is not None:
        model = _run_stage("movie", config, config.movie, workdir, model, _CONDITIONING, movie_objective,
                           sampler(config.movie), validate, body, resume=resume, log=log, progress=progress,
                           later=("ar",))
    model = _run_stage("ar", config, config.ar, workdir, model, _AR_PARTS, ar_objective, sampler(config.ar),
                       validate, body, resume=resume, log=log, progress=progress)
    training.save_model(workdir / "model", config.model, nnx.state(model))
    return model


def load_transformers(path: str | Path) -> dict[str, JAT]:
    """The models written by :func:`train_all` to ``<workdir>/models`` (or a shipped copy), by table name: those
    of :data:`TRANSFORMERS` whose folder exists (a run stopped early has fewer)."""
    folders = {name: Path(path) / _folder(name) for name in TRANSFORMERS}
    if not any(folder.is_dir() for folder in folders.values()):
        raise FileNotFoundError(f"{path} holds none of the transformers {[f.name for f in folders.values()]}")
    return {name: training.load_model_state(folder, lambda fields: JAT(JATConfig(**fields), rngs=nnx.Rngs(0)))
            for name, folder in folders.items() if folder.is_dir()}


def _folder(name: str) -> str:
    return name.lower().replace(" w/o ", "_without_").replace(" ", "_")


def _ar_stage_start(trained: JAT, config: JATConfig, seed: int) -> JAT:
    """A ``config`` model (JAT less what an ablation removes) as the JAT ``trained`` was when its ``ar/`` stage
    started: its conditioning networks (frozen in that stage) and the initial parameters :func:`train_transformer`
    gave its other parts from ``seed``."""
    start = JAT(trained.config, rngs=nnx.Rngs(seed))
    nnx.update(start, nnx.state(trained, _CONDITIONING))
    model = JAT(config, rngs=nnx.Rngs(seed))
    kept = {path for path, _ in nnx.to_flat_state(nnx.state(model, nnx.Param))}
    nnx.update(model, nnx.from_flat_state({path: variable for path, variable
                                           in nnx.to_flat_state(nnx.state(start, nnx.Param)) if path in kept}))
    return model


def train_all(config: TransformerTrainConfig, workdir: str | Path, body: geometry.BodyModel,
              backbone: ResNetBackbone, hmr_init: nnx.Module | None = None, *, resume: bool,
              log: Callable[[dict], None] = lambda record: None, progress: bool = True,
              data_workers: int = 1) -> dict[str, JAT]:
    """The four transformers of the module docstring, each in ``workdir/<name>/``, their models copied to
    ``workdir/models/``. ``config`` is JAT's (its ``multi_person_movie`` is the MPJATs' conditioning stage);
    ``hmr_init`` (e.g. PHD+T's f_HMR, of the same size) starts JAT's f_HMR."""
    workdir = Path(workdir)
    single = JATConfig(**{**dataclasses.asdict(config.model), "agent_aware": False, "joint_aware_bias": True})
    multi = dataclasses.replace(single, agent_aware=True)
    runs = {
        "JAT": (dataclasses.replace(config, model=single), None),
        "JAT w/o bias": (dataclasses.replace(config, model=dataclasses.replace(single, joint_aware_bias=False),
                                             movie=None), "JAT"),
        "MPJAT": (dataclasses.replace(config, model=multi, movie=config.multi_person_movie), "JAT"),
        "MPJAT w/o P": (dataclasses.replace(config, model=multi, movie=config.multi_person_movie,
                                            losses=dataclasses.replace(config.losses, interpenetration=0.0)), "JAT"),
    }
    models: dict[str, JAT] = {}
    for name, (run_config, parent) in runs.items():
        init = None
        if parent is not None:
            start = models[parent]
            if run_config.model.agent_aware:
                init = as_multi_person(start, run_config.model)
            else:  # an ablation of JAT: JAT's start, not the trained JAT, whose f_AR would train twice as long
                init = _ar_stage_start(start, run_config.model, config.seed)
        elif hmr_init is not None:
            init = JAT(run_config.model, rngs=nnx.Rngs(run_config.seed))
            nnx.update(init.hmr, nnx.state(hmr_init))
        if run_config.cache_dir is None:
            run_config = dataclasses.replace(run_config, cache_dir=str((workdir / "data_cache").resolve()))
        models[name] = train_transformer(run_config, workdir / _folder(name), body, backbone, init, resume=resume,
                                         log=lambda record, name=name: log({"model": name, **record}),
                                         progress=progress, data_workers=data_workers)
        training.save_model(workdir / "models" / _folder(name), run_config.model, nnx.state(models[name]))
    return models

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

Scenes of two people (:attr:`ForecastTrainConfig.people`): the windows hold both people of a recording captured
together over the same frames (:func:`scene_rows`), in the frame of either (drawn per window), and the objective
adds Eq. 4.42's interpenetration term ``P_t`` on the predicted frames. :data:`PAIR_FORECASTERS` (JAT, MPJAT and
MPJAT without that term, Table 5.9's ablation) are fine-tuned so from one trained single-person JAT
(:attr:`ForecastTrainConfig.start_from`; MPJAT's agent-aware parts start as copies of their single-person
counterparts, :func:`~dynamics.as_multi_person`, as the video MPJAT does), on the first salsa pair; with no other
pair to validate on, the last part of every training recording validates
(:attr:`ForecastTrainConfig.validation_tail`).
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

from ._data import scene_windows, window_starts
from ._forecast import ForecasterConfig, PoseForecaster, forecast_joints
from ._hmr import decoding_start
from ._jat import JATConfig
from ._losses import FrameTargets, LossWeights, frame_losses, interpenetration, penetration_surfaces
from ._phdt import PHDTConfig
from ._poses import FORECAST_FPS, PoseFrames, canonical_window, mirror_frames, pose_frames
from ._train import StageConfig, _run_stage
from ._train_jat import as_multi_person

__all__ = ["FORECASTERS", "PAIR_FORECASTERS", "ForecastTrainConfig", "canonical_scenes", "forecast_split",
           "initial_forecaster", "load_forecaster", "load_forecasters", "pair_split", "scene_rows", "train_forecaster",
           "train_forecasters", "train_pair_forecasters"]

# Each predicted frame decoded from the previous one moved on by half its last step: chosen on the validation files
# (docs/dynamics.md) over the previous pose as it is and over the whole step; PHD+T's by three quarters of it, chosen
# there later over twice the widths (three seeds each).
_DECODING = dict(decode_from="extrapolated", extrapolation=0.5)
_SMALL_JAT = JATConfig(feature_dim=128, temporal_dim=128, joint_dim=64, hmr_hidden=256, hmr_dropout=0.0,
                       bias_hidden=64, **_DECODING)
FORECASTERS: dict[str, ForecasterConfig] = {
    # No delta predictors: they supervise f_movie from the past frames of a video; here the past is observed.
    "PHD+T": ForecasterConfig(phdt=PHDTConfig(feature_dim=128, joint_dim=64, hmr_hidden=256, hmr_dropout=0.0,
                                              channels_per_group=64, delta_offsets=(),
                                              **{**_DECODING, "extrapolation": 0.75})),
    "JAT": ForecasterConfig(jat=_SMALL_JAT),
    "JAT w/o bias": ForecasterConfig(jat=dataclasses.replace(_SMALL_JAT, joint_aware_bias=False)),
}
"""The trained 3D forecasters, as the tables name them (CPU-sized: a few hundred thousand parameters each)."""
_MPJAT = ForecasterConfig(jat=dataclasses.replace(_SMALL_JAT, agent_aware=True))
PAIR_FORECASTERS: dict[str, tuple[ForecasterConfig, float]] = {
    "JAT": (FORECASTERS["JAT"], 1.0),
    "MPJAT": (_MPJAT, 1.0),
    "MPJAT w/o interpenetration": (_MPJAT, 0.0),
}
"""The two-person forecasters as the tables name them: each model and the weight of its interpenetration term."""
PAIR_TRAINING = ("60_03_scaled.bvh", "61_03_scaled.bvh")
PAIR_TEST = ("60_05_scaled.bvh", "61_05_scaled.bvh")
"""The CMU salsa pairs (``<data-root>/cmu_mocap``): the first trains (and validates), the second is the test pair,
as for the video models (:data:`~dynamics.TEST_MULTI_PERSON_CLIPS`)."""


@dataclasses.dataclass(frozen=True)
class ForecastTrainConfig:
    """Everything that determines one forecaster's training (written to ``config.json``)."""

    files: tuple[str, ...]
    """Training motion files (CMU-Mocap exp-map ``.txt``; the benchmark's test split is refused), or the files of
    people captured together joined by ``+``."""
    validation_files: tuple[str, ...] = ()
    """Validation motion files; none when :attr:`validation_tail` validates."""
    model: ForecasterConfig = FORECASTERS["JAT"]
    losses: LossWeights = LossWeights(joints_3d_error="distance")
    """The 3D-joint term on every joint's distance (MPJPE) instead of HMMR's squared error: chosen on the validation
    files with PHD+T (two seeds), and for the pair forecasters on the training pair's tail (docs/dynamics.md)."""
    stage: StageConfig = StageConfig(steps=2000, batch_size=32, learning_rate=5e-4, warmup_steps=50, clip_norm=500.0,
                                     average_decay=0.995)
    """2000 steps of 32 windows, the gradients clipped to a global norm of 500 (the median norm logged by unclipped
    trainings), the model a moving average of the parameters with a half-life of 138 steps; each chosen on the
    validation files with PHD+T: clipping over none and then 2000 steps over 1000 (three seeds each), the average over
    the parameters (two seeds; docs/dynamics.md)."""
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
    people: int = 1
    """People per training scene: 1, every person's motion on its own; 2, the two people of a recording captured
    together (the files are pairs joined by ``+``), each window in the frame of either."""
    validation_tail: float = 0.0
    """The last fraction of every training recording validates instead of training (no training window reaches
    into it); 0: :attr:`validation_files` validate."""
    start_from: str | None = None
    """A trained single-person JAT forecaster's folder: the model starts from its weights (module docstring) instead
    of :func:`initial_forecaster`'s."""
    seed: int = 0
    checkpoint_interval: int = 250
    validation_interval: int = 250
    log_interval: int = 50
    cache_dir: str | None = None
    """Where the retargeted motion is cached; None: ``<workdir>/data_cache``."""

    def __post_init__(self) -> None:
        if not self.files:
            raise ValueError("need training files")
        if bool(self.validation_files) == (self.validation_tail > 0):
            raise ValueError("validate on validation files or on a validation tail of the training files: give "
                             "exactly one")
        if not 0.0 <= self.validation_tail < 1.0:
            raise ValueError(f"validation_tail is a fraction in [0, 1), got {self.validation_tail}")
        if self.people not in (1, 2):
            raise ValueError(f"people must be 1 or 2, got {self.people}")
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
    validates (:func:`mocap.cmu_expmap_validation_files`), the rest train. Absolute paths."""
    validation = mocap.cmu_expmap_validation_files(data_root)
    training = [f for f in mocap.cmu_expmap_files(data_root, "train") if f not in validation]
    return tuple(str(f.resolve()) for f in training), tuple(str(f.resolve()) for f in validation)


def pair_split(data_root: str | os.PathLike | None = None) -> tuple[str, str]:
    """The training and the test salsa pair (:data:`PAIR_TRAINING`, :data:`PAIR_TEST`) as sources of
    :func:`~dynamics.pose_frames`: each pair's two files joined by ``+``."""
    root = mocap.find_data_root(data_root, "cmu_mocap")
    if root is None:
        raise ValueError("no data folder holds cmu_mocap/ (the CMU salsa pairs): pass --data-root")
    return tuple("+".join(str(root / "cmu_mocap" / name) for name in pair) for pair in (PAIR_TRAINING, PAIR_TEST))


def scene_rows(frames: PoseFrames, length: int, people: int = 1, stride: int = 1) -> np.ndarray:
    """The rows ``(W, people, length)`` of every window of ``length`` frames, every ``stride`` frames: each
    person's own (``people=1``) or every recording's ``people`` people over the same frames (recordings of fewer
    people give none)."""
    if people == 1:
        return window_starts(frames, length, stride)[:, None, None] + np.arange(length)
    scenes, present = scene_windows(frames, length, stride, people)
    return scenes[present.all(axis=1)]


@partial(jax.jit, static_argnums=2)
def _canonical(rotations, joints, last_observed: int):
    return jax.vmap(canonical_window, in_axes=(0, 0, None))(rotations, joints, last_observed)


def canonical_scenes(frames: PoseFrames, rows: np.ndarray, observed: int) -> PoseFrames:
    """The windows of ``rows`` (:func:`scene_rows`) in the virtual camera frame of their first person's last observed
    frame (:func:`~dynamics.canonical_window`): every array ``(W, people, length, ...)``."""
    windows = jax.tree.map(lambda column: column[rows], frames)
    rotations, joints = _canonical(jnp.asarray(windows.rotations), jnp.asarray(windows.joints3d), observed - 1)
    return windows._replace(rotations=np.asarray(rotations), joints3d=np.asarray(joints))


def _split_tail(frames: PoseFrames, fraction: float) -> tuple[PoseFrames, PoseFrames]:
    """The rows of every recording before its last ``fraction`` of frames, and those in it."""
    length = np.zeros(frames.video.max() + 1, np.int64)
    np.maximum.at(length, frames.video, frames.frame + 1)
    early = frames.frame < np.floor((1.0 - fraction) * length[frames.video])
    return PoseFrames(*(column[early] for column in frames)), PoseFrames(*(column[~early] for column in frames))


def _joined(parts: list[PoseFrames]) -> PoseFrames:
    """The rows of ``parts`` one after the other, each part's tracks and recordings numbered after the previous
    parts'."""
    offsets = lambda column: np.cumsum(  # noqa: E731
        [0] + [int(getattr(part, column).max()) + 1 for part in parts[:-1]])
    parts = [part._replace(track=part.track + track, video=part.video + video)
             for part, track, video in zip(parts, offsets("track"), offsets("video"))]
    return PoseFrames(*(np.concatenate(column) for column in zip(*parts)))


def _targets(rows: PoseFrames) -> FrameTargets:
    return FrameTargets(rows.rotations, rows.betas, rows.joints3d, None, None, None)


def _forecast_objective(config: ForecastTrainConfig, body, model: PoseForecaster, rows: PoseFrames, key, prior,
                        surfaces=None):
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
    if config.people > 1 and config.losses.interpenetration:
        terms["interpenetration"] = config.losses.interpenetration * jnp.mean(
            interpenetration(body, rollout.params, rollout.root, surfaces))
    return sum(terms.values()), terms, rollout.params


def _future_errors(body, model: PoseForecaster, rows: PoseFrames, observed: int) -> dict[str, jax.Array]:
    past = jax.tree.map(lambda x: x[:, :, :observed], rows)
    truth = rows.joints3d[:, :, observed:]
    predicted = forecast_joints(model, body, past.rotations, past.betas, past.joints3d, truth.shape[2])
    error = geometry.mpjpe_root_relative(predicted, truth, 0)  # (W, N, H)
    root = jnp.linalg.norm(predicted[..., 0, :] - truth[..., 0, :], axis=-1)
    return {"val_future_mpjpe_mm": 1000.0 * jnp.mean(error), "val_future_root_mm": 1000.0 * jnp.mean(root)}


def initial_forecaster(config: ForecasterConfig, seed: int, start_from: str | Path | None = None) -> PoseForecaster:
    """The parameters a forecaster starts from: those of JAT (with the bias) from ``seed`` for every part the
    config shares with it, so that an ablation differs from JAT only in what it removes; the rest from ``seed``.
    ``start_from``: a trained JAT forecaster's folder whose weights start the model instead (a JAT of the same
    sizes; an agent-aware model's agent-aware parts copied from their single-person counterparts)."""
    if start_from is not None:
        source = load_forecaster(Path(start_from))
        if config.jat is None or source.config.jat is None or dataclasses.replace(
                source.config.jat, agent_aware=config.jat.agent_aware) != config.jat:
            raise ValueError(f"{start_from} holds {source.config}, not a JAT that {config} can start from")
        model = PoseForecaster(config, rngs=nnx.Rngs(seed))
        model.pose_encoder = source.pose_encoder
        model.model = as_multi_person(source.model, config.jat) if config.jat.agent_aware else source.model
        return model
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
    parts = [pose_frames(config.files, body, config.fps / speed, cache_dir, progress) for speed in config.speeds]
    if config.validation_tail:
        validation = _split_tail(pose_frames(config.files, body, config.fps, cache_dir, progress),
                                 config.validation_tail)[1]
        parts = [_split_tail(part, config.validation_tail)[0] for part in parts]
    else:
        validation = pose_frames(config.validation_files, body, config.fps, cache_dir, progress)
    frames = _joined(parts)
    if config.mirror:
        frames = _joined([frames, mirror_frames(frames, body)])
    rows = scene_rows(frames, length, config.people)
    validation_rows = scene_rows(validation, length, config.people, stride=10)
    if len(rows) == 0 or len(validation_rows) == 0:
        raise ValueError(f"the {'validation' if len(rows) else 'training'} motion has no window of {length} frames"
                         + (f" with {config.people} people" if config.people > 1 else ""))
    validation_windows = canonical_scenes(validation, validation_rows, config.observed)

    def sample(key: jax.Array) -> PoseFrames:
        chosen = rows[np.asarray(jax.random.randint(key, (config.stage.batch_size,), 0, len(rows)))]
        if config.people > 1:  # each window in the frame of a person drawn from its people
            first = np.asarray(jax.random.randint(jax.random.fold_in(key, 1), (len(chosen),), 0, config.people))
            chosen = np.stack([np.roll(scene, -shift, axis=0) for scene, shift in zip(chosen, first)])
        return canonical_scenes(frames, chosen, config.observed)

    @nnx.jit
    def errors(model, rows):
        return _future_errors(body, model, rows, config.observed)

    def validate(model: PoseForecaster) -> dict[str, float]:
        return {name: float(value) for name, value in errors(model, validation_windows).items()}

    model = initial_forecaster(config.model, config.seed, config.start_from)
    objective = _forecast_objective
    if config.people > 1:  # the interpenetration term's body constants, closed over (the step traces the body)
        objective = partial(_forecast_objective, surfaces=penetration_surfaces(body))
    model = _run_stage("forecast", config, config.stage, workdir, model, nnx.Param, objective, sample, validate,
                       body, resume=resume, log=log, progress=progress)
    training.save_model(workdir / "model", config.model, nnx.state(model))
    return model


def train_forecasters(config: ForecastTrainConfig, workdir: str | Path, body: geometry.BodyModel, *, resume: bool,
                      names: Iterable[str] = tuple(FORECASTERS), model_changes: Mapping[str, object] | None = None,
                      width: int = 1, log: Callable[[dict], None] = lambda record: None, progress: bool = True
                      ) -> dict[str, PoseForecaster]:
    """Each of :data:`FORECASTERS` named in ``names`` trained as ``config`` says (its ``model`` replaced, its
    networks ``width`` times wider (:meth:`ForecasterConfig.widened`), with ``model_changes`` to its model's config,
    e.g. ``decode_from``), in ``workdir/<name>/``, the data cached once for
    all; the models are copied to ``workdir/models/<name>``."""
    changes = model_changes or {}
    runs = {name: dataclasses.replace(config, model=FORECASTERS[name].widened(width).replace_model(**changes))
            for name in names}
    return _train_table(config, workdir, body, runs, resume, log, progress)


def train_pair_forecasters(config: ForecastTrainConfig, workdir: str | Path, body: geometry.BodyModel, *,
                           resume: bool, names: Iterable[str] = tuple(PAIR_FORECASTERS),
                           log: Callable[[dict], None] = lambda record: None, progress: bool = True
                           ) -> dict[str, PoseForecaster]:
    """Each of :data:`PAIR_FORECASTERS` named in ``names`` trained as ``config`` says (two people per scene; its
    ``model`` and interpenetration weight replaced), as :func:`train_forecasters` does."""
    if config.people != 2 or config.start_from is None:
        raise ValueError("the pair forecasters train on scenes of two people from a trained JAT: set people=2 and "
                         "start_from")
    runs = {}
    for name in names:
        model, weight = PAIR_FORECASTERS[name]
        runs[name] = dataclasses.replace(config, model=model, losses=dataclasses.replace(
            config.losses, interpenetration=weight))
    return _train_table(config, workdir, body, runs, resume, log, progress)


def _train_table(config: ForecastTrainConfig, workdir: str | Path, body: geometry.BodyModel,
                 runs: Mapping[str, ForecastTrainConfig], resume: bool, log: Callable[[dict], None],
                 progress: bool) -> dict[str, PoseForecaster]:
    workdir = Path(workdir)
    cache_dir = config.cache_dir or str((workdir / "data_cache").resolve())
    models = {}
    for name, run in runs.items():
        models[name] = train_forecaster(dataclasses.replace(run, cache_dir=cache_dir), workdir / _folder(name), body,
                                        resume=resume, log=lambda record, name=name: log({"model": name, **record}),
                                        progress=progress)
        training.save_model(workdir / "models" / _folder(name), run.model, nnx.state(models[name]))
    return models


def _folder(name: str) -> str:
    return name.lower().replace(" w/o ", "_without_").replace("+", "").replace(" ", "_")


def load_forecaster(folder: str | Path) -> PoseForecaster:
    """One forecaster's folder (``config.json`` and ``state.npz``) as a model."""
    build = lambda fields: PoseForecaster(ForecasterConfig.from_fields(fields), rngs=nnx.Rngs(0))  # noqa: E731
    return training.load_model_state(folder, build)


def load_forecasters(path: str | Path, names: Iterable[str] = tuple(FORECASTERS)) -> dict[str, PoseForecaster]:
    """The models :func:`train_forecasters` (or :func:`train_pair_forecasters`, with ``names`` of
    :data:`PAIR_FORECASTERS`) wrote to ``<workdir>/models`` (or a shipped copy), by table name: those of ``names``
    whose folder exists."""
    folders = {name: Path(path) / _folder(name) for name in names}
    if not any(folder.is_dir() for folder in folders.values()):
        raise FileNotFoundError(f"{path} holds none of the forecasters {[f.name for f in folders.values()]}")
    return {name: load_forecaster(folder) for name, folder in folders.items() if folder.is_dir()}

"""FLEX's synthetic experiment: held-out CMU clips, FLEX against camera-dependent triangulation (paper Tables 1,
3 and 5) in the static and the dynamic camera setting.

Test data: ``sequences`` samples per camera motion (:func:`~flex.make_batch`, seeds from ``seed``) of the
held-out :data:`~flex.TEST_CLIPS`, 4 views, ``frames`` frames, the default 2D detector model; for the
"ground-truth 2D" rows the same samples (same motion windows and cameras) with :data:`mocap.PERFECT_DETECTOR`.
Every method is scored by :func:`~flex.motion_metrics` (MPJPE protocol #1 over the 17 joints, acceleration error,
MBLS) against the same camera-frame ground truth, and by the global root position error
(:func:`~flex.root_position_error`; FLEX's root estimate, which is up to scale, made metric with the intrinsics by
:func:`~flex.camera_root`).

Methods:

- FLEX (4 views, early fusion): the 2D input only, no calibration.
- DLT and Structural Triangulation (:func:`~flex.triangulation_baseline`) with the exact extrinsics, extrinsics
  perturbed by each relative scale in ``perturbations`` (Table 1's protocol, one draw per sequence and view), and,
  for moving cameras, the stale calibration of the first frame.
- Ablations (Table 5): FLEX models trained with 1, 2 and 3 views, each given the first views of the same samples;
  ground-truth versus detected 2D; fusion: averaged monocular (:func:`~flex.averaged_monocular`: the 1-view model on every
  view, its shared rotations and bones averaged over the views), late fusion and FLEX's early fusion.

Fixed rigs (the paper's protocol; ``rigs``): samples of the same clips seen by one fixed rig
(:func:`~flex.fixed_rig`: a Human3.6M-like ring, the real Shelf cameras), with white and with temporally correlated
2D noise (``noise_correlation``); FLEX trained on that rig (:data:`~flex.RIG_MODELS`; where present, the
duplicate-joint ablation's pair of :data:`~flex.SKELETON_MODELS`) and the random-rig model against DLT and Structural
Triangulation with the exact calibration and with ``perturbation_draws`` perturbed calibrations per scale, each one
draw for the whole rig (a rig calibrated once; every test sequence sees the same error), reported as the mean and
standard deviation over the draws.

The models (:data:`~flex.MODELS`, :data:`~flex.RIG_MODELS`) are read from ``model_dir`` (default:
:data:`~flex.SHIPPED_MODELS`) or trained by :func:`train_models`, which is how the shipped ones were made.
"""

from __future__ import annotations

import dataclasses
import json
import platform
import time
from collections.abc import Callable
from pathlib import Path

import jax
import numpy as np
from jaxtyping import ArrayLike
from matplotlib.figure import Figure

import mocap
import training
from flex import (CONFIGS, DETECTION_MODELS, FIXED_RIGS, MAIN_MODEL, MODELS, RIG_MODELS, SKELETON_MODELS, TEST_CLIPS,
                  VALIDATION_CLIPS, Batch, DataConfig, Flex, TrainConfig, averaged_monocular, camera_root, load_flex,
                  make_batch, motion_metrics, normalise_2d, predict, root_position_error, train, triangulation_baseline)
from experiments._stats import mean_and_sd
from geometry import FLEX20, STRUCTRI17, remap_joints

__all__ = ["ExperimentConfig", "RIG_NOISE_CORRELATION", "mean_and_spread", "plot_camera_poses", "run_experiment",
           "train_config", "train_models"]

_TEST_VIEWS = 4
"""Cameras of every test sample."""

RIG_NOISE_CORRELATION = 0.9
"""Lag-1 correlation of the 2D noise (:attr:`mocap.DetectorConfig.noise_correlation`) with which the rig models are
trained and the fixed rigs tested (beside white noise): fixed before any run, not tuned (at 30 fps an error keeps
about a third of itself after a third of a second)."""


@dataclasses.dataclass(frozen=True)
class ExperimentConfig:
    """Everything the experiment's numbers depend on besides the models (written to ``results.json``)."""

    seed: int = 0
    """Seed of the test samples and of their perturbed calibrations."""
    sequences: int = 16
    """Test samples per camera motion (static and dynamic), drawn from :data:`~flex.TEST_CLIPS`."""
    frames: int = 64
    """Frames per test sample."""
    clips: tuple[str, ...] = TEST_CLIPS
    """Clips the test samples are drawn from (held out of training): shipped clip names or paths of motion files
    of one person (:func:`mocap.load_clip_file`: CMU exp-map ``.txt``, ``.amc`` beside its ``.asf``, ``.bvh`` in
    CMU's units)."""
    perturbations: tuple[float, ...] = (0.03, 0.04)
    """Relative standard deviations of the perturbed extrinsics (Table 1: 3 % and 4 %)."""
    n_steps: int = 3
    """SCA steps of Structural Triangulation."""
    rigs: tuple[str, ...] = FIXED_RIGS
    """Fixed rigs evaluated with the paper's protocol (:data:`flex.FIXED_RIGS`); empty: none."""
    perturbation_draws: int = 5
    """Perturbed calibrations per rig and scale (each one draw for the whole rig); mean and spread are reported."""
    noise_correlation: float = RIG_NOISE_CORRELATION
    """Lag-1 correlation of the correlated 2D noise on the fixed rigs (they are also tested with white noise)."""
    plot_views: tuple[int, ...] = (0, 1)
    """Views (one row each) whose camera-frame poses ``skeletons.png`` draws."""
    plot_frames: int = 4
    """Frames (evenly spaced) of the first dynamic sample drawn in ``skeletons.png``."""

    def __post_init__(self) -> None:
        if self.sequences < 1:
            raise ValueError(f"sequences must be >= 1, got {self.sequences}")
        if self.frames < 3:
            raise ValueError(f"frames must be >= 3 (the acceleration error needs three), got {self.frames}")
        if not self.clips:
            raise ValueError("clips must name at least one clip")
        if any(not scale > 0 for scale in self.perturbations):
            raise ValueError(f"perturbations must be relative scales > 0, got {self.perturbations}")
        if self.n_steps < 0:
            raise ValueError(f"n_steps must be >= 0, got {self.n_steps}")
        unknown = sorted(set(self.rigs) - set(FIXED_RIGS))
        if unknown or len(set(self.rigs)) < len(self.rigs):
            raise ValueError(f"rigs must be distinct names of {FIXED_RIGS}, got {self.rigs}")
        if self.perturbation_draws < 2:
            raise ValueError(f"perturbation_draws must be >= 2 (a spread needs two), got {self.perturbation_draws}")
        if not 0.0 < self.noise_correlation < 1.0:
            raise ValueError(f"noise_correlation must be in (0, 1), got {self.noise_correlation}")
        if not self.plot_views or len(set(self.plot_views)) < len(self.plot_views) or not set(
                self.plot_views) <= set(range(_TEST_VIEWS)):
            raise ValueError(f"plot_views must be distinct views of 0..{_TEST_VIEWS - 1}, got {self.plot_views}")
        if not 1 <= self.plot_frames <= self.frames:
            raise ValueError(f"plot_frames must be in 1..frames={self.frames}, got {self.plot_frames}")


def train_config(name: str, steps: int, seed: int, cache_dir: Path, extra_clips: tuple[str, ...] = (), *,
                 batch_size: int = 16, pool_size: int | None = None, model_config: str = "small",
                 validation_clips: tuple[str, ...] = ()) -> TrainConfig:
    """The run that trains model ``name`` of :data:`~flex.MODELS`, :data:`~flex.RIG_MODELS`,
    :data:`~flex.DETECTION_MODELS` or :data:`~flex.SKELETON_MODELS`: the ``model_config`` of :data:`~flex.CONFIGS`
    (``"small"``: the shipped models; ``"paper"``: Table 6's) on the training clips plus ``extra_clips`` (motion
    files), validated on :data:`~flex.VALIDATION_CLIPS` plus ``validation_clips`` (motion files), ``batch_size``
    windows per step from a pool of ``pool_size`` (None: 4096 for a rig model, else :class:`~flex.TrainConfig`'s); a
    rig, detection or skeleton model sees only its rig, static, with the correlated 2D noise of
    :data:`RIG_NOISE_CORRELATION` (a skeleton model's samples are its rig model's)."""
    if model_config not in CONFIGS:
        raise ValueError(f"model_config must be one of {sorted(CONFIGS)}, got {model_config!r}")
    base = TrainConfig()
    clips = base.data.clip_names + tuple(extra_clips)
    validation = VALIDATION_CLIPS + tuple(validation_clips)
    # A short run (--quick, a smoke run) warms up over a tenth of its steps; from 1000 steps on, the default.
    warmup_steps = min(base.warmup_steps, steps // 10)
    if name in RIG_MODELS or name in DETECTION_MODELS or name in SKELETON_MODELS:
        detector = mocap.DetectorConfig(noise_correlation=RIG_NOISE_CORRELATION)
        model = dataclasses.replace(CONFIGS[model_config], views=_TEST_VIEWS)
        if name in RIG_MODELS:
            extra = {"rig": RIG_MODELS[name]}
        elif name in DETECTION_MODELS:
            extra = {"rig": DETECTION_MODELS[name], "input_joints": "detected"}
        else:
            rig, duplicate_joints = SKELETON_MODELS[name]
            extra = {"rig": rig}
            model = dataclasses.replace(model, rest_pose="tpose", duplicate_joints=duplicate_joints)
        data = DataConfig(views=_TEST_VIEWS, frames=base.data.frames, clips=clips, detector=detector, **extra)
        return TrainConfig(
            model=model, steps=steps, seed=seed, warmup_steps=warmup_steps,
            cache_dir=str(cache_dir), data=data, pool_size=pool_size or 4096, static_fraction=1.0,
            batch_size=batch_size, validation_data=dataclasses.replace(data, clips=validation))
    views, fusion = MODELS[name]
    return TrainConfig(
        model=dataclasses.replace(CONFIGS[model_config], views=views, fusion=fusion), steps=steps, seed=seed,
        warmup_steps=warmup_steps, cache_dir=str(cache_dir), batch_size=batch_size,
        pool_size=pool_size or base.pool_size, data=dataclasses.replace(base.data, views=views, clips=clips),
        validation_data=dataclasses.replace(base.validation_data, views=views, clips=validation))


def train_models(workdir: str | Path, steps: int, *, seed: int = 0, names: tuple[str, ...] = tuple(MODELS),
                 extra_clips: tuple[str, ...] = (), validation_clips: tuple[str, ...] = (), batch_size: int = 16,
                 pool_size: int | None = None, model_config: str = "small", data_workers: int = 1,
                 log: Callable[[dict], None] = lambda record: None, progress: bool = True) -> dict[str, Flex]:
    """Train the models ``names`` (of :data:`~flex.MODELS`, :data:`~flex.RIG_MODELS`, :data:`~flex.DETECTION_MODELS`
    and :data:`~flex.SKELETON_MODELS`) in ``workdir/<name>`` for
    ``steps`` steps each (:func:`train_config`), resuming a run that has checkpoints (refusing one of another
    config); a finished model folder ``workdir/<name>/model`` is what ``flex/assets/<name>`` ships, and is reused
    only if it was trained by the same config. The sample pools are cached once for all models in
    ``workdir/data_cache``, built by ``data_workers`` processes."""
    models = {}
    for name in names:
        run = Path(workdir) / name
        config = train_config(name, steps, seed, Path(workdir) / "data_cache", extra_clips, batch_size=batch_size,
                              pool_size=pool_size, model_config=model_config, validation_clips=validation_clips)
        done = (run / "model" / "state.npz").is_file()
        if done:
            # Only the same run may stand in for this one: a finished model of another size or step count is
            # refused here, as training.run_training refuses to resume another run's checkpoints.
            training.check_same_run(run, config)
        models[name] = load_flex(run / "model") if done else train(
            config, run, resume=(run / "checkpoints").is_dir(), progress=progress, data_workers=data_workers,
            log=lambda record, name=name: log({"model": name, **record}))
    return models


def _metrics(pred, gt, skeleton) -> dict[str, float]:
    m = motion_metrics(pred, gt, skeleton)
    return {"mpjpe_mm": float(m.mpjpe), "acceleration_error_mm": float(m.acceleration_error),
            "mbls_mm": float(m.mbls)}


def _true_root(batch: Batch):
    """The camera-frame root of every view and frame (metres), from the samples' normalised root and intrinsics."""
    normalised = normalise_2d(batch.points_2d, batch.confidences, STRUCTRI17.index("mid_hip"))
    return camera_root(batch.root_position, normalised.centre, normalised.scale, batch.cameras.K)


def _flex_metrics(model: Flex, batch: Batch) -> tuple[dict[str, float], jax.Array]:
    """A FLEX model's metrics on a batch (with the global root error, its root made metric by the intrinsics)
    and its FLEX20 prediction."""
    outputs = predict(model, batch.points_2d, batch.confidences)
    root = camera_root(outputs.root_position, outputs.centre, outputs.scale, batch.cameras.K)
    return (_metrics(outputs.joints_relative, batch.joints, FLEX20)
            | {"root_error_mm": float(root_position_error(root, _true_root(batch)))}), outputs.joints_relative


def _baseline_metrics(batch: Batch, method: str, calibration: str, key, scale: float, n_steps: int,
                      per_sequence: bool = True) -> tuple[dict[str, float], jax.Array]:
    """A triangulation baseline's metrics on a batch (with the global root error) and its prediction."""
    pred, root = triangulation_baseline(batch, method, calibration, key, scale=scale, n_steps=n_steps,
                                        per_sequence=per_sequence, with_root=True)
    return (_metrics(pred, batch.joints, STRUCTRI17)
            | {"root_error_mm": float(root_position_error(root, _true_root(batch)))}), pred


def _test_batches(config: ExperimentConfig) -> dict[tuple[str, str], Batch]:
    """(camera motion, "detected" or "gt") -> the test batch (same motion and cameras for both 2D sources)."""
    batches = {}
    for index, motion in enumerate(("static", "dynamic")):
        key = jax.random.fold_in(jax.random.key(config.seed), index)
        data = DataConfig(views=_TEST_VIEWS, frames=config.frames, clips=config.clips, camera_motion=motion)
        batches[motion, "detected"] = make_batch(key, data, config.sequences)
        batches[motion, "gt"] = make_batch(key, dataclasses.replace(data, detector=mocap.PERFECT_DETECTOR),
                                           config.sequences)
    return batches


def _first_views(batch: Batch, views: int) -> Batch:
    def cut(x):
        return x[:, :views] if x.ndim >= 2 and x.shape[1] == 4 else x
    return batch._replace(points_2d=batch.points_2d[:, :views], confidences=batch.confidences[:, :views],
                          joints=batch.joints[:, :views], root_position=batch.root_position[:, :views],
                          root_rotations=batch.root_rotations[:, :views], cameras=jax.tree.map(cut, batch.cameras))


def run_experiment(config: ExperimentConfig, models: dict[str, Flex], out: str | Path,
                   log: Callable[[dict], None] = lambda record: None) -> dict:
    """Evaluate every method (module docstring) and write ``out/results.json``, ``out/results.md`` and the PNGs;
    returns the results. ``models`` must hold the main model ``flex_4views``; an ablation whose model is absent is
    skipped and listed in the results as ``missing_models``."""
    if MAIN_MODEL not in models:
        raise ValueError(f"models lacks the main model {MAIN_MODEL!r} (has {sorted(models)})")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    batches = _test_batches(config)
    rows, ablations, predictions = [], [], {}

    def add(table: list, record: dict) -> None:
        table.append(record)
        log(record)

    for motion in ("static", "dynamic"):
        for source in ("detected", "gt"):
            batch = batches[motion, source]
            metrics, predictions[motion, source, "FLEX"] = _flex_metrics(models[MAIN_MODEL], batch)
            add(rows, {"camera_motion": motion, "input_2d": source, "method": "FLEX (4 views)",
                       "calibration": "none", **metrics})
            calibrations = [("exact", "exact", 0.0)] + [
                ("perturbed", f"perturbed {100 * s:g} %", s) for s in config.perturbations]
            if motion == "dynamic":
                calibrations.append(("static", "stale (first frame)", 0.0))
            for method, label in (("dlt", "DLT"), ("structural", "Structural Triangulation")):
                for index, (calibration, name, scale) in enumerate(calibrations):
                    key = jax.random.fold_in(jax.random.key(config.seed + 1), index)
                    metrics, predictions[motion, source, f"{label}, {name}"] = _baseline_metrics(
                        batch, method, calibration, key if scale else None, scale, config.n_steps)
                    add(rows, {"camera_motion": motion, "input_2d": source, "method": label, "calibration": name,
                               **metrics})
        batch = batches[motion, "detected"]
        for name, (views, fusion) in MODELS.items():
            if fusion == "late" or name not in models:
                continue
            view_batch = _first_views(batch, views)
            pred = predict(models[name], view_batch.points_2d, view_batch.confidences).joints_relative
            add(ablations, {"camera_motion": motion, "ablation": "views", "variant": f"{views} view(s)",
                            **_metrics(pred, view_batch.joints, FLEX20)})
        fusions = [("averaged monocular", "flex_1view", lambda: averaged_monocular(models["flex_1view"], batch)),
                   ("late fusion", "late_fusion_4views",
                    lambda: predict(models["late_fusion_4views"], batch.points_2d, batch.confidences).joints_relative),
                   ("early fusion (FLEX)", MAIN_MODEL, lambda: predictions[motion, "detected", "FLEX"])]
        for variant, pred in ((variant, run()) for variant, name, run in fusions if name in models):
            add(ablations, {"camera_motion": motion, "ablation": "fusion", "variant": variant,
                            **_metrics(pred, batch.joints, FLEX20 if pred.shape[-2] == 20 else STRUCTRI17)})

    rigs: list[dict] = []
    _evaluate_fixed_rigs(config, models, lambda record: add(rigs, record))

    results = {
        "config": dataclasses.asdict(config),
        "machine": {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
                    "jax": jax.__version__, "backend": jax.default_backend()},
        "main": rows, "ablations": ablations, "rigs": rigs,
        "missing_models": sorted(set(MODELS) - set(models)) + sorted(
            name for name, rig in RIG_MODELS.items() if rig in config.rigs and name not in models),
        "seconds": round(time.perf_counter() - start, 1),
    }
    (out / "results.json").write_text(json.dumps(results, indent=2) + "\n")
    (out / "results.md").write_text(_markdown(results))
    _plot_skeletons(config, batches["dynamic", "detected"], predictions, out / "skeletons.png")
    _plot_bars(results, out / "mpjpe.png")
    if rigs:
        _plot_rigs(results, out / "rigs.png")
    return results


def _evaluate_fixed_rigs(config: ExperimentConfig, models: dict[str, Flex], add: Callable[[dict], None]) -> None:
    """The fixed-rig rows (module docstring). Both noise settings share their motion, placements and white noise
    (the correlated noise filters the same draws); every method sees the same perturbed calibrations."""
    rig_model = {rig: name for name, rig in RIG_MODELS.items()}
    for rig in config.rigs:
        index = FIXED_RIGS.index(rig)  # a rig's samples and calibrations do not depend on which others run
        for correlation in (0.0, config.noise_correlation):
            data = DataConfig(views=_TEST_VIEWS, frames=config.frames, clips=config.clips, rig=rig,
                              detector=mocap.DetectorConfig(noise_correlation=correlation))
            batch = make_batch(jax.random.fold_in(jax.random.key(config.seed), 2 + index), data, config.sequences)
            setting = {"rig": rig, "noise_correlation": correlation}
            flex_models = [(f"FLEX (trained on {rig})", rig_model[rig]), ("FLEX (random rigs)", MAIN_MODEL)] + [
                (f"FLEX (trained on {rig}, T-pose rest, {'with' if duplicates else 'no'} duplicate joints)", name)
                for name, (skeleton_rig, duplicates) in SKELETON_MODELS.items() if skeleton_rig == rig]
            for label, name in flex_models:
                if name in models:
                    add({**setting, "method": label, "calibration": "none", **_flex_metrics(models[name], batch)[0]})
            for method, label in (("dlt", "DLT"), ("structural", "Structural Triangulation")):
                add({**setting, "method": label, "calibration": "exact",
                     **_baseline_metrics(batch, method, "exact", None, 0.0, config.n_steps)[0]})
                for scale_index, scale in enumerate(config.perturbations):
                    draws = [_baseline_metrics(batch, method, "perturbed",
                                               _draw_key(config.seed, index, scale_index, draw), scale,
                                               config.n_steps, per_sequence=False)[0]
                             for draw in range(config.perturbation_draws)]
                    add({**setting, "method": label, "calibration": f"perturbed {100 * scale:g} %",
                         **mean_and_spread(draws)})


def _draw_key(seed: int, rig: int, scale: int, draw: int) -> jax.Array:
    """The perturbed calibration ``draw`` of rig ``rig`` at scale ``scale`` (indices): shared by both methods and
    both noise settings."""
    return jax.random.fold_in(jax.random.fold_in(jax.random.fold_in(jax.random.key(seed + 1), rig), scale), draw)


def mean_and_spread(draws: list[dict[str, float]]) -> dict:
    """Each metric's mean over the draws, its sample standard deviation (``<metric>_sd``) and the draws' MPJPE."""
    out = {}
    for name in draws[0]:
        summary = mean_and_sd(*(d[name] for d in draws))
        out[name], out[f"{name}_sd"] = summary["mean"], summary["sd"]
    return out | {"draws_mpjpe_mm": [d["mpjpe_mm"] for d in draws]}


def _markdown(results: dict) -> str:
    lines = ["# FLEX on held-out synthetic CMU clips", "",
             f"Test clips {', '.join(results['config']['clips'])}; {results['config']['sequences']} sequences of "
             f"{results['config']['frames']} frames per camera motion, 4 views. MPJPE protocol #1 (17 joints, "
             "root-relative, camera frame), acceleration error (mm/frame^2), MBLS (bone-length std over time, mm), "
             "global root position error (camera frame, mm; FLEX's made metric with the intrinsics).", ""]
    for source, title in (("detected", "2D detector model"), ("gt", "ground-truth 2D")):
        lines += [f"## Methods, {title}", "",
                  "| cameras | method | calibration | MPJPE mm | accel. err. | MBLS mm | root err. mm |",
                  "|---|---|---|---|---|---|---|"]
        lines += [f"| {r['camera_motion']} | {r['method']} | {r['calibration']} | {r['mpjpe_mm']:.1f} | "
                  f"{r['acceleration_error_mm']:.2f} | {r['mbls_mm']:.1f} | {r['root_error_mm']:.0f} |"
                  for r in results["main"] if r["input_2d"] == source]
        lines.append("")
    lines += ["## Ablations (Table 5), 2D detector model", "",
              "| cameras | ablation | variant | MPJPE mm | accel. err. | MBLS mm |", "|---|---|---|---|---|---|"]
    lines += [f"| {r['camera_motion']} | {r['ablation']} | {r['variant']} | {r['mpjpe_mm']:.1f} | "
              f"{r['acceleration_error_mm']:.2f} | {r['mbls_mm']:.1f} |" for r in results["ablations"]]
    if results["rigs"]:
        config = results["config"]
        lines += ["", "## Fixed rigs (the paper's protocol), 2D detector model", "",
                  f"One rig for every sequence; perturbed: mean +- standard deviation over "
                  f"{config['perturbation_draws']} calibrations, each one draw for the whole rig.", "",
                  "| rig | 2D noise | method | calibration | MPJPE mm | accel. err. | MBLS mm | root err. mm |",
                  "|---|---|---|---|---|---|---|---|"]
        for r in results["rigs"]:
            noise = "white" if r["noise_correlation"] == 0 else f"correlated {r['noise_correlation']:g}"
            spread = f" +- {r['mpjpe_mm_sd']:.1f}" if "mpjpe_mm_sd" in r else ""
            root_spread = f" +- {r['root_error_mm_sd']:.0f}" if "root_error_mm_sd" in r else ""
            lines.append(f"| {r['rig']} | {noise} | {r['method']} | {r['calibration']} | {r['mpjpe_mm']:.1f}{spread} | "
                         f"{r['acceleration_error_mm']:.2f} | {r['mbls_mm']:.1f} | {r['root_error_mm']:.0f}{root_spread} |")
    if results["missing_models"]:
        lines += ["", f"Not evaluated (model absent): {', '.join(results['missing_models'])}."]
    machine = results["machine"]
    lines += ["", f"Machine: {machine['platform']} ({machine['processor']}), jax {machine['jax']} "
              f"({machine['backend']}); {results['seconds']} s.", ""]
    return "\n".join(lines)


def plot_camera_poses(poses: dict[str, tuple[ArrayLike, str]], views: tuple[int, ...], frames: ArrayLike,
                      title: str = ""):
    """A matplotlib figure of camera-frame poses, front view (x right, y up on the page): one row per view, one
    column per frame. ``poses`` maps a label to ``(STRUCTRI17 joints (views, frames, 17, 3), colour)``."""
    frames = np.asarray(frames)
    figure = Figure(figsize=(2.6 * len(frames), 3.2 * len(views)))
    axes = figure.subplots(len(views), len(frames), squeeze=False)
    for row, view in enumerate(views):
        for column, frame in enumerate(frames):
            ax = axes[row, column]
            for label, (joints, colour) in poses.items():
                pose = np.asarray(joints)[view, frame]
                for joint, parent in enumerate(STRUCTRI17.parents):
                    if parent >= 0:
                        ax.plot(pose[[joint, parent], 0], -pose[[joint, parent], 1], color=colour, lw=1.5,
                                label=label if joint == 1 else None)
            ax.set_aspect("equal")
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_title(f"view {view}, frame {frame}", fontsize=9)
    axes[0, 0].legend(fontsize=7, loc="lower left")
    if title:
        figure.suptitle(title)
    figure.tight_layout()
    return figure


def _plot_skeletons(config: ExperimentConfig, batch: Batch, predictions: dict, path: Path) -> None:
    """Ground truth, FLEX and Structural Triangulation with the stale calibration, first dynamic sample."""

    poses = {"ground truth": (batch.joints[0], "black"),
             "FLEX": (remap_joints(predictions["dynamic", "detected", "FLEX"][0], FLEX20, STRUCTRI17), "tab:red"),
             "ST, stale calibration": (
                 predictions["dynamic", "detected", "Structural Triangulation, stale (first frame)"][0], "tab:blue")}
    frames = np.linspace(0, config.frames - 1, config.plot_frames).round().astype(int)
    figure = plot_camera_poses(poses, config.plot_views, frames,
                               "Moving cameras, held-out clip: camera-frame poses (root-relative)")
    figure.savefig(path, dpi=110)


def _plot_rigs(results: dict, path: Path) -> None:
    """MPJPE on each fixed rig with correlated 2D noise, the perturbed rows with their spread over draws."""
    rigs = list(dict.fromkeys(r["rig"] for r in results["rigs"]))
    figure = Figure(figsize=(6 * len(rigs), 4.5))
    axes = figure.subplots(1, len(rigs), sharey=True, squeeze=False)[0]
    for ax, rig in zip(axes, rigs):
        rows = [r for r in results["rigs"] if r["rig"] == rig and r["noise_correlation"] > 0]
        labels = [r["method"].replace("Structural Triangulation", "ST") + ("" if r["calibration"] == "none" else
                                                                          f"\n{r['calibration']}") for r in rows]
        ax.bar(range(len(rows)), [r["mpjpe_mm"] for r in rows], yerr=[r.get("mpjpe_mm_sd", 0.0) for r in rows],
               color=["tab:red" if r["calibration"] == "none" else "tab:gray" for r in rows], capsize=3)
        ax.set_xticks(range(len(rows)), labels, rotation=60, ha="right", fontsize=7)
        ax.set_title(f"fixed rig {rig}, correlated 2D noise")
    axes[0].set_ylabel("MPJPE protocol #1 (mm)")
    figure.tight_layout()
    figure.savefig(path, dpi=110)


def _plot_bars(results: dict, path: Path) -> None:
    """MPJPE of every method and calibration, static and moving cameras, detected 2D."""
    figure = Figure(figsize=(12, 4.5))
    axes = figure.subplots(1, 2, sharey=True)
    for ax, motion in zip(axes, ("static", "dynamic")):
        rows = [r for r in results["main"] if r["camera_motion"] == motion and r["input_2d"] == "detected"]
        labels = [r["method"].replace("Structural Triangulation", "ST") + ("" if r["calibration"] == "none" else
                                                                          f"\n{r['calibration']}") for r in rows]
        colours = ["tab:red" if r["calibration"] == "none" else "tab:gray" for r in rows]
        ax.bar(range(len(rows)), [r["mpjpe_mm"] for r in rows], color=colours)
        ax.set_xticks(range(len(rows)), labels, rotation=60, ha="right", fontsize=7)
        ax.set_title(f"{motion} cameras")
    axes[0].set_ylabel("MPJPE protocol #1 (mm)")
    figure.tight_layout()
    figure.savefig(path, dpi=110)

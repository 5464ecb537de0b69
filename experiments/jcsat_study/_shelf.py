"""The Shelf experiment behind ``python -m experiments.shelf_jcsat``: run a method, write predictions, score them.

Real data (``data_root`` holding ``shelf/``): the OpenPose detections of the standard test frames
300..600 (``quick``: the first 60), scored against actorsGT under the three matching protocols of
``docs/protocols.md`` next to the 4D-association output (``shelf/4d_association/skel.txt``) scored by
the same evaluator. Without data: a seeded synthetic scene with the Shelf rig and the realistic
detector (:func:`mocap.synthesise_scene`), scored against its own ground truth, labelled synthetic.

Method ``jcsat`` runs the geometric pipeline first (its tracks are the persons of Algorithm 1) and
then the model on each track's windows (:func:`~jcsat.predict_shelf15`, ``aggregate``); both are scored, so
the table has the model, the baseline and (on real data) the 4D-association output. ``views`` keeps
a subset of the cameras (the others see nothing: paper Table 6); ``perturb_cameras`` builds the Joint
Cloud with K cameras' calibration perturbed as in Table 8 (:func:`geometry.perturb_extrinsics_bounded`).

:func:`run_shelf_experiment` reads the data (:func:`_load_data`), runs the methods (:func:`_run_methods`),
writes their predictions, scores them (:func:`_score`) and writes the metrics and the figure.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import jax
import numpy as np

import geometry
import mocap
from association import BaselineConfig, BaselineResult, run_geometric_baseline
from jcsat import (
    AGGREGATES,
    DEFAULT_AGGREGATE,
    DEFAULT_WINDOW_STRIDE,
    JCSAT,
    SHIPPED_MODEL,
    load_model,
    predict_shelf15,
    reconstruct,
)

from ._plot import plot_frame

__all__ = ["METHODS", "ShelfExperimentConfig", "ShelfExperimentResult", "check_input_files", "run_shelf_experiment",
           "synthetic_validation"]

METHODS: tuple[str, ...] = ("jcsat", "geometric")
"""``jcsat``: the model on the Joint Cloud of the baseline's tracks (scored beside the baseline);
``geometric``: the learning-free baseline alone."""

_QUICK_REAL_FRAMES = 60
_SHELF_VIEWS = 5
"""Cameras of the Shelf rig, real and synthetic (:func:`mocap.shelf_cameras`)."""


@dataclasses.dataclass(frozen=True)
class ShelfExperimentConfig:
    """Everything that determines a run (saved as ``config.json``)."""

    method: str = "jcsat"
    """:data:`METHODS`: ``"jcsat"``, the model on the baseline's tracks, scored beside the baseline; ``"geometric"``,
    the baseline alone (Joint Cloud -> K-Means people -> weighted medoid + re-triangulation)."""
    model: str | None = None
    """Folder written by :func:`~jcsat.train` (``<workdir>/model``); None: :data:`~jcsat.SHIPPED_MODEL`."""
    data_root: str | None = None
    """Folder with ``shelf/``; None runs the synthetic scene."""
    quick: bool = False
    """Real: the first 60 test frames; synthetic: 40 frames of 3 people."""
    seed: int = 0
    """Key of the synthetic scene (the baseline's K-Means key is ``baseline.seed``)."""
    synthetic_people: int = 4
    """People in the synthetic scene (without Shelf data)."""
    synthetic_frames: int = 150
    """Frames of the synthetic scene (without Shelf data)."""
    synthetic_clips: tuple[str, ...] | None = None
    """Clips the synthetic scene draws its people from (shipped names or motion files); None: every shipped clip."""
    plot: bool = True
    """Write ``frame.png`` (Joint Cloud of one person, baseline, ground truth, reprojections)."""
    baseline: BaselineConfig = BaselineConfig()
    """The geometric baseline, which also gives the model its tracks."""
    views: tuple[int, ...] | None = None
    """Cameras kept (0-based); the others' detections are dropped. None: all."""
    perturb_cameras: int = 0
    """Number of cameras (the first K kept ones) whose calibration is perturbed for the Joint Cloud."""
    perturb_seed: int = 0
    """Key of that perturbation (up to 0.25 cm and 2.5 degrees, paper Table 8)."""
    aggregate: str = DEFAULT_AGGREGATE
    """How the model's windows become one pose per frame (:data:`~jcsat.AGGREGATES`): ``"mean"`` (offline, the
    windows containing the frame; the default, :data:`~jcsat.DEFAULT_AGGREGATE` says why) or ``"last"`` (causal,
    online)."""
    window_stride: int = DEFAULT_WINDOW_STRIDE
    """``"mean"``'s window grid (:func:`~jcsat.predict_shelf15`'s ``stride``; the default:
    :data:`~jcsat.DEFAULT_WINDOW_STRIDE`)."""

    def __post_init__(self) -> None:
        if self.window_stride < 1:
            raise ValueError(f"window_stride must be >= 1, got {self.window_stride}")
        if self.aggregate not in AGGREGATES:
            raise ValueError(f"aggregate must be one of {AGGREGATES}, got {self.aggregate!r}")
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {self.method!r}")
        if self.views is not None:
            if len(set(self.views)) < len(self.views):
                raise ValueError(f"views must not repeat a camera, got {self.views}")
            if len(self.views) < 2:
                raise ValueError(f"at least two distinct views are needed, got {self.views}")
            if not set(self.views) <= set(range(_SHELF_VIEWS)):
                raise ValueError(f"views {self.views} outside the Shelf rig's 0..{_SHELF_VIEWS - 1}")
        if self.perturb_cameras < 0:
            raise ValueError(f"perturb_cameras must be >= 0, got {self.perturb_cameras}")
        kept = _SHELF_VIEWS if self.views is None else len(self.views)
        if self.perturb_cameras > kept:
            raise ValueError(f"perturb_cameras={self.perturb_cameras} but only {kept} views are kept")
        for clip in self.synthetic_clips or ():
            mocap.clip_files(clip)  # a ValueError naming a clip that is neither shipped nor a file
        if self.synthetic_clips == ():
            raise ValueError("synthetic_clips names no clip")
        if self.synthetic_people < 1 or self.synthetic_frames < 1:
            raise ValueError(f"synthetic_people and synthetic_frames must be >= 1, got {self.synthetic_people} "
                             f"and {self.synthetic_frames}")


def check_input_files(config: ShelfExperimentConfig) -> None:
    """Refuse a run whose input files are missing before any work starts (one line naming the file): the
    model folder when the model runs, and with real data the calibration, the detections, actorsGT and the
    4D-association output, which a run would otherwise reach only after its first stages. :func:`run_shelf_experiment`
    calls it first; a command line that trains a model before the run can call it before training."""
    needed = []
    if config.method == "jcsat" and config.model is not None:
        if not Path(config.model).is_dir():
            raise FileNotFoundError(f"model folder {config.model} does not exist")
        needed += [Path(config.model) / "config.json", Path(config.model) / "state.npz"]
    if config.data_root is not None:
        shelf = Path(config.data_root) / "shelf"
        needed += [shelf / "calibration_shelf.json", shelf / "actorsGT.mat", shelf / "4d_association" / "skel.txt"]
        needed += [shelf / "4d_association" / "detection" / f"{view}.txt" for view in range(_SHELF_VIEWS)]
    missing = [path for path in needed if not path.is_file()]
    if missing:
        raise FileNotFoundError(f"missing input file {missing[0]}" + (f" (and {len(missing) - 1} more)"
                                                                       if len(missing) > 1 else ""))


class ShelfExperimentResult(NamedTuple):
    metrics: dict
    """What ``metrics.json`` holds."""
    table: str
    """The printed summary."""
    baseline: BaselineResult


def _score_table(scores: dict[str, dict[str, mocap.ShelfScore]], actors: tuple[int, ...]) -> str:
    """Rows: method x protocol; columns: per-actor PCP, their average, joint precision and recall at 0.2 m,
    MPJPE over matched instances and misses (averages over the averaged actors)."""
    head = " ".join(f"{'A' + str(a + 1):>6}" for a in actors)
    lines = [f"{'method':<12} {'protocol':<10} {head} {'avg':>7} {'prec':>6} {'recall':>6} {'MPJPE mm':>9} {'misses':>6}"]
    for method, by_protocol in scores.items():
        for protocol, score in by_protocol.items():
            by_actor = {s.actor: s for s in score.actors}
            cells = " ".join(f"{by_actor[a].pcp:6.1f}" if a in by_actor else f"{'-':>6}" for a in actors)
            misses = sum(by_actor[a].misses for a in score.averaged_actors)
            lines.append(f"{method:<12} {protocol:<10} {cells} {score.average['pcp']:7.2f} "
                         f"{score.average['precision']:6.1f} {score.average['recall']:6.1f} "
                         f"{score.average['mpjpe_mm']:9.1f} {misses:6d}")
    return "\n".join(lines)


def _keep_views(detections: list[list[mocap.Detections]], views: tuple[int, ...]) -> list[list[mocap.Detections]]:
    """``detections`` with every view not in ``views`` emptied (the camera saw nothing)."""

    def empty(det: mocap.Detections) -> mocap.Detections:
        joints = tuple(c[:0] for c in det.joints)
        return mocap.Detections(joints, tuple(np.zeros((0, 0)) for _ in det.pafs),
                                None if det.person_ids is None else tuple(i[:0] for i in det.person_ids))

    return [[det if v in views else empty(det) for v, det in enumerate(frame)] for frame in detections]


def _perturbed(rig: geometry.Camera, cameras: tuple[int, ...], seed: int) -> geometry.Camera:
    """``rig`` with ``cameras`` perturbed by the Table 8 bounds (0.25 cm, 2.5 degrees), the rest exact."""
    noisy = geometry.perturb_extrinsics_bounded(jax.random.key(seed), rig)
    chosen = np.isin(np.arange(rig.K.shape[0]), cameras)
    return jax.tree.map(lambda exact, off: np.where(chosen.reshape((-1,) + (1,) * (np.ndim(exact) - 1)), off, exact),
                        rig, noisy)


class _ShelfData(NamedTuple):
    """What a run reads: the scene (synthetic or real), with the kept views and perturbed cameras applied."""

    rig: geometry.Camera
    """The calibration the Joint Cloud is built with (``perturb_cameras`` of them perturbed)."""
    exact_rig: geometry.Camera
    detections: list[list[mocap.Detections]]
    frame_indices: np.ndarray
    ground_truth: mocap.EvaluationGroundTruth
    actors: tuple[int, ...]
    views: tuple[int, ...]
    synthetic: bool
    description: dict
    """The ``data`` entry of ``metrics.json`` (and of the ``data`` event)."""


def _load_data(config: ShelfExperimentConfig) -> _ShelfData:
    """The synthetic scene (``data_root`` None) or the real Shelf test frames, their ground truth and actors;
    the views outside ``config.views`` emptied and the first ``perturb_cameras`` kept ones perturbed."""
    synthetic = config.data_root is None
    if synthetic:
        people = 3 if config.quick else config.synthetic_people
        frames = 40 if config.quick else config.synthetic_frames
        clips = None if config.synthetic_clips is None else [mocap.shared_clip(c) for c in config.synthetic_clips]
        scene = mocap.synthesise_scene(jax.random.key(config.seed), mocap.shelf_cameras(), num_people=people,
                                       num_frames=frames, clips=clips)
        rig, detections, frame_indices = scene.rig, scene.detections, np.arange(frames)
        ground_truth = mocap.EvaluationGroundTruth(frame_indices, np.swapaxes(scene.shelf15, 0, 1),
                                                   np.ones((people, frames), bool))
        actors = tuple(range(people))
        description = {"kind": "synthetic", "people": people, "frames": frames, "seed": config.seed,
                       "clips": list(scene.placement.names)}
    else:
        root = Path(config.data_root)
        rig = mocap.shelf_cameras(root)
        detections, frame_indices = mocap.load_shelf_detections(root)
        if config.quick:
            detections, frame_indices = detections[:_QUICK_REAL_FRAMES], frame_indices[:_QUICK_REAL_FRAMES]
        ground_truth = mocap.shelf_evaluation_ground_truth(root, frames=frame_indices)
        actors = (0, 1, 2, 3)
        description = {"kind": "shelf", "frames": [int(frame_indices[0]), int(frame_indices[-1])],
                       "data_root": str(root)}
    views = tuple(range(len(detections[0]))) if config.views is None else tuple(sorted(config.views))
    if config.views is not None:
        detections = _keep_views(detections, views)
    exact_rig = rig
    if config.perturb_cameras:
        rig = _perturbed(rig, views[:config.perturb_cameras], config.perturb_seed)
    description |= {"views": list(views), "perturbed_cameras": list(views[:config.perturb_cameras])}
    return _ShelfData(rig, exact_rig, detections, frame_indices, ground_truth, actors, views, synthetic, description)


class _MethodOutputs(NamedTuple):
    baseline: BaselineResult
    predictions: dict[str, mocap.PosePredictions]
    """Method name -> its predictions, ``config.method`` first."""
    track_poses: np.ndarray | None
    """The model's Shelf15 poses of every track and frame ``(tracks, frames, 15, 3)`` (method ``jcsat``)."""


def _run_methods(config: ShelfExperimentConfig, data: _ShelfData, event: Callable[..., None],
                 progress: Callable[[str], None]) -> _MethodOutputs:
    """The geometric baseline, then (method ``jcsat``) the model on the baseline's tracks (:func:`jcsat.reconstruct`);
    the stage timings are added to the baseline's ``seconds``."""
    # A broken model file fails here, before the baseline's half minute, not after it.
    model = load_model(SHIPPED_MODEL if config.model is None else config.model) if config.method == "jcsat" else None
    progress(config.method)
    run = reconstruct(data.rig, data.detections, data.frame_indices, model, baseline=config.baseline,
                      aggregate=config.aggregate, stride=config.window_stride)
    result = run.baseline
    result.seconds.update(run.seconds)
    event("geometric", seconds={k: round(v, 3) for k, v in result.seconds.items() if k != "jcsat"},
          tracks=int(result.present.shape[0]), predictions=int(result.predictions.num_predictions))
    compared = {"geometric": result.predictions}
    track_poses = None
    if model is not None:
        rows = run.predictions
        compared = {"jcsat": rows, **compared}
        position = np.searchsorted(data.frame_indices, rows.frame)
        track_poses = np.zeros(result.present.shape + (15, 3))
        track_poses[rows.person, position] = rows.joints
        event("jcsat", seconds=round(run.seconds["jcsat"], 3), windows=len(position),
              frames_per_second=round(len(data.frame_indices) / run.seconds["jcsat"], 2))
    return _MethodOutputs(result, compared, track_poses)


def _score(config: ShelfExperimentConfig, data: _ShelfData, predictions: dict[str, mocap.PosePredictions]
           ) -> tuple[dict[str, dict[str, mocap.ShelfScore]], tuple[int, ...]]:
    """Every method's (and on real data the 4D-association output's) score under every protocol, and the actors
    its PCP averages over: all on synthetic data; on real data actors 1-3, those annotated in the evaluated
    frames (actor 2 is absent from the first 60)."""
    averaged = (data.actors if data.synthetic
                else tuple(a for a in (0, 1, 2) if data.ground_truth.annotated[a].any()))
    compared = dict(predictions)
    if not data.synthetic:
        four_da = mocap.predictions_from_4dassoc(Path(config.data_root) / "shelf" / "4d_association" / "skel.txt")
        compared["4DA output"] = mocap.PosePredictions.create(
            *(field[np.isin(four_da.frame, data.frame_indices)] if field is not None else None for field in four_da)
        )
    scores = {name: {p: mocap.evaluate_shelf(pred, data.ground_truth, p, averaged)
                     for p in mocap.EVALUATION_PROTOCOLS}
              for name, pred in compared.items()}
    return scores, averaged


def _title(config: ShelfExperimentConfig, data: _ShelfData, averaged: tuple[int, ...]) -> str:
    """The two lines above the score table: the method and setting, the data and the averaged actors."""
    kind = ("SYNTHETIC Shelf-rig scene (mocap.synthesise_scene), NOT the real Shelf data" if data.synthetic
            else f"real Shelf, actorsGT frames {data.frame_indices[0]}..{data.frame_indices[-1]}")
    views = data.views
    setting = f"views {list(views)}" + (f", perturbed cameras {list(views[:config.perturb_cameras])}"
                                        if config.perturb_cameras else "")
    model = f"model: {config.model or SHIPPED_MODEL}, beside " if config.method == "jcsat" else ""
    return (f"method: {config.method} ({model}the learning-free Joint Cloud baseline 'geometric'); {setting}\n"
            f"data: {kind}; PCP averaged over actors {', '.join(str(a + 1) for a in averaged)}")


def _plot(path: Path, config: ShelfExperimentConfig, data: _ShelfData, outputs: _MethodOutputs) -> int:
    """Write the figure of the frame :func:`_plot_frame_choice` picks; returns that frame's index in the run."""
    result, truth_all = outputs.baseline, data.ground_truth
    frame = _plot_frame_choice(result, truth_all.annotated)
    truth = truth_all.joints[:, frame][truth_all.annotated[:, frame]]
    plot_frame(path, data.exact_rig, mocap.pad_detections(data.detections, config.baseline.max_candidates), result,
               frame, truth, title=f"{config.method}, {'synthetic' if data.synthetic else 'Shelf'} frame "
                                   f"{int(data.frame_indices[frame])}",
               track_poses=None if outputs.track_poses is None else outputs.track_poses[:, frame])
    return frame


def run_shelf_experiment(
    config: ShelfExperimentConfig,
    out_dir: str | Path,
    log: Callable[[dict], None] = lambda event: None,
    progress: Callable[[str], None] = lambda stage: None,
) -> ShelfExperimentResult:
    """Run ``config`` and write ``config.json``, ``predictions.jsonl``, ``metrics.json`` (and
    ``frame.png``) to ``out_dir``. ``log`` receives one JSON-ready dict per event, ``progress`` the
    name of each stage as it starts. Missing input files are refused before anything is written."""
    check_input_files(config)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "config.json").write_text(json.dumps(dataclasses.asdict(config), indent=2) + "\n")
    started = time.perf_counter()

    def event(stage: str, **fields) -> None:
        log({"stage": stage, "elapsed_s": round(time.perf_counter() - started, 3), **fields})

    progress("data")
    data = _load_data(config)
    event("data", **data.description)

    outputs = _run_methods(config, data, event, progress)
    for name, predictions in outputs.predictions.items():
        mocap.write_predictions(out / ("predictions.jsonl" if name == config.method else f"predictions_{name}.jsonl"),
                                predictions)

    progress("evaluation")
    scores, averaged = _score(config, data, outputs.predictions)
    title = _title(config, data, averaged)
    metrics = {
        "method": config.method, "data": data.description, "synthetic": data.synthetic,
        "scores": {name: {p: s.to_dict() for p, s in by.items()} for name, by in scores.items()},
        "seconds": {k: round(v, 3) for k, v in outputs.baseline.seconds.items()},
        "total_seconds": round(time.perf_counter() - started, 3),
    }
    event("evaluation", pcp={name: {p: round(s.average["pcp"], 2) for p, s in by.items()} for name, by in scores.items()})

    if config.plot:
        progress("plot")
        frame = _plot(out / "frame.png", config, data, outputs)
        metrics["plot"] = {"file": "frame.png", "frame": int(data.frame_indices[frame])}
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2) + "\n")
    event("done", total_seconds=metrics["total_seconds"])
    return ShelfExperimentResult(metrics, title + "\n" + _score_table(scores, data.actors), outputs.baseline)


def _plot_frame_choice(result: BaselineResult, annotated: np.ndarray) -> int:
    """A frame with the most annotated people and, among those, an output track count closest to that
    number (earliest on ties): every ground-truth person is shown, with little spurious-track clutter."""
    output = np.isin(np.arange(result.present.shape[0]), np.unique(result.predictions.person))
    tracks = (result.present & output[:, None]).sum(axis=0)
    people = np.asarray(annotated).sum(axis=0)
    candidates = np.flatnonzero(people == people.max())
    return int(candidates[np.argmin(np.abs(tracks[candidates] - people.max()))])


_AGGREGATE_SETTINGS = (("jcsat, last", "last", 1), ("jcsat, mean", "mean", 1), ("jcsat, mean, stride 2", "mean", 2),
                       ("jcsat, mean, stride 3", "mean", 3))


def synthetic_validation(
    settings: dict[str, BaselineConfig],
    seeds: tuple[int, ...] = (101, 102, 103),
    people: int = 4,
    frames: int = 90,
    protocol: str = "voxelpose",
    model: JCSAT | None = None,
) -> dict[str, dict[str, float]]:
    """Score baseline settings on SYNTHETIC Shelf-rig validation scenes (never on the Shelf test frames).

    One scene per seed (:func:`mocap.synthesise_scene` with :func:`mocap.shelf_cameras`, the
    realistic detector); every setting runs on every scene. Returns per setting the PCP (%,
    ``protocol``, averaged over all people) of each seed (``"seed <s>"``), their mean (``"pcp"``)
    and the mean number of tracks (``"tracks"``). The seeds differ from the main job's default (0).
    With ``model``, rows ``"jcsat, ..."`` score it on the default :class:`BaselineConfig`'s tracks with
    each of :data:`~jcsat.AGGREGATES` (``"mean"`` with window strides 1, 2 and 3).
    """
    scenes = [mocap.synthesise_scene(jax.random.key(seed), mocap.shelf_cameras(), num_people=people,
                                     num_frames=frames) for seed in seeds]
    rows: dict[str, list[tuple[float, int]]] = {}
    for scene in scenes:
        scene_truth = mocap.EvaluationGroundTruth(np.arange(frames), np.swapaxes(scene.shelf15, 0, 1),
                                                  np.ones((people, frames), bool))

        def score(predictions: mocap.PosePredictions) -> tuple[float, int]:
            pcp = mocap.evaluate_shelf(predictions, scene_truth, protocol, tuple(range(people))).average["pcp"]
            return pcp, len(np.unique(predictions.person))

        for name, config in settings.items():
            result = run_geometric_baseline(scene.rig, scene.detections, np.arange(frames), config)
            rows.setdefault(name, []).append(score(result.predictions))
        if model is not None:
            result = run_geometric_baseline(scene.rig, scene.detections, np.arange(frames), BaselineConfig())
            tracks = result.predictions
            for name, aggregate, stride in _AGGREGATE_SETTINGS:
                poses = predict_shelf15(model, result.person_cloud, tracks.person, tracks.frame, aggregate=aggregate,
                                        stride=stride)
                predicted = mocap.PosePredictions.create(tracks.frame, tracks.person, poses, score=tracks.score)
                rows.setdefault(name, []).append(score(predicted))
    return {name: {**{f"seed {seed}": pcp for seed, (pcp, _) in zip(seeds, scores)},
                   "pcp": float(np.mean([pcp for pcp, _ in scores])),
                   "tracks": float(np.mean([count for _, count in scores]))}
            for name, scores in rows.items()}

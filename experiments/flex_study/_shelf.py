"""FLEX on the real Shelf detections (issue 25, item 3), beside calibrated triangulation of the same detections.

Protocol (decided before the run; nothing here was tuned on the test frames 300..600):

- **People and their 2D.** The learning-free association with all 5 views and the exact calibration, as
  ``python -m experiments.structri_shelf`` runs it (:class:`~experiments.structri_study.ShelfScene`): its output
  tracks are the people, and per track, frame, view and SKEL19 joint the 2D detection and weight (the detection's
  score, 0 where the consensus did not use the view) that its re-triangulation used. The association uses the
  calibration; the reconstruction below does not (FLEX) or does (the baselines).
- **Views.** The first four cameras (``views``): the FLEX models take four; every method sees the same four.
- **Rows.** The actor-frames the association matched to a track (per frame, each annotated actor 1-3 to the nearest
  track within 0.5 m, :func:`~experiments.structri_study._shelf.match_tracks`), kept where every SKEL19 joint has at
  least two of the four views (triangulable), so every method is scored on the same rows. Coverage = rows /
  annotated actor-frames.
- **FLEX.** Per track, its 2D over all the run's frames (frames where the track is absent take its nearest present
  frame's 2D: they are never scored) made into the model's STRUCTRI17 input by :func:`flex.input_from_detections`,
  one forward pass, no extrinsics. Its camera-frame, root-relative pose per view (FLEX20 -> STRUCTRI17 ->
  Shelf15 by :func:`geometry.to_shelf15`, the ``"h36m"`` head rule) is turned to world orientation by that view's
  true rotation (for scoring only: FLEX's output has no world frame) and scored per view; the table gives the mean
  over the four views.
- **Baselines.** DLT (:func:`structri.ls_triangulation`, confidence-weighted least squares) and Structural
  Triangulation (:func:`structri.structural_triangulation`, ``n_steps`` SCA steps) on the same 2D and weights, with the
  exact calibration and with ``perturbation_draws`` draws of extrinsics perturbed by ``perturbation``
  (:func:`geometry.perturb_extrinsics_relative`, one draw for the whole rig; mean and standard deviation over the
  draws). Structural Triangulation's bone lengths: per track, :func:`association.track_bone_lengths` of the same
  calibration's DLT poses on the track's rows (no ground truth, no other calibration). SKEL19 -> Shelf15 by the
  ``"4da"`` head rule, as the Shelf evaluator scores the pipeline.
- **Metrics** (:func:`~experiments.structri_study.score_rows`, per actor then the mean over actors 1-3): MPJPE after
  root alignment (each pose translated so that its joint 14, the mid-hip, is the ground truth's), the same without
  the two head joints (each method derives them by its own rule), PCP on the same aligned poses (JCSAT /
  4D-association rule), limb-length error (MPBLE), stability (MBLS) and symmetry.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable
from pathlib import Path

import jax
import numpy as np

import geometry
import mocap
from association import track_bone_lengths
from experiments.structri_study import ShelfConfig, ShelfScene, score_rows, solvable
from flex import Flex, input_from_detections, predict
from structri import ls_triangulation, structural_triangulation

from ._synthetic import mean_and_spread

__all__ = ["FlexShelfConfig", "flex_poses", "run_flex_shelf"]

_STRUCTRI17_IN_FLEX20 = np.array([geometry.FLEX20.index(name) for name in geometry.STRUCTRI17.joints])
_METRICS = ("mpjpe_mm", "mpjpe_body_mm", "pcp", "mpble_mm", "mbls_mm", "symmetry_mm")
_BODY = np.r_[0:12, 14]
"""Shelf15 joints less the head's two (12, 13): each method's head joints come from its own rule (the detections'
face keypoints for the baselines, the body model's head joints for FLEX), which the annotation matches unequally."""


@dataclasses.dataclass(frozen=True)
class FlexShelfConfig:
    """Everything the table depends on (written to ``config.json``)."""

    data_root: str
    """Folder holding ``shelf/``."""
    frames: int = ShelfConfig.frames
    """The first this many test frames from 300 (301: all of 300..600)."""
    views: tuple[int, ...] = (0, 1, 2, 3)
    """The Shelf cameras every method sees (FLEX's models take four)."""
    perturbation: float = 0.03
    """Relative standard deviation of the perturbed extrinsics (0.03: 3 %)."""
    perturbation_draws: int = 5
    n_steps: int = 3
    """SCA steps of Structural Triangulation."""
    seed: int = 0
    """Seed of the perturbation draws."""

    def __post_init__(self) -> None:
        ShelfConfig(self.data_root, frames=self.frames)  # the data files and the frame count
        if len(set(self.views)) != len(self.views) or not set(self.views) <= set(range(5)) or len(self.views) < 2:
            raise ValueError(f"views must be at least 2 distinct Shelf cameras of 0..4, got {self.views}")
        if not self.perturbation > 0:
            raise ValueError(f"perturbation must be > 0, got {self.perturbation}")
        if self.perturbation_draws < 2:
            raise ValueError(f"perturbation_draws must be >= 2 (a spread), got {self.perturbation_draws}")
        if self.n_steps < 1:
            raise ValueError(f"n_steps must be >= 1, got {self.n_steps}")


def _held(pixels: np.ndarray, weight: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A track's (F, ...) 2D and weights with every frame where it is absent (all weights 0) taken from its nearest
    present frame."""
    present = np.flatnonzero(weight.reshape(len(weight), -1).any(axis=-1))
    nearest = present[np.abs(np.arange(len(weight))[:, None] - present[None]).argmin(axis=-1)]
    return pixels[nearest], weight[nearest]


def flex_poses(model: Flex, scene: ShelfScene, views: list[int]) -> dict[int, np.ndarray]:
    """Per track of ``scene`` (by its row in ``scene.pixels``): FLEX's Shelf15 pose per view and frame,
    root-relative, in each view's camera frame (``(views, frames, 15, 3)``, metres)."""
    poses = {}
    for track_index in range(len(scene.tracks)):
        weight = scene.weight[track_index][:, :, views]  # (F, 19, V)
        if not weight.any():
            continue
        pixels, weight = _held(scene.pixels[track_index][:, :, views], weight)
        points, confidences = input_from_detections(np.moveaxis(pixels, 2, 0), np.moveaxis(weight, 2, 0),
                                                    geometry.SKEL19)  # (V, F, 17, 2), (V, F, 17)
        joints = np.asarray(predict(model, points[None], confidences[None]).joints_relative[0])  # (V, F, 20, 3)
        poses[track_index] = np.asarray(geometry.to_shelf15(joints[..., _STRUCTRI17_IN_FLEX20, :], geometry.STRUCTRI17))
    return poses


def _aligned(pose: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """``pose`` translated so that its joint 14 (mid-hip) is the ground truth's."""
    return pose - pose[:, 14:15] + truth[:, 14:15]


def _triangulations(scene: ShelfScene, rows: np.ndarray, cameras: geometry.Camera, views: list[int],
                    n_steps: int) -> dict[str, np.ndarray]:
    """DLT and Structural Triangulation of the rows' 2D through ``cameras`` (Shelf15, world, metres)."""
    track, frame = scene.track[rows], scene.frame[rows]
    weight = scene.weight[track, frame][:, :, views]  # (N, 19, V)
    points = np.swapaxes(scene.pixels[track, frame][:, :, views], 1, 2)  # (N, V, 19, 2)
    confidences = np.swapaxes(weight, 1, 2)
    projections = np.asarray(geometry.projection_matrix(cameras))
    dlt = np.asarray(ls_triangulation(points, projections, geometry.SKEL19, confidences).pose)
    lengths = np.zeros((len(rows), geometry.SKEL19.num_joints - 1))
    for t in np.unique(track):
        mine = track == t
        lengths[mine] = track_bone_lengths(dlt[mine], (weight[mine] > 0).sum(-1), geometry.SKEL19)
    st = np.asarray(structural_triangulation(points, projections, lengths, geometry.SKEL19, confidences,
                                             n_steps=n_steps).pose)
    return {name: np.asarray(geometry.to_shelf15(pose, geometry.SKEL19)) for name, pose in (("DLT", dlt), ("ST", st))}


def run_flex_shelf(config: FlexShelfConfig, models: dict[str, Flex], out: str | Path,
                   log: Callable[[dict], None] = lambda record: None, scene: ShelfScene | None = None) -> dict:
    """The table (module docstring) for ``models`` (name -> a FLEX model of ``len(config.views)`` views); writes
    ``out/results.json`` and ``out/results.md`` and returns the results. ``scene``: the association's output for
    ``config.frames`` when it was already run (None: run it here). The triangulations run in float64
    (``jax.enable_x64`` for this call only)."""
    for name, model in models.items():
        if model.config.views != len(config.views):
            raise ValueError(f"model {name} takes {model.config.views} views, the table uses {len(config.views)}")
    with jax.enable_x64(True):
        return _run_flex_shelf(config, models, Path(out), log,
                               scene or ShelfScene(ShelfConfig(config.data_root, frames=config.frames)))


def _run_flex_shelf(config: FlexShelfConfig, models: dict[str, Flex], out: Path, log: Callable[[dict], None],
                    scene: ShelfScene) -> dict:
    if len(scene.frame_indices) != config.frames:
        raise ValueError(f"the scene has {len(scene.frame_indices)} frames, the config {config.frames}")
    start = time.perf_counter()
    views = list(config.views)
    rig = mocap.shelf_cameras(config.data_root).select(np.asarray(views))
    rows = np.flatnonzero(solvable(scene.weight[scene.track, scene.frame][:, :, views]))
    actor, frame, track = scene.actor[rows], scene.frame[rows], scene.track[rows]
    truth = scene.truth[actor, frame]

    def scores(poses: np.ndarray) -> dict:
        aligned = _aligned(poses, truth)
        body = 1000.0 * np.linalg.norm(aligned[:, _BODY] - truth[:, _BODY], axis=-1).mean(axis=-1)
        mean = score_rows(aligned, truth, actor, scene.reference_lengths)["mean"]
        return mean | {"mpjpe_body_mm": float(np.mean([body[actor == a].mean() for a in np.unique(actor)]))}

    results: dict = {"config": dataclasses.asdict(config), "rows": int(len(rows)),
                     "coverage": float(len(rows) / scene.annotated_count), "methods": {}}
    world_from_camera = np.swapaxes(np.asarray(rig.R), -1, -2)  # (V, 3, 3)
    for name, model in models.items():
        poses = flex_poses(model, scene, views)
        per_view = []
        for v in range(len(views)):
            camera_pose = np.stack([poses[int(t)][v, f] for t, f in zip(track, frame)])
            per_view.append(scores(np.einsum("ij,nkj->nki", world_from_camera[v], camera_pose)))
        results["methods"][name] = {m: float(np.mean([s[m] for s in per_view])) for m in _METRICS}
        log({"method": name, **results["methods"][name]})
    for method, poses in _triangulations(scene, rows, rig, views, config.n_steps).items():
        results["methods"][f"{method} exact"] = scores(poses)
        log({"method": f"{method} exact", **results["methods"][f"{method} exact"]})
    draws: dict[str, list[dict]] = {"DLT": [], "ST": []}
    for draw in range(config.perturbation_draws):
        key = jax.random.fold_in(jax.random.key(config.seed), draw)
        cameras = geometry.perturb_extrinsics_relative(key, rig, config.perturbation)
        for method, poses in _triangulations(scene, rows, cameras, views, config.n_steps).items():
            draws[method].append(scores(poses))
    label = f"{100 * config.perturbation:g} %"
    for method, values in draws.items():
        results["methods"][f"{method} {label}"] = mean_and_spread([{m: v[m] for m in _METRICS} for v in values])
        log({"method": f"{method} {label}", **results["methods"][f"{method} {label}"]})
    results["seconds"] = round(time.perf_counter() - start, 1)
    (out / "results.json").write_text(json.dumps(results, indent=1))
    (out / "results.md").write_text(_report(results))
    return results


def _report(results: dict) -> str:
    config = results["config"]
    lines = [
        f"FLEX on the real Shelf detections, frames 300..{299 + config['frames']}, cameras {config['views']}: "
        f"{results['rows']} actor-frames of actors 1-3 ({100 * results['coverage']:.1f} % of those annotated), "
        "the same rows for every method. MPJPE and PCP after root alignment (each pose's mid-hip moved onto the "
        "ground truth's); FLEX without extrinsics (the mean over its views), the baselines with the exact "
        f"calibration and with {config['perturbation_draws']} draws of extrinsics perturbed by "
        f"{100 * config['perturbation']:g} % (mean +- sd).",
        "",
        "| method | MPJPE (mm) | MPJPE w/o head (mm) | PCP (%) | MPBLE (mm) | MBLS (mm) | symmetry (mm) |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, m in results["methods"].items():
        cell = [f"{m[k]:.1f}" + (f" +- {m[k + '_sd']:.1f}" if k + "_sd" in m else "") for k in _METRICS]
        lines.append(f"| {name} | " + " | ".join(cell) + " |")
    return "\n".join(lines) + "\n"

"""Structural Triangulation on the real Shelf detections (issue 30, item 1): the paper's Tables 1-3 in shape.

Protocol (decided before the run; nothing here was tuned on the test frames 300..600):

- **Association, once, with all 5 views.** :func:`association.run_geometric_baseline` (default
  :class:`~association.BaselineConfig`) on the real OpenPose BODY25 detections (:func:`mocap.load_shelf_detections`,
  :func:`mocap.shelf_cameras`), as ``python -m experiments.shelf_jcsat`` runs it. Its tracks are the people; the
  pipeline's output tracks (those of :attr:`~association.BaselineResult.predictions`) are kept. For each track and
  frame, each SKEL19 joint's (:data:`geometry.SKEL19`, BODY25 minus eyes, small toes and heels) per-view 2D
  detections and weights are those the consensus re-triangulation used (:attr:`~association.BaselineResult.consensus`,
  weights = detection scores, 0 for a view not used).
- **View subsets.** The triangulation sees a subset of the views (the association stays the 5-view one, so every
  row triangulates the same people): for C in ``view_counts`` every combination of C of the 5 views (10, 10, 5 and 1
  subsets for C = 2, 3, 4, 5); the dropped views' weights are 0. Per C the table gives the mean (``results.json``
  also the min and max) over the subsets that evaluated any actor-frame, and the coverage over all of them.
- **Evaluated person-frames.** A track-frame is solvable for a subset when every SKEL19 joint has at least 2 views of
  positive weight in it. All methods of a subset are scored on the same solvable track-frames. Coverage = evaluated
  ground-truth actor-frames / all actor-frames of actors 1-3 annotated in the frames.
- **Track to actor.** Per frame, each annotated actor 1-3 goes to the track, among those solvable with all 5 views,
  whose 5-view LS pose (Shelf15, :func:`geometry.to_shelf15` with the SKEL19 4D-association head rule) has the
  smallest mean distance over the 14 Shelf joints (:func:`mocap.match_predictions`, ``"voxelpose"``), if that is
  below :data:`mocap.JCSAT_MATCH_GATE_M` (0.5 m); two actors may take one track. This assignment serves every method
  and subset.
- **Methods** (:data:`SHELF_METHODS`; metres and pixels, confidences = the weights): ``LS``
  (:func:`structri.ls_triangulation`, the paper's DLT(LS)), ``LEM`` (:func:`structri.lem_triangulation`),
  ``Lagrangian`` (:func:`structri.lagrangian_triangulation`, the official step sizes, ``lagrangian_iterations``),
  ``ST`` (:func:`structri.structural_triangulation`, ``n_steps`` SCA steps) with the track's lengths, and ``ST*``:
  the same with lengths from :func:`structri.estimate_bone_lengths` over the track's first ``estimate_frames``
  frames solvable with 5 views (left and right averaged). The track's lengths (ST and Lagrangian) are
  :func:`association.track_bone_lengths` (per bone the median, mirrored) of the 5-view LS poses of the track's
  solvable frames; no ground truth enters, and both length estimates use all 5 views whatever the subset. The
  library's default ``max_length_error`` (0.5) is kept; ``fallback`` is the fraction of evaluated frames whose
  status is FALLBACK_LS or UNDERDETERMINED.
- **Metrics** (against actorsGT, Shelf15, metres computed, millimetres and per cent reported; per actor over its
  evaluated frames, then the mean over actors 1-3 that have any): MPJPE over the 15 Shelf15 joints, no alignment;
  PCP with the JCSAT / 4D-association rule of the Shelf evaluator (:func:`geometry.pcp`, strict ``<``, the torso
  from the prediction's own pelvis, joint 14); over the 8 limb bones (:data:`LIMBS`: upper arms, forearms, thighs,
  shins): MPBLE, the mean ``|length - the actor's mean ground-truth length|`` (that mean over the actor's annotated
  frames of the run); MBLS, the square root of the mean over the bones of each length's variance over the frames
  (Structural Triangulation's definition); symmetry, the mean ``|left - right|`` length of the 4 limb pairs. The
  ground truth's own MBLS and symmetry on the same actor-frames are reported beside them (annotations are not
  rigid).
"""

from __future__ import annotations

import dataclasses
import itertools
import json
import time
from pathlib import Path

import jax
import numpy as np
from jaxtyping import Bool, Float, Int
from tqdm import tqdm

import geometry
import mocap
from association import BaselineResult, run_geometric_baseline, track_bone_lengths
from structri import (Status, estimate_bone_lengths, lagrangian_triangulation, lem_triangulation, ls_triangulation,
                      structural_triangulation)

__all__ = ["SHELF_METHODS", "ShelfConfig", "ShelfScene", "run_shelf", "score_rows", "solvable"]

SHELF_METHODS: tuple[str, ...] = ("LS", "LEM", "Lagrangian", "ST", "ST*")
"""Triangulation methods, in table order: unconstrained least squares (the paper's DLT(LS)), the official DLT
(linear eigen method), the Lagrangian baseline and Structural Triangulation + SCA with the track's lengths, and
Structural Triangulation with lengths estimated from the track's first frames."""

LIMBS: tuple[tuple[str, str], ...] = (
    ("r_shoulder", "r_elbow"), ("r_elbow", "r_wrist"), ("r_hip", "r_knee"), ("r_knee", "r_ankle"),
    ("l_shoulder", "l_elbow"), ("l_elbow", "l_wrist"), ("l_hip", "l_knee"), ("l_knee", "l_ankle"),
)
"""The 8 limb bones SKEL19 and Shelf share, the 4 right ones first, then their left mirrors in the same order."""

SHELF_VIEWS = 5
"""Cameras of the Shelf rig."""
ACTORS = (0, 1, 2)
"""The actors the Shelf protocol averages (actors 1-3)."""
TEST_FRAMES = len(mocap.shelf_test_frames())

_SKEL19_IN_BODY25 = np.array([geometry.BODY25.index(name) for name in geometry.SKEL19.joints])
_LIMB_BONES = np.array([next(k for k, bone in enumerate(geometry.SHELF15.bones)
                             if set(bone) == {geometry.SHELF15.index(a), geometry.SHELF15.index(b)})
                        for a, b in LIMBS])
_FAILED = (Status.FALLBACK_LS, Status.UNDERDETERMINED)


@dataclasses.dataclass(frozen=True)
class ShelfConfig:
    """Everything the table depends on (written to ``config.json``)."""

    data_root: str
    """Folder holding ``shelf/`` (calibration, the 4D-association OpenPose detections, actorsGT)."""
    frames: int = TEST_FRAMES
    """The first this many test frames from 300 (301: all of 300..600)."""
    view_counts: tuple[int, ...] = (2, 3, 4, 5)
    """Camera counts C; each runs every combination of C of the 5 views."""
    n_steps: int = 3
    """SCA steps of Structural Triangulation (the paper's N = 3)."""
    lagrangian_iterations: int = 200
    """Iterations of the Lagrangian baseline (the official code's 200)."""
    estimate_frames: int = 10
    """ST*: a track's first this many 5-view solvable frames give its estimated lengths."""

    def __post_init__(self) -> None:
        mocap.find_data_root(self.data_root, "shelf")
        shelf = Path(self.data_root) / "shelf"
        needed = [shelf / "calibration_shelf.json", shelf / "actorsGT.mat"]
        needed += [shelf / "4d_association" / "detection" / f"{view}.txt" for view in range(SHELF_VIEWS)]
        missing = [path for path in needed if not path.is_file()]
        if missing:
            raise ValueError(f"missing input file {missing[0]}")
        if not 1 <= self.frames <= TEST_FRAMES:
            raise ValueError(f"frames must be 1..{TEST_FRAMES}, got {self.frames}")
        if (not self.view_counts or len(set(self.view_counts)) < len(self.view_counts)
                or not set(self.view_counts) <= set(range(2, SHELF_VIEWS + 1))):
            raise ValueError(f"view_counts must be distinct camera counts in 2..{SHELF_VIEWS}, got {self.view_counts}")
        for name in ("n_steps", "lagrangian_iterations", "estimate_frames"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")


def view_subsets(num_views: int, count: int) -> list[tuple[int, ...]]:
    """Every combination of ``count`` of the views ``0..num_views - 1``, in lexicographic order."""
    return list(itertools.combinations(range(num_views), count))


def solvable(weight: Float[np.ndarray, "*b J V"], views: tuple[int, ...] | None = None) -> Bool[np.ndarray, "*b"]:
    """Whether every joint has at least 2 views of positive weight among ``views`` (None: all)."""
    positive = np.asarray(weight) > 0
    if views is not None:
        positive = positive[..., list(views)]
    return np.all(positive.sum(axis=-1) >= 2, axis=-1)


def limb_lengths(shelf15: Float[np.ndarray, "*b 15 3"]) -> Float[np.ndarray, "*b 8"]:
    """The :data:`LIMBS` lengths of Shelf15 poses (input unit)."""
    return np.asarray(geometry.bone_lengths(shelf15, geometry.SHELF15))[..., _LIMB_BONES]


def symmetry_error(lengths: Float[np.ndarray, "*b 8"]) -> Float[np.ndarray, "*b"]:
    """Mean ``|left - right|`` over the 4 limb pairs of :data:`LIMBS` lengths."""
    half = len(LIMBS) // 2
    return np.mean(np.abs(lengths[..., :half] - lengths[..., half:]), axis=-1)


def length_spread(lengths: Float[np.ndarray, "frames bones"]) -> float:
    """MBLS: square root of the mean over bones of each length's (population) variance over the frames."""
    return float(np.sqrt(np.mean(np.var(lengths, axis=0))))


def match_tracks(
    track_poses: Float[np.ndarray, "T F 15 3"],
    track_valid: Bool[np.ndarray, "T F"],
    ground_truth: Float[np.ndarray, "A F 15 3"],
    annotated: Bool[np.ndarray, "A F"],
) -> Int[np.ndarray, "A F"]:
    """Per frame, each annotated actor's track: the valid track with the smallest mean distance over the 14 Shelf
    joints (:func:`mocap.match_predictions`, ``"voxelpose"``), if below :data:`mocap.JCSAT_MATCH_GATE_M`; else -1."""
    assigned = np.full(annotated.shape, -1)
    for frame in range(annotated.shape[1]):
        tracks, actors = np.flatnonzero(track_valid[:, frame]), np.flatnonzero(annotated[:, frame])
        if not (tracks.size and actors.size):
            continue
        candidates, truth = track_poses[tracks, frame], ground_truth[actors, frame]
        nearest = mocap.match_predictions(candidates, truth, "voxelpose")
        distance = np.linalg.norm(candidates[nearest, :14] - truth[:, :14], axis=-1).mean(axis=-1)
        close = distance < mocap.JCSAT_MATCH_GATE_M
        assigned[actors[close], frame] = tracks[nearest[close]]
    return assigned


def track_observations(result: BaselineResult, tracks: Int[np.ndarray, " T"]
                       ) -> tuple[Float[np.ndarray, "T F 19 V 2"], Float[np.ndarray, "T F 19 V"]]:
    """Per track (of ``tracks``) and frame, the SKEL19 joints' 2D detections (pixels) and weights that the
    baseline's consensus re-triangulation used (:attr:`~association.BaselineResult.consensus`); zero weights
    where the track is absent or a view was not used."""
    num_frames, num_views = result.track_of.shape[0], result.consensus.view_weight.shape[-1]
    pixels = np.zeros((len(tracks), num_frames, geometry.SKEL19.num_joints, num_views, 2))
    weight = np.zeros(pixels.shape[:-1])
    frame, slot = np.nonzero(np.isin(result.track_of, tracks))
    row = np.searchsorted(tracks, result.track_of[frame, slot])
    pixels[row, frame] = np.asarray(result.consensus.pixels)[frame, slot][:, _SKEL19_IN_BODY25]
    weight[row, frame] = np.asarray(result.consensus.view_weight)[frame, slot][:, _SKEL19_IN_BODY25]
    return pixels, weight


def score_rows(
    predicted: Float[np.ndarray, "N 15 3"],
    truth: Float[np.ndarray, "N 15 3"],
    actor: Int[np.ndarray, " N"],
    reference_lengths: Float[np.ndarray, "A 8"],
) -> dict:
    """Scores of evaluated actor-frames (Shelf15, metres): per actor (``"actors"``, keyed by 1-based actor number)
    and their mean over the actors present (``"mean"``; None without rows): MPJPE, MPBLE, MBLS and symmetry in mm,
    PCP in %. ``reference_lengths[a]`` is actor a's mean ground-truth :data:`LIMBS` lengths."""
    errors = 1000.0 * np.asarray(geometry.mpjpe(predicted, truth))
    correct = np.asarray(geometry.pcp(predicted, truth, geometry.SHELF15, strict=True, zero_is_missing=True))
    lengths = limb_lengths(predicted)
    per_actor = {}
    for a in np.unique(actor):
        rows = actor == a
        per_actor[int(a) + 1] = {
            "frames": int(rows.sum()),
            "mpjpe_mm": float(errors[rows].mean()),
            "pcp": 100.0 * float(correct[rows].mean()),
            "mpble_mm": 1000.0 * float(np.abs(lengths[rows] - reference_lengths[a]).mean()),
            "mbls_mm": 1000.0 * length_spread(lengths[rows]),
            "symmetry_mm": 1000.0 * float(symmetry_error(lengths[rows]).mean()),
        }
    metrics = ("mpjpe_mm", "pcp", "mpble_mm", "mbls_mm", "symmetry_mm")
    mean = {m: float(np.mean([s[m] for s in per_actor.values()])) if per_actor else None for m in metrics}
    return {"mean": mean, "actors": per_actor}


class ShelfScene:
    """The association's output on the first ``config.frames`` test frames, reduced to what a table on the real
    detections needs (NumPy, metres and pixels; this table's and ``experiments.flex_shelf``'s): per track (``tracks``,
    rows of ``pixels``) and frame, the SKEL19 2D per view and their weights (``pixels``, ``weight``); the matched
    actor-frames (``actor``, ``frame``, ``track``), the ground truth (``truth``, ``annotated``) and each actor's
    reference limb lengths; each track's bone lengths from its 5-view poses (``lengths``, ``estimated_lengths``)."""

    def __init__(self, config: ShelfConfig):
        root = Path(config.data_root)
        rig = mocap.shelf_cameras(root)
        self.projections = np.asarray(geometry.projection_matrix(rig))
        detections, frame_indices = mocap.load_shelf_detections(root)
        detections, self.frame_indices = detections[:config.frames], frame_indices[:config.frames]
        truth = mocap.shelf_evaluation_ground_truth(root, frames=self.frame_indices)
        start = time.perf_counter()
        result = run_geometric_baseline(rig, detections, self.frame_indices)
        self.association_seconds = time.perf_counter() - start
        self.tracks = np.unique(result.predictions.person)
        self.pixels, self.weight = track_observations(result, self.tracks)
        self.truth = truth.joints[list(ACTORS)]
        self.annotated = truth.annotated[list(ACTORS)]
        # Each actor's reference limb lengths: the mean over its annotated frames of the run.
        self.reference_lengths = np.stack([limb_lengths(joints[seen]).mean(axis=0) if seen.any()
                                           else np.full(len(LIMBS), np.nan)
                                           for joints, seen in zip(self.truth, self.annotated)])

        # 5-view LS poses of every solvable track-frame: the matching and the track's lengths.
        self.solvable_all = solvable(self.weight)
        track, frame = np.nonzero(self.solvable_all)
        ls = ls_triangulation(self._points(track, frame), self.projections, geometry.SKEL19,
                              self._weights(track, frame))
        ls_pose = np.zeros(self.solvable_all.shape + (geometry.SKEL19.num_joints, 3))
        ls_pose[track, frame] = np.asarray(ls.pose)
        shelf15 = np.asarray(geometry.to_shelf15(ls_pose, geometry.SKEL19))
        self.assigned = match_tracks(shelf15, self.solvable_all, self.truth, self.annotated)

        # A track never solvable with 5 views has no lengths (NaN); it has no 5-view pose either, so it is never
        # matched and never solved.
        unknown = np.full(geometry.SKEL19.num_joints - 1, np.nan)
        views = (self.weight > 0).sum(axis=-1)
        self.lengths = np.stack([track_bone_lengths(ls_pose[t][seen], views[t][seen], geometry.SKEL19)
                                 if seen.any() else unknown for t, seen in enumerate(self.solvable_all)])
        self.estimated_lengths = np.stack([
            np.asarray(estimate_bone_lengths(
                self._points(t, first), self.projections, geometry.SKEL19, self._weights(t, first)))
            if first.size else unknown
            for t, first in ((t, np.flatnonzero(seen)[:config.estimate_frames])
                             for t, seen in enumerate(self.solvable_all))])

        # The matched actor-frames, one row each: the rows every method and subset is scored on.
        self.actor, self.frame = np.nonzero(self.assigned >= 0)
        self.track = self.assigned[self.actor, self.frame]
        self.annotated_count = int(self.annotated.sum())

    def _points(self, track, frame) -> np.ndarray:
        """``(..., views, joints, 2)``, the solvers' layout."""
        return np.swapaxes(self.pixels[track, frame], -2, -3)

    def _weights(self, track, frame) -> np.ndarray:
        """``(..., views, joints)``, the solvers' layout."""
        return np.swapaxes(self.weight[track, frame], -1, -2)


def _solve_subset(scene: ShelfScene, config: ShelfConfig, views: tuple[int, ...]) -> dict:
    """Every method on the matched rows with only ``views``' weights, scored on the rows solvable with them."""
    keep = np.isin(np.arange(SHELF_VIEWS), views)
    weight = scene.weight[scene.track, scene.frame] * keep
    evaluated = solvable(weight)
    # Every matched row is solved (fixed shapes: one compilation per method for all subsets); only the solvable
    # ones are scored.
    points, confidences = scene._points(scene.track, scene.frame), np.swapaxes(weight, -1, -2)
    P, skeleton = scene.projections, geometry.SKEL19
    lengths, estimated = scene.lengths[scene.track], scene.estimated_lengths[scene.track]
    results = {
        "LS": ls_triangulation(points, P, skeleton, confidences),
        "LEM": lem_triangulation(points, P, skeleton, confidences),
        "Lagrangian": lagrangian_triangulation(points, P, lengths, skeleton, confidences,
                                               n_iterations=config.lagrangian_iterations),
        "ST": structural_triangulation(points, P, lengths, skeleton, confidences, n_steps=config.n_steps),
        "ST*": structural_triangulation(points, P, estimated, skeleton, confidences, n_steps=config.n_steps),
    }
    actor, frame = scene.actor[evaluated], scene.frame[evaluated]
    truth = scene.truth[actor, frame]
    cell = {"views": list(views), "count": len(views), "evaluated": int(evaluated.sum()),
            "coverage": float(evaluated.sum() / scene.annotated_count), "methods": {}}
    for name, result in results.items():
        pose = np.asarray(result.pose)[evaluated]
        status = np.asarray(result.status)[evaluated]
        scores = score_rows(np.asarray(geometry.to_shelf15(pose, skeleton)), truth, actor, scene.reference_lengths)
        cell["methods"][name] = {**scores["mean"],
                                 "fallback": float(np.isin(status, _FAILED).mean()) if status.size else None,
                                 "single_step": float((status == Status.SINGLE_STEP).mean()) if status.size else None,
                                 "actors": scores["actors"]}
    truth_scores = score_rows(truth, truth, actor, scene.reference_lengths)
    cell["ground_truth"] = {**truth_scores["mean"], "actors": truth_scores["actors"]}
    return cell


_SUMMARISED = ("mpjpe_mm", "pcp", "mpble_mm", "mbls_mm", "symmetry_mm", "fallback")


def _summary(cells: list[dict]) -> dict:
    """Per camera count: coverage and every method's metrics, the mean over its subsets with their min and max;
    the metrics over the subsets that evaluated any actor-frame (``scored_subsets``; None where none did)."""

    def spread(values: list[float | None]) -> dict | None:
        values = [v for v in values if v is not None]
        if not values:
            return None
        return {"mean": float(np.mean(values)), "min": float(np.min(values)), "max": float(np.max(values))}

    out = {}
    for count in sorted({c["count"] for c in cells}):
        mine = [c for c in cells if c["count"] == count]
        entry = {"subsets": len(mine), "scored_subsets": sum(c["evaluated"] > 0 for c in mine),
                 "coverage": spread([c["coverage"] for c in mine]), "methods": {}}
        for name in SHELF_METHODS:
            entry["methods"][name] = {m: spread([c["methods"][name][m] for c in mine]) for m in _SUMMARISED}
        entry["ground_truth"] = {m: spread([c["ground_truth"][m] for c in mine])
                                 for m in ("mpble_mm", "mbls_mm", "symmetry_mm")}
        out[str(count)] = entry
    return out


def run_shelf(config: ShelfConfig, out: str | Path, scene: ShelfScene | None = None) -> dict:
    """Run the table and write ``config.json``, ``log.jsonl`` (one line for the association, then one per view
    subset), ``results.json`` (every subset and the summary per camera count) and ``results.md`` to ``out``.
    ``scene``: the association's output for ``config`` when it was already run (None: run it here).

    The solvers run in float64 (``jax.enable_x64`` for this call only; the global setting is left as it was)."""
    with jax.enable_x64(True):
        return _run_shelf(config, Path(out), scene or ShelfScene(config))


def _log(out: Path, entry: dict) -> None:
    with open(out / "log.jsonl", "a") as log:
        log.write(json.dumps(entry) + "\n")


def _run_shelf(config: ShelfConfig, out: Path, scene: ShelfScene) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    (out / "config.json").write_text(json.dumps(dataclasses.asdict(config), indent=2) + "\n")
    start = time.perf_counter()
    association = {"stage": "association", "seconds": round(scene.association_seconds, 3),
                   "tracks": len(scene.tracks), "matched_actor_frames": len(scene.actor),
                   "annotated_actor_frames": scene.annotated_count,
                   "frames": [int(scene.frame_indices[0]), int(scene.frame_indices[-1])]}
    _log(out, association | {"elapsed_s": round(time.perf_counter() - start, 3)})
    subsets = [views for count in config.view_counts for views in view_subsets(SHELF_VIEWS, count)]
    cells = []
    for views in tqdm(subsets, desc="structri_shelf", unit="subset"):
        cell = _solve_subset(scene, config, views)
        _log(out, {"stage": "subset", **cell, "elapsed_s": round(time.perf_counter() - start, 3)})
        cells.append(cell)
    results = {"config": dataclasses.asdict(config), "units": "mm and % (computed in metres)",
               "association": association, "summary": _summary(cells), "subsets": cells,
               "elapsed_s": time.perf_counter() - start}
    (out / "results.json").write_text(json.dumps(results, indent=1) + "\n")
    (out / "results.md").write_text(report(results))
    return results


def report(results: dict) -> str:
    """``results.md``: rows = method, one column per camera count C, each cell the mean over the C-view subsets of
    MPJPE / PCP / MPBLE / symmetry; then MBLS and the fallback rate in the same layout."""
    summary, association = results["summary"], results["association"]
    counts = list(summary)
    first, last = association["frames"]
    head = ["| method | " + " | ".join(f"C = {c} (coverage {100 * summary[c]['coverage']['mean']:.1f} %, "
                                         f"{summary[c]['scored_subsets']} of {summary[c]['subsets']} subsets)"
                                         for c in counts) + " |",
            "|---|" + "---|" * len(counts)]

    def cell(values: dict, fmt: str) -> str:
        """``fmt`` filled with the means over the subsets; n/a where no subset scored anything."""
        means = {m: v["mean"] for m, v in values.items() if v is not None}
        return fmt.format(**means) if len(means) == len(values) else "n/a"

    lines = [f"# Structural Triangulation on Shelf, real OpenPose detections (frames {first}..{last})", "",
             f"Tracks of the 5-view geometric baseline ({association['tracks']} output tracks), matched to actors 1-3 "
             f"in {association['matched_actor_frames']} of {association['annotated_actor_frames']} annotated "
             "actor-frames. Each C-view subset scores the matched actor-frames its views can triangulate (every "
             "SKEL19 joint seen by 2 of them); coverage: evaluated / annotated actor-frames, mean over all the "
             "subsets of C views. Metrics: means over the subsets that scored any actor-frame (their number in "
             "the header); min and max in results.json. Per actor, then the mean of actors 1-3; PCP: the JCSAT / "
             "4D-association rule (strict, torso from the predicted pelvis).", "",
             "## MPJPE (mm) / PCP (%) / MPBLE (mm) / symmetry (mm)", ""] + head
    scores = "{mpjpe_mm:.1f} / {pcp:.1f} / {mpble_mm:.1f} / {symmetry_mm:.1f}"
    lines += [f"| {name} | " + " | ".join(cell(summary[c]["methods"][name], scores) for c in counts) + " |"
              for name in SHELF_METHODS]
    lines += ["| actorsGT | " + " | ".join(cell(summary[c]["ground_truth"], "- / - / {mpble_mm:.1f} / {symmetry_mm:.1f}")
                                           for c in counts) + " |", "",
              "## MBLS (mm) / fallback to LS or underdetermined (% of evaluated frames)", ""] + head
    lines += [f"| {name} | " + " | ".join(cell(summary[c]["methods"][name], "{mbls_mm:.1f} / {fallback:.1%}")
                                          for c in counts) + " |" for name in SHELF_METHODS]
    lines += ["| actorsGT | " + " | ".join(cell(summary[c]["ground_truth"], "{mbls_mm:.1f} / -") for c in counts)
              + " |", "",
              "actorsGT: the annotations' own limb lengths on the same actor-frames (MPBLE against each actor's "
              "mean), which are not rigid.", ""]
    return "\n".join(lines)

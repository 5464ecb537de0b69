"""Shelf / Campus evaluation: PCP, joint precision / recall, MPJPE and Recall@500mm under the three
matching conventions of ``docs/protocols.md``, each named in every result.

Entry points::

    gt = mocap.shelf_evaluation_ground_truth(data_root)          # actorsGT frames 300..600, SHELF15
    predictions = mocap.read_predictions("run.jsonl")            # or mocap.PosePredictions.create(...)
    scores = [mocap.evaluate_shelf(predictions, gt, p) for p in mocap.EVALUATION_PROTOCOLS]
    print(mocap.format_shelf_scores(scores))

:func:`match_predictions` is the one implementation of the matching rules (one frame):

``"voxelpose"`` (VoxelPose, Faster-VoxelPose, MVPose)
    Every ground-truth (GT) person takes the prediction with the lowest MPJPE over the 14 Shelf
    joints, not one-to-one and without a distance gate; a frame without predictions leaves its GT
    unmatched (VoxelPose crashes there, MVPose scores 0/10: here it is a miss, scored 0). PCP with
    ``<=`` and the predicted torso starting at the mean of the predicted hips.
``"jcsat"`` (JCSAT ``evaluate.py``)
    Every prediction, in output order, goes to the GT with the smallest mean distance over all 15
    joints (zero joints included) if that is below 0.5 m; of several predictions on one GT the first
    is scored. An unmatched GT scores 0. PCP strict (``<``), a part with a predicted endpoint at
    exactly (0, 0, 0) is wrong, the torso starts at the prediction's own joint 14.
``"4dassoc"`` (4D Association ``evaluate_shelf``)
    Hungarian assignment (``scipy.optimize.linear_sum_assignment``) on the summed joint distance over
    15 joints, no gate; an unmatched GT is **not counted** (PCP over matched instances only). PCP
    strict, torso from the prediction's joint 14.

Every protocol reports, per actor, the same :class:`ActorScore` fields; only the matching, the PCP
rule and the PCP denominator change. Precision / recall at 0.2 m and MPJPE follow JCSAT semantics
(``docs/protocols.md``) on each protocol's matched pairs (under ``"voxelpose"`` a prediction nearest to two
people counts for both): a joint counts as detected if it is not (0, 0, 0),
recall is over all annotated instances (a miss adds zeros), MPJPE is the mean over matched instances
of the mean error over detected joints, with ``misses`` next to it, and ``mpjpe_jcsat_mm`` is
JCSAT's value (sum over matched instances / annotated instances: each miss adds 0 mm). Recall@500mm
is VoxelPose's (fraction of annotated GT whose nearest prediction by 14-joint MPJPE is < 0.5 m) and
does not depend on the protocol. Percentages are 0..100, MPJPE in millimetres; positions in metres.
"""

from __future__ import annotations

import os
import typing
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Literal, NamedTuple

import jax
import numpy as np
from jaxtyping import Bool, Float, Int
from scipy.optimize import linear_sum_assignment

import geometry

from ._predictions import PosePredictions
from ._shelf_campus import load_4dassoc_skeletons, load_shelf_ground_truth, shelf_test_frames

__all__ = [
    "EvaluationProtocol",
    "EVALUATION_PROTOCOLS",
    "JCSAT_MATCH_GATE_M",
    "JOINT_PRECISION_THRESHOLD_M",
    "VOXELPOSE_RECALL_THRESHOLD_M",
    "PCP_GROUPS",
    "EvaluationGroundTruth",
    "ground_truth_from_shelf14",
    "shelf_evaluation_ground_truth",
    "match_predictions",
    "ActorScore",
    "ShelfScore",
    "evaluate_shelf",
    "prediction_problems",
    "format_shelf_scores",
]

EvaluationProtocol = Literal["voxelpose", "jcsat", "4dassoc"]
EVALUATION_PROTOCOLS: tuple[str, ...] = typing.get_args(EvaluationProtocol)

JCSAT_MATCH_GATE_M = 0.5
"""JCSAT ``evaluate.py`` calls ``util_re_id`` with 0.5 m (the function's own default is 0.2 m)."""
JOINT_PRECISION_THRESHOLD_M = 0.2
VOXELPOSE_RECALL_THRESHOLD_M = 0.5

PCP_GROUPS: dict[str, tuple[str, ...]] = {
    "head": ("head",),
    "torso": ("torso",),
    "upper_arms": ("l_upper_arm", "r_upper_arm"),
    "lower_arms": ("l_lower_arm", "r_lower_arm"),
    "upper_legs": ("l_upper_leg", "r_upper_leg"),
    "lower_legs": ("l_lower_leg", "r_lower_leg"),
}
"""VoxelPose's bone groups, as SHELF15 PCP part names."""

_SHELF15 = geometry.SHELF15
_NUM_SHELF14 = 14
_HIPS = [_SHELF15.index("r_hip"), _SHELF15.index("l_hip")]
_MID_HIP = _SHELF15.index("mid_hip")
_PART_NAMES = [name for name, _, _ in _SHELF15.pcp_parts]


class EvaluationGroundTruth(NamedTuple):
    """Ground truth of an evaluation range, SHELF15 with joint 14 = mean of the hips (NumPy)."""

    frames: Int[np.ndarray, " frames"]
    """actorsGT frame index of each evaluated frame."""
    joints: Float[np.ndarray, "actors frames 15 3"]
    """Positions in metres, zeros where not annotated."""
    annotated: Bool[np.ndarray, "actors frames"]


def ground_truth_from_shelf14(
    joints: Float[np.ndarray, "actors frames 14 3"],
    annotated: Bool[np.ndarray, "actors frames"],
    frames: Int[np.ndarray, " frames"],
) -> EvaluationGroundTruth:
    """SHELF14 ground truth (e.g. a slice of :func:`load_shelf_ground_truth`, or Campus) to SHELF15."""
    joints = np.asarray(joints, dtype=np.float64)
    annotated = np.asarray(annotated, dtype=bool)
    frames = np.asarray(frames, dtype=np.int64)
    if joints.ndim != 4 or joints.shape[2:] != (_NUM_SHELF14, 3) or annotated.shape != joints.shape[:2]:
        raise ValueError(f"need joints (actors, frames, 14, 3) and annotated (actors, frames), "
                         f"got {joints.shape} and {annotated.shape}")
    if frames.shape != (joints.shape[1],) or len(np.unique(frames)) != len(frames):
        raise ValueError(f"frames must be {joints.shape[1]} distinct actorsGT indices, got shape {frames.shape}")
    shelf15 = np.asarray(geometry.to_shelf15(joints, geometry.SHELF14))
    return EvaluationGroundTruth(frames, np.where(annotated[..., None, None], shelf15, 0.0), annotated)


def shelf_evaluation_ground_truth(
    data_root: str | os.PathLike,
    source: Literal["actorsGT", "4dassoc"] = "actorsGT",
    frames: Int[np.ndarray, " frames"] | None = None,
) -> EvaluationGroundTruth:
    """The Shelf ground truth over ``frames`` (default: the 301 test frames 300..600).

    ``source="actorsGT"`` reads the official ``shelf/actorsGT.mat`` (mid-hip = mean of the hips);
    ``"4dassoc"`` reads ``shelf/4d_association/gt.txt`` (the same GT for frames 300..600 with its
    stored mid-hip, what JCSAT evaluates against; its person id is the actor index).
    """
    frames = shelf_test_frames() if frames is None else np.asarray(frames, dtype=np.int64)
    if source == "actorsGT":
        joints, annotated = load_shelf_ground_truth(data_root)
        if frames.min() < 0 or frames.max() >= joints.shape[1]:
            raise ValueError(f"frames must lie in 0..{joints.shape[1] - 1}")
        return ground_truth_from_shelf14(joints[:, frames, :, :], annotated[:, frames], frames)
    if source != "4dassoc":
        raise ValueError(f"unknown ground-truth source {source!r}; use 'actorsGT' or '4dassoc'")
    path = Path(data_root) / "shelf" / "4d_association" / "gt.txt"
    stored = load_4dassoc_skeletons(path, num_joints=_SHELF15.num_joints)
    stored_frames = shelf_test_frames()[: len(stored)]
    outside = np.setdiff1d(frames, stored_frames)
    if outside.size:
        raise ValueError(f"{path} covers frames {stored_frames[0]}..{stored_frames[-1]}, not {outside[:5].tolist()}")
    num_actors = 1 + max((p.person_id for persons in stored for p in persons), default=-1)
    joints = np.zeros((num_actors, len(frames), _SHELF15.num_joints, 3))
    annotated = np.zeros((num_actors, len(frames)), bool)
    for k, frame in enumerate(frames):
        for person in stored[int(frame - stored_frames[0])]:
            if annotated[person.person_id, k]:
                raise ValueError(f"{path}: actor {person.person_id} appears twice in frame {frame}")
            joints[person.person_id, k] = person.joints
            annotated[person.person_id, k] = True
    return EvaluationGroundTruth(frames, joints, annotated)


def _distances(pred: np.ndarray, gt: np.ndarray, num_joints: int) -> np.ndarray:
    """(g, k, num_joints) joint distances between every GT and every prediction, first joints only."""
    return np.linalg.norm(pred[None, :, :num_joints] - gt[:, None, :num_joints], axis=-1)


def match_predictions(
    predictions: Float[np.ndarray, "k 15 3"],
    ground_truth: Float[np.ndarray, "g 15 3"],
    protocol: EvaluationProtocol,
) -> Int[np.ndarray, " g"]:
    """Match one frame: for every GT person the index of its scored prediction, or -1 if unmatched.

    ``predictions`` in the method's output order, metres. The rules are in the module docstring.
    """
    if protocol not in EVALUATION_PROTOCOLS:
        raise ValueError(f"unknown protocol {protocol!r}; choose from {EVALUATION_PROTOCOLS}")
    pred = np.asarray(predictions, dtype=np.float64)
    gt = np.asarray(ground_truth, dtype=np.float64)
    for name, poses in (("predictions", pred), ("ground_truth", gt)):
        if poses.ndim != 3 or poses.shape[1:] != (_SHELF15.num_joints, 3):
            raise ValueError(f"{name} must have shape (n, 15, 3) (SHELF15, metres), got {poses.shape}")
    match = np.full(len(gt), -1, dtype=np.int64)
    if len(pred) == 0 or len(gt) == 0:
        return match
    if protocol == "voxelpose":
        return np.argmin(_distances(pred, gt, _NUM_SHELF14).mean(-1), axis=1)
    if protocol == "jcsat":
        mean_distance = _distances(pred, gt, _SHELF15.num_joints).mean(-1)  # (g, k)
        for k in range(len(pred)):
            nearest = int(np.argmin(mean_distance[:, k]))
            if mean_distance[nearest, k] < JCSAT_MATCH_GATE_M and match[nearest] < 0:
                match[nearest] = k
        return match
    rows, cols = linear_sum_assignment(_distances(pred, gt, _SHELF15.num_joints).sum(-1))
    match[rows] = cols
    return match


class ActorScore(NamedTuple):
    """One actor's scores under one protocol (percentages 0..100, MPJPE in mm)."""

    actor: int
    """0-based actor index (papers' A1 is actor 0)."""
    annotated: int
    """GT instances (frames where the actor is annotated)."""
    matched: int
    misses: int
    """``annotated - matched``."""
    parts_correct: int
    parts_total: int
    """10 per annotated instance; per matched instance under ``"4dassoc"``."""
    pcp: float
    """``100 parts_correct / parts_total`` (NaN only if nothing entered the denominator)."""
    group_pcp: dict[str, float]
    """PCP per :data:`PCP_GROUPS` group."""
    precision: float
    recall: float
    mpjpe_mm: float
    """Mean over matched instances (NaN if none is matched or has a detected joint)."""
    mpjpe_jcsat_mm: float
    recall_500mm: float


class ShelfScore(NamedTuple):
    """Per-actor scores under one protocol, and their mean over ``averaged_actors``."""

    protocol: str
    actors: tuple[ActorScore, ...]
    """Actors annotated at least once in the evaluated frames."""
    averaged_actors: tuple[int, ...]
    average: dict[str, float]
    """Mean over ``averaged_actors`` of pcp, precision, recall, mpjpe_mm, mpjpe_jcsat_mm, recall_500mm."""
    problems: tuple[str, ...] = ()
    """What :func:`prediction_problems` found wrong with the predictions (each also warned about)."""

    def to_dict(self) -> dict:
        """JSON-ready nested dict; an undefined value (NaN) becomes None (JSON null)."""
        def clean(value):
            if isinstance(value, dict):
                return {k: clean(v) for k, v in value.items()}
            return None if isinstance(value, float) and not np.isfinite(value) else value

        return {"protocol": self.protocol, "actors": [clean(a._asdict()) for a in self.actors],
                "averaged_actors": list(self.averaged_actors), "average": clean(self.average),
                "problems": list(self.problems)}


_AVERAGED_FIELDS = ("pcp", "precision", "recall", "mpjpe_mm", "mpjpe_jcsat_mm", "recall_500mm")


def _percent(numerator, denominator) -> float:
    return float(100.0 * numerator / denominator) if denominator else float("nan")


_UNIT_RATIO_LIMIT = 10.0
"""Predicted bones more than this many times longer (or shorter) than the ground truth's are a unit mistake."""
_MIN_COVERAGE = 0.9
"""Below this fraction of the evaluated frames with a prediction, the file is reported as incomplete."""

_UNIT_NAMES = ((300.0, 3000.0, "millimetres"), (30.0, 300.0, "centimetres"))


def _median_bone_length(joints: Float[np.ndarray, "n 15 3"]) -> float:
    """Median SHELF15 bone length over the bones whose two joints are reconstructed (not (0, 0, 0)); NaN if none."""
    parent, child = (np.array(ends) for ends in zip(*_SHELF15.bones))
    lengths = np.linalg.norm(joints[:, child] - joints[:, parent], axis=-1)
    present = np.any(joints != 0, axis=-1)
    known = lengths[present[:, parent] & present[:, child]]
    return float(np.median(known)) if known.size else float("nan")


def prediction_problems(predictions: PosePredictions, ground_truth: EvaluationGroundTruth) -> tuple[str, ...]:
    """What makes a score of ``predictions`` against ``ground_truth`` misleading, one line each (none: ``()``).

    - unit: the median predicted bone is more than 10 times as long (or short) as the
      ground truth's median bone (predictions in millimetres are 1000x and score PCP 0);
    - coverage: fewer than 90% of the evaluated frames (those with an annotated person) have a
      prediction (a truncated file, or shifted frame indices; every person there is scored a miss).
    """
    problems = []
    predicted, annotated = _median_bone_length(predictions.joints), _median_bone_length(
        ground_truth.joints[ground_truth.annotated])
    ratio = predicted / annotated if annotated > 0 else float("nan")
    if np.isfinite(ratio) and not 1 / _UNIT_RATIO_LIMIT <= ratio <= _UNIT_RATIO_LIMIT:
        unit = next((name for low, high, name in _UNIT_NAMES if low <= ratio < high), "a unit other than metres")
        problems.append(f"predicted bones are {ratio:.4g}x the ground truth's (median {predicted:.4g} vs "
                        f"{annotated:.3g} m): the joints look like {unit}; predictions must be in metres")
    evaluated = ground_truth.frames[ground_truth.annotated.any(axis=0)]
    covered = int(np.isin(evaluated, predictions.frame).sum())
    if evaluated.size and covered < _MIN_COVERAGE * evaluated.size:
        problems.append(f"predictions cover {covered} of the {evaluated.size} evaluated frames "
                        f"({100 * covered / evaluated.size:.1f}%): every person in the other frames is scored a miss")
    return tuple(problems)


def evaluate_shelf(
    predictions: PosePredictions,
    ground_truth: EvaluationGroundTruth,
    protocol: EvaluationProtocol,
    averaged_actors: tuple[int, ...] = (0, 1, 2),
) -> ShelfScore:
    """Score ``predictions`` against ``ground_truth`` under ``protocol`` (see the module docstring).

    Every prediction must lie in a frame of ``ground_truth.frames`` (a prediction elsewhere is most
    likely an off-by-300 detection index and raises ``ValueError``). ``averaged_actors`` are the
    0-based actors of the reported average: actors 1-3 for Shelf and Campus. The
    :func:`prediction_problems` of the predictions (a unit mistake, low coverage) are warned about
    (``UserWarning``) and returned in ``problems``.
    """
    if protocol not in EVALUATION_PROTOCOLS:
        raise ValueError(f"unknown protocol {protocol!r}; choose from {EVALUATION_PROTOCOLS}")
    outside = np.setdiff1d(predictions.frame, ground_truth.frames)
    if outside.size:
        raise ValueError(f"predictions in frames {outside[:5].tolist()} outside the evaluated frames "
                         f"{ground_truth.frames.min()}..{ground_truth.frames.max()} (actorsGT indices)")
    problems = prediction_problems(predictions, ground_truth)
    for problem in problems:
        warnings.warn(problem, stacklevel=2)
    num_actors = ground_truth.annotated.shape[0]
    pred_joints, gt_joints, actors = [], [], []
    near_500mm = np.zeros(num_actors, np.int64)
    for k, frame in enumerate(ground_truth.frames):
        present = np.flatnonzero(ground_truth.annotated[:, k])
        if present.size == 0:
            continue
        pred = predictions.in_frame(int(frame))
        gt = ground_truth.joints[present, k]
        if len(pred):
            nearest = _distances(pred, gt, _NUM_SHELF14).mean(-1).min(axis=1)
            near_500mm[present] += nearest < VOXELPOSE_RECALL_THRESHOLD_M
        match = match_predictions(pred, gt, protocol)
        hit = match >= 0
        pred_joints.append(pred[match[hit]])
        gt_joints.append(gt[hit])
        actors.append(present[hit])
    pred_joints = np.concatenate(pred_joints or [np.zeros((0, _SHELF15.num_joints, 3))])
    gt_joints = np.concatenate(gt_joints or [np.zeros((0, _SHELF15.num_joints, 3))])
    actors = np.concatenate(actors or [np.zeros(0, np.int64)])

    pcp_pred = pred_joints.copy()
    if protocol == "voxelpose":
        pcp_pred[:, _MID_HIP] = pcp_pred[:, _HIPS].mean(axis=1)
    strict = protocol != "voxelpose"
    correct = np.asarray(geometry.pcp(pcp_pred, gt_joints, _SHELF15, strict=strict,
                                      zero_is_missing=protocol == "jcsat"))
    hits = geometry.joint_precision_recall(pred_joints, gt_joints, JOINT_PRECISION_THRESHOLD_M)
    detected = np.any(pred_joints != 0, axis=-1)
    instance_mpjpe = np.asarray(geometry.mpjpe(pred_joints, gt_joints, detected))  # NaN: nothing detected

    group_index = {g: [_PART_NAMES.index(p) for p in parts] for g, parts in PCP_GROUPS.items()}
    scores = []
    for actor in range(num_actors):
        annotated = int(ground_truth.annotated[actor].sum())
        if annotated == 0:
            continue
        rows = actors == actor
        matched = int(rows.sum())
        counted = matched if protocol == "4dassoc" else annotated
        mine = correct[rows]
        pr = geometry.aggregate_precision_recall(jax.tree.map(lambda x, rows=rows: x[rows], hits),
                                                 unmatched_gt=annotated - matched)
        errors = instance_mpjpe[rows]
        errors = errors[np.isfinite(errors)]
        scores.append(ActorScore(
            actor=actor,
            annotated=annotated,
            matched=matched,
            misses=annotated - matched,
            parts_correct=int(mine.sum()),
            parts_total=len(_PART_NAMES) * counted,
            pcp=_percent(mine.sum(), len(_PART_NAMES) * counted),
            group_pcp={g: _percent(mine[:, ix].sum(), len(ix) * counted) for g, ix in group_index.items()},
            precision=100.0 * float(np.mean(pr.precision)),
            recall=100.0 * float(np.mean(pr.recall)),
            mpjpe_mm=1000.0 * float(errors.mean()) if errors.size else float("nan"),
            mpjpe_jcsat_mm=1000.0 * float(errors.sum()) / annotated,
            recall_500mm=_percent(near_500mm[actor], annotated),
        ))
    by_actor = {s.actor: s for s in scores}
    missing = [a for a in averaged_actors if a not in by_actor]
    if missing:
        raise ValueError(f"averaged actors {missing} are never annotated in the evaluated frames")
    average = {f: float(np.mean([getattr(by_actor[a], f) for a in averaged_actors])) for f in _AVERAGED_FIELDS}
    return ShelfScore(protocol, tuple(scores), tuple(averaged_actors), average, problems)


def _cell(value: float, digits: int = 1) -> str:
    return "n/a" if not np.isfinite(value) else f"{value:.{digits}f}"


def format_shelf_scores(scores: Sequence[ShelfScore]) -> str:
    """A plain-text table: per protocol, one row per metric, one column per actor and the average."""
    lines = []
    for score in scores:
        averaged = [a for a in score.actors if a.actor in score.averaged_actors]
        others = [a for a in score.actors if a.actor not in score.averaged_actors]
        label = "avg A" + ",".join(str(a + 1) for a in score.averaged_actors)
        header = ["", *(f"A{a.actor + 1}" for a in averaged), label, *(f"A{a.actor + 1}" for a in others)]

        def row(name, cell, average=None, columns=(averaged, others)):
            first, rest = columns
            middle = [] if average is None else [average]
            return [name, *(cell(a) for a in first), *(middle or [""]), *(cell(a) for a in rest)]

        avg = score.average
        table = [
            header,
            row("PCP %", lambda a: _cell(a.pcp), _cell(avg["pcp"], 2)),
            row("parts correct", lambda a: f"{a.parts_correct}/{a.parts_total}"),
            *(row(f"  {g} %", lambda a, g=g: _cell(a.group_pcp[g])) for g in PCP_GROUPS),
            row("precision@0.2m %", lambda a: _cell(a.precision), _cell(avg["precision"])),
            row("recall@0.2m %", lambda a: _cell(a.recall), _cell(avg["recall"])),
            row("MPJPE mm (matched)", lambda a: _cell(a.mpjpe_mm), _cell(avg["mpjpe_mm"])),
            row("MPJPE mm (JCSAT)", lambda a: _cell(a.mpjpe_jcsat_mm), _cell(avg["mpjpe_jcsat_mm"])),
            row("matched/annotated", lambda a: f"{a.matched}/{a.annotated}"),
            row("misses", lambda a: str(a.misses)),
            row("Recall@500mm %", lambda a: _cell(a.recall_500mm), _cell(avg["recall_500mm"])),
        ]
        widths = [max(len(r[c]) for r in table) for c in range(len(header))]
        lines.append(f"protocol: {score.protocol}")
        lines.extend("  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w) in enumerate(zip(r, widths)))
                     for r in table)
        lines.append("")
    return "\n".join(lines).rstrip("\n")

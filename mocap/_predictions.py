"""The exchange format for 3D pose predictions on Shelf / Campus: every method writes it, the evaluator
(:func:`mocap.evaluate_shelf`, ``python -m experiments.shelf_eval``) reads it.

In memory a prediction set is a :class:`PosePredictions`: flat arrays with one row per (frame, person),
in the order the method produced them (the ``"jcsat"`` protocol lets the first of several predictions
near one person win, so order is data). On disk it is **JSON lines** (UTF-8, one JSON object per line),
chosen because a method can write it incrementally, people can read and ``grep`` it, and a reader can
name the line of a mistake:

- line 1, the header: ``{"format": "mvmocap-pose-predictions", "version": 1, "skeleton": "SHELF15",
  "unit": "m", "frame_index": "actorsGT"}`` (written by :func:`write_predictions`; the reader checks
  every field, so a file in millimetres or another joint order is refused rather than misscored);
- every further line, one person in one frame: ``{"frame": f, "person": p, "joints": [[x, y, z], ...
  15 rows], "score": s}``. ``frame`` is the 0-based actorsGT frame index (image ``img_{f:06d}``; the
  Shelf test range is 300..600, *not* detection frame k = f - 300); ``person`` is the method's own
  track id (any integer; the evaluator matches by position, never by id); ``joints`` are
  :data:`geometry.SHELF15` positions in metres, world z up; ``score`` (optional, a float) is the
  method's confidence, kept but not used for scoring. A joint the method did not reconstruct is
  written ``null`` (or ``[0, 0, 0]``); both read back as (0, 0, 0), the 4DA/JCSAT convention the
  protocols understand (``docs/protocols.md``).

Example file::

    {"format": "mvmocap-pose-predictions", "version": 1, "skeleton": "SHELF15", "unit": "m", "frame_index": "actorsGT"}
    {"frame": 300, "person": 0, "joints": [[0.51, -0.12, 0.09], ..., [0.48, -0.05, 0.97]], "score": 0.93}
    {"frame": 300, "person": 1, "joints": [[1.72, 0.88, 0.10], ..., null, [1.70, 0.80, 0.95]]}

Frames without a line have no prediction (every annotated person there is a miss). Blank lines are
ignored. :func:`predictions_from_4dassoc` converts a 4D-association skeleton file (the method's
``skel.txt`` output, SKEL19, or a 15-joint ``gt.txt``) to this structure.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import NamedTuple

import numpy as np
from jaxtyping import Bool, Float, Int

import geometry

from ._shelf_campus import SHELF_DETECTION_FIRST_FRAME, load_4dassoc_skeletons

__all__ = [
    "PREDICTIONS_HEADER",
    "PosePredictions",
    "read_predictions",
    "write_predictions",
    "predictions_from_4dassoc",
    "suppress_duplicates",
]

PREDICTIONS_HEADER: dict[str, object] = {
    "format": "mvmocap-pose-predictions",
    "version": 1,
    "skeleton": "SHELF15",
    "unit": "m",
    "frame_index": "actorsGT",
}
"""The first line of every prediction file (see the module docstring)."""

_NUM_JOINTS = geometry.SHELF15.num_joints


class PosePredictions(NamedTuple):
    """3D pose predictions, one row per (frame, person), in the method's output order (NumPy).

    Build one with :meth:`create`, which validates; read and write with :func:`read_predictions` and
    :func:`write_predictions`.
    """

    frame: Int[np.ndarray, " n"]
    """actorsGT frame index of each row."""
    person: Int[np.ndarray, " n"]
    """The method's person / track id (not used for matching)."""
    joints: Float[np.ndarray, "n 15 3"]
    """SHELF15 positions in metres; (0, 0, 0) marks a joint the method did not reconstruct."""
    score: Float[np.ndarray, " n"] | None = None
    """Optional per-person confidence (all rows or none)."""

    @classmethod
    def create(cls, frame, person, joints, score=None) -> PosePredictions:
        """Validate and convert: ``frame``, ``person`` (n,) integers, ``joints`` (n, 15, 3) finite
        metres, ``score`` None or (n,) finite. Raises ``ValueError`` naming the problem."""
        joints = np.asarray(joints, dtype=np.float64)
        if joints.ndim != 3 or joints.shape[1:] != (_NUM_JOINTS, 3):
            raise ValueError(f"joints must have shape (n, {_NUM_JOINTS}, 3) (SHELF15, metres), got {joints.shape}")
        n = joints.shape[0]
        columns = {"frame": frame, "person": person}
        for name, value in columns.items():
            value = np.asarray(value)
            if value.shape != (n,) or not (value.size == 0 or np.issubdtype(value.dtype, np.integer)):
                raise ValueError(f"{name} must be ({n},) integers, got {value.dtype} {value.shape}")
            columns[name] = value.astype(np.int64)
        if not np.all(np.isfinite(joints)):
            row = int(np.argmax(~np.all(np.isfinite(joints), axis=(1, 2))))
            raise ValueError(f"joints of row {row} (frame {columns['frame'][row]}) contain NaN or inf; "
                             "write a missing joint as (0, 0, 0)")
        if np.any(columns["frame"] < 0):
            raise ValueError("frame indices must be non-negative actorsGT indices")
        if score is not None:
            score = np.asarray(score, dtype=np.float64)
            if score.shape != (n,) or not np.all(np.isfinite(score)):
                raise ValueError(f"score must be None or ({n},) finite values, got shape {score.shape}")
        return cls(columns["frame"], columns["person"], joints, score)

    @property
    def num_predictions(self) -> int:
        return self.joints.shape[0]

    def in_frame(self, frame: int) -> Float[np.ndarray, "k 15 3"]:
        """The joints predicted in actorsGT frame ``frame``, in output order."""
        return self.joints[self.frame == frame]

    def by_person(self, frames: Int[np.ndarray, " F"]) -> tuple[Int[np.ndarray, " P"], Float[np.ndarray, "P F 15 3"],
                                                              Bool[np.ndarray, "P F"]]:
        """The rows as one array per person over ``frames`` (increasing): the person ids (sorted), their joints
        (zeros where a person has no row) and where they have one. Raises ``ValueError`` for a row outside
        ``frames`` or two rows of one person in one frame."""
        frames = np.asarray(frames)
        persons, person_index = np.unique(self.person, return_inverse=True)
        frame_index = np.searchsorted(frames, self.frame)
        outside = (frame_index >= len(frames)) | (frames[np.minimum(frame_index, len(frames) - 1)] != self.frame)
        if outside.any():
            raise ValueError(f"prediction frame {self.frame[np.argmax(outside)]} is not among the {len(frames)} frames")
        joints = np.zeros((len(persons), len(frames), _NUM_JOINTS, 3))
        present = np.zeros((len(persons), len(frames)), bool)
        if len(np.unique(person_index * len(frames) + frame_index)) < self.num_predictions:
            raise ValueError("two rows of one person in one frame")
        joints[person_index, frame_index] = self.joints
        present[person_index, frame_index] = True
        return persons, joints, present


def write_predictions(path: str | os.PathLike, predictions: PosePredictions) -> None:
    """Write ``predictions`` as a JSON-lines prediction file (header first, rows in order)."""
    predictions = PosePredictions.create(*predictions)
    lines = [json.dumps(PREDICTIONS_HEADER)]
    for row in range(predictions.num_predictions):
        record = {
            "frame": int(predictions.frame[row]),
            "person": int(predictions.person[row]),
            # repr-exact floats: a round trip reproduces the arrays bit for bit
            "joints": predictions.joints[row].tolist(),
        }
        if predictions.score is not None:
            record["score"] = float(predictions.score[row])
        lines.append(json.dumps(record))
    Path(path).write_text("\n".join(lines) + "\n")


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _parse_joints(value) -> np.ndarray | str:
    """(15, 3) array, or a message saying what is wrong."""
    if not isinstance(value, list) or len(value) != _NUM_JOINTS:
        return f"'joints' must be a list of {_NUM_JOINTS} [x, y, z] rows (SHELF15)"
    rows = []
    for j, xyz in enumerate(value):
        if xyz is None:
            rows.append((0.0, 0.0, 0.0))
        elif isinstance(xyz, list) and len(xyz) == 3 and all(_is_number(c) for c in xyz):
            rows.append(tuple(float(c) for c in xyz))
        else:
            return f"joint {j} ({geometry.SHELF15.joints[j]}) must be null or 3 finite numbers, got {xyz!r}"
    return np.array(rows)


def read_predictions(path: str | os.PathLike) -> PosePredictions:
    """Read a JSON-lines prediction file (format in the module docstring).

    Raises ``ValueError`` with the file name and the 1-based line number for a wrong or missing
    header, invalid JSON, a missing or mistyped field, a joint list of the wrong size, non-finite
    values, or a score on some rows but not others.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as err:
        raise ValueError(f"{path}: not a UTF-8 text file ({err})") from err
    frames, persons, joints, scores = [], [], [], []
    header_seen = False
    score_line = None  # (line number, has score) of the first row, for the all-or-none rule
    for number, line in enumerate(text.splitlines(), start=1):
        if not line.strip():
            continue

        def error(message: str, number=number) -> ValueError:
            return ValueError(f"{path}, line {number}: {message}")

        try:
            record = json.loads(line)
        except json.JSONDecodeError as err:
            raise error(f"invalid JSON ({err.msg} at column {err.colno})") from None
        if not isinstance(record, dict):
            raise error(f"expected a JSON object, got {type(record).__name__}")
        if not header_seen:
            wrong = {k: record.get(k) for k, v in PREDICTIONS_HEADER.items() if record.get(k) != v}
            if wrong:
                raise error(f"not a prediction-file header: expected {PREDICTIONS_HEADER}, differs in {wrong}")
            header_seen = True
            continue
        unknown = set(record) - {"frame", "person", "joints", "score"}
        if unknown:
            raise error(f"unknown fields {sorted(unknown)}")
        for name in ("frame", "person"):
            if not _is_int(record.get(name)):
                raise error(f"'{name}' must be an integer, got {record.get(name)!r}")
        if record["frame"] < 0:
            raise error(f"'frame' must be a non-negative actorsGT index, got {record['frame']}")
        parsed = _parse_joints(record.get("joints"))
        if isinstance(parsed, str):
            raise error(parsed)
        has_score = "score" in record
        if has_score and not _is_number(record["score"]):
            raise error(f"'score' must be a finite number, got {record['score']!r}")
        if score_line is None:
            score_line = (number, has_score)
        elif has_score != score_line[1]:
            raise error(f"'score' must be given on every row or none (line {score_line[0]} "
                        f"{'has' if score_line[1] else 'has no'} score)")
        frames.append(record["frame"])
        persons.append(record["person"])
        joints.append(parsed)
        if has_score:
            scores.append(float(record["score"]))
    if not header_seen:
        raise ValueError(f"{path}, line 1: empty file, expected the header {PREDICTIONS_HEADER}")
    return PosePredictions.create(
        np.array(frames, dtype=np.int64),
        np.array(persons, dtype=np.int64),
        np.array(joints).reshape(-1, _NUM_JOINTS, 3),
        np.array(scores) if score_line is not None and score_line[1] else None,
    )


def suppress_duplicates(predictions: PosePredictions, min_distance: float) -> PosePredictions:
    """Pose non-maximum suppression: one prediction per person, the most confident first.

    Within each frame the rows are put in order of decreasing ``score`` (ties keep their order), and a row
    whose mean distance to a row already kept in that frame, over the joints both reconstruct, is below
    ``min_distance`` metres is dropped as a second prediction of the same person. Two rows without a
    common joint are never duplicates. Frames keep their order of first appearance. ``min_distance = 0``
    only reorders. The order matters under the ``"jcsat"`` protocol, where the first of several
    predictions near one person is the one scored.
    """
    if predictions.score is None:
        raise ValueError("suppress_duplicates ranks rows by score; these predictions have none")
    if not (min_distance >= 0.0 and math.isfinite(min_distance)):
        raise ValueError(f"min_distance must be a finite number of metres >= 0, got {min_distance}")
    reconstructed = np.any(predictions.joints != 0.0, axis=-1)
    kept_rows: list[int] = []
    for frame in dict.fromkeys(predictions.frame.tolist()):
        rows = np.flatnonzero(predictions.frame == frame)
        rows = rows[np.argsort(-predictions.score[rows], kind="stable")]
        n = len(rows)
        joints = np.broadcast_to(predictions.joints[rows][:, None], (n, n, _NUM_JOINTS, 3))
        common = reconstructed[rows][:, None] & reconstructed[rows][None]
        # NaN for a pair without a common joint, which no comparison below takes for a duplicate.
        distance = np.asarray(geometry.mpjpe(joints, np.swapaxes(joints, 0, 1), common))
        kept: list[int] = []
        for i in range(n):
            if not np.any(distance[i, kept] < min_distance):
                kept.append(i)
        kept_rows += rows[kept].tolist()
    return PosePredictions(*(column[kept_rows] for column in predictions))


def predictions_from_4dassoc(
    path: str | os.PathLike, first_frame: int = SHELF_DETECTION_FIRST_FRAME
) -> PosePredictions:
    """Convert a 4D-association skeleton file to predictions (frame k -> actorsGT ``first_frame + k``).

    A SKEL19 file (4DA's ``skel.txt``) goes through :func:`geometry.to_shelf15` with the 4DA head rule,
    applied to the stored positions as 4DA's ``MappingToShelf`` does (inactive joints are stored as
    zeros and stay as they are; joints derived from them are not re-zeroed, like 4DA). A 15-joint
    file (``gt.txt``) is taken as SHELF15 unchanged. Persons keep the file order and ids.
    """
    frames = load_4dassoc_skeletons(path)
    people = [(f, p) for f, persons in enumerate(frames) for p in persons]
    num_joints = {p.joints.shape[0] for _, p in people}
    if not people:
        joints = np.zeros((0, _NUM_JOINTS, 3))
    elif num_joints == {geometry.SKEL19.num_joints}:
        joints = np.asarray(geometry.to_shelf15(np.stack([p.joints for _, p in people]), geometry.SKEL19, "4da"))
    elif num_joints == {_NUM_JOINTS}:
        joints = np.stack([p.joints for _, p in people])
    else:
        raise ValueError(f"{path}: expected SKEL19 (19 joints) or SHELF15 (15 joints), got {sorted(num_joints)}")
    return PosePredictions.create(
        np.array([first_frame + f for f, _ in people], dtype=np.int64),
        np.array([p.person_id for _, p in people], dtype=np.int64),
        joints,
    )

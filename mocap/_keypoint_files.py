"""2D keypoint files of the standard detectors, read into (and written from) BODY25 :class:`Detections`.

Formats (x, y in pixels of the image as the detector wrote them, no conversion applied; a confidence per
keypoint, not limited to 1):

- **OpenPose JSON** (``--write_json``): one ``<name>_keypoints.json`` per image,
  ``{"version": .., "people": [{"pose_keypoints_2d": [x0, y0, c0, x1, y1, c1, ...], ...}, ...]}``, in the
  joint order of :data:`geometry.BODY25` (25 keypoints, 75 numbers) or of OpenPose's COCO model, ``COCO18``
  (18 keypoints, 54 numbers: nose, neck, r_shoulder, r_elbow, r_wrist, l_shoulder, l_elbow, l_wrist, r_hip,
  r_knee, r_ankle, l_hip, l_knee, l_ankle, r_eye, l_eye, r_ear, l_ear). Other keys are ignored.
- **COCO keypoint results** (mmpose, RTMPose): one JSON list per view of
  ``{"image_id": int or str, "category_id": 1, "keypoints": [x, y, s] * 17, "score": float}``, in the joint
  order of :data:`geometry.COCO17`. ``category_id`` and the person ``score`` are not read: the candidates
  carry the per-keypoint scores s. The image_ids are the frames, in natural order of their text (``2``
  before ``10``); an int and a str with the same text are one image.

In both, a keypoint with confidence 0 was not detected (OpenPose writes 0, 0, 0) and is no candidate; a
negative or NaN confidence is an error. The keypoint format is recognised from the count (17, 18 or 25
keypoints; :data:`KEYPOINT_FORMAT_JOINTS`), and all files read together must agree on it.

Conversion to BODY25 (:func:`detections_from_keypoints`): each person's detected keypoint of a type is a
candidate of that BODY25 joint type. Of the BODY25 joints a format lacks, neck is derived as the mean of the
shoulders and mid_hip as the mean of the hips (only where both are detected, with the smaller of their
confidences); the others have no candidates (COCO has no feet). The PAF of a pair is the
same-person indicator (1.0 where both candidates come from one detected person, else 0.0): the files hold
no affinities, and this keeps tools that draw limbs working.

Layouts (:func:`load_keypoint_detections`): a folder with one subfolder of OpenPose files per view
(EasyMocap's ``openpose/<camera>/``) or with one COCO results file ``<view>.json`` per view. Frames are
aligned across views by position (the k-th file of every view, in natural order of the file names) or by
frame number (the last integer of the file name before ``_keypoints.json``, or of the image_id).
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np

import geometry

from ._detections import BODY25_PAF_PAIRS, Detections

__all__ = [
    "DetectionFileError",
    "KEYPOINT_FORMAT_JOINTS",
    "KeypointDetections",
    "detections_from_keypoints",
    "load_keypoint_detections",
    "write_coco_keypoints",
    "write_openpose_keypoints",
]

KEYPOINT_FORMAT_JOINTS: dict[str, tuple[str, ...]] = {
    "BODY25": geometry.BODY25.joints,
    "COCO18": ("nose", "neck", "r_shoulder", "r_elbow", "r_wrist", "l_shoulder", "l_elbow", "l_wrist", "r_hip",
               "r_knee", "r_ankle", "l_hip", "l_knee", "l_ankle", "r_eye", "l_eye", "r_ear", "l_ear"),
    "COCO17": geometry.COCO17.joints,
}
"""The keypoint formats the files may hold: joint names (the :mod:`geometry` vocabulary) in file order."""

_DERIVED: dict[str, tuple[str, str]] = {"neck": ("l_shoulder", "r_shoulder"), "mid_hip": ("l_hip", "r_hip")}
"""BODY25 joints a format may lack, derived as the midpoint of two joints it has."""

_BODY25_OF = {
    fmt: np.array([geometry.BODY25.index(n) for n in names]) for fmt, names in KEYPOINT_FORMAT_JOINTS.items()}
"""Per format, the BODY25 index of each of its keypoints: the one table behind reading and writing."""

_DERIVED_OF = {
    fmt: tuple((geometry.BODY25.index(joint), geometry.BODY25.index(a), geometry.BODY25.index(b))
               for joint, (a, b) in _DERIVED.items() if joint not in names)
    for fmt, names in KEYPOINT_FORMAT_JOINTS.items()
}
"""Per format, (BODY25 joint, from joint a, from joint b) for each joint derived on reading."""

_FORMAT_OF_LENGTH = {len(names): fmt for fmt, names in KEYPOINT_FORMAT_JOINTS.items()}
_OPENPOSE_SUFFIX = "_keypoints.json"
_NUM_BODY25 = geometry.BODY25.num_joints


class DetectionFileError(ValueError):
    """A keypoint file or folder that cannot be read; the one-line message names the file (and line or person)."""


class KeypointDetections(NamedTuple):
    """Detections read by :func:`load_keypoint_detections`."""

    detections: list[list[Detections]]
    """BODY25 detections ``[frame][view]`` (no ``person_ids``; PAFs are the same-person indicator)."""
    views: tuple[str, ...]
    """The view (camera) names, in the order of the second index of ``detections``."""
    frame_names: tuple[str, ...]
    """Per frame, the first view's name for it: the file name without ``_keypoints.json``, or the image_id."""
    keypoint_format: str
    """The files' keypoint format (a key of :data:`KEYPOINT_FORMAT_JOINTS`); ``"unknown"`` when it was
    ``"auto"`` and no file holds a person."""
    dropped_frames: tuple[int, ...]
    """``frames="name"``: the frame numbers some view has but not all, left out; empty for ``"index"``."""

    @property
    def frame_numbers(self) -> np.ndarray:
        """Each frame's number, as ``frames="name"`` aligns them: the last integer of its name when every name has
        one and they increase (OpenPose's ``000300_keypoints.json`` is frame 300; a COCO image_id), else its
        position 0, 1, ... (int64)."""
        numbers = [_name_number(name) for name in self.frame_names]
        if None not in numbers and all(a < b for a, b in zip(numbers, numbers[1:])):
            return np.array(numbers, np.int64)
        return np.arange(len(self.frame_names), dtype=np.int64)


# ---------------------------------------------------------------------------------------------
# Conversion


def _keypoint_problem(keypoints: np.ndarray) -> str | None:
    """What is wrong with one person's ``(K, 3)`` keypoints of a known format, or None."""
    names = KEYPOINT_FORMAT_JOINTS[_FORMAT_OF_LENGTH[len(keypoints)]]
    bad_confidence = ~(keypoints[:, 2] >= 0.0)  # NaN included
    if bad_confidence.any():
        k = int(np.argmax(bad_confidence))
        return f"keypoint {k} ({names[k]}) has confidence {keypoints[k, 2]}, expected >= 0"
    bad_position = (keypoints[:, 2] > 0.0) & ~np.isfinite(keypoints[:, :2]).all(-1)
    if bad_position.any():
        k = int(np.argmax(bad_position))
        return f"keypoint {k} ({names[k]}) has a non-finite position {tuple(keypoints[k, :2].tolist())}"
    return None


def detections_from_keypoints(keypoints: np.ndarray, keypoint_format: str) -> Detections:
    """BODY25 detections from one view's ``(people, K, 3)`` keypoints (x, y pixels, confidence) in
    ``keypoint_format`` (a key of :data:`KEYPOINT_FORMAT_JOINTS`); see the module docstring for the rules.

    Candidates of a joint type come in person order. Raises ``ValueError`` for a wrong shape, a negative or
    NaN confidence, or a non-finite position of a detected keypoint.
    """
    if keypoint_format not in KEYPOINT_FORMAT_JOINTS:
        raise ValueError(f"unknown keypoint_format {keypoint_format!r}; known: {tuple(KEYPOINT_FORMAT_JOINTS)}")
    kp = np.asarray(keypoints, np.float64)
    num_keypoints = len(KEYPOINT_FORMAT_JOINTS[keypoint_format])
    if kp.ndim != 3 or kp.shape[1:] != (num_keypoints, 3):
        raise ValueError(f"{keypoint_format} keypoints should be (people, {num_keypoints}, 3), got {kp.shape}")
    for p, person in enumerate(kp):
        problem = _keypoint_problem(person)
        if problem:
            raise ValueError(f"person {p}: {problem}")
    body = np.zeros((len(kp), _NUM_BODY25, 3))
    body[:, _BODY25_OF[keypoint_format]] = kp
    for joint, a, b in _DERIVED_OF[keypoint_format]:
        both = (body[:, a, 2] > 0.0) & (body[:, b, 2] > 0.0)
        body[both, joint, :2] = (body[both, a, :2] + body[both, b, :2]) / 2.0
        body[both, joint, 2] = np.minimum(body[both, a, 2], body[both, b, 2])
    detected = body[..., 2] > 0.0  # (people, 25)
    owner = tuple(np.flatnonzero(detected[:, j]) for j in range(_NUM_BODY25))
    joints = tuple(body[owner[j], j] for j in range(_NUM_BODY25))
    pafs = tuple((owner[a][:, None] == owner[b][None, :]).astype(np.float64) for a, b in BODY25_PAF_PAIRS)
    return Detections(joints, pafs)


# ---------------------------------------------------------------------------------------------
# Reading


class _Frame(NamedTuple):
    """One view's keypoints in one image, as read (not yet converted)."""

    name: str
    where: str  # the file, and for COCO results the image_id, for messages
    people: tuple[np.ndarray, ...]  # (K, 3) each; K may still disagree with the other files
    labels: tuple[str, ...]  # per person, for messages: "person k" (OpenPose) or "entry i" (COCO)


def _natural_key(name: str) -> tuple:
    """Sort key putting ``frame2`` before ``frame10``: digit runs compare as numbers (odd split positions)."""
    return tuple(int(part) if i % 2 else part for i, part in enumerate(re.split(r"([0-9]+)", name)))


def _load_json(path: Path):
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as err:
        raise DetectionFileError(f"{path}, line {err.lineno}: malformed JSON ({err.msg})") from None
    except UnicodeDecodeError as err:
        raise DetectionFileError(f"{path}: not a UTF-8 text file ({err.reason})") from None


def _keypoint_array(where: str, label: str, values) -> np.ndarray:
    """One person's flat ``[x, y, c, ...]`` list as ``(K, 3)``, K one of the known formats' counts."""
    counts = " or ".join(str(3 * n) for n in sorted(_FORMAT_OF_LENGTH))
    if not isinstance(values, list):
        raise DetectionFileError(f"{where}, {label}: keypoints should be a list of {counts} numbers")
    try:
        flat = np.asarray(values, np.float64)  # JSON null becomes NaN, caught as a NaN confidence or position
    except (TypeError, ValueError):
        raise DetectionFileError(f"{where}, {label}: non-numeric keypoint values") from None
    if flat.ndim != 1 or len(flat) % 3 or len(flat) // 3 not in _FORMAT_OF_LENGTH:
        raise DetectionFileError(
            f"{where}, {label}: {len(values)} keypoint values, expected {counts} "
            f"({' / '.join(f'{len(n)} {f}' for f, n in KEYPOINT_FORMAT_JOINTS.items())} keypoints x 3)")
    keypoints = flat.reshape(-1, 3)
    problem = _keypoint_problem(keypoints)
    if problem:
        raise DetectionFileError(f"{where}, {label}: {problem}")
    return keypoints


def _read_openpose_file(path: Path) -> _Frame:
    data = _load_json(path)
    people = data.get("people") if isinstance(data, dict) else None
    if not isinstance(people, list):
        raise DetectionFileError(f"{path}: expected an object with a list \"people\" (OpenPose JSON)")
    arrays = []
    for k, person in enumerate(people):
        if not isinstance(person, dict) or "pose_keypoints_2d" not in person:
            raise DetectionFileError(f"{path}, person {k}: no \"pose_keypoints_2d\"")
        arrays.append(_keypoint_array(str(path), f"person {k}", person["pose_keypoints_2d"]))
    labels = tuple(f"person {k}" for k in range(len(arrays)))
    return _Frame(path.name[: -len(_OPENPOSE_SUFFIX)], str(path), tuple(arrays), labels)


def _read_coco_file(path: Path) -> list[_Frame]:
    data = _load_json(path)
    if not isinstance(data, list):
        raise DetectionFileError(f"{path}: expected a list of keypoint results (COCO results format)")
    images: dict[str, list[tuple[str, np.ndarray]]] = {}
    for i, entry in enumerate(data):
        if not isinstance(entry, dict) or "image_id" not in entry or "keypoints" not in entry:
            raise DetectionFileError(f"{path}, entry {i}: expected an object with \"image_id\" and \"keypoints\"")
        image_id = entry["image_id"]
        if isinstance(image_id, bool) or not isinstance(image_id, (int, str)):
            raise DetectionFileError(f"{path}, entry {i}: image_id should be an int or a str, got {image_id!r}")
        label = f"entry {i}"
        images.setdefault(str(image_id), []).append((label, _keypoint_array(str(path), label, entry["keypoints"])))
    return [
        _Frame(name, f"{path}, image_id {name}", tuple(kp for _, kp in images[name]),
               tuple(label for label, _ in images[name]))
        for name in sorted(images, key=_natural_key)
    ]


def _read_view(source: Path) -> list[_Frame]:
    if source.is_dir():
        files = sorted(source.glob(f"*{_OPENPOSE_SUFFIX}"), key=lambda p: _natural_key(p.name))
        return [_read_openpose_file(p) for p in files]
    return _read_coco_file(source)


def _view_sources(root: Path, views: tuple[str, ...] | None) -> tuple[tuple[str, ...], list[Path]]:
    """The view names and, per view, its OpenPose folder or COCO results file."""
    if not root.is_dir():
        raise DetectionFileError(f"{root}: no such folder")
    if views is None:
        visible = sorted((p for p in root.iterdir() if not p.name.startswith(".")), key=lambda p: _natural_key(p.name))
        sources = [p for p in visible if p.is_dir()] or [p for p in visible if p.suffix == ".json" and p.is_file()]
        if not sources:
            raise DetectionFileError(f"{root}: no view subfolders (OpenPose JSON) or <view>.json files (COCO results)")
        return tuple(p.name if p.is_dir() else p.stem for p in sources), sources
    if isinstance(views, str):
        raise ValueError(f"views should be a sequence of view names, got the string {views!r}")
    sources = []
    for view in views:
        folder, file = root / view, root / f"{view}.json"
        if not (folder.is_dir() or file.is_file()):
            raise DetectionFileError(f"{folder}: view {view!r} has neither this folder nor the file {file.name}")
        sources.append(folder if folder.is_dir() else file)
    return tuple(views), sources


def _keypoint_format(per_view: list[list[_Frame]], keypoint_format: str) -> str:
    """The format every person of every file has: ``keypoint_format``, or with ``"auto"`` the first person's."""
    expected, origin = (None, "") if keypoint_format == "auto" else (keypoint_format, "keypoint_format")
    for frames in per_view:
        for frame in frames:
            for label, keypoints in zip(frame.labels, frame.people):
                fmt = _FORMAT_OF_LENGTH[len(keypoints)]
                if expected is None:
                    expected, origin = fmt, f"{frame.where}, {label}"
                elif fmt != expected:
                    raise DetectionFileError(
                        f"{frame.where}, {label}: {len(keypoints)} keypoints ({fmt}), but {origin} is {expected}")
    return "unknown" if expected is None else expected


def _name_number(name: str) -> int | None:
    """The frame number in a frame's name: its last integer (None: there is none)."""
    digits = re.findall(r"[0-9]+", name)
    return int(digits[-1]) if digits else None


def _frame_number(frame: _Frame) -> int:
    number = _name_number(frame.name)
    if number is None:
        raise DetectionFileError(f"{frame.where}: no frame number in the name {frame.name!r} (frames='name')")
    return number


def load_keypoint_detections(
    path: str | os.PathLike,
    *,
    views: tuple[str, ...] | None = None,
    keypoint_format: str = "auto",
    frames: str = "index",
) -> KeypointDetections:
    """Read a folder of OpenPose JSON or COCO keypoint results (module docstring) as BODY25 detections.

    ``path`` holds one subfolder of ``*_keypoints.json`` files per view, or one ``<view>.json`` COCO results
    file per view. ``views`` (e.g. the calibration's camera names, in rig order) selects and orders them; by
    default all subfolders (else all ``.json`` files), in natural order of their names; hidden ones (a
    leading ``.``) are skipped. ``keypoint_format`` is ``"auto"`` (from the keypoint count) or a key of
    :data:`KEYPOINT_FORMAT_JOINTS` that every person must have.

    ``frames="index"`` pairs the k-th frame of every view (files or image_ids in natural order) and needs
    equal frame counts; ``frames="name"`` pairs equal frame numbers (the last integer of the name) and keeps
    the frames every view has, in increasing number, listing the others in ``dropped_frames``. A COCO
    results file lists no image where nothing was detected, so such a frame is missing from that view.

    Raises :class:`DetectionFileError` (one line naming the file, and the line, person or entry) for a
    missing view, differing frame counts under ``"index"``, a keypoint count that is not 17, 18 or 25 x 3 or
    disagrees with ``keypoint_format`` or the other files, malformed JSON, a negative or NaN confidence, a
    non-finite position of a detected keypoint, a frame without a number under ``"name"`` (or two with one
    number), and no frames at all.
    """
    if keypoint_format != "auto" and keypoint_format not in KEYPOINT_FORMAT_JOINTS:
        raise ValueError(
            f"keypoint_format should be 'auto' or one of {tuple(KEYPOINT_FORMAT_JOINTS)}, got {keypoint_format!r}")
    if frames not in ("index", "name"):
        raise ValueError(f"frames should be 'index' or 'name', got {frames!r}")
    root = Path(path)
    names, sources = _view_sources(root, views)
    per_view = [_read_view(source) for source in sources]
    fmt = _keypoint_format(per_view, keypoint_format)
    dropped: tuple[int, ...] = ()
    if frames == "index":
        for source, view_frames in zip(sources, per_view):
            if len(view_frames) != len(per_view[0]):
                raise DetectionFileError(
                    f"{source}: {len(view_frames)} frames, but {sources[0]} has {len(per_view[0])} "
                    "(frames='name' aligns by frame number)")
        aligned = list(zip(*per_view))
    else:
        numbered = []
        for view_frames in per_view:
            by_number: dict[int, _Frame] = {}
            for frame in view_frames:
                other = by_number.setdefault(_frame_number(frame), frame)
                if other is not frame:
                    raise DetectionFileError(f"{frame.where}: same frame number as {other.where} (frames='name')")
            numbered.append(by_number)
        common = set.intersection(*(set(n) for n in numbered))
        dropped = tuple(sorted(set.union(*(set(n) for n in numbered)) - common))
        aligned = [tuple(n[number] for n in numbered) for number in sorted(common)]
    if not aligned:
        raise DetectionFileError(f"{root}: no frames" + (" in every view (frames='name')" if dropped else ""))
    # With no person anywhere every frame converts to empty detections, whatever the format.
    converted = "BODY25" if fmt == "unknown" else fmt
    nobody = np.zeros((0, len(KEYPOINT_FORMAT_JOINTS[converted]), 3))
    detections = [
        [detections_from_keypoints(np.stack(frame.people) if frame.people else nobody, converted) for frame in row]
        for row in aligned
    ]
    return KeypointDetections(detections, names, tuple(row[0].name for row in aligned), fmt, dropped)


# ---------------------------------------------------------------------------------------------
# Writing


def _people(det: Detections, where: str) -> tuple[np.ndarray, np.ndarray]:
    """Pack one view's candidates into people: ``(P, 25, 3)`` BODY25 keypoints (zeros: none) and ``(P,)`` ids.

    Without ``person_ids``, person k holds the k-th candidate of every joint type (id -1). With them, one
    person per known id; a second candidate of one id and joint type, and each spurious (-1) candidate, go to
    extra people after them (id -1), in candidate order. Candidates with confidence 0 are dropped first.
    """
    if det.num_joint_types != _NUM_BODY25:
        raise ValueError(f"{where}: {det.num_joint_types} joint types, expected BODY25's {_NUM_BODY25}")
    kept, ids = [], []
    for j, cand in enumerate(det.joints):
        cand = np.asarray(cand, np.float64).reshape(-1, 3)
        if not (np.all(cand[:, 2] >= 0.0) and np.all(np.isfinite(cand))):
            raise ValueError(f"{where}, joint {geometry.BODY25.joints[j]}: a candidate has a non-finite value "
                             "or a negative confidence")
        detected = cand[:, 2] > 0.0
        kept.append(cand[detected])
        own_ids = np.full(len(cand), -1) if det.person_ids is None else np.asarray(det.person_ids[j])
        ids.append(own_ids[detected])
    known = np.unique(np.concatenate(ids + [np.zeros(0, int)]))
    known = known[known >= 0]
    rows = []
    for pid in ids:
        _, first = np.unique(pid, return_index=True)
        own = (pid >= 0) & np.isin(np.arange(len(pid)), first)
        row = np.empty(len(pid), int)
        row[own] = np.searchsorted(known, pid[own])
        row[~own] = len(known) + np.arange(np.count_nonzero(~own))
        rows.append(row)
    num_people = max([len(known)] + [int(r.max()) + 1 for r in rows if len(r)])
    body = np.zeros((num_people, _NUM_BODY25, 3))
    for j, (row, cand) in enumerate(zip(rows, kept)):
        body[row, j] = cand
    person_ids = np.concatenate([known, np.full(num_people - len(known), -1)])
    return body, person_ids


def _checked_names(detections: list[list[Detections]], views: tuple[str, ...],
                   frame_numbers: Sequence[int] | np.ndarray | None) -> tuple[tuple[str, ...], list[int]]:
    """The view names and the frame numbers (default 0, 1, ...) after checking them against ``detections``."""
    if isinstance(views, str) or len(set(views)) != len(views):
        raise ValueError(f"views should be distinct view names, got {views!r}")
    for f, frame in enumerate(detections):
        if len(frame) != len(views):
            raise ValueError(f"frame {f} has {len(frame)} views, but {len(views)} view names were given")
    numbers = list(range(len(detections))) if frame_numbers is None else [int(n) for n in frame_numbers]
    if len(numbers) != len(detections) or any(n < 0 for n in numbers) or len(set(numbers)) != len(numbers):
        raise ValueError(f"frame_numbers should be {len(detections)} distinct numbers >= 0, got {frame_numbers!r}")
    return tuple(views), numbers


def write_openpose_keypoints(
    folder: str | os.PathLike, detections: list[list[Detections]], views: tuple[str, ...],
    frame_numbers: Sequence[int] | np.ndarray | None = None,
) -> None:
    """Write BODY25 detections ``[frame][view]`` as OpenPose JSON: ``folder/<view>/<number:06d>_keypoints.json``,
    where frame f's number is ``frame_numbers[f]`` (default f).

    Candidates are packed into ``"people"``: person k holds the k-th candidate of every joint type (zeros
    where a type has fewer), or, when ``person_ids`` are present, one person per id (``"person_id": [id]``),
    then the spurious and surplus candidates. Candidates with confidence exactly 0 cannot be represented
    (0 means "not detected") and are dropped. PAFs are not written. Reading the folder back gives the same
    candidates per frame, view and joint type (in another order). Each file is written atomically; other
    files in the folder are left as they are.
    """
    views, numbers = _checked_names(detections, views, frame_numbers)
    for f, frame in enumerate(detections):
        for view, det in zip(views, frame):
            body, ids = _people(det, f"frame {f}, view {view!r}")
            people = [{"person_id": [int(i)], "pose_keypoints_2d": kp.ravel().tolist()} for kp, i in zip(body, ids)]
            text = json.dumps({"version": 1.3, "people": people}, separators=(",", ":"), allow_nan=False)
            geometry.replace_file(Path(folder) / view / f"{numbers[f]:06d}{_OPENPOSE_SUFFIX}",
                                  lambda temporary: temporary.write_text(text + "\n", encoding="utf-8"))


def write_coco_keypoints(
    folder: str | os.PathLike, detections: list[list[Detections]], views: tuple[str, ...],
    frame_numbers: Sequence[int] | np.ndarray | None = None,
) -> None:
    """Write BODY25 detections ``[frame][view]`` as COCO keypoint results: ``folder/<view>.json``, one entry
    (line) per person, ``image_id`` = ``frame_numbers[f]`` (default f), ``category_id`` 1, the 17
    :data:`geometry.COCO17` keypoints and ``score`` = the mean confidence of the person's detected keypoints.

    People are packed as by :func:`write_openpose_keypoints`; the other BODY25 joints (neck, mid_hip, feet)
    are not written, and a person left with no keypoint is left out. A view where nobody is left in a frame
    gets one entry of zeros (score 0, no candidates when read), so that the frame stays in its file.
    Candidates with confidence exactly 0 are dropped. Reading back gives the same candidates of the 17 COCO
    joints, plus neck and mid_hip derived from each written person. Each file is written atomically.
    """
    views, numbers = _checked_names(detections, views, frame_numbers)
    coco = _BODY25_OF["COCO17"]
    for v, view in enumerate(views):
        lines = []
        for f, frame in enumerate(detections):
            body, _ = _people(frame[v], f"frame {f}, view {view!r}")
            people = [kp for kp in body[:, coco] if np.any(kp[:, 2] > 0.0)] or [np.zeros((len(coco), 3))]
            for kp in people:
                detected = kp[:, 2] > 0.0
                score = float(kp[detected, 2].mean()) if detected.any() else 0.0
                entry = {"image_id": numbers[f], "category_id": 1, "keypoints": kp.ravel().tolist(), "score": score}
                lines.append(json.dumps(entry, separators=(",", ":"), allow_nan=False))
        text = "[\n" + ",\n".join(lines) + "\n]\n"
        geometry.replace_file(Path(folder) / f"{view}.json",
                              lambda temporary: temporary.write_text(text, encoding="utf-8"))

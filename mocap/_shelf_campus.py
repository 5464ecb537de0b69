"""Loaders for the real Shelf and Campus data (TUM CAMP, Belagiannis et al., CVPR 2014).

Data layout (``data_root`` is the folder with ``shelf/`` and ``campus/``; see its README.md):

- ``shelf/actorsGT.mat``: the official 3D ground truth, 4 actors x 3200 frames, Shelf14 joints, metres.
- ``shelf/4d_association/{gt,skel}.txt``: 3D skeletons in the 4D-association (4DA, Zhang et al.,
  CVPR 2020) text format, for actorsGT frames 300..600.
- ``shelf/4d_association/detection/{view}.txt``: OpenPose BODY25 candidates and part affinities per
  view, 4DA text format; detection frame k is actorsGT frame 300 + k.
- ``{shelf,campus}/calibration_*.json``: VoxelPose camera tables. Copies ship in
  ``mocap/assets/calibration`` so the camera rigs load without the data folder.

Everything here is NumPy (the cameras excepted, which are :class:`geometry.Camera` pytrees). A
malformed file raises ``ValueError`` naming the file and the line (text) or key (MATLAB).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import NamedTuple

import numpy as np
import scipy.io
from jaxtyping import Bool, Float, Int

import geometry

from ._detections import BODY25_PAF_PAIRS, Detections

__all__ = [
    "SHELF_NUM_VIEWS",
    "SHELF_DETECTION_FIRST_FRAME",
    "FOUR_D_ASSOCIATION_PAF_EXPONENT",
    "PersonSkeleton",
    "shelf_cameras",
    "campus_cameras",
    "shelf_test_frames",
    "campus_test_frames",
    "load_shelf_ground_truth",
    "load_4dassoc_skeletons",
    "load_4dassoc_detections",
    "load_shelf_detections",
]

SHELF_NUM_VIEWS = 5
SHELF_DETECTION_FIRST_FRAME = 300
"""actorsGT frame index of detection frame 0 (the first frame of the standard test range)."""
FOUR_D_ASSOCIATION_PAF_EXPONENT = 0.2
"""4DA's ``ParseDetections`` raises every stored PAF score to this power after reading; pass it as
``paf_exponent`` to reproduce 4DA's inputs exactly (it flattens the scores towards 1)."""

_BODY25_SKEL_TYPE = 4  # 4DA's SkelType enum value for BODY25
_BODY25_NUM_JOINTS = 25
_ASSETS = Path(__file__).resolve().parent / "assets" / "calibration"


class PersonSkeleton(NamedTuple):
    """One person in one frame of a 4DA skeleton file."""

    person_id: int
    """Identity as stored (in the Shelf gt.txt, the actorsGT actor index 0..3)."""
    joints: np.ndarray
    """(J, 3) positions in metres; inactive joints are stored as 0."""
    active: np.ndarray
    """(J,) bool: the stored validity/activity row is > 0 (4DA writes 1.19e-7 for some weakly
    active joints, which do carry positions)."""


# ---------------------------------------------------------------------------------------------
# Cameras


def _calibration_rig(data_root, relative: str, image_size: tuple[int, int]) -> geometry.Camera:
    # The shipped assets mirror the data folder's layout.
    path = (_ASSETS if data_root is None else Path(data_root)) / relative
    return geometry.load_voxelpose_calibration(path, image_size=image_size)


def shelf_cameras(data_root: str | os.PathLike | None = None) -> geometry.Camera:
    """The 5 Shelf cameras as a stacked rig (metres, image 1032x776 px).

    Read from the shipped copy of VoxelPose's ``calibration_shelf.json``, or from
    ``data_root/shelf/calibration_shelf.json`` when ``data_root`` is given."""
    return _calibration_rig(data_root, "shelf/calibration_shelf.json", geometry.SHELF_IMAGE_SIZE)


def campus_cameras(data_root: str | os.PathLike | None = None) -> geometry.Camera:
    """The 3 Campus cameras as a stacked rig (metres, image 360x288 px).

    Read from the shipped copy of VoxelPose's ``calibration_campus.json``, or from
    ``data_root/campus/calibration_campus.json`` when ``data_root`` is given."""
    return _calibration_rig(data_root, "campus/calibration_campus.json", geometry.CAMPUS_IMAGE_SIZE)


# ---------------------------------------------------------------------------------------------
# Frame ranges and ground truth


def shelf_test_frames() -> Int[np.ndarray, "301"]:
    """The standard Shelf test frames, actorsGT indices 300..600 inclusive (VoxelPose, 4DA, JCSAT)."""
    return np.arange(300, 601)


def campus_test_frames() -> Int[np.ndarray, "222"]:
    """The standard Campus test frames, 350..470 and 650..750 inclusive (VoxelPose, MVPose)."""
    return np.concatenate([np.arange(350, 471), np.arange(650, 751)])


def load_shelf_ground_truth(
    data_root: str | os.PathLike,
) -> tuple[Float[np.ndarray, "actors frames 14 3"], Bool[np.ndarray, "actors frames"]]:
    """The official Shelf ground truth from ``data_root/shelf/actorsGT.mat``.

    Returns ``positions`` (4, 3200, 14, 3) in metres, SHELF14 joint order, world z-up, and
    ``annotated`` (4, 3200) bool. Frames where an actor is not annotated hold zeros (never NaN).
    Frame index f is the 0-based image index (VoxelPose ``img_{f:06d}.png``).
    """
    path = Path(data_root) / "shelf" / "actorsGT.mat"
    if not path.is_file():
        raise FileNotFoundError(f"Shelf ground truth not found: {path}")
    try:
        mat = scipy.io.loadmat(path)
    except (OSError, ValueError) as err:
        raise ValueError(f"{path}: cannot read as a MATLAB file ({err})") from err
    if "actor3D" not in mat:
        raise ValueError(f"{path}: no key 'actor3D' (keys: {sorted(k for k in mat if not k.startswith('__'))})")
    actors = mat["actor3D"]
    if actors.dtype != object or actors.ndim != 2 or actors.shape[0] != 1:
        raise ValueError(f"{path}: key 'actor3D' should be a (1, actors) cell array, got {actors.dtype} {actors.shape}")
    num_actors = actors.shape[1]
    shapes = [actors[0, p].shape for p in range(num_actors)]
    if len(set(shapes)) != 1 or len(shapes[0]) != 2 or shapes[0][1] != 1:
        raise ValueError(f"{path}: key 'actor3D' should hold one (frames, 1) cell array per actor, got {shapes}")
    num_frames = shapes[0][0]
    positions = np.zeros((num_actors, num_frames, 14, 3))
    annotated = np.zeros((num_actors, num_frames), bool)
    for p in range(num_actors):
        for f in range(num_frames):
            cell = np.asarray(actors[0, p][f, 0])
            if cell.size == 0:
                continue
            key = f"actor3D{{0,{p}}}{{{f},0}}"
            if cell.shape != (14, 3) or not np.issubdtype(cell.dtype, np.number):
                raise ValueError(f"{path}: key {key} should be empty or a (14, 3) array, got {cell.dtype} {cell.shape}")
            if not np.all(np.isfinite(cell)):
                raise ValueError(f"{path}: key {key} contains NaN or inf")
            positions[p, f] = cell
            annotated[p, f] = True
    return positions, annotated


# ---------------------------------------------------------------------------------------------
# 4D-association text formats


class _Tokens:
    """A whole text file split into whitespace-separated tokens and parsed as floats once, with a cursor.

    Line numbers are computed only when an error is reported.
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        try:
            self.text = self.path.read_text()
        except UnicodeDecodeError as err:
            raise ValueError(f"{self.path}: not a text file ({err})") from err
        self.tokens = self.text.split()
        self.pos = 0
        try:
            self.values = np.array(self.tokens, dtype=np.float64)
        except ValueError:
            bad = next(i for i, t in enumerate(self.tokens) if not _is_float(t))
            raise self.error(bad, f"non-numeric value {self.tokens[bad]!r}") from None
        finite = np.isfinite(self.values)
        if not finite.all():
            bad = int(np.argmin(finite))
            raise self.error(bad, f"non-finite value {self.tokens[bad]!r}")

    def line_of(self, index: int) -> int:
        counts = np.cumsum([len(line.split()) for line in self.text.splitlines()])
        return min(int(np.searchsorted(counts, index, side="right")) + 1, max(len(counts), 1))

    def error(self, index: int, message: str) -> ValueError:
        return ValueError(f"{self.path}, line {self.line_of(index)}: {message}")

    def _advance(self, count: int, what: str) -> int:
        start, end = self.pos, self.pos + count
        if end > len(self.tokens):
            raise ValueError(
                f"{self.path}, line {self.line_of(len(self.tokens))}: file ends while reading {what} "
                f"({count} values needed, {len(self.tokens) - start} left)"
            )
        self.pos = end
        return start

    def count(self, what: str) -> int:
        index = self._advance(1, what)
        if not self.tokens[index].isdigit():
            raise self.error(index, f"expected a non-negative integer for {what}, got {self.tokens[index]!r}")
        return int(self.values[index])

    def floats(self, count: int, what: str) -> np.ndarray:
        start = self._advance(count, what)
        return self.values[start:self.pos]

    def expect_end(self, what: str) -> None:
        if self.pos != len(self.tokens):
            raise self.error(self.pos, f"unexpected data after {what} ({len(self.tokens) - self.pos} extra values)")


def _is_float(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def load_4dassoc_skeletons(path: str | os.PathLike, num_joints: int | None = None) -> list[list[PersonSkeleton]]:
    """Read a 4DA skeleton file (Shelf ``gt.txt``: 15 joints, ``skel.txt``: 19 joints, SKEL19).

    Format: header ``J F`` (joints, frames); per frame the number of persons, then per person
    its id and a 4 x J matrix (rows x, y, z in metres, then validity/activity). Returns
    ``frames[f]`` = list of :class:`PersonSkeleton` in file order. ``num_joints``, when given,
    must match the header.
    """
    tok = _Tokens(path)
    n_joints = tok.count("the header's joint count")
    n_frames = tok.count("the header's frame count")
    if num_joints is not None and n_joints != num_joints:
        raise tok.error(0, f"header says {n_joints} joints, expected {num_joints}")
    frames = []
    for f in range(n_frames):
        persons = []
        for k in range(tok.count(f"the person count of frame {f}")):
            person_id = tok.count(f"the id of person {k} in frame {f}")
            m = tok.floats(4 * n_joints, f"the 4x{n_joints} matrix of person {k} in frame {f}").reshape(4, n_joints)
            persons.append(PersonSkeleton(person_id, m[:3].T.copy(), m[3] > 0))
        frames.append(persons)
    tok.expect_end(f"the {n_frames} frames of the header")
    return frames


def load_4dassoc_detections(
    path: str | os.PathLike, image_size: tuple[int, int], paf_exponent: float = 1.0
) -> list[Detections]:
    """Read one view's OpenPose BODY25 detections in the 4DA text format (all frames).

    Format: header ``4 F`` (4 = 4DA's SkelType BODY25, F frames); per frame 25 joint blocks (a
    count n, then 3 rows of n values: x / (W - 1), y / (H - 1), score) and 26 PAF blocks, one
    n_a x n_b matrix (rows = candidates of joint a) per pair of
    :data:`~mocap.BODY25_PAF_PAIRS`, whose sizes follow from the joint counts.

    ``image_size`` is (W, H) in pixels; coordinates are returned in pixels (x * (W - 1),
    y * (H - 1)). PAF scores are returned as stored; ``paf_exponent`` raises them to a power, e.g.
    :data:`FOUR_D_ASSOCIATION_PAF_EXPONENT` to reproduce 4DA's own post-processing.
    """
    width, height = image_size
    if width < 2 or height < 2:
        raise ValueError(f"image_size should be (width, height) in pixels, got {image_size}")
    tok = _Tokens(path)
    skel_type = tok.count("the header's skeleton type")
    if skel_type != _BODY25_SKEL_TYPE:
        raise tok.error(0, f"header skeleton type {skel_type} is not BODY25 ({_BODY25_SKEL_TYPE})")
    n_frames = tok.count("the header's frame count")
    scale = np.array([width - 1.0, height - 1.0, 1.0])
    out = []
    for f in range(n_frames):
        joints = []
        for j in range(_BODY25_NUM_JOINTS):
            n = tok.count(f"the candidate count of joint {j} in frame {f}")
            block = tok.floats(3 * n, f"the 3x{n} candidates of joint {j} in frame {f}")
            joints.append(block.reshape(3, n).T * scale)
        shapes = [(len(joints[a]), len(joints[b])) for a, b in BODY25_PAF_PAIRS]
        ends = np.cumsum([n_a * n_b for n_a, n_b in shapes])
        flat = tok.floats(int(ends[-1]), f"the {len(shapes)} PAF matrices of frame {f}")
        if paf_exponent != 1.0:
            flat = flat**paf_exponent
        pafs = tuple(flat[end - n_a * n_b:end].reshape(n_a, n_b) for end, (n_a, n_b) in zip(ends, shapes))
        out.append(Detections(tuple(joints), pafs))
    tok.expect_end(f"the {n_frames} frames of the header")
    return out


def load_shelf_detections(
    data_root: str | os.PathLike, paf_exponent: float = 1.0
) -> tuple[list[list[Detections]], Int[np.ndarray, " frames"]]:
    """The real Shelf OpenPose detections of all 5 views (``shelf/4d_association/detection/*.txt``).

    Returns ``frames[k][view]`` and ``gt_frame_indices`` (k -> actorsGT frame 300 + k, so the
    301 frames are the standard test range). See :func:`load_4dassoc_detections` for
    ``paf_exponent``.
    """
    folder = Path(data_root) / "shelf" / "4d_association" / "detection"
    views = [
        load_4dassoc_detections(folder / f"{v}.txt", geometry.SHELF_IMAGE_SIZE, paf_exponent)
        for v in range(SHELF_NUM_VIEWS)
    ]
    lengths = [len(v) for v in views]
    if len(set(lengths)) != 1:
        raise ValueError(f"{folder}: the view files hold different frame counts {lengths}")
    frames = [list(per_view) for per_view in zip(*views)]
    return frames, SHELF_DETECTION_FIRST_FRAME + np.arange(lengths[0])

"""Loaders for the camera calibration formats of the Shelf and Campus datasets.

Each loader returns a stacked rig (:class:`~geometry.Camera` with a leading ``views`` axis, ordered by
camera id) in the project's convention: metres, ``x_cam = R X + t``, OpenCV distortion. Malformed
files raise :class:`CalibrationError` naming the file and the line (text) or camera and key (JSON).

Formats:

- VoxelPose JSON (``calibration_shelf.json``, ``calibration_campus.json``): keys ``"0".."n-1"``, each
  with ``R`` (3x3), ``T`` (3x1, the camera CENTRE in world millimetres: ``x_cam = R (X_mm - T)``),
  ``fx, fy, cx, cy`` and the Human3.6M-style distortion ``k`` (3: k1, k2, k3) and ``p`` (2). VoxelPose's
  ``project_point_radial`` applies ``p`` in OpenCV's order, so ``dist = (k1, k2, p[0], p[1], k3)``.
  The image size is not in the file.
- 4D Association JSON: keys ``"0".."n-1"``, each with ``K`` (9 values, row-major), ``RT`` (12 values,
  row-major 3x4 ``[R | t]``, t in metres) and ``imgSize`` [width, height]. No distortion.
- TUM projection matrices ``P0.txt, P1.txt, ...``: a 3x4 matrix acting on world metres, rows on lines,
  values separated by commas (Shelf) or spaces (Campus). Decomposed with
  :func:`~geometry.camera_from_projection`; the image size is not in the file.
"""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from os import PathLike
from pathlib import Path

import numpy as np

from ._camera import Camera, camera_from_projection

__all__ = [
    "CalibrationError",
    "SHELF_IMAGE_SIZE",
    "CAMPUS_IMAGE_SIZE",
    "load_voxelpose_calibration",
    "load_4dassociation_calibration",
    "load_projection_matrices",
]

SHELF_IMAGE_SIZE = (1032, 776)
"""Shelf image [width, height] in pixels."""
CAMPUS_IMAGE_SIZE = (360, 288)
"""Campus image [width, height] in pixels (the TUM P matrices are already scaled to it)."""

_ROTATION_TOLERANCE = 1e-4
"""Largest |R R^T - I| entry accepted; the published files round R to 6-8 digits."""


class CalibrationError(ValueError):
    """A calibration file is missing, malformed or inconsistent; the message names file and place."""


def _read_json(path: Path) -> dict:
    """The camera entries of a calibration JSON, ordered by camera id."""
    try:
        text = path.read_text()
    except OSError as error:
        raise CalibrationError(f"{path}: cannot read calibration file: {error}") from error
    try:
        data = json.loads(text)
    except json.JSONDecodeError as error:
        raise CalibrationError(f"{path}:{error.lineno}:{error.colno}: invalid JSON: {error.msg}") from error
    if not isinstance(data, dict) or not data:
        raise CalibrationError(f"{path}: expected a JSON object with one entry per camera")
    expected = [str(i) for i in range(len(data))]
    if sorted(data, key=lambda k: (len(k), k)) != expected:
        raise CalibrationError(f"{path}: camera keys must be '0'..'{len(data) - 1}', got {sorted(data)}")
    for key in expected:
        if not isinstance(data[key], dict):
            raise CalibrationError(f"{path}: camera '{key}' must be a JSON object")
    return {key: data[key] for key in expected}


def _json_array(path: Path, camera: str, entry: dict, key: str, shape: tuple[int, ...]) -> np.ndarray:
    where = f"{path}: camera '{camera}', key '{key}'"
    if key not in entry:
        raise CalibrationError(f"{where}: missing (present keys: {sorted(entry)})")
    try:
        value = np.asarray(entry[key], dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise CalibrationError(f"{where}: not an array of numbers ({error})") from error
    if value.size != int(np.prod(shape)):
        raise CalibrationError(f"{where}: expected {int(np.prod(shape))} values {shape}, got shape {value.shape}")
    if not np.all(np.isfinite(value)):
        raise CalibrationError(f"{where}: contains NaN or inf")
    return value.reshape(shape)


def _check_rotation(where: str, R: np.ndarray) -> None:
    error, det = np.abs(R @ R.T - np.eye(3)).max(), np.linalg.det(R)
    if error > _ROTATION_TOLERANCE or det < 0:
        raise CalibrationError(f"{where}: not a rotation matrix (|R R^T - I| = {error:.2g}, det = {det:.3g})")


def _stack(cameras: list[dict[str, np.ndarray]]) -> Camera:
    fields = {name: np.stack([c[name] for c in cameras]) for name in cameras[0]}
    return Camera.create(**fields)


def load_voxelpose_calibration(
    path: str | PathLike, *, image_size: Sequence[float | int] | np.ndarray
) -> Camera:
    """Load a VoxelPose calibration JSON (R, camera centre T in mm, fx, fy, cx, cy, k, p) as a rig.

    ``image_size`` is [width, height] in pixels (not stored in the file: :data:`SHELF_IMAGE_SIZE`,
    :data:`CAMPUS_IMAGE_SIZE`). ``t = -R T / 1000`` converts the centre in millimetres to the
    world-to-camera translation in metres."""
    path = Path(path)
    cameras = []
    for key, entry in _read_json(path).items():
        R = _json_array(path, key, entry, "R", (3, 3))
        _check_rotation(f"{path}: camera '{key}', key 'R'", R)
        centre_mm = _json_array(path, key, entry, "T", (3,))
        fx, fy, cx, cy = (float(_json_array(path, key, entry, name, ())) for name in ("fx", "fy", "cx", "cy"))
        k = _json_array(path, key, entry, "k", (3,))
        p = _json_array(path, key, entry, "p", (2,))
        cameras.append({
            "K": np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]),
            "R": R,
            "t": -R @ centre_mm / 1000.0,
            "dist": np.array([k[0], k[1], p[0], p[1], k[2]]),
            "image_size": np.asarray(image_size, np.float64),
        })
    return _stack(cameras)


def load_4dassociation_calibration(path: str | PathLike) -> Camera:
    """Load a 4D Association calibration JSON (K, RT with t in metres, imgSize) as a rig."""
    path = Path(path)
    cameras = []
    for key, entry in _read_json(path).items():
        K = _json_array(path, key, entry, "K", (3, 3))
        RT = _json_array(path, key, entry, "RT", (3, 4))
        _check_rotation(f"{path}: camera '{key}', key 'RT'", RT[:, :3])
        cameras.append({
            "K": K,
            "R": RT[:, :3],
            "t": RT[:, 3],
            "dist": np.zeros(5),
            "image_size": _json_array(path, key, entry, "imgSize", (2,)),
        })
    return _stack(cameras)


def _read_projection_matrix(path: Path) -> np.ndarray:
    try:
        lines = path.read_text().splitlines()
    except OSError as error:
        raise CalibrationError(f"{path}: cannot read projection matrix: {error}") from error
    rows = []
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        if len(rows) == 3:
            raise CalibrationError(f"{path}:{number}: a 3x4 projection matrix has 3 rows; extra line {line!r}")
        fields = re.split(r"[,\s]+", line.strip())
        try:
            row = [float(field) for field in fields]
        except ValueError:
            raise CalibrationError(f"{path}:{number}: not numbers separated by commas or spaces: {line!r}") from None
        if len(row) != 4 or not np.all(np.isfinite(row)):
            raise CalibrationError(f"{path}:{number}: expected 4 finite numbers, got {line!r}")
        rows.append(row)
    if len(rows) != 3:
        raise CalibrationError(f"{path}:{len(lines)}: expected 3 rows of a 3x4 projection matrix, found {len(rows)}")
    P = np.array(rows)
    if abs(np.linalg.det(P[:, :3])) < 1e-12 * np.abs(P[:, :3]).max() ** 3:
        raise CalibrationError(f"{path}: the left 3x3 block of P is singular; not a finite camera")
    return P


def load_projection_matrices(
    source: str | PathLike | Sequence[str | PathLike], *, image_size: Sequence[float | int] | np.ndarray
) -> Camera:
    """Load TUM 3x4 projection matrices (acting on metres) as a rig with zero distortion.

    ``source`` is a folder (its ``P<i>.txt`` files, ordered by i) or a sequence of files in camera
    order. ``image_size`` is [width, height] in pixels."""
    if isinstance(source, (str, PathLike)):
        folder = Path(source)
        numbered = [(m, p) for p in folder.glob("P*.txt") if (m := re.fullmatch(r"P(\d+)\.txt", p.name))]
        paths = [p for _, p in sorted(numbered, key=lambda mp: int(mp[0].group(1)))]
        if not paths:
            raise CalibrationError(f"{folder}: no projection matrix files P<i>.txt")
    else:
        paths = [Path(p) for p in source]
    cameras = [
        camera_from_projection(_read_projection_matrix(path), image_size=np.asarray(image_size, np.float64))
        for path in paths
    ]
    return _stack([{name: np.asarray(value) for name, value in cam._asdict().items()} for cam in cameras])

"""The calibration formats of the Shelf and Campus datasets, read and (the JSON ones) written.

Each loader returns a stacked rig (:class:`~geometry.Camera` with a leading ``views`` axis, ordered by
camera id) in the project's convention: metres, ``x_cam = R X + t``, OpenCV distortion. Malformed
files raise :class:`CalibrationError` naming the file and the line (text) or camera and key (JSON).
Each writer is the exact inverse of its loader and replaces the file atomically. The EasyMocap and
aniposelib formats and :func:`~geometry.load_calibration`, which recognises every layout, are in
``_calibration_formats.py``; the checks they share with these formats live here.

Formats:

- VoxelPose JSON (``calibration_shelf.json``, ``calibration_campus.json``): keys ``"0".."n-1"``, each
  with ``R`` (3x3), ``T`` (3x1, the camera CENTRE in world millimetres: ``x_cam = R (X_mm - T)``),
  ``fx, fy, cx, cy`` and the Human3.6M-style distortion ``k`` (3: k1, k2, k3) and ``p`` (2). VoxelPose's
  ``project_point_radial`` applies ``p`` in OpenCV's order, so ``dist = (k1, k2, p[0], p[1], k3)``.
  The image size is not in the file; the writer refuses a K with skew (VoxelPose has no place for it).
- 4D Association JSON: keys ``"0".."n-1"``, each with ``K`` (9 values, row-major), ``RT`` (12 values,
  row-major 3x4 ``[R | t]``, t in metres) and ``imgSize`` [width, height]. No distortion: the writer
  refuses a rig that has some.
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
from ._files import replace_file

__all__ = [
    "CalibrationError",
    "SHELF_IMAGE_SIZE",
    "CAMPUS_IMAGE_SIZE",
    "load_voxelpose_calibration",
    "load_4dassociation_calibration",
    "load_projection_matrices",
    "save_voxelpose_calibration",
    "save_4dassociation_calibration",
]

SHELF_IMAGE_SIZE = (1032, 776)
"""Shelf image [width, height] in pixels."""
CAMPUS_IMAGE_SIZE = (360, 288)
"""Campus image [width, height] in pixels (the TUM P matrices are already scaled to it)."""

_ROTATION_TOLERANCE = 1e-4
"""Largest |R R^T - I| entry accepted, and largest entry difference between two stored forms of one
rotation (EasyMocap's Rodrigues vector and matrix); the published files round R to 6-8 digits."""


class CalibrationError(ValueError):
    """A calibration file is missing, malformed or inconsistent, or a rig cannot be written in the asked
    format; the one-line message names the file and the place (camera and key, or line)."""


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


def _entry_array(path: Path, camera: str, entry: dict, key: str, shape: tuple[int, ...] | None) -> np.ndarray:
    """The numbers under ``key`` of a camera's JSON object or TOML table, in ``shape`` (None: a flat list of
    any length, as a vector)."""
    where = f"{path}: camera '{camera}', key '{key}'"
    if key not in entry:
        raise CalibrationError(f"{where}: missing (present keys: {sorted(entry)})")
    try:
        value = np.asarray(entry[key], dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise CalibrationError(f"{where}: not an array of numbers ({error})") from error
    if shape is None:
        if value.ndim > 1:
            raise CalibrationError(f"{where}: expected a flat list of numbers, got shape {value.shape}")
        shape = (value.size,)
    if value.size != int(np.prod(shape)):
        raise CalibrationError(f"{where}: expected {int(np.prod(shape))} values {shape}, got shape {value.shape}")
    _check_finite(where, value)
    return value.reshape(shape)


def _check_finite(where: str, value: np.ndarray) -> None:
    if not np.all(np.isfinite(value)):
        raise CalibrationError(f"{where}: contains NaN or inf")


def _check_rotation(where: str, R: np.ndarray) -> None:
    error, det = np.abs(R @ R.T - np.eye(3)).max(), np.linalg.det(R)
    if error > _ROTATION_TOLERANCE or det < 0:
        raise CalibrationError(f"{where}: not a rotation matrix (|R R^T - I| = {error:.2g}, det = {det:.3g})")


def _stack(cameras: list[dict[str, np.ndarray]]) -> Camera:
    fields = {name: np.stack([c[name] for c in cameras]) for name in cameras[0]}
    return Camera.create(**fields)


def _rig_arrays(rig: Camera) -> dict[str, np.ndarray]:
    """The rig's fields as float64 NumPy arrays, each with the leading views axis."""
    if np.ndim(rig.K) != 3:
        raise ValueError(f"expected a rig (a Camera with a leading views axis), got K of shape {np.shape(rig.K)}")
    return {name: np.asarray(value, np.float64) for name, value in rig._asdict().items()}


def _image_size_values(image_size: np.ndarray) -> list[int | float]:
    """[width, height] as the files hold them: integers (what the tools write) unless fractional."""
    return [int(v) if float(v).is_integer() else float(v) for v in image_size]


def _write_json(path: Path, data: dict) -> None:
    replace_file(path, lambda temporary: temporary.write_text(json.dumps(data, indent=2) + "\n"))


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
        R = _entry_array(path, key, entry, "R", (3, 3))
        _check_rotation(f"{path}: camera '{key}', key 'R'", R)
        centre_mm = _entry_array(path, key, entry, "T", (3,))
        fx, fy, cx, cy = (float(_entry_array(path, key, entry, name, ())) for name in ("fx", "fy", "cx", "cy"))
        k = _entry_array(path, key, entry, "k", (3,))
        p = _entry_array(path, key, entry, "p", (2,))
        cameras.append({
            "K": np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]),
            "R": R,
            "t": -R @ centre_mm / 1000.0,
            "dist": np.array([k[0], k[1], p[0], p[1], k[2]]),
            "image_size": np.asarray(image_size, np.float64),
        })
    return _stack(cameras)


def save_voxelpose_calibration(path: str | PathLike, rig: Camera) -> None:
    """Write a rig as a VoxelPose calibration JSON, the inverse of :func:`load_voxelpose_calibration`.

    The camera centre ``T = -R^-1 t`` goes in millimetres (``R^-1``, not ``R^T``: the published R are
    orthonormal to 6 digits only, and the loader multiplies by that R) and ``dist`` splits into
    ``k = (k1, k2, k3)`` and ``p = (p1, p2)``; the image size is not stored. A K with skew cannot be written."""
    path = Path(path)
    arrays = _rig_arrays(rig)
    data = {}
    for i, (K, R, t, dist) in enumerate(zip(arrays["K"], arrays["R"], arrays["t"], arrays["dist"])):
        if K[0, 1] != 0.0 or K[1, 0] != 0.0 or np.any(K[2] != [0.0, 0.0, 1.0]):
            raise CalibrationError(f"{path}: camera '{i}': VoxelPose stores fx, fy, cx, cy only, got K = {K.tolist()}")
        data[str(i)] = {
            "k": [[dist[0]], [dist[1]], [dist[4]]],
            "p": [[dist[2]], [dist[3]]],
            "R": R.tolist(),
            "T": (-np.linalg.solve(R, t) * 1000.0)[:, None].tolist(),
            "fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2],
        }
    _write_json(path, data)


def load_4dassociation_calibration(path: str | PathLike) -> Camera:
    """Load a 4D Association calibration JSON (K, RT with t in metres, imgSize) as a rig."""
    path = Path(path)
    cameras = []
    for key, entry in _read_json(path).items():
        K = _entry_array(path, key, entry, "K", (3, 3))
        RT = _entry_array(path, key, entry, "RT", (3, 4))
        _check_rotation(f"{path}: camera '{key}', key 'RT'", RT[:, :3])
        cameras.append({
            "K": K,
            "R": RT[:, :3],
            "t": RT[:, 3],
            "dist": np.zeros(5),
            "image_size": _entry_array(path, key, entry, "imgSize", (2,)),
        })
    return _stack(cameras)


def save_4dassociation_calibration(path: str | PathLike, rig: Camera) -> None:
    """Write a rig as a 4D Association calibration JSON, the inverse of :func:`load_4dassociation_calibration`.

    The format has no distortion, so a rig with any non-zero coefficient is refused."""
    path = Path(path)
    arrays = _rig_arrays(rig)
    data = {}
    for i, (K, R, t, dist, image_size) in enumerate(zip(*arrays.values())):
        if np.any(dist != 0.0):
            raise CalibrationError(
                f"{path}: camera '{i}': 4D Association calibrations have no distortion, got dist = {dist.tolist()}")
        data[str(i)] = {
            "K": K.ravel().tolist(),
            "RT": np.column_stack([R, t]).ravel().tolist(),
            "imgSize": _image_size_values(image_size),
        }
    _write_json(path, data)


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


def _projection_files(folder: Path) -> list[tuple[int, Path]]:
    """The folder's ``P<i>.txt`` files with their numbers i, ordered by i (P10 after P9)."""
    numbered = [(int(m.group(1)), p) for p in folder.glob("P*.txt") if (m := re.fullmatch(r"P(\d+)\.txt", p.name))]
    return sorted(numbered)


def load_projection_matrices(
    source: str | PathLike | Sequence[str | PathLike], *, image_size: Sequence[float | int] | np.ndarray
) -> Camera:
    """Load TUM 3x4 projection matrices (acting on metres) as a rig with zero distortion.

    ``source`` is a folder (its ``P<i>.txt`` files, ordered by i) or a sequence of files in camera
    order. ``image_size`` is [width, height] in pixels."""
    if isinstance(source, (str, PathLike)):
        folder = Path(source)
        paths = [path for _, path in _projection_files(folder)]
        if not paths:
            raise CalibrationError(f"{folder}: no projection matrix files P<i>.txt")
    else:
        paths = [Path(p) for p in source]
    cameras = [
        camera_from_projection(_read_projection_matrix(path), image_size=np.asarray(image_size, np.float64))
        for path in paths
    ]
    return _stack([{name: np.asarray(value) for name, value in cam._asdict().items()} for cam in cameras])

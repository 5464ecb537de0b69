"""The EasyMocap and aniposelib calibration files, read and written, and one entry point for every layout.

Loaders return a :class:`Calibration`: the stacked rig (project convention: metres, ``x_cam = R X + t``,
OpenCV distortion ``(k1, k2, p1, p2, k3)``, image size [width, height]) and the cameras' names in file
order. Malformed files raise :class:`~geometry.CalibrationError` with one line naming the file, the
camera and the key (or the line of a syntax error). Writers replace their files atomically.

Formats:

- EasyMocap (OpenCV FileStorage YAML, read and written with ``cv2.FileStorage``): a folder with
  ``intri.yml`` and ``extri.yml``, each opening with ``names``, the list of camera names. Per camera
  ``<name>``, ``intri.yml`` holds ``K_<name>`` (3x3 ``!!opencv-matrix``, pixels), ``dist_<name>`` (1xN
  or Nx1, N >= 4, OpenCV order; ``D_<name>`` is read when ``dist_`` is absent, as EasyMocap's reader
  does) and optionally ``H_<name>``, ``W_<name>`` (image height and width, pixels; -1 for unknown);
  ``extri.yml`` holds ``R_<name>`` (3x1 Rodrigues vector), optionally ``Rot_<name>`` (its 3x3 matrix,
  preferred when present; the two must agree) and ``T_<name>`` (3x1, metres), both world-to-camera.
  Camera names become keys, so the writer takes letters, digits, ``_`` and ``-`` (words separated by
  single spaces), but not ``true``, ``false`` or ``null``, which OpenCV writes unquoted and reads back
  as other types.
- aniposelib ``calibration.toml``: tables ``[cam_0]``, ``[cam_1]``, ... (ordered by number; aniposelib
  sorts them as text, which puts cam_10 before cam_2), each with ``name``, ``size = [width, height]``,
  ``matrix`` (3x3, pixels), ``distortions`` (OpenCV order, at most 5 used, fewer zero-padded),
  ``rotation`` (Rodrigues vector, world-to-camera) and ``translation`` (3, in the calibration board's
  unit, often millimetres: ``metres_per_unit`` converts), and an optional ``[metadata]`` table, which
  is ignored. ``fisheye = true`` cameras (OpenCV's fisheye model) are refused. A Rodrigues vector holds
  only a true rotation: an R orthonormal to a few digits (the published Shelf files) is written as its
  nearest rotation.
- VoxelPose and 4D Association JSON and TUM ``P<i>.txt`` folders: see ``_calibration_io.py``; their
  cameras are named by position (``"0".."n-1"``) or by the P file's number.

Distortion lists longer than five (OpenCV's rational, thin-prism and tilt terms) are read only when the
extra terms are zero: the project's camera does not model them.
"""

from __future__ import annotations

import math
import re
import tomllib
from collections.abc import Iterable, Sequence
from os import PathLike
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np

from ._calibration_io import (
    _ROTATION_TOLERANCE,
    CalibrationError,
    _check_finite,
    _check_rotation,
    _entry_array,
    _image_size_values,
    _projection_files,
    _read_json,
    _rig_arrays,
    _stack,
    load_4dassociation_calibration,
    load_projection_matrices,
    load_voxelpose_calibration,
    save_4dassociation_calibration,
    save_voxelpose_calibration,
)
from ._files import replace_file
from ._camera import Camera

__all__ = [
    "CALIBRATION_FORMATS",
    "Calibration",
    "load_easymocap_calibration",
    "save_easymocap_calibration",
    "load_anipose_calibration",
    "save_anipose_calibration",
    "load_calibration",
    "save_calibration",
]

CALIBRATION_FORMATS = ("easymocap", "anipose", "voxelpose", "4dassociation")
"""The formats :func:`save_calibration` writes."""

_LAYOUTS = (
    "a folder with intri.yml and extri.yml (EasyMocap)",
    "calibration.toml or a folder holding it (anipose)",
    "a .json file (VoxelPose or 4D Association)",
    "a folder of P<i>.txt files (TUM)",
)

_NAME_AS_KEY = re.compile(r"(?!(?:true|false|null)$)[A-Za-z0-9_-]+(?: [A-Za-z0-9_-]+)*")
"""Camera names OpenCV accepts inside a FileStorage key (K_<name>) and reads back unchanged from ``names``
(OpenCV writes true, false and null unquoted and reads them back as a number and as nothing)."""


class Calibration(NamedTuple):
    """A stacked rig and its cameras' names, in the same order."""

    rig: Camera
    names: tuple[str, ...]


def _check_calibration(path: Path, calibration: Calibration) -> dict[str, np.ndarray]:
    """The rig's arrays, after checking that the names are distinct strings, one per camera."""
    arrays = _rig_arrays(calibration.rig)
    names = calibration.names
    if len(names) != len(arrays["K"]) or len(set(names)) != len(names) or not all(isinstance(n, str) for n in names):
        raise ValueError(f"{path}: expected {len(arrays['K'])} distinct camera names (one per view), got {names!r}")
    return arrays


def _check_unit(metres_per_unit: float) -> None:
    if not (math.isfinite(metres_per_unit) and metres_per_unit > 0):
        raise ValueError(f"metres_per_unit must be a positive number, got {metres_per_unit}")


def _opencv_distortion(where: str, values: np.ndarray, fewest: int) -> np.ndarray:
    """OpenCV's first five coefficients ``(k1, k2, p1, p2, k3)``, zero-padded (OpenCV reads four as k3 = 0)."""
    if values.size < fewest:
        raise CalibrationError(f"{where}: expected at least {fewest} distortion coefficients, got {values.size}")
    if np.any(values[5:] != 0.0):
        raise CalibrationError(f"{where}: non-zero coefficients after k3 (OpenCV's rational, thin-prism or tilt "
                               f"terms) are not modelled, got {values.tolist()}")
    return np.pad(values[:5], (0, max(0, 5 - values.size)))


# --------------------------------------------------------------------------------------------
# EasyMocap: OpenCV FileStorage YAML


def _open_yaml(path: Path) -> cv2.FileStorage:
    if not path.is_file():  # checked first: OpenCV prints to stderr when asked to open a missing file
        raise CalibrationError(f"{path}: cannot read calibration file: no such file")
    try:
        return cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as error:
        # The binding wraps a parse error in SystemError; OpenCV's message spans lines and names the
        # position as "<file>(<line>): <reason>".
        found = re.search(r"\((\d+)\): ([^'\n]+)", str(error.__cause__ or error))
        raise CalibrationError(f"{path}:{found[1]}: invalid OpenCV YAML: {found[2]}" if found else
                               f"{path}: not an OpenCV FileStorage YAML file") from error


def _yaml_names(path: Path, storage: cv2.FileStorage) -> tuple[str, ...]:
    node = storage.getNode("names")
    if node.empty():
        raise CalibrationError(f"{path}: key 'names': missing (the list of camera names)")
    if not node.isSeq() or node.size() == 0:
        raise CalibrationError(f"{path}: key 'names': expected a non-empty list of camera names")
    names = []
    for i in range(node.size()):
        item = node.at(i)
        if item.isString():
            names.append(item.string())
        elif item.isInt():  # an unquoted number, which EasyMocap's reader also takes as the name
            names.append(str(int(item.real())))
        else:
            raise CalibrationError(f"{path}: key 'names', item {i}: expected a camera name")
    if len(set(names)) != len(names):
        raise CalibrationError(f"{path}: key 'names': camera names repeat: {names}")
    return tuple(names)


def _yaml_matrix(
    path: Path, storage: cv2.FileStorage, camera: str, key: str, shape: tuple[int, int] | None, *, required: bool
) -> np.ndarray | None:
    """The ``!!opencv-matrix`` under ``key`` as float64, of ``shape`` (None: a 1xN or Nx1 vector, returned
    flat); None when the key is absent and not ``required``."""
    where = f"{path}: camera '{camera}', key '{key}'"
    node = storage.getNode(key)
    if node.empty():
        if required:
            raise CalibrationError(f"{where}: missing")
        return None
    try:
        value = node.mat() if node.isMap() else None
    except cv2.error:  # a map without OpenCV's rows, cols, dt, data (or data of the wrong length)
        value = None
    if value is None:
        raise CalibrationError(f"{where}: expected an !!opencv-matrix with rows, cols, dt and data")
    value = np.asarray(value, np.float64)
    got = "x".join(map(str, value.shape))
    if shape is None and min(value.shape) != 1:
        raise CalibrationError(f"{where}: expected a 1xN or Nx1 vector, got {got}")
    if shape is not None and value.shape != shape:
        raise CalibrationError(f"{where}: expected a {shape[0]}x{shape[1]} matrix, got {got}")
    _check_finite(where, value)
    return value.ravel() if shape is None else value


def _yaml_number(path: Path, storage: cv2.FileStorage, camera: str, key: str) -> float | None:
    where = f"{path}: camera '{camera}', key '{key}'"
    node = storage.getNode(key)
    if node.empty():
        return None
    if not (node.isInt() or node.isReal()):
        raise CalibrationError(f"{where}: expected a number")
    value = node.real()
    _check_finite(where, np.array(value))
    return value


def _yaml_vector3(path: Path, storage: cv2.FileStorage, camera: str, key: str, *, required: bool) -> np.ndarray | None:
    value = _yaml_matrix(path, storage, camera, key, None, required=required)
    if value is not None and value.size != 3:
        raise CalibrationError(f"{path}: camera '{camera}', key '{key}': expected 3 values, got {value.size}")
    return value


def _easymocap_intrinsics(
    path: Path, storage: cv2.FileStorage, name: str, image_size: Sequence[float | int] | np.ndarray | None
) -> dict[str, np.ndarray]:
    K = _yaml_matrix(path, storage, name, f"K_{name}", (3, 3), required=True)
    dist_key = f"dist_{name}" if not storage.getNode(f"dist_{name}").empty() else f"D_{name}"
    dist = _yaml_matrix(path, storage, name, dist_key, None, required=False)
    if dist is None:
        raise CalibrationError(f"{path}: camera '{name}', key 'dist_{name}': missing (nor is there D_{name})")
    height, width = (_yaml_number(path, storage, name, f"{axis}_{name}") for axis in "HW")
    if (height is None) != (width is None):
        missing = "H" if height is None else "W"
        raise CalibrationError(f"{path}: camera '{name}', key '{missing}_{name}': missing (the other side is there)")
    if height is not None and min(height, width) <= 0:
        height = width = None  # EasyMocap's reader fills -1 for a size it lacks, and its writer writes that back
    if height is None and image_size is None:
        raise CalibrationError(
            f"{path}: camera '{name}', key 'H_{name}': missing or -1 (unknown); pass image_size=(width, height)")
    return {
        "K": K,
        "dist": _opencv_distortion(f"{path}: camera '{name}', key '{dist_key}'", dist, 4),
        "image_size": np.asarray(image_size if height is None else (width, height), np.float64),
    }


def _easymocap_extrinsics(path: Path, storage: cv2.FileStorage, name: str) -> dict[str, np.ndarray]:
    rvec = _yaml_vector3(path, storage, name, f"R_{name}", required=False)
    R = _yaml_matrix(path, storage, name, f"Rot_{name}", (3, 3), required=False)
    if R is None and rvec is None:
        raise CalibrationError(f"{path}: camera '{name}', key 'R_{name}': missing (nor is there Rot_{name})")
    if R is None:
        R = cv2.Rodrigues(rvec)[0]
    else:
        _check_rotation(f"{path}: camera '{name}', key 'Rot_{name}'", R)
        if rvec is not None and (gap := np.abs(cv2.Rodrigues(rvec)[0] - R).max()) > _ROTATION_TOLERANCE:
            raise CalibrationError(
                f"{path}: camera '{name}', key 'R_{name}': its rotation differs from Rot_{name} by up to {gap:.2g}")
    return {"R": R, "t": _yaml_vector3(path, storage, name, f"T_{name}", required=True)}


def load_easymocap_calibration(
    folder_or_intri: str | PathLike,
    extri: str | PathLike | None = None,
    *,
    image_size: Sequence[float | int] | np.ndarray | None = None,
) -> Calibration:
    """Load EasyMocap's ``intri.yml`` and ``extri.yml`` (a folder holding both, or the intri file and,
    by default, the ``extri.yml`` beside it), cameras in the order of intri's ``names``.

    ``image_size`` [width, height] is used for cameras without ``H_``/``W_`` (older EasyMocap files),
    and is required when some camera lacks them."""
    intri_path = Path(folder_or_intri)
    if intri_path.is_dir():
        intri_path = intri_path / "intri.yml"
    extri_path = intri_path.with_name("extri.yml") if extri is None else Path(extri)
    intri_storage, extri_storage = _open_yaml(intri_path), _open_yaml(extri_path)
    names = _yaml_names(intri_path, intri_storage)
    extri_names = _yaml_names(extri_path, extri_storage)
    if set(extri_names) != set(names):
        raise CalibrationError(
            f"{extri_path}: key 'names': {list(extri_names)} differ from {intri_path.name}'s {list(names)}")
    cameras = [
        {**_easymocap_intrinsics(intri_path, intri_storage, name, image_size),
         **_easymocap_extrinsics(extri_path, extri_storage, name)}
        for name in names
    ]
    return Calibration(_stack(cameras), names)


def _write_yaml(path: Path, names: tuple[str, ...], fields: dict[str, list]) -> None:
    """``names``, then each camera's ``<field>_<name>`` in the order of ``fields``, the layout EasyMocap writes."""

    def write(temporary: Path) -> None:
        storage = cv2.FileStorage(str(temporary), cv2.FILE_STORAGE_WRITE)
        storage.startWriteStruct("names", cv2.FileNode_SEQ)
        for name in names:
            storage.write("", name)
        storage.endWriteStruct()
        for i, name in enumerate(names):
            for field, values in fields.items():
                storage.write(f"{field}_{name}", values[i])
        storage.release()

    replace_file(path, write)


def save_easymocap_calibration(folder: str | PathLike, calibration: Calibration) -> None:
    """Write ``intri.yml`` and ``extri.yml`` into ``folder`` (made if missing), the inverse of
    :func:`load_easymocap_calibration`: full double precision, ``H_``/``W_`` included."""
    folder = Path(folder)
    arrays = _check_calibration(folder, calibration)
    for name in calibration.names:
        if not _NAME_AS_KEY.fullmatch(name):
            raise CalibrationError(f"{folder}: camera '{name}': an EasyMocap camera name becomes part of OpenCV keys "
                                   "(K_<name>): letters, digits, '_' and '-' (words split by one space), not "
                                   "true, false or null")
    sizes = [_image_size_values(size) for size in arrays["image_size"]]
    _write_yaml(folder / "intri.yml", calibration.names, {
        "K": list(arrays["K"]),
        "dist": [dist[None] for dist in arrays["dist"]],
        "H": [height for _, height in sizes],
        "W": [width for width, _ in sizes],
    })
    _write_yaml(folder / "extri.yml", calibration.names, {
        "R": [cv2.Rodrigues(R)[0] for R in arrays["R"]],
        "Rot": list(arrays["R"]),
        "T": [t[:, None] for t in arrays["t"]],
    })


# --------------------------------------------------------------------------------------------
# aniposelib: calibration.toml


def _read_toml(path: Path) -> dict:
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as error:
        raise CalibrationError(f"{path}: cannot read calibration file: {error}") from error
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as error:
        # tomllib ends its message with "(at line L, column C)" or "(at end of document)".
        found = re.fullmatch(r"(.*) \(at line (\d+), column (\d+)\)", str(error))
        raise CalibrationError(f"{path}:{found[2]}:{found[3]}: invalid TOML: {found[1]}" if found else
                               f"{path}:{max(1, len(text.splitlines()))}: invalid TOML: {error}") from error


def load_anipose_calibration(path: str | PathLike, *, metres_per_unit: float = 1.0) -> Calibration:
    """Load an aniposelib ``calibration.toml`` (the file, or a folder holding it), cameras ordered by
    section number. ``metres_per_unit`` converts ``translation`` to metres (0.001 for a board in mm)."""
    _check_unit(metres_per_unit)
    path = Path(path)
    if path.is_dir():
        path = path / "calibration.toml"
    sections = {key: value for key, value in _read_toml(path).items() if key != "metadata"}
    expected = [f"cam_{i}" for i in range(len(sections))]
    if not sections or sorted(sections, key=lambda key: (len(key), key)) != expected:
        raise CalibrationError(f"{path}: expected tables [cam_0]..[cam_{max(len(sections), 1) - 1}] and an optional "
                               f"[metadata], got {sorted(sections)}")
    names, cameras = [], []
    for key in expected:
        section = sections[key]
        if not isinstance(section, dict):
            raise CalibrationError(f"{path}: camera '{key}': expected a table [{key}]")
        if not isinstance(section.get("name"), str):
            problem = "missing" if "name" not in section else f"expected a string, got {section['name']!r}"
            raise CalibrationError(f"{path}: camera '{key}', key 'name': {problem}")
        if section.get("fisheye", False):
            raise CalibrationError(f"{path}: camera '{key}', key 'fisheye': OpenCV's fisheye model is not supported")
        names.append(section["name"])
        cameras.append({
            "K": _entry_array(path, key, section, "matrix", (3, 3)),
            "R": cv2.Rodrigues(_entry_array(path, key, section, "rotation", (3,)))[0],
            "t": _entry_array(path, key, section, "translation", (3,)) * metres_per_unit,
            "dist": _opencv_distortion(f"{path}: camera '{key}', key 'distortions'",
                                       _entry_array(path, key, section, "distortions", None), 0),
            "image_size": _entry_array(path, key, section, "size", (2,)),
        })
    if len(set(names)) != len(names):
        raise CalibrationError(f"{path}: key 'name': camera names repeat: {names}")
    return Calibration(_stack(cameras), tuple(names))


def _toml_string(text: str) -> str:
    """A TOML basic string: quotes, backslashes and control characters escaped."""
    return '"' + "".join(
        f"\\u{ord(c):04x}" if c in '"\\' or ord(c) < 0x20 or ord(c) == 0x7F else c for c in text) + '"'


def _toml_array(values: Iterable[float | int | str]) -> str:
    """aniposelib's layout (the ``toml`` package's): ``[ 1.0, 2.0,]``; ``repr`` keeps every float digit."""
    return "[ " + ", ".join(v if isinstance(v, str) else repr(v) for v in values) + ",]"


def save_anipose_calibration(path: str | PathLike, calibration: Calibration, *, metres_per_unit: float = 1.0) -> None:
    """Write an aniposelib ``calibration.toml``, the inverse of :func:`load_anipose_calibration`: the
    translation divided by ``metres_per_unit``, the Rodrigues vector from ``cv2.Rodrigues``."""
    _check_unit(metres_per_unit)
    path = Path(path)
    arrays = _check_calibration(path, calibration)
    lines = []
    for i, (name, K, R, t, dist, size) in enumerate(zip(calibration.names, *arrays.values())):
        lines += [
            f"[cam_{i}]",
            f"name = {_toml_string(name)}",
            f"size = {_toml_array(_image_size_values(size))}",
            f"matrix = {_toml_array(_toml_array(row.tolist()) for row in K)}",
            f"distortions = {_toml_array(dist.tolist())}",
            f"rotation = {_toml_array(cv2.Rodrigues(R)[0].ravel().tolist())}",
            f"translation = {_toml_array((t / metres_per_unit).tolist())}",
            "",
        ]
    lines += ["[metadata]", ""]
    replace_file(path, lambda temporary: temporary.write_text("\n".join(lines), encoding="utf-8"))


# --------------------------------------------------------------------------------------------
# Every layout


def _needs_image_size(path: Path, image_size, what: str) -> None:
    if image_size is None:
        raise CalibrationError(f"{path}: {what} does not store the image size; pass image_size=(width, height)")


def load_calibration(
    path: str | PathLike,
    *,
    image_size: Sequence[float | int] | np.ndarray | None = None,
    metres_per_unit: float = 1.0,
) -> Calibration:
    """Load a calibration in any supported layout, recognised from the path:

    - a folder with ``intri.yml`` and ``extri.yml``: EasyMocap;
    - ``calibration.toml`` or a folder holding it: aniposelib (``metres_per_unit`` converts its unit);
    - a ``.json`` file: VoxelPose when its cameras have ``fx``, 4D Association when they have ``K`` and ``RT``;
    - a folder of ``P<i>.txt``: TUM projection matrices.

    ``image_size`` [width, height] is needed only where the file lacks it (VoxelPose, TUM, EasyMocap
    without ``H_``/``W_``); a folder holding several layouts is refused rather than guessed."""
    path = Path(path)
    if path.is_dir():
        found = [layout for layout, present in (
            ("EasyMocap", (path / "intri.yml").is_file() and (path / "extri.yml").is_file()),
            ("anipose", (path / "calibration.toml").is_file()),
            ("TUM", bool(_projection_files(path))),
        ) if present]
        if len(found) > 1:
            raise CalibrationError(f"{path}: holds calibrations in several layouts ({', '.join(found)}); "
                                   "call that format's loader")
        if found == ["EasyMocap"]:
            return load_easymocap_calibration(path, image_size=image_size)
        if found == ["anipose"]:
            return load_anipose_calibration(path, metres_per_unit=metres_per_unit)
        if found == ["TUM"]:
            _needs_image_size(path, image_size, "a folder of TUM projection matrices")
            names = tuple(str(number) for number, _ in _projection_files(path))
            return Calibration(load_projection_matrices(path, image_size=image_size), names)
    elif path.suffix == ".toml":
        return load_anipose_calibration(path, metres_per_unit=metres_per_unit)
    elif path.suffix == ".json":
        entries = _read_json(path)
        names = tuple(entries)
        if "fx" in entries["0"]:
            _needs_image_size(path, image_size, "a VoxelPose calibration")
            return Calibration(load_voxelpose_calibration(path, image_size=image_size), names)
        if "K" in entries["0"] and "RT" in entries["0"]:
            return Calibration(load_4dassociation_calibration(path), names)
        raise CalibrationError(f"{path}: camera '0' has neither 'fx' (VoxelPose) nor 'K' and 'RT' (4D Association)")
    what = "not a calibration layout" if path.exists() else "no such file or folder"
    raise CalibrationError(f"{path}: {what}; expected {'; or '.join(_LAYOUTS)}")


def save_calibration(
    path: str | PathLike, calibration: Calibration, format: str, *, metres_per_unit: float = 1.0
) -> None:
    """Write a calibration in one of :data:`CALIBRATION_FORMATS`, atomically: ``path`` is the folder for
    ``"easymocap"`` and the file otherwise. The JSON formats name cameras by position, so they drop
    ``names``; ``metres_per_unit`` sets anipose's translation unit."""
    if format == "easymocap":
        save_easymocap_calibration(path, calibration)
    elif format == "anipose":
        save_anipose_calibration(path, calibration, metres_per_unit=metres_per_unit)
    elif format == "voxelpose":
        save_voxelpose_calibration(path, calibration.rig)
    elif format == "4dassociation":
        save_4dassociation_calibration(path, calibration.rig)
    else:
        raise ValueError(f"unknown calibration format {format!r}; expected one of {CALIBRATION_FORMATS}")

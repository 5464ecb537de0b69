"""A trained NNX model on disk: ``config.json`` (its config dataclass) and ``state.npz`` (its variables).

``state.npz`` is a compressed numpy archive with one entry per variable, named by its NNX path. A floating-point
array is stored as its byte planes: the entry ``PATH|byte planes of DTYPE`` holds uint8 ``(itemsize, *shape)``,
plane ``i`` the ``i``-th little-endian byte of every element. Weights' low bytes are close to random, but their high
bytes (sign, exponent) repeat, and laid out together they compress: rewritten so by ``experiments.store_models``
(2026-12-01), the eighteen shipped float16 models went from 64.9 MiB of uncompressed arrays to 55.7 MiB, which
keeps the repository small enough to travel to the GPU machine (``tests/test_repository.py``). Archives of plain
arrays, as the project wrote them before, still load."""

from __future__ import annotations

import json
import math
import os
import zipfile
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx

from ._files import _write_temporary
from ._loop import to_jsonable

__all__ = ["STORAGE_DTYPES", "load_model_state", "read_model_arrays", "save_model", "store_model_as"]

M = TypeVar("M", bound=nnx.Module)


def _storable(state: Any) -> Any:
    """The state without RNG keys and counters (they only seed training-time randomness)."""
    return nnx.filter_state(state, nnx.Not(nnx.RngState))


STORAGE_DTYPES = ("float32", "float16")
"""What :func:`save_model` and :func:`store_model_as` may store a model's floating-point arrays in: float16 halves
the files (the project ships its larger models so); loading casts them back to the model's own dtype."""


def save_model(path: str | Path, config: Any, state: Any, *, dtype: str | None = None) -> None:
    """Write a model's config dataclass and its NNX ``state`` (for example ``nnx.merge_state(params, rest)``);
    ``dtype`` (one of :data:`STORAGE_DTYPES`) stores every floating-point array in that precision.

    Both files are written in full to temporary files in the folder and only then renamed into place, so a
    killed run leaves the previous model (or none), never a truncated file."""
    path = Path(path)
    config_text = (json.dumps(to_jsonable(config), indent=2) + "\n").encode()
    leaves = jax.tree_util.tree_flatten_with_path(_storable(state))[0]
    arrays = {jax.tree_util.keystr(k): np.asarray(v) for k, v in leaves}
    _write_model(path, {"state.npz": _stored_arrays(arrays, dtype, path), "config.json": config_text})


def store_model_as(path: str | Path, dtype: str) -> None:
    """Rewrite the model folder ``path`` (:func:`save_model`) with its floating-point arrays in ``dtype`` (one of
    :data:`STORAGE_DTYPES`), atomically; its config is kept. How a trained model becomes a compact shipped one."""
    path = Path(path)
    _check_model_folder(path)
    _read_config(path / "config.json")
    _write_model(path, {"state.npz": _stored_arrays(_read_arrays(path / "state.npz"), dtype, path)})


_BYTE_PLANES = "|byte planes of "
"""What separates a variable's path from its dtype in the name of an entry stored as byte planes."""


def _to_byte_planes(name: str, array: np.ndarray) -> tuple[str, np.ndarray]:
    """The archive entry of one array: floating-point ones as byte planes (module docstring), others as they are."""
    if array.dtype.kind != "f":
        return name, array
    little = np.ascontiguousarray(array, dtype=array.dtype.newbyteorder("<")).reshape(-1)
    planes = little.view(np.uint8).reshape(array.size, array.itemsize).T
    return f"{name}{_BYTE_PLANES}{array.dtype.name}", planes.reshape((array.itemsize, *array.shape))


def _from_byte_planes(entry: str, stored: np.ndarray, path: Path) -> tuple[str, np.ndarray]:
    """The variable path and array of one archive entry (inverse of :func:`_to_byte_planes`)."""
    name, planes, dtype_name = entry.partition(_BYTE_PLANES)
    if not planes:
        return name, stored
    try:
        dtype = np.dtype(dtype_name).newbyteorder("<")
    except TypeError:
        dtype = None
    if dtype is None or dtype.kind != "f" or stored.dtype != np.uint8 or stored.shape[:1] != (dtype.itemsize,):
        raise ValueError(f"{path}: entry {entry} is not the byte planes of a {dtype_name} array "
                         f"(stored: {stored.dtype}{list(stored.shape)})")
    elements = np.ascontiguousarray(stored.reshape(dtype.itemsize, math.prod(stored.shape[1:])).T)
    return name, elements.view(dtype).reshape(stored.shape[1:]).astype(dtype.newbyteorder("="))


def _stored_arrays(arrays: dict[str, np.ndarray], dtype: str | None, path: Path) -> dict[str, np.ndarray]:
    """``arrays`` with the floating-point ones cast to ``dtype`` (``None``: as they are); refuses a value that
    overflows it rather than storing an infinity."""
    if dtype is None:
        return arrays
    if dtype not in STORAGE_DTYPES:
        raise ValueError(f"storage dtype must be one of {', '.join(STORAGE_DTYPES)}, got {dtype!r}")
    stored = {}
    for name, array in arrays.items():
        if np.issubdtype(array.dtype, np.floating):
            with np.errstate(over="ignore"):  # an overflow is refused just below, by name
                cast = array.astype(dtype)
            if not np.array_equal(np.isfinite(cast), np.isfinite(array)):
                raise ValueError(f"{path}: array {name} does not fit in {dtype} (largest magnitude "
                                 f"{np.nanmax(np.abs(array)):.4g})")
            array = cast
        stored[name] = array
    return stored


def _write_model(path: Path, contents: dict[str, dict[str, np.ndarray] | bytes]) -> None:
    """Write each named file of a model folder (arrays: ``state.npz``; bytes: as they are) to a temporary file,
    then rename them all into place, in the order given."""
    path.mkdir(parents=True, exist_ok=True)

    def writer(content: dict[str, np.ndarray] | bytes) -> Callable[[Any], None]:
        if isinstance(content, bytes):
            return lambda file: file.write(content)
        return lambda file: np.savez_compressed(file, **dict(_to_byte_planes(*item) for item in content.items()))

    written = {}
    try:
        for name, content in contents.items():
            written[name] = _write_temporary(path / name, writer(content))
    except BaseException:
        for temporary in written.values():
            temporary.unlink()
        raise
    for name in contents:
        os.replace(written[name], path / name)
    directory = os.open(path, os.O_RDONLY)
    try:
        os.fsync(directory)  # the renames themselves reach the disk
    finally:
        os.close(directory)


def _check_model_folder(path: Path) -> None:
    missing = [name for name in ("config.json", "state.npz") if not (path / name).is_file()]
    if missing:
        raise FileNotFoundError(f"{path} is not a saved model folder: no {', '.join(missing)}")


def _read_config(path: Path) -> dict[str, Any]:
    try:
        fields = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise ValueError(f"{path} is not valid JSON (truncated or corrupt: {error})") from None
    if not isinstance(fields, dict):
        raise ValueError(f"{path} must hold a JSON object of config fields, got {type(fields).__name__}")
    return fields


def read_model_arrays(path: str | Path) -> dict[str, np.ndarray]:
    """The arrays of the model folder ``path`` (:func:`save_model`) by variable path (``"['kernel'].value"``), in
    the precision they are stored in; no model is built."""
    path = Path(path)
    _check_model_folder(path)
    return _read_arrays(path / "state.npz")


def _read_arrays(path: Path) -> dict[str, np.ndarray]:
    try:
        # Opened here, not by np.load, which leaves its own handle open when the zip directory is unreadable.
        with path.open("rb") as file, np.load(file, allow_pickle=False) as arrays:
            stored = {entry: arrays[entry] for entry in arrays.files}
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError) as error:
        raise ValueError(f"{path} cannot be read (truncated or corrupt: {error})") from None
    return dict(_from_byte_planes(entry, array, path) for entry, array in stored.items())


def load_model_state(path: str | Path, build: Callable[[dict[str, Any]], M]) -> M:
    """The model saved by :func:`save_model` at ``path``: ``build(config fields)`` makes a fresh model of the
    right structure (lists in the JSON become tuples), then its variables are replaced by the stored ones (arrays
    stored in another floating-point precision are cast to the model's)."""
    path = Path(path)
    _check_model_folder(path)
    fields = _read_config(path / "config.json")
    fields = {k: tuple(v) if isinstance(v, list) else v for k, v in fields.items()}
    # The structure is traced abstractly: initialising every layer eagerly only to overwrite it cost most of a load.
    model = nnx.eval_shape(lambda: build(fields))
    stored = _storable(nnx.state(model))
    leaves, treedef = jax.tree_util.tree_flatten_with_path(stored)
    state_path = path / "state.npz"
    arrays = _read_arrays(state_path)
    absent = [jax.tree_util.keystr(k) for k, _ in leaves if jax.tree_util.keystr(k) not in arrays]
    if absent:
        raise ValueError(f"{state_path} does not match the model of its config.json: no {absent[:3]}")
    for key, expected in leaves:
        name, array = jax.tree_util.keystr(key), arrays[jax.tree_util.keystr(key)]
        recast = np.issubdtype(array.dtype, np.floating) and jnp.issubdtype(expected.dtype, jnp.floating)
        if array.shape != expected.shape or (array.dtype != expected.dtype and not recast):
            raise ValueError(f"{state_path} does not match the model of its config.json: array {name} is "
                             f"{array.dtype}{list(array.shape)}, the model expects "
                             f"{expected.dtype}{list(expected.shape)}")
    values = [jnp.asarray(arrays[jax.tree_util.keystr(k)], dtype=expected.dtype) for k, expected in leaves]
    nnx.update(model, jax.tree_util.tree_unflatten(treedef, values))
    if jax.tree.leaves(nnx.state(model, nnx.RngState)):
        # The RNG keys and counters are not stored: the ones a fresh build has (one jitted build, the rest of
        # whose initialisation XLA drops).
        nnx.update(model, jax.jit(lambda: nnx.state(build(fields), nnx.RngState))())
    return model

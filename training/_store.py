"""A trained NNX model on disk: ``config.json`` (its config dataclass) and ``state.npz`` (its variables)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx

from ._loop import to_jsonable

__all__ = ["load_model_state", "save_model"]

M = TypeVar("M", bound=nnx.Module)


def _storable(state: Any) -> Any:
    """The state without RNG keys and counters (they only seed training-time randomness)."""
    return nnx.filter_state(state, nnx.Not(nnx.RngState))


def save_model(path: str | Path, config: Any, state: Any) -> None:
    """Write a model's config dataclass and its NNX ``state`` (for example ``nnx.merge_state(params, rest)``)."""
    path = Path(path)
    path.mkdir(parents=True, exist_ok=True)
    (path / "config.json").write_text(json.dumps(to_jsonable(config), indent=2) + "\n")
    leaves = jax.tree_util.tree_flatten_with_path(_storable(state))[0]
    np.savez(path / "state.npz", **{jax.tree_util.keystr(k): np.asarray(v) for k, v in leaves})


def load_model_state(path: str | Path, build: Callable[[dict[str, Any]], M]) -> M:
    """The model saved by :func:`save_model` at ``path``: ``build(config fields)`` makes a fresh model of the
    right structure (lists in the JSON become tuples), then its variables are replaced by the stored ones."""
    path = Path(path)
    missing = [name for name in ("config.json", "state.npz") if not (path / name).is_file()]
    if missing:
        raise FileNotFoundError(f"{path} is not a saved model folder: no {', '.join(missing)}")
    fields = json.loads((path / "config.json").read_text())
    fields = {k: tuple(v) if isinstance(v, list) else v for k, v in fields.items()}
    # The structure is traced abstractly: initialising every layer eagerly only to overwrite it cost most of a load.
    model = nnx.eval_shape(lambda: build(fields))
    stored = _storable(nnx.state(model))
    leaves, treedef = jax.tree_util.tree_flatten_with_path(stored)
    with np.load(path / "state.npz") as arrays:
        absent = [jax.tree_util.keystr(k) for k, _ in leaves if jax.tree_util.keystr(k) not in arrays]
        if absent:
            raise ValueError(f"{path / 'state.npz'} does not match the model of its config.json: no {absent[:3]}")
        values = [jnp.asarray(arrays[jax.tree_util.keystr(k)], v.dtype) for k, v in leaves]
    nnx.update(model, jax.tree_util.tree_unflatten(treedef, values))
    if jax.tree.leaves(nnx.state(model, nnx.RngState)):
        # The RNG keys and counters are not stored: the ones a fresh build has (one jitted build, the rest of
        # whose initialisation XLA drops).
        nnx.update(model, jax.jit(lambda: nnx.state(build(fields), nnx.RngState))())
    return model

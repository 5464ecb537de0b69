"""Rewrite trained model folders in a compact precision: how a trained model becomes a shipped one.

    python -m experiments.store_models dynamics/assets/phdt/phdt flex/assets/flex_4views [--dtype float16]

Each MODEL is a folder written by ``training.save_model`` (``config.json`` + ``state.npz``); its floating-point
arrays are rewritten in --dtype (float16: half the size), atomically, and read back in the model's own precision
by every loader. Prints each folder's size before and after.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Literal

import tyro

import training
from experiments import _cli


@dataclasses.dataclass(frozen=True)
class Config:
    models: tyro.conf.Positional[tuple[Path, ...]]
    """Model folders, each with config.json and state.npz."""
    dtype: Literal[training.STORAGE_DTYPES] = "float16"  # type: ignore[valid-type]
    """Precision the floating-point arrays are stored in (training.STORAGE_DTYPES)."""

    def __post_init__(self) -> None:
        if not self.models:
            raise ValueError("name at least one model folder")
        for folder in self.models:
            missing = [name for name in ("config.json", "state.npz") if not (folder / name).is_file()]
            if missing:
                raise ValueError(f"{folder} is not a saved model folder: no {', '.join(missing)}")


def main(config: Config) -> None:
    for folder in config.models:
        before = (folder / "state.npz").stat().st_size
        training.store_model_as(folder, config.dtype)
        print(f"{folder}: state.npz {before / 2**20:.2f} MiB -> {(folder / 'state.npz').stat().st_size / 2**20:.2f} "
              f"MiB ({config.dtype})")


if __name__ == "__main__":
    _cli.run(main, Config, description=__doc__)

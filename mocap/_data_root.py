"""The one place that finds the real-data folder (``--data-root`` or ``$MVMOCAP_DATA_ROOT``)."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["find_data_root"]

DATA_ROOT_VARIABLE = "MVMOCAP_DATA_ROOT"


def find_data_root(path: str | os.PathLike | None = None, needs: str | None = None) -> Path | None:
    """The data folder: ``path`` when given, else ``$MVMOCAP_DATA_ROOT`` when set, else None (no guessing).

    ``needs``: an entry the folder must hold (``"shelf"``, ``"cmu_mocap"``, ...). A folder that was named
    (by ``path`` or the variable) but does not exist or lacks ``needs`` is a one-line ValueError naming it.
    """
    if path is not None:
        root, origin = Path(path), "data folder"
    elif os.environ.get(DATA_ROOT_VARIABLE):
        root, origin = Path(os.environ[DATA_ROOT_VARIABLE]), f"${DATA_ROOT_VARIABLE}"
    else:
        return None
    if not root.is_dir():
        raise ValueError(f"{origin} {root} is not a folder")
    if needs is not None and not (root / needs).exists():
        raise ValueError(f"{origin} {root} holds no {needs}")
    return root

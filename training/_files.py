"""Files written whole or not at all."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO

__all__ = ["write_atomically"]


def write_atomically(path: str | Path, write: Callable[[BinaryIO], None]) -> None:
    """Write a file whole or not at all: ``write(binary file)`` fills a temporary file next to ``path``, which
    reaches the disk and only then replaces ``path``; a killed or failing writer leaves the previous file (or
    none), never a truncated one. The one way the project writes caches, records and models."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    os.replace(_write_temporary(path, write), path)


def _write_temporary(path: Path, write: Callable[[BinaryIO], None]) -> Path:
    """``write(binary file)`` into a hidden temporary file next to ``path``, flushed to disk; returns its path
    for :func:`os.replace` (removed if ``write`` fails)."""
    descriptor, temporary = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".partial")
    try:
        with os.fdopen(descriptor, "wb") as file:
            write(file)
            file.flush()
            os.fsync(file.fileno())
    except BaseException:
        os.unlink(temporary)
        raise
    return Path(temporary)

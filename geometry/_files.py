"""Files that appear whole or not at all."""

from __future__ import annotations

import os
import secrets
from collections.abc import Callable
from pathlib import Path

__all__ = ["replace_file"]


def replace_file(path: str | os.PathLike, write: Callable[[Path], None]) -> None:
    """``write(temporary)`` fills a new file beside ``path``, which then replaces ``path`` (:func:`os.replace`): a
    reader never sees a half-written file, and a killed or failing writer leaves the previous file (or none).

    The temporary file is hidden and keeps ``path``'s suffix, because OpenCV, Pillow and ffmpeg choose the format
    from it; it is created with the umask's permissions, as the finished file should be. The one way the project
    replaces a file outside training, whose :func:`training.write_atomically` also flushes checkpoints, caches and
    models to disk and commits a model's two files together."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.stem}.{secrets.token_hex(6)}.partial{path.suffix}")
    try:
        write(temporary)
        os.replace(temporary, path)
    finally:
        temporary.unlink(missing_ok=True)

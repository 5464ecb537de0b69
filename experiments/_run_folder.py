"""Run folders replaced as a whole: a run writes into a fresh staging folder that becomes ``--out`` on success."""

from __future__ import annotations

import contextlib
import datetime
import json
import os
import shutil
from collections.abc import Iterator, Sequence
from pathlib import Path

import training

__all__ = ["run_folder"]


def _now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")


@contextlib.contextmanager
def run_folder(out: str | os.PathLike, keep: Sequence[str] = ()) -> Iterator[Path]:
    """Yield a fresh, empty staging folder beside ``out`` for the run's outputs; when the block succeeds, write
    ``run.json`` (:func:`training.provenance`, ``started``, ``finished``) there and replace ``out`` with it.

    A failed run (any exception) deletes the staging folder and leaves ``out`` as it was: never a mix of old
    and new outputs. ``keep`` names entries of ``out`` that a run writes in place because they must survive a
    kill (resumable training workdirs such as ``train``): they are moved into the new folder, not staged.
    """
    out = Path(out).absolute()
    if out.exists() and not out.is_dir():  # replacing it would move the file aside after the run's work
        raise ValueError(f"--out {out} is a file, not a folder")
    out.parent.mkdir(parents=True, exist_ok=True)
    record = {**training.provenance(), "started": _now()}  # what starts the run, not what is there at its end
    staging = Path(f"{out.parent / ('.' + out.name)}.staging-{os.getpid()}")
    shutil.rmtree(staging, ignore_errors=True)  # a leftover of a killed run with the same process id
    staging.mkdir()
    try:
        yield staging
        (staging / "run.json").write_text(json.dumps({**record, "finished": _now()}, indent=2) + "\n")
        for name in keep:
            if (out / name).exists():
                (out / name).replace(staging / name)
        if out.exists():
            previous = Path(f"{out.parent / ('.' + out.name)}.previous-{os.getpid()}")
            out.replace(previous)
            staging.replace(out)
            shutil.rmtree(previous)
        else:
            staging.replace(out)
    finally:
        shutil.rmtree(staging, ignore_errors=True)

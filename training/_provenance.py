"""What made a run: package versions, the git commit, the command line and the device (``run.json``)."""

from __future__ import annotations

import importlib.metadata
import os
import platform
import subprocess
import sys
from pathlib import Path
from typing import Any

__all__ = ["provenance"]

PACKAGES = ("jax", "jaxlib", "flax", "optax", "optimistix", "orbax-checkpoint", "numpy", "opencv-python-headless",
            "scipy", "mvmocap")
"""Distributions whose versions a run records (None where one is not installed)."""

_REPOSITORY = Path(__file__).resolve().parents[1]


def _version(distribution: str) -> str | None:
    try:
        return importlib.metadata.version(distribution)
    except importlib.metadata.PackageNotFoundError:
        return None


def _git() -> dict[str, Any]:
    """The code's commit and whether its tree differs from it (both None outside a git checkout)."""
    def git(*args: str) -> str:
        return subprocess.run(["git", "-C", str(_REPOSITORY), *args], capture_output=True, text=True, check=True,
                              timeout=30).stdout.strip()

    try:
        return {"commit": git("rev-parse", "HEAD"), "dirty": bool(git("status", "--porcelain", "--untracked-files=no"))}
    except (OSError, subprocess.SubprocessError):
        return {"commit": None, "dirty": None}


def _cpu_model() -> str | None:
    try:
        with open("/proc/cpuinfo") as stream:
            for line in stream:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or None


def provenance() -> dict[str, Any]:
    """A JSON-ready record of what is running now: ``versions`` (python and :data:`PACKAGES`), ``git``
    (``commit``, ``dirty``), ``argv``, ``cwd`` and ``device`` (jax platform, device kind and count, CPU model
    and cores). Asking jax for its devices starts its backend: call this once the runtime is configured."""
    import jax

    devices = jax.devices()
    return {
        "versions": {"python": platform.python_version(), **{name: _version(name) for name in PACKAGES}},
        "git": _git(),
        "argv": list(sys.argv),
        "cwd": os.getcwd(),
        "device": {"platform": jax.default_backend(), "kind": devices[0].device_kind, "count": len(devices),
                   "cpu": _cpu_model(), "cpu_count": os.cpu_count()},
    }

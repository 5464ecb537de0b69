"""What made a run: package versions, the git commit, the command line and the device (``run.json``)."""

from __future__ import annotations

import importlib.metadata
import os
import platform
import subprocess
import sys
from pathlib import Path
from typing import Any

__all__ = ["SIMD_FEATURES", "provenance"]

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


SIMD_FEATURES = ("sse4_2", "avx", "avx2", "fma", "avx512f", "avx512_vnni", "avx512_bf16")
"""CPU instruction sets a run records: XLA's CPU code depends on them, and results that hinge on borderline
decisions (Shelf tracking, docs/jcsat.md) have differed between installs."""


def _cpu() -> tuple[str | None, list[str] | None]:
    """The CPU model and which of :data:`SIMD_FEATURES` it has (from ``/proc/cpuinfo``; None where unknown)."""
    model, flags = None, None
    try:
        with open("/proc/cpuinfo") as stream:
            for line in stream:
                key, _, value = line.partition(":")
                if key.strip() == "model name" and model is None:
                    model = value.strip()
                elif key.strip() == "flags" and flags is None:
                    flags = set(value.split())
    except OSError:
        pass
    return model or platform.processor() or None, None if flags is None else [f for f in SIMD_FEATURES if f in flags]


def provenance() -> dict[str, Any]:
    """A JSON-ready record of what is running now: ``versions`` (python and :data:`PACKAGES`), ``git``
    (``commit``, ``dirty``), ``argv``, ``cwd``, ``xla_flags`` and ``device`` (jax platform, device kind and
    count, CPU model, instruction sets and cores). Asking jax for its devices starts its backend: call this once the runtime is configured."""
    import jax

    devices = jax.devices()
    cpu, cpu_features = _cpu()
    return {
        "versions": {"python": platform.python_version(), **{name: _version(name) for name in PACKAGES}},
        "git": _git(),
        "argv": list(sys.argv),
        "cwd": os.getcwd(),
        "xla_flags": os.environ.get("XLA_FLAGS"),
        "device": {"platform": jax.default_backend(), "kind": devices[0].device_kind, "count": len(devices),
                   "cpu": cpu, "cpu_features": cpu_features, "cpu_count": os.cpu_count()},
    }

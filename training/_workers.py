"""Data building in CPU-only worker processes, for the training runs that build their samples before they start."""

from __future__ import annotations

import multiprocessing
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor
from typing import TypeVar

import jax
import tqdm

__all__ = ["process_map"]

Result = TypeVar("Result")


def process_map(fn: Callable[..., Result], jobs: Sequence[Iterable], workers: int,
                progress: str | None = None) -> list[Result]:
    """``[fn(*job) for job in jobs]``, in ``workers`` spawned processes when ``workers > 1`` (in order), with a
    progress bar of finished jobs named ``progress`` (None: no bar).

    The workers run JAX on the CPU with the parent's precision, so that they stay off the accelerator the parent
    trains on; ``fn`` must be importable (a module-level function) and its arguments picklable."""
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    bar = lambda results: tqdm.tqdm(results, total=len(jobs), disable=progress is None, desc=progress)  # noqa: E731
    if workers == 1 or len(jobs) <= 1:
        return [fn(*job) for job in bar(jobs)]
    context = multiprocessing.get_context("spawn")  # a forked JAX runtime is not safe
    with ProcessPoolExecutor(min(workers, len(jobs)), mp_context=context, initializer=_cpu_worker,
                             initargs=(bool(jax.config.jax_enable_x64),)) as pool:
        return list(bar(pool.map(fn, *zip(*jobs))))


def _cpu_worker(enable_x64: bool) -> None:
    jax.config.update("jax_platforms", "cpu")
    jax.config.update("jax_enable_x64", enable_x64)

"""The resumable training loop and the data-parallel shardings (see the package docstring)."""

from __future__ import annotations

import dataclasses
import datetime
import json
import time
import warnings
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, TypeVar

import jax
import numpy as np
import orbax.checkpoint as ocp
import tqdm
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from ._files import write_atomically
from ._provenance import provenance

__all__ = ["check_same_run", "data_parallel_shardings", "run_training", "to_jsonable"]

S = TypeVar("S")
"""A training state: a NamedTuple of arrays with a ``step`` field."""


def to_jsonable(value: Any) -> Any:
    """Dataclasses (nested) as dicts, tuples as lists, anything else JSON cannot hold as its ``str``."""
    return json.loads(json.dumps(
        value, default=lambda v: dataclasses.asdict(v) if dataclasses.is_dataclass(v) else str(v)))


def data_parallel_shardings(batch_size: int) -> tuple[NamedSharding, NamedSharding]:
    """``(replicated, batch_sharded)`` on a one-axis ``"data"`` mesh over the local devices.

    On CPU, ``XLA_FLAGS=--xla_force_host_platform_device_count=N`` (set before jax starts) gives N devices."""
    devices = jax.local_devices()
    if batch_size % len(devices):
        raise ValueError(f"batch_size {batch_size} must be a multiple of the {len(devices)} local devices "
                         "(data parallelism splits every batch evenly)")
    mesh = Mesh(np.array(devices), ("data",))
    return NamedSharding(mesh, PartitionSpec()), NamedSharding(mesh, PartitionSpec("data"))


def _recorded(config: Any, independent_of: tuple[str, ...]) -> dict:
    """``config`` as its run's ``config.json`` holds it: JSON values, without the fields the run does not read."""
    return {name: value for name, value in to_jsonable(dataclasses.asdict(config)).items()
            if name not in independent_of}


def _config_differences(stored: dict, config: Any, independent_of: tuple[str, ...] = (), prefix: str = ""
                        ) -> list[str]:
    """The dotted names of the fields where ``config`` (a dataclass) and a run's stored ``config.json`` differ,
    leaving out the top-level fields named in ``independent_of``.

    A field the stored config lacks was added to the code after the run started: it counts as equal when
    ``config`` holds the field's default, because a new field's default keeps the program the run was trained by
    (``StageConfig.clip_norm=None``: no clipping)."""
    fields = {field.name: field for field in dataclasses.fields(config) if field.name not in independent_of}
    differences = [prefix + name for name in sorted(set(stored) - set(fields) - set(independent_of))]  # gone since
    for name, field in fields.items():
        value = getattr(config, name)
        if name not in stored:
            default = field.default_factory() if field.default_factory is not dataclasses.MISSING else field.default
            if default is dataclasses.MISSING or to_jsonable(value) != to_jsonable(default):
                differences.append(prefix + name)
        elif dataclasses.is_dataclass(value) and isinstance(stored[name], dict):
            differences += _config_differences(stored[name], value, prefix=f"{prefix}{name}.")
        elif stored[name] != to_jsonable(value):
            differences.append(prefix + name)
    return differences


def _truncate_log(path: Path, last_step: int) -> None:
    """Drop log lines past the restored step (or all of a run killed before its first checkpoint):
    the run writes them again, identically. A run killed while writing a line leaves it torn (the last line,
    not valid JSON): it is dropped with a warning; a bad line before the last is refused."""
    if not path.is_file():
        return
    lines = path.read_text().splitlines()
    records = []
    for number, line in enumerate(lines, 1):
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError:
            if number < len(lines):
                raise ValueError(f"{path}:{number} is not a JSON record (only a torn last line is dropped)") from None
            warnings.warn(f"{path}:{number}: dropped a torn last line (a run killed while logging)", stacklevel=3)
            lines = lines[:-1]
    kept = [line for line, record in zip(lines, records) if record["step"] <= last_step]
    path.write_text("".join(line + "\n" for line in kept))


def _checkpointed(state: Any) -> dict:
    """The fields of ``state`` a checkpoint holds: all but those that are None (a part the run does not keep, such
    as a moving average it does not take), so that adding such a field leaves older checkpoints restorable."""
    return {name: value for name, value in state._asdict().items() if value is not None}


def _restore_latest(manager: ocp.CheckpointManager, state: S) -> tuple[S, int]:
    """The state of the latest checkpoint that restores and its step. A newer one that does not (corrupt,
    half-deleted) is skipped with a warning naming its step and deleted once an older one restored, so the
    run saves that step again; when none restores, the latest one's error is raised and nothing deleted."""
    abstract = jax.tree.map(ocp.utils.to_shape_dtype_struct, state)
    failed: list[tuple[int, Exception]] = []
    for step in sorted(manager.all_steps(), reverse=True):
        try:
            restored = manager.restore(step, args=ocp.args.StandardRestore(_checkpointed(abstract)))
        except Exception as error:  # orbax and tensorstore raise many types for a damaged checkpoint
            failed.append((step, error))
            continue
        for skipped, error in failed:
            reason = f"{type(error).__name__}: {str(error).splitlines()[0] if str(error) else ''}"
            warnings.warn(f"resuming from checkpoint step {step}: skipped step {skipped} in {manager.directory}, "
                          f"which does not restore ({reason})", stacklevel=3)
            manager.delete(skipped)
        return type(state)(**restored), step
    step, error = failed[0]
    raise ValueError(f"no checkpoint in {manager.directory} restores; the latest (step {step}) fails with "
                     f"{type(error).__name__}") from error


def check_same_run(workdir: str | Path, config: Any, independent_of: tuple[str, ...] = ()) -> None:
    """Refuse ``config`` where ``workdir`` holds a run (its ``config.json``) of another config, naming the fields
    that differ: the rule by which :func:`run_training` resumes, for callers that reuse a finished run's model."""
    config_path = Path(workdir) / "config.json"
    if config_path.is_file():
        differences = _config_differences(json.loads(config_path.read_text()), config, independent_of)
        if differences:
            raise ValueError(f"{config_path} records a run of another config (it differs in "
                             f"{', '.join(differences[:4])}): resume only the same run")


def run_training(
    workdir: str | Path,
    config: Any,
    state: S,
    step: Callable[[S, int], tuple[S, Mapping[str, jax.Array]]],
    *,
    steps: int,
    resume: bool,
    log_interval: int,
    checkpoint_interval: int,
    validation_interval: int,
    validate: Callable[[S], Mapping[str, float]],
    replicated: NamedSharding,
    learning_rate: Callable[[int], Any] | None = None,
    independent_of: tuple[str, ...] = (),
    log: Callable[[dict], None] = lambda record: None,
    progress: bool = True,
    description: str = "train",
) -> S:
    """Run ``state = step(state, i)`` for ``i`` from the state's step count to ``steps`` in ``workdir``; return it.

    ``state`` is the step-0 state, a NamedTuple of arrays with a ``step`` field (the number of steps taken):
    exactly what a checkpoint holds (less its fields that are None). ``step`` must be a deterministic function of
    ``(state, i)`` (draw step i's randomness from ``fold_in(key, i)``), so that a resumed run repeats an
    uninterrupted one bit for bit. It returns the new state and the step's metrics.

    Files in ``workdir``: ``config.json`` (``config``, a dataclass, less its top-level fields named in
    ``independent_of``: those the run does not read, such as a later training stage's, so that changing them
    does not make it another run); ``run.json`` (:func:`provenance` of the
    latest invocation, resumed or not, and its start time); ``log.jsonl``, one JSON object per
    logged step (``step``, the metrics every ``log_interval`` steps with the ``learning_rate(i)`` as ``lr``
    and ``seconds_per_step``, ``validate(state)`` every ``validation_interval`` steps, both at the last);
    ``checkpoints/<step>/`` (orbax, atomic, the last two kept) every ``checkpoint_interval`` steps and at the
    end. ``resume=True`` continues from the latest checkpoint that restores (refusing a different config, by the
    fields that differ; a field the stored config lacks, added to the code since, must hold its default; a corrupt one
    is skipped with a warning for the one before it, a torn last log line dropped with a warning); ``resume=False``
    refuses a ``workdir`` that already has checkpoints. ``log`` receives every record written; ``progress``
    shows a tqdm bar. The state is kept on ``replicated`` devices.
    """
    for name, value in (("steps", steps), ("log_interval", log_interval), ("checkpoint_interval", checkpoint_interval),
                        ("validation_interval", validation_interval)):
        if value < 1:
            raise ValueError(f"{name} must be >= 1, got {value}")
    unknown = sorted(set(independent_of) - {field.name for field in dataclasses.fields(config)})
    if unknown:
        raise ValueError(f"independent_of names {unknown}, which {type(config).__name__} has no fields for")
    workdir = Path(workdir).resolve()
    workdir.mkdir(parents=True, exist_ok=True)
    config_json = json.dumps(_recorded(config, independent_of), indent=2, sort_keys=True) + "\n"
    config_path, log_path = workdir / "config.json", workdir / "log.jsonl"
    if resume:
        check_same_run(workdir, config, independent_of)

    options = ocp.CheckpointManagerOptions(max_to_keep=2)
    with ocp.CheckpointManager(workdir / "checkpoints", options=options) as manager:
        latest = manager.latest_step()
        if latest is not None and not resume:
            raise ValueError(f"{workdir} already has checkpoints (step {latest}); pass resume=True or a new workdir")
        if latest is not None:
            state, latest = _restore_latest(manager, state)
        _truncate_log(log_path, 0 if latest is None else latest)
        config_path.write_text(config_json)
        started = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
        record = (json.dumps({**provenance(), "started": started}, indent=2) + "\n").encode()
        write_atomically(workdir / "run.json", lambda file: file.write(record))
        state = jax.device_put(state, replicated)

        first = int(state.step)
        timer_start, timer_steps = None, 0
        # The bar is closed on an error or a kill too, so that what is printed next starts a line of its own.
        with (tqdm.tqdm(total=steps, initial=first, disable=not progress, desc=description) as bar,
              log_path.open("a") as log_file):
            for i in range(first, steps):
                state, metrics = step(state, i)
                done = i + 1
                timer_steps += 1
                record: dict[str, Any] = {}
                if done % log_interval == 0 or done == steps:
                    record.update({k: float(v) for k, v in metrics.items()})
                    if learning_rate is not None:
                        record["lr"] = float(learning_rate(i))
                    if timer_start is not None:
                        record["seconds_per_step"] = (time.perf_counter() - timer_start) / timer_steps
                    if "loss" in record:
                        bar.set_postfix(loss=f"{record['loss']:.4g}")
                if done % validation_interval == 0 or done == steps:
                    record.update(validate(state))
                if done % checkpoint_interval == 0 or done == steps:
                    manager.save(done, args=ocp.args.StandardSave(_checkpointed(state)))
                if record:
                    record = {"step": done, **record}
                    log_file.write(json.dumps(record) + "\n")
                    log_file.flush()
                    log(record)
                if record or timer_start is None:
                    # Timings cover training steps only: not the first (compiling) step, validation or saving.
                    jax.block_until_ready(state)
                    timer_start, timer_steps = time.perf_counter(), 0
                bar.update(1)
        manager.wait_until_finished()
    return state

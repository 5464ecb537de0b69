"""How many videos to render per training clip, and how many steps to train the conditioning stage on them, chosen
on validation: the conditioning stage (backbone and HMR head, :func:`dynamics.train_conditioning`) trained for each
candidate (renders per clip, steps) with several seeds, and scored on fresh validation renders of training clips
(:func:`dynamics.conditioning_metrics`) per clip.

More renders show the networks more camera distances and body shapes for the same motion; two renders per clip
(the default until 2026-11-28) left a depth bias on the two-person test take (docs/dynamics.md). More steps let the
backbone, trained from scratch, see each render more often. Scored: root-relative MPJPE, the error of the pelvis the
crop camera places, and its depth over the true depth."""

from __future__ import annotations

import dataclasses
import itertools
import json
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import jax

import geometry
import training
from dynamics import DataConfig, TrainConfig, build_frames, conditioning_metrics, train_conditioning
from experiments._stats import mean_and_sd

from ._report import digits
from ._seeds import mean_sd_cell

__all__ = ["renders_markdown", "renders_summary", "run_renders_study"]

_METRICS = {"mpjpe_mm": "MPJPE (mm)", "root_mm": "root (mm)", "depth_ratio": "depth / true depth"}


def run_renders_study(out: Path, workdir: Path, base: TrainConfig, renders: Sequence[int], steps: Sequence[int],
                      seeds: Sequence[int], validation: DataConfig, body: geometry.BodyModel, *,
                      log: Callable[[dict], None], progress: bool, data_workers: int) -> dict:
    """Train ``base`` (its data and model) with each number of ``renders`` per clip, each number of conditioning
    ``steps`` and each of ``seeds`` in ``workdir/renders<R>_steps<N>_seed<S>`` (resumable; one render cache in
    ``workdir/data_cache``), score each on ``validation`` per clip and write ``out/results.json`` and
    ``results.md``; returns the results."""
    started = time.perf_counter()
    cache_dir = (workdir / "data_cache").resolve()
    validation_frames = build_frames(validation, body, cache_dir, progress, data_workers)
    runs = []
    for count, stage_steps, seed in itertools.product(renders, steps, seeds):
        config = dataclasses.replace(base, data=dataclasses.replace(base.data, renders=count),
                                     image=dataclasses.replace(base.image, steps=stage_steps),
                                     validation=validation, seed=seed, cache_dir=str(cache_dir))
        candidate = {"renders": count, "steps": stage_steps, "seed": seed}
        model = train_conditioning(config, workdir / f"renders{count}_steps{stage_steps}_seed{seed}", body,
                                   resume=True, log=lambda record, candidate=candidate: log({**candidate, **record}),
                                   progress=progress, data_workers=data_workers)
        per_clip = {}
        for index, clip in enumerate(validation.clips):
            rows = validation_frames.clip == index
            per_clip[clip] = conditioning_metrics(body, model, jax.tree.map(lambda column: column[rows],
                                                                           validation_frames))
        per_clip["all"] = conditioning_metrics(body, model, validation_frames)
        runs.append({**candidate, "metrics": per_clip})
        log({**candidate, "validation": per_clip})
    results = {"config": {"base": base, "renders": list(renders), "steps": list(steps), "seeds": list(seeds),
                          "validation": validation},
               "runs": runs, "summary": renders_summary(runs),
               "seconds": round(time.perf_counter() - started, 1)}
    results = training.to_jsonable(results)
    (out / "results.json").write_text(json.dumps(results, indent=1) + "\n")
    (out / "results.md").write_text(renders_markdown(results))
    return results


def _candidate_name(run: dict) -> str:
    """A candidate's row label: its renders per clip and conditioning steps."""
    return f"renders {run['renders']}, steps {run['steps']}"


def renders_summary(runs: Sequence[dict]) -> dict[str, dict]:
    """Per candidate (:func:`_candidate_name`) and validation clip: each metric's mean and sample sd (0 for one seed)
    over the candidate's runs (``{"renders", "steps", "seed", "metrics": {clip: {metric: value}}}``)."""
    summary = {}
    for name in dict.fromkeys(map(_candidate_name, runs)):
        mine = [run["metrics"] for run in runs if _candidate_name(run) == name]
        summary[name] = {clip: {metric: mean_and_sd(*(metrics[clip][metric] for metrics in mine))
                                for metric in _METRICS}
                         for clip in mine[0]}
    return summary


def renders_markdown(results: dict) -> str:
    """One table per validation clip (and all frames): each candidate's metrics, mean ± sd over the seeds."""
    config, validation = results["config"], results["config"]["validation"]
    lines = ["# Renders per training clip and conditioning steps, chosen on validation", "",
             f"The conditioning stage trained for each candidate with seeds {config['seeds']} (mean ± sample "
             f"sd over them), scored on {validation['renders']} fresh render(s) of each of {validation['clips']} "
             f"(seed {validation['seed']}).", ""]
    for clip in next(iter(results["summary"].values())):
        lines += [f"## {clip}", "", "| candidate | " + " | ".join(_METRICS.values()) + " |",
                  "|---|" + "---|" * len(_METRICS)]
        for name, per_clip in results["summary"].items():
            lines.append(f"| {name} | " + " | ".join(mean_sd_cell(per_clip[clip][metric], digits=digits(metric))
                                                      for metric in _METRICS) + " |")
        lines.append("")
    return "\n".join(lines)

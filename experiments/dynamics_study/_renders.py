"""How many videos to render per training clip, chosen on validation: the conditioning stage (backbone and HMR
head, :func:`dynamics.train_conditioning`) trained on each candidate's renders with several seeds, the same steps,
and scored on fresh validation renders of training clips (:func:`dynamics.conditioning_metrics`) per clip.

More renders show the networks more camera distances and body shapes for the same motion; two renders per clip
(the default until 2026-11-28) left a depth bias on the two-person test take (docs/dynamics.md). Scored: root-relative
MPJPE, the error of the pelvis the crop camera places, and its depth over the true depth."""

from __future__ import annotations

import dataclasses
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


def run_renders_study(out: Path, workdir: Path, base: TrainConfig, renders: Sequence[int], seeds: Sequence[int],
                      validation: DataConfig, body: geometry.BodyModel, *, log: Callable[[dict], None],
                      progress: bool, data_workers: int) -> dict:
    """Train ``base`` (its data, steps and model) with each number of ``renders`` per clip and each of ``seeds`` in
    ``workdir/renders<R>_seed<S>`` (resumable; one render cache in ``workdir/data_cache``), score each on
    ``validation`` per clip and write ``out/results.json`` and ``results.md``; returns the results."""
    started = time.perf_counter()
    cache_dir = (workdir / "data_cache").resolve()
    validation_frames = build_frames(validation, body, cache_dir, progress, data_workers)
    runs = []
    for count in renders:
        for seed in seeds:
            config = dataclasses.replace(base, data=dataclasses.replace(base.data, renders=count),
                                         validation=validation, seed=seed, cache_dir=str(cache_dir))
            model = train_conditioning(config, workdir / f"renders{count}_seed{seed}", body, resume=True,
                                       log=lambda record, count=count, seed=seed: log(
                                           {"renders": count, "seed": seed, **record}),
                                       progress=progress, data_workers=data_workers)
            per_clip = {}
            for index, clip in enumerate(validation.clips):
                rows = validation_frames.clip == index
                per_clip[clip] = conditioning_metrics(body, model,
                                                      jax.tree.map(lambda column: column[rows], validation_frames))
            per_clip["all"] = conditioning_metrics(body, model, validation_frames)
            runs.append({"renders": count, "seed": seed, "metrics": per_clip})
            log({"renders": count, "seed": seed, "validation": per_clip})
    results = {"config": {"base": base, "renders": list(renders), "seeds": list(seeds), "validation": validation},
               "runs": runs, "summary": renders_summary(runs),
               "seconds": round(time.perf_counter() - started, 1)}
    results = training.to_jsonable(results)
    (out / "results.json").write_text(json.dumps(results, indent=1) + "\n")
    (out / "results.md").write_text(renders_markdown(results))
    return results


def renders_summary(runs: Sequence[dict]) -> dict[str, dict]:
    """Per candidate (its number of renders, as a string) and validation clip: each metric's mean and sample sd
    (0 for one seed) over the candidate's runs (``{"renders", "seed", "metrics": {clip: {metric: value}}}``)."""
    summary = {}
    for count in dict.fromkeys(run["renders"] for run in runs):
        mine = [run["metrics"] for run in runs if run["renders"] == count]
        summary[str(count)] = {clip: {name: mean_and_sd(*(metrics[clip][name] for metrics in mine))
                                      for name in _METRICS}
                               for clip in mine[0]}
    return summary


def renders_markdown(results: dict) -> str:
    """One table per validation clip (and all frames): each candidate's metrics, mean ± sd over the seeds."""
    config, validation = results["config"], results["config"]["validation"]
    lines = ["# Renders per training clip, chosen on validation", "",
             f"The conditioning stage trained on each candidate's renders with seeds {config['seeds']} (mean ± sample "
             f"sd over them), scored on {validation['renders']} fresh render(s) of each of {validation['clips']} "
             f"(seed {validation['seed']}).", ""]
    for clip in next(iter(results["summary"].values())):
        lines += [f"## {clip}", "", "| renders | " + " | ".join(_METRICS.values()) + " |",
                  "|---|" + "---|" * len(_METRICS)]
        for count, per_clip in results["summary"].items():
            lines.append(f"| {count} | " + " | ".join(mean_sd_cell(per_clip[clip][name], digits=digits(name))
                                                       for name in _METRICS) + " |")
        lines.append("")
    return "\n".join(lines)

"""Which motion to render, how many videos per training clip, how to mirror them, how the backbone pools its last map,
how much dropout the HMR head trains with, and how many steps to train the conditioning stage on them, chosen on
validation: the conditioning stage (backbone and HMR head, :func:`dynamics.train_conditioning`) trained for each
candidate (motion, renders per clip, mirrors, pooling, head dropout, steps) with several seeds, and scored
(:func:`dynamics.conditioning_metrics`) per clip on fresh validation renders of training clips and, when given, on
renders of held-out motion, beside the reference of a constant pose (:func:`dynamics.mean_pose_metrics`: each motion's
mean training pose with the true root rotation).

More motion shows the networks more poses (the shipped clips hold about 1250 frames); more renders show them more camera
distances and body shapes for the same motion; two renders per clip (the default until 2026-11-28) left a depth bias on
the two-person test take (docs/dynamics.md). More steps let the backbone, trained from scratch, see each render more
often. Mirrors drawn anew keep the renders' left and right part colours on the left and right limbs, which mirrored
pixels swap. A flattened last map keeps where in the crop each feature fired, which the average over positions throws
away. The HMR head's dropout (0.5, HMR's) may hold back how well the networks fit their training renders, which they
fit little better than the validation ones (docs/dynamics.md). Scored: root-relative MPJPE and PA-MPJPE, the error of
the pelvis the crop camera places, its depth over the true depth, the root rotation's error, and the MPJPE with the
true root rotation put in (what the local pose and shape miss)."""

from __future__ import annotations

import dataclasses
import itertools
import json
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Literal

import jax

import geometry
import training
from dynamics import (DataConfig, Pooling, TrainConfig, build_frames, conditioning_metrics, mean_local_pose,
                      mean_pose_metrics, train_conditioning)
from experiments._stats import mean_and_sd

from ._report import digits
from ._seeds import mean_sd_cell

__all__ = ["Flips", "renders_markdown", "renders_summary", "run_renders_study"]

_METRICS = {"mpjpe_mm": "MPJPE (mm)", "pa_mpjpe_mm": "PA-MPJPE (mm)", "root_mm": "root (mm)",
            "depth_ratio": "depth / true depth", "orientation_deg": "root rotation (deg)",
            "true_rotation_mpjpe_mm": "MPJPE with the true root rotation (mm)"}
Flips = Literal["pixels", "redraw"]
"""How the mirrored training variants are made: their pixels mirrored, or the mirrored people rendered anew."""
HELD_OUT = "held-out motion"
_UNTAGGED = {"pooling": "mean", "hmr_dropout": 0.5}
"""What every run trained before the pooling and dropout options had: their run folders name neither, so they resume."""
"""The group of :func:`run_renders_study`'s held-out validation frames."""


def run_renders_study(out: Path, workdir: Path, base: TrainConfig, motions: Mapping[str, tuple[str, ...]],
                      data: Sequence[tuple[str, int]], steps: Sequence[int], seeds: Sequence[int],
                      validation: DataConfig, body: geometry.BodyModel, *, held_out: DataConfig | None = None,
                      flips: Sequence[Flips] | None = None, poolings: Sequence[Pooling] | None = None,
                      dropouts: Sequence[float] | None = None, log: Callable[[dict], None], progress: bool,
                      data_workers: int) -> dict:
    """Train ``base`` (its model) on each of the ``data`` candidates (a name of ``motions``, which maps it to its
    training clips, and the videos rendered per clip), each way of mirroring the ``flips`` (``pixels`` or ``redraw``,
    :attr:`dynamics.DataConfig.redraw_flips`; None: ``base``'s), each of the backbone's ``poolings``
    (:attr:`dynamics.BackboneConfig.pooling`; None: ``base``'s), each of the HMR head's ``dropouts``
    (:attr:`dynamics.PHDTConfig.hmr_dropout`; None: ``base``'s), each number of conditioning ``steps`` and each of
    ``seeds`` in ``workdir/<motion>_renders<R>_<flips>[_<pooling>][_dropout<D>]_steps<N>_seed<S>`` (pooling and
    dropout named where they are not :data:`_UNTAGGED`'s; resumable; one render cache in
    ``workdir/data_cache``), score each on ``validation`` per clip and on all its frames, and on ``held_out`` (motion no
    candidate trains on) as a whole, and write ``out/results.json`` and ``results.md``; returns the results."""
    started = time.perf_counter()
    flips = flips or ("redraw" if base.data.redraw_flips else "pixels",)
    poolings = poolings or (base.backbone.pooling,)
    dropouts = dropouts or (base.model.hmr_dropout,)
    cache_dir = (workdir / "data_cache").resolve()
    groups = {}
    validation_frames = build_frames(validation, body, cache_dir, progress, data_workers)
    for index, clip in enumerate(validation.clips):
        groups[clip] = jax.tree.map(lambda column, rows=validation_frames.clip == index: column[rows], validation_frames)
    groups["all"] = validation_frames
    if held_out is not None:
        groups[HELD_OUT] = build_frames(held_out, body, cache_dir, progress, data_workers)
    runs, references = [], {}
    for (motion, count), flip, pooling, dropout, stage_steps, seed in itertools.product(data, flips, poolings, dropouts,
                                                                                       steps, seeds):
        frames_config = dataclasses.replace(base.data, clips=motions[motion], renders=count,
                                            redraw_flips=flip == "redraw")
        config = dataclasses.replace(base, data=frames_config, image=dataclasses.replace(base.image, steps=stage_steps),
                                     backbone=dataclasses.replace(base.backbone, pooling=pooling),
                                     model=dataclasses.replace(base.model, hmr_dropout=dropout),
                                     validation=validation, seed=seed, cache_dir=str(cache_dir))
        candidate = {"motion": motion, "renders": count, "flips": flip, "pooling": pooling, "hmr_dropout": dropout,
                     "steps": stage_steps, "seed": seed}
        tags = ("" if pooling == _UNTAGGED["pooling"] else f"_{pooling}") + (
            "" if dropout == _UNTAGGED["hmr_dropout"] else f"_dropout{dropout:g}")
        name = f"{motion}_renders{count}_{flip}{tags}_steps{stage_steps}"
        model = train_conditioning(config, workdir / f"{name}_seed{seed}", body, resume=True, progress=progress,
                                   data_workers=data_workers,
                                   log=lambda record, candidate=candidate: log({**candidate, **record}))
        metrics = {group: conditioning_metrics(body, model, frames) for group, frames in groups.items()}
        runs.append({**candidate, "metrics": metrics})
        log({**candidate, "validation": metrics})
        if motion not in references:  # the training frames' mean pose: renders and mirrors change views, not poses
            pose = mean_local_pose(build_frames(frames_config, body, cache_dir, progress, data_workers).rotations)
            references[motion] = {group: mean_pose_metrics(body, pose, frames) for group, frames in groups.items()}
    results = {"config": {"base": base, "motions": dict(motions), "data": [list(pair) for pair in data],
                          "flips": list(flips), "poolings": list(poolings), "dropouts": list(dropouts),
                          "steps": list(steps), "seeds": list(seeds),
                          "validation": validation, "held_out": held_out},
               "runs": runs, "summary": renders_summary(runs), "mean_pose": references,
               "seconds": round(time.perf_counter() - started, 1)}
    results = training.to_jsonable(results)
    (out / "results.json").write_text(json.dumps(results, indent=1) + "\n")
    (out / "results.md").write_text(renders_markdown(results))
    return results


def _candidate_name(run: dict) -> str:
    """A candidate's row label: its motion, renders per clip, mirrors, pooling and head dropout (where the run says)
    and conditioning steps."""
    mirrors = {"pixels": ", pixels mirrored", "redraw": ", mirrors redrawn"}.get(run.get("flips"), "")
    pooling = {"mean": ", last map averaged", "flatten": ", last map flattened"}.get(run.get("pooling"), "")
    dropout = "" if run.get("hmr_dropout") is None else f", head dropout {run['hmr_dropout']:g}"
    return f"{run['motion']} motion, renders {run['renders']}{mirrors}{pooling}{dropout}, steps {run['steps']}"


def renders_summary(runs: Sequence[dict]) -> dict[str, dict]:
    """Per candidate (:func:`_candidate_name`) and validation group: each metric's mean and sample sd (0 for one
    seed) over the candidate's runs (``{"motion", "renders", "steps", "seed", "metrics": {group: {metric:
    value}}}``)."""
    summary = {}
    for name in dict.fromkeys(map(_candidate_name, runs)):
        mine = [run["metrics"] for run in runs if _candidate_name(run) == name]
        summary[name] = {clip: {metric: mean_and_sd(*(metrics[clip][metric] for metrics in mine))
                                for metric in _METRICS}
                         for clip in mine[0]}
    return summary


def renders_markdown(results: dict) -> str:
    """One table per validation group: each candidate's metrics, mean ± sd over the seeds, and each motion's
    mean-pose reference."""
    config, validation = results["config"], results["config"]["validation"]
    held_out = config.get("held_out")
    lines = ["# Motion, renders per training clip, mirrors, pooling, head dropout and conditioning steps, chosen on "
             "validation", "",
             f"The conditioning stage trained for each candidate with seeds {config['seeds']} (mean ± sample "
             f"sd over them), scored on {validation['renders']} fresh render(s) of each of {validation['clips']} "
             f"(seed {validation['seed']})"
             + ("" if held_out is None else f" and on {held_out['renders']} render(s) of each of "
                f"{len(held_out['clips'])} files of held-out motion ('{HELD_OUT}', seed {held_out['seed']})")
             + ". Reference rows: a constant pose, the motion's mean training pose, given the true root rotation and "
               "shape.", ""]
    for group in next(iter(results["summary"].values())):
        lines += [f"## {group}", "", "| candidate | " + " | ".join(_METRICS.values()) + " |",
                  "|---|" + "---|" * len(_METRICS)]
        for name, per_group in results["summary"].items():
            lines.append(f"| {name} | " + " | ".join(mean_sd_cell(per_group[group][metric], digits=digits(metric))
                                                      for metric in _METRICS) + " |")
        for motion, reference in results.get("mean_pose", {}).items():
            lines.append(f"| mean pose of the {motion} motion (reference) | "
                         + " | ".join(f"{reference[group][metric]:.1f}" if metric in reference[group] else ""
                                      for metric in _METRICS) + " |")
        lines.append("")
    return "\n".join(lines)

"""Choose the geometric baseline's settings on SYNTHETIC Shelf-rig validation scenes (never on Shelf 300-600).

    .venv/bin/python -m experiments.shelf_validate [--seeds 101 102 103] [--people 4] [--frames 90]
        [--protocol voxelpose|jcsat|4dassoc] [--jcsat] [--json]

Scores a grid of :class:`association.BaselineConfig` variants with :func:`experiments.jcsat_study.synthetic_validation` and prints one
row per setting: PCP (``--protocol``, all synthetic people) per seed and their mean. The grid varies the
temporal outlier filter's window and distance (distance 0 is a plain median filter), chosen under the
VoxelPose protocol, the duplicate suppression distance, chosen under the JCSAT protocol (the only one
where a second prediction of a person costs anything), and the Structural Triangulation refinement's steps,
prior weight and bone-outlier ratio (:class:`association.GeometricConfig`), chosen under the VoxelPose protocol.
The defaults of :class:`association.BaselineConfig` are the best rows of these tables, or the simpler of tied rows
(their docstrings give the figures). About 6 minutes on 2 CPU cores (2026-11-24, without ``--jcsat``).
``--jcsat`` adds the shipped model with each way of turning its windows into poses (:data:`jcsat.AGGREGATES`); the main job's default
(``experiments.jcsat_study.ShelfExperimentConfig.aggregate``) is the better of those rows.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os

os.environ.setdefault("XLA_FLAGS", "--xla_cpu_experimental_ynn_fusion_type=")

import jax  # noqa: E402

import association  # noqa: E402
import jcsat  # noqa: E402
from experiments import jcsat_study  # noqa: E402
import mocap  # noqa: E402


def settings() -> dict[str, association.BaselineConfig]:
    base = dataclasses.replace(association.BaselineConfig(), outlier_half_window=0)
    grid = {"no outlier filter": base}
    for half_window in (2, 3, 5):
        for distance in (0.0, 0.05, 0.1, 0.15, 0.25):
            grid[f"outliers +-{half_window} frames, {distance:g} m"] = dataclasses.replace(
                base, outlier_half_window=half_window, outlier_distance=distance)
    for distance in (0.0, 0.1, 0.2, 0.3, 0.4, 0.5):
        grid[f"duplicates within {distance:g} m"] = dataclasses.replace(association.BaselineConfig(),
                                                                        duplicate_distance=distance)
    geometric = association.GeometricConfig()
    structural = [(0, geometric.structural_prior_weight)]
    structural += [(steps, 0.01) for steps in (3, 6, 9, 12)] + [(9, weight) for weight in (0.003, 0.05, 0.3)]
    for steps, weight in structural:
        name = f"structural {steps} steps, prior {weight:g}" if steps else "no structural refinement"
        grid[name] = dataclasses.replace(association.BaselineConfig(), geometric=dataclasses.replace(
            geometric, structural_steps=steps, structural_prior_weight=weight))
    for deviation in (0.0, 0.25, 0.5, 1.0):
        name = f"bone outliers beyond {deviation:g}" if deviation else "no bone outliers"
        grid[name] = dataclasses.replace(association.BaselineConfig(), geometric=dataclasses.replace(
            geometric, max_bone_deviation=deviation))
    return grid


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m experiments.shelf_validate", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, nargs="+", default=[101, 102, 103],
                        help="one synthetic scene per seed (default: %(default)s; the main job uses seed 0)")
    parser.add_argument("--people", type=int, default=4, help="people per scene (default: %(default)s)")
    parser.add_argument("--frames", type=int, default=90, help="frames per scene (default: %(default)s)")
    parser.add_argument("--protocol", choices=mocap.EVALUATION_PROTOCOLS, default="voxelpose",
                        help="matching protocol of the PCP (default: %(default)s; see mocap.evaluate_shelf)")
    parser.add_argument("--jcsat", action="store_true",
                        help="also score the shipped JCSAT model with each aggregate (last, mean)")
    parser.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    args = parser.parse_args(argv)
    jax.config.update("jax_enable_x64", True)
    model = jcsat.load_model(jcsat.SHIPPED_MODEL) if args.jcsat else None
    table = jcsat_study.synthetic_validation(settings(), tuple(args.seeds), args.people, args.frames, args.protocol,
                                       model=model)
    if args.json:
        print(json.dumps(table))
        return 0
    columns = [f"seed {s}" for s in args.seeds] + ["pcp", "tracks"]
    print(f"{'setting':<34}" + "".join(f"{c:>10}" for c in columns))
    for name, row in table.items():
        print(f"{name:<34}" + "".join(f"{row[c]:10.2f}" for c in columns))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

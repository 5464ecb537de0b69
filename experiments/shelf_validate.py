"""Choose the geometric baseline's settings on SYNTHETIC Shelf-rig validation scenes (never on Shelf 300-600).

Scores a grid of :class:`association.BaselineConfig` variants with :func:`jcsat_study.synthetic_validation` and prints one
row per setting: PCP (``--protocol``, all synthetic people) per seed and their mean. The grid varies the
temporal outlier filter's window and distance (distance 0 is a plain median filter), chosen under the
VoxelPose protocol, the duplicate suppression distance, chosen under the JCSAT protocol (the only one
where a second prediction of a person costs anything), and the Structural Triangulation refinement's steps,
prior weight and bone-outlier ratio (:class:`association.GeometricConfig`), chosen under the VoxelPose protocol.
The defaults of :class:`association.BaselineConfig` are the best rows of these tables, or the simpler of tied rows
(their docstrings give the figures). About 6 minutes on 2 CPU cores without ``--jcsat``.
``--jcsat`` adds the shipped model with each way of turning its windows into poses (:data:`jcsat.AGGREGATES`);
the main job's default (``jcsat_study.ShelfExperimentConfig.aggregate``) is the better of those rows.
"""

from __future__ import annotations

import dataclasses
import json
from typing import Literal

import association
import jcsat
import mocap
from experiments import _cli, jcsat_study


@dataclasses.dataclass(frozen=True)
class Config:
    seeds: tuple[int, ...] = (101, 102, 103)
    """One synthetic scene per seed (the main job uses seed 0)."""
    people: int = 4
    """People per scene."""
    frames: int = 90
    """Frames per scene."""
    protocol: Literal[mocap.EVALUATION_PROTOCOLS] = "voxelpose"  # type: ignore[valid-type]
    """Matching protocol of the PCP (see mocap.evaluate_shelf)."""
    jcsat: bool = False
    """Also score the shipped JCSAT model with each aggregate (last, mean)."""
    json: bool = False
    """Print one JSON object instead of a table."""

    def __post_init__(self) -> None:
        if not self.seeds:
            raise ValueError("--seeds needs at least one seed")
        if self.people < 1 or self.frames < 1:
            raise ValueError(f"--people and --frames must be >= 1, got {self.people} and {self.frames}")


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


def main(config: Config) -> None:
    model = jcsat.load_model(jcsat.SHIPPED_MODEL) if config.jcsat else None
    table = jcsat_study.synthetic_validation(settings(), config.seeds, config.people, config.frames, config.protocol,
                                       model=model)
    if config.json:
        print(json.dumps(table))
        return
    columns = [f"seed {s}" for s in config.seeds] + ["pcp", "tracks"]
    print(f"{'setting':<34}" + "".join(f"{c:>10}" for c in columns))
    for name, row in table.items():
        print(f"{name:<34}" + "".join(f"{row[c]:10.2f}" for c in columns))


if __name__ == "__main__":
    _cli.run(main, Config, description=__doc__, float64=True)

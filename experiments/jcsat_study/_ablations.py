"""The paper's ablations (JCSAT, Tables 6, 7 and 8) as one study: every row scored on synthetic validation scenes and
on Shelf, beside the geometric baseline under the same setting and the 4D-association output.

A row evaluates one model under one test-time setting. Test-time rows (views kept, cameras perturbed) use the
shipped model; training rows (candidate masking, the kinematic losses, the aggregations, the encoder size) train a
variant of one base run (:data:`jcsat.TRAIN_CONFIGS`) from scratch, all with the same seed, scenes and steps, and
evaluate it on all views. A variant whose ``model/`` folder exists is not trained again, and training resumes from
its checkpoints: a killed study continues where it stopped.

Synthetic validation: scenes of the held-out validation clips (:data:`jcsat.VALIDATION_CLIPS`), one per seed, PCP over
all their people. Shelf: the test frames 300-600, PCP over actors 1-3. Nothing here chooses anything.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from pathlib import Path

import numpy as np

import jcsat

from ._shelf import ShelfExperimentConfig, run_shelf_experiment

__all__ = ["ABLATION_ROWS", "SHIPPED", "VARIANTS", "AblationRow", "ablation_table", "run_ablations"]

SHIPPED = "shipped"
"""The variant name of rows that evaluate the shipped model (no training)."""


def _model_change(change: Callable[[jcsat.JCSATConfig], jcsat.JCSATConfig]
                  ) -> Callable[[jcsat.TrainConfig], jcsat.TrainConfig]:
    return lambda config: dataclasses.replace(config, model=change(config.model_config))


VARIANTS: dict[str, Callable[[jcsat.TrainConfig], jcsat.TrainConfig]] = {
    "reference": lambda config: config,
    "no candidate masking": _model_change(lambda model: dataclasses.replace(model, mask_ratio=(0.0, 0.0))),
    "no kinematic losses": lambda config: dataclasses.replace(
        config, losses=dataclasses.replace(config.losses, bone_temporal=0.0, bone_symmetry=0.0)),
    "no OTAP (masked means)": _model_change(lambda model: jcsat.aggregation_variant(model, "otap_a")),
    "V-OTAP only": _model_change(lambda model: jcsat.aggregation_variant(model, "otap_b")),
    "T-, S-OTAP only": _model_change(lambda model: jcsat.aggregation_variant(model, "otap_c")),
    "encoder 'cpu'": lambda config: dataclasses.replace(config, model="cpu"),
    "encoder 'cpu_wide'": lambda config: dataclasses.replace(config, model="cpu_wide"),
}
"""How each training row's run differs from the base run."""


@dataclasses.dataclass(frozen=True)
class AblationRow:
    table: str
    """The paper's table: ``"6"``, ``"7"`` or ``"8"``."""
    name: str
    variant: str = SHIPPED
    """:data:`SHIPPED` or a key of :data:`VARIANTS` (trained by the study)."""
    views: tuple[int, ...] | None = None
    """Cameras kept (None: all five)."""
    perturb_cameras: int = 0
    """The first this many kept cameras perturbed (up to 0.25 cm and 2.5 degrees, Table 8)."""


ABLATION_ROWS: tuple[AblationRow, ...] = (
    AblationRow("6", "5 views"),
    AblationRow("6", "4 views", views=(0, 1, 2, 3)),
    AblationRow("6", "3 views", views=(0, 1, 2)),
    AblationRow("6", "trained: reference", "reference"),
    AblationRow("6", "trained: no candidate masking", "no candidate masking"),
    AblationRow("6", "trained: no kinematic losses", "no kinematic losses"),
    AblationRow("7", "trained: OTAP in T, S and V", "reference"),
    AblationRow("7", "trained: no OTAP (masked means)", "no OTAP (masked means)"),
    AblationRow("7", "trained: V-OTAP only", "V-OTAP only"),
    AblationRow("7", "trained: T-, S-OTAP only", "T-, S-OTAP only"),
    AblationRow("7", "trained: encoder 'cpu'", "encoder 'cpu'"),
    AblationRow("7", "trained: encoder 'cpu_wide'", "encoder 'cpu_wide'"),
    AblationRow("8", "exact cameras"),
    AblationRow("8", "1 perturbed camera", perturb_cameras=1),
    AblationRow("8", "2 perturbed cameras", perturb_cameras=2),
    AblationRow("8", "3 perturbed cameras", perturb_cameras=3),
)
"""The study's rows, in table order (a row's test-time setting with the shipped model, or a trained variant)."""

_METHODS = ("jcsat", "geometric", "4DA output")
_PROTOCOLS = ("voxelpose", "jcsat")


def _slug(text: str) -> str:
    return "".join(c if c.isalnum() else "_" for c in text.lower()).strip("_")


def _train_variants(rows: tuple[AblationRow, ...], base: jcsat.TrainConfig, workdir: Path, data_workers: int,
                    log: Callable[[dict], None]) -> dict[str, Path]:
    """Each variant the rows name, trained in ``workdir/<variant>`` (variants that make the same run share it)."""
    folders: dict[str, Path] = {}
    trained: dict[str, Path] = {}
    for variant in dict.fromkeys(row.variant for row in rows if row.variant != SHIPPED):
        config = dataclasses.replace(VARIANTS[variant](base), cache_dir=str(workdir / "data_cache"))
        key = json.dumps(dataclasses.asdict(config), sort_keys=True, default=str)
        if key not in trained:
            folder = workdir / _slug(variant)
            if not (folder / "model").is_dir():
                log({"stage": "train", "variant": variant})
                jcsat.train(config, folder, resume=(folder / "checkpoints").is_dir(), data_workers=data_workers,
                            log=lambda record, v=variant: log({"stage": "train", "variant": v, **record}))
            trained[key] = folder / "model"
        folders[variant] = trained[key]
    return folders


def _pcp(metrics: dict) -> dict[str, dict[str, float | None]]:
    return {method: {protocol: by[protocol]["average"]["pcp"] for protocol in _PROTOCOLS}
            for method, by in metrics["scores"].items() if method in _METHODS}


def run_ablations(
    rows: tuple[AblationRow, ...],
    out: Path,
    *,
    workdir: Path,
    data_root: str | None,
    base: jcsat.TrainConfig,
    seeds: tuple[int, ...],
    quick: bool = False,
    data_workers: int = 1,
    log: Callable[[dict], None] = lambda record: None,
    progress: Callable[[str], None] = lambda row: None,
) -> dict:
    """Train the rows' variants into ``workdir`` (``base`` changed by :data:`VARIANTS`), then score every row on the
    synthetic validation scenes of ``seeds`` and, with ``data_root``, on Shelf (the runs' files in ``out/rows``; a
    setting two rows share runs once). Returns ``{"rows": [...]}``: per row its table, name, variant, setting and PCP
    (%) per evaluation (``"synthetic"``: the mean over the seeds, each seed's in ``"synthetic_seeds"``; ``"shelf"``),
    method and protocol."""
    models = _train_variants(rows, base, workdir, data_workers, log)
    scored: dict[ShelfExperimentConfig, dict] = {}
    results = []
    for row in rows:
        progress(row.name)
        model = None if row.variant == SHIPPED else str(models[row.variant])
        setting = ShelfExperimentConfig(model=model, quick=quick, plot=False, views=row.views,
                                        perturb_cameras=row.perturb_cameras, synthetic_clips=jcsat.VALIDATION_CLIPS)
        if setting not in scored:
            folder = out / "rows" / f"{row.table}_{_slug(row.name)}"
            per_seed = [_pcp(run_shelf_experiment(dataclasses.replace(setting, seed=seed),
                                                  folder / f"synthetic_{seed}").metrics) for seed in seeds]
            scores = {"synthetic": {method: {protocol: float(np.mean([s[method][protocol] for s in per_seed]))
                                             for protocol in _PROTOCOLS} for method in per_seed[0]},
                      "synthetic_seeds": dict(zip(map(str, seeds), per_seed))}
            if data_root is not None:
                shelf = run_shelf_experiment(dataclasses.replace(setting, data_root=data_root), folder / "shelf")
                scores["shelf"] = _pcp(shelf.metrics)
            scored[setting] = scores
        result = {"table": row.table, "name": row.name, "variant": row.variant, "model": model or SHIPPED,
                  "views": list(row.views or range(5)), "perturb_cameras": row.perturb_cameras, **scored[setting]}
        log({"stage": "row", **{k: v for k, v in result.items() if k != "synthetic_seeds"}})
        results.append(result)
    return {"rows": results}


def ablation_table(study: dict) -> str:
    """Markdown: one table per paper table, a row per study row; PCP (%) under the VoxelPose / JCSAT protocols of the
    model, the geometric baseline under the same setting and (Shelf) the 4D-association output."""

    def cell(scores: dict | None, method: str) -> str:
        if scores is None or method not in scores:
            return "-"
        return " / ".join("-" if scores[method][p] is None else f"{scores[method][p]:.2f}" for p in _PROTOCOLS)

    lines = []
    for table in dict.fromkeys(row["table"] for row in study["rows"]):
        lines += [f"### Table {table}", "", "| row | synthetic: model | synthetic: baseline | Shelf: model | "
                  "Shelf: baseline | Shelf: 4DA output |", "|---|---|---|---|---|---|"]
        for row in study["rows"]:
            if row["table"] == table:
                synthetic, shelf = row["synthetic"], row.get("shelf")
                cells = [cell(synthetic, "jcsat"), cell(synthetic, "geometric"), cell(shelf, "jcsat"),
                         cell(shelf, "geometric"), cell(shelf, "4DA output")]
                lines.append(f"| {row['name']} | " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)

"""The ablation study (python -m experiments.jcsat_ablations): each variant changes one thing, rows that share a
setting share one evaluation and one training, the synthetic scenes use only the held-out clips."""

import dataclasses
import json

import pytest
from flax import nnx

import jcsat
import training
from experiments import _cli, jcsat_ablations, jcsat_study
from experiments.jcsat_study._ablations import _train_variants

TINY = jcsat.JCSATConfig(dim=8, depth=1, heads=2, head_dim=4, mlp_dim=8, out_dim=8, view_dim=8, view_depth=1,
                         view_heads=2, view_head_dim=4, view_mlp_dim=8, otap_iterations=3)


def _changed(a, b, prefix="") -> set[str]:
    """Dotted names of the leaves where two nested dicts differ."""
    if isinstance(a, dict) and isinstance(b, dict):
        return set().union(*(_changed(a.get(k), b.get(k), f"{prefix}{k}.") for k in a.keys() | b.keys()))
    return set() if a == b else {prefix.rstrip(".")}


def test_each_variant_changes_one_thing():
    def resolved(config: jcsat.TrainConfig) -> dict:  # a model named or given by its configuration compares alike
        return dataclasses.asdict(dataclasses.replace(config, model=config.model_config))

    base = jcsat.TRAIN_CONFIGS["cpu"]
    changed = {name: _changed(resolved(base), resolved(change(base))) for name, change in jcsat_study.VARIANTS.items()}
    assert changed["reference"] == set() and changed["encoder 'cpu'"] == set()
    assert changed["no candidate masking"] == {"model.mask_ratio"}
    assert changed["no kinematic losses"] == {"losses.bone_temporal", "losses.bone_symmetry"}
    assert changed["no OTAP (masked means)"] == {f"model.{p}_selective" for p in ("trajectory", "structure", "view")}
    assert changed["V-OTAP only"] == {"model.trajectory_selective", "model.structure_selective"}
    assert changed["T-, S-OTAP only"] == {"model.view_selective"}
    assert changed["encoder 'cpu_wide'"] and all(name.startswith("model.") for name in changed["encoder 'cpu_wide'"])
    assert {row.variant for row in jcsat_study.ABLATION_ROWS} <= set(jcsat_study.VARIANTS) | {jcsat_study.SHIPPED}


def _untrained(config: jcsat.TrainConfig, workdir, **options) -> None:
    """Stands in for jcsat.train (tested in test_jcsat_train.py): the run's fresh model, saved where train saves it."""
    model = jcsat.JCSAT(config.model, rngs=nnx.Rngs(config.seed))
    training.save_model(workdir / "model", config.model, nnx.state(model))
    (workdir / "config.json").write_text(json.dumps({"losses": dataclasses.asdict(config.losses),
                                                      "cache_dir": config.cache_dir}))


def test_study_on_synthetic_validation(tmp_path, monkeypatch):
    monkeypatch.setattr(jcsat, "train", _untrained)
    base = jcsat.TrainConfig(model=TINY, batch_size=2, steps=2, warmup_steps=1, checkpoint_interval=1,
                             validation_interval=2, log_interval=1, validation_windows=2,
                             data=jcsat.DataConfig(num_scenes=1, num_frames=12, num_people=2),
                             validation_data=jcsat.DataConfig(clips=jcsat.VALIDATION_CLIPS, num_scenes=1, num_frames=12,
                                                              num_people=2, first_seed=500))
    rows = (jcsat_study.AblationRow("6", "3 views", views=(0, 1, 2)),
            jcsat_study.AblationRow("6", "no kinematic losses", "no kinematic losses"),
            jcsat_study.AblationRow("7", "the same run again", "no kinematic losses"))
    records = []
    study = jcsat_study.run_ablations(rows, tmp_path / "out", workdir=tmp_path / "train", data_root=None, base=base,
                                      seeds=(101,), quick=True, log=records.append)
    first, trained, again = study["rows"]
    assert [r["variant"] for r in records if r["stage"] == "train"] == ["no kinematic losses"]
    run = json.loads((tmp_path / "train" / "no_kinematic_losses" / "config.json").read_text())
    assert run["losses"]["bone_temporal"] == run["losses"]["bone_symmetry"] == 0 and run["losses"]["rec"] == 1
    assert run["cache_dir"] == str(tmp_path / "train" / "data_cache")  # the variants share their scenes
    assert trained["synthetic"] == again["synthetic"] and "shelf" not in trained
    assert set(first["synthetic"]) == {"jcsat", "geometric"} and first["model"] == jcsat_study.SHIPPED
    assert all(0 <= pcp <= 100 for method in first["synthetic"].values() for pcp in method.values())
    for folder in (tmp_path / "out" / "rows").iterdir():  # a shared setting was evaluated once
        metrics = json.loads((folder / "synthetic_101" / "metrics.json").read_text())
        assert set(metrics["data"]["clips"]) <= set(jcsat.VALIDATION_CLIPS), metrics["data"]["clips"]
    assert len(list((tmp_path / "out" / "rows").iterdir())) == 2
    # A second study reuses the trained variant.
    records.clear()
    _train_variants(rows, base, tmp_path / "train", 1, records.append)
    assert records == []
    table = jcsat_study.ablation_table(study)
    assert "### Table 6" in table and "### Table 7" in table and "| 3 views |" in table


@pytest.mark.parametrize("argv, message", [
    (["--steps", "1"], "--steps must be >= 2"),
    (["--tables"], "--tables names no table"),
    (["--data-root", "."], "holds no shelf"),
])
def test_options_are_checked(argv, message, capsys):
    with pytest.raises(SystemExit) as exit_info:
        _cli.parse(jcsat_ablations.Config, argv, prog="jcsat_ablations")
    assert exit_info.value.code == 2
    error = capsys.readouterr().err
    assert error.startswith("jcsat_ablations: error: ") and error.count("\n") == 1 and message in error, error

"""Mean and spread over training seeds: of experiments.dynamics runs (experiments/dynamics_study/_seeds.py,
``python -m experiments.dynamics_seeds``) and of the renders study's candidates (``_renders.py``, ``python -m
experiments.dynamics_renders``; its training and metrics are tested in test_dynamics_train.py)."""

import json

import numpy as np
import pytest

from dynamics import HORIZONS
from experiments import _cli, dynamics_renders, dynamics_seeds
from experiments.dynamics_study import renders_markdown, renders_summary, seeds_markdown, seeds_summary

_METHODS = ("MPJAT", "ZeroMotion")


def _results(rng: np.random.Generator, frames: int = 30) -> dict:
    """A results.json of experiments.dynamics with random numbers, one two-person group."""
    metrics = lambda: {m: float(rng.uniform(50, 300)) for m in ("mpjpe", "pa_mpjpe", "pck", "root", "depth_ratio")}  # noqa: E731
    per_frame = lambda: {m: rng.uniform(50, 300, frames).tolist() for m in ("mpjpe", "pa_mpjpe", "pck", "root", "depth_ratio")}  # noqa: E731
    group = {"samples": 148, "conditioning": {m: metrics() for m in _METHODS},
             "prediction": {m: per_frame() for m in _METHODS},
             "penetration": {m: rng.uniform(0, 1, frames).tolist() for m in _METHODS + ("ground truth",)}}
    return {"config": {"clips": ["60_05_61_05_salsa"], "stride": 5}, "summary": {"two_person": group}}


def test_every_cell_is_the_mean_and_sample_sd_over_runs_and_the_baseline_difference_is_paired():
    rng = np.random.default_rng(0)
    runs = [_results(rng) for _ in range(3)]
    summary = seeds_summary(runs)["two_person"]
    values = np.array([run["summary"]["two_person"]["prediction"]["MPJAT"]["mpjpe"] for run in runs])
    np.testing.assert_allclose(summary["prediction"]["MPJAT"]["mpjpe"]["mean"], values.mean(0))
    np.testing.assert_allclose(summary["prediction"]["MPJAT"]["mpjpe"]["sd"], values.std(0, ddof=1))
    roots = [run["summary"]["two_person"]["conditioning"]["ZeroMotion"]["root"] for run in runs]
    assert summary["conditioning"]["ZeroMotion"]["root"]["sd"] == pytest.approx(np.std(roots, ddof=1))
    baseline = np.array([run["summary"]["two_person"]["prediction"]["ZeroMotion"]["mpjpe"] for run in runs])
    np.testing.assert_allclose(summary["below_zero_motion"]["MPJAT"]["sd"], (values - baseline).std(0, ddof=1))
    assert set(summary["below_zero_motion"]) == {"MPJAT"} and summary["samples"] == 148
    np.testing.assert_allclose(summary["penetration"]["ground truth"]["mean"],
                               np.mean([run["summary"]["two_person"]["penetration"]["ground truth"] for run in runs], 0))
    report = seeds_markdown(seeds_summary(runs), ["a", "b", "c"])
    at_30 = summary["prediction"]["MPJAT"]["mpjpe"]
    assert f"{at_30['mean'][29]:.1f} ± {at_30['sd'][29]:.1f}" in report and "3 training seeds" in report
    assert report.count(" | ".join(f"@{k}" for k in HORIZONS)) == 5  # three metrics, the difference, penetration


def test_runs_of_different_evaluations_or_one_run_are_refused():
    rng = np.random.default_rng(1)
    first, second = _results(rng), _results(rng)
    with pytest.raises(ValueError, match="at least two runs"):
        seeds_summary([first])
    with pytest.raises(ValueError, match="run 2 evaluated differently"):
        seeds_summary([first, {**second, "config": {"clips": ["02_01_walk"], "stride": 5}}])
    with pytest.raises(ValueError, match="run 2 scored other groups or methods"):
        seeds_summary([first, _results(rng, frames=20)])


def test_the_command_writes_the_tables_and_refuses_a_folder_without_results(tmp_path, capsys):
    rng = np.random.default_rng(2)
    runs = []
    for seed in range(2):
        (tmp_path / f"s{seed}").mkdir()
        (tmp_path / f"s{seed}" / "results.json").write_text(json.dumps(_results(rng)))
        runs.append(str(tmp_path / f"s{seed}"))
    dynamics_seeds.main(_cli.parse(dynamics_seeds.Config, ["--runs", *runs, "--out", str(tmp_path / "out")],
                                   prog="dynamics_seeds"))
    written = json.loads((tmp_path / "out" / "seeds.json").read_text())
    assert written["runs"] == runs and "two_person" in written["summary"]
    assert (tmp_path / "out" / "seeds.md").read_text() in capsys.readouterr().out
    for argv, message in (([runs[0]], "at least two runs"), ([runs[0], str(tmp_path)], "holds no results.json")):
        with pytest.raises(SystemExit) as exit_info:
            _cli.parse(dynamics_seeds.Config, ["--runs", *argv, "--out", str(tmp_path / "x")], prog="dynamics_seeds")
        assert exit_info.value.code == 2
        assert message in capsys.readouterr().err


def test_the_renders_study_summarises_each_candidate_over_its_seeds_and_refuses_bad_options(capsys):
    runs = [{"renders": count, "seed": seed,
             "metrics": {"walk": {"mpjpe_mm": 100.0 + count + seed, "root_mm": 10.0 * seed, "depth_ratio": 0.9 + seed / 100}}}
            for count in (2, 8) for seed in (0, 1, 2)]
    summary = renders_summary(runs)
    assert list(summary) == ["2", "8"]
    assert summary["8"]["walk"]["mpjpe_mm"] == pytest.approx({"mean": 109.0, "sd": 1.0})
    config = {"seeds": [0, 1, 2], "validation": {"renders": 3, "clips": ["walk"], "seed": 1000}}
    assert "| 8 | 109.0 ± 1.0 | 10.0 ± 10.0 | 0.910 ± 0.010 |" in renders_markdown({"config": config, "summary": summary})
    assert renders_summary(runs[:1])["2"]["walk"]["root_mm"] == {"mean": 0.0, "sd": 0.0}  # one seed: no spread
    for argv, message in ((["--renders", "2", "2"], "--renders needs distinct values"),
                          (["--renders", "0", "2"], "must be >= 1"), (["--seeds"], "--seeds needs distinct values")):
        with pytest.raises(SystemExit):
            _cli.parse(dynamics_renders.Config, ["--out", "x", *argv], prog="dynamics_renders")
        assert message in capsys.readouterr().err

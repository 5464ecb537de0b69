"""Mean and spread over training seeds: of experiments.dynamics runs (experiments/dynamics_study/_seeds.py,
``python -m experiments.dynamics_seeds``) and of the renders study's candidates (``_renders.py``, ``python -m
experiments.dynamics_renders``; its training and metrics are tested in test_dynamics_train.py, its loop over
candidates here)."""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

import dynamics
from dynamics import HORIZONS
from experiments import _cli, dynamics_renders, dynamics_seeds
from experiments.dynamics import training_configs
from experiments.dynamics_study import (forecast_seeds_markdown, forecast_seeds_summary, renders_markdown,
                                       renders_summary, run_renders_study, seeds_markdown, seeds_summary)
from experiments.dynamics_study import _renders

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
    incomplete = _results(rng)
    del incomplete["summary"]["two_person"]["prediction"]["ZeroMotion"]
    with pytest.raises(ValueError, match=r"run 2's results.json lacks summary.two_person.prediction.ZeroMotion.mpjpe: "
                                         "not as experiments.dynamics writes it"):
        seeds_summary([first, incomplete])


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


def _forecast_results(rng: np.random.Generator, root: str = "/data", methods=("ZeroMotion", "Constant velocity",
                                                                                "JAT")) -> dict:
    """A results.json of experiments.dynamics_forecast with random numbers: two actions scored, one too short."""
    table = {method: {action: rng.uniform(20, 150, 5).tolist() for action in ("walking", "jumping")}
             for method in methods}
    for scores in table.values():
        scores["average"] = np.mean([scores["walking"], scores["jumping"]], axis=0).tolist()
    return {"fps": 25.0, "observed_frames": 25, "horizons_ms": [80, 160, 320, 400, 1000],
            "horizon_frames": [2, 4, 8, 10, 25], "stride": 10, "people": 1,
            "files": [f"{root}/cmu_expmap/test/{action}/{action}_1.txt"
                      for action in ("walking", "jumping", "running")],
            "windows": {"walking": 3, "jumping": 2, "running": 0}, "mpjpe_mm": table, "seconds": 1.0}


def test_forecast_runs_give_each_cell_over_seeds_and_the_percentage_below_zero_motion_within_each_run():
    rng = np.random.default_rng(3)
    runs = [_forecast_results(rng), _forecast_results(rng, root="/elsewhere"), _forecast_results(rng)]
    summary = forecast_seeds_summary(runs)
    jat = np.array([run["mpjpe_mm"]["JAT"]["average"] for run in runs])
    zero = np.array([run["mpjpe_mm"]["ZeroMotion"]["average"] for run in runs])
    np.testing.assert_allclose(summary["mpjpe_mm"]["JAT"]["average"]["mean"], jat.mean(0))
    np.testing.assert_allclose(summary["mpjpe_mm"]["JAT"]["walking"]["sd"],
                               np.std([run["mpjpe_mm"]["JAT"]["walking"] for run in runs], 0, ddof=1))
    below = 100 * (1 - jat / zero)  # paired within each run: not 1 - mean(JAT) / mean(ZeroMotion)
    np.testing.assert_allclose(summary["below_zero_motion_percent"]["JAT"]["mean"], below.mean(0))
    np.testing.assert_allclose(summary["below_zero_motion_percent"]["JAT"]["sd"], below.std(0, ddof=1))
    assert list(summary["below_zero_motion_percent"]) == ["JAT"]
    assert summary["mean_of_horizons_mm"]["JAT"]["mean"] == pytest.approx(jat.mean())
    assert summary["differences_mm"] == {}  # one forecaster
    ablated = [_forecast_results(rng, methods=("ZeroMotion", "JAT", "JAT w/o bias")) for _ in range(3)]
    change = np.array([run["mpjpe_mm"]["JAT w/o bias"]["average"] for run in ablated]) - np.array(
        [run["mpjpe_mm"]["JAT"]["average"] for run in ablated])
    difference = forecast_seeds_summary(ablated)["differences_mm"]
    assert list(difference) == ["JAT w/o bias - JAT"]
    np.testing.assert_allclose(difference["JAT w/o bias - JAT"]["sd"], change.std(0, ddof=1))
    assert "| JAT w/o bias - JAT |" in forecast_seeds_markdown(forecast_seeds_summary(ablated), ["a", "b", "c"])
    report = forecast_seeds_markdown(summary, ["a", "b", "c"])
    cell = summary["mpjpe_mm"]["JAT"]["average"]
    assert f"| JAT | {cell['mean'][0]:.1f} ± {cell['sd'][0]:.1f} |" in report and "3 training seeds" in report
    assert "## jumping (2 windows)" in report and "running" not in report and "(5 windows)" in report


def test_forecast_runs_of_different_evaluations_are_refused():
    rng = np.random.default_rng(4)
    first = _forecast_results(rng)
    with pytest.raises(ValueError, match="at least two runs"):
        forecast_seeds_summary([first])
    with pytest.raises(ValueError, match=r"run 2 evaluated differently from run 1 \(stride differ\)"):
        forecast_seeds_summary([first, {**_forecast_results(rng), "stride": 25}])
    other_files = _forecast_results(rng)
    other_files["files"] = other_files["files"][:2]
    with pytest.raises(ValueError, match=r"\(files differ\)"):
        forecast_seeds_summary([first, other_files])
    with pytest.raises(ValueError, match="run 2 scored other methods than run 1"):
        forecast_seeds_summary([first, _forecast_results(rng, methods=("ZeroMotion", "Constant velocity", "PHD+T"))])
    edited = {key: value for key, value in _forecast_results(rng).items() if key != "fps"}
    del edited["mpjpe_mm"]["JAT"]["average"]
    with pytest.raises(ValueError, match=r"run 1's results.json lacks fps, mpjpe_mm.JAT.average: not as "
                                         "experiments.dynamics_forecast writes it"):
        forecast_seeds_summary([edited, first])


def test_the_command_takes_forecast_runs_and_refuses_a_mix(tmp_path, capsys):
    rng = np.random.default_rng(5)
    for name, result in (("f0", _forecast_results(rng)), ("f1", _forecast_results(rng)), ("v0", _results(rng))):
        (tmp_path / name).mkdir()
        (tmp_path / name / "results.json").write_text(json.dumps(result))
    argv = lambda *names: ["--runs", *(str(tmp_path / n) for n in names), "--out", str(tmp_path / "out")]  # noqa: E731
    dynamics_seeds.main(_cli.parse(dynamics_seeds.Config, argv("f0", "f1"), prog="dynamics_seeds"))
    written = json.loads((tmp_path / "out" / "seeds.json").read_text())
    assert "below_zero_motion_percent" in written["summary"]
    assert (tmp_path / "out" / "seeds.md").read_text() in capsys.readouterr().out
    with pytest.raises(ValueError, match=r"mixes experiments.dynamics and experiments.dynamics_forecast runs "
                                         r"\(forecast: \S+f0, video: \S+v0\)"):
        dynamics_seeds.main(_cli.parse(dynamics_seeds.Config, argv("f0", "v0"), prog="dynamics_seeds"))


def test_the_renders_study_summarises_each_candidate_over_its_seeds_and_refuses_bad_options(capsys):
    runs = [{"motion": "shipped", "renders": count, "steps": steps, "seed": seed,
             "metrics": {"walk": {"mpjpe_mm": 100.0 + count + seed - steps / 1000, "pa_mpjpe_mm": 50.0,
                                  "root_mm": 10.0 * seed, "depth_ratio": 0.9 + seed / 100,
                                  "orientation_deg": 20.0 + seed, "true_rotation_mpjpe_mm": 90.0 + seed}}}
            for count, steps in ((2, 2000), (8, 2000), (8, 8000)) for seed in (0, 1, 2)]
    summary = renders_summary(runs)
    assert list(summary) == ["shipped motion, renders 2, steps 2000", "shipped motion, renders 8, steps 2000",
                             "shipped motion, renders 8, steps 8000"]
    assert summary["shipped motion, renders 8, steps 2000"]["walk"]["mpjpe_mm"] == pytest.approx(
        {"mean": 107.0, "sd": 1.0})
    assert summary["shipped motion, renders 8, steps 8000"]["walk"]["mpjpe_mm"] == pytest.approx(
        {"mean": 101.0, "sd": 1.0})
    config = {"seeds": [0, 1, 2], "validation": {"renders": 3, "clips": ["walk"], "seed": 1000}}
    markdown = renders_markdown({"config": config, "summary": summary,
                                 "mean_pose": {"shipped": {"walk": {"mpjpe_mm": 90.04, "pa_mpjpe_mm": 80.0}}}})
    assert ("| shipped motion, renders 8, steps 8000 | 101.0 ± 1.0 | 50.0 ± 0.0 | 10.0 ± 10.0 | 0.910 ± 0.010 | 21.0 ± 1.0 "
            "| 91.0 ± 1.0 |" in markdown)
    assert "| mean pose of the shipped motion (reference) | 90.0 | 80.0 |  |  |  |  |" in markdown
    assert renders_summary(runs[:1])["shipped motion, renders 2, steps 2000"]["walk"]["root_mm"] == {
        "mean": 0.0, "sd": 0.0}  # one seed
    for argv, message in ((["--renders", "2", "2"], "--renders needs distinct values"),
                          (["--renders", "0", "2"], "must be >= 1"), (["--seeds"], "--seeds needs distinct values"),
                          (["--steps"], "--steps needs distinct values"),
                          (["--steps", "2000", "100"], "--steps must exceed the stage's 100 warm-up steps"),
                          (["--motion", "benchmark"], "--motion benchmark needs --data-root"),
                          (["--motion", "shipped", "shipped"], "--motion needs distinct values"),
                          (["--flips", "redraw", "redraw"], "--flips needs distinct values"),
                          (["--pooling", "flatten", "flatten"], "--pooling needs distinct values"),
                          (["--pooling", "max"], "--pooling"),
                          (["--hmr-dropout", "0.5", "0.5"], "--hmr-dropout needs distinct values"),
                          (["--hmr-dropout", "1"], "--hmr-dropout rates must be in [0, 1), got [1.0]"),
                          (["--motion", "shipped", "benchmark", "--renders", "16", "4", "2", "--data-root", "d"],
                           "--motion shipped benchmark needs one --renders count per motion, got [16, 4, 2]")):
        with pytest.raises(SystemExit):
            _cli.parse(dynamics_renders.Config, ["--out", "x", *argv], prog="dynamics_renders")
        assert message in capsys.readouterr().err


def test_the_renders_study_trains_each_candidate_and_seed_in_its_own_resumable_folder(tmp_path, monkeypatch):
    """The loop over (motion and renders, mirrors, pooling, head dropout, steps, seed), with the training and the
    metrics replaced by fakes (tested in test_dynamics_train.py): each run's config carries its candidate, each
    validation group is scored on its rows, the held-out frames as one group, and each motion's mean pose is taken from
    its own training frames."""
    trained, posed = [], []

    def fake_train(config, workdir, body, *, resume, log, progress, data_workers):
        assert resume and Path(config.cache_dir) == tmp_path / "train" / "data_cache"
        trained.append((config.data.clips, config.data.renders, config.data.redraw_flips, config.backbone.pooling,
                        config.model.hmr_dropout, config.image.steps, config.seed, Path(workdir).name))
        log({"step": config.image.steps})
        return config.data.renders + config.image.steps / 1000 + config.seed / 10  # the "model": its candidate

    def fake_frames(config, *args):
        clips = np.array([0, 0, 1] if config.clips == validation.clips else [0, 1, 2, 3, 4])
        return dynamics.Frames(*[clips] * len(dynamics.Frames._fields))

    monkeypatch.setattr(_renders, "build_frames", fake_frames)
    monkeypatch.setattr(_renders, "train_conditioning", fake_train)
    monkeypatch.setattr(_renders, "conditioning_metrics", lambda body, model, frames: {
        "mpjpe_mm": model + len(frames.clip), "pa_mpjpe_mm": 0.0, "root_mm": 0.0, "depth_ratio": 1.0,
        "orientation_deg": 0.0, "true_rotation_mpjpe_mm": 0.0})
    monkeypatch.setattr(_renders, "mean_local_pose", lambda rotations: posed.append(len(rotations)) or len(rotations))
    monkeypatch.setattr(_renders, "mean_pose_metrics", lambda body, pose, frames: {"mpjpe_mm": pose})
    base, _ = training_configs("small", 0, False, None)
    validation = dataclasses.replace(dynamics.VALIDATION_DATA, renders=1)
    held_out = dataclasses.replace(validation, clips=("02_05_punch",))
    records = []
    motions = {"shipped": ("02_01_walk",), "benchmark": ("02_01_walk", "02_03_run")}
    results = run_renders_study(tmp_path, tmp_path / "train", base, motions, (("shipped", 8), ("benchmark", 16)),
                                (2000, 8000), (0, 1), validation, body=None, held_out=held_out,
                                flips=("pixels", "redraw"), poolings=("mean", "flatten"), dropouts=(0.5, 0.0),
                                log=records.append, progress=False, data_workers=1)
    # The mean pooling and the base's dropout keep the names of the runs from before those options.
    assert trained == [(motions[m], r, f == "redraw", p, d, n, s,
                        f"{m}_renders{r}_{f}{'_flatten' if p == 'flatten' else ''}{'_dropout0' if d == 0 else ''}"
                        f"_steps{n}_seed{s}")
                       for m, r in (("shipped", 8), ("benchmark", 16)) for f in ("pixels", "redraw")
                       for p in ("mean", "flatten") for d in (0.5, 0.0) for n in (2000, 8000) for s in (0, 1)]
    assert {"motion": "benchmark", "renders": 16, "flips": "redraw", "pooling": "flatten", "hmr_dropout": 0.0,
            "steps": 8000, "seed": 1, "step": 8000} in records
    walk, salsa = validation.clips
    last = results["runs"][-1]
    assert last["metrics"][walk]["mpjpe_mm"] == pytest.approx(24.1 + 2) and last["metrics"]["all"]["mpjpe_mm"] == 27.1
    assert last["metrics"][_renders.HELD_OUT]["mpjpe_mm"] == pytest.approx(24.1 + 5)
    assert results["summary"]["benchmark motion, renders 16, mirrors redrawn, last map flattened, head dropout 0, "
                              "steps 8000"][salsa]["mpjpe_mm"]["mean"] == pytest.approx(25.05)
    assert posed == [5, 5] and list(results["mean_pose"]) == ["shipped", "benchmark"]  # once per motion
    assert json.loads((tmp_path / "results.json").read_text())["config"]["steps"] == [2000, 8000]
    assert json.loads((tmp_path / "results.json").read_text())["config"]["flips"] == ["pixels", "redraw"]
    assert json.loads((tmp_path / "results.json").read_text())["config"]["poolings"] == ["mean", "flatten"]
    assert json.loads((tmp_path / "results.json").read_text())["config"]["dropouts"] == [0.5, 0.0]
    assert "| shipped motion, renders 8, pixels mirrored, last map averaged, head dropout 0.5, steps 2000 |" in (
        tmp_path / "results.md").read_text()
    assert "| shipped motion, renders 8, mirrors redrawn, last map averaged, head dropout 0, steps 2000 |" in (
        tmp_path / "results.md").read_text()
    assert f"## {_renders.HELD_OUT}" in (tmp_path / "results.md").read_text()
    # Without mirrors, poolings or dropouts given, the base's: the recipe's redrawn mirrors, flattened map, 0.5.
    trained.clear()
    run_renders_study(tmp_path, tmp_path / "train", base, motions, (("shipped", 8),), (2000,), (0,), validation,
                      body=None, log=records.append, progress=False, data_workers=1)
    assert trained == [(motions["shipped"], 8, True, "flatten", 0.5, 2000, 0,
                        "shipped_renders8_redraw_flatten_steps2000_seed0")]



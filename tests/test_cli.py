"""The one command line of the experiments (experiments/_cli.py), run folders, provenance and the data folder."""

import dataclasses
import importlib
import json
import os
import re
import shutil
import subprocess
import sys
import typing
from pathlib import Path

import pytest
import tyro

import jcsat
import mocap
import training
from experiments import _cli

REPO = Path(__file__).resolve().parents[1]
ENTRY_POINTS = ("bench_dynamics", "bench_geometry", "bench_jcsat", "bench_joint_cloud", "bench_otap", "bench_structri",
                "convert_cmu", "dynamics", "dynamics_forecast", "flex_shelf", "flex_synthetic", "preview_scene",
                "shelf_eval", "shelf_jcsat", "shelf_validate", "structri_shelf", "structri_virtual", "jcsat_ablations")


def _options(config_type: type, prefix: str = "") -> list[str]:
    """Every option tyro makes of ``config_type``: ``--field-name``, nested configs as ``--outer.field-name``
    unless marked ``tyro.conf.OmitArgPrefixes``."""
    options = []
    hints = typing.get_type_hints(config_type, include_extras=True)
    for field in dataclasses.fields(config_type):
        hint = hints[field.name]
        markers = getattr(hint, "__metadata__", ())
        inner = typing.get_args(hint)[0] if markers else hint
        if dataclasses.is_dataclass(inner):
            omitted = tyro.conf.OmitArgPrefixes in markers
            options += _options(inner, prefix if omitted else f"{prefix}{field.name.replace('_', '-')}.")
        else:
            options.append(f"--{prefix}{field.name.replace('_', '-')}")
    return options


def _run(module: str, *argv: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", f"experiments.{module}", *argv], cwd=REPO, capture_output=True,
                          text=True, timeout=300, env={**os.environ, "PYTHONPATH": str(REPO), **(env or {})})


@pytest.mark.parametrize("name", ENTRY_POINTS)
def test_help_of_every_entry_point_names_every_option(name, capsys):
    module = importlib.import_module(f"experiments.{name}")
    with pytest.raises(SystemExit) as exit_info:
        _cli.parse(module.Config, ["--help"], prog=name, description=module.__doc__)
    assert exit_info.value.code == 0
    text = capsys.readouterr().out
    missing = [option for option in _options(module.Config) + ["--debug"] if option not in text]
    assert not missing, missing


def test_dynamics_forecast_help_states_the_training_defaults():
    """The defaults --help names for the forecasters' training are the configs' own (they went stale once)."""
    import inspect

    import dynamics
    from experiments import dynamics_forecast

    source = " ".join(inspect.getsource(dynamics_forecast.Config).split())
    single = next(field.default for field in dataclasses.fields(dynamics.ForecastTrainConfig) if field.name == "stage")
    pairs = dynamics_forecast.PAIR_TRAIN["stage"]
    for phrase, field in (("steps per model", "steps"), ("windows per step", "batch_size"),
                          ("the peak learning rate", "learning_rate")):
        stated = re.search(rf"{phrase} \(default: dynamics.ForecastTrainConfig's (\S+); with --pairs (\S+)\)", source)
        assert stated, phrase
        assert [float(number) for number in stated.groups()] == [getattr(single, field), getattr(pairs, field)], phrase
    stated = re.findall(r"default: dynamics.ForecastTrainConfig's (\S+), with --pairs none\)", source)
    assert [float(number) for number in stated] == [single.clip_norm, single.average_decay]
    assert pairs.clip_norm is None and pairs.average_decay is None
    stated = re.search(r"joints_3d_error; default: dynamics.ForecastTrainConfig's (\w+), with --pairs too\)", source)
    losses = next(field.default for field in dataclasses.fields(dynamics.ForecastTrainConfig) if field.name == "losses")
    assert stated and stated.group(1) == losses.joints_3d_error
    pair_losses = dynamics_forecast.PAIR_TRAIN.get("losses", losses)  # without its own, ForecastTrainConfig's
    assert pair_losses.joints_3d_error == losses.joints_3d_error


def test_shelf_jcsat_help_shows_the_nested_baseline_options(capsys):
    from experiments import shelf_jcsat

    assert "--baseline.geometric.structural-steps" in _options(shelf_jcsat.Config)
    assert set(shelf_jcsat.ALIASES.values()) <= set(_options(shelf_jcsat.Config))


@pytest.mark.parametrize("argv, message", [
    (["--model", "/nonexistent"], "--model /nonexistent is not a folder"),
    (["--data-root", "/nonexistent"], "data folder /nonexistent is not a folder"),
    (["--method", "nope"], "method must be one of"),
    (["--bogus"], "unrecognised option(s): --bogus"),
    (["--steps", "x"], "--steps"),
])
def test_a_bad_option_is_one_line_and_exit_2(argv, message, capsys):
    from experiments import shelf_jcsat

    with pytest.raises(SystemExit) as exit_info:
        _cli.parse(shelf_jcsat.Config, argv, prog="shelf_jcsat", aliases=shelf_jcsat.ALIASES)
    assert exit_info.value.code == 2
    error = capsys.readouterr().err
    assert error.startswith("shelf_jcsat: error: ") and error.count("\n") == 1 and message in error, error


def test_bool_options_are_flags_not_strings(capsys):
    from experiments import structri_virtual

    def parse(*argv):
        return _cli.parse(structri_virtual.Config, ["--out", "x", *argv], prog="structri_virtual")

    assert parse("--no-recentre").virtual.recentre is False and parse("--recentre").virtual.recentre is True
    for word in ("ture", "False"):
        with pytest.raises(SystemExit) as exit_info:
            parse("--recentre", word)
        assert exit_info.value.code == 2 and f"unrecognised option(s): {word}" in capsys.readouterr().err


def test_quick_changes_only_the_options_left_at_their_default(capsys):
    from experiments import structri_virtual

    config = _cli.parse(structri_virtual.Config, ["--out", "x", "--quick", "--views", "5"], prog="structri_virtual")
    assert config.experiment().views == (5,) and config.experiment().frames == structri_virtual.QUICK["frames"]


@dataclasses.dataclass(frozen=True)
class _Failing:
    error: typing.Literal["value", "type", "interrupt"] = "value"
    """Which failure main meets."""


def _failing_main(config: _Failing) -> None:
    raise {"value": ValueError("the data said no\nsecond line"), "type": TypeError("NoneType.__format__"),
           "interrupt": KeyboardInterrupt()}[config.error]


@pytest.mark.parametrize("error, line", [("value", "the data said no"), ("type", "TypeError: NoneType.__format__")])
def test_a_failing_run_is_one_line_and_exit_2(error, line, capsys):
    with pytest.raises(SystemExit) as exit_info:
        _cli.run(_failing_main, _Failing, argv=["--error", error], float64=True)
    assert exit_info.value.code == 2
    stderr = capsys.readouterr().err
    assert stderr == f"python -m experiments.test_cli: error: {line} (rerun with --debug for the traceback)\n"


def test_debug_shows_the_traceback(capsys):
    with pytest.raises(SystemExit) as exit_info:
        _cli.run(_failing_main, _Failing, argv=["--debug"], float64=True)
    assert exit_info.value.code == 2
    stderr = capsys.readouterr().err
    assert "Traceback (most recent call last)" in stderr and "_failing_main" in stderr
    assert stderr.rstrip().endswith("error: the data said no")


def test_an_interrupted_run_exits_130(capsys):
    with pytest.raises(SystemExit) as exit_info:
        _cli.run(_failing_main, _Failing, argv=["--error", "interrupt"], float64=True)
    assert exit_info.value.code == 130


def _folder(path: Path) -> dict[str, str]:
    return {str(p.relative_to(path)): p.read_text() for p in sorted(path.rglob("*")) if p.is_file()}


def test_a_failed_run_leaves_the_previous_outputs_untouched(tmp_path):
    out = tmp_path / "run"
    with _cli.run_folder(out) as staging:
        (staging / "metrics.json").write_text("old metrics")
        (staging / "predictions.jsonl").write_text("old predictions")
    before = _folder(out)
    with pytest.raises(RuntimeError, match="died"), _cli.run_folder(out) as staging:
        (staging / "config.json").write_text("new config")
        raise RuntimeError("died")
    assert _folder(out) == before and sorted(p.name for p in tmp_path.iterdir()) == ["run"]


def test_an_out_that_is_a_file_is_refused_before_the_run(tmp_path):
    out = tmp_path / "notes.txt"
    out.write_text("a file")
    with pytest.raises(ValueError, match=r"--out .*notes.txt is a file, not a folder"), _cli.run_folder(out):
        pytest.fail("the run started")
    assert out.read_text() == "a file" and sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"]


def test_a_run_replaces_the_outputs_as_a_whole_and_keeps_the_training_workdir(tmp_path):
    out = tmp_path / "run"
    with _cli.run_folder(out) as staging:
        (staging / "metrics.json").write_text("old")
    (out / "train").mkdir()
    (out / "train" / "checkpoint").write_text("resumable")
    with _cli.run_folder(out, keep=("train",)) as staging:
        (staging / "config.json").write_text("new")
    assert sorted(_folder(out)) == ["config.json", "run.json", "train/checkpoint"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]


def test_run_json_records_what_made_the_run(tmp_path):
    with _cli.run_folder(tmp_path / "run") as staging:
        (staging / "x").write_text("")
    record = json.loads((tmp_path / "run" / "run.json").read_text())
    assert set(record) == {"versions", "git", "argv", "cwd", "xla_flags", "device", "started", "finished"}
    assert "--xla_cpu_experimental_ynn_fusion_type=" in record["xla_flags"]  # the configuration numbers came from
    assert {"python", "jax", "jaxlib", "flax", "optax", "optimistix", "orbax-checkpoint", "numpy",
            "opencv-python-headless", "scipy", "mvmocap"} == set(record["versions"])
    assert record["versions"]["jax"] and record["versions"]["numpy"]
    assert len(record["git"]["commit"]) == 40 and isinstance(record["git"]["dirty"], bool)
    assert record["argv"] == sys.argv and record["cwd"] == os.getcwd()
    assert set(record["device"]) == {"platform", "kind", "count", "cpu", "cpu_features", "cpu_count"}
    assert set(record["device"]["cpu_features"]) <= set(training.SIMD_FEATURES)
    assert record["device"]["count"] >= 1 and record["started"] <= record["finished"]


def test_provenance_without_git_says_null(monkeypatch):
    monkeypatch.setenv("PATH", "/nonexistent")
    assert training.provenance()["git"] == {"commit": None, "dirty": None}


def test_find_data_root(tmp_path, monkeypatch):
    monkeypatch.delenv("MVMOCAP_DATA_ROOT", raising=False)
    assert mocap.find_data_root() is None
    (tmp_path / "shelf").mkdir()
    assert mocap.find_data_root(tmp_path, "shelf") == tmp_path
    with pytest.raises(ValueError, match=f"data folder {tmp_path} holds no cmu_mocap"):
        mocap.find_data_root(tmp_path, "cmu_mocap")
    with pytest.raises(ValueError, match="data folder /nonexistent is not a folder"):
        mocap.find_data_root("/nonexistent")
    monkeypatch.setenv("MVMOCAP_DATA_ROOT", str(tmp_path))
    assert mocap.find_data_root(needs="shelf") == tmp_path
    assert mocap.find_data_root(tmp_path / "shelf") == tmp_path / "shelf"  # the explicit path wins
    monkeypatch.setenv("MVMOCAP_DATA_ROOT", str(tmp_path / "absent"))
    with pytest.raises(ValueError, match=r"\$MVMOCAP_DATA_ROOT .*absent is not a folder"):
        mocap.find_data_root()


def test_entry_point_process_refuses_a_bad_option_in_one_line(tmp_path):
    result = _run("structri_virtual", "--out", str(tmp_path / "out"), "--recentre", "ture")
    assert result.returncode == 2 and result.stdout == ""
    assert result.stderr == ("python -m experiments.structri_virtual: error: unrecognised option(s): ture "
                             "(see --help)\n"), result.stderr


def test_entry_point_process_that_fails_writes_no_outputs(tmp_path):
    """``--frames 0`` (no poses): the run fails in one line and leaves no output folder behind."""
    out = tmp_path / "out"
    result = _run("structri_virtual", "--out", str(out), "--frames", "0", "--patterns", "round", "--views", "2",
                  "--sigmas", "2", "--reference-frames", "1")
    assert result.returncode == 2, result.stderr
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith("python -m experiments.structri_virtual: error: ") and "Traceback" not in result.stderr
    assert not out.exists() and list(tmp_path.iterdir()) == []


@pytest.mark.data
def test_entry_point_process_warns_in_one_line(data_root, tmp_path):
    """A warning reads like an error: one line naming the command, no source line (here shelf_eval's coverage
    warning for predictions of 10 frames; the process's other stderr lines are XLA's log)."""
    predictions = mocap.predictions_from_4dassoc(data_root / "shelf" / "4d_association" / "skel.txt")
    keep = predictions.frame < 310
    mocap.write_predictions(tmp_path / "p.jsonl", mocap.PosePredictions(
        *(x[keep] if x is not None else None for x in predictions)))
    result = _run("shelf_eval", "--pred", str(tmp_path / "p.jsonl"), "--data-root", str(data_root),
                  "--protocol", "jcsat")
    assert result.returncode == 0, result.stderr
    said = [line for line in result.stderr.splitlines() if "shelf_eval" in line or "Warning" in line]
    assert said == ["python -m experiments.shelf_eval: warning: predictions cover 10 of the 279 evaluated frames "
                    "(3.6%): every person in the other frames is scored a miss"]


@pytest.mark.data
def test_a_run_that_fails_under_its_progress_bar_says_so_on_a_line_of_its_own(data_root, tmp_path):
    """The shipped model with a truncated ``state.npz`` fails in the bar's first stage; the bar is closed first."""
    model = tmp_path / "model"
    shutil.copytree(jcsat.SHIPPED_MODEL, model)
    (model / "state.npz").write_bytes((model / "state.npz").read_bytes()[:1000])
    result = _run("shelf_jcsat", "--data-root", str(data_root), "--model", str(model), "--out", str(tmp_path / "out"))
    assert result.returncode == 2
    assert re.search(r"(^|\n)python -m experiments.shelf_jcsat: error: \S+state.npz cannot be read", result.stderr), \
        result.stderr



def test_flex_synthetic_refuses_a_clip_that_is_neither_shipped_nor_a_file(capsys):
    from experiments import flex_synthetic

    with pytest.raises(SystemExit) as exit_info:
        _cli.parse(flex_synthetic.Config, ["--out", "x", "--clips", "02_01_walk", "no_such_walk.txt"],
                   prog="flex_synthetic")
    assert exit_info.value.code == 2
    error = capsys.readouterr().err
    assert error.count("\n") == 1 and "--clips 'no_such_walk.txt' is neither a shipped clip" in error, error

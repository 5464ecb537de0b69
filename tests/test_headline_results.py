"""The README's headline results, pinned: each command runs as a user runs it (one subprocess per command, its
output JSON read back), so a collapse of a shipped model or of the baseline fails here.

The pinned values are the ones these commands printed on the development machine on 2026-11-25 (2-core AMD
EPYC VM, jax/jaxlib 0.10.1, numpy 2.4.6). On one machine and install the runs repeat exactly; across machines and
installs the Shelf figures move through borderline K-Means and tracking decisions (docs/jcsat.md,
"Reproducibility across machines"), hence the tolerances below, each justified where it is set.

Only stable command-line flags are used (``--data-root``, ``--out``, ``--quick``), and only the output files are
read: the experiment code behind the entry points may move without touching this file.
"""

import json
import subprocess
import sys
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pytest

from _compile_flags import user_environment

REPO = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.slow


def _run(module: str, *args: str | Path, out: Path) -> None:
    """``python -m experiments.MODULE ARGS --out OUT`` from the repository root, with XLA's default compilation
    (tests/_compile_flags.py); fails with its last output lines."""
    env = user_environment(PYTHONPATH=str(REPO))
    run = subprocess.run([sys.executable, "-m", f"experiments.{module}", *map(str, args), "--out", str(out)],
                         cwd=REPO, env=env, capture_output=True, text=True)
    if run.returncode != 0:
        pytest.fail(f"experiments.{module} exited with {run.returncode}:\n{run.stderr[-3000:]}", pytrace=False)


# ---------------------------------------------------------------------------------------------------------------
# Shelf, real OpenPose detections, actorsGT frames 300-600 (the main job; README "Shelf, real OpenPose detections")


class Scores(NamedTuple):
    pcp: float  # average over actors 1-3, %
    mpjpe_mm: float  # over the matched instances of actors 1-3
    actor_pcp: tuple[float, float, float]  # actors 1, 2, 3
    actor_mpjpe_mm: tuple[float, float, float]


# `python -m experiments.shelf_jcsat --data-root DATA --out OUT` on 2026-11-25 (2-core AMD EPYC VM with AVX-512, jax
# 0.10.1, numpy 2.4.6), the figures the README quotes; an earlier fresh install that day printed the same averages.
# One other install of the same machine type and packages printed model 97.00 / 96.64 and baseline 96.82 / 96.46
# (VoxelPose / JCSAT protocol) with the same code (byte-identical predictions before and after the package
# restructure on each machine): the K-Means and tracking decisions of borderline frames differ between installs
# (docs/jcsat.md, "Reproducibility across machines").
# On these predictions the 4D-association protocol (Hungarian matching) pairs every person as the VoxelPose protocol
# does, so the two rows of each method are the same figures.
_JCSAT_VOXELPOSE = Scores(pcp=97.0260, mpjpe_mm=58.1862, actor_pcp=(99.7133, 94.5946, 96.7702),
                          actor_mpjpe_mm=(56.1327, 62.4573, 55.9687))
_GEOMETRIC_VOXELPOSE = Scores(pcp=96.8798, mpjpe_mm=57.6526, actor_pcp=(99.1756, 93.5135, 97.9503),
                              actor_mpjpe_mm=(56.0975, 67.9891, 48.8712))
SHELF = {
    "jcsat": {
        "voxelpose": _JCSAT_VOXELPOSE,
        "jcsat": Scores(pcp=96.5756, mpjpe_mm=59.0648, actor_pcp=(99.7133, 93.2432, 96.7702),
                        actor_mpjpe_mm=(56.1327, 65.0930, 55.9687)),
        "4dassoc": _JCSAT_VOXELPOSE,
    },
    "geometric": {
        "voxelpose": _GEOMETRIC_VOXELPOSE,
        "jcsat": Scores(pcp=96.6095, mpjpe_mm=58.8534, actor_pcp=(99.1756, 92.7027, 97.9503),
                        actor_mpjpe_mm=(56.0975, 71.5916, 48.8712)),
        "4dassoc": _GEOMETRIC_VOXELPOSE,
    },
}
# The 4D-association output (skel.txt) is a fixed file scored by the evaluator alone, the same under every protocol:
# only the rounding of the pinned digits may differ.
FOUR_D_ASSOCIATION = Scores(pcp=96.2674, mpjpe_mm=53.9272, actor_pcp=(99.7491, 91.3514, 97.7019),
                            actor_mpjpe_mm=(52.5426, 59.2741, 49.9648))
# Tolerances of the methods' rows, from the other install's figures against these: averages moved by up to 0.152 PCP
# points (the baseline under the JCSAT protocol: one part of actor 2 and one of actor 3), actors by up to 0.27 (one
# part of actor 2's 370), MPJPE by up to 0.2 mm on the average and 0.5 mm on one actor. The tolerances allow about
# twice that: 0.3 points on an average, 0.5 per actor, 1 mm and 2 mm. Actor 4 is left out: it is not in the headline
# average and moved by 2 points across installs. A collapse of the model or the baseline moves these by whole points
# or centimetres.
PCP_TOLERANCE, ACTOR_PCP_TOLERANCE, MPJPE_TOLERANCE_MM, ACTOR_MPJPE_TOLERANCE_MM = 0.3, 0.5, 1.0, 2.0
EXACT_TOLERANCE = 1e-4  # the pinned values' rounding


@pytest.fixture(scope="module")
def shelf_metrics(data_root, tmp_path_factory) -> dict:
    out = tmp_path_factory.mktemp("shelf_jcsat")
    _run("shelf_jcsat", "--data-root", data_root, out=out)
    return json.loads((out / "metrics.json").read_text())


def _assert_scores(scores: dict, expected: Scores, pcp_tolerance, actor_pcp_tolerance, mpjpe_tolerance,
                   actor_mpjpe_tolerance) -> None:
    actors = scores["actors"][:3]
    assert scores["averaged_actors"] == [0, 1, 2]
    assert [a["misses"] for a in actors] == [0, 0, 0]
    assert scores["average"]["pcp"] == pytest.approx(expected.pcp, abs=pcp_tolerance)
    assert scores["average"]["mpjpe_mm"] == pytest.approx(expected.mpjpe_mm, abs=mpjpe_tolerance)
    assert [a["pcp"] for a in actors] == pytest.approx(expected.actor_pcp, abs=actor_pcp_tolerance)
    assert [a["mpjpe_mm"] for a in actors] == pytest.approx(expected.actor_mpjpe_mm, abs=actor_mpjpe_tolerance)


@pytest.mark.data
def test_shelf_runs_on_the_real_frames_with_the_shipped_model(shelf_metrics):
    assert not shelf_metrics["synthetic"]
    assert shelf_metrics["data"]["kind"] == "shelf" and shelf_metrics["data"]["frames"] == [300, 600]
    assert shelf_metrics["data"]["views"] == [0, 1, 2, 3, 4]
    assert set(shelf_metrics["scores"]) == {*SHELF, "4DA output"}


@pytest.mark.data
@pytest.mark.parametrize("method, protocol", [(m, p) for m in SHELF for p in SHELF[m]])
def test_shelf_headline_pcp_and_mpjpe(shelf_metrics, method, protocol):
    _assert_scores(shelf_metrics["scores"][method][protocol], SHELF[method][protocol], PCP_TOLERANCE,
                   ACTOR_PCP_TOLERANCE, MPJPE_TOLERANCE_MM, ACTOR_MPJPE_TOLERANCE_MM)


@pytest.mark.data
@pytest.mark.parametrize("protocol", ["voxelpose", "jcsat", "4dassoc"])
def test_shelf_four_d_association_output_row(shelf_metrics, protocol):
    _assert_scores(shelf_metrics["scores"]["4DA output"][protocol], FOUR_D_ASSOCIATION, *(EXACT_TOLERANCE,) * 4)


# ---------------------------------------------------------------------------------------------------------------
# Continuous results (no discrete decisions to flip): run to run they repeat exactly; across installs, float
# differences in the 6th or 7th digit (XLA versions, CPU instruction sets) do not grow past the 4th in these averages.
# A regression (another model, a wrong bone, another camera or noise draw) moves them by percents.
RELATIVE_TOLERANCE = 1e-3


def _assert_table(measured: dict, expected: dict, rel: float = RELATIVE_TOLERANCE) -> None:
    """Every pinned row within ``rel``; the message lists each row that is off."""
    assert measured.keys() >= expected.keys(), sorted(set(expected) - set(measured))
    off = {key: (measured[key], value) for key, value in expected.items()
           if measured[key] != pytest.approx(value, rel=rel)}
    assert not off, f"measured against pinned: {off}"


# `python -m experiments.structri_virtual --quick --out OUT` (README "Structural Triangulation, virtual rings", on
# the quick grid: 120 poses): MPJPE mm of LEM, LS and ST + SCA per (pattern, cameras, sigma px).
STRUCTRI_QUICK = {
    ("round", 2, 2): (232.564, 126.204, 68.783),
    ("round", 2, 10): (462.227, 232.449, 135.757),
    ("round", 3, 2): (5.694, 5.151, 4.334),
    ("round", 3, 10): (29.953, 25.796, 21.197),
    ("round", 4, 2): (5.473, 4.503, 3.777),
    ("round", 4, 10): (27.819, 22.483, 18.848),
    ("half", 2, 2): (6.568, 6.385, 5.324),
    ("half", 2, 10): (32.658, 31.368, 25.835),
    ("half", 3, 2): (6.011, 5.253, 4.307),
    ("half", 3, 10): (30.834, 26.082, 21.633),
    ("half", 4, 2): (5.245, 4.498, 3.792),
    ("half", 4, 10): (27.621, 22.308, 18.346),
}


def test_structri_virtual_quick(tmp_path):
    _run("structri_virtual", "--quick", out=tmp_path)
    results = json.loads((tmp_path / "results.json").read_text())
    measured = {(c["pattern"], c["views"], c["sigma"]): tuple(c["mpjpe_mm"][m] for m in ("LEM", "LS", "ST"))
                for c in results["cells"]}
    assert len(measured) == len(STRUCTRI_QUICK) and results["poses"]["frames"] == 120
    _assert_table(measured, STRUCTRI_QUICK)
    assert all(target["met"] for target in results["targets"].values()), results["targets"]


# `python -m experiments.flex_synthetic --quick --out OUT` on the shipped models (README "FLEX, held-out synthetic CMU
# clips", on 4 sequences instead of 16): (MPJPE mm, acceleration error mm/frame^2) per (cameras, method, calibration),
# 2D detector input.
FLEX_QUICK = {
    ("static", "FLEX (4 views)", "none"): (87.976, 23.019),
    ("static", "DLT", "exact"): (49.441, 131.101),
    ("static", "DLT", "perturbed 3 %"): (58.043, 138.875),
    ("static", "DLT", "perturbed 4 %"): (59.935, 138.262),
    ("static", "Structural Triangulation", "exact"): (44.007, 115.886),
    ("static", "Structural Triangulation", "perturbed 3 %"): (50.917, 121.146),
    ("static", "Structural Triangulation", "perturbed 4 %"): (53.787, 120.715),
    ("dynamic", "FLEX (4 views)", "none"): (89.439, 29.456),
    ("dynamic", "DLT", "exact"): (52.448, 137.241),
    ("dynamic", "DLT", "perturbed 3 %"): (67.763, 158.362),
    ("dynamic", "DLT", "perturbed 4 %"): (79.178, 178.054),
    ("dynamic", "DLT", "stale (first frame)"): (103.341, 201.640),
    ("dynamic", "Structural Triangulation", "exact"): (46.976, 123.158),
    ("dynamic", "Structural Triangulation", "perturbed 3 %"): (57.383, 131.538),
    ("dynamic", "Structural Triangulation", "perturbed 4 %"): (69.454, 154.306),
    ("dynamic", "Structural Triangulation", "stale (first frame)"): (88.769, 170.838),
}


# The same run's fixed rig (h36m_ring, 2 perturbed calibrations per scale), correlated 2D noise: (MPJPE mm,
# acceleration error mm/frame^2) per (method, calibration), the perturbed rows' means over the draws. DLT with 3 %
# is not pinned: one of its two draws sends a few joints far off (166 +- 94 mm), a figure no tolerance makes stable.
# The rig's rows get RIG_TOLERANCE: on a 2-core VM without AVX-512 (2026-11-27) Structural Triangulation with 3 %
# perturbed calibrations gave 61.835 mm and 132.387 mm/frame^2, 0.04 % and 0.10 % off these AVX-512 figures.
RIG_TOLERANCE = 3e-3
FLEX_QUICK_RIG = {
    ("FLEX (trained on h36m_ring)", "none"): (79.103, 23.639),
    ("FLEX (random rigs)", "none"): (72.756, 26.381),
    ("DLT", "exact"): (51.299, 102.030),
    ("DLT", "perturbed 4 %"): (70.948, 148.158),
    ("Structural Triangulation", "exact"): (44.938, 90.357),
    ("Structural Triangulation", "perturbed 3 %"): (61.862, 132.521),
    ("Structural Triangulation", "perturbed 4 %"): (58.205, 115.456),
}


def test_flex_synthetic_quick_on_the_shipped_models(tmp_path):
    _run("flex_synthetic", "--quick", out=tmp_path)
    results = json.loads((tmp_path / "results.json").read_text())
    assert results["config"]["sequences"] == 4 and results["missing_models"] == []
    measured = {(r["camera_motion"], r["method"], r["calibration"]): (r["mpjpe_mm"], r["acceleration_error_mm"])
                for r in results["main"] if r["input_2d"] == "detected"}
    assert measured.keys() == FLEX_QUICK.keys()
    _assert_table(measured, FLEX_QUICK)
    # Fixed rig: both noise settings share motion and calibrations; each perturbed row is the mean of its draws.
    rigs = {(r["noise_correlation"], r["method"], r["calibration"]): r for r in results["rigs"]}
    assert {rig for rig, _, _ in rigs} == {0.0, 0.9} and len(rigs) == len(results["rigs"]) == 2 * (2 + 2 * 3)
    _assert_table({(m, c): (r["mpjpe_mm"], r["acceleration_error_mm"]) for (noise, m, c), r in rigs.items()
                   if noise > 0}, FLEX_QUICK_RIG, rel=RIG_TOLERANCE)
    for row in results["rigs"]:
        assert np.isfinite(row["root_error_mm"]) and row["root_error_mm"] > 0
        if "draws_mpjpe_mm" in row:
            assert len(row["draws_mpjpe_mm"]) == 2 and row["mpjpe_mm"] == pytest.approx(np.mean(row["draws_mpjpe_mm"]))
    assert rigs[0.0, "DLT", "exact"]["mpjpe_mm"] != rigs[0.9, "DLT", "exact"]["mpjpe_mm"]
    # Every method, calibration, input and ablation is scored, finite (the structure the tables are made of).
    main = {(r["camera_motion"], r["input_2d"], r["method"], r["calibration"]) for r in results["main"]}
    for motion in ("static", "dynamic"):
        for source in ("detected", "gt"):
            assert (motion, source, "FLEX (4 views)", "none") in main
            for method in ("DLT", "Structural Triangulation"):
                for calibration in ("exact", "perturbed 3 %", "perturbed 4 %"):
                    assert (motion, source, method, calibration) in main
            assert ((motion, source, "DLT", "stale (first frame)") in main) == (motion == "dynamic")
    variants = [(r["camera_motion"], r["variant"]) for r in results["ablations"]]
    assert len(variants) == 2 * 7 and ("dynamic", "averaged monocular") in variants
    for row in results["main"] + results["ablations"]:
        assert all(np.isfinite(row[k]) and row[k] >= 0 for k in ("mpjpe_mm", "acceleration_error_mm", "mbls_mm"))
    exact_gt = [r for r in results["main"] if r["input_2d"] == "gt" and r["calibration"] == "exact"]
    assert all(r["mpjpe_mm"] < 5 for r in exact_gt)  # exact 2D and cameras: triangulation is exact
    for name in ("rigs.png", "results.md", "skeletons.png", "mpjpe.png"):
        assert (tmp_path / name).stat().st_size > 0
    assert len((tmp_path / "log.jsonl").read_text().splitlines()) == sum(
        len(results[table]) for table in ("main", "ablations", "rigs"))


# `python -m experiments.dynamics --quick --out OUT` on the shipped models (README "Dynamics", on test windows every
# 15 frames): two-person samples, MPJPE then PA-MPJPE (mm) at future frames 1, 10, 20 and 30 per method.
DYNAMICS_HORIZONS = (1, 10, 20, 30)
DYNAMICS_QUICK = {
    "JAT": (119.167, 148.218, 164.014, 168.351, 98.321, 104.610, 107.907, 104.783),
    "JAT w/o bias": (119.201, 148.894, 162.604, 167.242, 98.324, 104.410, 107.656, 104.938),
    "MPJAT": (119.336, 146.630, 163.732, 166.533, 98.356, 104.310, 107.472, 102.925),
    "MPJAT w/o P": (119.824, 147.889, 163.991, 166.505, 98.363, 104.506, 107.298, 102.915),
    "PHD+T": (117.594, 148.459, 168.005, 176.166, 98.381, 105.106, 106.938, 104.650),
    "ZeroMotion": (117.420, 146.365, 160.268, 167.341, 97.988, 104.686, 106.267, 103.982),
}


def test_dynamics_quick_on_the_shipped_models(tmp_path):
    _run("dynamics", "--quick", out=tmp_path)
    summary = json.loads((tmp_path / "results.json").read_text())["summary"]
    assert summary["single_person"]["samples"] == 47 and summary["two_person"]["samples"] == 50
    two_person = summary["two_person"]["prediction"]
    measured = {method: tuple(metrics[name][k - 1] for name in ("mpjpe", "pa_mpjpe") for k in DYNAMICS_HORIZONS)
                for method, metrics in two_person.items()}
    assert measured.keys() == DYNAMICS_QUICK.keys()
    _assert_table(measured, DYNAMICS_QUICK)
    # The depth ratio (docs/dynamics.md): with 16 renders per training clip the pair is placed within 2 % of its depth,
    # not 5 % too near the camera as with 8 nor a fifth as with 2.
    depth = {group: summary[group]["conditioning"]["PHD+T"]["depth_ratio"] for group in ("single_person", "two_person")}
    assert depth == pytest.approx({"single_person": 0.9861, "two_person": 0.9901}, abs=1e-3)
    # The rest of what the run writes (this is the test of the experiment's outputs too).
    for method, metrics in two_person.items():
        assert all(len(metrics[name]) == 30 for name in ("mpjpe", "pa_mpjpe", "pck", "root", "depth_ratio")), method
    assert all(value >= 0 for method in DYNAMICS_QUICK for value in summary["two_person"]["penetration"][method])
    assert "ground truth" in summary["two_person"]["penetration"]
    for name in ("results.md", "prediction_two_person.png", "strip.png", "run.json"):
        assert (tmp_path / name).is_file(), name
    markdown = (tmp_path / "results.md").read_text()
    assert "| ZeroMotion |" in markdown and "| MPJAT |" in markdown and "Interpenetration" in markdown


# `python -m experiments.dynamics_forecast --quick --data-root DATA --out OUT` on the shipped 3D forecasters (docs/
# dynamics.md "3D forecasting", on test windows every 25 frames): MPJPE (mm) averaged over the actions of the CMU-Mocap
# benchmark's test split at 80, 160, 320, 400 and 1000 ms.
FORECAST_QUICK = {
    "ZeroMotion": (35.181, 65.944, 112.723, 122.573, 116.026),
    "Constant velocity": (20.563, 57.050, 142.481, 188.755, 475.941),
    "PHD+T": (17.391, 39.739, 73.664, 82.266, 104.528),
    "JAT": (19.466, 42.530, 76.564, 83.823, 104.707),
    "JAT w/o bias": (19.182, 41.069, 72.590, 79.567, 106.753),
}


# `python -m experiments.dynamics_forecast --pairs --quick --data-root DATA --out OUT` on the shipped pair forecasters
# (docs/dynamics.md "Two people"): the test salsa pair, windows every 25 frames, MPJPE (mm) at 80-1000 ms, and the
# interpenetration (mm) of each method's forecast at those horizons.
FORECAST_PAIRS_QUICK = {
    "ZeroMotion": (60.970, 99.658, 134.584, 143.430, 179.251),
    "Constant velocity": (54.167, 140.056, 318.215, 396.566, 950.368),
    "JAT (one person)": (69.468, 150.258, 189.721, 193.923, 225.306),
    "JAT": (45.494, 85.520, 119.349, 130.454, 153.345),
    "MPJAT": (44.592, 84.066, 117.442, 129.261, 146.966),
    "MPJAT w/o interpenetration": (44.869, 84.695, 118.824, 130.300, 147.790),
}
# Depths of a few vertices averaged: figures of a few hundredths of a millimetre, pinned to a thousandth (absolute).
FORECAST_PAIRS_PENETRATION = {
    "ZeroMotion": (0.0000, 0.0000, 0.0000, 0.0000, 0.0000),
    "ground truth": (0.0344, 0.0067, 0.0000, 0.0000, 0.0000),
    "JAT (one person)": (0.0188, 0.0767, 0.0073, 0.0000, 0.1326),
    "JAT": (0.0000, 0.0531, 0.4294, 0.4898, 0.7048),
    "MPJAT": (0.0049, 0.0861, 0.4634, 0.5500, 1.5448),
    "MPJAT w/o interpenetration": (0.0070, 0.0935, 0.4658, 0.5585, 1.7285),
}


@pytest.mark.parametrize(("options", "windows", "pinned", "penetration"), [
    ((), {"basketball": 3, "jumping": 16, "running": 0, "soccer": 4, "walking": 2, "walking_extra": 37,
          "washwindow": 21}, FORECAST_QUICK, None),
    (("--pairs",), {"60_05_scaled+61_05_scaled": 13}, FORECAST_PAIRS_QUICK, FORECAST_PAIRS_PENETRATION),
], ids=["one person", "pairs"])
def test_dynamics_forecast_quick_on_the_shipped_models(data_root, tmp_path, options, windows, pinned, penetration):
    _run("dynamics_forecast", *options, "--quick", "--data-root", data_root, out=tmp_path)
    results = json.loads((tmp_path / "results.json").read_text())
    assert results["fps"] == 25.0 and results["observed_frames"] == 25 and results["horizon_frames"] == [2, 4, 8, 10, 25]
    assert results["windows"] == windows and results["people"] == (2 if penetration else 1)
    measured = {method: tuple(table["average"]) for method, table in results["mpjpe_mm"].items()}
    assert measured.keys() == pinned.keys()
    _assert_table(measured, pinned)
    for name in ("results.md", "forecast.png", "run.json", "log.jsonl"):
        assert (tmp_path / name).is_file(), name
    markdown = (tmp_path / "results.md").read_text()
    if penetration is None:
        assert "No window (file shorter than 50 frames): running." in markdown and "penetration_mm" not in results
        return
    assert "## Interpenetration" in markdown
    depths = {method: tuple(values) for method, values in results["penetration_mm"].items()}
    assert depths.keys() == penetration.keys()
    off = {method: (depths[method], value) for method, value in penetration.items()
           if depths[method] != pytest.approx(value, abs=1e-3)}
    assert not off, f"measured against pinned: {off}"

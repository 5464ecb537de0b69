"""The real-Shelf table of Structural Triangulation (experiments/structri_study/_shelf.py, structri_shelf)."""

import json
from types import SimpleNamespace

import numpy as np
import pytest

import flex
import geometry
from experiments import _cli, structri_shelf
from experiments.flex_study import FlexShelfConfig, run_flex_shelf
from experiments.structri_study import SHELF_METHODS, ShelfConfig, ShelfScene, run_shelf
from experiments.structri_study._shelf import (LIMBS, length_spread, limb_lengths, match_tracks, score_rows, solvable,
                                               symmetry_error, track_observations, view_subsets)

FLEX_ROWS = 94
FLEX_MPJPE = {"flex_4views": 183.8, "DLT exact": 59.2, "ST exact": 58.9, "DLT 3 %": 66.5, "ST 3 %": 66.0}
"""experiments.flex_shelf's table on the --quick frames (2 perturbation draws): its rows and MPJPE (mm)."""

LIMB_LENGTHS = np.array([0.30, 0.25, 0.45, 0.45, 0.32, 0.28, 0.44, 0.46])
"""Right upper arm, forearm, thigh, shin, then the left ones (:data:`LIMBS` order), metres."""


def _shelf15_pose(offset=(0.0, 0.0, 0.0)) -> np.ndarray:
    """A Shelf15 pose standing along z with :data:`LIMB_LENGTHS`, its right side at x = 0 and left at x = 0.4."""
    at = {"r_shoulder": (0, 0, 1.5), "r_elbow": (0, 0, 1.2), "r_wrist": (0, 0, 0.95), "r_hip": (0, 0, 1.0),
          "r_knee": (0, 0, 0.55), "r_ankle": (0, 0, 0.1), "l_shoulder": (0.4, 0, 1.5), "l_elbow": (0.4, 0, 1.18),
          "l_wrist": (0.4, 0, 0.9), "l_hip": (0.4, 0, 1.0), "l_knee": (0.4, 0, 0.56), "l_ankle": (0.4, 0, 0.1),
          "head_bottom": (0.2, 0, 1.6), "head_top": (0.2, 0, 1.85), "mid_hip": (0.2, 0, 1.0)}
    pose = np.array([at[name] for name in geometry.SHELF15.joints], float)
    return pose + np.asarray(offset)


def test_view_subsets_are_every_combination():
    assert [len(view_subsets(5, c)) for c in (2, 3, 4, 5)] == [10, 10, 5, 1]
    assert view_subsets(5, 4)[0] == (0, 1, 2, 3) and view_subsets(5, 5) == [(0, 1, 2, 3, 4)]
    assert len(set(view_subsets(5, 3))) == 10


def test_solvable_needs_two_positive_views_per_joint_within_the_subset():
    weight = np.zeros((3, 2, 4))  # 3 track-frames, 2 joints, 4 views
    weight[0] = [[0.9, 0.8, 0, 0], [0.5, 0.4, 0.3, 0]]  # both joints seen by views 0 and 1
    weight[1] = [[0.9, 0.8, 0, 0.6], [0.5, 0, 0, 0.7]]  # joint 1: views 0 and 3 only
    weight[2] = [[0.9, 0, 0, 0], [0.5, 0.4, 0.3, 0.2]]  # joint 0: one view
    assert solvable(weight).tolist() == [True, True, False]
    assert solvable(weight, (0, 1)).tolist() == [True, False, False]
    assert solvable(weight, (0, 3)).tolist() == [False, True, False]
    assert solvable(weight, (1, 2, 3)).tolist() == [False, False, False]


def test_limb_lengths_symmetry_and_spread_by_hand():
    lengths = limb_lengths(_shelf15_pose())
    np.testing.assert_allclose(lengths, LIMB_LENGTHS, atol=1e-12)
    assert LIMBS[4] == ("l_shoulder", "l_elbow")  # the left bones mirror the right ones in order
    # |0.30 - 0.32|, |0.25 - 0.28|, |0.45 - 0.44|, |0.45 - 0.46|
    assert symmetry_error(lengths) == pytest.approx((0.02 + 0.03 + 0.01 + 0.01) / 4)
    # Variances over the frames 1 and 0, mean 0.5.
    assert length_spread(np.array([[1.0, 2.0], [3.0, 2.0]])) == pytest.approx(np.sqrt(0.5))


def test_match_tracks_takes_the_nearest_valid_track_within_half_a_metre():
    actor0, actor1 = _shelf15_pose(), _shelf15_pose((2.0, 0.0, 0.0))
    tracks = np.stack([np.stack([actor0 + 0.05] * 2),  # beside actor 0 in both frames
                       np.stack([actor1 + [0, 0, 0.6]] * 2),  # 0.6 m above actor 1: beyond the gate
                       np.stack([actor1 + 0.01] * 2)])  # on actor 1, but not solvable in frame 0
    valid = np.array([[True, True], [True, True], [False, True]])
    truth = np.stack([np.stack([actor0] * 2), np.stack([actor1] * 2), np.stack([actor0] * 2)])
    annotated = np.array([[True, True], [True, True], [False, False]])
    assert match_tracks(tracks, valid, truth, annotated).tolist() == [[0, 0], [-1, 2], [-1, -1]]


def test_track_observations_map_slots_to_tracks_and_body25_to_skel19():
    frames, slots, joints, views = 2, 2, 25, 3
    pixels = np.arange(frames * slots * joints * views * 2, dtype=float).reshape(frames, slots, joints, views, 2)
    weight = pixels[..., 0] + 1.0
    result = SimpleNamespace(track_of=np.array([[4, -1], [-1, 7]]),
                             consensus=SimpleNamespace(pixels=pixels, view_weight=weight))
    got_pixels, got_weight = track_observations(result, np.array([4, 7]))
    skel19 = [geometry.BODY25.index(name) for name in geometry.SKEL19.joints]
    assert got_pixels.shape == (2, frames, 19, views, 2) and got_weight.shape == (2, frames, 19, views)
    np.testing.assert_array_equal(got_pixels[0, 0], pixels[0, 0, skel19])
    np.testing.assert_array_equal(got_weight[1, 1], weight[1, 1, skel19])
    assert not got_weight[0, 1].any() and not got_weight[1, 0].any()  # absent tracks weigh nothing


def test_score_rows_by_hand():
    truth = np.stack([_shelf15_pose()] * 3)
    predicted = truth + [0.1, 0.0, 0.0]  # every joint 100 mm off, the lengths exact
    reference = np.stack([LIMB_LENGTHS + 0.01, LIMB_LENGTHS])
    scores = score_rows(predicted, truth, np.array([0, 0, 1]), reference)
    assert sorted(scores["actors"]) == [1, 2] and scores["actors"][1]["frames"] == 2
    assert scores["mean"]["mpjpe_mm"] == pytest.approx(100.0)
    assert scores["actors"][1]["mpble_mm"] == pytest.approx(10.0) and scores["actors"][2]["mpble_mm"] == pytest.approx(0.0)
    assert scores["mean"]["mpble_mm"] == pytest.approx(5.0)
    assert scores["mean"]["symmetry_mm"] == pytest.approx(17.5) and scores["mean"]["mbls_mm"] == pytest.approx(0.0)
    # 100 mm is below half of every part but the 250 mm head (strict rule: 100 < 125 passes, the torso too).
    assert scores["mean"]["pcp"] == pytest.approx(100.0)
    far = score_rows(truth + [0.2, 0, 0], truth, np.array([0, 0, 1]), reference)
    # 200 mm fails the parts shorter than 400 mm: upper arms, forearms, head (5 of 10).
    assert far["mean"]["pcp"] == pytest.approx(50.0)
    assert score_rows(truth[:0], truth[:0], np.zeros(0, int), reference)["mean"]["pcp"] is None


def test_config_refuses_bad_settings(data_root, tmp_path):
    with pytest.raises(ValueError, match="holds no shelf"):
        ShelfConfig(str(tmp_path))
    for bad in (dict(view_counts=(1, 2)), dict(view_counts=(3, 3)), dict(frames=0), dict(frames=302),
                dict(n_steps=0), dict(estimate_frames=0)):
        with pytest.raises(ValueError):
            ShelfConfig(str(data_root), **bad)


def test_a_missing_data_folder_is_one_line_naming_it(capsys):
    with pytest.raises(SystemExit) as exit_info:
        _cli.parse(structri_shelf.Config, ["--out", "x", "--data-root", "/nonexistent"], prog="structri_shelf")
    assert exit_info.value.code == 2
    error = capsys.readouterr().err
    assert error.startswith("structri_shelf: error: ") and error.count("\n") == 1, error
    assert "data folder /nonexistent is not a folder" in error


@pytest.fixture(scope="module")
def quick_scene(data_root) -> ShelfScene:
    """The association of the --quick frames, run once for this table and FLEX's (tests/test_flex_shelf.py tests
    the rest of that table)."""
    return ShelfScene(ShelfConfig(str(data_root), **structri_shelf.QUICK))


def test_quick_table_on_the_real_detections(data_root, quick_scene, tmp_path):
    """The --quick setting in-process: the files, their structure and a few values measured on 2026-11-25 (2-core
    VM). The tolerances allow for the association moving a little between installs (docs/jcsat.md: up to 0.15 PCP
    points on the full run); the coverage and counts are exact."""
    config = ShelfConfig(str(data_root), **structri_shelf.QUICK)
    results = run_shelf(config, tmp_path, quick_scene)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["config.json", "log.jsonl", "results.json", "results.md"]
    assert json.loads((tmp_path / "results.json").read_text())["summary"] == results["summary"]
    log = [json.loads(line) for line in (tmp_path / "log.jsonl").read_text().splitlines()]
    assert [entry["stage"] for entry in log] == ["association"] + ["subset"] * 11
    assert results["association"]["matched_actor_frames"] == 120 == results["association"]["annotated_actor_frames"]
    summary = results["summary"]
    assert list(summary) == ["2", "5"] and summary["2"]["subsets"] == 10 and summary["5"]["subsets"] == 1
    # With two views, some joint of every track-frame lacks a second view: nothing is scored.
    assert summary["2"]["scored_subsets"] == 0 and summary["2"]["coverage"]["max"] == 0.0
    assert summary["2"]["methods"]["ST"]["mpjpe_mm"] is None
    five = summary["5"]
    assert five["coverage"]["mean"] == 1.0 and set(five["methods"]) == set(SHELF_METHODS)
    measured = {"LS": (50.8, 97.6, 24.0, 13.4), "LEM": (50.4, 97.6, 23.8, 13.8), "Lagrangian": (50.3, 98.0, 23.0, 5.3),
                "ST": (50.3, 97.8, 22.9, 0.0), "ST*": (50.7, 97.7, 23.1, 0.0)}
    for name, (mpjpe, pcp, mpble, symmetry) in measured.items():
        got = five["methods"][name]
        assert got["mpjpe_mm"]["mean"] == pytest.approx(mpjpe, abs=0.5), name
        assert got["pcp"]["mean"] == pytest.approx(pcp, abs=0.5), name
        assert got["mpble_mm"]["mean"] == pytest.approx(mpble, abs=0.5), name
        assert got["symmetry_mm"]["mean"] == pytest.approx(symmetry, abs=0.5), name
        assert got["fallback"]["mean"] == 0.0, name
    assert "| ST | n/a | 50.3 / 97.8 / 22.9 / 0.0 |" in (tmp_path / "results.md").read_text()


def test_flex_table_on_the_same_detections(data_root, quick_scene, tmp_path):
    """experiments.flex_shelf's table on the --quick frames with 2 perturbation draws and the shipped random-rig
    model; values measured on 2026-11-26 (2-core VM)."""
    config = FlexShelfConfig(str(data_root), frames=len(quick_scene.frame_indices), perturbation_draws=2)
    results = run_flex_shelf(config, {"flex_4views": flex.load_models()["flex_4views"]}, tmp_path, scene=quick_scene)
    assert json.loads((tmp_path / "results.json").read_text())["methods"] == results["methods"]
    assert list(results["methods"]) == ["flex_4views", "DLT exact", "ST exact", "DLT 3 %", "ST 3 %"]
    assert results["rows"] == FLEX_ROWS
    measured = {name: round(method["mpjpe_mm"], 1) for name, method in results["methods"].items()}
    assert measured == pytest.approx(FLEX_MPJPE, abs=1.0)
    assert results["methods"]["ST 3 %"]["mpjpe_mm_sd"] > 0 and "| flex_4views |" in (tmp_path / "results.md").read_text()
    with pytest.raises(ValueError, match="model flex_1view takes 1 views, the table uses 4"):
        run_flex_shelf(config, {"flex_1view": flex.load_models()["flex_1view"]}, tmp_path, scene=quick_scene)

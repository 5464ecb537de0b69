"""Shelf evaluator and prediction files: the 4D-association check values of docs/protocols.md,
hand-computed cases where the three matching conventions differ, the JSON-lines format, and the CLI."""

import json
import re

import numpy as np
import pytest
from numpy.testing import assert_allclose

import geometry
from experiments import _cli, shelf_eval
from mocap import (EVALUATION_PROTOCOLS, PREDICTIONS_HEADER, PosePredictions, evaluate_shelf, format_shelf_scores,
                   ground_truth_from_shelf14, match_predictions, prediction_problems, predictions_from_4dassoc,
                   read_predictions, shelf_evaluation_ground_truth, suppress_duplicates, write_predictions)


# A standing person (SHELF14, metres). Bones: legs 0.45, lower arms 0.3, upper arms 0.269, head 0.5,
# torso (mid-hip (0, 0, 0.9) to head bottom) 0.6; the right ankle is 0.1 m from the origin.
PERSON14 = np.array([
    [0, -0.1, 0.0], [0, -0.1, 0.45], [0, -0.1, 0.9], [0, 0.1, 0.9], [0, 0.1, 0.45], [0, 0.1, 0.0],
    [0, -0.3, 0.9], [0, -0.3, 1.2], [0, -0.2, 1.45], [0, 0.2, 1.45], [0, 0.3, 1.2], [0, 0.3, 0.9],
    [0, 0, 1.5], [0, 0, 2.0],
])
PERSON15 = np.vstack([PERSON14, [0, 0, 0.9]])


def at(x):
    """The test person moved by x metres along the world x axis (SHELF15)."""
    return PERSON15 + np.array([x, 0.0, 0.0])


def ground_truth(*frames_of_actors):
    """One frame per argument: a dict actor -> x position of the test person."""
    num_actors = 1 + max(a for frame in frames_of_actors for a in frame)
    joints = np.zeros((num_actors, len(frames_of_actors), 14, 3))
    annotated = np.zeros((num_actors, len(frames_of_actors)), bool)
    for k, frame in enumerate(frames_of_actors):
        for actor, x in frame.items():
            joints[actor, k], annotated[actor, k] = at(x)[:14], True
    return ground_truth_from_shelf14(joints, annotated, np.arange(len(frames_of_actors)))


def predictions(*rows):
    """rows of (frame, joints (15, 3))."""
    return PosePredictions.create([f for f, _ in rows], list(range(len(rows))), np.stack([j for _, j in rows]))


def score(preds, gt, protocol, actors=(0,)):
    result = evaluate_shelf(preds, gt, protocol, averaged_actors=actors)
    assert result.protocol == protocol
    return {a.actor: a for a in result.actors}, result


# --- the 4D-association output (docs/protocols.md) -----------------------------------------------


@pytest.fixture(scope="module")
def fourda_predictions(data_root):
    return predictions_from_4dassoc(data_root / "shelf" / "4d_association" / "skel.txt")


@pytest.mark.parametrize("source", ["actorsGT", "4dassoc"])
def test_4da_output_reproduces_the_check_values(data_root, fourda_predictions, source):
    gt = shelf_evaluation_ground_truth(data_root, source)
    assert gt.annotated.sum(axis=1).tolist() == [279, 37, 161, 33]
    for protocol in EVALUATION_PROTOCOLS:
        actors, result = score(fourda_predictions, gt, protocol, (0, 1, 2))
        counts = [(actors[a].parts_correct, actors[a].parts_total) for a in range(4)]
        assert counts == [(2783, 2790), (338, 370), (1573, 1610), (305, 330)], protocol
        assert result.average["pcp"] == pytest.approx(96.27, abs=0.005)
        got = [[actors[a].precision, actors[a].recall, actors[a].mpjpe_mm, actors[a].mpjpe_jcsat_mm]
               for a in range(4)]
        expected = [[99.9, 99.9, 52.5, 52.5], [98.9, 96.2, 59.3, 59.3], [99.7, 99.7, 50.0, 50.0],
                    [96.4, 94.3, 72.1, 72.1]]
        assert_allclose(got, expected, atol=0.05 + 1e-9)
        assert sum(a.misses for a in result.actors) == 0
        assert sum(round(a.recall_500mm * a.annotated / 100) for a in result.actors) == 510


def test_4dassoc_ground_truth_file_scores_perfectly_against_actors_gt(data_root):
    truth = predictions_from_4dassoc(data_root / "shelf" / "4d_association" / "gt.txt")
    assert truth.num_predictions == 510 and truth.frame.min() == 300 and truth.frame.max() <= 600
    gt = shelf_evaluation_ground_truth(data_root)
    for protocol in EVALUATION_PROTOCOLS:
        actors, result = score(truth, gt, protocol, (0, 1, 2))
        assert all(a.pcp == 100.0 and a.misses == 0 and a.precision == 100.0 for a in result.actors)
        assert result.average["mpjpe_mm"] < 0.01  # gt.txt agrees with actorsGT.mat to 7.5e-6 m


# --- hand-made cases where the conventions differ ------------------------------------------------


def test_matching_rules_on_one_frame():
    """GT A at x = 0 and B at x = 1; predictions P at 0.4, Q at -0.55 (every joint moved by that)."""
    gt = np.stack([at(0.0), at(1.0)])
    pred = np.stack([at(0.4), at(-0.55)])
    # VoxelPose: both take the nearest, P (0.4 and 0.6 m), not one-to-one.
    assert match_predictions(pred, gt, "voxelpose").tolist() == [0, 0]
    # Hungarian: A-Q + B-P = 0.55 + 0.6 beats A-P + B-Q = 0.4 + 1.55.
    assert match_predictions(pred, gt, "4dassoc").tolist() == [1, 0]
    # JCSAT: P goes to A (0.4 < 0.5); Q's nearest is A at 0.55 >= 0.5, so B stays unmatched.
    assert match_predictions(pred, gt, "jcsat").tolist() == [0, -1]
    for protocol in EVALUATION_PROTOCOLS:
        assert match_predictions(pred[:0], gt, protocol).tolist() == [-1, -1]
        assert match_predictions(pred, gt[:0], protocol).tolist() == []


def test_missed_person():
    """Frame 0: actors 0 and 1, one exact prediction of actor 0; frame 1: both predicted exactly."""
    gt = ground_truth({0: 0.0, 1: 2.0}, {0: 0.0, 1: 2.0})
    preds = predictions((0, at(0.0)), (1, at(0.0)), (1, at(2.0)))
    vp, _ = score(preds, gt, "voxelpose", (0, 1))
    js, _ = score(preds, gt, "jcsat", (0, 1))
    da, result = score(preds, gt, "4dassoc", (0, 1))
    assert [vp[0].pcp, js[0].pcp, da[0].pcp] == [100.0, 100.0, 100.0]
    # VoxelPose scores actor 1 in frame 0 against actor 0's pose 2 m away: 0/10 counted.
    assert (vp[1].parts_correct, vp[1].parts_total, vp[1].misses) == (10, 20, 0)
    assert (vp[1].precision, vp[1].recall, vp[1].mpjpe_mm, vp[1].recall_500mm) == (50.0, 50.0, 1000.0, 50.0)
    # JCSAT: a miss, scored 0/10; recall counts it, precision and MPJPE do not (JCSAT MPJPE adds 0 mm).
    assert (js[1].parts_correct, js[1].parts_total, js[1].misses) == (10, 20, 1)
    assert (js[1].precision, js[1].recall, js[1].mpjpe_mm, js[1].mpjpe_jcsat_mm) == (100.0, 50.0, 0.0, 0.0)
    # 4DA: the miss is not counted at all.
    assert (da[1].parts_correct, da[1].parts_total, da[1].pcp, da[1].misses) == (10, 10, 100.0, 1)
    assert result.average["pcp"] == 100.0 and da[1].recall == 50.0 and da[1].recall_500mm == 50.0


def test_duplicate_prediction_first_in_order_wins_under_jcsat():
    """One actor; predictions: a copy moved 0.45 m (inside the 0.5 m gate, every part wrong), then an
    exact copy. JCSAT scores the first; VoxelPose and 4DA take the exact one."""
    gt = ground_truth({0: 0.0})
    preds = predictions((0, at(0.45)), (0, at(0.0)))
    assert score(preds, gt, "jcsat")[0][0].pcp == 0.0
    assert score(preds, gt, "jcsat")[0][0].precision == 0.0
    assert score(preds, gt, "voxelpose")[0][0].pcp == 100.0
    assert score(preds, gt, "4dassoc")[0][0].pcp == 100.0
    reordered = predictions((0, at(0.0)), (0, at(0.45)))
    assert score(reordered, gt, "jcsat")[0][0].pcp == 100.0


def test_suppress_duplicates_keeps_the_most_confident_prediction_of_each_person():
    """Frame 3: a copy 0.15 m off (score 1), the person (score 5), a second person 1 m away (score 2), and two
    half skeletons at one place with no joint in common. Frame 1 after it: one person. At 0.2 m the copy goes
    and the rest is ranked by score within its frame, frames in their order; at 0 m nothing goes."""
    left, right = at(3.0), at(3.0)
    left[[0, 1, 2, 6, 7, 8]], right[[3, 4, 5, 9, 10, 11, 12, 13, 14]] = 0.0, 0.0
    rows = [(3, at(0.15), 1.0), (3, at(0.0), 5.0), (3, at(1.0), 2.0), (3, left, 0.5), (3, right, 0.4),
            (1, at(0.0), 1.0)]
    preds = PosePredictions.create([f for f, _, _ in rows], [10, 11, 12, 13, 14, 15],
                                   np.stack([j for _, j, _ in rows]), score=[s for _, _, s in rows])
    kept = suppress_duplicates(preds, 0.2)
    assert kept.person.tolist() == [11, 12, 13, 14, 15] and kept.frame.tolist() == [3, 3, 3, 3, 1]
    np.testing.assert_array_equal(kept.joints[0], at(0.0))
    assert kept.score.tolist() == [5.0, 2.0, 0.5, 0.4, 1.0]
    assert suppress_duplicates(preds, 0.0).person.tolist() == [11, 12, 10, 13, 14, 15]
    assert suppress_duplicates(preds, 0.1).person.tolist() == [11, 12, 10, 13, 14, 15]
    assert suppress_duplicates(preds, 1.5).person.tolist() == [11, 13, 14, 15]


def test_suppressing_a_duplicate_restores_the_jcsat_score():
    gt = ground_truth({0: 0.0})
    preds = PosePredictions.create([0, 0], [0, 1], np.stack([at(0.45), at(0.0)]), score=[1.0, 2.0])
    assert score(preds, gt, "jcsat")[0][0].pcp == 0.0
    kept = suppress_duplicates(preds, 0.5)
    assert kept.num_predictions == 1 and score(kept, gt, "jcsat")[0][0].pcp == 100.0


def test_suppress_duplicates_refuses_bad_arguments():
    unscored = predictions((0, at(0.0)))
    with pytest.raises(ValueError, match="have none"):
        suppress_duplicates(unscored, 0.2)
    scored = unscored._replace(score=np.ones(1))
    for bad in (-0.1, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="min_distance"):
            suppress_duplicates(scored, bad)


def test_far_prediction():
    """One actor, one prediction moved 0.6 m: outside the JCSAT gate and VoxelPose's Recall@500mm."""
    gt = ground_truth({0: 0.0})
    preds = predictions((0, at(0.6)))
    vp, js, da = (score(preds, gt, p)[0][0] for p in ("voxelpose", "jcsat", "4dassoc"))
    assert [(a.parts_correct, a.parts_total, a.misses) for a in (vp, js, da)] == [(0, 10, 0), (0, 10, 1), (0, 10, 0)]
    assert vp.recall_500mm == js.recall_500mm == 0.0
    assert vp.mpjpe_mm == pytest.approx(600.0) and np.isnan(js.mpjpe_mm) and js.mpjpe_jcsat_mm == 0.0
    assert score(predictions((0, at(0.4))), gt, "voxelpose")[0][0].recall_500mm == 100.0


def test_pcp_rule_boundary_torso_start_and_zero_endpoint():
    gt = ground_truth({0: 0.0})
    # Every joint moved 0.25 m sideways: the head (0.5 m) sits exactly on the boundary, the torso
    # (0.6 m) passes, the shorter limbs fail. VoxelPose's <= keeps the head, the strict rule does not.
    shifted = predictions((0, PERSON15 + np.array([0.0, 0.25, 0.0])))
    assert [score(shifted, gt, p)[0][0].parts_correct for p in ("voxelpose", "jcsat", "4dassoc")] == [2, 1, 1]
    assert score(shifted, gt, "voxelpose")[0][0].group_pcp["head"] == 100.0
    # A wrong joint 14 (1 m off): VoxelPose starts the torso at the predicted hips, the others at joint 14.
    bad_pelvis = at(0.0)
    bad_pelvis[14] += [0.0, 0.0, 1.0]
    counts = {p: score(predictions((0, bad_pelvis)), gt, p)[0][0] for p in EVALUATION_PROTOCOLS}
    assert {p: a.parts_correct for p, a in counts.items()} == {"voxelpose": 10, "jcsat": 9, "4dassoc": 9}
    assert counts["jcsat"].group_pcp["torso"] == 0.0
    # The right ankle predicted at exactly (0, 0, 0), 0.1 m from the GT ankle: near enough for the
    # distance rule, but JCSAT treats it as missing (part wrong, joint not detected).
    zero_ankle = at(0.0)
    zero_ankle[0] = 0.0
    ankle = {p: score(predictions((0, zero_ankle)), gt, p)[0][0] for p in EVALUATION_PROTOCOLS}
    assert {p: a.parts_correct for p, a in ankle.items()} == {"voxelpose": 10, "jcsat": 9, "4dassoc": 10}
    # Precision and recall per joint, then averaged: the undetected ankle has both 0 (JCSAT).
    assert ankle["jcsat"].precision == ankle["jcsat"].recall == pytest.approx(100.0 * 14 / 15)


def test_averages_and_table():
    gt = ground_truth({0: 0.0, 1: 2.0, 2: 4.0})
    preds = predictions((0, at(0.0)), (0, at(2.6)), (0, at(4.0)))  # actor 1's prediction 0.6 m off
    scores = [evaluate_shelf(preds, gt, p, averaged_actors=(0, 1)) for p in EVALUATION_PROTOCOLS]
    assert [s.average["pcp"] for s in scores] == [50.0, 50.0, 50.0]
    table = format_shelf_scores(scores)
    for protocol in EVALUATION_PROTOCOLS:
        assert f"protocol: {protocol}" in table
    assert "avg A1,2" in table and "0/10" in table
    misses_rows = [line.split() for line in table.splitlines() if line.startswith("misses")]
    assert misses_rows == [["misses", "0", "0", "0"], ["misses", "0", "1", "0"], ["misses", "0", "0", "0"]]
    json.dumps([s.to_dict() for s in scores], allow_nan=False)  # NaN-free: undefined values are null


def test_bad_arguments_raise():
    gt = ground_truth({0: 0.0})
    with pytest.raises((ValueError, TypeError), match="mvpose"):  # TypeError: the runtime Literal check
        evaluate_shelf(predictions((0, at(0.0))), gt, "mvpose")
    with pytest.raises((ValueError, TypeError), match="hungarian"):
        match_predictions(at(0.0)[None], at(0.0)[None], "hungarian")
    with pytest.raises(ValueError, match=r"frames \[7\] outside"):
        evaluate_shelf(predictions((7, at(0.0))), gt, "jcsat")
    with pytest.raises(ValueError, match=r"averaged actors \[2\]"):
        evaluate_shelf(predictions((0, at(0.0))), gt, "jcsat", averaged_actors=(0, 2))
    with pytest.raises(ValueError, match=r"\(n, 15, 3\)"):
        PosePredictions.create([0], [0], np.zeros((1, 14, 3)))
    with pytest.raises(ValueError, match="NaN"):
        PosePredictions.create([0], [0], np.full((1, 15, 3), np.nan))
    with pytest.raises(ValueError, match="integers"):
        PosePredictions.create([0.5], [0], np.zeros((1, 15, 3)))


# --- the prediction file format ------------------------------------------------------------------


def test_round_trip_is_exact(tmp_path):
    rng = np.random.default_rng(0)
    original = PosePredictions.create([300, 300, 302], [4, 1, 4], rng.normal(size=(3, 15, 3)), [0.9, 0.5, 1.0])
    write_predictions(tmp_path / "p.jsonl", original)
    back = read_predictions(tmp_path / "p.jsonl")
    for a, b in zip(original, back):
        np.testing.assert_array_equal(a, b)
    unscored = original._replace(score=None)
    write_predictions(tmp_path / "q.jsonl", unscored)
    assert read_predictions(tmp_path / "q.jsonl").score is None
    empty = PosePredictions.create(np.zeros(0, int), np.zeros(0, int), np.zeros((0, 15, 3)))
    write_predictions(tmp_path / "e.jsonl", empty)
    assert read_predictions(tmp_path / "e.jsonl").num_predictions == 0


def test_null_joint_reads_as_zero_and_blank_lines_are_skipped(tmp_path):
    joints = [[0.1, 0.2, 0.3]] * 14 + [None]
    path = tmp_path / "p.jsonl"
    path.write_text(json.dumps(PREDICTIONS_HEADER) + "\n\n" + json.dumps({"frame": 300, "person": 0, "joints": joints}))
    read = read_predictions(path)
    assert read.joints.shape == (1, 15, 3) and np.all(read.joints[0, 14] == 0) and read.joints[0, 0, 2] == 0.3


ROW = {"frame": 300, "person": 0, "joints": [[0.0, 0.0, 1.0]] * 15}


@pytest.mark.parametrize(
    ("lines", "line", "match"),
    [
        ([], 1, "empty file"),
        ([{**PREDICTIONS_HEADER, "unit": "mm"}], 1, "header"),
        ([ROW], 1, "header"),
        ([PREDICTIONS_HEADER, ROW, "{not json"], 3, "invalid JSON"),
        ([PREDICTIONS_HEADER, [1, 2]], 2, "JSON object"),
        ([PREDICTIONS_HEADER, {**ROW, "joints": ROW["joints"][:14]}], 2, "15"),
        ([PREDICTIONS_HEADER, {**ROW, "joints": [[0, 0]] + ROW["joints"][1:]}], 2, "joint 0 \\(r_ankle\\)"),
        ([PREDICTIONS_HEADER, ROW, '{"frame": 300, "person": 1, "joints": [[NaN, 0, 0]' + ", [0, 0, 0]" * 14 + "]}"],
         3, "finite"),
        ([PREDICTIONS_HEADER, {**ROW, "frame": 300.0}], 2, "'frame' must be an integer"),
        ([PREDICTIONS_HEADER, {**ROW, "person": True}], 2, "'person' must be an integer"),
        ([PREDICTIONS_HEADER, {**ROW, "frame": -1}], 2, "non-negative"),
        ([PREDICTIONS_HEADER, {**ROW, "score": 0.5}, ROW], 3, "every row or none"),
        ([PREDICTIONS_HEADER, {**ROW, "score": "high"}], 2, "'score'"),
        ([PREDICTIONS_HEADER, {**ROW, "joint": 1}], 2, "unknown fields"),
    ],
)
def test_malformed_files_name_file_and_line(tmp_path, lines, line, match):
    path = tmp_path / "bad.jsonl"
    path.write_text("\n".join(x if isinstance(x, str) else json.dumps(x) for x in lines))
    with pytest.raises(ValueError, match=f"bad.jsonl, line {line}: .*{match}"):
        read_predictions(path)


def test_skel19_conversion_uses_the_4da_head_rule(tmp_path):
    rng = np.random.default_rng(1)
    people = [rng.normal(size=(19, 3)) + [0, 0, 1.0] for _ in range(3)]
    blocks = ["19 2", "2"]
    for pid, person in zip([5, 2], people[:2]):
        blocks += [str(pid), *(" ".join(repr(float(v)) for v in row) for row in np.vstack([person.T, np.ones(19)]))]
    blocks += ["1", "7", *(" ".join(repr(float(v)) for v in row) for row in np.vstack([people[2].T, np.ones(19)]))]
    (tmp_path / "skel.txt").write_text("\n".join(blocks) + "\n")
    converted = predictions_from_4dassoc(tmp_path / "skel.txt", first_frame=10)
    assert converted.frame.tolist() == [10, 10, 11] and converted.person.tolist() == [5, 2, 7]
    assert_allclose(converted.joints, geometry.to_shelf15(np.stack(people), geometry.SKEL19, "4da"))


# --- the command line ----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def small_prediction_file(data_root, fourda_predictions, tmp_path_factory):
    """The 4DA output of frames 300..309 only."""
    keep = fourda_predictions.frame < 310
    path = tmp_path_factory.mktemp("pred") / "small.jsonl"
    write_predictions(path, PosePredictions(*(x[keep] if x is not None else None for x in fourda_predictions)))
    return path


def test_cli_json(data_root, small_prediction_file, capsys):
    with pytest.warns(UserWarning, match="predictions cover 10 of the 279 evaluated frames"):
        shelf_eval.main(shelf_eval.Config(pred=small_prediction_file, data_root=data_root, protocol="jcsat", json=True))
    out = json.loads(capsys.readouterr().out)
    assert [s["protocol"] for s in out["scores"]] == ["jcsat"]
    actors = {a["actor"]: a for a in out["scores"][0]["actors"]}
    # Frames 310..600 have no prediction: JCSAT scores their annotated actors 0 (misses).
    assert actors[0]["matched"] == 10 and actors[0]["annotated"] == 279 and actors[0]["misses"] == 269


def test_cli_table_all_protocols(data_root, small_prediction_file, capsys):
    with pytest.warns(UserWarning, match="predictions cover 10 of the 279 evaluated frames"):
        shelf_eval.main(shelf_eval.Config(pred=small_prediction_file, data_root=data_root))
    out = capsys.readouterr().out
    assert all(f"protocol: {p}" in out for p in EVALUATION_PROTOCOLS)


def test_cli_reports_a_bad_file(data_root, tmp_path, capsys):
    path = tmp_path / "bad.jsonl"
    path.write_text(json.dumps(PREDICTIONS_HEADER) + "\n{oops\n")
    with pytest.raises(ValueError, match="bad.jsonl, line 2"):
        shelf_eval.main(shelf_eval.Config(pred=path, data_root=data_root))


def test_cli_help_names_every_option(capsys):
    with pytest.raises(SystemExit) as exit_info:
        _cli.parse(shelf_eval.Config, ["--help"], prog="shelf_eval")
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    assert all(option in out for option in ("--pred", "--data-root", "--protocol", "--ground-truth", "--json"))


# --- bad input ("Trustworthy runs"): a score that would mislead is warned about ----------------------


def test_predictions_in_millimetres_are_reported():
    gt = ground_truth(*({0: 0.0, 1: 2.0} for _ in range(10)))
    metres = predictions(*((f, at(x)) for f in range(10) for x in (0.0, 2.0)))
    assert prediction_problems(metres, gt) == ()
    millimetres = metres._replace(joints=1000.0 * metres.joints)
    message = r"predicted bones are 1000x the ground truth's .* the joints look like millimetres"
    assert len(prediction_problems(millimetres, gt)) == 1
    assert re.search(message, prediction_problems(millimetres, gt)[0])
    with pytest.warns(UserWarning, match=message):
        result = evaluate_shelf(millimetres, gt, "voxelpose", averaged_actors=(0, 1))
    assert result.average["pcp"] == 0.0 and re.search(message, result.problems[0])
    assert result.to_dict()["problems"] == list(result.problems)
    # Unreconstructed (0, 0, 0) joints do not enter the bone lengths: a person 5 m from the origin with only the
    # right leg reconstructed has two 0.45 m bones, not a dozen 5 m ones to the origin.
    leg_only = predictions(*((f, at(5.0)) for f in range(10)))
    leg_only.joints[:, 3:] = 0.0
    assert prediction_problems(leg_only, gt) == ()


def test_predictions_covering_few_frames_are_reported():
    gt = ground_truth(*({0: 0.0} for _ in range(20)), {})  # the last frame has no annotated person
    full = predictions(*((f, at(0.0)) for f in range(20)))
    assert prediction_problems(full, gt) == ()
    assert prediction_problems(predictions(*((f, at(0.0)) for f in range(18))), gt) == ()  # 90% is enough
    short = predictions(*((f, at(0.0)) for f in range(4)))
    message = r"predictions cover 4 of the 20 evaluated frames \(20.0%\)"
    with pytest.warns(UserWarning, match=message):
        result = evaluate_shelf(short, gt, "jcsat", averaged_actors=(0,))
    assert result.average["pcp"] == 20.0 and len(result.problems) == 1

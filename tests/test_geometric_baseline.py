"""The geometric baseline and the Shelf experiment on small synthetic scenes (on real Shelf, both are pinned
by tests/test_headline_results.py)."""

import dataclasses
import inspect
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import association
import geometry
import mocap
from experiments import jcsat_study

FRAMES = 8
CONFIG = association.BaselineConfig(max_candidates=6)  # one padding for every scene here: one compilation


def _scores(result, body25_gt, people):
    gt15 = np.asarray(geometry.to_shelf15(body25_gt, geometry.BODY25))  # same head rule as the predictions
    truth = mocap.EvaluationGroundTruth(np.arange(FRAMES), np.swapaxes(gt15, 0, 1), np.ones((people, FRAMES), bool))
    return mocap.evaluate_shelf(result.predictions, truth, "voxelpose", tuple(range(people)))


def test_perfect_detector_recovers_ground_truth():
    scene = mocap.synthesise_scene(jax.random.key(0), mocap.shelf_cameras(), num_people=2, num_frames=FRAMES,
                                   detector=mocap.PERFECT_DETECTOR)
    result = association.run_geometric_baseline(scene.rig, scene.detections, np.arange(FRAMES), CONFIG)
    score = _scores(result, scene.body25, 2)
    # Not exactly 100: a joint seen by two views only has one true candidate, and a cross-person
    # candidate passing the ray filter can tie with it (one part of 160 here).
    assert score.average["pcp"] >= 99.0
    # Exact reconstruction is checked without the temporal median filter, which smooths correct joints too,
    # and without the structural refinement, whose bone lengths are left/right symmetric (this mocap
    # skeleton's upper arms differ by 1.5 cm).
    unfiltered = dataclasses.replace(CONFIG, outlier_half_window=0)
    exact = dataclasses.replace(unfiltered, geometric=dataclasses.replace(CONFIG.geometric, structural_steps=0))
    for config, median_error, within_1cm in ((exact, 1e-6, 0.9), (unfiltered, 3e-3, 0.85)):
        result = association.run_geometric_baseline(scene.rig, scene.detections, np.arange(FRAMES), config)
        errors = np.linalg.norm(result.body25[:, :, None] - scene.body25[None], axis=-1)  # (T, F, people, 25)
        nearest = errors.mean(-1).argmin(-1)
        own = np.take_along_axis(errors, nearest[..., None, None], axis=2)[:, :, 0][result.present]
        assert np.median(own) < median_error and np.mean(own < 0.01) > within_1cm


def test_realistic_detector_sensible():
    scene = mocap.synthesise_scene(jax.random.key(0), mocap.shelf_cameras(), num_people=2, num_frames=FRAMES)
    result = association.run_geometric_baseline(scene.rig, scene.detections, np.arange(FRAMES), CONFIG)
    score = _scores(result, scene.body25, 2)
    assert score.average["pcp"] > 70.0


def test_consensus_rejects_outlier_candidate():
    rig = mocap.shelf_cameras()
    truth = np.array([0.3, 0.2, 1.1])
    pixels = np.stack([np.asarray(geometry.project(rig.select(v), truth)) for v in range(5)])[:, None]  # (V, 1, 2)
    pairs = association.view_pairs(5)
    points = np.tile(truth, (10, 1))
    points[0] = truth + [0.5, 0.0, 0.0]  # a spurious candidate (its pair's detections are the true ones here)
    args = (points, np.ones(10), pairs, np.zeros((10, 2), np.int32), pixels, np.ones((5, 1)))
    joint = association.consensus_joint(*map(jnp.asarray, args), geometry.projection_matrix(rig), 0.1)
    assert bool(joint.supported) and int(joint.num_views) == 5
    np.testing.assert_allclose(joint.point, truth, atol=1e-6)
    # The detections it was triangulated from are reported, for the structural refinement.
    np.testing.assert_array_equal(joint.weight, np.ones(5))
    np.testing.assert_allclose(joint.pixels, pixels[:, 0])


def test_fill_missing_uses_nearest_frame():
    joints = np.arange(4 * 2 * 3, dtype=float).reshape(4, 2, 3)
    valid = np.array([[True, False], [False, False], [False, False], [True, True]])
    filled, ok = association.fill_missing(joints, valid, np.array([True, True, True, True]))
    np.testing.assert_array_equal(filled[1, 0], joints[0, 0])
    np.testing.assert_array_equal(filled[2, 0], joints[3, 0])
    np.testing.assert_array_equal(filled[0, 1], joints[3, 1])
    assert ok.all()


def test_filled_centres_take_the_nearest_present_frame():
    present = np.array([[False, True, False, True, False, False], [False] * 6])
    centre = np.zeros((2, 6, 3))
    centre[0, 1], centre[0, 3] = 1.0, 3.0
    filled = association.filled_centres(present, centre)
    np.testing.assert_array_equal(filled[0, :, 0], [1.0, 1.0, 1.0, 3.0, 3.0, 3.0])  # frame 2: a tie, the earlier
    np.testing.assert_array_equal(filled[1], 0.0)


def test_temporal_outlier_rejection():
    rng = np.random.default_rng(0)
    frames = np.arange(20)
    joints = np.stack([0.01 * frames, np.zeros(20), np.ones(20)], axis=-1)[:, None, :] + rng.normal(0, 0.002, (20, 1, 3))
    valid = np.ones((20, 1), bool)
    valid[15:18] = False  # frame 18 has only 3 valid frames within +-3: not enough to be judged
    corrupted = joints.copy()
    corrupted[5, 0] += [0.5, 0.0, 0.0]  # another person's hand won the medoid in one frame
    corrupted[18, 0] += [0.5, 0.0, 0.0]
    corrupted[16, 0] = 99.0  # invalid frames are neither used nor changed
    out = association.reject_temporal_outliers(corrupted, valid, half_window=3, max_deviation=0.15)
    assert np.linalg.norm(out[5, 0] - joints[5, 0]) < 0.02
    np.testing.assert_array_equal(out[18], corrupted[18])
    np.testing.assert_array_equal(out[16], corrupted[16])
    untouched = np.setdiff1d(frames, [5])
    np.testing.assert_array_equal(out[untouched], corrupted[untouched])
    np.testing.assert_array_equal(association.reject_temporal_outliers(corrupted, valid, 0, 0.15), corrupted)
    median = association.reject_temporal_outliers(joints, valid, 1, 0.0)  # distance 0: a plain median filter
    np.testing.assert_allclose(median[1], np.median(joints[0:3], axis=0))
    fast = 0.3 * frames[:, None, None] * np.ones((1, 1, 3))  # steady motion, 0.52 m per frame: never an outlier
    np.testing.assert_array_equal(association.reject_temporal_outliers(fast, valid | True, 3, 0.15), fast)
    with pytest.raises(ValueError, match="half_window"):
        association.reject_temporal_outliers(joints, valid, -1, 0.1)


def test_experiment_end_to_end(tmp_path):
    config = jcsat_study.ShelfExperimentConfig(method="geometric", synthetic_people=2, synthetic_frames=FRAMES, baseline=CONFIG)
    events = []
    result = jcsat_study.run_shelf_experiment(config, tmp_path, log=events.append)
    assert "SYNTHETIC" in result.table and "geometric" in result.table
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["synthetic"] and set(metrics["scores"]["geometric"]) == set(mocap.EVALUATION_PROTOCOLS)
    assert mocap.read_predictions(tmp_path / "predictions.jsonl").num_predictions == result.baseline.predictions.num_predictions
    assert json.loads((tmp_path / "config.json").read_text())["baseline"]["joint_cloud"]["min_score"] == 0.2
    assert (tmp_path / "frame.png").stat().st_size > 10_000
    assert [e["stage"] for e in events][-1] == "done"
    with pytest.raises(ValueError, match="method"):
        jcsat_study.ShelfExperimentConfig(method="voxelpose")


def test_reprojection_check_adds_views_and_rejects_far_detections():
    rig = mocap.shelf_cameras()
    truth = np.array([0.3, 0.2, 1.1])
    projections = geometry.projection_matrix(rig)
    exact = np.stack([np.asarray(geometry.project(rig.select(v), truth)) for v in range(5)])
    # Views 0-3: the true detection (index 0) and a far one (index 1); view 4: only a far one.
    pixels = np.stack([exact, exact + 80.0], axis=1)
    pixels[4, 0] = exact[4] + 200.0
    score = np.ones((5, 2))
    # One candidate from views (0, 1) only: without the check two views are re-triangulated.
    args = (np.array([truth]), np.ones(1), np.array([[0, 1]]), np.zeros((1, 2), np.int32), pixels, score)
    args = tuple(map(jnp.asarray, args)) + (projections, 0.1)
    joint = association.consensus_joint(*args)
    assert int(joint.num_views) == 2 and np.asarray(joint.weight).tolist() == [1, 1, 0, 0, 0]
    joint = association.consensus_joint(*args, inlier_pixels=20.0)
    assert int(joint.num_views) == 4  # views 0-3 hold an inlier; view 4's only detection is 200 px off
    np.testing.assert_allclose(joint.point, truth, atol=1e-6)
    assert np.asarray(joint.weight).tolist() == [1, 1, 1, 1, 0]
    np.testing.assert_allclose(joint.pixels[:4], exact[:4])
    score[:, 0] = 0.1  # below min_score: never an inlier
    joint = association.consensus_joint(*args[:5], jnp.asarray(score), projections, 0.1, inlier_pixels=20.0)
    assert int(joint.num_views) == 2


def test_short_tracks_dropped_and_gaps_bridged():
    scene = mocap.synthesise_scene(jax.random.key(0), mocap.shelf_cameras(), num_people=2, num_frames=FRAMES,
                                   detector=mocap.PERFECT_DETECTOR)
    # Person 1 vanishes from every view in frames 3-4: its track has a two-frame gap.
    detections = [[d if f not in (3, 4) else mocap.Detections(
        tuple(c[ids != 1] for c, ids in zip(d.joints, d.person_ids)),
        tuple(p[np.ix_(ia != 1, ib != 1)] for p, (ia, ib) in zip(
            d.pafs, [(d.person_ids[a], d.person_ids[b]) for a, b in mocap.BODY25_PAF_PAIRS])),
        tuple(ids[ids != 1] for ids in d.person_ids)) for d in views] for f, views in enumerate(scene.detections)]
    bridged = association.run_geometric_baseline(scene.rig, detections, np.arange(FRAMES),
                                           dataclasses.replace(CONFIG, max_gap_frames=2, min_track_frames=1))
    strict = association.run_geometric_baseline(scene.rig, detections, np.arange(FRAMES),
                                          dataclasses.replace(CONFIG, max_gap_frames=1, min_track_frames=1))
    assert bridged.predictions.num_predictions == 2 * FRAMES
    assert strict.predictions.num_predictions == 2 * FRAMES - 2
    pruned = association.run_geometric_baseline(scene.rig, detections, np.arange(FRAMES),
                                          dataclasses.replace(CONFIG, max_gap_frames=0, min_track_frames=FRAMES))
    # Only the never-interrupted person is output.
    assert pruned.predictions.num_predictions == FRAMES and len(np.unique(pruned.predictions.person)) == 1


def test_predictions_ranked_by_support_and_duplicates_suppressed():
    """Rows are scored by the Joint Cloud candidates of their track's cluster and ranked by it within each
    frame; a suppression distance larger than the scene keeps only each frame's best-supported person."""
    scene = mocap.synthesise_scene(jax.random.key(0), mocap.shelf_cameras(), num_people=2, num_frames=FRAMES)
    ranked = association.run_geometric_baseline(scene.rig, scene.detections, np.arange(FRAMES),
                                          dataclasses.replace(CONFIG, duplicate_distance=0.0))
    rows = ranked.predictions
    support = np.asarray(ranked.person_cloud.mask).sum(axis=(2, 3, 4))
    np.testing.assert_array_equal(rows.score, support[rows.person, rows.frame])
    assert np.all(np.diff(rows.frame) >= 0)
    for frame in range(FRAMES):
        assert np.all(np.diff(rows.score[rows.frame == frame]) <= 0)
    assert len(np.unique(rows.frame)) == FRAMES and rows.num_predictions > FRAMES
    single = association.run_geometric_baseline(scene.rig, scene.detections, np.arange(FRAMES),
                                          dataclasses.replace(CONFIG, duplicate_distance=100.0)).predictions
    assert single.frame.tolist() == list(range(FRAMES))
    first = [int(np.flatnonzero(rows.frame == frame)[0]) for frame in range(FRAMES)]
    np.testing.assert_array_equal(single.person, rows.person[first])


@pytest.mark.parametrize("field, bad", [("outlier_half_window", -1), ("outlier_distance", -0.1),
                                        ("outlier_distance", float("nan"))])
def test_bad_outlier_filter_is_named_before_anything_runs(field, bad):
    with pytest.raises(ValueError, match=field):
        association.BaselineConfig(**{field: bad})


@pytest.mark.parametrize("bad", [-0.1, float("nan"), float("inf")])
def test_bad_duplicate_distance_is_named_before_anything_runs(bad):
    with pytest.raises(ValueError, match="duplicate_distance"):
        association.BaselineConfig(duplicate_distance=bad)


def test_track_bone_lengths_median_of_triangulated_frames_and_mirror_average():
    skeleton = geometry.SKEL19
    frames = 9
    rest = np.zeros((skeleton.num_joints, 3))
    for j in skeleton.topological_order[1:]:  # every bone 0.1 m along x, except the right forearm
        rest[j] = rest[skeleton.parents[j]] + [0.1, 0.0, 0.0]
    r_wrist, r_elbow, l_wrist = (skeleton.index(n) for n in ("r_wrist", "r_elbow", "l_wrist"))
    rest[r_wrist] = rest[r_elbow] + [0.3, 0.0, 0.0]
    joints = np.repeat(rest[None], frames, axis=0)
    joints[4, r_wrist] += [5.0, 0.0, 0.0]  # one wild frame: the median ignores it
    views = np.full((frames, skeleton.num_joints), 3)
    views[:, l_wrist] = 0  # the left forearm is never triangulated: its mirror's length is used
    views[7, r_wrist] = 1
    joints[7, r_wrist] += [9.0, 0.0, 0.0]  # fewer than two views: not counted at all
    lengths = association.track_bone_lengths(joints, views, skeleton)
    bone_of = {c: k for k, (_, c) in enumerate(skeleton.bones)}
    np.testing.assert_allclose(lengths[bone_of[r_wrist]], 0.3)
    np.testing.assert_allclose(lengths[bone_of[l_wrist]], 0.3)
    others = [k for k in range(len(lengths)) if k not in (bone_of[r_wrist], bone_of[l_wrist])]
    np.testing.assert_allclose(lengths[others], 0.1)
    views[:, r_wrist] = 0
    assert np.isnan(association.track_bone_lengths(joints, views, skeleton)[bone_of[r_wrist]])


def _noisy_track(seed, frames=12):
    """One person of a synthetic scene seen by the Shelf cameras, its detections with pixel noise, and
    their DLT triangulation (the raw baseline joints)."""
    rig = mocap.shelf_cameras()
    scene = mocap.synthesise_scene(jax.random.key(seed), rig, num_people=1, num_frames=frames,
                                   detector=mocap.PERFECT_DETECTOR)
    truth = np.asarray(scene.body25[:, 0])  # (F, 25, 3)
    views = rig.num_views
    exact = np.stack([np.asarray(geometry.project(rig.select(v), truth)) for v in range(views)], axis=2)  # (F,25,V,2)
    pixels = exact + np.random.default_rng(seed).normal(0.0, 4.0, exact.shape)
    weight = np.ones(pixels.shape[:3])
    projections = np.asarray(geometry.projection_matrix(rig))
    raw = np.asarray(geometry.triangulate(projections, np.moveaxis(pixels, 2, -2), weight).point)
    return projections, truth, raw, pixels, weight


def test_structural_refinement_meets_track_bone_lengths_and_reduces_error():
    projections, truth, raw, pixels, weight = _noisy_track(3)
    skeleton = geometry.SKEL19
    joints = [geometry.BODY25.index(name) for name in skeleton.joints]
    valid = np.ones(raw.shape[:2], bool)
    num_views = np.full(raw.shape[:2], projections.shape[0])
    refined, done = association.structural_refinement(projections, raw[None], valid[None], num_views[None],
                                                pixels[None], weight[None], steps=9, prior_weight=0.01)
    assert done.all()
    target = association.track_bone_lengths(raw[:, joints], num_views[:, joints], skeleton)
    parent, child = np.asarray(skeleton.bones).T
    solved = refined[0][:, joints]
    np.testing.assert_allclose(np.linalg.norm(solved[:, child] - solved[:, parent], axis=-1),
                               np.broadcast_to(target, (raw.shape[0], len(target))), rtol=0.02)
    error = lambda pose: np.linalg.norm(pose[:, joints] - truth[:, joints], axis=-1).mean()  # noqa: E731
    assert error(refined[0]) < error(raw)
    others = [j for j in range(geometry.BODY25.num_joints) if j not in joints]
    np.testing.assert_array_equal(refined[0][:, others], raw[:, others])


def test_structural_refinement_keeps_unseen_joints_and_tracks_without_lengths():
    projections, _, raw, pixels, weight = _noisy_track(4)
    frames = raw.shape[0]
    wrist = geometry.BODY25.index("l_wrist")
    valid = np.ones(raw.shape[:2], bool)
    num_views = np.full(raw.shape[:2], projections.shape[0])
    valid[5, wrist] = False  # no candidate: left as is (the pipeline fills it from its neighbours later)
    weight = weight.copy()
    weight[6, wrist, 1:] = 0.0  # one detection: the projected estimate anchors the joint
    num_views[6, wrist] = 0
    body = np.stack([raw, raw])
    no_lengths = num_views.copy()
    no_lengths[:, geometry.BODY25.index("l_ankle")] = 0  # never triangulated, nor its mirror:
    no_lengths[:, geometry.BODY25.index("r_ankle")] = 0  # the second track has no shin length
    refined, done = association.structural_refinement(
        projections, body, np.stack([valid, valid]), np.stack([num_views, no_lengths]),
        np.stack([pixels, pixels]), np.stack([weight, weight]), steps=3, prior_weight=0.01)
    assert done[0].all() and not done[1].any()
    np.testing.assert_array_equal(refined[1], body[1])
    np.testing.assert_array_equal(refined[0, 5, wrist], raw[5, wrist])
    assert np.all(np.isfinite(refined)) and np.linalg.norm(refined[0, 6, wrist] - raw[6, wrist]) < 0.1
    assert frames == refined.shape[1]
    unchecked = inspect.unwrap(association.structural_refinement)  # its own check, not the tests' jaxtyping hook
    with pytest.raises(ValueError, match="pixels must have shape"):
        unchecked(projections, body, np.stack([valid, valid]), np.stack([num_views, num_views]),
                  np.stack([pixels, pixels])[:, :, :, :2], np.stack([weight, weight]), 3, 0.01)


def test_bone_outliers_reject_the_wrong_joint_not_its_neighbours():
    skeleton = geometry.SKEL19
    rest = np.zeros((skeleton.num_joints, 3))
    for j in skeleton.topological_order[1:]:
        rest[j] = rest[skeleton.parents[j]] + [0.1, 0.0, 0.0]
    lengths = np.full(len(skeleton.bones), 0.1)
    r_wrist, r_elbow, nose = (skeleton.index(n) for n in ("r_wrist", "r_elbow", "nose"))
    joints = np.repeat(rest[None], 4, axis=0)
    joints[1, r_wrist] += [0.0, 0.3, 0.0]  # a leaf: its one bone deviates
    joints[2, r_elbow] += [0.0, 0.3, 0.0]  # both forearm bones deviate: the elbow, not the correct wrist
    joints[3, nose] += [0.0, 0.0, 0.3]  # its three bones deviate, each ear's one bone too: the nose only
    valid = np.ones(joints.shape[:2], bool)
    expected = np.zeros(joints.shape[:2], bool)
    expected[1, r_wrist] = expected[2, r_elbow] = expected[3, nose] = True
    np.testing.assert_array_equal(association.bone_outliers(joints, valid, lengths, skeleton, 0.5), expected)
    assert not association.bone_outliers(joints, valid, lengths, skeleton, 3.0).any()  # 0.32 m is within 4 x 0.1 m
    unknown = lengths.copy()
    unknown[[k for k, (_, c) in enumerate(skeleton.bones) if c == r_wrist]] = np.nan
    assert not association.bone_outliers(joints, valid, unknown, skeleton, 0.5)[1, r_wrist]
    valid[1, r_elbow] = False  # the wrist has no bone to a valid joint left: nothing to judge it by
    assert not association.bone_outliers(joints, valid, lengths, skeleton, 0.5)[1].any()


def test_structural_refinement_distrusts_bone_outliers():
    projections, truth, raw, pixels, weight = _noisy_track(5)
    wrist = geometry.BODY25.index("l_wrist")
    wrong = slice(4, 7)  # three frames (of 12) whose wrist detections belong to a point 0.8 m away in every view
    pixels = pixels.copy()
    away = geometry.project_to_views(mocap.shelf_cameras(), truth[wrong, wrist] + [0.8, 0.0, 0.0])  # (V, 3, 2)
    pixels[wrong, wrist] = np.swapaxes(np.asarray(away), 0, 1)
    raw = raw.copy()
    raw[:, wrist] = np.asarray(geometry.triangulate(projections, pixels[:, wrist], weight[:, wrist]).point)
    args = (projections, raw[None], np.ones((1,) + raw.shape[:2], bool), np.full((1,) + raw.shape[:2], 5),
            pixels[None], weight[None])
    trusting, _ = association.structural_refinement(*args, steps=9, prior_weight=0.01)
    distrusting, done = association.structural_refinement(*args, steps=9, prior_weight=0.01, max_bone_deviation=0.5)
    assert done.all()
    error = lambda pose: np.linalg.norm(pose[0, wrong, wrist] - truth[wrong, wrist], axis=-1)  # noqa: E731
    assert np.all(error(trusting) > 0.3) and np.all(error(distrusting) < 0.1)
    right = np.r_[0:4, 7:12]
    np.testing.assert_allclose(distrusting[0, right], trusting[0, right], atol=1e-9)


@pytest.mark.parametrize("field, bad", [("structural_steps", -1), ("structural_prior_weight", 0.0),
                                        ("structural_prior_weight", float("nan")), ("max_bone_deviation", -0.5),
                                        ("max_bone_deviation", float("inf"))])
def test_bad_structural_settings_are_named(field, bad):
    with pytest.raises(ValueError, match=field):
        association.GeometricConfig(**{field: bad})

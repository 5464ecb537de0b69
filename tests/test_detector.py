"""The 2D detector model: structure, exactness without noise, occlusion geometry, event rates."""

import dataclasses

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import geometry
import mocap
from geometry import BODY25
from mocap import BODY25_PAF_PAIRS, PERFECT_DETECTOR, DetectorConfig, detect, detect_with_events, view_geometry

# A standing person facing -y with the left side along +x (metres, z up): a local stand-in pose.
_POSE = {
    "nose": (0, -0.10, 1.62), "neck": (0, 0, 1.50), "r_shoulder": (-0.19, 0, 1.47), "r_elbow": (-0.22, 0, 1.19),
    "r_wrist": (-0.24, -0.02, 0.94), "l_shoulder": (0.19, 0, 1.47), "l_elbow": (0.22, 0, 1.19),
    "l_wrist": (0.24, -0.02, 0.94), "mid_hip": (0, 0, 0.95), "r_hip": (-0.10, 0, 0.95), "r_knee": (-0.11, -0.01, 0.52),
    "r_ankle": (-0.11, 0.02, 0.09), "l_hip": (0.10, 0, 0.95), "l_knee": (0.11, -0.01, 0.52),
    "l_ankle": (0.11, 0.02, 0.09), "r_eye": (-0.035, -0.09, 1.66), "l_eye": (0.035, -0.09, 1.66),
    "r_ear": (-0.075, 0.0, 1.64), "l_ear": (0.075, 0.0, 1.64), "l_big_toe": (0.12, -0.14, 0.02),
    "l_small_toe": (0.16, -0.12, 0.02), "l_heel": (0.11, 0.06, 0.03), "r_big_toe": (-0.12, -0.14, 0.02),
    "r_small_toe": (-0.16, -0.12, 0.02), "r_heel": (-0.11, 0.06, 0.03),
}
STANDING = np.array([_POSE[n] for n in BODY25.joints])
IMAGE = (1032.0, 776.0)


def make_rig(eyes) -> geometry.Camera:
    """Cameras at ``eyes`` (metres) looking at (0, 0, 1), f = 1000 px, Shelf-sized images."""
    K = np.array([[1000.0, 0.0, 515.5], [0.0, 1000.0, 387.5], [0.0, 0.0, 1.0]])
    Rs, ts = [], []
    for eye in np.asarray(eyes, float):
        R = np.asarray(geometry.look_at(eye, np.array([0.0, 0.0, 1.0])))
        Rs.append(R)
        ts.append(-R @ eye)
    n = len(Rs)
    return geometry.Camera.create(np.broadcast_to(K, (n, 3, 3)), np.stack(Rs), np.stack(ts), image_size=IMAGE)


RING = make_rig([(4.0 * np.cos(a), 4.0 * np.sin(a), 1.6) for a in np.linspace(0, 2 * np.pi, 5)[:-1]])


def person(x, y, heading=0.0):
    c, s = np.cos(heading), np.sin(heading)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return STANDING @ R.T + np.array([x, y, 0.0])


def crowd(num_frames, rng):
    """(frames, 4, 25, 3): four people drifting and turning near the centre."""
    t = np.linspace(0.0, 1.0, num_frames)
    starts = np.array([[-0.8, -0.6], [0.8, -0.5], [-0.5, 0.9], [0.7, 0.8]])
    headings = rng.uniform(0, 2 * np.pi, 4)
    return np.stack([
        np.stack([person(*(starts[p] + 0.3 * np.array([np.cos(3 * ti + p), np.sin(2 * ti)])), headings[p] + 4 * ti)
                  for p in range(4)])
        for ti in t
    ])


def test_structure_matches_detections():
    joints = crowd(6, np.random.default_rng(0))
    frames = detect(jax.random.key(0), RING, joints)
    assert len(frames) == 6 and all(len(f) == RING.num_views for f in frames)
    config = DetectorConfig()
    for frame in frames:
        for det, size in zip(frame, np.asarray(RING.image_size)):
            assert isinstance(det, mocap.Detections)
            assert det.num_joint_types == 25 and len(det.pafs) == len(BODY25_PAF_PAIRS) == 26
            for cand, ids in zip(det.joints, det.person_ids):
                assert cand.ndim == 2 and cand.shape[1] == 3 and ids.shape == (len(cand),)
                assert np.all((cand[:, :2] >= 0) & (cand[:, :2] <= size - 1))  # nothing outside the image
                assert np.all((cand[:, 2] >= config.score_threshold) & (cand[:, 2] <= 1))
                assert np.all((ids >= -1) & (ids < 4))
                # raster order, as OpenPose's peak search returns candidates
                raster = np.round(cand[:, 1]) * size[0] + cand[:, 0]
                assert np.all(np.diff(raster) >= 0)
            for paf, (a, b) in zip(det.pafs, BODY25_PAF_PAIRS):
                assert paf.shape == (len(det.joints[a]), len(det.joints[b]))
                assert np.all((paf >= 0) & (paf <= config.max_paf))
    padded = mocap.pad_detections(frames)
    assert padded.xy.shape[:3] == (6, RING.num_views, 25) and padded.person_ids is not None


def test_same_key_same_output_different_key_different():
    joints = crowd(5, np.random.default_rng(1))
    a = detect(jax.random.key(3), RING, joints)
    b = detect(jax.random.key(3), RING, joints)
    c = detect(jax.random.key(4), RING, joints)
    flat = lambda frames: np.concatenate([c.ravel() for f in frames for d in f for c in d.joints + d.pafs])  # noqa: E731
    assert np.array_equal(flat(a), flat(b))
    assert not np.array_equal(flat(a), flat(c)) or len(flat(a)) != len(flat(c))
    # raw uint32 keys work too and are deterministic
    assert np.array_equal(flat(detect(jnp.array([0, 3], jnp.uint32), RING, joints)),
                          flat(detect(jnp.array([0, 3], jnp.uint32), RING, joints)))


def test_perfect_detector_reproduces_opencv_projection():
    joints = crowd(4, np.random.default_rng(2))
    frames, events = detect_with_events(jax.random.key(0), RING, joints, PERFECT_DETECTOR)
    for v in range(RING.num_views):
        cam = RING.select(v)
        rvec, _ = cv2.Rodrigues(np.asarray(cam.R))
        for f, frame in enumerate(frames):
            expected, _ = cv2.projectPoints(joints[f].reshape(-1, 3), rvec, np.asarray(cam.t), np.asarray(cam.K),
                                            np.asarray(cam.dist))
            expected = expected.reshape(4, 25, 2)
            inside = np.all((expected >= 0) & (expected <= np.asarray(cam.image_size) - 1), axis=-1)
            det = frame[v]
            assert sum(len(c) for c in det.joints) == inside.sum()  # no spurious, none missing
            for j in range(25):
                ids = det.person_ids[j]
                assert sorted(ids) == sorted(np.flatnonzero(inside[:, j]))
                np.testing.assert_allclose(det.joints[j][:, :2], expected[ids, j], atol=1e-6)
            # every same-person PAF is the strongest of its row
            for paf, (a, b) in zip(det.pafs, BODY25_PAF_PAIRS):
                same = det.person_ids[a][:, None] == det.person_ids[b][None, :]
                assert np.all(paf[~same] == 0) and np.all(paf[same] > 0)
    assert not events.left_right_swapped.any() and not events.missed.any()


def test_person_behind_another_is_occluded_only_in_that_view():
    # Camera 0 on the -y axis looks at A; B stands 1 m behind A on the same line. Camera 1 is on the x axis.
    rig = make_rig([(0.0, -4.0, 1.2), (4.0, 0.0, 1.2)])
    one = np.stack([person(0.0, -1.0), person(0.0, 0.0)])
    joints = np.broadcast_to(one, (80, 2, 25, 3))
    geo = view_geometry(rig, joints)
    occluded_front = (geo.occlusion[0, 0, 1] > 0.5).mean()
    occluded_side = (geo.occlusion[0, 1, 1] > 0.5).mean()
    assert occluded_front > 0.6, occluded_front
    assert geo.occlusion[0, 0, 0].max() == 0.0  # the front person is not hidden by the back one
    # From the side both stand apart; only self-occlusion (far-side limbs) remains.
    assert occluded_side < 0.5 and geo.occlusion[0, 1, 1, BODY25.index("nose")] == 0.0
    config = DetectorConfig(person_miss_probability=0.0, occluded_person_miss_probability=0.0)
    _, events = detect_with_events(jax.random.key(0), rig, joints, config)
    reported = events.reported[:, :, 1].mean(axis=(0, 2))  # person B, per view
    assert reported[0] < 0.5 * reported[1], reported


def test_self_occlusion_of_far_side_in_profile():
    rig = make_rig([(4.0, 0.0, 1.2)])  # sees the person's left side (left along +x)
    geo = view_geometry(rig, person(0.0, 0.0)[None, None])
    occ = geo.occlusion[0, 0, 0]
    for near, far in [("l_shoulder", "r_shoulder"), ("l_ear", "r_ear"), ("l_knee", "r_knee")]:
        assert occ[BODY25.index(near)] < 0.5 < occ[BODY25.index(far)], (near, far)
    assert geo.sideness[0, 0, 0] > 0.95


def _within(count, probabilities, sigmas=4.0):
    expected = probabilities.sum()
    return abs(count - expected) <= sigmas * np.sqrt(max((probabilities * (1 - probabilities)).sum(), 1.0))


def test_event_rates_follow_configuration():
    joints = crowd(120, np.random.default_rng(4))
    config = DetectorConfig(left_right_swap_probability=0.05, side_view_swap_probability=0.3,
                            person_miss_probability=0.1)
    _, events = detect_with_events(jax.random.key(5), RING, joints, config)
    assert _within(events.left_right_swapped.sum(), events.swap_probability)
    assert _within(events.missed.sum(), events.miss_probability)
    assert _within(events.identity_swapped.sum(), events.identity_swap_probability)
    # side views swap more: the configured formula
    expected = 0.05 + 0.3 * events.geometry.sideness**2
    np.testing.assert_allclose(events.swap_probability[..., 0], np.minimum(expected, 1.0))
    assert events.swap_probability.min() >= 0.05 and events.missed.mean() >= 0.1 * 0.6
    # a missed person has no candidate in that view
    assert not events.reported[events.missed].any()


def test_left_right_swap_moves_labels_to_the_mirrored_joint():
    rig = make_rig([(0.0, -4.0, 1.2)])
    joints = np.broadcast_to(person(0.0, 0.0)[None, None], (40, 1, 25, 3))
    config = PERFECT_DETECTOR.__class__(**{**PERFECT_DETECTOR.__dict__, "left_right_swap_probability": 0.5})
    frames, events = detect_with_events(jax.random.key(1), rig, joints, config)
    truth = np.asarray(geometry.project(rig.select(0), joints[0, 0]))
    l_elbow, r_elbow = BODY25.index("l_elbow"), BODY25.index("r_elbow")
    for f, frame in enumerate(frames):
        got = frame[0].joints[l_elbow][0, :2]
        want = truth[r_elbow] if events.left_right_swapped[f, 0, 0, 0] else truth[l_elbow]
        np.testing.assert_allclose(got, want, atol=1e-9)
    assert 0 < events.left_right_swapped[:, 0, 0, 0].sum() < 40


def test_identity_swaps_link_nearby_people():
    rig = make_rig([(0.0, -4.0, 1.2)])
    # Two people side by side with overlapping arms in the image.
    joints = np.broadcast_to(np.stack([person(-0.22, 0.0), person(0.22, 0.3)]), (60, 2, 25, 3))
    config = DetectorConfig(identity_swap_probability=1.0, paf_clutter_probability=0.0, paf_miss_probability=0.0,
                            paf_noise=0.0)
    frames, events = detect_with_events(jax.random.key(2), rig, joints, config)
    assert events.identity_swapped.any()
    f, v, p, q, k = map(int, np.argwhere(events.identity_swapped)[0])
    a, b = BODY25_PAF_PAIRS[k]
    det = frames[f][v]
    i = np.flatnonzero(det.person_ids[a] == p)[0]
    m = np.flatnonzero(det.person_ids[b] == q)[0]
    assert det.pafs[k][i, m] > 0  # a link across people


def test_bad_input_raises():
    with pytest.raises(ValueError, match="shape"):
        detect(jax.random.key(0), RING, np.zeros((3, 2, 17, 3)))
    with pytest.raises(ValueError, match=r"at least one frame and one person, got shape \(3, 0, 25, 3\)"):
        detect(jax.random.key(0), RING, np.zeros((3, 0, 25, 3)))
    bad = crowd(2, np.random.default_rng(0))
    bad[0, 0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        detect(jax.random.key(0), RING, bad)
    with pytest.raises(ValueError, match="in \\[0, 1\\]"):
        DetectorConfig(joint_dropout=1.5)
    with pytest.raises(ValueError, match="stacked rig"):
        detect(jax.random.key(0), RING.select(0), crowd(2, np.random.default_rng(0)))


def test_occlusion_splits_into_self_and_others():
    rig = make_rig([(0.0, -4.0, 1.2), (4.0, 0.0, 1.2)])
    joints = np.broadcast_to(np.stack([person(0.0, -1.0), person(0.0, 0.0)]), (4, 2, 25, 3))
    geo = view_geometry(rig, joints)
    np.testing.assert_array_equal(geo.occlusion, np.maximum(geo.self_occlusion, geo.others_occlusion))
    # Alone, a person's occlusion is its self-occlusion; B behind A (view 0) is hidden by A, not by itself.
    alone = view_geometry(rig, joints[:, 1:])
    np.testing.assert_allclose(alone.occlusion, geo.self_occlusion[:, :, 1:], atol=1e-12)
    assert geo.others_occlusion[0, 0, 1].mean() > 0.6 and geo.others_occlusion[0, 1, 1].max() == 0.0
    # Facing the camera, the mid-hip between the thigh roots is not hidden by the person's own body.
    assert geo.self_occlusion[0, 0, 0, BODY25.index("mid_hip")] == 0.0
    # Self-occlusion rarely drops a body joint; occlusion by another person often does.
    config = DetectorConfig(person_miss_probability=0.0, occluded_person_miss_probability=0.0)
    many = np.broadcast_to(joints[:1], (200, 2, 25, 3))
    _, events = detect_with_events(jax.random.key(1), rig, many, config)
    hidden = geo.others_occlusion[0, 0, 1] > 0.9
    body = np.array([name not in ("nose", "r_eye", "l_eye", "r_ear", "l_ear") for name in BODY25.joints])
    by_others = events.reported[:, 0, 1][:, hidden & body].mean()
    self_hidden = (geo.self_occlusion[0, 1, 1] > 0.9) & body  # far-side limbs in profile
    assert self_hidden.sum() >= 3 and events.reported[:, 1, 1][:, self_hidden].mean() > by_others + 0.15


@pytest.mark.parametrize("correlation", [0.0, 0.9])
def test_pixel_noise_correlation_in_time(correlation):
    """A still person seen by one camera for 400 frames: the reported positions' errors have the configured lag-1
    correlation and keep their per-frame spread (``pixel_noise`` of the apparent height)."""
    rig = make_rig([(0.0, -4.0, 1.2)])
    joints = np.broadcast_to(person(0.0, 0.0)[None, None], (400, 1, 25, 3))
    config = dataclasses.replace(PERFECT_DETECTOR, pixel_noise=0.01, noise_correlation=correlation)
    frames, events = detect_with_events(jax.random.key(2), rig, joints, config)
    found = mocap.oracle_keypoints(mocap.pad_detections(frames), 1)[:, 0, 0]  # (frames, 25, 3)
    error = (found[..., :2] - events.geometry.pixels[:, 0, 0])[:, found[0, :, 2] > 0]  # (frames, joints, 2)
    lag1 = np.mean(error[1:] * error[:-1]) / np.mean(error**2)
    assert abs(lag1 - correlation) < 0.05
    spread = 0.01 * events.geometry.apparent_height[0, 0, 0]
    assert 0.8 * spread < np.sqrt(np.mean(error**2)) < 1.2 * spread


def test_noise_correlation_must_be_below_one():
    with pytest.raises(ValueError, match="noise_correlation"):
        DetectorConfig(noise_correlation=1.0)

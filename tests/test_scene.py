"""Synthetic scenes: determinism, placement without collisions, ground truth, realism vs real Shelf."""

import jax
import numpy as np
import pytest

import geometry
import mocap
from geometry import BODY25

RIG = mocap.shelf_cameras()
HIP = BODY25.index("mid_hip")


@pytest.fixture(scope="module")
def scene():
    return mocap.synthesise_scene(jax.random.key(7), RIG, num_people=4, num_frames=60)


def test_same_key_same_scene_different_key_different(scene):
    again = mocap.synthesise_scene(jax.random.key(7), RIG, num_people=4, num_frames=60)
    other = mocap.synthesise_scene(jax.random.key(8), RIG, num_people=4, num_frames=60)
    assert np.array_equal(scene.body25, again.body25) and scene.placement.names == again.placement.names
    for f in (0, 59):
        for a, b in zip(scene.detections[f], again.detections[f]):
            for x, y in zip(a.joints + a.pafs + a.person_ids, b.joints + b.pafs + b.person_ids):
                assert np.array_equal(x, y)
    assert not np.allclose(scene.body25, other.body25)


def test_shapes_and_ground_truth(scene):
    n_f, n_v, n_p = 60, RIG.num_views, 4
    assert scene.body25.shape == (n_f, n_p, 25, 3) and scene.structri17.shape == (n_f, n_p, 17, 3)
    assert scene.shelf15.shape == (n_f, n_p, 15, 3)
    assert scene.body25_pixels.shape == (n_f, n_v, n_p, 25, 2) and scene.visible.shape == (n_f, n_v, n_p, 25)
    assert scene.shelf15_pixels.shape == (n_f, n_v, n_p, 15, 2)
    assert len(scene.detections) == n_f and all(len(frame) == n_v for frame in scene.detections)
    assert len(scene.placement.names) == n_p and scene.fps == 30.0
    # people stand on the z = 0 floor, upright (heads above hips above ankles)
    z = scene.body25[..., 2]
    assert -0.1 < z.min() and np.all(z[..., BODY25.index("nose")] > z[..., HIP])
    assert np.median(z[..., BODY25.index("nose")]) > 1.3
    # the SHELF15 mid-hip is the centre of the STRUCTRI17 hips; BODY25 and STRUCTRI17 come from one motion
    np.testing.assert_allclose(scene.shelf15[..., 14, :], scene.structri17[..., [2, 3], :].mean(-2), atol=1e-12)
    np.testing.assert_allclose(scene.body25[..., HIP, :], scene.structri17[..., 0, :], atol=0.15)
    # projections agree with geometry.project for one view
    np.testing.assert_allclose(scene.body25_pixels[:, 2], np.asarray(geometry.project(RIG.select(2), scene.body25)),
                               atol=1e-6)


def test_no_collisions_and_inside_area(scene):
    roots = scene.body25[:, :, HIP, :2]
    groups = scene.placement.group_of_person
    distances = np.linalg.norm(roots[:, :, None] - roots[:, None], axis=-1)
    different = groups[:, None] != groups[None, :]
    assert distances[:, different].min() >= 0.7 - 1e-9
    assert np.isclose(distances[:, different].min(), scene.placement.min_root_distance)
    x0, y0, x1, y1 = mocap.capture_area(RIG)
    assert np.all((roots >= np.array([x0, y0]) - 1e-9) & (roots <= np.array([x1, y1]) + 1e-9))
    # the Shelf rig looks at the real Shelf actors' area (actorsGT x in [-0.9, 1.8], y in [-1.9, 1.3])
    assert -1.5 < x0 < 0.0 < 1.0 < x1 < 2.5 and -2.5 < y0 < -0.5 < 0.5 < y1 < 2.0


def test_crowding_fails_loudly():
    with pytest.raises(ValueError, match="could not place"):
        mocap.synthesise_scene(jax.random.key(0), RIG, num_people=4, num_frames=10, area=(0, 0, 0.5, 0.5),
                               max_attempts=2)


def test_person_ids_match_projected_truth(scene):
    errors, sizes = [], []
    for f in range(0, 60, 10):
        for v, det in enumerate(scene.detections[f]):
            for j, (cand, ids) in enumerate(zip(det.joints, det.person_ids)):
                for (x, y, _), p in zip(cand, ids):
                    if p >= 0 and not scene.events.left_right_swapped[f, v, p].any():
                        errors.append(np.hypot(*(np.array([x, y]) - scene.body25_pixels[f, v, p, j])))
                        sizes.append(scene.events.geometry.apparent_height[f, v, p])
    relative = np.array(errors) / np.array(sizes)
    assert np.median(relative) < 0.03  # pixel noise ~1.2% of the apparent height per axis
    assert np.median(errors) > 0.5  # but noise there is


def _statistics(frames):
    counts = np.array([[sum(len(c) for c in det.joints) for det in frame] for frame in frames])
    scores = np.concatenate([c[:, 2] for frame in frames for det in frame for c in det.joints])
    pafs = np.concatenate([p.ravel() for frame in frames for det in frame for p in det.pafs])
    return counts.mean(), np.median(scores), np.mean(pafs == 0)


def test_statistics_in_range_of_real_shelf(scene):
    count, median_score, zero_paf = _statistics(scene.detections)
    assert 40 <= count <= 80, count
    assert 0.65 <= median_score <= 0.85 and 0.55 <= zero_paf <= 0.85
    assert min(c[:, 2].min() for frame in scene.detections for det in frame for c in det.joints if len(c)) >= 0.15


@pytest.mark.data
def test_statistics_close_to_real_shelf_detections(data_root, scene):
    frames, _ = mocap.load_shelf_detections(data_root)
    real_count, real_score, real_zero = _statistics(frames)
    count, score, zero = _statistics(scene.detections)
    assert abs(count - real_count) < 0.35 * real_count, (count, real_count)
    assert abs(score - real_score) < 0.05, (score, real_score)
    assert abs(zero - real_zero) < 0.15, (zero, real_zero)


def test_preview_writes_png(tmp_path):
    from experiments.preview_scene import Config, main

    out = tmp_path / "frame.png"
    main(Config(out=out, source="synthetic", frame=1, num_frames=2, num_people=2))
    assert out.stat().st_size > 10_000
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_preview_shelf_without_data_is_a_clear_error(tmp_path):
    from experiments.preview_scene import Config

    with pytest.raises(ValueError, match="needs the real Shelf data"):
        Config(source="shelf", out=tmp_path / "x.png", data_root=tmp_path)

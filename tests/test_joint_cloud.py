"""Joint Cloud construction, K-Means, tracking and the model tensor."""


import jax
import jax.numpy as jnp
import numpy as np
import pytest

import association
import geometry
import mocap
from association.numpy_reference import numpy_joint_cloud_frame

NUM_JOINTS = 3  # a small frame: 3 joint types keep the NumPy loop reference fast


@pytest.fixture(scope="module")
def frame():
    """Two people, five Shelf views, three joint types, noisy pixels, one low score and one padded slot."""
    rig = mocap.shelf_cameras()
    rng = np.random.default_rng(0)
    people = np.array([[0.0, 0.0, 1.0], [1.2, 0.5, 1.0]])[:, None, :] + rng.normal(0, 0.3, (2, NUM_JOINTS, 3))
    pixels = np.stack([np.asarray(geometry.project(rig.select(v), people)) for v in range(5)])  # (V, 2, J, 2)
    pixels += rng.normal(0, 1.0, pixels.shape)
    xy = np.zeros((5, NUM_JOINTS, 3, 2))
    xy[:, :, :2] = np.swapaxes(pixels, 1, 2)
    score = np.zeros((5, NUM_JOINTS, 3))
    score[:, :, :2] = rng.uniform(0.3, 0.9, (5, NUM_JOINTS, 2))
    mask = np.zeros((5, NUM_JOINTS, 3), bool)
    mask[:, :, :2] = True
    score[1, 0, 0] = 0.1  # below the score filter
    mask[2, 1, 1] = False  # person 1's joint 1 not detected in view 2
    return rig, xy, score, mask, people


def test_matches_numpy_loop_reference(frame):
    rig, xy, score, mask, _ = frame
    cloud = association.build_joint_cloud(rig, xy[None], score[None], mask[None])
    reference = numpy_joint_cloud_frame(rig, xy, score, mask)
    valid = np.asarray(cloud.valid[0])
    assert valid.sum() == len(reference) > 10
    for item in reference:
        index = (0, item["pair"], item["joint"], item["a"], item["b"])
        assert valid[index[1:]]
        np.testing.assert_allclose(cloud.point[index], item["point"], atol=1e-5)  # cv2 rounds to ~1 um
        np.testing.assert_allclose(cloud.ray_distance[index], item["ray_distance"], atol=1e-9)
        np.testing.assert_allclose(cloud.reprojection_error[index], item["reprojection_error"], atol=1e-4)
        pair = association.view_pairs(5)[item["pair"]]
        np.testing.assert_allclose(cloud.score[index], [score[pair[0], item["joint"], item["a"]],
                                                        score[pair[1], item["joint"], item["b"]]])
    assert not np.asarray(cloud.point[0])[~valid].any()


def test_filters(frame):
    rig, xy, score, mask, people = frame
    cloud = association.build_joint_cloud(rig, xy[None], score[None], mask[None])
    pairs = association.view_pairs(5)
    valid = np.asarray(cloud.valid[0])
    assert not valid[pairs[:, 0] == 1, 0, 0].any() and not valid[pairs[:, 1] == 1, 0, :, 0].any()  # low score
    assert not valid[pairs[:, 0] == 2, 1, 1].any() and not valid[pairs[:, 1] == 2, 1, :, 1].any()  # padded
    same = valid[:, :, [0, 1], [0, 1]]  # same person in both views: pass unless filtered by score/mask
    cross = valid[:, :, [0, 1], [1, 0]]
    assert same.mean() > 0.8 and cross.mean() < 0.5 * same.mean()
    # Same-person candidates are close to the truth; the ray filter bounds the ones that pass.
    points = np.asarray(cloud.point[0])[:, np.arange(NUM_JOINTS)[:, None], [0, 1], [0, 1]]  # (P, J, 2, 3)
    error = np.linalg.norm(points - np.swapaxes(people, 0, 1)[None], axis=-1)[same]
    assert error.max() < 0.05
    assert (np.asarray(cloud.ray_distance[0])[valid] < 0.1).all()
    loose_config = association.JointCloudConfig(max_ray_distance=5.0)
    loose = association.build_joint_cloud(rig, xy[None], score[None], mask[None], loose_config)
    strict_config = association.JointCloudConfig(min_score=0.5)
    strict = association.build_joint_cloud(rig, xy[None], score[None], mask[None], strict_config)
    assert np.asarray(loose.valid).sum() > valid.sum() > np.asarray(strict.valid).sum()


def test_pruned_frames_equal_the_dense_frame_kernel(frame):
    """build_joint_cloud triangulates only score-filtered entries, pair by pair; joint_cloud_frame
    computes the whole grid. Three frames: the fixture, one with other noise and scores, one empty."""
    rig, xy, score, mask, _ = frame
    rng = np.random.default_rng(7)
    xy_f = np.stack([xy, xy + rng.normal(0, 2.0, xy.shape), xy])
    score_f = np.stack([score, rng.uniform(0.0, 0.6, score.shape), score])
    mask_f = np.stack([mask, mask, np.zeros_like(mask)])
    cloud = association.build_joint_cloud(rig, xy_f, score_f, mask_f)
    dense = jax.vmap(association.joint_cloud_frame, in_axes=(None, 0, 0, 0))(
        rig, jnp.asarray(xy_f), jnp.asarray(score_f), jnp.asarray(mask_f))
    assert 10 < int(np.asarray(cloud.valid).sum()) and not np.asarray(cloud.valid[2]).any()
    for name, a, b in zip(association.JointCloud._fields, cloud, dense):
        assert a.shape == b.shape and a.dtype == b.dtype, name
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-12, atol=1e-12, err_msg=name)


def test_entry_buckets_bound_padding_and_compilations():
    from association._joint_cloud import _bucket

    counts = np.arange(1, 200_000, 37)
    buckets = np.array([_bucket(int(c)) for c in counts])
    assert (buckets >= counts).all() and (buckets < np.maximum(counts + 256, counts * 1.07)).all()
    assert len(set(buckets.tolist())) < 150  # a few lengths per power of two, not one per count


def test_jit_equals_eager(frame):
    rig, xy, score, mask, _ = frame
    args = (rig, jnp.asarray(xy), jnp.asarray(score), jnp.asarray(mask))
    eager = association.joint_cloud_frame(*args)
    jitted = jax.jit(association.joint_cloud_frame)(*args)
    for a, b in zip(eager, jitted):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), atol=1e-9)


def test_bad_input_raises(frame):
    rig, xy, score, mask, _ = frame
    with pytest.raises((ValueError, TypeError), match="xy"):  # jaxtyping's TypeCheckError is a TypeError
        association.build_joint_cloud(rig, xy, score, mask)
    bad = xy.copy()
    bad[0, 0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        association.build_joint_cloud(rig, bad[None], score[None], mask[None])
    with pytest.raises(ValueError, match="max_ray_distance"):
        association.JointCloudConfig(max_ray_distance=0.0)
    assert len(association.view_pairs(5)) == 10 and association.view_pairs(3).tolist() == [[0, 1], [0, 2], [1, 2]]


def _blobs(seed: int):
    rng = np.random.default_rng(seed)
    centres = np.array([[0.0, 0.0, 1.0], [2.0, 0.0, 1.0], [0.0, 2.0, 1.0]])
    points = np.concatenate([c + rng.normal(0, 0.05, (12, 3)) for c in centres] + [np.zeros((4, 3))])
    weight = np.r_[np.ones(36), np.zeros(4)]  # 4 padded rows at the origin
    return centres, points, weight


def test_kmeans_finds_separated_clusters_deterministically():
    centres, points, weight = _blobs(1)
    key = jax.random.key(3)
    result = association.kmeans(points, weight, 3, key, num_slots=5)
    again = association.kmeans(points, weight, 3, key, num_slots=5)
    np.testing.assert_array_equal(np.asarray(result.centres), np.asarray(again.centres))
    assert np.asarray(result.active).tolist() == [True, True, True, False, False]
    found = np.asarray(result.centres)[:3]
    distance = np.linalg.norm(found[:, None] - centres[None], axis=-1)
    assert sorted(distance.argmin(axis=1).tolist()) == [0, 1, 2] and distance.min(axis=1).max() < 0.05


def test_trimmed_kmeans_ignores_outlier():
    centres, points, weight = _blobs(2)
    points[-1], weight[-1] = [8.0, 8.0, 1.0], 1.0  # one far spurious candidate
    plain = association.kmeans(points, weight, 3, jax.random.key(0), num_slots=3)
    trimmed = association.kmeans(points, weight, 3, jax.random.key(0), num_slots=3, trim=0.3)
    worst = lambda r: np.linalg.norm(np.asarray(r.centres)[:, None] - centres[None], axis=-1).min(axis=0).max()  # noqa: E731
    assert worst(trimmed) < 0.05 < worst(plain)


def test_tracking_survives_swapped_detection_order():
    rng = np.random.default_rng(0)
    paths = np.stack([np.array([0.0, 0.0, 1.0]) + np.cumsum(rng.normal(0, 0.02, (20, 3)), 0),
                      np.array([1.5, 0.0, 1.0]) + np.cumsum(rng.normal(0, 0.02, (20, 3)), 0)], axis=1)  # (F, 2, 3)
    swapped = paths.copy()
    swapped[10:] = paths[10:, ::-1]  # the detector lists the people in the other order from frame 10
    active = np.ones((20, 2), bool)
    slot_of_person0 = np.r_[np.zeros(10, int), np.ones(10, int)]
    track = association.track_centres(swapped, active, gate=0.5)
    assert set(track[np.arange(20), slot_of_person0]) == {0}
    assert set(track[np.arange(20), 1 - slot_of_person0]) == {1}
    np.testing.assert_array_equal(association.track_centres(paths, active, gate=0.5), np.tile([0, 1], (20, 1)))


def test_windows_and_people_count():
    windows = association.window_frames(12, 10)
    assert windows.shape == (12, 10) and windows[0].tolist() == [0] * 10 and windows[11].tolist() == list(range(2, 12))
    score = np.zeros((2, 3, 25, 4))
    mask = np.zeros((2, 3, 25, 4), bool)
    mask[:, :, 8, :3] = True
    score[:, :, 8, :3] = 0.5
    score[0, 0, 8, 2] = 0.1  # view 0 of frame 0 sees only two confident mid-hips
    for rule, expected in (("min", [2, 3]), ("median", [3, 3]), ("max", [3, 3])):
        assert association.people_count(score, mask, association.ClusterConfig(people_rule=rule)).tolist() == expected


def test_model_tensor_layout():
    scene = mocap.synthesise_scene(jax.random.key(1), mocap.shelf_cameras(), num_people=2, num_frames=4,
                                   detector=mocap.PERFECT_DETECTOR)
    people = association.track_people(scene.rig, mocap.pad_detections(scene.detections, 6), jax.random.key(0))
    assert set(people.seconds) == {"joint_cloud", "clustering", "tracking", "model_tensor"}
    tensor = people.person_cloud
    tracks = tensor.present.shape[0]
    assert tensor.points.shape == (tracks, 4, 10, 4, 25, 3) and tensor.mask.shape == (tracks, 4, 10, 4, 25)
    assert tracks >= 2 and tensor.present.sum() >= 8
    # Kept candidates of a person lie within the joint radius of its centre.
    t, f, p, m, j = np.nonzero(np.asarray(tensor.mask))
    distance = np.linalg.norm(np.asarray(tensor.points)[t, f, p, m, j] - tensor.centre[t, f], axis=-1)
    assert (distance < np.asarray(association.BODY25_JOINT_RADIUS)[j]).all()
    assert not np.asarray(tensor.points)[~np.asarray(tensor.mask)].any()

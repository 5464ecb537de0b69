"""FLEX input normalisation and training samples (flex/_normalise.py, flex/_data.py), and the FLEX20 skeleton data."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

import geometry
from geometry import FLEX20, FLEX20_ROTATING, STRUCTRI17
from flex import (
    DataConfig, fixed_rig, flex_forward_kinematics, local_rotations, make_batch, make_sample, normalise_2d, rig_centre,
    sign_continuous, symmetric_bone_lengths,
)

# The shapes of tests/test_flex_model.py's batch, so that a joint run compiles the geometry kernels once.
CONFIG = DataConfig(views=4, frames=16)
DYNAMIC = DataConfig(views=4, frames=16, camera_motion="dynamic")
CONFIG_SHAPE = (4, 16, 17, 2)
"""``points_2d`` of one CONFIG sample: views, frames, STRUCTRI17 joints, pixels."""


@pytest.fixture(scope="module")
def static_batch():
    return make_batch(jax.random.key(1), CONFIG, 2)


@pytest.fixture(scope="module")
def dynamic_batch():
    return make_batch(jax.random.key(2), DYNAMIC, 2)


def _camera_centres(batch) -> np.ndarray:
    return np.asarray(geometry.camera_centre(batch.cameras))  # (B, K, T, 3)


def test_sampling_is_deterministic_from_the_key(static_batch):
    again = make_batch(jax.random.key(1), CONFIG, 2)
    for a, b in zip(jax.tree.leaves(static_batch), jax.tree.leaves(again)):
        assert_array_equal(a, b)
    other = make_sample(jax.random.key(3), CONFIG)
    assert not np.array_equal(other.points_2d, static_batch.points_2d[0])
    assert_array_equal(make_sample(5, CONFIG).points_2d, make_sample(jax.random.key(5), CONFIG).points_2d)


def test_shapes_and_ranges(static_batch):
    b, k, t = 2, CONFIG.views, CONFIG.frames
    shapes = {name: np.shape(value) for name, value in static_batch._asdict().items() if name != "cameras"}
    assert shapes == {
        "points_2d": (b, k, t, 17, 2), "confidences": (b, k, t, 17), "joints": (b, k, t, 17, 3),
        "root_position": (b, k, t, 3), "bone_lengths": (b, 10), "contacts": (b, t, 2), "rotations": (b, t, 14, 4),
        "root_rotations": (b, k, t, 4),
    }
    assert np.all((static_batch.confidences >= 0) & (static_batch.confidences <= 1))
    assert 0.5 < np.mean(static_batch.confidences > 0) < 1.0  # the detector misses some joints, not most
    assert np.all(static_batch.points_2d[static_batch.confidences == 0] == 0)
    assert set(np.unique(static_batch.contacts)) <= {0.0, 1.0}
    assert_allclose(static_batch.joints[..., STRUCTRI17.index("mid_hip"), :], 0.0)
    assert np.all(static_batch.root_position[..., 2] > 0)
    assert np.all((static_batch.bone_lengths > 0.03) & (static_batch.bone_lengths < 0.6))
    assert_allclose(np.linalg.norm(static_batch.rotations, axis=-1), 1.0, atol=1e-12)


def test_root_target_is_the_detected_root_at_the_normalised_depth(static_batch):
    """The camera model of flex._model: the root target is ``(x d, y d, d)`` with ``(x, y)`` the root's normalised
    image position (near the detection) and ``d`` the metric depth times scale / focal length."""
    cameras = static_batch.cameras
    root = STRUCTRI17.index("mid_hip")
    normalised = normalise_2d(static_batch.points_2d, static_batch.confidences, root)
    scale = np.asarray(normalised.scale)[..., None]  # (B, K, 1)
    metric_depth = static_batch.root_position[..., 2] * cameras.K[..., 0, 0] / scale
    assert np.all((metric_depth > CONFIG.distance[0] - 1.0) & (metric_depth < CONFIG.distance[1] + 6.0))
    xy = static_batch.root_position[..., :2] / static_batch.root_position[..., 2:]
    pixels = np.asarray(normalised.centre)[:, :, None] + scale[..., None] * xy
    seen = static_batch.confidences[..., root] > 0
    error = np.linalg.norm(pixels - static_batch.points_2d[..., root, :], axis=-1)[seen]
    assert np.median(error) < 10.0  # pixels: detector noise on a person a few hundred pixels tall


def test_static_cameras_stay_and_dynamic_cameras_move(static_batch, dynamic_batch):
    static, dynamic = _camera_centres(static_batch), _camera_centres(dynamic_batch)
    assert_allclose(static, np.broadcast_to(static[:, :, :1], static.shape), atol=1e-12)
    rotations = static_batch.cameras.R
    assert_allclose(rotations, np.broadcast_to(rotations[:, :, :1], rotations.shape))
    assert np.all(np.linalg.norm(dynamic[:, :, -1] - dynamic[:, :, 0], axis=-1) > 1e-3)
    turned = geometry.geodesic_distance(dynamic_batch.cameras.R[:, :, 0], dynamic_batch.cameras.R[:, :, -1])
    assert np.all(np.asarray(turned) > 1e-4)


def test_ground_truth_rotations_reproduce_the_poses(static_batch, dynamic_batch):
    """FK of the real rotations and the symmetric bones gives the camera-frame ground truth up to the skeleton's
    left/right asymmetry (millimetres), for static and moving cameras."""
    for batch in (static_batch, dynamic_batch):
        poses = flex_forward_kinematics(batch.bone_lengths, batch.rotations, batch.root_rotations)
        error = np.linalg.norm(geometry.remap_joints(poses, FLEX20, STRUCTRI17) - batch.joints, axis=-1)
        assert error.mean() < 0.005 and error.max() < 0.02
        # Sign-continuous quaternions: no jump between frames.
        assert np.all(np.sum(batch.rotations[:, 1:] * batch.rotations[:, :-1], axis=-1) > 0)
        assert np.all(np.sum(batch.root_rotations[:, :, 1:] * batch.root_rotations[:, :, :-1], axis=-1) > 0)


@pytest.mark.parametrize("rest_pose", ["totem", "tpose"])
def test_local_rotations_are_exact_with_the_joints_own_bone_lengths(rest_pose):
    h36m = make_sample(jax.random.key(4), CONFIG).joints[0]  # (T, 17, 3): a real motion, camera frame
    joints = np.asarray(geometry.flex20_from_structri17(h36m))
    local = np.asarray(local_rotations(joints, rest_pose))
    assert_allclose(np.einsum("...ij,...kj->...ik", local, local), np.broadcast_to(np.eye(3), local.shape), atol=1e-9)
    assert_allclose(np.linalg.det(local), 1.0, atol=1e-9)
    end_effectors = [j for j in range(1, FLEX20.num_joints) if j not in FLEX20_ROTATING]
    assert_allclose(local[:, end_effectors], np.broadcast_to(np.eye(3), local[:, end_effectors].shape))
    lengths = np.asarray(geometry.bone_lengths(joints, FLEX20))  # (T, 19): bone k ends at joint k + 1
    directions = np.asarray(geometry.FLEX20_REST_DIRECTIONS[rest_pose])
    offsets = np.concatenate([np.zeros((len(joints), 1)), lengths], axis=1)[..., None] * directions
    positions, _ = geometry.forward_kinematics(local, offsets, joints[:, 0], FLEX20)
    assert_allclose(positions, joints, atol=1e-9)


def test_symmetric_bone_lengths_average_left_and_right():
    joints = np.asarray(geometry.flex20_from_structri17(np.random.default_rng(0).normal(size=(17, 3))))
    lengths = np.asarray(geometry.bone_lengths(joints, FLEX20))
    bones = np.asarray(symmetric_bone_lengths(joints))
    j = FLEX20.index
    assert_allclose(bones[1], 0.5 * (lengths[j("r_knee") - 1] + lengths[j("l_knee") - 1]))
    assert_allclose(bones[4], lengths[j("thorax") - 1])  # spine -> thorax, and its two arm copies
    assert_allclose(bones[9], 0.5 * (lengths[j("r_wrist") - 1] + lengths[j("l_wrist") - 1]))


def test_normalisation_ignores_each_views_shift_and_scale(static_batch):
    """Another focal length, principal point or image size changes a view's pixels by a shift and an isotropic
    scale; the normalised input must not change (only its centre and scale do)."""
    points, confidences = static_batch.points_2d, static_batch.confidences
    root = STRUCTRI17.index("mid_hip")
    base = normalise_2d(points, confidences, root)
    rng = np.random.default_rng(0)
    for _ in range(5):
        scale = rng.uniform(0.1, 10.0, (2, CONFIG.views))
        shift = rng.uniform(-2000.0, 2000.0, (2, CONFIG.views, 2))
        moved = normalise_2d(points * scale[..., None, None, None] + shift[:, :, None, None], confidences, root)
        assert_allclose(moved.features, base.features, atol=1e-9)
        assert_allclose(moved.scale, base.scale * scale, rtol=1e-9)
        assert_allclose(moved.centre, base.centre * scale[..., None] + shift, rtol=1e-9, atol=1e-6)


def test_normalisation_of_missing_joints_and_empty_views():
    rng = np.random.default_rng(0)
    points = rng.normal(500.0, 50.0, (2, 6, 17, 2))
    confidences = rng.uniform(0.3, 1.0, (2, 6, 17))
    confidences[0, 2, 5] = 0.0  # one joint missing
    confidences[0, 3, 0] = 0.0  # the root missing in a frame: that frame's other joints are unusable
    points[0, 4, 7] = np.nan  # a non-finite detection counts as missing
    confidences[1] = 0.0  # an empty view
    out = normalise_2d(points, confidences, 0)
    features = np.asarray(out.features)
    assert np.all(np.isfinite(features)) and np.all(np.isfinite(out.scale)) and np.all(np.isfinite(out.centre))
    assert np.all(features[0, 2, 5] == 0) and np.all(features[0, 3] == 0) and np.all(features[0, 4, 7] == 0)
    assert np.all(features[1] == 0) and float(out.scale[1]) == 1.0
    # Root-relative in units of the scale: the other joints' weighted RMS distance is 1.
    weight = features[0, :, 1:, 2] * features[0, :, :1, 2]
    rms = np.sqrt(np.sum(weight * np.sum(features[0, :, 1:, :2] ** 2, -1)) / np.sum(weight))
    assert_allclose(rms, 1.0, rtol=1e-12)
    with pytest.raises(ValueError, match="root"):
        normalise_2d(points, confidences, 17)


def test_config_validation():
    with pytest.raises(ValueError, match="unknown"):
        DataConfig(clips=("no_such_clip",))
    with pytest.raises(ValueError, match="distance"):
        DataConfig(distance=(3.0, 2.0))


@pytest.mark.parametrize("rig", ["h36m_ring", "shelf"])
def test_a_fixed_rig_sees_every_sample_and_the_person_moves_to_it(rig):
    """The rig's first views at every frame of every sample; the person's mean root within ``placement_radius`` of
    the rig's centre (the point its optical axes meet), at a different place and heading in each sample; the
    ground truth is the person seen through those cameras."""
    config = DataConfig(views=4, frames=16, rig=rig, placement_radius=0.5)
    batch = make_batch(jax.random.key(4), config, 3)
    cameras = fixed_rig(rig)
    for name in ("K", "R", "t"):
        assert_allclose(getattr(batch.cameras, name), np.broadcast_to(
            np.asarray(getattr(cameras, name))[None, :4, None], getattr(batch.cameras, name).shape), atol=1e-6)
    centre = rig_centre(cameras)
    means = np.stack([_world_root(batch, sample).mean(0) for sample in range(3)])
    assert np.all(np.linalg.norm(means[:, :2] - centre[:2], axis=-1) <= 0.5 + 1e-6)
    assert len(np.unique(means[:, :2].round(6), axis=0)) == 3
    assert np.mean(batch.confidences > 0) > 0.5


def _world_root(batch, sample) -> np.ndarray:
    """The root's world path (frames, 3) back from view 0's ``root_position`` (``(x d, y d, d)`` of the exact root
    projection, :func:`flex.root_frame`) and the view's true camera."""
    normalised = normalise_2d(batch.points_2d[sample], batch.confidences[sample], STRUCTRI17.index("mid_hip"))
    K, R, t = (np.asarray(x[sample, 0, 0]) for x in (batch.cameras.K, batch.cameras.R, batch.cameras.t))
    scale, centre = float(normalised.scale[0]), np.asarray(normalised.centre[0])
    x, d = np.asarray(batch.root_position[sample, 0, :, :2]), np.asarray(batch.root_position[sample, 0, :, 2:])
    depth = d * K[0, 0] / scale
    pixels = x / d * scale + centre
    in_camera = np.concatenate([(pixels - K[:2, 2]) / K[0, 0] * depth, depth], axis=-1)
    return (in_camera - t) @ R


def test_fixed_rig_options_are_checked():
    with pytest.raises(ValueError, match="static cameras"):
        DataConfig(rig="h36m_ring", camera_motion="dynamic")
    with pytest.raises(ValueError, match="4 cameras, fewer than views=5"):
        DataConfig(views=5, rig="h36m_ring")
    with pytest.raises(ValueError, match="calibration file"):
        DataConfig(rig="no_such_rig")
    with pytest.raises(ValueError, match="placement_radius"):
        DataConfig(rig="shelf", placement_radius=-1.0)
    assert_allclose(rig_centre(fixed_rig("h36m_ring")), [0.0, 0.0, 1.0], atol=1e-9)


def test_flex20_skeleton_data():
    assert list(FLEX20.parents) == [-1, 0, 1, 2, 0, 4, 5, 0, 7, 8, 9, 10, 8, 12, 13, 14, 8, 16, 17, 18]
    x = jnp.arange(17 * 3.0).reshape(17, 3)
    flex20 = geometry.flex20_from_structri17(x)
    assert_array_equal(geometry.remap_joints(flex20, FLEX20, STRUCTRI17), x)
    for duplicate, original in geometry.FLEX20_DUPLICATE_OF.items():
        assert_array_equal(flex20[FLEX20.index(duplicate)], flex20[FLEX20.index(original)])


def test_sign_continuous_keeps_the_rotations_and_removes_the_sign_jumps():
    rng = np.random.default_rng(0)
    steps = 0.05 * rng.normal(size=(40, 3, 3))
    q = np.asarray(geometry.axis_angle_to_quaternion(np.cumsum(steps, axis=0)))  # slow motion (frames, 3, 4)
    flipped = q * rng.choice([-1.0, 1.0], size=q.shape[:-1])[..., None]
    fixed = np.asarray(sign_continuous(flipped))
    assert np.all(np.sum(fixed[1:] * fixed[:-1], axis=-1) > 0.9)
    assert_allclose(np.abs(np.sum(fixed * q, axis=-1)), 1.0, atol=1e-12)  # each +-q


def test_a_motion_file_is_a_clip_of_the_samples(data_root):
    """Any CMU motion file (here an exp-map file of the benchmark's test split) feeds the samples as a shipped clip
    does; a name that is neither is refused before any sampling."""
    path = str(data_root / "cmu_expmap" / "test" / "walking" / "walking_1.txt")
    sample = make_sample(jax.random.key(0), DataConfig(views=4, frames=16, clips=(path,)))
    assert sample.points_2d.shape == CONFIG_SHAPE and np.isfinite(np.asarray(sample.joints)).all()
    with pytest.raises(ValueError, match=r"shipped clips .* or motion files, got unknown \['no_such_clip'\]"):
        DataConfig(clips=("no_such_clip",))

"""motion_from_joints: joint rotations with fixed bone lengths fitted to 3D joints, checked through a BVH round trip."""

import jax
import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.spatial.transform import Rotation

import mocap
from geometry import SHELF15

ROUND_TRIP_M = 1e-6
"""Stated tolerance of the BVH round trip (8 decimals of metres and degrees in the file)."""
_PARENTS_FIRST = (14, 2, 3, 12, 1, 4, 0, 5, 8, 9, 13, 7, 10, 6, 11)
"""Shelf15's joints, each after its parent."""


@pytest.fixture(scope="module")
def person() -> np.ndarray:
    """One synthetic person's Shelf15 joints over 40 frames (metres): real CMU motion, bones that vary in length
    (the head joints come from a head rule)."""
    scene = mocap.synthesise_scene(jax.random.key(3), mocap.shelf_cameras(), num_people=1, num_frames=40)
    return np.asarray(scene.shelf15)[:, 0]


def _bvh_positions(tmp_path, motion: mocap.Motion) -> np.ndarray:
    """The skeleton joints' positions read back from the motion's BVH (the reader renames leaves '<parent>_end')."""
    names = mocap.write_bvh(tmp_path / "person.bvh", motion.joint_names, motion.parents, motion.offsets,
                            motion.local_rotations, motion.root_positions, fps=motion.fps, metres_per_unit=1.0)
    back = mocap.read_bvh(tmp_path / "person.bvh", 1.0)
    return back.positions[:, [back.joint_names.index(name) for name in names[:SHELF15.num_joints]]]


def _fixed_length_joints(joints: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """Independent statement of the fit: the root, plus every bone in its observed direction at its fixed length."""
    out = np.zeros_like(joints)
    out[:, SHELF15.root] = joints[:, SHELF15.root]
    for joint in _PARENTS_FIRST:
        parent = SHELF15.parents[joint]
        if parent >= 0:
            bone = joints[:, joint] - joints[:, parent]
            out[:, joint] = out[:, parent] + lengths[joint] * bone / np.linalg.norm(bone, axis=-1, keepdims=True)
    return out


def test_bvh_reproduces_the_joints_with_fixed_bone_lengths(tmp_path, person):
    motion = mocap.motion_from_joints(person, SHELF15, fps=25.0)
    lengths = np.array([np.median(np.linalg.norm(person[:, j] - person[:, p], axis=-1)) if p >= 0 else 0.0
                        for j, p in enumerate(SHELF15.parents)])
    expected = _fixed_length_joints(person, lengths)
    read_back = _bvh_positions(tmp_path, motion)
    assert_allclose(read_back, expected, atol=ROUND_TRIP_M)
    # ... and the input within the length deviations summed along each joint's path from the root.
    deviation = np.abs(np.linalg.norm(person - person[:, list(SHELF15.parents)], axis=-1) - lengths)
    deviation[:, SHELF15.root] = 0.0
    assert (np.linalg.norm(read_back - person, axis=-1) <= _path_sums(deviation) + ROUND_TRIP_M).all()
    assert np.linalg.norm(read_back - person, axis=-1).max() > 1e-3, "synthetic bones vary; the fit normalises them"


def _path_sums(per_joint: np.ndarray) -> np.ndarray:
    """Per joint, the sum of ``per_joint`` over the joints on its path from the root (its own included)."""
    out = np.zeros_like(per_joint)
    for joint in range(SHELF15.num_joints):
        node = joint
        while node >= 0:
            out[:, joint] += per_joint[:, node]
            node = SHELF15.parents[node]
    return out


def test_rigid_skeleton_is_reproduced_exactly(tmp_path):
    """Joints made by forward kinematics of a rigid skeleton under random rotations come back to 1e-6 m."""
    rng = np.random.default_rng(0)
    rest = rng.normal(size=(SHELF15.num_joints, 3)) * 0.3
    rotations = Rotation.random(30 * SHELF15.num_joints, random_state=1).as_matrix().reshape(30, -1, 3, 3)
    joints = np.zeros((30, SHELF15.num_joints, 3))
    world = np.zeros_like(rotations)
    for joint in _PARENTS_FIRST:
        parent = SHELF15.parents[joint]
        if parent < 0:
            world[:, joint], joints[:, joint] = rotations[:, joint], rng.normal(size=(30, 3))
        else:
            world[:, joint] = world[:, parent] @ rotations[:, joint]
            joints[:, joint] = joints[:, parent] + world[:, parent] @ rest[joint]
    motion = mocap.motion_from_joints(joints, SHELF15, fps=30.0)
    assert_allclose(_bvh_positions(tmp_path, motion), joints, atol=ROUND_TRIP_M)
    gram = np.swapaxes(motion.local_rotations, -1, -2) @ motion.local_rotations
    assert_allclose(gram, np.broadcast_to(np.eye(3), gram.shape), atol=1e-9)
    assert_allclose(motion.local_rotations[0, SHELF15.root], world[0, SHELF15.root] @ world[0, SHELF15.root].T,
                    atol=1e-9)  # the rest pose is the reference frame (frame 0 here): the root's identity


def test_missing_joints_take_the_nearest_frames_direction(person):
    valid = np.ones(person.shape[:2], bool)
    wrist = SHELF15.index("l_wrist")
    valid[10:20, wrist] = False
    valid[:, SHELF15.index("head_top")] = False  # never seen: its bone has length 0
    motion = mocap.motion_from_joints(np.where(valid[..., None], person, np.nan), SHELF15, fps=25.0, valid=valid)
    assert np.isfinite(motion.positions).all()
    elbow = SHELF15.index("l_elbow")
    direction = motion.positions[:, wrist] - motion.positions[:, elbow]
    direction /= np.linalg.norm(direction, axis=-1, keepdims=True)
    observed = person[:, wrist] - person[:, elbow]
    observed /= np.linalg.norm(observed, axis=-1, keepdims=True)
    assert_allclose(direction[10:15], observed[[9] * 5], atol=1e-9)  # frames 10-14 nearer to 9, 15-19 to 20
    assert_allclose(direction[15:20], observed[[20] * 5], atol=1e-9)
    assert_allclose(motion.positions[:, SHELF15.index("head_top")], motion.positions[:, SHELF15.index("head_bottom")],
                    atol=1e-12)


@pytest.mark.parametrize("change, message", [
    (lambda j, v: (j[:, :14], None), "shape"),
    (lambda j, v: (j[:0], None), "shape"),
    (lambda j, v: (j, np.zeros_like(v)), "root joint 'mid_hip' is never valid"),
])
def test_bad_input_is_refused_in_one_line(person, change, message):
    joints, valid = change(person, np.ones(person.shape[:2], bool))
    with pytest.raises(ValueError, match=message) as error:
        mocap.motion_from_joints(joints, SHELF15, fps=25.0, valid=valid)
    assert "\n" not in str(error.value)


def test_predictions_by_person():
    frames = np.array([300, 301, 303])
    joints = np.arange(4 * 15 * 3, dtype=float).reshape(4, 15, 3)
    predictions = mocap.PosePredictions.create(np.array([300, 300, 301, 303]), np.array([7, 2, 7, 2]), joints)
    persons, by_person, present = predictions.by_person(frames)
    assert persons.tolist() == [2, 7]
    assert present.tolist() == [[True, False, True], [True, True, False]]
    assert_allclose(by_person[0, 2], joints[3])
    assert_allclose(by_person[1, 1], joints[2])
    assert not by_person[0, 1].any()
    with pytest.raises(ValueError, match="frame 302 is not among"):
        mocap.PosePredictions.create(np.array([302]), np.array([0]), joints[:1]).by_person(frames)
    with pytest.raises(ValueError, match="two rows of one person"):
        mocap.PosePredictions.create(np.array([300, 300]), np.array([0, 0]), joints[:2]).by_person(frames)

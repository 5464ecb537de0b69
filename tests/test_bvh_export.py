"""BVH export: :func:`mocap.write_bvh` round trips through :func:`mocap.read_bvh`, and :func:`flex.to_bvh`
reproduces FLEX's forward kinematics in its documented frame (the view's camera frame; read back,
``(x, y, z) -> (x, z, -y)``)."""

import numpy as np
import pytest
from jaxtyping import TypeCheckError

import flex
import geometry
import mocap
from geometry import FLEX20

CAMERA_TO_READ = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
"""Where flex.to_bvh's docstring says a camera-frame point lands once read back: (x, y, z) -> (x, z, -y)."""

# A small tree with the root not first and two end sites: hips -> spine -> neck -> head, hips -> r_foot.
NAMES = ("spine", "hips", "head", "r_foot", "neck")
PARENTS = (1, -1, 4, 1, 0)
OFFSETS = np.array([[0.0, 0.1, 0.0], [0.0, 0.0, 0.0], [0.0, 0.15, 0.02], [-0.1, -0.9, 0.0], [0.0, 0.3, 0.0]])


def _axis_rotation(axis: int, degrees: float) -> np.ndarray:
    angles = np.zeros(3)
    angles[axis] = np.deg2rad(degrees)
    return np.asarray(geometry.euler_to_matrix(angles, "XYZ"))


def _simple_motion() -> tuple[np.ndarray, np.ndarray]:
    """Local rotations (3 frames) and root positions: rest; root 90 deg about z and spine 90 deg about x; and a
    random root with the spine at gimbal lock (90 deg about y, the middle axis of ZYX)."""
    local = np.broadcast_to(np.eye(3), (3, len(NAMES), 3, 3)).copy()
    local[1, 1], local[1, 0] = _axis_rotation(2, 90.0), _axis_rotation(0, 90.0)
    local[2, 1] = np.asarray(geometry.axis_angle_to_matrix(np.array([0.3, -1.2, 2.0])))
    local[2, 0] = _axis_rotation(1, 90.0) @ _axis_rotation(0, 20.0)
    local[2, 4] = _axis_rotation(1, -90.0)
    local[:, 2] = _axis_rotation(0, 33.0)  # an end effector's rotation: moves nothing, not written
    return local, np.array([[1.0, 2.0, 3.0], [1.0, 2.0, 3.0], [-0.5, 0.25, 1.0]])


def test_write_bvh_round_trip(tmp_path):
    local, root = _simple_motion()
    path = tmp_path / "simple.bvh"
    names = mocap.write_bvh(path, NAMES, PARENTS, OFFSETS, local, root, fps=120.0, metres_per_unit=0.01)
    assert names == ("spine", "hips", "neck_end", "hips_end", "neck")
    motion = mocap.read_bvh(path, 0.01)
    assert motion.joint_names == ("hips", "spine", "neck", "neck_end", "hips_end")  # depth first
    assert motion.fps == 120.0 and motion.num_frames == 3
    text = path.read_text()
    assert "CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation" in text
    assert text.count("End Site") == 2 and text.count("CHANNELS 3 Zrotation Yrotation Xrotation") == 2
    index = [motion.node(n) for n in names]
    positions = motion.positions[:, index]
    # frame 1 by hand: the root turns +y into -x, then the spine's 90 deg about x turns the neck bone to +z
    spine = root[1] + [-0.1, 0.0, 0.0]
    np.testing.assert_allclose(positions[1, 0], spine, atol=1e-9)
    np.testing.assert_allclose(positions[1, 4], spine + [0.0, 0.0, 0.3], atol=1e-9)
    expected, _ = geometry.forward_kinematics(local, OFFSETS, root, PARENTS)
    np.testing.assert_allclose(positions, np.asarray(expected), atol=1e-9)
    np.testing.assert_allclose(motion.root_positions, root, atol=1e-9)
    jointed = [0, 1, 4]  # the end sites' rotations are not written
    np.testing.assert_allclose(motion.local_rotations[:, np.asarray(index)[jointed]], local[:, jointed], atol=1e-9)


def test_write_bvh_round_trips_a_motion(tmp_path):
    """A Motion's fields go in as they are; every node, end sites included, comes back in place."""
    motion = mocap.procedural_motion(seed=3, num_frames=12)
    path = tmp_path / "walk.bvh"
    names = mocap.write_bvh(path, motion.joint_names, motion.parents, motion.offsets, motion.local_rotations,
                            motion.root_positions, fps=motion.fps, metres_per_unit=0.01)
    back = mocap.read_bvh(path, 0.01)
    assert back.fps == motion.fps
    np.testing.assert_allclose(back.positions[:, [back.node(n) for n in names]], motion.positions, atol=1e-7)


@pytest.mark.parametrize("rest_pose, metres_per_unit", [("totem", 1.0), ("tpose", 0.01)])
def test_flex_to_bvh_matches_forward_kinematics(tmp_path, rest_pose, metres_per_unit):
    rng = np.random.default_rng(7)
    frames = 6
    bones = rng.uniform(0.1, 0.5, 10)
    rotations = rng.normal(size=(frames, 14, 4))  # not unit: normalised as the FK layer does
    root_rotation = rng.normal(size=(frames, 4))
    root_position = rng.normal(size=(frames, 3)) + [0.0, 0.0, 4.0]
    path = tmp_path / "flex.bvh"
    names = flex.to_bvh(path, bones, rotations, root_rotation, root_position, fps=25.0, rest_pose=rest_pose,
                        metres_per_unit=metres_per_unit)
    assert [names[j] for j in geometry.FLEX20_END_EFFECTORS] == [
        "r_knee_end", "l_knee_end", "neck_nose_end", "l_elbow_end", "r_elbow_end"]
    motion = mocap.read_bvh(path, metres_per_unit)
    assert sorted(motion.joint_names) == sorted(names) and motion.fps == 25.0
    camera = np.asarray(flex.flex_forward_kinematics(bones, rotations, root_rotation[None], rest_pose))[0]
    expected = (camera + root_position[:, None]) @ CAMERA_TO_READ.T
    np.testing.assert_allclose(motion.positions[:, [motion.node(n) for n in names]], expected, atol=1e-5)


def test_flex_to_bvh_upright_person_facing_the_camera(tmp_path):
    """Body frame (x left, y up, z forward) facing an OpenCV camera is a half turn about x: the file then has the
    identity root rotation (the BVH rest pose, y up) and the root in the camera frame with y and z negated."""
    frames, mpu = 2, 0.01
    rotations = np.broadcast_to([1.0, 0.0, 0.0, 0.0], (frames, 14, 4))
    facing = np.broadcast_to([0.0, 1.0, 0.0, 0.0], (frames, 4))
    root_position = np.array([[0.2, 0.1, 3.0], [0.3, 0.1, 3.5]])
    path = tmp_path / "upright.bvh"
    names = flex.to_bvh(path, np.full(10, 0.3), rotations, facing, root_position, fps=30.0, metres_per_unit=mpu)
    lines = path.read_text().splitlines()
    values = np.array([line.split() for line in lines[lines.index("Frame Time: 0.0333333333") + 1:]], float)
    np.testing.assert_allclose(values[:, :3], root_position * [1.0, -1.0, -1.0] / mpu, atol=1e-6)
    np.testing.assert_allclose(values[:, 3:], 0.0, atol=1e-6)  # every joint at rest
    motion = mocap.read_bvh(path, mpu)
    head, root = motion.node(names[FLEX20.index("head")]), motion.node(names[FLEX20.root])
    np.testing.assert_allclose(motion.positions[:, head] - motion.positions[:, root], [[0.0, 0.0, 1.2]] * 2,
                               atol=1e-9)  # totem: the four spine and head bones straight up (read back: +z)


def _write(path, names=NAMES, parents=PARENTS, offsets=OFFSETS, local=None, root=None, fps=30.0, mpu=1.0):
    simple_local, simple_root = _simple_motion()
    return mocap.write_bvh(path, names, parents, offsets, simple_local if local is None else local,
                           simple_root if root is None else root, fps=fps, metres_per_unit=mpu)


@pytest.mark.parametrize("kwargs, message", [
    (dict(names=NAMES[:4], parents=PARENTS[:4]), "parent index out of range"),
    (dict(parents=(1, -1, 4, -1, 0)), "exactly one root"),
    (dict(names=("spine", "hips", "head", "r foot", "neck")), "without whitespace"),
    (dict(parents=(1, -1, 4, 4, 0)), r"several nodes \['neck_end'\]"),  # two end sites under the neck
    (dict(names=("spine", "hips", "head", "r_foot", "hips_end")), r"several nodes \['hips_end'\]"),
    (dict(names=NAMES + ("extra",), parents=PARENTS + (1,)), r"offsets must have shape \(6, 3\)"),
    (dict(local=np.zeros((0, 5, 3, 3)), root=np.zeros((0, 3))), "no frames"),
    (dict(root=np.array([[0.0, 0.0, np.nan]] * 3)), "non-finite"),
    (dict(local=np.broadcast_to(np.diag([1.0, 1.0, -1.0]), (3, 5, 3, 3))), "not rotation matrices"),
    (dict(local=np.broadcast_to(2.0 * np.eye(3), (3, 5, 3, 3))), "not rotation matrices"),
    (dict(fps=0.0), "must be positive"),
    (dict(mpu=-1.0), "must be positive"),
])
def test_write_bvh_rejects_bad_input(tmp_path, kwargs, message):
    path = tmp_path / "bad.bvh"
    with pytest.raises(ValueError, match=message):
        _write(path, **kwargs)
    assert not path.exists()  # checked before anything is written


@pytest.mark.parametrize("kwargs", [
    dict(offsets=OFFSETS[:, :2]),
    dict(local=np.broadcast_to(np.eye(3), (3, 5, 3, 3))[:2]),  # 2 frames of rotations, 3 root positions
])
def test_write_bvh_rejects_inconsistent_shapes(tmp_path, kwargs):
    # Under the test suite's runtime annotation checks jaxtyping catches the shape first.
    with pytest.raises((ValueError, TypeCheckError)):
        _write(tmp_path / "bad.bvh", **kwargs)


def _flex_inputs(frames=4):
    return dict(bone_lengths=np.full(10, 0.3), rotations=np.tile([1.0, 0.0, 0.0, 0.0], (frames, 14, 1)),
                root_rotation=np.tile([1.0, 0.0, 0.0, 0.0], (frames, 1)), root_position=np.zeros((frames, 3)))


@pytest.mark.parametrize("change, errors, message", [
    (dict(rotations=np.ones((4, 13, 4))), (ValueError, TypeCheckError), "rotations"),
    (dict(root_rotation=np.ones((3, 4))), (ValueError, TypeCheckError), "root_rotation"),
    (dict(bone_lengths=np.ones(9)), (ValueError, TypeCheckError), "bone_lengths"),
    (dict(root_position=np.array([[0.0, np.inf, 0.0]] * 4)), ValueError, "non-finite"),
    (dict(rotations=np.full((4, 14, 4), np.nan)), ValueError, "non-finite"),
    (dict(bone_lengths=np.array([0.3] * 9 + [-0.1])), ValueError, "bone lengths must be positive"),
    (dict(rest_pose="apose"), (ValueError, TypeCheckError), "rest_pose"),
    (dict(fps=-30.0), ValueError, "must be positive"),
])
def test_to_bvh_rejects_bad_input(tmp_path, change, errors, message):
    arguments = {**_flex_inputs(), "fps": 30.0, **change}
    path = tmp_path / "bad.bvh"
    with pytest.raises(errors, match=message):
        flex.to_bvh(path, **arguments)
    assert not path.exists()


@pytest.mark.parametrize("metres_per_unit", [-1.0, 0.0, float("nan")])
def test_read_bvh_refuses_a_scale_that_is_not_positive(tmp_path, metres_per_unit):
    path = tmp_path / "one.bvh"
    path.write_text("HIERARCHY\nROOT hips\n{\n  OFFSET 0 0 0\n  CHANNELS 3 Xposition Yposition Zposition\n"
                    "  End Site\n  {\n    OFFSET 0 1 0\n  }\n}\nMOTION\nFrames: 1\nFrame Time: 0.1\n1 2 3\n")
    assert mocap.read_bvh(path, 0.5).fps == pytest.approx(10.0)  # the file itself is fine
    with pytest.raises(ValueError, match="metres_per_unit must be a finite number > 0"):
        mocap.read_bvh(path, metres_per_unit)

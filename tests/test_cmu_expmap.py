"""The exponential-map CMU reader (mocap/_cmu_expmap.py): the data folder README's properties on the real files, an
independent forward kinematics (SciPy rotations, the README's row-vector form) on one frame, malformed files, and
the files as clips of a synthetic scene."""

import hashlib

import jax
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import geometry
import mocap

NODE = {name: i for i, name in enumerate(mocap.CMU_EXPMAP_NODES)}


@pytest.fixture(scope="module")
def splits(data_root):
    return {split: mocap.cmu_expmap_files(data_root, split) for split in ("train", "test")}


@pytest.fixture(scope="module")
def walk(splits):
    path = next(p for p in splits["test"] if p.parent.name == "walking")
    return path, mocap.read_cmu_expmap(path)


def test_the_split_has_the_readme_files_and_frames(splits):
    assert (len(splits["train"]), len(splits["test"])) == (72, 24)
    actions = {p.parent.name for p in splits["train"]}
    assert actions == {"basketball", "basketball_signal", "directing_traffic", "jumping", "running", "soccer",
                       "walking", "walking_extra"}
    lines = {split: sum(1 for p in files for line in p.read_text().splitlines() if line.strip())
             for split, files in splits.items()}
    assert lines == {"train": 53_775, "test": 14_095}
    # Held out: no test file repeats a training file's motion.
    digest = {split: {hashlib.sha256(p.read_bytes()).hexdigest() for p in files} for split, files in splits.items()}
    assert not digest["train"] & digest["test"]


def test_walk_has_constant_bones_human_proportions_and_walking_speed(walk):
    _, motion = walk
    assert motion.rig == "cmu" and motion.fps == mocap.CMU_EXPMAP_FPS
    pos = motion.positions
    parents = np.array(motion.parents)
    lengths = np.linalg.norm(pos[:, 1:] - pos[:, parents[1:]], axis=-1)
    np.testing.assert_allclose(lengths, np.broadcast_to(lengths[0], lengths.shape), rtol=0, atol=1e-9)
    root = pos[:, 0]
    feet = pos[:, [NODE["ltoes"], NODE["rtoes"]], 2].min(axis=1)
    assert 0.85 < np.mean(root[:, 2] - feet) < 1.0  # the README: about 17 units (0.96 m) below the root
    assert 0.4 < np.mean(pos[:, NODE["head_end"], 2] - root[:, 2]) < 0.6  # about 9 units above it
    speed = np.linalg.norm(np.diff(root[:, :2], axis=0), axis=1).mean() * motion.fps
    assert 0.9 < speed < 1.6  # metres per second


def test_left_is_left_and_the_walker_moves_forward(walk):
    _, motion = walk
    body = mocap.motion_joint_positions(motion, geometry.BODY25)
    left_to_right = body[:, geometry.BODY25.index("l_hip")] - body[:, geometry.BODY25.index("r_hip")]
    forward = np.cross(left_to_right, [0.0, 0.0, 1.0])  # z up: left x up is forward
    velocity = np.gradient(body[:, geometry.BODY25.index("mid_hip")], axis=0)
    assert np.mean(np.sum(forward * velocity, axis=-1) > 0) > 0.95
    nose = body[:, geometry.BODY25.index("nose")] - body[:, geometry.BODY25.index("neck")]
    assert np.all(np.sum(forward * nose, axis=-1) > 0)


def test_one_frame_against_the_readme_forward_kinematics(walk):
    """The README's row-vector form, written out with SciPy's rotation vectors: R_i = E(r_i) R_parent,
    x_i = o_i R_parent + x_parent, root at o_0 + the position; then ASF units to metres and y up to z up."""
    path, motion = walk
    frame = 57
    values = np.array([float(v) for v in path.read_text().splitlines()[frame].strip().rstrip(",").split(",")])
    rotvecs = values[3:].reshape(-1, 3)
    R, x = {}, {}
    for i, parent in enumerate(mocap.CMU_EXPMAP_PARENTS):
        E = Rotation.from_rotvec(rotvecs[i]).as_matrix()
        if parent < 0:
            R[i], x[i] = E, mocap.CMU_EXPMAP_OFFSETS[i] + values[:3]
        else:
            R[i], x[i] = E @ R[parent], mocap.CMU_EXPMAP_OFFSETS[i] @ R[parent] + x[parent]
    expected = np.stack([x[i] for i in range(len(x))]) * mocap.CMU_METRES_PER_UNIT
    expected = np.stack([expected[:, 0], -expected[:, 2], expected[:, 1]], axis=-1)  # (x, y, z) -> (x, -z, y)
    np.testing.assert_allclose(motion.positions[frame], expected, rtol=0, atol=1e-9)


@pytest.mark.parametrize("content, message", [
    ("", ":1: no frames"),
    ("1," * 117 + "\n" + "1," * 116 + "\n", ":2: expected 117 comma-separated values, got 116"),
    ("1," * 116 + "x,\n", ":1: a value is not a number"),
    ("1," * 116 + "inf\n", ":1: a value is not finite"),
])
def test_a_malformed_file_names_its_line(tmp_path, content, message):
    path = tmp_path / "walking_1.txt"
    path.write_text(content)
    with pytest.raises(ValueError, match=f"^{path}{message}"):
        mocap.read_cmu_expmap(path)


def test_a_bad_split_or_folder_is_refused(tmp_path, data_root):
    with pytest.raises(ValueError, match="split must be one of"):
        mocap.cmu_expmap_files(data_root, "validation")
    with pytest.raises(ValueError, match="holds no cmu_expmap"):
        mocap.cmu_expmap_files(tmp_path)


def test_the_validation_files_are_the_last_of_each_train_action(data_root):
    """The highest-numbered file of each of the 8 actions, listed by hand from the data folder."""
    validation = mocap.cmu_expmap_validation_files(data_root)
    assert [f"{f.parent.name}/{f.name}" for f in validation] == [
        "basketball/basketball_5.txt", "basketball_signal/basketball_signal_5.txt",
        "directing_traffic/directing_traffic_4.txt", "jumping/jumping_5.txt", "running/running_5.txt",
        "soccer/soccer_5.txt", "walking/walking_5.txt", "walking_extra/walking_52.txt"]
    assert set(validation) <= set(mocap.cmu_expmap_files(data_root, "train"))


def test_a_file_is_a_clip_that_scene_synthesis_takes(walk):
    path, motion = walk
    clip = mocap.cmu_expmap_clip(path)
    assert clip.name == "test/walking/walking_1" and clip.fps == 30.0 and clip.num_people == 1
    assert clip.num_frames == len(motion.positions[::4])  # 120 Hz to 30 Hz picks every 4th frame
    np.testing.assert_allclose(clip.structri17[0, 1], mocap.motion_joint_positions(motion, geometry.STRUCTRI17)[4])
    scene = mocap.synthesise_scene(jax.random.key(0), mocap.shelf_cameras(), num_people=2, num_frames=40,
                                   clips=[clip, mocap.load_clip("02_01_walk")])
    assert scene.num_people == 2 and scene.num_frames == 40


def test_load_clip_file_reads_every_cmu_format_and_refuses_the_rest(data_root, tmp_path):
    shipped = mocap.load_clip_file("02_01_walk")
    np.testing.assert_array_equal(shipped.body25, mocap.load_clip("02_01_walk").body25)
    amc = mocap.load_clip_file("cmu_mocap/02_01.amc", data_root)  # the shipped clip's source: the same motion
    np.testing.assert_allclose(amc.structri17, shipped.structri17, atol=6e-4)  # shipped: rounded to 1 mm
    expmap = mocap.load_clip_file("cmu_expmap/test/walking/walking_1.txt", data_root)
    assert expmap.name == "test/walking/walking_1" and expmap.fps == 30.0
    bvh = mocap.load_clip_file(data_root / "cmu_mocap" / "18_01.bvh")
    height = np.ptp(bvh.structri17[0, 0, :, 2])
    assert 1.3 < height < 2.0
    with pytest.raises(ValueError, match="60_03_scaled.bvh: its rest pose is 0.07 m tall"):
        mocap.load_clip_file("cmu_mocap/60_03_scaled.bvh", data_root)  # the salsa files use other units
    with pytest.raises(ValueError, match="'nope' is neither a shipped clip"):
        mocap.load_clip_file("nope", data_root)
    (tmp_path / "x.csv").write_text("1,2\n")
    with pytest.raises(ValueError, match="x.csv: not a motion file this reads"):
        mocap.load_clip_file(tmp_path / "x.csv")

"""CMU ASF/AMC and BVH readers, the Motion structure, resampling and the joint mappings.

Real-file tests use ``data_root`` (skipped without it); generated fixtures cover the rest. FK results
are checked against independent SciPy implementations of the two formats' kinematics.
"""

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import mocap
from geometry import BODY25, SHELF14, SHELF15, STRUCTRI17

CMU_UNIT = 0.0254 / 0.45


@pytest.fixture(scope="module")
def cmu(data_root) -> Path:
    folder = data_root / "cmu_mocap"
    if not folder.is_dir():
        pytest.skip(f"no cmu_mocap folder in {data_root}")
    return folder


@pytest.fixture(scope="module")
def walk(cmu) -> mocap.Motion:
    return mocap.read_asf_amc(cmu / "02.asf", cmu / "02_01.amc")


@pytest.fixture(scope="module")
def handshake(cmu) -> mocap.Motion:
    return mocap.read_bvh(cmu / "18_01.bvh", mocap.CMU_METRES_PER_UNIT, fps=120.0)


@pytest.fixture(scope="module")
def salsa(cmu) -> tuple[mocap.Motion, mocap.Motion]:
    return (mocap.read_bvh(cmu / "60_03_scaled.bvh", mocap.SALSA_METRES_PER_UNIT),
            mocap.read_bvh(cmu / "61_03_scaled.bvh", mocap.SALSA_METRES_PER_UNIT))


def _bone_lengths(motion: mocap.Motion) -> np.ndarray:
    child = np.array([j for j, p in enumerate(motion.parents) if p >= 0])
    parent = np.array([motion.parents[j] for j in child])
    return np.linalg.norm(motion.positions[:, child] - motion.positions[:, parent], axis=-1)


def _check_anatomy(motion: mocap.Motion, femur=(0.35, 0.5)):
    """Plausible bones, z up, left joints on the person's left (the root's rest x axis)."""
    h = mocap.motion_joint_positions(motion, STRUCTRI17)
    j = STRUCTRI17.index
    femur_length = np.linalg.norm(h[:, j("r_hip")] - h[:, j("r_knee")], axis=-1)
    assert femur[0] < femur_length.mean() < femur[1]
    for a, b, lo, hi in (("r_knee", "r_ankle", 0.35, 0.5), ("r_shoulder", "r_elbow", 0.22, 0.36),
                         ("r_elbow", "r_wrist", 0.17, 0.3), ("l_hip", "r_hip", 0.1, 0.3),
                         ("mid_hip", "thorax", 0.2, 0.6)):
        length = np.linalg.norm(h[:, j(a)] - h[:, j(b)], axis=-1)
        assert lo < length.mean() < hi, (a, b, length.mean())
    assert (h[:, j("head"), 2] > h[:, j("mid_hip"), 2]).mean() > 0.95
    assert (h[:, j("mid_hip"), 2] > h[:, [j("l_ankle"), j("r_ankle")], 2].max(axis=1)).mean() > 0.95
    left = motion.global_rotations[:, motion.parents.index(-1), :, 0]
    for name in ("hip", "shoulder", "knee", "elbow"):
        d = h[:, j("l_" + name)] - h[:, j("r_" + name)]
        assert (np.sum(d * left, axis=-1) > 0).mean() > 0.95, name
    body = mocap.motion_joint_positions(motion, BODY25)
    b = BODY25.index
    assert (body[:, b("nose"), 2] > body[:, b("neck"), 2]).mean() > 0.95
    eyes = np.linalg.norm(body[:, b("l_eye")] - body[:, b("r_eye")], axis=-1)
    assert 0.04 < eyes.mean() < 0.1
    for side in "lr":
        d = body[:, b(f"{side}_big_toe")] - body[:, b(f"{side}_heel")]
        assert 0.15 < np.linalg.norm(d, axis=-1).mean() < 0.32
        assert np.all(np.isfinite(body))
    sides = body[:, b("l_ear")] - body[:, b("r_ear")]
    assert (np.sum(sides * left, axis=-1) > 0).mean() > 0.95


# ------------------------------------------------------------------ real files


def test_asf_amc_walk(walk):
    assert walk.num_frames == 343 and walk.fps == 120.0 and walk.rig == "cmu"
    lengths = _bone_lengths(walk)
    np.testing.assert_allclose(lengths, lengths[:1].repeat(len(lengths), 0), atol=1e-9)
    femur = np.linalg.norm(walk.positions[:, walk.node("rtibia")] - walk.positions[:, walk.node("rfemur")], axis=-1)
    np.testing.assert_allclose(femur, 7.58734 * CMU_UNIT, rtol=1e-9)  # 02.asf rfemur length
    assert 0.40 < femur[0] < 0.45
    _check_anatomy(walk)
    feet = walk.positions[:, [walk.node("ltoes_end"), walk.node("rtoes_end")], 2]
    assert -0.05 < feet.min() < 0.15  # the floor is near z = 0


def test_asf_amc_matches_scipy_reference(cmu, walk):
    """CMU's amc2mat kinematics written independently with SciPy, on a few frames."""
    text = (cmu / "02.asf").read_text().replace("\r", "")
    bones, hierarchy, current = {}, {}, None
    section = ""
    for line in text.splitlines():
        tok = line.split()
        if not tok:
            continue
        if tok[0].startswith(":"):
            section = tok[0]
        elif section == ":bonedata":
            if tok[0] == "name":
                current = bones.setdefault(tok[1], {"dof": []})
            elif tok[0] == "direction":
                current["dir"] = np.array(tok[1:4], float)
            elif tok[0] == "length":
                current["len"] = float(tok[1])
            elif tok[0] == "axis":
                current["C"] = Rotation.from_euler("xyz", np.array(tok[1:4], float), degrees=True).as_matrix()
            elif tok[0] == "dof":
                current["dof"] = tok[1:]
        elif section == ":hierarchy" and tok[0] not in ("begin", "end"):
            for child in tok[1:]:
                hierarchy[child] = tok[0]
    frames = {}
    lines = (cmu / "02_01.amc").read_text().replace("\r", "").splitlines()
    for k, line in enumerate(lines):
        if line.strip() in ("1", "200"):
            frames[int(line)] = {ln.split()[0]: np.array(ln.split()[1:], float) for ln in lines[k + 1:k + 30]}
    world = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], float)
    for number, values in frames.items():
        root = values["root"]
        rot = {"root": Rotation.from_euler("xyz", root[3:], degrees=True).as_matrix()}
        end = {"root": root[:3]}
        for bone in hierarchy:  # the ASF lists parents before children
            b = bones[bone]
            angles = {"rx": 0.0, "ry": 0.0, "rz": 0.0}
            angles.update(zip(b["dof"], values.get(bone, [])))
            m = Rotation.from_euler("xyz", [angles["rx"], angles["ry"], angles["rz"]], degrees=True).as_matrix()
            rot[bone] = rot[hierarchy[bone]] @ b["C"] @ m @ b["C"].T
            end[bone] = end[hierarchy[bone]] + rot[bone] @ (b["len"] * b["dir"] / np.linalg.norm(b["dir"]))
        for bone, node in (("rhipjoint", "rfemur"), ("ltibia", "lfoot"), ("head", "head_end"),
                           ("rradius", "rwrist"), ("lthumb", "lthumb_end")):
            expected = world @ end[bone] * CMU_UNIT
            np.testing.assert_allclose(walk.positions[number - 1, walk.node(node)], expected, atol=1e-9)


def test_frame_counts_of_the_big_files(cmu):
    asf = mocap.read_asf(cmu / "01.asf")
    root, bones = mocap.read_amc(cmu / "01_01.amc", asf)
    assert root.shape == (2751, 6) and bones["lfemur"].shape == (2751, 3) and bones["ltibia"].shape == (2751, 1)
    assert np.abs(root[:, 3:]).max() <= 2 * np.pi  # degrees were converted to radians


def test_bvh_handshake(handshake, cmu):
    assert handshake.num_frames == 303 and handshake.fps == 120.0 and handshake.rig == "cmu"
    assert mocap.read_bvh(cmu / "18_01.bvh", 1.0).fps == 30.0  # the header's (wrong) rate
    femur = np.linalg.norm(handshake.positions[:, handshake.node("ltibia")]
                           - handshake.positions[:, handshake.node("lfemur")], axis=-1)
    np.testing.assert_allclose(femur, np.hypot(2.54611, 6.99539) * CMU_UNIT, rtol=1e-9)
    _check_anatomy(handshake)


def test_bvh_matches_scipy_reference(handshake, cmu):
    """BVH FK written independently (SciPy intrinsic Euler, recursive offsets) for one frame."""
    lines = (cmu / "18_01.bvh").read_text().replace("\r", "").splitlines()
    start = lines.index("MOTION") + 3
    values = np.array(lines[start + 100].split(), float)
    root_pos = values[:3]
    angles = values[3:].reshape(-1, 3)  # one ZYX triple per joint with channels, in file order
    joints = [j for j in handshake.joint_names if not j.endswith("_end")]
    g_rot, pos = {}, {}
    for k, name in enumerate(joints):
        j = handshake.node(name)
        local = Rotation.from_euler("ZYX", angles[k], degrees=True).as_matrix()
        p = handshake.parents[j]
        if p < 0:
            g_rot[j], pos[j] = local, root_pos
        else:
            pos[j] = pos[p] + g_rot[p] @ (handshake.offsets[j] / CMU_UNIT)
            g_rot[j] = g_rot[p] @ local
    world = np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], float)
    for j in pos:
        np.testing.assert_allclose(handshake.positions[100, j], world @ pos[j] * CMU_UNIT, atol=1e-9)


def test_salsa_pair(salsa):
    lead, follow = salsa
    assert lead.num_frames == follow.num_frames == 1830 and lead.fps == 120.0 and lead.rig == "daz"
    distance = np.linalg.norm(lead.root_positions - follow.root_positions, axis=-1) / mocap.SALSA_METRES_PER_UNIT
    assert 0.25 < distance.min() and distance.max() < 2.0 and 0.4 < np.median(distance) < 0.8
    for person in salsa:
        _check_anatomy(person)
    shelf = mocap.motion_joint_positions(lead, SHELF15)
    np.testing.assert_allclose(shelf[:, 14], shelf[:, 2:4].mean(axis=1))
    assert mocap.motion_joint_positions(lead, SHELF14).shape == (1830, 14, 3)


def test_resample_keeps_duration_and_bones(walk):
    down = mocap.resample_motion(walk, 30.0)
    assert down.fps == 30.0 and abs(down.duration - walk.duration) <= 1 / 30
    np.testing.assert_allclose(down.positions, walk.positions[::4], atol=1e-12)
    odd = mocap.resample_motion(walk, 50.0)  # non-integer ratio: slerp
    assert abs(odd.duration - walk.duration) <= 1 / 50
    lengths = _bone_lengths(odd)
    np.testing.assert_allclose(lengths, _bone_lengths(walk)[:1].repeat(len(lengths), 0), atol=1e-9)
    # frame 5 at 50 Hz is t = 0.1 s = source frame 12 exactly; frame 1 sits between source 2 and 3
    np.testing.assert_allclose(odd.positions[5], walk.positions[12], atol=1e-9)
    between = odd.positions[1]
    gap = np.linalg.norm(walk.positions[3] - walk.positions[2], axis=-1)
    assert np.all(np.linalg.norm(between - 0.6 * walk.positions[2] - 0.4 * walk.positions[3], axis=-1)
                  <= 0.1 * gap + 1e-4)


# ------------------------------------------------------------------ generated fixtures

ASF = """# test skeleton
:version 1.10
:name TEST
:units
  mass 1.0
  length 0.45
  angle deg
:root
   order TX TY TZ RX RY RZ
   axis XYZ
   position 0 0 0
   orientation 0 0 0
:bonedata
  begin
     id 1
     name up
     direction 0 1 0
     length 2
     axis 0 0 90 XYZ
    dof rx rz
  end
  begin
     id 2
     name side
     direction 1 0 0
     length 3
     axis 0 0 0 XYZ
    dof ry
  end
:hierarchy
  begin
    root up
    up side
  end
"""

AMC_FRAMES = ["1", "root 1 2 3 0 90 0", "up 10 20", "side 30",
              "2", "root 1 2 4 0 0 0", "up 0 0", "side 0"]


def _write(path: Path, lines, newline="\n") -> Path:
    path.write_bytes(newline.join(lines).encode() + newline.encode())
    return path


def _amc(tmp_path, frames=AMC_FRAMES, newline="\n"):
    asf = _write(tmp_path / "t.asf", ASF.splitlines(), newline)
    amc = _write(tmp_path / "t.amc", [":FULLY-SPECIFIED", ":DEGREES", *frames], newline)
    return asf, amc


def test_asf_amc_fixture(tmp_path):
    asf, amc = _amc(tmp_path)
    motion = mocap.read_asf_amc(asf, amc)
    assert motion.joint_names == ("root", "up", "side", "side_end") and motion.num_frames == 2
    # frame 2: identity rotations, root at (1, 2, 4) units; "side" starts 2 units up (y-up -> z-up)
    z_up = np.array([1.0, -4.0, 2.0]) * CMU_UNIT
    np.testing.assert_allclose(motion.positions[1, 0], z_up)
    np.testing.assert_allclose(motion.positions[1, 2], z_up + np.array([0, 0, 2.0]) * CMU_UNIT, atol=1e-12)
    np.testing.assert_allclose(motion.positions[1, 3], z_up + np.array([3.0, 0, 2.0]) * CMU_UNIT, atol=1e-12)
    lengths = _bone_lengths(motion)
    np.testing.assert_allclose(lengths[0], lengths[1], atol=1e-12)


def test_crlf_parses_the_same(tmp_path):
    (tmp_path / "lf").mkdir()
    (tmp_path / "crlf").mkdir()
    lf = mocap.read_asf_amc(*_amc(tmp_path / "lf"))
    crlf = mocap.read_asf_amc(*_amc(tmp_path / "crlf", newline="\r\n"))
    assert b"\r\n" in (tmp_path / "crlf" / "t.amc").read_bytes()
    np.testing.assert_array_equal(lf.positions, crlf.positions)
    bvh_lf = mocap.read_bvh(_write(tmp_path / "lf.bvh", BVH.splitlines()), 0.01)
    bvh_crlf = mocap.read_bvh(_write(tmp_path / "crlf.bvh", BVH.splitlines(), "\r\n"), 0.01)
    np.testing.assert_array_equal(bvh_lf.positions, bvh_crlf.positions)


def test_asf_axes_follow_their_order_and_angle_unit(tmp_path):
    """Root ``axis``/``orientation`` and bone ``axis`` lines: angle k turns about the k-th axis of the order, the
    first applied first (SciPy's extrinsic Euler angles), in the ``:units angle`` unit."""
    degrees = (ASF.replace("axis XYZ", "axis ZYX").replace("orientation 0 0 0", "orientation 10 -20 30")
               .replace("axis 0 0 90 XYZ", "axis 40 25 -15 YXZ"))
    def in_radians(*angles):
        return " ".join(str(float(a)) for a in np.deg2rad(angles))

    radians = (degrees.replace("angle deg", "angle rad")
               .replace("orientation 10 -20 30", "orientation " + in_radians(10, -20, 30))
               .replace("axis 40 25 -15 YXZ", "axis " + in_radians(40, 25, -15) + " YXZ"))
    for name, text in (("deg.asf", degrees), ("rad.asf", radians)):
        asf = mocap.read_asf(_write(tmp_path / name, text.splitlines()))
        np.testing.assert_allclose(asf.root_axis, Rotation.from_euler("zyx", [10, -20, 30], degrees=True).as_matrix(),
                                   atol=1e-12, err_msg=name)
        np.testing.assert_allclose(asf.axis["up"], Rotation.from_euler("yxz", [40, 25, -15], degrees=True).as_matrix(),
                                   atol=1e-12, err_msg=name)


@pytest.mark.parametrize("frames, line, message", [
    (AMC_FRAMES[:-1], 9, "has 2 bone lines"),  # truncated last frame
    (AMC_FRAMES[:2] + ["neck 1 2"] + AMC_FRAMES[3:], 5, "unknown bone 'neck'"),
    (AMC_FRAMES[:3] + ["side 3x"] + AMC_FRAMES[4:], 6, "not a number"),
    (AMC_FRAMES[:2] + ["up 10"] + AMC_FRAMES[3:], 5, "needs 2 values"),
])
def test_amc_errors_name_file_and_line(tmp_path, frames, line, message):
    asf, amc = _amc(tmp_path, frames)
    with pytest.raises(ValueError, match=rf"t\.amc:{line}: .*{message}"):
        mocap.read_asf_amc(asf, amc)


def test_asf_errors_name_file_and_line(tmp_path):
    bad = ASF.replace("length 3", "length three").splitlines()
    path = _write(tmp_path / "bad.asf", bad)
    with pytest.raises(ValueError, match=rf"bad\.asf:{bad.index('     length three') + 1}: .*not a number"):
        mocap.read_asf(path)
    bad = ASF.replace("up side", "up elbow").splitlines()
    with pytest.raises(ValueError, match=r"bad2\.asf:\d+: unknown bone 'elbow'"):
        mocap.read_asf(_write(tmp_path / "bad2.asf", bad))


BVH = """HIERARCHY
ROOT hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT spine
  {
    OFFSET 0 10 0
    CHANNELS 3 Xrotation Zrotation Yrotation
    End Site
    {
      OFFSET 0 5 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.008333
1 2 3 0 0 0 0 0 0
1 2 3 90 0 0 0 0 90"""


def test_bvh_fixture(tmp_path):
    motion = mocap.read_bvh(_write(tmp_path / "t.bvh", BVH.splitlines()), 0.01)
    assert motion.fps == 120.0 and motion.joint_names == ("hips", "spine", "spine_end")
    base = np.array([1.0, -3.0, 2.0]) * 0.01
    np.testing.assert_allclose(motion.positions[0, 2], base + [0, 0, 0.15], atol=1e-12)
    # frame 2: root turned 90 deg about the file's z: the spine (file +y) points along file -x
    np.testing.assert_allclose(motion.positions[1, 1], base + [-0.10, 0, 0], atol=1e-12)
    np.testing.assert_allclose(motion.positions[1, 2], base + [-0.15, 0, 0], atol=1e-12)
    assert mocap.read_bvh(tmp_path / "t.bvh", 1.0, fps=30.0).fps == 30.0


@pytest.mark.parametrize("edit, line, message", [
    (lambda ls: ls[:-1], 19, "header says 2 frames, file has 1"),  # truncated
    (lambda ls: ls[:-1] + ["1 2 3 90 0 0 0 0"], 20, "has 8 values, the hierarchy has 9"),
    (lambda ls: ls[:-1] + ["1 2 3 90 0 0 0 0 nan9"], 20, "not a number"),
    (lambda ls: [ln.replace("CHANNELS 3 Xrotation", "CHANNELS 2 Xrotation") for ln in ls], 9, "says 2 but lists 3"),
    (lambda ls: [ln.replace("JOINT spine", "JUNK spine") for ln in ls], 6, "unexpected 'JUNK'"),
])
def test_bvh_errors_name_file_and_line(tmp_path, edit, line, message):
    path = _write(tmp_path / "broken.bvh", edit(BVH.splitlines()))
    with pytest.raises(ValueError, match=rf"broken\.bvh:{line}: .*{message}"):
        mocap.read_bvh(path, 1.0)


def test_unknown_rig_has_no_mapping(tmp_path):
    motion = mocap.read_bvh(_write(tmp_path / "t.bvh", BVH.splitlines()), 0.01)
    assert motion.rig == "unknown"
    with pytest.raises(ValueError, match="unknown rig"):
        mocap.motion_joint_positions(motion, STRUCTRI17)


def test_procedural_motion_anatomy():
    motion = mocap.procedural_motion(seed=4, num_frames=200)
    lengths = _bone_lengths(motion)
    np.testing.assert_allclose(lengths, lengths[:1].repeat(len(lengths), 0), atol=1e-9)
    _check_anatomy(motion)
    head = mocap.motion_joint_positions(motion, STRUCTRI17)[:, STRUCTRI17.index("head"), 2]
    assert np.all((1.5 < head) & (head < 2.0))

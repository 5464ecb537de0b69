"""Calibration formats: EasyMocap YAML, aniposelib TOML and the JSON writers round-trip, files written the way
those tools write them project like ``cv2.projectPoints``, ``load_calibration`` recognises every layout, and
malformed files fail with one line naming file, camera and key."""

import tomllib

import cv2
import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from geometry import (
    CALIBRATION_FORMATS,
    SHELF_IMAGE_SIZE,
    Calibration,
    CalibrationError,
    Camera,
    depth,
    load_anipose_calibration,
    load_calibration,
    load_easymocap_calibration,
    load_voxelpose_calibration,
    project_to_views,
    projection_matrix,
    save_4dassociation_calibration,
    save_anipose_calibration,
    save_calibration,
    save_easymocap_calibration,
    save_voxelpose_calibration,
)
from geometry import replace_file

IMAGE_SIZE = (1280.0, 720.0)
NAMES = ("01", "cam_2", "side-left", "back 3")


def seeded_rig(distortion: bool = True) -> Camera:
    """Four cameras about 4-6 m from the origin, looking at it roughly along their own z."""
    rng = np.random.default_rng(0)
    views = 4
    K = np.zeros((views, 3, 3))
    K[:, 0, 0], K[:, 1, 1] = rng.uniform(900.0, 1300.0, (2, views))
    K[:, 0, 2], K[:, 1, 2], K[:, 2, 2] = rng.uniform(600.0, 680.0, views), rng.uniform(330.0, 390.0, views), 1.0
    R = np.stack([cv2.Rodrigues(rng.normal(0.0, 0.3, 3))[0] for _ in range(views)])
    t = np.column_stack([rng.uniform(-0.3, 0.3, (views, 2)), rng.uniform(4.0, 6.0, views)])
    dist = rng.normal(0.0, [0.1, 0.05, 1e-3, 1e-3, 0.01], (views, 5)) * distortion
    return Camera.create(K, R, t, dist, IMAGE_SIZE)


def points_near_origin(count: int = 64) -> np.ndarray:
    return np.random.default_rng(1).uniform(-0.5, 0.5, (count, 3))


def one_line_error(call, match: str) -> CalibrationError:
    with pytest.raises(CalibrationError, match=match) as caught:
        call()
    assert "\n" not in str(caught.value)
    return caught.value


# --------------------------------------------------------------------------------------------
# Round trips


@pytest.mark.parametrize("format", CALIBRATION_FORMATS)
def test_round_trip(tmp_path, format):
    """EasyMocap and 4D Association keep every field bit for bit (OpenCV writes 17 digits, JSON repr); anipose goes
    through a Rodrigues vector and a translation in mm, VoxelPose through a camera centre in mm: 1e-14 there."""
    rig = seeded_rig(distortion=format != "4dassociation")
    target = tmp_path / {"easymocap": "rig", "anipose": "calibration.toml"}.get(format, "cal.json")
    save_calibration(target, Calibration(rig, NAMES), format, metres_per_unit=0.001)
    loaded = load_calibration(target, image_size=IMAGE_SIZE, metres_per_unit=0.001)
    assert loaded.names == (NAMES if format in ("easymocap", "anipose") else ("0", "1", "2", "3"))
    atol = 1e-14 if format in ("anipose", "voxelpose") else 0.0
    for field in Camera._fields:
        assert_allclose(getattr(loaded.rig, field), getattr(rig, field), rtol=0.0, atol=atol, err_msg=field)


def test_voxelpose_writer_inverts_rotations_rounded_like_the_published_files(tmp_path):
    """Published R are orthonormal to 6 digits: the centre must be -R^-1 t for the loader's t = -R T to give t back
    (-R^T t gives it back to 4e-6 m here)."""
    rig = seeded_rig()
    rig = rig._replace(R=np.round(np.asarray(rig.R), 6))
    save_voxelpose_calibration(tmp_path / "cal.json", rig)
    assert_allclose(load_voxelpose_calibration(tmp_path / "cal.json", image_size=IMAGE_SIZE).t, rig.t,
                    rtol=0.0, atol=1e-14)


def test_names_survive_both_text_formats(tmp_path):
    easymocap = ("-1", "1e5", "True", "left cam")  # OpenCV quotes the first two, reads the others as strings
    save_easymocap_calibration(tmp_path, Calibration(seeded_rig(), easymocap))
    assert load_easymocap_calibration(tmp_path).names == easymocap
    anipose = ('say "hi"', "back\\slash", "tab\there", "caméra\x7f")
    save_anipose_calibration(tmp_path / "calibration.toml", Calibration(seeded_rig(), anipose))
    assert load_anipose_calibration(tmp_path).names == anipose


def test_saving_replaces_files_and_leaves_nothing_else(tmp_path):
    calibration = Calibration(seeded_rig(), NAMES)
    save_easymocap_calibration(tmp_path, calibration)
    save_easymocap_calibration(tmp_path, Calibration(seeded_rig(distortion=False), NAMES))
    save_anipose_calibration(tmp_path / "calibration.toml", calibration)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["calibration.toml", "extri.yml", "intri.yml"]
    assert_array_equal(load_easymocap_calibration(tmp_path).rig.dist, 0.0)


def test_failed_write_keeps_the_old_file(tmp_path):
    target = tmp_path / "cal.json"
    target.write_text("old")

    def write_half(temporary):
        temporary.write_text("half")
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        replace_file(target, write_half)
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["cal.json"]


# --------------------------------------------------------------------------------------------
# Files as EasyMocap and aniposelib write them, against cv2.projectPoints

# EasyMocap's FileStorage writer: 6 decimals, two-space indents, CRLF line ends (added when written below).
# Camera 01 has only the Rodrigues vector; camera 02 also Rot_ (exactly 90 degrees about x, which R_ rounds).
INTRI = """%YAML:1.0
---
names:
  - "01"
  - "02"
K_01: !!opencv-matrix
  rows: 3
  cols: 3
  dt: d
  data: [1150.423212, 0.000000, 640.118302, 0.000000, 1148.902270, 362.471900, 0.000000, 0.000000, 1.000000]
dist_01: !!opencv-matrix
  rows: 1
  cols: 5
  dt: d
  data: [-0.212345, 0.083112, 0.000512, -0.000734, -0.012001]
H_01: 720
W_01: 1280
K_02: !!opencv-matrix
  rows: 3
  cols: 3
  dt: d
  data: [1921.500000, 0.000000, 959.500000, 0.000000, 1918.250000, 539.500000, 0.000000, 0.000000, 1.000000]
dist_02: !!opencv-matrix
  rows: 5
  cols: 1
  dt: d
  data: [0.051000, -0.020000, -0.001200, 0.000900, 0.003000]
H_02: 1080
W_02: 1920
"""

EXTRI = """%YAML:1.0
---
names:
  - "01"
  - "02"
R_01: !!opencv-matrix
  rows: 3
  cols: 1
  dt: d
  data: [0.103210, -0.214502, 0.051230]
T_01: !!opencv-matrix
  rows: 3
  cols: 1
  dt: d
  data: [0.102000, -0.203000, 4.012000]
R_02: !!opencv-matrix
  rows: 3
  cols: 1
  dt: d
  data: [1.570796, 0.000000, 0.000000]
Rot_02: !!opencv-matrix
  rows: 3
  cols: 3
  dt: d
  data: [1.000000, 0.000000, 0.000000, 0.000000, 0.000000, -1.000000, 0.000000, 1.000000, 0.000000]
T_02: !!opencv-matrix
  rows: 3
  cols: 1
  dt: d
  data: [0.050000, 1.000000, 4.500000]
"""

# aniposelib's dump (the toml package's layout), translation in millimetres.
ANIPOSE = """[cam_0]
name = "A"
size = [ 1280, 1024,]
matrix = [ [ 1325.2452, 0.0, 639.5,], [ 0.0, 1321.8817, 511.5,], [ 0.0, 0.0, 1.0,],]
distortions = [ -0.2193, 0.117, 0.0013, -0.0021, 0.0,]
rotation = [ 0.05, -0.12, 0.02,]
translation = [ 120.5, -80.25, 3500.0,]

[cam_1]
name = "B"
size = [ 1280, 1024,]
matrix = [ [ 1290.75, 0.0, 645.25,], [ 0.0, 1290.75, 505.0,], [ 0.0, 0.0, 1.0,],]
distortions = [ 0.0412, -0.0105, 0.0, 0.0, 0.0031,]
rotation = [ 0.03, 0.6, -0.01,]
translation = [ -400.0, 50.0, 3800.0,]

[metadata]
adjusted = false
error = 0.5312
"""


def write_easymocap(folder, intri: str = INTRI, extri: str = EXTRI) -> None:
    for name, text in (("intri.yml", intri), ("extri.yml", extri)):
        (folder / name).write_bytes(text.replace("\n", "\r\n").encode())


def test_easymocap_files_project_like_opencv(tmp_path):
    write_easymocap(tmp_path)
    calibration = load_easymocap_calibration(tmp_path)
    assert calibration.names == ("01", "02")
    assert_array_equal(calibration.rig.image_size, [[1280.0, 720.0], [1920.0, 1080.0]])
    points = points_near_origin()
    ours = np.asarray(project_to_views(calibration.rig, points))
    intri = cv2.FileStorage(str(tmp_path / "intri.yml"), cv2.FILE_STORAGE_READ)
    extri = cv2.FileStorage(str(tmp_path / "extri.yml"), cv2.FILE_STORAGE_READ)
    for view, name in enumerate(("01", "02")):
        # The file's rotation as EasyMocap's newer reader takes it: Rot_ when present, else R_.
        rotation = extri.getNode(f"Rot_{name}")
        rvec = extri.getNode(f"R_{name}").mat() if rotation.empty() else cv2.Rodrigues(rotation.mat())[0]
        reference, _ = cv2.projectPoints(points, rvec, extri.getNode(f"T_{name}").mat(),
                                         intri.getNode(f"K_{name}").mat(), intri.getNode(f"dist_{name}").mat())
        assert_allclose(ours[view], reference[:, 0], rtol=0.0, atol=1e-6)


def test_anipose_file_projects_like_opencv(tmp_path):
    (tmp_path / "calibration.toml").write_text(ANIPOSE)
    calibration = load_anipose_calibration(tmp_path, metres_per_unit=0.001)
    assert calibration.names == ("A", "B")
    assert_array_equal(calibration.rig.image_size, [[1280.0, 1024.0]] * 2)
    points = points_near_origin()
    ours = np.asarray(project_to_views(calibration.rig, points))
    for view, section in enumerate(tomllib.loads(ANIPOSE)[f"cam_{i}"] for i in range(2)):
        rvec, tvec_mm = np.array(section["rotation"]), np.array(section["translation"])
        reference, _ = cv2.projectPoints(points * 1000.0, rvec, tvec_mm, np.array(section["matrix"]),
                                         np.array(section["distortions"]))
        assert_allclose(ours[view], reference[:, 0], rtol=0.0, atol=1e-6)


def test_short_distortion_lists_are_zero_padded(tmp_path):
    # Four coefficients (OpenCV's k3 = 0), and eight whose rational terms are zero under the older key D_.
    intri = INTRI.replace("cols: 5\n  dt: d\n  data: [-0.212345, 0.083112, 0.000512, -0.000734, -0.012001]",
                          "cols: 4\n  dt: d\n  data: [-0.212345, 0.083112, 0.000512, -0.000734]")
    intri = intri.replace("rows: 5\n  cols: 1\n  dt: d\n  data: [0.051000, -0.020000, -0.001200, 0.000900, 0.003000]",
                          "rows: 8\n  cols: 1\n  dt: d\n  data: [0.051, -0.02, -0.0012, 0.0009, 0.003, 0.0, 0.0, 0.0]")
    write_easymocap(tmp_path, intri.replace("dist_02", "D_02"))
    assert_array_equal(load_easymocap_calibration(tmp_path).rig.dist,
                       [[-0.212345, 0.083112, 0.000512, -0.000734, 0.0], [0.051, -0.02, -0.0012, 0.0009, 0.003]])
    (tmp_path / "calibration.toml").write_text(ANIPOSE.replace("[ -0.2193, 0.117, 0.0013, -0.0021, 0.0,]",
                                                               "[ -0.2193, 0.117,]"))
    assert_array_equal(load_anipose_calibration(tmp_path).rig.dist[0], [-0.2193, 0.117, 0.0, 0.0, 0.0])


def test_easymocap_without_image_size_takes_the_argument(tmp_path):
    # Older files have no H_, W_; EasyMocap writes -1 back for a size it read as unknown.
    write_easymocap(tmp_path, INTRI.replace("H_01: 720\nW_01: 1280\n", "").replace("H_02: 1080\nW_02: 1920\n",
                                                                                   "H_02: -1\nW_02: -1\n"))
    assert_array_equal(load_calibration(tmp_path, image_size=(640, 480)).rig.image_size, [[640.0, 480.0]] * 2)
    one_line_error(lambda: load_calibration(tmp_path),
                   r"intri\.yml: camera '01', key 'H_01': missing or -1 \(unknown\); pass image_size")


@pytest.mark.data
def test_shelf_converted_projects_alike(data_root, tmp_path):
    """Shelf's R are orthonormal to 6 digits only: EasyMocap keeps them (Rot_), anipose's Rodrigues vector can hold
    only the nearest rotation, which moves Shelf points by up to 1e-3 px (measured 5.5e-4 px)."""
    rig = load_voxelpose_calibration(data_root / "shelf" / "calibration_shelf.json", image_size=SHELF_IMAGE_SIZE)
    calibration = Calibration(rig, tuple(str(i) for i in range(5)))
    save_calibration(tmp_path / "easymocap", calibration, "easymocap")
    save_calibration(tmp_path / "anipose" / "calibration.toml", calibration, "anipose", metres_per_unit=0.001)
    # Points over the volume the Shelf actors move in (x -0.7..1.8 m, y -1.4..1.0 m, up to 1.7 m high).
    points = np.random.default_rng(2).uniform([-0.7, -1.4, 0.0], [1.8, 1.0, 1.8], (200, 3))
    assert all(float(np.min(depth(rig.select(view), points))) > 1.0 for view in range(5))
    expected = np.asarray(project_to_views(rig, points))
    for folder, tolerance in (("easymocap", 1e-6), ("anipose", 1e-3)):
        loaded = load_calibration(tmp_path / folder, metres_per_unit=0.001)
        assert loaded.names == calibration.names
        assert_array_equal(loaded.rig.image_size, rig.image_size)
        assert_allclose(project_to_views(loaded.rig, points), expected, rtol=0.0, atol=tolerance, err_msg=folder)


# --------------------------------------------------------------------------------------------
# Recognising the layout


def test_load_calibration_recognises_each_layout(tmp_path):
    rig = seeded_rig(distortion=False)
    save_easymocap_calibration(tmp_path / "easymocap", Calibration(rig, NAMES))
    save_anipose_calibration(tmp_path / "anipose" / "calibration.toml", Calibration(rig, NAMES))
    save_voxelpose_calibration(tmp_path / "voxelpose.json", rig)
    save_4dassociation_calibration(tmp_path / "4da.json", rig)
    (tmp_path / "tum").mkdir()
    for number, P in zip((1, 2, 3, 10), np.asarray(projection_matrix(rig))):
        (tmp_path / "tum" / f"P{number}.txt").write_text("\n".join(" ".join(f"{v:.17g}" for v in row) for row in P))
    points = points_near_origin()
    expected = np.asarray(project_to_views(rig, points))
    for path, names in (("easymocap", NAMES), ("anipose", NAMES), ("anipose/calibration.toml", NAMES),
                        ("voxelpose.json", ("0", "1", "2", "3")), ("4da.json", ("0", "1", "2", "3")),
                        ("tum", ("1", "2", "3", "10"))):
        loaded = load_calibration(tmp_path / path, image_size=IMAGE_SIZE)
        assert loaded.names == names, path
        assert_allclose(project_to_views(loaded.rig, points), expected, rtol=0.0, atol=1e-6, err_msg=path)
    for path, what in (("voxelpose.json", "a VoxelPose calibration"), ("tum", "a folder of TUM projection matrices")):
        one_line_error(lambda: load_calibration(tmp_path / path),
                       rf"{path}: {what} does not store the image size; pass image_size=\(width, height\)")


def test_load_calibration_refuses_what_it_does_not_recognise(tmp_path):
    (tmp_path / "empty").mkdir()
    error = one_line_error(lambda: load_calibration(tmp_path / "empty"), r"empty: not a calibration layout; expected")
    for layout in ("intri.yml and extri.yml", "calibration.toml", ".json", "P<i>.txt"):
        assert layout in str(error)
    one_line_error(lambda: load_calibration(tmp_path / "absent.toml2"), r"absent\.toml2: no such file or folder")
    (tmp_path / "other.json").write_text('{"0": {"focal": 1000}}')
    one_line_error(lambda: load_calibration(tmp_path / "other.json"), r"other\.json: camera '0' has neither 'fx'")
    write_easymocap(tmp_path / "empty")
    (tmp_path / "empty" / "calibration.toml").write_text(ANIPOSE)
    one_line_error(lambda: load_calibration(tmp_path / "empty"), r"several layouts \(EasyMocap, anipose\)")


# --------------------------------------------------------------------------------------------
# Malformed files: one line naming file, camera and key


@pytest.mark.parametrize(
    ("file", "old", "new", "message"),
    [
        ("intri", "K_02:", "KK_02:", r"intri\.yml: camera '02', key 'K_02': missing"),
        ("intri", "K_01: !!opencv-matrix\n  rows: 3\n  cols: 3\n  dt: d\n  data: [1150.423212, 0.000000, 640.118302, ",
         "K_01: !!opencv-matrix\n  rows: 3\n  cols: 1\n  dt: d\n  data: [1150.423212, 0.000000, 640.118302]\nX: [",
         r"intri\.yml: camera '01', key 'K_01': expected a 3x3 matrix, got 3x1"),
        ("intri", "K_02: !!opencv-matrix\n  rows: 3\n  cols: 3\n  dt: d\n  data:", "K_02:\n  data:",
         r"intri\.yml: camera '02', key 'K_02': expected an !!opencv-matrix"),
        ("intri", "[-0.212345, 0.083112, 0.000512, -0.000734, -0.012001]", "[-0.212345, 0.083112, .nan, 0.0, 0.0]",
         r"intri\.yml: camera '01', key 'dist_01': contains NaN or inf"),
        ("intri", "cols: 5\n  dt: d\n  data: [-0.212345, 0.083112, 0.000512, -0.000734, -0.012001]",
         "cols: 3\n  dt: d\n  data: [-0.212345, 0.083112, 0.000512]",
         r"intri\.yml: camera '01', key 'dist_01': expected at least 4 distortion coefficients, got 3"),
        ("intri", "rows: 5\n  cols: 1\n  dt: d\n  data: [0.051000, -0.020000, -0.001200, 0.000900, 0.003000]",
         "rows: 8\n  cols: 1\n  dt: d\n  data: [0.051, -0.02, -0.0012, 0.0009, 0.003, 0.1, 0.0, 0.0]",
         r"intri\.yml: camera '02', key 'dist_02': non-zero coefficients after k3"),
        ("intri", "W_01: 1280\n", "", r"intri\.yml: camera '01', key 'W_01': missing"),
        ("intri", "H_02: 1080", "H_02: tall", r"intri\.yml: camera '02', key 'H_02': expected a number"),
        ("intri", 'names:\n  - "01"\n  - "02"\n', "", r"intri\.yml: key 'names': missing"),
        ("intri", "  rows: 1\n  cols: 5", "  rows: 1\n cols: 5",
         r"intri\.yml:13: invalid OpenCV YAML: Incorrect indentation"),
        ("extri", "[0.102000, -0.203000, 4.012000]", "[0.102000, -0.203000, .inf]",
         r"extri\.yml: camera '01', key 'T_01': contains NaN or inf"),
        ("extri", "T_02: !!opencv-matrix\n  rows: 3\n  cols: 1\n  dt: d\n  data: [0.050000, 1.000000, 4.500000]",
         "T_02: !!opencv-matrix\n  rows: 2\n  cols: 1\n  dt: d\n  data: [0.050000, 1.000000]",
         r"extri\.yml: camera '02', key 'T_02': expected 3 values, got 2"),
        ("extri", "R_01:", "RR_01:", r"extri\.yml: camera '01', key 'R_01': missing \(nor is there Rot_01\)"),
        ("extri", "[1.000000, 0.000000, 0.000000, 0.000000, 0.000000, -1.000000",
         "[2.000000, 0.000000, 0.000000, 0.000000, 0.000000, -1.000000",
         r"extri\.yml: camera '02', key 'Rot_02': not a rotation matrix"),
        ("extri", "[1.570796, 0.000000, 0.000000]", "[1.470796, 0.000000, 0.000000]",
         r"extri\.yml: camera '02', key 'R_02': its rotation differs from Rot_02 by up to 0\.1"),
        ("extri", '  - "02"\n', '  - "03"\n', r"extri\.yml: key 'names': \['01', '03'\] differ from intri\.yml's"),
    ],
)
def test_easymocap_malformed(tmp_path, file, old, new, message):
    intri, extri = INTRI, EXTRI
    if file == "intri":
        assert intri.count(old) == 1
        intri = intri.replace(old, new)
    else:
        assert extri.count(old) == 1
        extri = extri.replace(old, new)
    write_easymocap(tmp_path, intri, extri)
    one_line_error(lambda: load_easymocap_calibration(tmp_path), message)


def test_easymocap_missing_or_empty_file(tmp_path):
    write_easymocap(tmp_path)
    (tmp_path / "extri.yml").unlink()
    one_line_error(lambda: load_easymocap_calibration(tmp_path), r"extri\.yml: cannot read calibration file")
    (tmp_path / "intri.yml").write_text("")
    one_line_error(lambda: load_easymocap_calibration(tmp_path), r"intri\.yml: not an OpenCV FileStorage YAML file")


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ('name = "A"\n', 'name = "A\n', r"calibration\.toml:2:10: invalid TOML: Illegal character"),
        ("error = 0.5312\n", "error = [\n",
         r"calibration\.toml:19: invalid TOML: Invalid value \(at end of document\)"),
        ('name = "B"\n', "", r"calibration\.toml: camera 'cam_1', key 'name': missing"),
        ('name = "B"\n', "name = 2\n", r"calibration\.toml: camera 'cam_1', key 'name': expected a string, got 2"),
        ("[ [ 1290.75, 0.0, 645.25,], [ 0.0, 1290.75, 505.0,], [ 0.0, 0.0, 1.0,],]",
         "[ [ 1290.75, 0.0, 645.25,], [ 0.0, 1290.75, 505.0,],]",
         r"calibration\.toml: camera 'cam_1', key 'matrix': expected 9 values"),
        ("[ 120.5, -80.25, 3500.0,]", "[ 120.5, nan, 3500.0,]",
         r"calibration\.toml: camera 'cam_0', key 'translation': contains NaN or inf"),
        ("rotation = [ 0.03, 0.6, -0.01,]\n", "", r"calibration\.toml: camera 'cam_1', key 'rotation': missing"),
        ("[ -0.2193, 0.117, 0.0013, -0.0021, 0.0,]", "[ -0.2193, 0.117, 0.0013, -0.0021, 0.0, 0.1,]",
         r"calibration\.toml: camera 'cam_0', key 'distortions': non-zero coefficients after k3"),
        ('name = "A"\n', 'name = "A"\nfisheye = true\n', r"calibration\.toml: camera 'cam_0', key 'fisheye'"),
        ("[cam_1]", "[camera_1]", r"calibration\.toml: expected tables \[cam_0\]\.\.\[cam_1\]"),
        ('name = "B"', 'name = "A"', r"calibration\.toml: key 'name': camera names repeat"),
    ],
)
def test_anipose_malformed(tmp_path, old, new, message):
    assert ANIPOSE.count(old) == 1
    (tmp_path / "calibration.toml").write_text(ANIPOSE.replace(old, new))
    one_line_error(lambda: load_anipose_calibration(tmp_path), message)


def test_anipose_missing_file(tmp_path):
    one_line_error(lambda: load_anipose_calibration(tmp_path), r"calibration\.toml: cannot read calibration file")


def test_writers_refuse_what_the_format_cannot_hold(tmp_path):
    rig = seeded_rig()
    one_line_error(lambda: save_4dassociation_calibration(tmp_path / "4da.json", rig),
                   r"4da\.json: camera '0': 4D Association calibrations have no distortion")
    skewed = rig._replace(K=rig.K.at[2, 0, 1].set(0.5))
    one_line_error(lambda: save_voxelpose_calibration(tmp_path / "vp.json", skewed),
                   r"vp\.json: camera '2': VoxelPose stores fx, fy, cx, cy only")
    one_line_error(lambda: save_easymocap_calibration(tmp_path, Calibration(rig, ("a", "b", "c.d", "e"))),
                   r"camera 'c\.d': an EasyMocap camera name becomes part of OpenCV keys")
    one_line_error(lambda: save_easymocap_calibration(tmp_path, Calibration(rig, ("a", "b", "true", "e"))),
                   r"camera 'true': an EasyMocap camera name")
    with pytest.raises(ValueError, match="expected 4 distinct camera names"):
        save_anipose_calibration(tmp_path / "calibration.toml", Calibration(rig, ("a", "b", "a", "c")))
    with pytest.raises(ValueError, match="unknown calibration format 'colmap'"):
        save_calibration(tmp_path, Calibration(rig, NAMES), "colmap")
    with pytest.raises(ValueError, match="metres_per_unit must be a positive number"):
        load_anipose_calibration(tmp_path, metres_per_unit=0.0)
    assert list(tmp_path.iterdir()) == []

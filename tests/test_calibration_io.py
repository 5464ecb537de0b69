"""Calibration loaders: the three Shelf formats and the two Campus formats agree; bad files fail loudly."""

import json

import numpy as np
import pytest
import scipy.io
from numpy.testing import assert_allclose

from geometry import (
    CAMPUS_IMAGE_SIZE,
    SHELF_IMAGE_SIZE,
    CalibrationError,
    Camera,
    camera_centre,
    depth,
    load_4dassociation_calibration,
    load_projection_matrices,
    load_voxelpose_calibration,
    project,
    project_to_views,
    projection_matrix,
)


def reprojection_gap(rig_a: Camera, rig_b: Camera, points: np.ndarray) -> np.ndarray:
    """Per-view largest pixel distance between the two rigs' projections of the points."""
    gap = np.linalg.norm(np.asarray(project_to_views(rig_a, points) - project_to_views(rig_b, points)), axis=-1)
    return gap.max(axis=-1)


@pytest.fixture(scope="module")
def shelf_gt_points(data_root) -> np.ndarray:
    """Every annotated ground-truth joint of the Shelf test frames 300..600 (metres)."""
    actors = scipy.io.loadmat(data_root / "shelf" / "actorsGT.mat")["actor3D"]
    per_actor = np.array(np.array(actors.tolist()).tolist(), dtype=object).squeeze()
    points = [per_actor[a][f] for a in range(4) for f in range(300, 601) if per_actor[a][f].size]
    return np.concatenate(points).astype(np.float64)


def test_shelf_formats_agree(data_root, shelf_gt_points):
    shelf = data_root / "shelf"
    voxelpose = load_voxelpose_calibration(shelf / "calibration_shelf.json", image_size=SHELF_IMAGE_SIZE)
    fourd = load_4dassociation_calibration(shelf / "4d_association" / "calibration.json")
    tum = load_projection_matrices(shelf / "Calibration", image_size=SHELF_IMAGE_SIZE)
    assert voxelpose.num_views == fourd.num_views == tum.num_views == 5
    for rig in (voxelpose, fourd, tum):
        assert_allclose(rig.image_size, np.tile([1032.0, 776.0], (5, 1)))
        assert_allclose(np.linalg.det(np.asarray(rig.R)), 1.0, atol=1e-4)
    # Measured: VoxelPose vs 4DA <= 0.0019 px. The P*.txt files keep 5 significant digits, which
    # alone moves camera 0's projections by up to 0.060 px (median 0.027 px) over the GT joints;
    # the full-precision P in Camera0.cal agrees to 0.002 px.
    assert reprojection_gap(voxelpose, fourd, shelf_gt_points).max() < 0.005
    tum_gap = reprojection_gap(voxelpose, tum, shelf_gt_points)
    assert tum_gap.max() < 0.065
    assert tum_gap.min() < 0.015
    assert reprojection_gap(fourd, tum, shelf_gt_points).max() < 0.065
    # Decomposition is exact: our K[R|t] reproduces the file's P up to scale.
    P_file = np.loadtxt(shelf / "Calibration" / "P0.txt", delimiter=",")
    P_ours = np.asarray(projection_matrix(tum.select(0)))
    assert_allclose(P_ours / P_ours[2, 3], P_file / P_file[2, 3], rtol=1e-10, atol=1e-12)


def test_shelf_gt_is_in_front_of_every_camera(data_root, shelf_gt_points):
    rig = load_voxelpose_calibration(data_root / "shelf" / "calibration_shelf.json", image_size=SHELF_IMAGE_SIZE)
    for view in range(rig.num_views):
        assert float(np.min(depth(rig.select(view), shelf_gt_points))) > 1.0


def test_campus_formats_agree(data_root):
    campus = data_root / "campus"
    voxelpose = load_voxelpose_calibration(campus / "calibration_campus.json", image_size=CAMPUS_IMAGE_SIZE)
    tum = load_projection_matrices(campus / "Calibration", image_size=CAMPUS_IMAGE_SIZE)
    assert voxelpose.num_views == tum.num_views == 3
    # VoxelPose's Campus space: centre (3, 4.5, 1) m, size 12 x 12 x 2 m; keep points every view sees.
    axes = np.linspace(-3.0, 9.0, 13), np.linspace(-1.5, 10.5, 13), np.linspace(0.0, 2.0, 5)
    grid = np.stack(np.meshgrid(*axes), axis=-1).reshape(-1, 3)
    pixels = np.asarray(project_to_views(voxelpose, grid))
    in_image = np.all((pixels > 0) & (pixels < np.array(CAMPUS_IMAGE_SIZE)), axis=(0, -1))
    in_front = np.all([np.asarray(depth(voxelpose.select(v), grid)) > 0 for v in range(3)], axis=0)
    visible = grid[in_image & in_front]
    assert len(visible) > 100
    assert reprojection_gap(voxelpose, tum, visible).max() < 0.03  # measured 0.013 px


def write_json(path, data) -> None:
    path.write_text(json.dumps(data, indent=2))


def voxelpose_entry(k=(0.0, 0.0, 0.0), p=(0.0, 0.0)) -> dict:
    angle = 0.3
    R = [[np.cos(angle), 0.0, np.sin(angle)], [0.0, 1.0, 0.0], [-np.sin(angle), 0.0, np.cos(angle)]]
    return {"R": R, "T": [[100.0], [-2000.0], [1500.0]], "fx": 1000.0, "fy": 990.0, "cx": 500.0, "cy": 380.0,
            "k": [[v] for v in k], "p": [[v] for v in p]}


def voxelpose_reference_projection(entry: dict, points_mm: np.ndarray) -> np.ndarray:
    """VoxelPose's ``project_point_radial`` (Human3.6M convention), transcribed."""
    R, T = np.array(entry["R"]), np.array(entry["T"])
    k, p = np.array(entry["k"]), np.array(entry["p"]).ravel()
    xcam = R @ (points_mm.T - T)
    y = xcam[:2] / xcam[2]
    r2 = np.sum(y**2, axis=0)
    radial = 1 + np.einsum("ij,ij->j", np.tile(k, (1, len(points_mm))), np.array([r2, r2**2, r2**3]))
    tan = p[0] * y[1] + p[1] * y[0]
    y = y * (radial + 2 * tan)[None, :] + np.outer(np.array([p[1], p[0]]), r2)
    f = np.array([[entry["fx"]], [entry["fy"]]])
    c = np.array([[entry["cx"]], [entry["cy"]]])
    return (f * y + c).T


def test_voxelpose_units_and_distortion_order(tmp_path):
    entry = voxelpose_entry(k=(-0.25, 0.08, 0.01), p=(2e-3, -1e-3))
    write_json(tmp_path / "cal.json", {"0": entry, "1": voxelpose_entry()})
    rig = load_voxelpose_calibration(tmp_path / "cal.json", image_size=(1000, 760))
    assert_allclose(camera_centre(rig)[0], [0.1, -2.0, 1.5], atol=1e-12)
    assert_allclose(rig.dist[0], [-0.25, 0.08, 2e-3, -1e-3, 0.01])
    rng = np.random.default_rng(0)
    points_m = np.array([0.1, -2.0, 1.5]) + (np.asarray(rig.R[0]).T @ np.array([0.0, 0.0, 3.0])) \
        + rng.uniform(-0.8, 0.8, (50, 3))
    assert_allclose(project(rig.select(0), points_m), voxelpose_reference_projection(entry, points_m * 1000.0),
                    atol=1e-6)


def test_4dassociation_fields(tmp_path):
    K = [800.0, 0.0, 400.0, 0.0, 810.0, 300.0, 0.0, 0.0, 1.0]
    RT = [0.0, -1.0, 0.0, 0.5, 0.0, 0.0, -1.0, 1.0, 1.0, 0.0, 0.0, 3.0]
    write_json(tmp_path / "cal.json", {"0": {"K": K, "RT": RT, "imgSize": [800, 600]}})
    rig = load_4dassociation_calibration(tmp_path / "cal.json")
    assert_allclose(rig.K[0], np.reshape(K, (3, 3)))
    assert_allclose(rig.R[0], np.reshape(RT, (3, 4))[:, :3])
    assert_allclose(rig.t[0], [0.5, 1.0, 3.0])
    assert_allclose(rig.image_size[0], [800.0, 600.0])
    assert_allclose(rig.dist, 0.0)


def test_projection_files_order_and_separators(tmp_path):
    rig = [Camera.create(np.array([[900.0 + 10 * i, 0.0, 400.0], [0.0, 900.0, 300.0], [0.0, 0.0, 1.0]]),
                         np.eye(3), np.array([0.1 * i, 0.0, 4.0])) for i in range(11)]
    for i, camera in enumerate(rig):
        P = -2.5 * np.asarray(projection_matrix(camera))  # the scale and sign of P are free
        separator = "," if i % 2 else " "
        (tmp_path / f"P{i}.txt").write_text("\n".join(separator.join(f"{v:.17g}" for v in row) for row in P) + "\n\n")
    loaded = load_projection_matrices(tmp_path, image_size=(800, 600))
    assert loaded.num_views == 11
    for i, camera in enumerate(rig):  # P10 comes after P9, not after P1
        assert_allclose(loaded.K[i], camera.K, rtol=1e-12)
        assert_allclose(loaded.t[i], camera.t, atol=1e-12)
    subset = load_projection_matrices([tmp_path / "P3.txt", tmp_path / "P1.txt"], image_size=(800, 600))
    assert_allclose(subset.t[:, 0], [0.3, 0.1], atol=1e-12)


@pytest.mark.parametrize(
    ("mutate", "message"),
    [
        (lambda d: d["1"].pop("fx"), r"cal\.json: camera '1', key 'fx': missing"),
        (lambda d: d["0"].update(R=[[1.0, 0.0], [0.0, 1.0]]), r"cal\.json: camera '0', key 'R': expected 9 values"),
        (lambda d: d["0"].update(R=[[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 1.0]]),
         r"cal\.json: camera '0', key 'R': not a rotation"),
        (lambda d: d["1"].update(k=[[0.1], [0.2]]), r"camera '1', key 'k': expected 3 values"),
        (lambda d: d["0"].update(cx="centre"), r"camera '0', key 'cx': not an array of numbers"),
        (lambda d: d["0"].update(fy=float("nan")), r"camera '0', key 'fy': contains NaN"),
        (lambda d: d.update({"3": d["1"]}), r"cal\.json: camera keys must be '0'..'2'"),
    ],
)
def test_voxelpose_malformed(tmp_path, mutate, message):
    data = {"0": voxelpose_entry(), "1": voxelpose_entry()}
    mutate(data)
    write_json(tmp_path / "cal.json", data)
    with pytest.raises(CalibrationError, match=message):
        load_voxelpose_calibration(tmp_path / "cal.json", image_size=(1000, 760))


def test_json_syntax_error_names_line(tmp_path):
    (tmp_path / "cal.json").write_text('{\n  "0": {\n    "K": [1, 2,, 3]\n  }\n}\n')
    with pytest.raises(CalibrationError, match=r"cal\.json:3:\d+: invalid JSON"):
        load_4dassociation_calibration(tmp_path / "cal.json")
    with pytest.raises(CalibrationError, match=r"missing\.json: cannot read"):
        load_4dassociation_calibration(tmp_path / "missing.json")


def test_4dassociation_malformed(tmp_path):
    entry = {"K": [800.0, 0, 400, 0, 810, 300, 0, 0, 1], "RT": [1.0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1], "imgSize": [8, 6]}
    write_json(tmp_path / "cal.json", {"0": entry})
    with pytest.raises(CalibrationError, match=r"cal\.json: camera '0', key 'RT': expected 12 values"):
        load_4dassociation_calibration(tmp_path / "cal.json")


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("1 0 0 0\n0 1 0 0\n0 0 1\n", r"P0\.txt:3: expected 4 finite numbers"),
        ("1,0,0,0\n0,one,0,0\n0,0,1,0\n", r"P0\.txt:2: not numbers"),
        ("1 0 0 0\n0 1 0 0\n", r"P0\.txt:2: expected 3 rows"),
        ("1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n", r"P0\.txt:4: a 3x4 projection matrix has 3 rows"),
        ("1 0 0 0\n0 1 0 0\n0 0 0 1\n", r"P0\.txt: the left 3x3 block of P is singular"),
    ],
)
def test_projection_file_malformed(tmp_path, text, message):
    (tmp_path / "P0.txt").write_text(text)
    with pytest.raises(CalibrationError, match=message):
        load_projection_matrices(tmp_path, image_size=(100, 100))


def test_projection_folder_without_files(tmp_path):
    with pytest.raises(CalibrationError, match="no projection matrix files"):
        load_projection_matrices(tmp_path, image_size=(100, 100))

"""Shelf / Campus loaders: the real files (``data_root``) and generated 4D-association fixtures."""

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import geometry
import mocap
from geometry import BODY25, SHELF14
from mocap import BODY25_PAF_PAIRS

ASSETS = Path(mocap.__file__).resolve().parent / "assets" / "calibration"


# ---------------------------------------------------------------------------------------------
# Writers for the 4DA text formats (test fixtures; the same layout 4DA's serialiser produces)


def _write_skeletons(path: Path, frames: list[list[tuple[int, np.ndarray]]], num_joints: int) -> None:
    lines = [f"{num_joints}\t{len(frames)}"]
    for persons in frames:
        lines.append(str(len(persons)))
        for person_id, matrix in persons:
            lines.append(str(person_id))
            lines += [" ".join(f"{v:.9g}" for v in row) for row in matrix]
    path.write_text("\n".join(lines) + "\n")


def _write_detections(path: Path, frames: list[tuple[list[np.ndarray], list[np.ndarray]]]) -> None:
    """``frames[f] = (joints, pafs)``: 25 arrays (3, n) normalised x, y, score; 26 (n_a, n_b)."""
    lines = [f"4\t{len(frames)}"]
    for joints, pafs in frames:
        for block in joints:
            lines.append(str(block.shape[1]))
            lines += [" ".join(f"{v:.9g}" for v in row) for row in block]
        for paf in pafs:
            lines += [" ".join(f"{v:.9g}" for v in row) for row in paf]
    path.write_text("\n".join(lines) + "\n")


def _random_detection_frame(rng: np.random.Generator, counts: list[int]):
    joints = [np.vstack([rng.uniform(0, 1, (2, n)), rng.uniform(0.05, 1, (1, n))]) for n in counts]
    pafs = [rng.uniform(0, 1, (counts[a], counts[b])) for a, b in BODY25_PAF_PAIRS]
    return joints, pafs


# ---------------------------------------------------------------------------------------------
# Without the data folder


def test_test_frame_ranges():
    shelf, campus = mocap.shelf_test_frames(), mocap.campus_test_frames()
    assert (len(shelf), shelf[0], shelf[-1]) == (301, 300, 600)
    assert len(campus) == 222 and {350, 470, 650, 750} <= set(campus.tolist()) and 471 not in campus


@pytest.mark.parametrize(
    "rig_fn, name, views, size",
    [(mocap.shelf_cameras, "shelf/calibration_shelf.json", 5, (1032, 776)),
     (mocap.campus_cameras, "campus/calibration_campus.json", 3, (360, 288))],
)
def test_shipped_calibration(rig_fn, name, views, size):
    rig = rig_fn()
    assert rig.num_views == views
    assert rig.K.shape == (views, 3, 3) and rig.R.shape == (views, 3, 3) and rig.t.shape == (views, 3)
    assert rig.dist.shape == (views, 5) and np.all(np.asarray(rig.dist) == 0)
    np.testing.assert_array_equal(rig.image_size, np.broadcast_to(size, (views, 2)))
    # Independent reference: the table's format, x_cam = R (X_mm - T), read with the json module.
    table = json.loads((ASSETS / name).read_text())
    for v in range(views):
        R, t = np.asarray(rig.R[v]), np.asarray(rig.t[v])
        centre_mm = np.ravel(table[str(v)]["T"])
        np.testing.assert_allclose(R, table[str(v)]["R"], atol=1e-12)
        np.testing.assert_allclose(t, -np.asarray(table[str(v)]["R"]) @ centre_mm / 1000.0, atol=1e-12)
        # The stored R is rounded to 6 digits, so the centre comes back to ~1e-5 m only.
        np.testing.assert_allclose(-R.T @ t, centre_mm / 1000.0, atol=1e-5)
        np.testing.assert_allclose(np.asarray(rig.K[v])[[0, 1, 0, 1], [0, 1, 2, 2]],
                                   [table[str(v)][k] for k in ("fx", "fy", "cx", "cy")], atol=1e-12)


def test_missing_calibration_names_the_file(tmp_path):
    with pytest.raises(geometry.CalibrationError, match="calibration_shelf.json"):
        mocap.shelf_cameras(tmp_path)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    num_joints=st.integers(1, 20),
    persons_per_frame=st.lists(st.integers(0, 3), min_size=0, max_size=4),
    seed=st.integers(0, 2**32 - 1),
)
def test_skeletons_round_trip(tmp_path, num_joints, persons_per_frame, seed):
    rng = np.random.default_rng(seed)
    frames = []
    for n in persons_per_frame:
        persons = []
        for _ in range(n):
            m = np.vstack([rng.normal(size=(3, num_joints)), rng.integers(0, 2, (1, num_joints))])
            m[:3, m[3] == 0] = 0.0
            persons.append((int(rng.integers(0, 10)), m))
        frames.append(persons)
    path = tmp_path / "skel.txt"
    _write_skeletons(path, frames, num_joints)
    loaded = mocap.load_4dassoc_skeletons(path, num_joints=num_joints)
    assert len(loaded) == len(frames)
    for want, got in zip(frames, loaded):
        assert [p.person_id for p in got] == [pid for pid, _ in want]
        for (_, m), person in zip(want, got):
            assert person.joints.shape == (num_joints, 3) and person.active.dtype == bool
            np.testing.assert_allclose(person.joints, m[:3].T, rtol=1e-8)
            np.testing.assert_array_equal(person.active, m[3] > 0)


def test_detections_round_trip_with_empty_blocks(tmp_path):
    rng = np.random.default_rng(0)
    counts_per_frame = [
        [int(n) for n in rng.integers(0, 4, 25)],
        [0] * 25,  # no candidates at all: every PAF is 0 x 0
        [2 if j == 8 else 0 for j in range(25)],  # mid-hip only: PAF (1, 8) is 0 x 2, PAF (8, 9) is 2 x 0
    ]
    counts_per_frame[0][8] = 0  # a 0 x n PAF next to non-empty ones in the same frame
    frames = [_random_detection_frame(rng, c) for c in counts_per_frame]
    path = tmp_path / "0.txt"
    _write_detections(path, frames)
    width, height = 1032, 776
    loaded = mocap.load_4dassoc_detections(path, (width, height))
    assert len(loaded) == 3
    for (joints, pafs), det in zip(frames, loaded):
        assert det.num_joint_types == 25 and len(det.pafs) == 26 and det.person_ids is None
        for block, got in zip(joints, det.joints):
            assert got.shape == (block.shape[1], 3)
            np.testing.assert_allclose(got, (block * [[width - 1], [height - 1], [1]]).T, rtol=1e-8)
        for paf, got in zip(pafs, det.pafs):
            assert got.shape == paf.shape
            np.testing.assert_allclose(got, paf, rtol=1e-8)
    assert loaded[2].pafs[BODY25_PAF_PAIRS.index((1, 8))].shape == (0, 2)
    assert loaded[2].pafs[BODY25_PAF_PAIRS.index((8, 9))].shape == (2, 0)
    powered = mocap.load_4dassoc_detections(path, (width, height), paf_exponent=mocap.FOUR_D_ASSOCIATION_PAF_EXPONENT)
    for a, b in zip(loaded[0].pafs, powered[0].pafs):
        np.testing.assert_allclose(b, a**0.2, rtol=1e-12)


def _detection_lines(tmp_path) -> list[str]:
    _write_detections(tmp_path / "ok.txt", [_random_detection_frame(np.random.default_rng(1), [1] * 25)])
    return (tmp_path / "ok.txt").read_text().splitlines()


@pytest.mark.parametrize(
    "edit, line, message",
    [
        (lambda ls: ["7\t1"] + ls[1:], 1, "not BODY25"),
        (lambda ls: ls[:4] + ["abc"] + ls[5:], 5, "non-numeric value 'abc'"),  # line 5: joint 0's scores
        (lambda ls: ls[:4] + ["nan"] + ls[5:], 5, "non-finite"),
        (lambda ls: ls[:5] + ["-1"] + ls[6:], 6, "non-negative integer"),  # line 6: joint 1's count
        (lambda ls: ls[:-3], None, "file ends while reading"),  # truncated inside the PAF blocks
        (lambda ls: ls + ["0.5"], None, "unexpected data after"),
    ],
)
def test_malformed_detections_name_file_and_line(tmp_path, edit, line, message):
    lines = edit(_detection_lines(tmp_path))
    path = tmp_path / "broken_view.txt"
    path.write_text("\n".join(lines) + "\n")
    expected_line = len(lines) if line is None else line
    with pytest.raises(ValueError, match=rf"broken_view\.txt, line {expected_line}: .*{message}"):
        mocap.load_4dassoc_detections(path, (1032, 776))


@pytest.mark.parametrize(
    "text, line, message",
    [
        ("15 1\n1\n0\n" + "1 " * 45 + "\n" + "1 " * 14 + "\n", 5, "file ends while reading the 4x15 matrix"),
        ("15 1\n1\n-1\n", 3, "expected a non-negative integer for the id"),
        ("15 1\n1.5\n", 2, "expected a non-negative integer for the person count of frame 0, got '1.5'"),
        ("15\n", 1, "file ends while reading the header's frame count"),
        ("19 1\n0\n", 1, "header says 19 joints, expected 15"),
        ("15 1\n1\n0\n" + "1 " * 44 + "1e\n" + "1 " * 15 + "\n", 4, "non-numeric value '1e'"),
    ],
)
def test_malformed_skeletons_name_file_and_line(tmp_path, text, line, message):
    path = tmp_path / "bad_gt.txt"
    path.write_text(text)
    with pytest.raises(ValueError, match=rf"bad_gt\.txt, line {line}: {message}"):
        mocap.load_4dassoc_skeletons(path, num_joints=15)


def test_ground_truth_errors_name_file_and_key(tmp_path):
    import scipy.io

    (tmp_path / "shelf").mkdir()
    with pytest.raises(FileNotFoundError, match="actorsGT.mat"):
        mocap.load_shelf_ground_truth(tmp_path)
    cells = np.empty((1, 2), object)
    for p in range(2):
        cells[0, p] = np.empty((3, 1), object)
        for f in range(3):
            cells[0, p][f, 0] = np.zeros((1, 0))
    cells[0, 1][2, 0] = np.ones((13, 3))
    scipy.io.savemat(tmp_path / "shelf" / "actorsGT.mat", {"actor3D": cells})
    with pytest.raises(ValueError, match=r"actorsGT\.mat: key actor3D\{0,1\}\{2,0\} should be empty or a \(14, 3\)"):
        mocap.load_shelf_ground_truth(tmp_path)
    cells[0, 1][2, 0] = np.ones((14, 3))
    scipy.io.savemat(tmp_path / "shelf" / "actorsGT.mat", {"actor3D": cells})
    positions, annotated = mocap.load_shelf_ground_truth(tmp_path)
    assert positions.shape == (2, 3, 14, 3) and annotated.tolist() == [[False] * 3, [False, False, True]]
    assert positions.sum() == 42.0
    scipy.io.savemat(tmp_path / "shelf" / "actorsGT.mat", {"actor2D": cells})
    with pytest.raises(ValueError, match=r"actorsGT\.mat: no key 'actor3D'"):
        mocap.load_shelf_ground_truth(tmp_path)


# ---------------------------------------------------------------------------------------------
# The real data


@pytest.fixture(scope="module")
def shelf_gt(data_root):
    return mocap.load_shelf_ground_truth(data_root)


@pytest.fixture(scope="module")
def shelf_detections(data_root):
    return mocap.load_shelf_detections(data_root)


def test_shipped_calibration_is_the_data_copy(data_root):
    for name in ("shelf/calibration_shelf.json", "campus/calibration_campus.json"):
        assert (ASSETS / name).read_bytes() == (data_root / name).read_bytes()
    for a, b in zip(mocap.shelf_cameras(data_root), mocap.shelf_cameras()):
        np.testing.assert_array_equal(a, b)
    assert mocap.campus_cameras(data_root).num_views == 3


def test_shelf_ground_truth(shelf_gt):
    positions, annotated = shelf_gt
    assert positions.shape == (4, 3200, 14, 3) and annotated.shape == (4, 3200)
    assert np.all(np.isfinite(positions))
    assert annotated[:, 300:601].sum(axis=1).tolist() == [279, 37, 161, 33]
    assert np.all(positions[~annotated] == 0)
    assert np.all(np.abs(positions[annotated]).sum(axis=(1, 2)) > 0)
    heights = positions[annotated][:, 13, 2]  # head top, metres, z up
    assert 1.3 < np.median(heights) < 2.1


def test_gt_txt_agrees_with_actors_gt(data_root, shelf_gt):
    positions, annotated = shelf_gt
    frames = mocap.load_4dassoc_skeletons(data_root / "shelf/4d_association/gt.txt", num_joints=15)
    assert len(frames) == 301
    max_diff = 0.0
    for k, persons in enumerate(frames):
        f = 300 + k
        assert sorted(p.person_id for p in persons) == np.flatnonzero(annotated[:, f]).tolist()
        for p in persons:
            assert p.active.all()
            max_diff = max(max_diff, np.abs(p.joints[:14] - positions[p.person_id, f]).max())
            np.testing.assert_allclose(p.joints[14], p.joints[[2, 3]].mean(axis=0), atol=1e-5)
    assert max_diff < 1e-5


def test_skel_txt(data_root):
    frames = mocap.load_4dassoc_skeletons(data_root / "shelf/4d_association/skel.txt", num_joints=19)
    persons = [p for frame in frames for p in frame]
    assert len(frames) == 301 and len(persons) == 1019
    assert all(p.joints.shape == (19, 3) for p in persons)
    assert sum(not p.joints.any() and not p.active.any() for p in persons) == 135
    assert all(not p.joints[~p.active].any() for p in persons)


def test_shelf_detections_structure(shelf_detections):
    frames, gt_frames = shelf_detections
    assert len(frames) == 301 and all(len(f) == 5 for f in frames)
    np.testing.assert_array_equal(gt_frames, mocap.shelf_test_frames())
    for v in range(5):
        per_frame = [sum(len(c) for c in frame[v].joints) for frame in frames]
        assert 56 < np.mean(per_frame) < 62, (v, np.mean(per_frame))
    for frame in frames:
        for det in frame:
            for (a, b), paf in zip(BODY25_PAF_PAIRS, det.pafs):
                assert paf.shape == (len(det.joints[a]), len(det.joints[b]))
            xy = np.concatenate(det.joints)
            assert np.all((xy[:, 0] >= 0) & (xy[:, 0] <= 1031) & (xy[:, 1] >= 0) & (xy[:, 1] <= 775))
            # OpenPose heatmap peaks and PAF scores slightly exceed 1 (max 1.04 and 1.18 here).
            assert np.all((xy[:, 2] > 0.1) & (xy[:, 2] < 1.1))
            assert all(np.all((paf >= 0) & (paf < 1.25)) for paf in det.pafs)


def _median_reprojection_px(positions, annotated, padded, rig, shift: int) -> np.ndarray:
    """Per view: median distance from each projected GT limb joint to the nearest candidate of
    the same BODY25 joint type, detection frame k compared with GT frame 300 + k + shift."""
    shelf_idx = [i for i, name in enumerate(SHELF14.joints) if name in BODY25.joints]
    body25_idx = [BODY25.index(SHELF14.joints[i]) for i in shelf_idx]
    frames = np.arange(301)
    actor, k = np.nonzero(annotated[:, 300 + frames + shift])
    points = positions[actor, 300 + k + shift][:, shelf_idx]  # (instances, 12, 3)
    projected = np.asarray(geometry.project_to_views(rig, points))  # (views, instances, 12, 2)
    cand = padded.xy[k][:, :, body25_idx]  # (instances, views, 12, C, 2)
    dist = np.linalg.norm(cand - np.moveaxis(projected, 0, 1)[:, :, :, None], axis=-1)
    dist = np.where(padded.mask[k][:, :, body25_idx], dist, np.inf).min(axis=-1)  # (instances, views, 12)
    return np.array([np.median(d[np.isfinite(d)]) for d in np.moveaxis(dist, 1, 0)])


def test_detections_reproject_onto_ground_truth(shelf_gt, shelf_detections):
    positions, annotated = shelf_gt
    padded = mocap.pad_detections(shelf_detections[0])
    rig = mocap.shelf_cameras()
    aligned = _median_reprojection_px(positions, annotated, padded, rig, 0)
    assert np.all(aligned < 25), aligned  # the data README measured 11-21 px
    for shift in (-20, 20):
        shifted = _median_reprojection_px(positions, annotated, padded, rig, shift)
        assert np.all(shifted > 1.5 * aligned), (shift, aligned, shifted)


def test_paf_exponent_on_real_file(data_root, shelf_detections):
    path = data_root / "shelf/4d_association/detection/3.txt"
    powered = mocap.load_4dassoc_detections(path, geometry.SHELF_IMAGE_SIZE, paf_exponent=0.2)
    stored = [frame[3] for frame in shelf_detections[0]]
    for a, b in zip(stored[::50], powered[::50]):
        for pa, pb in zip(a.pafs, b.pafs):
            np.testing.assert_allclose(pb, pa**0.2, rtol=1e-12)

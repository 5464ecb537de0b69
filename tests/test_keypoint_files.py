"""OpenPose JSON and COCO keypoint results: reading literal files, writing and reading back, alignment, errors."""

import json

import jax
import numpy as np
import pytest

import mocap

# The detectors' documented joint orders, spelled out here rather than taken from the module under test.
BODY25 = ("nose", "neck", "r_shoulder", "r_elbow", "r_wrist", "l_shoulder", "l_elbow", "l_wrist", "mid_hip",
          "r_hip", "r_knee", "r_ankle", "l_hip", "l_knee", "l_ankle", "r_eye", "l_eye", "r_ear", "l_ear",
          "l_big_toe", "l_small_toe", "l_heel", "r_big_toe", "r_small_toe", "r_heel")
COCO18 = ("nose", "neck", "r_shoulder", "r_elbow", "r_wrist", "l_shoulder", "l_elbow", "l_wrist", "r_hip",
          "r_knee", "r_ankle", "l_hip", "l_knee", "l_ankle", "r_eye", "l_eye", "r_ear", "l_ear")
COCO17 = ("nose", "l_eye", "r_eye", "l_ear", "r_ear", "l_shoulder", "r_shoulder", "l_elbow", "r_elbow",
          "l_wrist", "r_wrist", "l_hip", "r_hip", "l_knee", "r_knee", "l_ankle", "r_ankle")
FEET = ("l_big_toe", "l_small_toe", "l_heel", "r_big_toe", "r_small_toe", "r_heel")
PAIR = {pair: k for k, pair in enumerate(mocap.BODY25_PAF_PAIRS)}


def _flat(order, keypoints):
    """A flat [x, y, c] * K list in ``order`` with the given {joint: (x, y, c)}, zeros elsewhere."""
    out = [0] * (3 * len(order))
    for name, xyc in keypoints.items():
        out[3 * order.index(name):3 * order.index(name) + 3] = xyc
    return out


def _openpose(folder, view, name, people, order=BODY25):
    path = folder / view / f"{name}_keypoints.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"version": 1.3, "people": [{"person_id": [-1], "pose_keypoints_2d": _flat(order, p)}
                                                          for p in people]}))
    return path


def _candidates(det, joint):
    """The candidates of a BODY25 joint type as a sorted list of (x, y, c) rows (a multiset)."""
    return sorted(map(tuple, det.joints[BODY25.index(joint)].tolist()))


def _assert_same_candidates(got, expected, joints=BODY25):
    assert len(got) == len(expected)
    for f, (got_frame, expected_frame) in enumerate(zip(got, expected)):
        assert len(got_frame) == len(expected_frame)
        for v, (a, b) in enumerate(zip(got_frame, expected_frame)):
            for joint in joints:
                rows = b.joints[BODY25.index(joint)]
                expected_rows = sorted(map(tuple, rows[rows[:, 2] != 0].tolist()))
                assert _candidates(a, joint) == expected_rows, (f, v, joint)


def test_the_module_orders_are_the_documented_ones():
    assert mocap.KEYPOINT_FORMAT_JOINTS == {"BODY25": BODY25, "COCO18": COCO18, "COCO17": COCO17}


def test_openpose_body25_files_read_to_their_candidates(tmp_path):
    a = {"nose": (10, 20, 0.9), "neck": (5, 5, 0.6), "mid_hip": (30, 40, 0.8), "l_heel": (1, 2, 0.5)}
    b = {"nose": (50, 60, 0.7), "mid_hip": (70, 80, 0.4), "r_hip": (7, 8, 0.0)}  # confidence 0: not detected
    _openpose(tmp_path, "cam0", "000000", [a, b])
    _openpose(tmp_path, "cam0", "000001", [])
    _openpose(tmp_path, "cam1", "000000", [b])
    _openpose(tmp_path, "cam1", "000001", [a])
    read = mocap.load_keypoint_detections(tmp_path)
    assert (read.views, read.frame_names, read.keypoint_format, read.dropped_frames) == (
        ("cam0", "cam1"), ("000000", "000001"), "BODY25", ())
    det = read.detections[0][0]
    assert det.person_ids is None and det.num_joint_types == 25
    assert _candidates(det, "nose") == [(10, 20, 0.9), (50, 60, 0.7)]
    assert _candidates(det, "mid_hip") == [(30, 40, 0.8), (70, 80, 0.4)]
    assert _candidates(det, "neck") == [(5, 5, 0.6)]
    assert _candidates(det, "l_heel") == [(1, 2, 0.5)]
    assert _candidates(det, "r_hip") == []
    # neck -> mid_hip: the neck is person a's, as is the first mid_hip candidate (person order)
    np.testing.assert_array_equal(det.pafs[PAIR[1, 8]], [[1.0, 0.0]])
    assert all(len(c) == 0 for c in read.detections[1][0].joints)
    assert _candidates(read.detections[1][1], "l_heel") == [(1, 2, 0.5)]
    for frame in read.detections:
        for det in frame:
            assert [p.shape for p in det.pafs] == [(len(det.joints[i]), len(det.joints[k])) for i, k in PAIR]


COCO18_FILE = """{"version":1.3,"people":[
{"person_id":[-1],"pose_keypoints_2d":[1,2,0.5, 3,4,0.6, 0,0,0, 0,0,0, 0,0,0, 0,0,0, 0,0,0, 0,0,0,
 10,20,0.8, 0,0,0, 0,0,0, 14,24,0.6, 0,0,0, 0,0,0, 0,0,0, 0,0,0, 5,6,0.3, 0,0,0],
 "face_keypoints_2d":[],"hand_left_keypoints_2d":[],"hand_right_keypoints_2d":[]},
{"person_id":[-1],"pose_keypoints_2d":[0,0,0, 0,0,0, 0,0,0, 0,0,0, 0,0,0, 0,0,0, 0,0,0, 0,0,0,
 100,200,0.7, 0,0,0, 0,0,0, 0,0,0, 0,0,0, 0,0,0, 0,0,0, 0,0,0, 0,0,0, 9,9,0.2]}
]}
"""


def test_openpose_coco18_files_are_reordered_and_get_a_mid_hip(tmp_path):
    (tmp_path / "cam0").mkdir()
    (tmp_path / "cam0" / "f_0_keypoints.json").write_text(COCO18_FILE)
    _openpose(tmp_path, "cam0", "f_1", [{"r_ankle": (1, 1, 0.1)}], COCO18)
    _openpose(tmp_path, "cam1", "f_0", [], COCO18)
    _openpose(tmp_path, "cam1", "f_1", [{"l_eye": (2, 3, 0.4), "r_hip": (0, 0, 0.5), "l_hip": (4, 6, 0.9)}], COCO18)
    read = mocap.load_keypoint_detections(tmp_path, views=("cam1", "cam0"))
    assert read.views == ("cam1", "cam0") and read.keypoint_format == "COCO18"
    det = read.detections[0][1]
    assert _candidates(det, "nose") == [(1, 2, 0.5)]
    assert _candidates(det, "neck") == [(3, 4, 0.6)]
    assert _candidates(det, "r_hip") == [(10, 20, 0.8), (100, 200, 0.7)]
    assert _candidates(det, "l_hip") == [(14, 24, 0.6)]
    assert _candidates(det, "mid_hip") == [(12, 22, 0.6)]  # only the first person has both hips
    assert _candidates(det, "r_ear") == [(5, 6, 0.3)]
    assert _candidates(det, "l_ear") == [(9, 9, 0.2)]
    assert all(_candidates(det, j) == [] for j in FEET)
    np.testing.assert_array_equal(det.pafs[PAIR[8, 9]], [[1.0, 0.0]])  # mid_hip -> r_hip: the same person
    assert _candidates(read.detections[0][0], "nose") == []
    assert _candidates(read.detections[1][1], "r_ankle") == [(1, 1, 0.1)]
    other = read.detections[1][0]
    assert _candidates(other, "l_eye") == [(2, 3, 0.4)]
    assert _candidates(other, "r_hip") == [(0, 0, 0.5)]  # at the image corner, but detected
    assert _candidates(other, "mid_hip") == [(2, 3, 0.5)]


def _coco_entry(image_id, keypoints, score=0.9):
    return {"image_id": image_id, "category_id": 1, "keypoints": _flat(COCO17, keypoints), "score": score}


def test_coco17_results_get_neck_and_mid_hip_where_both_sides_are_detected(tmp_path):
    full = {"l_shoulder": (10, 10, 0.9), "r_shoulder": (20, 10, 0.7), "l_hip": (10, 30, 0.5), "r_hip": (20, 30, 0.8),
            "l_ankle": (10, 50, 0.4)}
    no_left_shoulder = {"r_shoulder": (60, 10, 0.9), "l_hip": (50, 30, 0.6), "r_hip": (60, 30, 0.6), "nose": (55, 0, 1)}
    (tmp_path / "cam0.json").write_text(json.dumps(
        [_coco_entry(7, full), _coco_entry(3, no_left_shoulder), _coco_entry(7, no_left_shoulder)]))
    (tmp_path / "cam1.json").write_text(json.dumps(
        [_coco_entry("img_3.jpg", {"nose": (1, 2, 0.3)}), _coco_entry("img_7.jpg", {"l_eye": (3, 4, 0.2)})]))
    read = mocap.load_keypoint_detections(tmp_path, frames="name")
    assert read.views == ("cam0", "cam1") and read.frame_names == ("3", "7") and read.keypoint_format == "COCO17"
    det = read.detections[1][0]  # image 7 of cam0: both people
    assert _candidates(det, "neck") == [(15, 10, 0.7)]
    assert _candidates(det, "mid_hip") == [(15, 30, 0.5), (55, 30, 0.6)]
    assert _candidates(det, "r_shoulder") == [(20, 10, 0.7), (60, 10, 0.9)]
    assert _candidates(det, "l_ankle") == [(10, 50, 0.4)]
    assert all(_candidates(det, j) == [] for j in FEET)
    np.testing.assert_array_equal(det.pafs[PAIR[1, 2]], [[1.0, 0.0]])  # neck -> r_shoulder
    np.testing.assert_array_equal(det.pafs[PAIR[8, 12]], [[1.0, 0.0], [0.0, 1.0]])  # mid_hip -> l_hip
    first = read.detections[0][0]
    assert _candidates(first, "neck") == [] and _candidates(first, "mid_hip") == [(55, 30, 0.6)]
    assert _candidates(read.detections[0][1], "nose") == [(1, 2, 0.3)]
    assert _candidates(read.detections[1][1], "l_eye") == [(3, 4, 0.2)]


def test_alignment_by_name_keeps_the_frames_of_every_view(tmp_path):
    person = [{"nose": (1, 1, 0.5)}]
    for name in ("frame_1", "frame_2", "frame_10"):
        _openpose(tmp_path, "cam0", name, person)
    for name in ("frame_10", "frame_1"):
        _openpose(tmp_path, "cam1", name, person)
    read = mocap.load_keypoint_detections(tmp_path, frames="name")
    assert read.frame_names == ("frame_1", "frame_10") and read.dropped_frames == (2,)
    assert len(read.detections) == 2 and all(len(frame) == 2 for frame in read.detections)
    by_index = mocap.load_keypoint_detections(tmp_path, views=("cam0",))
    assert by_index.frame_names == ("frame_1", "frame_2", "frame_10")  # natural order, not text order


@pytest.fixture(scope="module")
def scene():
    return mocap.synthesise_scene(jax.random.key(0), mocap.shelf_cameras(), num_people=2, num_frames=3)


def test_synthetic_detections_survive_openpose_files(tmp_path, scene):
    views = ("a", "b", "c", "d", "e")
    mocap.write_openpose_keypoints(tmp_path, scene.detections, views)
    assert sorted(p.name for p in (tmp_path / "c").iterdir()) == [f"{f:06d}_keypoints.json" for f in range(3)]
    read = mocap.load_keypoint_detections(tmp_path, views=views)
    assert read.views == views and read.keypoint_format == "BODY25"
    _assert_same_candidates(read.detections, scene.detections)


def test_synthetic_detections_survive_coco_results(tmp_path, scene):
    views = ("a", "b", "c", "d", "e")
    mocap.write_coco_keypoints(tmp_path, scene.detections, views)
    read = mocap.load_keypoint_detections(tmp_path)
    assert read.views == views and read.keypoint_format == "COCO17"
    _assert_same_candidates(read.detections, scene.detections, COCO17)
    for frame in read.detections:
        for det in frame:
            assert all(_candidates(det, j) == [] for j in FEET)
            left, right = det.joints[BODY25.index("l_shoulder")], det.joints[BODY25.index("r_shoulder")]
            midpoints = (left[:, None, :2] + right[None, :, :2]) / 2  # every neck is some pair's midpoint
            for neck in det.joints[BODY25.index("neck")]:
                assert np.isclose(midpoints, neck[:2]).all(-1).any()


def _body25(candidates, person_ids=None):
    """Detections from {joint: [(x, y, c), ...]} with zero PAFs."""
    joints = tuple(np.asarray(candidates.get(j, []), float).reshape(-1, 3) for j in BODY25)
    pafs = tuple(np.zeros((len(joints[a]), len(joints[b]))) for a, b in mocap.BODY25_PAF_PAIRS)
    ids = None if person_ids is None else tuple(np.asarray(person_ids.get(j, []), int) for j in BODY25)
    return mocap.Detections(joints, pafs, ids)


def test_writers_pack_people_and_drop_zero_confidence(tmp_path):
    candidates = {"nose": [(1, 1, 0.5), (2, 2, 0.0), (3, 3, 0.6)], "neck": [(4, 4, 0.7)], "l_heel": [(5, 5, 0.1)]}
    det = _body25(candidates)
    mocap.write_openpose_keypoints(tmp_path, [[det]], ("v",))
    people = json.loads((tmp_path / "v" / "000000_keypoints.json").read_text())["people"]
    assert [p["pose_keypoints_2d"][:6] for p in people] == [[1, 1, 0.5, 4, 4, 0.7], [3, 3, 0.6, 0, 0, 0]]
    _assert_same_candidates(mocap.load_keypoint_detections(tmp_path).detections, [[det]])
    # grouped by person: the spurious (-1) and the second candidate of person 3 go to extra people
    ids = {"nose": [3, -1, 5, 3], "neck": [5, 3], "l_heel": [-1]}
    grouped = _body25({**candidates, "nose": candidates["nose"] + [(9, 9, 0.2)], "neck": [(4, 4, 0.7), (6, 6, 0.8)]},
                      ids)
    mocap.write_openpose_keypoints(tmp_path / "grouped", [[grouped]], ("v",))
    people = json.loads((tmp_path / "grouped" / "v" / "000000_keypoints.json").read_text())["people"]
    assert [(p["person_id"], p["pose_keypoints_2d"][:6]) for p in people] == [
        ([3], [1, 1, 0.5, 6, 6, 0.8]), ([5], [3, 3, 0.6, 4, 4, 0.7]), ([-1], [9, 9, 0.2, 0, 0, 0])]
    assert people[2]["pose_keypoints_2d"][3 * BODY25.index("l_heel"):][:3] == [5, 5, 0.1]
    _assert_same_candidates(mocap.load_keypoint_detections(tmp_path / "grouped").detections, [[grouped]])
    # COCO: a frame where a view has nobody keeps its place with one entry of zeros
    mocap.write_coco_keypoints(tmp_path / "coco", [[det, _body25({})], [det, det]], ("v", "w"))
    read = mocap.load_keypoint_detections(tmp_path / "coco")
    assert len(read.detections) == 2 and all(len(c) == 0 for c in read.detections[0][1].joints)
    _assert_same_candidates(read.detections, [[det, _body25({})], [det, det]], COCO17)
    assert not list(tmp_path.rglob("*.partial"))


@pytest.mark.data
def test_real_shelf_detections_survive_openpose_files(tmp_path, data_root):
    frames, _ = mocap.load_shelf_detections(data_root)
    views = tuple(str(v) for v in range(mocap.SHELF_NUM_VIEWS))
    mocap.write_openpose_keypoints(tmp_path, frames[:20], views)
    read = mocap.load_keypoint_detections(tmp_path, views=views)
    assert len(read.detections) == 20
    _assert_same_candidates(read.detections, frames[:20])
    # Lossless: the real files hold no candidate with confidence 0 (which a keypoint file could not carry).
    assert not any((c[:, 2] == 0).any() for frame in frames for det in frame for c in det.joints)


def _two_views(tmp_path):
    for view in ("cam0", "cam1"):
        for name in ("000000", "000001"):
            _openpose(tmp_path, view, name, [{"nose": (1, 2, 0.5)}])


def _raw(path, text):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def _bad_count(tmp_path):
    return _raw(tmp_path / "cam1" / "000001_keypoints.json",
                json.dumps({"people": [{"pose_keypoints_2d": [1, 2, 0.5] * 20}]})), {}, "person 0"


def _missing_view(tmp_path):
    return tmp_path / "cam2", {"views": ("cam0", "cam2")}, "cam2.json"


def _frame_counts(tmp_path):
    (tmp_path / "cam1" / "000001_keypoints.json").unlink()
    return tmp_path / "cam1", {}, "frames='name'"


def _format_given(tmp_path):
    return tmp_path / "cam0" / "000000_keypoints.json", {"keypoint_format": "COCO18"}, "BODY25"


def _formats_differ(tmp_path):
    path = _openpose(tmp_path, "cam1", "000000", [{"nose": (1, 2, 0.5)}], COCO18)
    return path, {}, "COCO18"


def _malformed(tmp_path):
    return _raw(tmp_path / "cam0" / "000001_keypoints.json",
                '{"version": 1.3,\n "people": [\n  {"pose_keypoints_2d": [1, 2,,]}]}'), {}, "line 3"


def _nan_confidence(tmp_path):
    values = _flat(BODY25, {"neck": (1, 2, 0.5)})
    text = json.dumps({"people": [{"pose_keypoints_2d": values}, {"pose_keypoints_2d": values[:5] + ["NAN"] + values[6:]}]})
    return _raw(tmp_path / "cam1" / "000000_keypoints.json", text.replace('"NAN"', "NaN")), {}, "person 1: keypoint 1 (neck)"


def _negative_confidence(tmp_path):
    path = _openpose(tmp_path, "cam0", "000001", [{"nose": (1, 2, 0.5), "l_ear": (1, 2, -0.1)}])
    return path, {}, "l_ear"


def _no_frames(tmp_path):
    for path in tmp_path.rglob("*.json"):
        path.unlink()
    return tmp_path, {}, "no frames"


def _coco_negative_score(tmp_path):
    entries = [_coco_entry(0, {"nose": (1, 2, 0.5)}), _coco_entry(1, {"r_hip": (1, 2, -1)})]
    return _raw(tmp_path / "coco" / "cam0.json", json.dumps(entries)), {"views": ("cam0",)}, "entry 1"


def _no_frame_number(tmp_path):
    path = _openpose(tmp_path, "cam0", "last", [])
    return path, {"frames": "name"}, "no frame number"


@pytest.mark.parametrize("case", [_missing_view, _frame_counts, _bad_count, _format_given, _formats_differ,
                                  _malformed, _nan_confidence, _negative_confidence, _no_frames,
                                  _coco_negative_score, _no_frame_number])
def test_errors_are_one_line_naming_the_file(tmp_path, case):
    _two_views(tmp_path)
    path, options, detail = case(tmp_path)
    root = path.parent if case is _coco_negative_score else tmp_path
    with pytest.raises(mocap.DetectionFileError) as err:
        mocap.load_keypoint_detections(root, **options)
    message = str(err.value)
    assert "\n" not in message and str(path) in message and detail in message, message
    assert isinstance(err.value, ValueError)

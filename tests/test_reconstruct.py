"""``python -m experiments.reconstruct`` on files written the way a user's own recording comes: a worked example
scored against its ground truth, the Shelf export read back to the main job's inputs, and the command line."""

import json
import os
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest
from numpy.testing import assert_allclose

import geometry
import jcsat
import mocap

REPO = Path(__file__).resolve().parents[1]
BVH_TOLERANCE_M = 2e-6
"""The BVH round trip's tolerance (8 decimals in the file) beyond each person's bone-length normalisation, which
summary.json gives to 1e-6 m."""


def _command(*args, check: bool = True) -> subprocess.CompletedProcess:
    run = subprocess.run([sys.executable, "-m", "experiments.reconstruct", *map(str, args)], cwd=REPO,
                         env={**os.environ, "PYTHONPATH": str(REPO)}, capture_output=True, text=True)
    if check and run.returncode != 0:
        pytest.fail(f"experiments.reconstruct exited with {run.returncode}:\n{run.stderr[-3000:]}", pytrace=False)
    return run


@pytest.fixture(scope="module")
def scene():
    return mocap.synthesise_scene(jax.random.key(5), mocap.shelf_cameras(), num_people=3, num_frames=40)


@pytest.fixture(scope="module")
def worked_example(scene, tmp_path_factory):
    """The scene written as EasyMocap calibration and OpenPose JSON folders, then reconstructed by the command."""
    folder = tmp_path_factory.mktemp("recording")
    cameras = ("left", "shelf_a", "shelf_b", "right", "top")
    geometry.save_calibration(folder / "calibration", geometry.Calibration(scene.rig, cameras), "easymocap")
    mocap.write_openpose_keypoints(folder / "openpose", scene.detections, cameras)
    out = folder / "out"
    _command("--calibration", folder / "calibration", "--detections", folder / "openpose", "--out", out,
             "--method", "geometric", "--animation-frames", "8")
    return out


@pytest.mark.slow
def test_worked_example_scores_against_the_scene_and_equals_the_library_call(scene, worked_example):
    frames = np.arange(scene.shelf15.shape[0])
    predictions = mocap.read_predictions(worked_example / "predictions.jsonl")
    truth = mocap.EvaluationGroundTruth(frames, np.swapaxes(scene.shelf15, 0, 1), np.ones((3, len(frames)), bool))
    score = mocap.evaluate_shelf(predictions, truth, "voxelpose", (0, 1, 2))
    assert score.average["pcp"] > 90.0 and score.average["mpjpe_mm"] < 100.0, score.average
    # The writer groups the synthetic candidates by person (the files have people, not candidate lists), so the
    # command's inputs are the scene's candidates in another order: compare with the library on what it read.
    calibration = geometry.load_calibration(worked_example.parent / "calibration")
    read = mocap.load_keypoint_detections(worked_example.parent / "openpose", views=calibration.names)
    direct = jcsat.reconstruct(calibration.rig, read.detections, frames).predictions  # no model: geometric only
    assert_allclose(predictions.joints, direct.joints, atol=1e-9)
    assert (predictions.frame == direct.frame).all() and (predictions.person == direct.person).all()


@pytest.mark.slow
def test_worked_example_writes_every_output(scene, worked_example):
    expected = {"predictions.jsonl", "keypoints3d", "bvh", "viewer.html", "scene.gif", "frame.png", "summary.json",
                "config.json", "log.jsonl", "run.json"}
    assert {path.name for path in worked_example.iterdir()} == expected
    summary = json.loads((worked_example / "summary.json").read_text())
    assert summary["cameras"] == ["left", "shelf_a", "shelf_b", "right", "top"]
    assert summary["frames"] == {"count": 40, "first": 0, "last": 39} and summary["keypoint_format"] == "BODY25"
    predictions = mocap.read_predictions(worked_example / "predictions.jsonl")
    persons, joints, present = predictions.by_person(np.arange(40))
    assert sorted(summary["people"]) == [str(p) for p in persons]

    frame = json.loads((worked_example / "keypoints3d" / "000012.json").read_text())
    assert [person["id"] for person in frame] == persons[present[:, 12]].tolist()
    assert_allclose(np.array(frame[0]["keypoints3d"])[:, :3], joints[present[:, 12]][0, 12], atol=1e-6)

    for p, person in enumerate(persons):
        span = summary["people"][str(person)]
        motion = mocap.read_bvh(worked_example / "bvh" / f"person_{person}.bvh", 1.0)
        assert motion.num_frames == span["frames"] and motion.fps == pytest.approx(25.0)
        read_back = motion.positions[:, [motion.joint_names.index(name) for name in _bvh_names()]]
        observed = joints[p, span["first_frame"]:span["first_frame"] + span["frames"]]
        shown = present[p, span["first_frame"]:span["first_frame"] + span["frames"]]
        gap = np.linalg.norm(read_back - observed, axis=-1)[shown]
        assert gap.max() <= span["max_joint_change_m"] + BVH_TOLERANCE_M


def _bvh_names() -> list[str]:
    """The names :func:`mocap.read_bvh` gives the Shelf15 joints of a written person (leaves: ``<parent>_end``)."""
    motion = mocap.motion_from_joints(np.zeros((1, 15, 3)) + np.arange(45.0).reshape(1, 15, 3), geometry.SHELF15,
                                      fps=25.0)
    children = {parent for parent in motion.parents if parent >= 0}
    return [name if j in children or j == geometry.SHELF15.root else f"{motion.joint_names[motion.parents[j]]}_end"
            for j, name in enumerate(motion.joint_names[:15])]


@pytest.mark.data
@pytest.mark.parametrize("keypoint_format", ["openpose", "coco"])
def test_shelf_export_reads_back_to_the_main_jobs_inputs(data_root, tmp_path, keypoint_format):
    """The exported Shelf files hold the main job's inputs: the same cameras and, for OpenPose, the same candidates
    in the same order, bit for bit, so the pipeline decides as in the main job; COCO keeps the 17 COCO joints."""
    out = tmp_path / "files"  # the command as a user runs it: its calibration must not go through float32
    run = subprocess.run([sys.executable, "-m", "experiments.export_shelf", "--data-root", str(data_root), "--quick",
                          "--keypoint-format", keypoint_format, "--out", str(out)], cwd=REPO,
                         env={**os.environ, "PYTHONPATH": str(REPO)}, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr[-2000:]
    calibration = geometry.load_calibration(out / "calibration")
    read = mocap.load_keypoint_detections(out / "keypoints", views=calibration.names)
    rig = mocap.shelf_cameras(data_root)
    for field, exact in zip(calibration.rig, rig):
        np.testing.assert_array_equal(np.asarray(field), np.asarray(exact))  # bit for bit: same decisions
    detections, frames = mocap.load_shelf_detections(data_root)
    assert read.frame_numbers.tolist() == frames[:60].tolist()
    coco = [geometry.BODY25.index(name) for name in geometry.COCO17.joints]
    for f in range(60):
        for view in range(5):
            kept = range(25) if keypoint_format == "openpose" else coco
            for j in kept:
                np.testing.assert_array_equal(read.detections[f][view].joints[j], detections[f][view].joints[j])


def test_frame_numbers_come_from_the_names_when_they_all_have_increasing_ones():
    def frame_numbers(names):
        return mocap.KeypointDetections([], (), names, "BODY25", ()).frame_numbers

    assert frame_numbers(("000300_keypoints", "cam1_000301_keypoints")).tolist() == [300, 301]
    assert frame_numbers(("b", "a")).tolist() == [0, 1]
    assert frame_numbers(("img_5", "img_3")).tolist() == [0, 1]


def test_bad_options_are_refused_in_one_line(tmp_path):
    run = _command("--calibration", tmp_path / "missing", "--detections", tmp_path, "--out", tmp_path / "o",
                   check=False)
    assert run.returncode == 2 and len(run.stderr.strip().splitlines()) == 1, run.stderr
    assert f"--calibration {tmp_path / 'missing'} does not exist" in run.stderr
    assert not (tmp_path / "o").exists()

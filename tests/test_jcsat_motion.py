"""JCSAT's synthetic scenes draw people from motion files too (the CMU-Mocap benchmark's train split), and the held-out
motion (validation clips, the benchmark's test split) never enters training."""

import dataclasses

import jax
import numpy as np
import pytest

import mocap
from experiments import _cli, shelf_jcsat
from jcsat import VALIDATION_CLIPS, DataConfig, TrainConfig, build_dataset

pytestmark = pytest.mark.data


@pytest.fixture(scope="module")
def train_file(data_root) -> str:
    return str(mocap.cmu_expmap_files(data_root, "train")[0].resolve())


@pytest.fixture(scope="module")
def test_file(data_root) -> str:
    return str(mocap.cmu_expmap_files(data_root, "test")[0].resolve())


def test_a_scene_draws_a_person_from_an_expmap_file(train_file, tmp_path):
    """Three people, one clip each: the exp-map file's person is in the scene and its windows are labelled."""
    config = DataConfig(clips=(train_file, "02_01_walk", "02_03_run"), num_scenes=1, num_frames=24, num_people=3)
    dataset = build_dataset(config, tmp_path)
    assert dataset.num_windows > 0 and (dataset.person >= 0).any()
    expmap = mocap.shared_clip(train_file)
    assert expmap.fps == mocap.load_clip("02_01_walk").fps  # resampled to the shipped clips' rate
    scene = mocap.synthesise_scene(jax.random.key(0), mocap.shelf_cameras(), num_people=3, num_frames=24,
                                   clips=[mocap.shared_clip(clip) for clip in config.clips])  # as the build does
    assert expmap.name in scene.placement.names
    assert mocap.shared_clip(train_file) is expmap  # read once per process


def test_the_cache_key_names_the_files(train_file, data_root):
    other = str(mocap.cmu_expmap_files(data_root, "train")[1].resolve())
    assert DataConfig(clips=(train_file,)).cache_key() != DataConfig(clips=(other,)).cache_key()


def test_held_out_motion_is_refused_for_training(train_file, test_file):
    TrainConfig(data=DataConfig(clips=(train_file, "02_01_walk")))
    for clip in (test_file, VALIDATION_CLIPS[0]):
        with pytest.raises(ValueError, match="held out") as error:
            TrainConfig(data=DataConfig(clips=(train_file, clip)))
        assert "\n" not in str(error.value)
    with pytest.raises(ValueError, match="neither a shipped clip"):
        DataConfig(clips=("no/such/file.txt",))
    assert mocap.cmu_expmap_split(test_file) == "test" and mocap.cmu_expmap_split(train_file) == "train"
    assert mocap.cmu_expmap_split("02_01_walk") is None


def test_shelf_jcsat_adds_the_train_split(data_root, tmp_path):
    def parse(*argv):
        return _cli.parse(shelf_jcsat.Config, ["--data-root", str(data_root), "--out", str(tmp_path), *argv],
                          prog="shelf_jcsat")

    config = parse("--train", "--train-expmap")
    files = config.expmap_clips()
    assert len(files) == len(mocap.cmu_expmap_files(data_root, "train")) and all(f.startswith("/") for f in files)
    assert not any(mocap.cmu_expmap_split(f) == "test" for f in files)
    train_config = dataclasses.replace(TrainConfig(), data=dataclasses.replace(
        TrainConfig().data, clips=TrainConfig().data.clips + files))  # what --train-expmap trains on: accepted
    assert np.isin(files, train_config.data.clips).all()
    with pytest.raises(SystemExit):
        parse("--train-expmap")  # needs --train

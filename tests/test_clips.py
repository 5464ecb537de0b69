"""Shipped compact CMU clips, their converter, and the procedural fallback."""

import numpy as np
import pytest

import mocap
from experiments import convert_cmu
from geometry import BODY25, SHELF14, SHELF15, STRUCTRI17

SHIPPED = {"01_01_jumps": 1, "02_01_walk": 1, "02_03_run": 1, "02_04_jump": 1, "02_05_punch": 1,
           "03_01_uneven": 1, "18_01_handshake": 1, "60_03_61_03_salsa": 2, "60_05_61_05_salsa": 2}


def _limb_lengths(h36m: np.ndarray) -> np.ndarray:
    pairs = [(STRUCTRI17.index(a), STRUCTRI17.index(b)) for a, b in
             (("r_hip", "r_knee"), ("r_knee", "r_ankle"), ("l_shoulder", "l_elbow"), ("l_elbow", "l_wrist"))]
    return np.stack([np.linalg.norm(h36m[..., a, :] - h36m[..., b, :], axis=-1) for a, b in pairs], axis=-1)


def test_list_and_acknowledgement():
    assert sorted(SHIPPED) == mocap.list_clips()
    text = (mocap.ASSETS / "ACKNOWLEDGEMENTS.md").read_text()
    assert ("The data used in this project was obtained from mocap.cs.cmu.edu.\n"
            "The database was created with funding from NSF EIA-0196217.") in text
    size = sum(p.stat().st_size for p in mocap.ASSETS.glob("*.npz"))
    assert size < 4 * 2**20


@pytest.mark.parametrize("name", sorted(SHIPPED))
def test_shipped_clip_loads(name):
    clip = mocap.load_clip(name)
    assert clip.fps == 30.0 and clip.num_people == SHIPPED[name] == len(clip.trials)
    assert clip.body25.shape == (clip.num_people, clip.num_frames, 25, 3)
    assert clip.structri17.shape == (clip.num_people, clip.num_frames, 17, 3)
    assert clip.num_frames > 40 and np.isfinite(clip.body25).all()
    # bones are rigid up to the 1 mm quantisation; z is up
    limbs = _limb_lengths(clip.structri17)
    assert np.all(limbs.std(axis=1) < 2e-3) and np.all((0.15 < limbs) & (limbs < 0.6))
    head = clip.structri17[..., STRUCTRI17.index("head"), 2]
    ankles = clip.structri17[..., [STRUCTRI17.index("l_ankle"), STRUCTRI17.index("r_ankle")], 2].max(axis=-1)
    assert np.mean(head - ankles > 1.0) > 0.9
    shelf = clip.joints(SHELF15)
    np.testing.assert_allclose(shelf[..., 14, :], clip.structri17[..., [2, 3], :].mean(axis=-2))
    assert clip.joints(SHELF14).shape[-2] == 14 and clip.joints(BODY25) is clip.body25


def test_unknown_clip():
    with pytest.raises(KeyError, match="no shipped clip 'nope'"):
        mocap.load_clip("nope")


@pytest.mark.parametrize("name", ["02_03_run", "18_01_handshake"])
def test_reconversion_reproduces_shipped(data_root, tmp_path, name):
    if not (data_root / "cmu_mocap").is_dir():
        pytest.skip("no cmu_mocap data")
    convert_cmu.main(convert_cmu.Config(out=tmp_path, data_root=data_root, clips=(name,)))
    fresh, shipped = mocap.load_clip(name, tmp_path), mocap.load_clip(name)
    np.testing.assert_allclose(fresh.body25, shipped.body25, atol=1e-3 + 1e-9)
    np.testing.assert_allclose(fresh.structri17, shipped.structri17, atol=1e-3 + 1e-9)
    assert (tmp_path / f"{name}.npz").read_bytes() == (mocap.ASSETS / f"{name}.npz").read_bytes()


def test_quantisation_round_trip(tmp_path):
    clip = mocap.procedural_clip(seed=1, num_frames=50)
    mocap.save_clip(clip, tmp_path / "p.npz")
    loaded = mocap.load_clip("p", tmp_path)
    np.testing.assert_allclose(loaded.body25, clip.body25, atol=0.5e-3 + 1e-12)
    np.testing.assert_allclose(loaded.structri17, clip.structri17, atol=0.5e-3 + 1e-12)
    assert loaded.trials == clip.trials and loaded.fps == clip.fps
    far = clip._replace(body25=clip.body25 + 40.0)
    with pytest.raises(ValueError, match="int16"):
        mocap.save_clip(far, tmp_path / "far.npz")


def test_procedural_is_deterministic_and_walks():
    a = mocap.procedural_clip(seed=7, num_frames=90, num_people=2)
    b = mocap.procedural_clip(seed=7, num_frames=90, num_people=2)
    c = mocap.procedural_clip(seed=8, num_frames=90, num_people=2)
    np.testing.assert_array_equal(a.body25, b.body25)
    assert not np.allclose(a.body25, c.body25)
    assert a.body25.shape == (2, 90, 25, 3) and a.structri17.shape == (2, 90, 17, 3)
    pelvis = a.structri17[:, :, 0]
    speed = np.linalg.norm(np.diff(pelvis[..., :2], axis=1), axis=-1) * a.fps
    assert np.all((0.6 < speed.mean(axis=1)) & (speed.mean(axis=1) < 1.8))
    assert np.all(np.linalg.norm(pelvis[0, :, :2] - pelvis[1, :, :2], axis=-1)[0] > 1.5)
    limbs = _limb_lengths(a.structri17)
    assert np.all(limbs.std(axis=1) < 1e-9)

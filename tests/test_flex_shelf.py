"""FLEX on the real Shelf detections (experiments.flex_shelf): the detector-joint input and the options; the table's
values are pinned in tests/test_structri_shelf.py, which runs the association it shares."""

import numpy as np
import pytest

import flex
import geometry
import mocap
from experiments import flex_shelf
from experiments.flex_study import FlexShelfConfig


def test_input_weights_are_affine_combinations_of_their_support():
    weights = flex.input_joint_weights(geometry.SKEL19)
    np.testing.assert_allclose(weights.sum(axis=-1), 1.0, atol=1e-12)
    for j, name in enumerate(geometry.STRUCTRI17.joints):
        support = {geometry.SKEL19.index(n) for n in flex.INPUT_SUPPORT[name]}
        assert set(np.flatnonzero(weights[j])) <= support, name
    # On a clip never fitted on, the limbs (the same joints in both sets) are exact and the rest within 9 cm.
    clip = mocap.shared_clip(flex.VALIDATION_CLIPS[0])
    mapped = np.einsum("kj,...jc->...kc", flex.input_joint_weights(), clip.body25)
    error = np.linalg.norm(mapped - clip.structri17, axis=-1).mean(axis=(0, 1))
    limbs = [geometry.STRUCTRI17.index(f"{s}_{p}") for s in "rl" for p in ("knee", "ankle", "elbow", "wrist")]
    assert error[limbs].max() < 1e-9 and error.max() < 0.09


def test_a_missed_support_joint_misses_the_input_joint():
    points = np.random.default_rng(0).uniform(0, 500, (3, 25, 2))
    confidences = np.full((3, 25), 0.9)
    confidences[1, geometry.BODY25.index("r_ear")] = 0.0
    confidences[2, geometry.BODY25.index("neck")] = 0.4
    combined, confidence = flex.input_from_detections(points, confidences)
    head, spine, knee = (geometry.STRUCTRI17.index(n) for n in ("head", "spine", "r_knee"))
    assert combined.shape == (3, 17, 2) and confidence[0, head] == 0.9
    assert confidence[1, head] == 0.0 and confidence[1, spine] == 0.9
    assert confidence[2, spine] == 0.4 and confidence[2, knee] == 0.9
    with pytest.raises(ValueError, match=r"points must be \(\.\.\., 25, 2\) BODY25 pixels"):
        flex.input_from_detections(points[:, :19], confidences[:, :19])
    points[0, 3] = np.nan
    with pytest.raises(ValueError, match="points must be finite where the confidence is positive"):
        flex.input_from_detections(points, confidences)
    confidences[0, 3] = 0.0  # a missed joint's pixels are not read
    assert np.isfinite(flex.input_from_detections(points, confidences)[0][0, geometry.STRUCTRI17.index("r_knee")]).all()
    with pytest.raises(ValueError, match="confidences must be finite detector scores >= 0"):
        flex.input_from_detections(points, np.full((3, 25), -0.5))


def test_detected_input_differs_from_the_body_models_joints_only_off_the_limbs():
    config = flex.DataConfig(views=2, frames=16, clips=("02_01_walk",))
    own = flex.make_sample(5, config)
    detected = flex.make_sample(5, flex.DataConfig(views=2, frames=16, clips=("02_01_walk",), input_joints="detected"))
    both = (own.confidences > 0) & (detected.confidences > 0)
    apart = np.where(both, np.linalg.norm(own.points_2d - detected.points_2d, axis=-1), 0.0).max(axis=(0, 1))
    limbs = [geometry.STRUCTRI17.index(f"{s}_{p}") for s in "rl" for p in ("knee", "ankle", "elbow", "wrist")]
    torso = [geometry.STRUCTRI17.index(n) for n in ("spine", "thorax", "head")]
    assert apart[limbs].max() < 1e-9 and apart[torso].min() > 1.0
    np.testing.assert_array_equal(own.joints, detected.joints)


@pytest.mark.parametrize(("options", "message"), [
    (dict(views=(0, 0, 1, 2)), "views must be at least 2 distinct Shelf cameras"),
    (dict(perturbation=0.0), "perturbation must be > 0"),
    (dict(perturbation_draws=1), "perturbation_draws must be >= 2"),
    (dict(frames=0), "frames must be"),
])
def test_config_refuses_bad_settings(data_root, options, message):
    with pytest.raises(ValueError, match=message):
        FlexShelfConfig(str(data_root), **options)


def test_command_refuses_a_missing_model_folder(tmp_path):
    with pytest.raises(ValueError, match="--model-dir .* is not a folder"):
        flex_shelf.Config(out=tmp_path, model_dir=tmp_path / "none")

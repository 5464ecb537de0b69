"""JAT and MPJAT (dynamics/_jat.py): causality, people independence or interaction, padding, the key/value cache,
the Joint-Aware Bias inside the model, the untrained f_AR's ZeroMotion, scene windows and the interpenetration
loss (dynamics/_losses.py)."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx
from jaxtyping import TypeCheckError
from numpy.testing import assert_allclose

import geometry
import dynamics
from dynamics import (JAT, JATConfig, SMPLParams, as_multi_person, interpenetration, penetration_surfaces,
                      scene_windows, zero_motion)
from test_dynamics import BODY, K, true_frames

SMALL = JATConfig(feature_dim=16, temporal_dim=16, joint_dim=8, hmr_hidden=16, bias_hidden=8, receptive_field=10)
"""Observing 16 frames and predicting 4, the attention window (10 frames) slides."""
PEOPLE, FRAMES, HORIZON = 2, 16, 4


def scene(seed: int = 0):
    rng = np.random.default_rng(seed)
    features = rng.normal(size=(1, PEOPLE, FRAMES, SMALL.feature_dim))
    boxes = np.broadcast_to(np.array([100.0, 60, 180, 140]), (1, PEOPLE, FRAMES, 4)) + rng.normal(
        scale=2.0, size=(1, PEOPLE, FRAMES, 4))
    return features, boxes, np.broadcast_to(K, (1, PEOPLE, FRAMES, 3, 3))


def model(agent_aware: bool, seed: int = 0, **changes) -> JAT:
    jat = JAT(dataclasses.replace(SMALL, agent_aware=agent_aware, **changes), rngs=nnx.Rngs(seed))
    # A trained-looking f_AR: the zero-initialised residual output would make every rollout ZeroMotion.
    kernel = jat.ar_output.kernel
    kernel[...] = 0.3 * jax.random.normal(jax.random.key(seed), kernel.shape, kernel.dtype)
    return jat


@nnx.jit
def predict(jat: JAT, features, boxes, Ks, present):
    """The observation, the cached rollout and the naive one (one compilation per model structure and shape)."""
    observed = jat.observe(BODY, features, boxes, Ks, present)
    return observed, jat.rollout(BODY, observed, HORIZON, present), jat.rollout(BODY, observed, HORIZON, present,
                                                                               cached=False)


def run(jat, features, boxes, Ks, present=None):
    present = np.ones(features.shape[:2], bool) if present is None else present
    observed, cached, naive = predict(jat, features, boxes, Ks, present)
    for a, b in zip(jax.tree.leaves(cached), jax.tree.leaves(naive)):  # every call checks the cache
        assert_allclose(a, b, rtol=1e-9, atol=1e-10)
    return observed, cached


@pytest.fixture(scope="module")
def models():
    return {aware: model(aware) for aware in (False, True)}


def test_observation_is_causal_and_jit_equals_eager(models):
    features, boxes, Ks = scene()
    changed = features.copy()
    changed[..., 10:, :] += 1.0
    for jat in models.values():
        before, rollout = run(jat, features, boxes, Ks)
        after, _ = run(jat, changed, boxes, Ks)
        assert_allclose(after.temporal[..., :10, :], before.temporal[..., :10, :], atol=1e-12)
        assert not np.allclose(after.temporal[..., 10:, :], before.temporal[..., 10:, :])
        assert rollout.params.rot6d.shape == (1, PEOPLE, HORIZON, 24, 6) and rollout.root.shape == (1, PEOPLE, HORIZON, 3)
    eager = models[True].observe(BODY, features, boxes, Ks)
    for a, b in zip(jax.tree.leaves(eager), jax.tree.leaves(run(models[True], features, boxes, Ks)[0])):
        assert_allclose(a, b, rtol=1e-9, atol=1e-10)


def test_forecast_scenes_pads_batches_and_equals_one_scene_at_a_time(models):
    """dynamics.forecast_scenes (the evaluation's and the strip's forecasts): 17 scenes in two batches of 16, the
    second padded; each scene's outputs are those of the scene alone."""
    scenes = [scene(seed) for seed in range(17)]
    features, boxes, Ks = (np.concatenate(part) for part in zip(*scenes))
    present = np.ones((17, PEOPLE), bool)
    present[3, 1] = False
    seen, rollout = dynamics.forecast_scenes(models[True], BODY, features, boxes, Ks, present, FRAMES, HORIZON)
    assert rollout.params.rot6d.shape == (17, PEOPLE, HORIZON, 24, 6)
    for index in (0, 3, 16):
        alone = run(models[True], *scenes[index], present[index:index + 1])
        for ours, theirs in zip(jax.tree.leaves((seen, rollout)), jax.tree.leaves(alone)):
            assert_allclose(np.asarray(ours)[index], np.asarray(theirs)[0], rtol=1e-8, atol=1e-9)


def test_jat_keeps_people_apart_and_mpjat_lets_them_interact(models):
    features, boxes, Ks = scene(1)
    changed = features.copy()
    changed[:, 1] += 1.0  # only person 1's frames
    for aware, jat in models.items():
        _, before = run(jat, features, boxes, Ks)
        _, after = run(jat, changed, boxes, Ks)
        person0 = lambda rollout: np.asarray(rollout.params.rot6d[:, 0])  # noqa: E731
        assert np.allclose(person0(after), person0(before), atol=1e-12) != aware


def test_an_absent_person_changes_nothing_and_padding_equals_a_smaller_scene(models):
    features, boxes, Ks = scene(2)
    present = np.array([[True, False]])
    mpjat = models[True]
    _, padded = run(mpjat, features, boxes, Ks, present)
    changed = features.copy()
    changed[:, 1] += 5.0
    _, padded_changed = run(mpjat, changed, boxes, Ks, present)
    _, alone = run(mpjat, features[:, :1], boxes[:, :1], Ks[:, :1])
    for a, b, c in zip(jax.tree.leaves(padded), jax.tree.leaves(padded_changed), jax.tree.leaves(alone)):
        assert np.isfinite(np.asarray(a)).all()
        assert_allclose(np.asarray(a)[:, 0], np.asarray(b)[:, 0], atol=1e-12)
        assert_allclose(np.asarray(a)[:, 0], np.asarray(c)[:, 0], rtol=1e-9, atol=1e-9)
    with pytest.raises((ValueError, TypeCheckError), match="present"):
        mpjat.observe(BODY, features, boxes, Ks, np.ones((1, 3), bool))


def test_the_joint_aware_bias_reaches_the_prediction(models):
    features, boxes, Ks = scene(5)
    _, before = run(models[False], features, boxes, Ks)
    changed = nnx.clone(models[False])
    changed.bias_self.fc2.bias[...] = changed.bias_self.fc2.bias[...] + 1.0  # a constant bias: no effect
    _, shifted = run(changed, features, boxes, Ks)
    assert_allclose(shifted.features, before.features, rtol=1e-9, atol=1e-10)
    changed.bias_self.fc2.kernel[...] = changed.bias_self.fc2.kernel[...] + 1.0
    _, after = run(changed, features, boxes, Ks)
    assert not np.allclose(after.features, before.features)
    assert not hasattr(model(False, joint_aware_bias=False), "bias_self")


def test_an_untrained_ar_head_predicts_zero_motion():
    jat = JAT(SMALL, rngs=nnx.Rngs(6))
    observed, rollout = run(jat, *scene(6))
    repeated = zero_motion(observed, HORIZON)
    for a, b in zip(jax.tree.leaves((rollout.params, rollout.root)), jax.tree.leaves((repeated.params, repeated.root))):
        assert_allclose(a, b, rtol=1e-6, atol=1e-9)


def test_multi_person_from_single_person_agrees_on_one_person(models):
    jat = models[False]
    mpjat = as_multi_person(jat, dataclasses.replace(SMALL, agent_aware=True))
    features, boxes, Ks = scene(7)
    single = [features[:, :1], boxes[:, :1], Ks[:, :1]]
    for a, b in zip(jax.tree.leaves(run(jat, *single)), jax.tree.leaves(run(mpjat, *single))):
        assert_allclose(a, b, rtol=1e-9, atol=1e-10)
    with pytest.raises(ValueError, match="agent_aware=True"):
        as_multi_person(jat, SMALL)


def test_scene_windows_group_people_and_pad():
    two = true_frames(np.random.default_rng(8), 6, tracks=2)
    one = true_frames(np.random.default_rng(9), 6)
    frames = jax.tree.map(lambda a, b: np.concatenate([a, b]), two, one)
    frames = frames._replace(video=np.r_[np.zeros(12, int), np.ones(6, int)], person=np.r_[np.repeat([0, 1], 6), np.zeros(6, int)],
                             track=np.r_[two.track, one.track + 2])
    windows, present = scene_windows(frames, 4, stride=2)
    assert windows.shape == (4, 2, 4)
    assert present.tolist() == [[True, True]] * 2 + [[True, False]] * 2
    assert_allclose(windows[0], [[0, 1, 2, 3], [6, 7, 8, 9]])
    assert_allclose(windows[3], [[14, 15, 16, 17], [14, 15, 16, 17]])  # the absent person repeats the first
    with pytest.raises(ValueError, match="more than people=1"):
        scene_windows(frames, 4, people=1)


def test_interpenetration_vanishes_apart_and_pushes_overlapping_people_apart():
    rotations = np.broadcast_to(np.diag([1.0, -1.0, -1.0]), (1, 2, 1, 24, 3, 3))
    params = SMPLParams(jnp.asarray(geometry.matrix_to_rotation_6d(rotations)), jnp.zeros((1, 2, 1, 3)),
                        jnp.zeros((1, 2, 1, 3)))
    apart = jnp.array([[[[-1.5, 0.0, 5.0]], [[1.5, 0.0, 5.0]]]])
    close = jnp.array([[[[-0.1, 0.0, 5.0]], [[0.1, 0.0, 5.0]]]])
    assert float(interpenetration(BODY, params, apart)[0, 0]) == 0.0
    overlap = float(interpenetration(BODY, params, close)[0, 0])
    assert overlap > 0.1
    closer = float(interpenetration(BODY, params, close * jnp.array([0.5, 1, 1])[None, None, None])[0, 0])
    assert closer > overlap
    gradient = jax.grad(lambda root: jnp.sum(interpenetration(BODY, params, root)))(close)
    assert gradient[0, 0, 0, 0] > 0 and gradient[0, 1, 0, 0] < 0  # descending moves person 0 left, person 1 right
    # Inside a jitted step the body model is an argument (traced): its capsules come precomputed.
    surfaces = penetration_surfaces(BODY)
    traced = jax.jit(lambda body, root: interpenetration(body, params, root, surfaces))(BODY, close)
    assert_allclose(float(traced[0, 0]), overlap, rtol=1e-6)
    with pytest.raises(jax.errors.TracerArrayConversionError):
        jax.jit(lambda body, root: interpenetration(body, params, root))(BODY, close)

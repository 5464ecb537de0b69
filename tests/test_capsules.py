"""The capsule body (geometry/_capsules.py): the signed distance by hand, the radius fit on the stand-in and on
an official-format file, the interpenetration of two bodies, gradients, and the posed sampled vertices
(geometry.body_points) against the full forward function."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from numpy.testing import assert_allclose
from test_body import _smpl_arrays, random_model, random_rotations

from geometry import (SMPL24, Capsules, body_capsules, body_forward, body_joints, body_points, capsule_sdf,
                      load_body_model, penetration, stand_in_body_model, surface_points)
from geometry._body import _radius

STAND_IN = stand_in_body_model()
CAPSULES = body_capsules(STAND_IN)


def stand_in_radii(capsules: Capsules) -> np.ndarray:
    return np.array([_radius(SMPL24.joints[end]) for end in capsules.ends])


def test_one_capsule_by_hand():
    joints = np.zeros((24, 3))
    joints[1] = [0.0, 1.0, 0.0]  # a capsule from the origin to (0, 1, 0), radius 0.1
    capsule = Capsules(np.array([0]), np.array([1]), np.array([0.1]))
    points = np.array([[0.0, 0.5, 0.0],  # on the axis: as deep as the radius
                       [0.0, 0.0, 0.0],  # an end point
                       [0.05, 0.3, 0.0],  # inside, 5 cm off the axis
                       [0.3, 0.5, 0.4],  # beside: 0.5 from the axis
                       [0.0, 1.4, 0.0],  # beyond the end cap
                       [0.3, -0.4, 0.0]])  # beyond the start cap, off the axis: 0.5 from the end point
    expected = np.array([-0.1, -0.1, -0.05, 0.4, 0.3, 0.4])
    assert_allclose(capsule_sdf(joints, capsule, points), expected, atol=1e-15)
    assert_allclose(penetration(joints, capsule, points), np.maximum(-expected, 0.0), atol=1e-15)
    # A second capsule: the union's distance is the nearer one.
    two = Capsules(np.array([0, 0]), np.array([1, 2]), np.array([0.1, 0.2]))
    joints[2] = [2.0, 0.0, 0.0]
    assert_allclose(capsule_sdf(joints, two, np.array([[1.0, 0.1, 0.0]])), [-0.1], atol=1e-15)


def test_stand_in_radii_are_its_capsules():
    assert len(CAPSULES.starts) == 23  # every bone of SMPL24
    assert [tuple(b) for b in zip(CAPSULES.starts, CAPSULES.ends)] == list(SMPL24.bones)
    assert_allclose(CAPSULES.radii, stand_in_radii(CAPSULES), atol=1e-12)


def test_sign_and_surface_of_a_posed_body():
    rotations = np.stack([np.eye(3), *random_rotations(4)[1:]])  # upright, the limbs posed
    betas, translation = np.array([0.5, 0.0, -0.5]), np.array([0.3, 0.9, 2.0])
    joints = body_joints(STAND_IN, rotations, betas, translation)
    assert np.all(np.asarray(capsule_sdf(joints, CAPSULES, joints)) < 0)  # its own joints are inside
    directions = np.random.default_rng(0).normal(size=(50, 3))
    centre = np.asarray(joints).mean(0)
    reach = np.linalg.norm(np.asarray(joints) - centre, axis=1).max()
    far = centre + (reach + 1.0) * directions / np.linalg.norm(directions, axis=1, keepdims=True)
    assert np.all(np.asarray(capsule_sdf(joints, CAPSULES, far)) > 0.8)  # 1 m beyond every joint, minus a radius
    # The stand-in's own surface is its capsules (height and leg length scale them; girth is unfitted: zero).
    vertices = surface_points(STAND_IN, 400)
    posed = body_points(STAND_IN, rotations, betas, translation, vertices)
    sdf = np.asarray(capsule_sdf(joints, CAPSULES, posed))
    assert np.median(np.abs(sdf)) < 0.02
    assert sdf.max() < 0.05


def test_interpenetration_of_two_bodies():
    rotations = np.stack([np.eye(3), *random_rotations(5)[1:]])
    betas, vertices = np.zeros(3), surface_points(STAND_IN, 300)
    joints = body_joints(STAND_IN, rotations, betas, np.zeros(3))

    def loss(shift: float) -> float:  # the second person's vertices inside the first person's capsules
        other = body_points(STAND_IN, rotations, betas, np.array([0.0, 0.0, shift]), vertices)
        return float(jnp.sum(penetration(joints, CAPSULES, other)))

    assert loss(3.0) == 0.0
    # A copy shifted by s less than a limb's thickness puts half its surface about s deep, so the loss grows as
    # the copy comes closer only down to a few centimetres.
    overlaps = [loss(shift) for shift in (0.2, 0.1, 0.05)]
    assert 0 < overlaps[0] < overlaps[1] < overlaps[2]


def test_gradients_finite_and_jit_matches_eager():
    joints = np.array(body_joints(STAND_IN, random_rotations(6), np.zeros(3), np.zeros(3)))
    joints[22] = joints[20]  # a zero-length capsule (wrist -> hand)
    points = np.concatenate([joints[[0, 20, 22]],  # on capsule axes and ends: distance exactly 0
                             0.5 * (joints[[1, 18]] + joints[[4, 20]]),  # mid-axis
                             joints[[20]] + np.array([[0.01, 0.0, 0.0]]),
                             np.random.default_rng(1).normal(scale=0.5, size=(20, 3))])

    def loss(joints, points):
        return jnp.sum(penetration(joints, CAPSULES, points)) + jnp.sum(capsule_sdf(joints, CAPSULES, points))

    for grad in jax.jit(jax.grad(loss, argnums=(0, 1)))(joints, points):
        assert np.all(np.isfinite(grad)) and np.any(grad != 0)
    sdf_jit = jax.jit(capsule_sdf)(joints, CAPSULES, points)  # the capsules trace as index arrays
    assert_allclose(sdf_jit, capsule_sdf(joints, CAPSULES, points), atol=1e-15)
    closed = jax.jit(lambda j, p: penetration(j, CAPSULES, p))
    assert_allclose(closed(joints, points), penetration(joints, CAPSULES, points), atol=1e-15)
    batched = jax.vmap(capsule_sdf, in_axes=(0, None, None))(np.stack([joints, joints + 1.0]), CAPSULES, points)
    assert_allclose(batched[1], capsule_sdf(joints + 1.0, CAPSULES, points), atol=1e-15)


@pytest.mark.parametrize("model", [random_model(0, vertices=200), STAND_IN], ids=["random", "stand_in"])
def test_body_points_are_the_forward_vertices(model):
    rotations, betas = random_rotations(8), np.linspace(-1.0, 1.0, model.num_shapes)
    translation = np.array([0.2, -0.1, 1.5])
    vertices = np.array([5, 0, 17, 5, len(model.v_template) - 1, 42])  # any order, repeats allowed
    expected = np.asarray(body_forward(model, rotations, betas, translation).vertices)[vertices]
    assert_allclose(body_points(model, rotations, betas, translation, vertices), expected, rtol=1e-10, atol=1e-13)
    jitted = jax.jit(body_points)(model, rotations, betas, translation, vertices)
    assert_allclose(jitted, expected, rtol=1e-10, atol=1e-13)
    with pytest.raises(ValueError, match="vertex indices must lie in"):
        body_points(model, rotations, betas, translation, np.array([0, len(model.v_template)]))


def test_surface_points_spread_deterministically():
    first = surface_points(STAND_IN, 200)
    assert np.array_equal(first, surface_points(STAND_IN, 200))
    assert not np.array_equal(first, surface_points(STAND_IN, 200, seed=1))
    assert np.array_equal(surface_points(STAND_IN, 50), first[:50])  # a prefix of the larger sample
    assert len(np.unique(first)) == 200 and first.min() >= 0 and first.max() < len(STAND_IN.v_template)
    template = np.asarray(STAND_IN.v_template)
    gaps = np.linalg.norm(template[:, None] - template[first][None], axis=-1).min(1)
    assert gaps.max() < 0.1  # every vertex within 10 cm of a sample
    everything = surface_points(STAND_IN, len(template))
    assert np.array_equal(np.sort(everything), np.arange(len(template)))
    for count in (0, len(template) + 1):
        with pytest.raises(ValueError, match="count must lie in"):
            surface_points(STAND_IN, count)


def test_official_format_file_with_smpl_like_leaf_weights(tmp_path):
    """A coarser stand-in through the official file format, with its leaf joints carrying the outer half of
    their parts as SMPL's hands, toes and head do; and a zero-length bone, which gets no capsule."""
    model = stand_in_body_model(around=8, rings=4, cap_rings=2)
    arrays = _smpl_arrays(model)
    weights, template = arrays["weights"].copy(), arrays["v_template"]
    rest = arrays["J_regressor"] @ template
    leaves = [(p, c) for p, c in SMPL24.bones if c not in SMPL24.parents]
    for parent, child in leaves:
        axis = rest[child] - rest[parent]
        beyond = (weights[:, parent] > 0.99) & ((template - rest[parent]) @ axis > 0.6 * axis @ axis)
        weights[beyond, child], weights[beyond, parent] = 1.0, 0.0
    assert sum(weights[:, c].sum() > 0 for _, c in leaves) == 5
    np.savez(tmp_path / "model.npz", **{**arrays, "weights": weights})
    capsules = body_capsules(load_body_model(tmp_path / "model.npz"))
    assert_allclose(capsules.radii, stand_in_radii(capsules), atol=1e-12)

    regressor = arrays["J_regressor"].copy()
    hand, wrist = SMPL24.index("l_hand"), SMPL24.index("l_wrist")
    regressor[hand] = regressor[wrist]
    np.savez(tmp_path / "short.npz", **{**arrays, "J_regressor": regressor})
    short = body_capsules(load_body_model(tmp_path / "short.npz"))
    assert len(short.starts) == 22 and hand not in short.ends
    forearm = short.ends == wrist  # now the bone arriving at a leaf: it carries the hand's vertices too
    assert_allclose(short.radii[~forearm], stand_in_radii(short)[~forearm], atol=1e-12)
    assert short.radii[forearm] > stand_in_radii(short)[forearm]

"""Forward kinematics and bone-vector maps against plain NumPy/SciPy references."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose
from scipy.spatial.transform import Rotation

import geometry as g

# geometry/_metrics.py also defines a ``bone_lengths`` (without the zero-length gradient guard) that
# the package star-import currently lets win; test this module's one until the two are merged.
from geometry._kinematics import bone_lengths

TREES = [g.STRUCTRI17, g.SMPL24]


def _numpy_fk(local_rotations, offsets, root_position, parents):
    """Reference FK by recursion to the root (no topological order, no shared code)."""
    n = len(parents)
    rotations, positions = [None] * n, [None] * n

    def visit(j):
        if rotations[j] is None:
            p = parents[j]
            if p < 0:
                rotations[j], positions[j] = local_rotations[j], np.asarray(root_position)
            else:
                visit(p)
                rotations[j] = rotations[p] @ local_rotations[j]
                positions[j] = positions[p] + rotations[p] @ offsets[j]

    for j in range(n):
        visit(j)
    return np.stack(positions), np.stack(rotations)


def _random_pose(skeleton, seed, frames=None):
    rng = np.random.default_rng(seed)
    n = skeleton.num_joints
    shape = (n,) if frames is None else (frames, n)
    rotations = Rotation.random(int(np.prod(shape)), random_state=rng).as_matrix().reshape(*shape, 3, 3)
    return rotations, rng.normal(scale=0.2, size=(n, 3)), rng.normal(size=3)


@pytest.mark.parametrize("skeleton", TREES + [g.BODY25], ids=lambda s: s.name)
def test_fk_matches_numpy_reference(skeleton):
    rotations, offsets, root = _random_pose(skeleton, 0, frames=3)
    positions, global_rotations = g.forward_kinematics(rotations, offsets, root, skeleton.parents)
    for f in range(3):
        ref_pos, ref_rot = _numpy_fk(rotations[f], offsets, root, skeleton.parents)
        assert_allclose(np.asarray(positions[f]), ref_pos, atol=1e-14)
        assert_allclose(np.asarray(global_rotations[f]), ref_rot, atol=1e-14)


def test_structri17_has_parents_after_children_and_fk_still_visits_them_first():
    parents = g.STRUCTRI17.parents
    assert parents == (-1, 2, 0, 0, 3, 4, 1, 0, 7, 16, 11, 12, 8, 8, 13, 14, 8)
    assert any(p > c for c, p in enumerate(parents))
    rotations, offsets, root = _random_pose(g.STRUCTRI17, 1)
    # Index-order accumulation would read the unset parent of joint 1 (joint 2); the tuple and the
    # Skeleton must both give the recursive reference.
    for tree in (parents, g.STRUCTRI17):
        positions, _ = g.forward_kinematics(rotations, offsets, root, tree)
        assert_allclose(np.asarray(positions), _numpy_fk(rotations, offsets, root, parents)[0], atol=1e-14)


@pytest.mark.parametrize("skeleton", TREES, ids=lambda s: s.name)
def test_fk_with_identity_rotations_is_the_root_plus_cumulative_offsets(skeleton):
    _, offsets, root = _random_pose(skeleton, 2)
    identity = np.broadcast_to(np.eye(3), (skeleton.num_joints, 3, 3))
    positions, global_rotations = g.forward_kinematics(identity, offsets, root, skeleton)
    for j in range(skeleton.num_joints):
        expected, node = np.array(root), j
        while skeleton.parents[node] >= 0:
            expected, node = expected + offsets[node], skeleton.parents[node]
        assert_allclose(np.asarray(positions[j]), expected, atol=1e-14)
    assert_allclose(np.asarray(global_rotations), identity, atol=0)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), tree=st.sampled_from(TREES))
def test_fk_preserves_bone_lengths(seed, tree):
    rotations, offsets, root = _random_pose(tree, seed)
    positions, _ = g.forward_kinematics(rotations, offsets, root, tree)
    expected = np.linalg.norm(offsets[[c for _, c in tree.bones]], axis=1)
    assert_allclose(np.asarray(bone_lengths(positions, tree)), expected, rtol=1e-12, atol=1e-14)


def test_fk_bone_vectors_are_parent_rotated_offsets():
    rotations, offsets, root = _random_pose(g.SMPL24, 3, frames=4)
    positions, global_rotations = g.forward_kinematics(rotations, offsets, root, g.SMPL24)
    parent, child = np.array(g.SMPL24.bones).T
    expected = np.einsum("fkab,kb->fka", np.asarray(global_rotations)[:, parent], offsets[child])
    assert_allclose(np.asarray(g.bone_vectors(positions, g.SMPL24)), expected, atol=1e-14)


def test_fk_broadcasts_unbatched_offsets_and_root():
    rotations, offsets, root = _random_pose(g.STRUCTRI17, 4, frames=5)
    roots = np.random.default_rng(5).normal(size=(5, 3))
    positions, rots = g.forward_kinematics(rotations, offsets, roots, g.STRUCTRI17)
    assert positions.shape == (5, 17, 3) and rots.shape == (5, 17, 3, 3)
    full, _ = g.forward_kinematics(rotations, np.broadcast_to(offsets, (5, 17, 3)), roots, g.STRUCTRI17)
    assert_allclose(np.asarray(positions), np.asarray(full), atol=0)
    # One pose for many roots: the rotations broadcast too.
    moved, _ = g.forward_kinematics(rotations[0], offsets, roots, g.STRUCTRI17)
    assert_allclose(np.asarray(moved - moved[:, :1]), np.broadcast_to(positions[0] - positions[0, :1], (5, 17, 3)),
                    atol=1e-14)


def test_fk_jit_equals_eager_and_gradients_are_finite_at_zero():
    _, offsets, root = _random_pose(g.SMPL24, 6)

    def fk_from_rotvecs(rotvecs):
        return g.forward_kinematics(g.axis_angle_to_matrix(rotvecs), offsets, root, g.SMPL24)[0]

    rotvecs = np.random.default_rng(7).normal(scale=0.5, size=(2, 24, 3))
    assert_allclose(np.asarray(jax.jit(fk_from_rotvecs)(rotvecs)), np.asarray(fk_from_rotvecs(rotvecs)), atol=1e-14)
    jac = np.asarray(jax.jit(jax.jacfwd(fk_from_rotvecs))(jnp.zeros((24, 3))))
    assert np.isfinite(jac).all()
    # At the rest pose, rotating the root about axis e by eps moves joint j by eps * e x (x_j - x_root).
    rest = np.asarray(fk_from_rotvecs(np.zeros((24, 3))))
    for axis in range(3):
        assert_allclose(jac[:, :, 0, axis], np.cross(np.eye(3)[axis], rest - rest[0]), atol=1e-14)


@pytest.mark.parametrize("skeleton", TREES + [g.BODY25], ids=lambda s: s.name)
def test_bone_matrices_invert_each_other_and_match_bone_vectors(skeleton):
    n = skeleton.num_joints
    to_bones, to_joints = g.joints_to_bones_matrix(skeleton), g.bones_to_joints_matrix(skeleton)
    assert to_bones.shape == to_joints.shape == (3 * n, 3 * n)
    assert_allclose(to_joints @ to_bones, np.eye(3 * n), atol=0)
    assert_allclose(to_bones @ to_joints, np.eye(3 * n), atol=0)
    assert_allclose(to_joints, np.linalg.inv(to_bones), atol=1e-12)
    joints = np.random.default_rng(8).normal(size=(n, 3))
    stacked = to_bones @ joints.reshape(-1)
    assert_allclose(stacked[:3], joints[skeleton.root], atol=0)
    assert_allclose(stacked[3:].reshape(-1, 3), np.asarray(g.bone_vectors(joints, skeleton)), atol=1e-15)


def test_structri17_bone_matrix_is_structural_triangulation_layout():
    # ST's conv_J2B: block 0 is x_0, block k >= 1 is x_k - x_parent(k).
    parents = g.STRUCTRI17.parents
    expected = np.zeros((17, 17))
    expected[0, 0] = 1.0
    for k in range(1, 17):
        expected[k, k], expected[k, parents[k]] = 1.0, -1.0
    assert_allclose(g.joints_to_bones_matrix(g.STRUCTRI17), np.kron(expected, np.eye(3)), atol=0)


def test_joints_from_bones_inverts_bone_vectors_and_agrees_with_fk():
    rotations, offsets, root = _random_pose(g.STRUCTRI17, 9, frames=3)
    positions, _ = g.forward_kinematics(rotations, offsets, root, g.STRUCTRI17)
    bones = g.bone_vectors(positions, g.STRUCTRI17)
    assert bones.shape == (3, 16, 3)
    assert_allclose(np.asarray(g.joints_from_bones(root, bones, g.STRUCTRI17)), np.asarray(positions), atol=1e-14)
    flat = np.concatenate([np.broadcast_to(root, (3, 1, 3)), np.asarray(bones)], axis=1).reshape(3, -1)
    via_matrix = flat @ g.bones_to_joints_matrix(g.STRUCTRI17).T
    assert_allclose(via_matrix.reshape(3, 17, 3), np.asarray(positions), atol=1e-14)


def test_bone_lengths_gradient_is_finite_for_zero_length_bones():
    joints = jnp.zeros((17, 3))
    grad = jax.grad(lambda x: jnp.sum(bone_lengths(x, g.STRUCTRI17)))(joints)
    assert np.isfinite(np.asarray(grad)).all()


def test_bad_inputs_raise_clear_errors():
    rotations, offsets, root = _random_pose(g.STRUCTRI17, 10)
    with pytest.raises(ValueError, match=r"SMPL24 \(24 joints\), got \(17, 3, 3\)"):
        g.forward_kinematics(rotations, offsets, root, g.SMPL24)
    with pytest.raises(ValueError, match="tree|parent"):
        g.forward_kinematics(rotations[:3], offsets[:3], root, (-1, 2, 1))
    with pytest.raises(ValueError, match="joints must have shape"):
        g.bone_vectors(np.zeros((24, 3)), g.STRUCTRI17)

"""The body model (geometry/_body.py): SMPL's forward function against a NumPy reference, the generated
stand-in, and the official-file loader."""

import pickle
from collections import Counter

import cv2
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.sparse
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose

from geometry import (SMPL24, BodyModel, body_forward, body_joints, body_points, load_body_model,
                      matrix_to_rotation_6d, rotation_6d_to_matrix, stand_in_body_model)

STAND_IN = stand_in_body_model()


def random_model(seed: int, vertices: int = 60, shapes: int = 4) -> BodyModel:
    rng = np.random.default_rng(seed)
    regressor = rng.uniform(size=(24, vertices))
    return BodyModel(v_template=jnp.asarray(rng.normal(size=(vertices, 3))),
                     shapedirs=jnp.asarray(0.1 * rng.normal(size=(vertices, 3, shapes))),
                     posedirs=jnp.asarray(0.05 * rng.normal(size=(vertices, 3, 207))),
                     J_regressor=jnp.asarray(regressor / regressor.sum(1, keepdims=True)),
                     weights=jnp.asarray(rng.dirichlet(np.full(24, 0.3), size=vertices)),
                     faces=jnp.zeros((1, 3), jnp.int32))


def random_rotations(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.stack([cv2.Rodrigues(rng.normal(scale=0.8, size=3))[0] for _ in range(24)])


def numpy_smpl(model: BodyModel, rotations, betas, translation):
    """SMPL with 4x4 homogeneous transforms, joint by joint in index order (SMPL24's parents precede their
    children), as the official smpl_webuser code writes it."""
    v_shaped = np.asarray(model.v_template) + np.asarray(model.shapedirs) @ betas
    J = np.asarray(model.J_regressor) @ v_shaped
    v_posed = v_shaped + np.asarray(model.posedirs) @ (rotations[1:] - np.eye(3)).ravel()
    G = np.zeros((24, 4, 4))
    for j, parent in enumerate(SMPL24.parents):
        local = np.eye(4)
        local[:3, :3] = rotations[j]
        local[:3, 3] = J[j] - (J[parent] if parent >= 0 else 0.0)
        G[j] = local if parent < 0 else G[parent] @ local
    skinning = G.copy()
    skinning[:, :3, 3] -= np.einsum("jab,jb->ja", G[:, :3, :3], J)
    T = np.einsum("vj,jab->vab", np.asarray(model.weights), skinning)
    vertices = np.einsum("vab,vb->va", T[:, :3, :3], v_posed) + T[:, :3, 3]
    return vertices + translation, G[:, :3, 3] + translation


@pytest.mark.parametrize("seed", [0, 1])
def test_matches_a_numpy_reference_jit_and_eager(seed):
    model = random_model(seed)
    rng = np.random.default_rng(seed + 10)
    rotations, betas, translation = random_rotations(seed), rng.normal(size=4), rng.normal(size=3)
    expected_vertices, expected_joints = numpy_smpl(model, rotations, betas, translation)
    for forward in (body_forward, jax.jit(body_forward)):
        out = forward(model, rotations, betas, translation)
        assert_allclose(out.vertices, expected_vertices, atol=1e-12)
        assert_allclose(out.joints, expected_joints, atol=1e-12)


def test_rest_pose_is_the_template():
    out = body_forward(STAND_IN, np.broadcast_to(np.eye(3), (24, 3, 3)), np.zeros(3), np.zeros(3))
    assert_allclose(out.vertices, STAND_IN.v_template, atol=1e-15)
    assert_allclose(out.joints, STAND_IN.J_regressor @ STAND_IN.v_template, atol=1e-15)


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 2**16), st.floats(-3.0, 3.0))
def test_a_global_rotation_and_translation_move_the_body_rigidly(seed, height):
    rng = np.random.default_rng(seed)
    rotations, betas, translation = random_rotations(seed), np.array([height, 0.5, -0.5]), rng.normal(size=3)
    base = body_forward(STAND_IN, rotations, betas, np.zeros(3))
    turn = cv2.Rodrigues(rng.normal(size=3))[0]
    moved = body_forward(STAND_IN, np.concatenate([(turn @ rotations[0])[None], rotations[1:]]), betas, translation)
    pivot = np.asarray(base.joints[0])  # the root stays at its rest position
    assert_allclose(moved.vertices, (np.asarray(base.vertices) - pivot) @ turn.T + pivot + translation, atol=1e-12)
    assert_allclose(moved.joints, (np.asarray(base.joints) - pivot) @ turn.T + pivot + translation, atol=1e-12)


def test_batches_with_vmap_and_has_finite_gradients():
    rotations = np.stack([random_rotations(s) for s in range(3)])
    betas = np.random.default_rng(0).normal(size=(3, 3))
    batched = jax.vmap(body_forward, in_axes=(None, 0, 0, None))(STAND_IN, rotations, betas, np.zeros(3))
    for i in range(3):
        assert_allclose(batched.vertices[i], body_forward(STAND_IN, rotations[i], betas[i], np.zeros(3)).vertices,
                        atol=1e-12)
    rot6d = matrix_to_rotation_6d(rotations[0])
    assert_allclose(body_forward(STAND_IN, rotation_6d_to_matrix(rot6d), betas[0], np.zeros(3)).vertices,
                    body_forward(STAND_IN, rotations[0], betas[0], np.zeros(3)).vertices, atol=1e-12)

    def loss(rot6d, betas):
        return jnp.sum(body_forward(STAND_IN, rotation_6d_to_matrix(rot6d), betas, jnp.zeros(3)).vertices ** 2)

    grads = jax.grad(loss, argnums=(0, 1))(rot6d, betas[0])
    assert all(np.all(np.isfinite(g)) and np.any(g != 0) for g in grads)


def test_body_joints_equal_the_forward_joints_without_skinning():
    rotations = random_rotations(7)
    betas, translation = np.array([0.4, -0.3, 0.8]), np.array([0.1, -0.2, 3.0])
    expected = body_forward(STAND_IN, rotations, betas, translation).joints
    assert_allclose(body_joints(STAND_IN, rotations, betas, translation), expected, atol=1e-12)
    assert_allclose(jax.jit(body_joints)(STAND_IN, rotations, betas, translation), expected, atol=1e-12)


def test_stand_in_is_a_closed_outward_mesh_with_sound_weights():
    faces, vertices = np.asarray(STAND_IN.faces), np.asarray(STAND_IN.v_template)
    assert 1000 <= len(vertices) <= 3000
    edges = Counter(map(tuple, np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])))
    assert max(edges.values()) == 1 and all((b, a) in edges for a, b in edges)  # every edge in two faces, once each way
    cross = np.cross(vertices[faces[:, 1]] - vertices[faces[:, 0]], vertices[faces[:, 2]] - vertices[faces[:, 0]])
    assert np.all(np.linalg.norm(cross, axis=1) > 1e-8)  # no degenerate triangle
    volume = np.einsum("fi,fi->f", vertices[faces[:, 0]], np.cross(vertices[faces[:, 1]], vertices[faces[:, 2]]))
    assert volume.sum() / 6 > 0  # counter-clockwise seen from outside
    weights = np.asarray(STAND_IN.weights)
    assert np.all(weights >= 0)
    assert_allclose(weights.sum(1), 1.0, atol=1e-12)
    assert np.all(np.asarray(STAND_IN.posedirs) == 0)
    assert 1.5 < np.ptp(vertices[:, 1]) < 2.0  # metres, y up


def test_stand_in_shape_directions():
    rest = np.asarray(STAND_IN.J_regressor @ STAND_IN.v_template)
    pose = np.broadcast_to(np.eye(3), (24, 3, 3))

    def joints(betas):
        return np.asarray(body_forward(STAND_IN, pose, np.asarray(betas, float), np.zeros(3)).joints)

    assert_allclose(joints([1.0, 0, 0]), 1.1 * rest, atol=1e-12)  # height: 10 % per unit, about the pelvis
    assert_allclose(joints([0, 2.0, 0]), rest, atol=1e-12)  # girth moves no joint
    girth = body_forward(STAND_IN, pose, np.array([0, 1.0, 0]), np.zeros(3)).vertices
    assert np.ptp(np.asarray(girth)[:, 0]) > np.ptp(np.asarray(STAND_IN.v_template)[:, 0])
    legs = joints([0, 0, 1.0])
    ankle, head = SMPL24.index("l_ankle"), SMPL24.index("head")
    assert legs[ankle, 1] < rest[ankle, 1] - 0.05
    assert_allclose(legs[head], rest[head], atol=1e-12)


def _smpl_arrays(model: BodyModel) -> dict:
    kintree = np.array([[4294967295 if p < 0 else p for p in SMPL24.parents], range(24)], np.int64)
    return {"v_template": np.asarray(model.v_template), "shapedirs": np.asarray(model.shapedirs),
            "posedirs": np.asarray(model.posedirs), "J_regressor": np.asarray(model.J_regressor),
            "weights": np.asarray(model.weights), "f": np.asarray(model.faces).astype(np.uint32),
            "kintree_table": kintree}


def test_loads_official_files(tmp_path):
    arrays = _smpl_arrays(STAND_IN)
    np.savez(tmp_path / "model.npz", **arrays)
    with open(tmp_path / "model.pkl", "wb") as file:  # the release pickles a scipy sparse regressor
        pickle.dump({**arrays, "J_regressor": scipy.sparse.csc_matrix(arrays["J_regressor"])}, file)
    rotations, betas = random_rotations(3), np.array([0.3, -1.0, 0.5])
    expected = body_forward(STAND_IN, rotations, betas, np.ones(3)).vertices
    for name in ("model.npz", "model.pkl"):
        loaded = load_body_model(tmp_path / name)
        assert_allclose(body_forward(loaded, rotations, betas, np.ones(3)).vertices, expected, atol=1e-12)
    assert load_body_model(tmp_path / "model.npz", num_shapes=2).num_shapes == 2


def test_clear_errors(tmp_path):
    arrays = _smpl_arrays(STAND_IN)
    with pytest.raises(FileNotFoundError, match="no body model file"):
        load_body_model(tmp_path / "absent.npz")
    np.savez(tmp_path / "partial.npz", **{k: v for k, v in arrays.items() if k != "weights"})
    with pytest.raises(ValueError, match=r"lacks the SMPL keys \['weights'\]"):
        load_body_model(tmp_path / "partial.npz")
    tree = arrays["kintree_table"].copy()
    tree[0, 5] = 3
    np.savez(tmp_path / "tree.npz", **{**arrays, "kintree_table": tree})
    with pytest.raises(ValueError, match="not SMPL24"):
        load_body_model(tmp_path / "tree.npz")
    np.savez(tmp_path / "weights.npz", **{**arrays, "weights": arrays["weights"][:-1]})
    with pytest.raises(ValueError, match=r"weights has shape \(2529, 24\), expected \(2530, 24\)"):
        load_body_model(tmp_path / "weights.npz")
    (tmp_path / "model.obj").write_text("")
    with pytest.raises(ValueError, match=".pkl or .npz"):
        load_body_model(tmp_path / "model.obj")
    with pytest.raises(ValueError, match=r"rotations \(24, 3, 3\), betas \(3,\)"):
        body_forward(STAND_IN, np.zeros((23, 3, 3)), np.zeros(3), np.zeros(3))
    rest = np.broadcast_to(np.eye(3), (24, 3, 3))
    with pytest.raises(ValueError, match="betas contains NaN"):
        body_forward(STAND_IN, rest, np.array([0.0, np.nan, 0.0]), np.zeros(3))
    with pytest.raises(ValueError, match="translation contains NaN"):
        body_joints(STAND_IN, rest, np.zeros(3), np.array([0.0, 0.0, np.inf]))
    with pytest.raises(ValueError, match="rotations contains NaN"):
        body_points(STAND_IN, np.where(np.arange(24)[:, None, None] == 5, np.nan, rest), np.zeros(3), np.zeros(3),
                    np.arange(4))

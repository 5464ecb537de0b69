"""The transformer blocks of JAT / MPJAT (dynamics/_attention.py) and the Joint-Aware Bias (dynamics/_canonical.py).

Checked against the thesis: the sinusoidal encoding (Eq. 3.20), the input encoder (Eq. 4.15) and f_JAB (Eq. 4.27)
by formula, the agent masks by the hand-built indicator and tiled causal mask of Eq. 4.34-4.35 (Fig. 4.8); then
the properties the layers exist for: causality, people attending to each other, self / other parameters and
biases acting on their own blocks only, the bias reaching the logits, padding queries staying finite, key/value
caching, jit, vmap and eager agreeing. Canonicalisation: the identity at j = t, invariance to a global rigid
motion, one joint by hand.

Compilation dominates the run time on a small CPU (an eager layer call compiles every operation), so each test
compiles one program for all its cases, the modules share one initialisation program, and references are NumPy.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx
from numpy.testing import assert_allclose
from scipy.special import erf

import geometry
from dynamics import (
    GPTLayer, InputEncoder, JointAwareBias, KeyValues, agent_masks, canonical_features, canonicalise,
    sinusoidal_encoding,
)

DIM = 8
PEOPLE, FRAMES = 2, 3
# Person-major tokens (Eq. 4.29): token i is person i // FRAMES at frame i % FRAMES.
PERSON = np.arange(PEOPLE * FRAMES) // FRAMES
TIME = np.arange(PEOPLE * FRAMES) % FRAMES


def rbg_key(seed: int) -> jax.Array:
    """A key of the "rbg" generator: threefry's kernels compile slowly on a small CPU."""
    return jax.random.key(seed, impl="rbg")


def normal(seed: int, shape: tuple[int, ...]) -> np.ndarray:
    return np.random.default_rng(seed).standard_normal(shape)


def gelu(x: np.ndarray) -> np.ndarray:
    """The exact GELU in NumPy."""
    return 0.5 * x * (1.0 + erf(x / np.sqrt(2.0)))


def numpy(*arrays) -> tuple[np.ndarray, ...]:
    return tuple(np.array(a) for a in arrays)


def jax_arrays(*arrays) -> tuple[jax.Array, ...]:
    return tuple(jnp.asarray(a) for a in arrays)


def masks(person=PERSON, time=TIME, valid=None, receptive_field=None) -> tuple[jax.Array, jax.Array]:
    """Self-attention masks of the tokens ``(person, time)``."""
    valid = np.ones(np.shape(person), bool) if valid is None else valid
    return agent_masks(*jax_arrays(person, time, person, time, valid), receptive_field=receptive_field)


@nnx.jit
def self_attend(layer: GPTLayer, x, same_person, allowed):
    """Full self-attention of the tokens ``x``."""
    return layer(x, layer.key_values(x), same_person, allowed)


@pytest.fixture(scope="module")
def modules() -> dict:
    """GPT layers with and without agent awareness, an input encoder and a Joint-Aware Bias, all weights drawn by
    one compiled program."""

    def build():
        rngs = nnx.Rngs(rbg_key(0))
        return {"plain": GPTLayer(DIM, agent_aware=False, rngs=rngs),
                "agent": GPTLayer(DIM, agent_aware=True, rngs=rngs),
                "encoder": InputEncoder(5, DIM, rngs=rngs), "bias": JointAwareBias(16, rngs=rngs)}

    return nnx.jit(build)()


# ----------------------------------------------------------------------------------------------
# Positional encoding and input encoder


def test_sinusoidal_encoding_matches_the_formula():
    positions = np.array([[0, 1, 5], [7, 100, 3]])
    dim = 6
    want = np.zeros((*positions.shape, dim))
    for i in range(dim // 2):
        angle = positions / 10000.0 ** (2 * i / dim)
        want[..., 2 * i], want[..., 2 * i + 1] = np.sin(angle), np.cos(angle)
    got = sinusoidal_encoding(positions, dim)
    assert got.dtype == jnp.result_type(float)
    assert_allclose(np.asarray(got), want, rtol=1e-12, atol=1e-12)
    with pytest.raises(ValueError, match="even"):
        sinusoidal_encoding(positions, 5)


def test_input_encoder_formula_and_broadcast_positions(modules):
    encoder = modules["encoder"]
    x = normal(0, (2, 4, 5))
    positions = np.array([3, 4, 5, 6])
    encode = nnx.jit(lambda encoder, x, positions: (encoder(x, positions), encoder(x, jnp.tile(positions, (2, 1)))))
    got, tiled = numpy(*encode(encoder, *jax_arrays(x, positions)))
    assert got.shape == (2, 4, DIM)
    assert_allclose(got, tiled, rtol=1e-12, atol=1e-12)
    w1, b1, w2, b2 = numpy(encoder.fc1.kernel[...], encoder.fc1.bias[...], encoder.fc2.kernel[...],
                           encoder.fc2.bias[...])
    pe = np.broadcast_to(np.asarray(sinusoidal_encoding(positions, DIM)), (2, 4, DIM))
    want = gelu(np.concatenate([gelu(x @ w1 + b1), pe], axis=-1) @ w2 + b2)  # Eq. 4.15
    assert_allclose(got, want, rtol=1e-9, atol=1e-12)


# ----------------------------------------------------------------------------------------------
# Masks


def test_agent_masks_match_the_thesis_indicators():
    same_person, allowed = numpy(*masks())
    tokens = PEOPLE * FRAMES
    # Eq. 4.35 with 1-based i, j: 1_self[i, j] = floor((i - 1) / t) == floor((j - 1) / t).
    indicator = np.array([[(i - 1) // FRAMES == (j - 1) // FRAMES for j in range(1, tokens + 1)]
                          for i in range(1, tokens + 1)])
    assert_allclose(same_person, indicator)
    assert_allclose(~same_person, 1 - indicator)  # 1_other, Eq. 4.36
    # Eq. 4.34 / Fig. 4.8: the t x t causal mask tiled N x N.
    causal = np.tril(np.ones((FRAMES, FRAMES), bool))
    assert_allclose(allowed, np.tile(causal, (PEOPLE, PEOPLE)))
    # A receptive field of 2 frames drops keys more than one frame old.
    windowed = np.asarray(masks(receptive_field=2)[1])
    band = causal & ~np.tri(FRAMES, k=-2, dtype=bool)  # key frame in query - 1 .. query
    assert_allclose(windowed, np.tile(band, (PEOPLE, PEOPLE)))
    assert not windowed[2, 0] and not windowed[2, 3] and windowed[2, 1] and windowed[2, 4]
    # Invalid keys (e.g. an absent person's tokens) are columns nobody attends to.
    valid = np.array([True, True, True, False, True, False])
    padded = np.asarray(masks(valid=valid)[1])
    assert_allclose(padded, allowed & valid[None, :])


# ----------------------------------------------------------------------------------------------
# GPT layer: causality, interaction, caching, jit


def perturbed_inputs() -> np.ndarray:
    """Three token sets: random, with frame 2 of both people changed, with person 1's frame 0 changed."""
    x = normal(1, (PEOPLE * FRAMES, DIM))
    future, other = x.copy(), x.copy()
    future[TIME == 2] += normal(2, (PEOPLE, DIM))
    other[FRAMES] += normal(3, (DIM,))
    return np.stack([x, future, other])


def batched(mask: jax.Array, size: int) -> jax.Array:
    return jnp.broadcast_to(mask, (size, *mask.shape))


def test_layer_is_causal_and_people_attend_to_each_other(modules):
    x = perturbed_inputs()
    same_person, allowed = masks()
    for name in ("plain", "agent"):
        out, future, other = np.asarray(self_attend(modules[name], x, batched(same_person, 3), batched(allowed, 3)))
        assert_allclose(future[TIME < 2], out[TIME < 2], rtol=1e-12, atol=1e-12)
        assert not np.allclose(future[TIME == 2], out[TIME == 2])
        # Person 1's frame 0 reaches person 0's frame 2: people attend to each other.
        assert not np.allclose(other[2], out[2]), name


def test_layer_jit_vmap_and_eager_agree(modules):
    layer = modules["agent"]
    x = perturbed_inputs()  # the same shapes as the previous test: its program is reused
    same_person, allowed = masks()
    jitted = np.asarray(self_attend(layer, x, batched(same_person, 3), batched(allowed, 3)))
    eager = layer(jnp.asarray(x[1]), layer.key_values(jnp.asarray(x[1])), same_person, allowed)
    assert_allclose(np.asarray(eager), jitted[1], rtol=1e-9, atol=1e-12)
    mapped = nnx.jit(lambda layer, x: jax.vmap(lambda x: layer(x, layer.key_values(x), same_person, allowed))(x))
    assert_allclose(np.asarray(mapped(layer, x)), jitted, rtol=1e-9, atol=1e-12)


def test_cached_key_values_equal_full_ones(modules):
    last = np.flatnonzero(TIME == FRAMES - 1)  # f_AR's queries: each person's latest frame

    @nnx.jit
    def outputs(layer, x, same_person, allowed):
        # Keys and values of the first L - 1 tokens (the cache) and of the newest token, concatenated.
        cached = jax.tree.map(lambda a, b: jnp.concatenate([a, b], axis=0), layer.key_values(x[:-1]),
                              layer.key_values(x[-1:]))
        assert isinstance(cached, KeyValues)
        return (layer(x, layer.key_values(x), same_person, allowed), layer(x, cached, same_person, allowed),
                layer(x[last], cached, same_person[last], allowed[last]))

    full, cached, subset = numpy(*outputs(modules["agent"], normal(4, (PEOPLE * FRAMES, DIM)), *masks()))
    assert_allclose(cached, full, rtol=1e-12, atol=1e-12)
    assert_allclose(subset, full[last], rtol=1e-12, atol=1e-12)


def test_padding_query_is_finite_with_finite_gradients(modules):
    layer = modules["agent"]
    valid = np.array([True, True, True, False, False, False])
    same_person, allowed = numpy(*masks(valid=valid))
    allowed[0] = False  # a query with no allowed key at all
    same_person, allowed = jax_arrays(same_person, allowed)
    graphdef, params = nnx.split(layer)

    @jax.jit
    def run(params, x):
        def loss(params, x):
            layer = nnx.merge(graphdef, params)
            out = layer(x, layer.key_values(x), same_person, allowed)
            attention = layer.attention
            mix = attention(x[:1], attention.key_values(x), same_person[:1], allowed[:1])
            return jnp.sum(jnp.sin(out)), (out, mix)

        return jax.grad(loss, argnums=(0, 1), has_aux=True)(params, x)

    (param_grads, x_grads), (out, mix) = jax.tree.map(np.asarray, run(params, normal(6, (PEOPLE * FRAMES, DIM))))
    assert np.all(np.isfinite(out))
    assert all(np.all(np.isfinite(g)) for g in jax.tree.leaves(param_grads))
    assert np.all(np.isfinite(x_grads))
    # The padding query's attention output is a zero mix of values: only the out projection's bias remains.
    assert_allclose(mix, np.asarray(layer.attention.out.bias[...])[None], atol=1e-12)


# ----------------------------------------------------------------------------------------------
# Agent-aware attention: self / other blocks and biases


@nnx.jit
def attend(attention, x, same_person, allowed, bias_self=None):
    return attention(x, attention.key_values(x), same_person, allowed, bias_self)


def test_other_projections_act_on_other_blocks_only(modules):
    attention = modules["agent"].attention
    changed = nnx.clone(attention)
    for linear in (changed.query_other, changed.key_other):
        linear.kernel[...] = jnp.asarray(normal(8, linear.kernel.shape), linear.kernel.dtype)
    x = normal(7, (PEOPLE * FRAMES, DIM))
    for person in (np.zeros_like(PERSON), PERSON):
        same_person, allowed = masks(person=person)
        before, after = (np.asarray(attend(module, x, same_person, allowed)) for module in (attention, changed))
        if np.all(np.asarray(same_person)):  # one person: every pair is a 'self' pair
            assert_allclose(after, before, rtol=1e-12, atol=1e-12)
        else:
            assert not np.allclose(after, before)


def test_biases_act_on_their_own_blocks(modules):
    attention = modules["agent"].attention
    same_person, allowed = masks()
    x = jnp.asarray(normal(9, (PEOPLE * FRAMES, DIM)))

    @jax.jit
    def gradients(bias_self, bias_other):
        def loss(bias_self, bias_other):
            out = attention(x, attention.key_values(x), same_person, allowed, bias_self, bias_other)
            return jnp.sum(jnp.sin(out))

        return jax.grad(loss, argnums=(0, 1))(bias_self, bias_other)

    grad_self, grad_other = numpy(*gradients(*jax_arrays(*(normal(seed, (6, 6)) for seed in (10, 11)))))
    same_person, allowed = numpy(same_person, allowed)
    assert np.all(grad_self[~same_person | ~allowed] == 0)
    assert np.all(grad_other[same_person | ~allowed] == 0)
    assert np.all(grad_self[same_person & allowed] != 0)
    assert np.all(grad_other[~same_person & allowed] != 0)


def test_bias_reaches_the_logits(modules):
    attention = modules["agent"].attention
    keys, chosen = 4, 2
    x = normal(12, (2, keys, DIM))  # a batch of 2, each the last token querying 4 tokens of one person

    @nnx.jit
    def outputs(attention, x, huge, constant):
        kv = attention.key_values(x)
        same_person = allowed = jnp.ones((2, 1, keys), bool)
        queries = x[:, -1:]
        return (attention(queries, kv, same_person, allowed), attention(queries, kv, same_person, allowed, huge),
                attention(queries, kv, same_person, allowed, constant), attention.out(kv.values[:, chosen:chosen + 1]))

    huge = np.zeros((2, 1, keys))
    huge[..., chosen] = 1e4
    plain, got, shifted, want = numpy(*outputs(attention, *jax_arrays(x, huge, np.full((2, 1, keys), 3.7))))
    assert_allclose(got, want, rtol=1e-9, atol=1e-12)
    assert not np.allclose(got, plain)
    # A bias constant over the keys shifts every logit alike: softmax ignores it.
    assert_allclose(shifted, plain, rtol=1e-12, atol=1e-12)


# ----------------------------------------------------------------------------------------------
# Canonicalisation and the Joint-Aware Bias


axis_angle_to_matrix = jax.jit(geometry.axis_angle_to_matrix)  # one program instead of its operations one by one


def random_pose(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Random camera-frame joints in front of the camera and random rotations (joint 0 global, 1..23 local)."""
    rng = np.random.default_rng(seed)
    joints = rng.standard_normal((24, 3)) + np.array([0.0, 0.0, 4.0])
    rotations = np.array(axis_angle_to_matrix(rng.standard_normal((24, 3))))
    return joints, rotations


def test_canonicalise_is_the_identity_at_the_query_frame():
    joints, rotations = random_pose(13)
    canonical_joints, canonical_rotations = numpy(*canonicalise(*jax_arrays(joints, rotations, joints, rotations)))
    assert_allclose(canonical_rotations, np.broadcast_to(np.eye(3), (24, 3, 3)), atol=1e-12)
    assert_allclose(canonical_joints[0], np.zeros(3), atol=1e-12)
    assert_allclose(canonical_joints, (joints - joints[:1]) @ rotations[0], atol=1e-12)


def test_canonical_features_are_invariant_to_a_global_rigid_motion():
    query, key = random_pose(14), random_pose(15)
    rotation = random_pose(18)[1][0]
    translation = np.array([1.0, -2.0, 0.5])

    def moved(pose):
        joints, rotations = pose
        rotations = rotations.copy()
        rotations[0] = rotation @ rotations[0]  # the root is global; local rotations do not move
        return joints @ rotation.T + translation, rotations

    features = np.asarray(canonical_features(*jax_arrays(*query, *key)))
    assert features.shape == (288,)
    assert_allclose(np.asarray(canonical_features(*jax_arrays(*moved(query), *moved(key)))), features, atol=1e-12)
    assert not np.allclose(features, np.asarray(canonical_features(*jax_arrays(*query, *moved(key)))))


def test_canonicalise_one_joint_by_hand():
    quarter_turn = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # 90 degrees about z
    query_joints, query_rotations = random_pose(16)
    key_joints, key_rotations = random_pose(17)
    query_joints[0] = [1.0, 2.0, 3.0]
    query_rotations[0] = quarter_turn
    key_joints[5] = [1.0, 3.0, 3.0]  # one unit along camera y from the query's pelvis
    key_rotations[0] = quarter_turn @ quarter_turn
    joints, rotations = numpy(*canonicalise(*jax_arrays(query_joints, query_rotations, key_joints, key_rotations)))
    # Camera +y is the query pelvis' +x (its frame turned a quarter about z).
    assert_allclose(joints[5], [1.0, 0.0, 0.0], atol=1e-12)
    assert_allclose(rotations[0], quarter_turn, atol=1e-12)  # the key's pelvis a further quarter turn
    assert_allclose(rotations[7], key_rotations[7] @ query_rotations[7].T, atol=1e-12)  # Eq. 4.25


def test_joint_aware_bias_shapes_formula_and_jit(modules):
    bias = modules["bias"]
    features = normal(19, (2, 3, 288))
    jitted = np.asarray(nnx.jit(lambda bias, f: bias(f))(bias, features))
    assert jitted.shape == (2, 3)
    assert_allclose(np.asarray(bias(jnp.asarray(features[1, 2]))), jitted[1, 2], rtol=1e-9, atol=1e-12)
    w1, b1, w2, b2 = numpy(bias.fc1.kernel[...], bias.fc1.bias[...], bias.fc2.kernel[...], bias.fc2.bias[...])
    assert_allclose(jitted, gelu(features @ w1 + b1) @ w2[:, 0] + b2[0], rtol=1e-9, atol=1e-12)  # Eq. 4.27

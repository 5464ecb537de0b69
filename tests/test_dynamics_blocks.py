"""Neural building blocks of the dynamics models (dynamics/_backbone.py, _hmr.py, _tcn.py, _prior.py) and the crop
camera <-> translation conversion (geometry/_camera.py).

Every module is checked for batched shapes, jit == eager (the eager call on one item of the jitted batch) and
finite gradients, plus the property it exists for: causality, the mean start, the first-order camera match, the
LSGAN targets. Compilation dominates the run time on a small CPU, so the file keeps the number of compiled
programs low: small widths, test data and results handled in NumPy (indexing a JAX array compiles a kernel per
shape), one program for a module's outputs and gradients, and keys of the "rbg" generator.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from flax import nnx
from jaxtyping import TypeCheckError
from numpy.testing import assert_allclose
from scipy.spatial.transform import Rotation

import geometry
from dynamics import (
    CausalTCN, HMRHead, PosePrior, ResNetBackbone, SMPLParams, lsgan_discriminator_loss, lsgan_generator_loss,
    mean_params,
)

NUM_SHAPES = 10


def rbg_key(seed: int) -> jax.Array:
    """A key of the "rbg" generator: threefry's kernels (the default) take seconds per shape to compile on a
    small CPU, for weight initialisation and dropout alike."""
    return jax.random.key(seed, impl="rbg")


def build(factory):
    """``factory()`` with all initial weights drawn by one compiled program instead of one per weight shape."""
    return nnx.jit(factory)()


def normal(seed: int, shape: tuple[int, ...]) -> np.ndarray:
    return np.random.default_rng(seed).standard_normal(shape)


def uniform(seed: int, shape: tuple[int, ...], low: float = 0.0, high: float = 1.0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(low, high, shape)


def random_rotations(seed: int, shape: tuple[int, ...]) -> np.ndarray:
    rotvecs = 0.5 * normal(seed, (*shape, 3))
    return Rotation.from_rotvec(rotvecs.reshape(-1, 3)).as_matrix().reshape(*shape, 3, 3)


def eager(model: nnx.Module, *args: np.ndarray, **kwargs):
    """``model`` called op by op on NumPy inputs; NumPy outputs."""
    return jax.tree.map(np.asarray, model(*(jnp.asarray(a) for a in args), **kwargs))


def jitted(model: nnx.Module):
    """``run(*args, **kwargs) -> (outputs, gradients)``: the model's outputs and the parameters' gradient of a
    scalar of them from one compiled program (the state is an argument, ``model`` is not modified); NumPy in
    and out."""
    graphdef, params, rest = nnx.split(model, nnx.Param, ...)

    def loss(params, args, kwargs):
        outputs = nnx.merge(graphdef, params, rest)(*args, **kwargs)
        return sum(jnp.sum(jnp.sin(leaf)) for leaf in jax.tree.leaves(outputs)), outputs

    compiled = jax.jit(jax.grad(loss, has_aux=True))

    def run(*args, **kwargs):
        gradients, outputs = compiled(params, tuple(jnp.asarray(a) for a in args), kwargs)
        return jax.tree.map(np.asarray, outputs), jax.tree.map(np.asarray, gradients)

    return run


def assert_finite_gradients(gradients) -> None:
    """Every gradient is finite, and not all of them are zero."""
    leaves = jax.tree.leaves(gradients)
    assert all(np.all(np.isfinite(g)) for g in leaves)
    assert any(np.any(g != 0) for g in leaves)


# ----------------------------------------------------------------------------------------------
# Backbone


def test_backbone_default_sizes_on_64x64_crops():
    """Traced only (no weights drawn, nothing compiled): the default network maps 64 x 64 crops to features."""
    graphdef, state = nnx.split(nnx.eval_shape(lambda: ResNetBackbone(rngs=nnx.Rngs(0))))
    crops = jax.ShapeDtypeStruct((2, 3, 64, 64, 3), jnp.float32)
    features = jax.eval_shape(lambda state, crops: nnx.merge(graphdef, state)(crops), state, crops)
    assert features.shape == (2, 3, 256)


def test_backbone_shapes_jit_and_gradients():
    backbone = build(lambda: ResNetBackbone(widths=(8, 16), feature_dim=12, norm_groups=4, rngs=nnx.Rngs(rbg_key(0))))
    crops = uniform(0, (2, 1, 64, 64, 3))
    run = jitted(backbone)
    features, gradients = run(crops)
    assert features.shape == (2, 1, 12)
    assert_allclose(eager(backbone, crops[1]), features[1], rtol=1e-9, atol=1e-12)
    assert not np.allclose(features[0, 0], features[1, 0])
    assert_finite_gradients(gradients)
    # No batch statistics: a crop's features do not depend on the other crops of the batch.
    other = crops.copy()
    other[1] = uniform(1, (1, 64, 64, 3))
    assert_allclose(run(other)[0][0], features[0], rtol=1e-9, atol=1e-12)
    # Crops of another size than it was built for are refused (the global pooling would take any).
    with pytest.raises(ValueError, match="the backbone takes 64 x 64 crops, got 32 x 32"):
        backbone(jnp.asarray(uniform(2, (1, 32, 32, 3))))


@pytest.mark.parametrize(("crop_size", "widths", "side"), [(64, (16, 32, 64, 128), 4), (50, (8, 16, 32), 7)])
def test_backbone_flatten_pooling_keeps_the_last_map(crop_size, widths, side):
    """``pooling="flatten"``: the head reads the whole last map (``side`` x ``side`` x ``widths[-1]``, the side
    rounded up at every stride), and gives the features of that map flattened, not of its mean."""
    backbone = build(lambda: ResNetBackbone(widths=widths, feature_dim=12, norm_groups=4, crop_size=crop_size,
                                            pooling="flatten", rngs=nnx.Rngs(rbg_key(3))))
    assert backbone.head.kernel.shape == (side * side * widths[-1], 12)
    crops = jnp.asarray(uniform(4, (2, crop_size, crop_size, 3)))
    last = jax.nn.relu(backbone.stem_norm(backbone.stem(2.0 * crops - 1.0)))
    for block in backbone.blocks:
        last = block(last)
    assert last.shape == (2, side, side, widths[-1])
    assert_allclose(backbone(crops), backbone.head(last.reshape(2, -1)), rtol=1e-6, atol=1e-6)
    with pytest.raises((ValueError, TypeCheckError), match="pooling"):  # the type checker or, without it, the module
        ResNetBackbone(widths=widths, pooling="max", rngs=nnx.Rngs(0))


# ----------------------------------------------------------------------------------------------
# HMR head and its mean


@pytest.fixture(scope="module")
def head():
    return build(lambda: HMRHead(24, mean_params(NUM_SHAPES), hidden=32, rngs=nnx.Rngs(rbg_key(1))))


def test_hmr_head_shapes_jit_dropout_and_gradients(head):
    features = normal(0, (2, 3, 24))
    run = jitted(head)
    params, gradients = run(features)
    assert [a.shape for a in params] == [(2, 3, 24, 6), (2, 3, NUM_SHAPES), (2, 3, 3)]
    for got, want in zip(eager(head, features[1, 2]), params):
        assert_allclose(got, want[1, 2], rtol=1e-9, atol=1e-12)
    assert_finite_gradients(gradients)
    # Dropout only with a key: without one the head is deterministic, with one it samples.
    dropped, gradients = run(features, key=rbg_key(1))
    assert not np.allclose(dropped.rot6d, params.rot6d)
    assert_finite_gradients(gradients)


def test_hmr_head_with_a_zero_decoder_returns_its_start(head):
    mean = jax.tree.map(np.asarray, mean_params(NUM_SHAPES))
    head = nnx.clone(head)  # the fixture is shared
    head.decoder.kernel[...] = jnp.zeros(head.decoder.kernel.shape, head.decoder.kernel.dtype)
    features = normal(0, (24,))  # one item, as the previous test's eager call: its kernels are compiled
    for key in (None, rbg_key(3)):
        for got, want in zip(eager(head, features, key=key), mean):
            assert_allclose(got, want, atol=1e-7)  # the mean is stored float32
    start = SMPLParams(*(normal(i, a.shape) for i, a in enumerate(mean)))
    for got, want in zip(eager(head, features, start=jax.tree.map(jnp.asarray, start)), start):
        assert_allclose(got, want, atol=1e-12)


def test_mean_params_face_the_camera_upright():
    mean = jax.tree.map(np.asarray, mean_params(NUM_SHAPES))
    assert mean.rot6d.shape == (24, 6) and mean.betas.shape == (NUM_SHAPES,)
    assert_allclose(mean.camera, [0.9, 0.0, 0.0])
    assert_allclose(mean.betas, 0.0)
    rotations = np.asarray(jax.jit(geometry.rotation_6d_to_matrix)(mean.rot6d))
    assert_allclose(rotations[1:], np.broadcast_to(np.eye(3), (23, 3, 3)), atol=1e-12)
    body = geometry.stand_in_body_model()  # rest pose y up, facing +z, the person's left at +x
    # With every other joint at rest, the posed body is the rest body turned by the root's rotation.
    joints = (np.asarray(body.J_regressor) @ np.asarray(body.v_template)) @ rotations[0].T
    index = geometry.SMPL24.index
    assert joints[index("head"), 1] < joints[index("mid_hip"), 1]  # head up in the image: smaller camera y
    assert joints[index("l_hand"), 0] > joints[index("r_hand"), 0]  # facing us, the left hand is on the image right
    assert rotations[0, 2, 2] == pytest.approx(-1.0)  # the body's forward (+z) points back at the camera


# ----------------------------------------------------------------------------------------------
# Crop camera <-> translation

K_SKEWED = np.array([[1100.0, 0.7, 660.0], [0.0, 1000.0, 350.0], [0.0, 0.0, 1.0]])
TALL_BOX = np.array([500.0, 200.0, 600.0, 460.0])  # h > w: F = f_y
WIDE_BOX = np.array([300.0, 400.0, 520.0, 470.0])  # w > h: F = f_x


@pytest.mark.parametrize("box, focal", [(TALL_BOX, 1000.0), (WIDE_BOX, 1100.0)])
def test_crop_camera_round_trip_and_depth(box, focal):
    camera = np.array([0.8, 0.15, -0.3])
    translation = np.asarray(geometry.crop_camera_to_translation(camera, box, K_SKEWED))
    size = np.max(box[2:] - box[:2])
    assert translation[2] == pytest.approx(2.0 * focal / (0.8 * size))
    assert_allclose(geometry.translation_to_crop_camera(translation, box, K_SKEWED), camera, rtol=1e-12)
    # The root projects (full perspective, skew included) exactly where the crop camera puts it.
    root_pixel = (K_SKEWED @ translation)[:2] / translation[2]
    assert_allclose(root_pixel, 0.5 * (box[:2] + box[2:]) + 0.5 * size * camera[1:], rtol=1e-12)
    other = np.array([0.4, -1.2, 9.0])
    assert_allclose(geometry.crop_camera_to_translation(geometry.translation_to_crop_camera(other, box, K_SKEWED),
                                                        box, K_SKEWED), other, rtol=1e-12)
    assert_allclose(jax.jit(geometry.crop_camera_to_translation)(camera, box, K_SKEWED), translation, rtol=1e-12)
    assert_allclose(jax.jit(geometry.translation_to_crop_camera)(translation, box, K_SKEWED), camera, rtol=1e-12)


def test_crop_camera_matches_full_perspective_to_first_order():
    """A body at a fixed lateral offset moving away: full perspective through the translation, in crop units,
    approaches the weak crop projection, with a relative error that falls like 1 / distance. At the root the
    projection's derivative along x and y is exactly the crop camera's scale."""
    K = np.array([[1000.0, 0.0, 640.0], [0.0, 1000.0, 360.0], [0.0, 0.0, 1.0]])
    body = uniform(0, (30, 3), -0.5, 0.5)
    body[0] = 0.0  # the root

    @jax.jit
    def compare(distance):
        """The crop camera of the body's box, its translation, the weak projection's relative error and the full
        projection's derivative at the root (crop units per metre)."""
        translation = jnp.stack([0.6, -0.4, distance])
        camera_model = geometry.Camera(jnp.asarray(K), jnp.eye(3), translation, jnp.zeros(5), jnp.zeros(2))
        pixels = jax.vmap(geometry.project_point, in_axes=(None, 0))(camera_model, body)
        box = jnp.concatenate([jnp.min(pixels, axis=0), jnp.max(pixels, axis=0)])
        crop_camera = geometry.translation_to_crop_camera(translation, box, K)
        centre, half = 0.5 * (box[:2] + box[2:]), 0.5 * jnp.max(box[2:] - box[:2])

        def crop_units(point):
            return (geometry.project_point(camera_model, point) - centre) / half

        weak = crop_camera[0] * body[:, :2] + crop_camera[None, 1:]
        error = jnp.max(jnp.abs(jax.vmap(crop_units)(body) - weak)) / jnp.max(jnp.abs(weak - crop_camera[None, 1:]))
        derivative = jax.jacfwd(crop_units)(jnp.zeros(3))[:, :2]
        return crop_camera, geometry.crop_camera_to_translation(crop_camera, box, K), error, derivative

    errors = []
    for distance in (4.0, 8.0, 16.0, 32.0):
        crop_camera, translation, error, derivative = jax.tree.map(np.asarray, compare(distance))
        assert_allclose(translation, [0.6, -0.4, distance], rtol=1e-12)
        assert_allclose(derivative, crop_camera[0] * np.eye(2), rtol=1e-12)
        errors.append(float(error))
    assert errors[-1] < 0.05  # a few per cent at 32 m, 0.7 m off the optical axis
    for nearer, farther in zip(errors, errors[1:]):
        assert farther < 0.55 * nearer  # halves as the distance doubles


# ----------------------------------------------------------------------------------------------
# Causal TCN

CHANNELS, FRAMES = 8, 20


@pytest.fixture(scope="module")
def tcn():
    return build(lambda: CausalTCN(CHANNELS, groups=2, rngs=nnx.Rngs(rbg_key(3))))


def test_tcn_shapes_jit_causality_and_gradients(tcn):
    """One batch of FRAMES + 1 sequences, arranged (3, 7): sequence t has frame t perturbed, the last is the
    original. Perturbing frame t leaves every earlier output bit-identical and changes output t."""
    x = normal(0, (FRAMES, CHANNELS))
    perturbed = np.concatenate([x[None] + np.eye(FRAMES)[:, :, None], x[None]]).reshape(3, 7, FRAMES, CHANNELS)
    outputs, gradients = jitted(tcn)(perturbed)
    assert outputs.shape == perturbed.shape and tcn.receptive_field == 13
    assert_allclose(eager(tcn, perturbed[1, 2]), outputs[1, 2], rtol=1e-9, atol=1e-12)
    outputs = outputs.reshape(FRAMES + 1, FRAMES, CHANNELS)
    for t in range(FRAMES):
        np.testing.assert_array_equal(outputs[t, :t], outputs[-1, :t])
        assert not np.array_equal(outputs[t, t], outputs[-1, t])
    assert_finite_gradients(gradients)


def test_tcn_output_t_sees_exactly_inputs_t_minus_12_to_t(tcn):
    graphdef, state = nnx.split(tcn)
    jacobian = jax.jit(jax.jacfwd(lambda x: nnx.merge(graphdef, state)(x)))(normal(1, (FRAMES, CHANNELS)))
    depends = np.any(np.asarray(jacobian) != 0.0, axis=(1, 3))  # (T out, T in); exact: an unreachable input
    t_out, t_in = np.meshgrid(np.arange(FRAMES), np.arange(FRAMES), indexing="ij")  # gets an exactly zero tangent
    np.testing.assert_array_equal(depends, (t_in <= t_out) & (t_in >= t_out - (tcn.receptive_field - 1)))


# ----------------------------------------------------------------------------------------------
# Pose prior and LSGAN losses


@pytest.fixture(scope="module")
def prior():
    return build(lambda: PosePrior(NUM_SHAPES, pose_hidden=32, rngs=nnx.Rngs(rbg_key(4))))


def test_prior_shapes_jit_root_and_gradients(prior):
    rotations = random_rotations(0, (2, 3, 24))
    betas = normal(1, (2, 3, NUM_SHAPES))
    run = jitted(prior)
    scores, gradients = run(rotations, betas)
    assert scores.shape == (2, 3, 25)
    assert_allclose(eager(prior, rotations[1, 2], betas[1, 2]), scores[1, 2], rtol=1e-9, atol=1e-12)
    assert_finite_gradients(gradients)

    def heads_changed_by(new_rotations, new_betas):
        return np.flatnonzero(np.any(run(new_rotations, new_betas)[0] != scores, axis=(0, 1)))

    # The root's global orientation is not judged; joint j's head sees only joint j + 1 (the full-pose head, 23,
    # sees all of them); the shape head, 24, sees only the betas.
    turned, bent = rotations.copy(), rotations.copy()
    turned[..., 0, :, :] = random_rotations(2, (2, 3))
    bent[..., 5, :, :] = np.eye(3)
    np.testing.assert_array_equal(heads_changed_by(turned, betas), [])
    np.testing.assert_array_equal(heads_changed_by(bent, betas), [4, 23])
    np.testing.assert_array_equal(heads_changed_by(rotations, betas + 1.0), [24])


def test_lsgan_losses():
    discriminator_loss, generator_loss = jax.jit(lsgan_discriminator_loss), jax.jit(lsgan_generator_loss)
    ones, zeros, halves = np.ones((4, 25)), np.zeros((4, 25)), np.full((4, 25), 0.5)
    assert float(discriminator_loss(ones, zeros)) == 0.0  # a perfect discriminator
    assert float(discriminator_loss(zeros, ones)) == 2.0  # a perfectly wrong one
    assert float(discriminator_loss(halves, halves)) == 0.5
    assert float(generator_loss(ones)) == 0.0  # the discriminator is fooled
    assert float(generator_loss(zeros)) == 1.0
    one_head_unfooled = ones.copy()
    one_head_unfooled[:, 3] = 0.0
    assert float(generator_loss(one_head_unfooled)) == pytest.approx(1 / 25)  # the mean over the heads
    real, fake = normal(0, (4, 25)), normal(1, (4, 25))
    grad_real, grad_fake = jax.jit(jax.grad(lsgan_discriminator_loss, argnums=(0, 1)))(real, fake)
    assert_allclose(grad_real, 2 * (real - 1) / real.size, rtol=1e-12)
    assert_allclose(grad_fake, 2 * fake / fake.size, rtol=1e-12)

"""FLEX network, FK layer, discriminator and losses (flex/_model.py, flex/_losses.py).

One module-scoped model of the "cpu" config on one small synthetic batch (2 sequences, 4 views, 16 frames) keeps
the file fast; the paper's config is only traced (``nnx.eval_shape`` / ``jax.eval_shape``).
"""

import dataclasses

import jax
import jax.numpy as jnp
import jaxtyping
import numpy as np
import optax
import pytest
from flax import nnx
from numpy.testing import assert_allclose

import geometry
from geometry import FLEX20, FLEX20_BONE_OF_JOINT, FLEX20_BONES, FLEX20_ROTATING
from flex import (
    CONFIGS, DataConfig, Discriminator, Flex, FlexConfig, LossWeights, discriminator_loss, flex_forward_kinematics,
    INDEPENDENT_ROTATIONS, generator_loss, make_batch, parameter_count, predict,
)

CPU = CONFIGS["cpu"]
FRAMES = 16


@pytest.fixture(scope="module")
def batch():
    return make_batch(jax.random.key(0), DataConfig(views=CPU.views, frames=FRAMES, camera_motion="dynamic"), 2)


@pytest.fixture(scope="module")
def model():
    """A model whose outputs depend on its input: the output layers are zero-initialised (an untrained model
    predicts the standing pose), so they get random weights here."""
    model = Flex(CPU, rngs=nnx.Rngs(0))
    for seed, layer in enumerate((model.rotation_branch.shrink, model.rotation_branch.view_head)):
        layer.kernel[...] = 0.1 * jax.random.normal(jax.random.key(seed), layer.kernel.shape, layer.kernel.dtype)
    return model


@pytest.fixture(scope="module")
def discriminator():
    return Discriminator(CPU, rngs=nnx.Rngs(1))


def jitted(model: Flex):
    """``model(points, confidences, key=key)`` under ``jax.jit`` with the state as an argument."""
    graphdef, state = nnx.split(model)

    @jax.jit
    def run(state, points, confidences, key):
        return nnx.merge(graphdef, state)(points, confidences, key=key)

    return lambda points, confidences, key=None: run(state, points, confidences, key)


@pytest.fixture(scope="module")
def run(model):
    return jitted(model)


@pytest.fixture(scope="module")
def outputs(run, batch):
    return run(batch.points_2d, batch.confidences)


def test_paper_config_traces_with_the_paper_sizes():
    config = CONFIGS["paper"]
    model = nnx.eval_shape(lambda: Flex(config, rngs=nnx.Rngs(0)))
    # The expansion maps 3J = 51 input channels to C = 1024; E_Q's shrink gives 4 x 14 + 2 + 5 K channels.
    assert model.rotation_branch.expand.layer.kernel.shape == (51, 1024)
    assert model.rotation_branch.shrink.kernel.shape == (1024, 4 * 14 + 2)
    assert model.rotation_branch.multi_view[0].layer.kernel.shape == (5, 5, 1024, 1024)
    assert model.bone_branch.shrink.kernel.shape == (1024, len(FLEX20_BONES))
    assert parameter_count(model) > 20e6
    graphdef, state = nnx.split(model)
    points = jax.ShapeDtypeStruct((2, 4, 196, 17, 2), jnp.float32)
    confidences = jax.ShapeDtypeStruct((2, 4, 196, 17), jnp.float32)
    out = jax.eval_shape(lambda s, p, c: nnx.merge(graphdef, s)(p, c), state, points, confidences)
    assert out.joints.shape == (2, 4, 196, 20, 3) and out.bone_lengths.shape == (2, 10)


def test_cpu_output_shapes(outputs):
    b, k, t = 2, CPU.views, FRAMES
    expected = {
        "rotations": (b, t, 14, 4), "root_rotations": (b, k, t, 4), "contacts": (b, t, 2), "root_depth": (b, k, t),
        "root_position": (b, k, t, 3), "bone_lengths": (b, 10), "joints_relative": (b, k, t, 20, 3),
        "joints": (b, k, t, 20, 3), "scale": (b, k), "centre": (b, k, 2),
    }
    assert {name: value.shape for name, value in outputs._asdict().items()} == expected
    assert all(bool(jnp.all(jnp.isfinite(value))) for value in outputs)
    assert_allclose(jnp.linalg.norm(outputs.rotations, axis=-1), 1.0, atol=1e-6)
    assert_allclose(jnp.linalg.norm(outputs.root_rotations, axis=-1), 1.0, atol=1e-6)
    assert bool(jnp.all(outputs.bone_lengths > 0)) and bool(jnp.all(outputs.root_depth > 0))
    assert bool(jnp.all((outputs.contacts > 0) & (outputs.contacts < 1)))
    assert_allclose(outputs.joints_relative[..., 0, :], 0.0, atol=1e-12)
    assert_allclose(outputs.joints[..., 0, :], outputs.root_position, atol=1e-12)


def test_jit_equals_eager(model, batch, outputs):
    eager = model(batch.points_2d, batch.confidences)
    for name, a, b in zip(outputs._fields, eager, outputs):
        assert_allclose(a, b, rtol=1e-4, atol=1e-5, err_msg=name)


def test_predict_is_the_deterministic_call_compiled(model, batch, outputs):
    predicted = predict(model, batch.points_2d, batch.confidences)
    for name, a, b in zip(outputs._fields, predicted, outputs):
        assert_allclose(a, b, rtol=1e-6, atol=1e-9, err_msg=name)
    with pytest.raises(ValueError, match="points_2d must be"):
        predict(model, batch.points_2d[:, :1], batch.confidences[:, :1])


def test_fk_has_exactly_the_predicted_symmetric_bone_lengths(outputs):
    lengths = geometry.bone_lengths(outputs.joints_relative, FLEX20)  # (B, K, T, 19): bone k ends at joint k + 1
    bone = np.asarray(FLEX20_BONE_OF_JOINT[1:])
    predicted = outputs.bone_lengths[:, None, None, :]
    expected = jnp.where(bone >= 0, jnp.take(predicted, np.maximum(bone, 0), axis=-1), 0.0)
    assert_allclose(lengths, jnp.broadcast_to(expected, lengths.shape), rtol=1e-9, atol=1e-12)
    for left, right in FLEX20.left_right_pairs:
        assert_allclose(lengths[..., left - 1], lengths[..., right - 1], rtol=1e-12)


def test_views_share_the_pose_up_to_a_rigid_transform(outputs):
    """Every view's pose is the same body turned by its root rotation: pose_k = R_k R_0^T pose_0."""
    roots = geometry.quaternion_to_matrix(outputs.root_rotations)  # (B, K, T, 3, 3)
    relative = jnp.einsum("bktij,btlj->bktil", roots, roots[:, 0])  # R_k R_0^T
    turned = jnp.einsum("bktij,btnj->bktni", relative, outputs.joints_relative[:, 0])
    assert_allclose(turned, outputs.joints_relative, atol=1e-9)
    poses = outputs.joints_relative
    distances = jnp.linalg.norm(poses[..., :, None, :] - poses[..., None, :, :], axis=-1)
    assert_allclose(distances, jnp.broadcast_to(distances[:, :1], distances.shape), atol=1e-9)


def test_fk_layer_normalises_quaternions_and_treats_zero_as_identity():
    # The batch's shapes (2 sequences, 4 views, 16 frames): the same compilation as the other tests.
    bones = jnp.tile(jnp.asarray([[0.1, 0.4, 0.4, 0.2, 0.25, 0.1, 0.1, 0.15, 0.3, 0.25]]), (2, 1))
    identity = jnp.zeros((2, FRAMES, 14, 4)).at[..., 0].set(1.0)
    root = jnp.zeros((2, CPU.views, FRAMES, 4)).at[..., 0].set(1.0)
    rest = flex_forward_kinematics(bones, identity, root)
    assert_allclose(flex_forward_kinematics(bones, 3.0 * identity, 0.0 * root), rest, atol=1e-12)
    # Totem rest pose: the head straight above the root, at the sum of the spine, neck and head bones.
    assert_allclose(rest[0, 0, 0, FLEX20.index("head")], [0.0, 0.2 + 0.25 + 0.1 + 0.1, 0.0], atol=1e-12)
    assert_allclose(rest[0, 0, 0, FLEX20.index("l_wrist")], [0.0, 0.2 + 0.25 + 0.15 + 0.3 + 0.25, 0.0], atol=1e-12)
    tpose = flex_forward_kinematics(bones, identity, root, "tpose")
    assert_allclose(tpose[0, 0, 0, FLEX20.index("l_wrist")], [0.15 + 0.3 + 0.25, 0.2 + 0.25, 0.0], atol=1e-12)
    assert_allclose(tpose[0, 0, 0, FLEX20.index("r_wrist")], [-(0.15 + 0.3 + 0.25), 0.2 + 0.25, 0.0], atol=1e-12)


def test_model_is_invariant_to_each_views_image_similarity(run, batch, outputs):
    """No calibration enters: another focal length / principal point / image size (a per-view shift and
    isotropic scale of the pixels) leaves every output unchanged except the normalisation's scale and centre."""
    scale = jnp.asarray([0.5, 1.0, 2.0, 3.3])[None, :, None, None, None]
    shift = jnp.asarray([[100.0, -40.0], [0.0, 0.0], [-300.0, 7.0], [12.0, 900.0]])[None, :, None, None, :]
    moved = run(batch.points_2d * scale + shift, batch.confidences)
    for name, a, b in zip(outputs._fields, outputs, moved):
        if name == "scale":
            assert_allclose(b, a * scale[..., 0, 0, 0], rtol=1e-9)
        elif name == "centre":
            assert_allclose(b, a * scale[..., 0, 0, :] + shift[:, :, 0, 0], rtol=1e-9)
        else:
            assert_allclose(a, b, rtol=1e-4, atol=1e-5, err_msg=name)


def test_untrained_model_predicts_a_person_standing_upright_and_facing_each_camera(batch):
    outputs = Flex(CPU, rngs=nnx.Rngs(3))(batch.points_2d, batch.confidences)
    pose = np.asarray(outputs.joints_relative)  # OpenCV camera frames: x right, y down, z away
    j = FLEX20.index
    assert np.all(pose[..., j("head"), 1] < -0.5) and np.all(pose[..., j("r_ankle"), 1] > 0.7)
    assert np.all(pose[..., j("l_hip"), 0] > 0.05) and np.all(pose[..., j("r_hip"), 0] < -0.05)  # facing the camera
    for side in ("l", "r"):  # shoulders sideways, arms hanging
        assert np.all(np.abs(pose[..., j(f"{side}_shoulder"), 0]) > 0.1)
        assert np.all(pose[..., j(f"{side}_wrist"), 1] > pose[..., j(f"{side}_elbow"), 1] + 0.1)
        assert np.all(pose[..., j(f"{side}_elbow"), 1] > pose[..., j(f"{side}_shoulder"), 1] + 0.1)


def test_per_view_outputs_follow_their_views(run, batch, outputs):
    """Each view's root rotation and depth come from its own features: a cyclic shift of the input views (the
    multi-view convolution is circular) shifts the per-view outputs with it and leaves the shared ones."""
    order = np.roll(np.arange(CPU.views), 1)
    shifted = run(batch.points_2d[:, order], batch.confidences[:, order])
    assert np.abs(np.asarray(outputs.root_rotations)[:, 1:] - np.asarray(outputs.root_rotations)[:, :1]).max() > 1e-2
    for name in ("root_rotations", "root_depth", "joints_relative"):
        assert_allclose(getattr(shifted, name), np.asarray(getattr(outputs, name))[:, order], atol=1e-5, err_msg=name)
    for name in ("rotations", "bone_lengths", "contacts"):
        assert_allclose(getattr(shifted, name), getattr(outputs, name), atol=1e-5, err_msg=name)


def test_discriminator_gets_gradients_on_every_joint(discriminator, batch, outputs):
    grads = nnx.grad(lambda d: discriminator_loss(d, outputs, batch))(discriminator)
    for module in (grads.joints, grads.root):
        for name in ("conv_in", "conv_out", "head"):
            per_joint = np.abs(np.asarray(getattr(module, name)[...])).reshape(getattr(module, name).shape[0], -1)
            assert np.all(per_joint.max(axis=1) > 0), name


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda p, c: (p[:, :3], c[:, :3]), "views"),
        (lambda p, c: (p[..., :10, :], c[..., :10]), "joints"),
        (lambda p, c: (p, c[..., :-1]), "confidences"),
        (lambda p, c: (p[:, :, :8], c[:, :, :8]), "at least 13 frames"),
    ],
)
def test_bad_shapes_raise(model, batch, change, message):
    # Under the test suite's jaxtyping checks an inconsistent annotation fails first, naming the argument.
    with pytest.raises((ValueError, jaxtyping.TypeCheckError), match=message):
        model(*change(batch.points_2d, batch.confidences))


def test_config_validation():
    assert CPU.min_frames == 13
    with pytest.raises(ValueError, match="multiple of heads"):
        FlexConfig(channels=30, heads=4)
    with pytest.raises(ValueError, match="dropout"):
        FlexConfig(dropout=1.0)


def _angles(joints, child_a: str, child_b: str, parent: str):
    """Per pose, the angle (radians) between the bones parent -> child_a and parent -> child_b."""
    a = joints[..., FLEX20.index(child_a), :] - joints[..., FLEX20.index(parent), :]
    b = joints[..., FLEX20.index(child_b), :] - joints[..., FLEX20.index(parent), :]
    cosine = np.sum(a * b, axis=-1) / np.linalg.norm(a, axis=-1) / np.linalg.norm(b, axis=-1)
    return np.arccos(np.clip(cosine, -1.0, 1.0))


def test_without_duplicate_joints_the_pelvis_and_the_thorax_are_rigid(model, batch, outputs):
    """Paper App. C: without the duplicates the bones next to the root (hips, spine) and next to the neck
    (shoulders, neck) keep their rest angles in every pose; with them (the module's model) they move independently."""
    def spreads(joints):
        return [np.ptp(_angles(joints, "l_hip", "spine", "mid_hip")),
                np.ptp(_angles(joints, "l_shoulder", "neck_nose", "thorax")),
                np.ptp(_angles(joints, "l_shoulder", "r_shoulder", "thorax"))]

    assert min(spreads(np.asarray(outputs.joints_relative))) > 0.05
    tied = Flex(dataclasses.replace(CPU, rest_pose="tpose", duplicate_joints=False), rngs=nnx.Rngs(0))
    nnx.update(tied, nnx.state(model))  # the same random output layers: poses far from the rest pose
    joints = np.asarray(predict(tied, batch.points_2d, batch.confidences).joints_relative)
    assert max(spreads(joints)) < 1e-4
    assert_allclose(_angles(joints, "l_shoulder", "neck_nose", "thorax"), np.pi / 2, atol=1e-4)


def test_skeleton_without_duplicates_needs_the_tpose_and_has_d_judge_the_free_joints(batch):
    with pytest.raises(ValueError, match="needs rest_pose 'tpose'"):
        FlexConfig(duplicate_joints=False)
    config = dataclasses.replace(CPU, rest_pose="tpose", duplicate_joints=False)
    scores, _ = Discriminator(config, rngs=nnx.Rngs(1))(batch.rotations, batch.root_rotations)
    assert scores.shape == (2, 11) and len(INDEPENDENT_ROTATIONS) == 11
    assert [FLEX20_ROTATING[i] for i in sorted(set(range(14)) - set(INDEPENDENT_ROTATIONS))] == [
        FLEX20.index(name) for name in ("spine_base", "l_thorax", "r_thorax")]


def test_discriminator_is_per_joint(discriminator, batch):
    """D_j sees only joint j: changing one joint's rotations changes only its score."""
    rotations, roots = jnp.asarray(batch.rotations), jnp.asarray(batch.root_rotations)
    scores, root_scores = discriminator(rotations, roots)
    assert scores.shape == (2, 14) and root_scores.shape == (2, CPU.views)
    assert bool(jnp.all((scores > 0) & (scores < 1)))
    noisy = rotations.at[:, :, 3].add(jax.random.normal(jax.random.key(0), rotations[:, :, 3].shape))
    changed, changed_roots = discriminator(noisy, roots)
    differs = np.asarray(jnp.abs(changed - scores) > 0).any(axis=0)
    assert differs.tolist() == [j == 3 for j in range(14)]
    assert_allclose(changed_roots, root_scores)


def test_losses_are_finite_and_zero_where_the_prediction_is_exact(outputs, batch, discriminator):
    total, terms = generator_loss(outputs, batch, discriminator)
    assert bool(jnp.isfinite(total)) and all(bool(jnp.isfinite(v)) and float(v) >= 0 for v in terms.values())
    # The ground truth itself, fed through the output structure, has zero position, skeleton and depth loss
    # (the FK of the ground-truth rotations reproduces the poses up to the asymmetry of the real skeleton).
    relative = flex_forward_kinematics(batch.bone_lengths, batch.rotations, batch.root_rotations)
    exact = outputs._replace(joints_relative=relative, bone_lengths=jnp.asarray(batch.bone_lengths),
                             root_depth=jnp.asarray(batch.root_position[..., 2]))
    _, exact_terms = generator_loss(exact, batch, discriminator)
    assert float(exact_terms["skeleton"]) == 0.0 and float(exact_terms["root"]) == 0.0
    assert float(exact_terms["position"]) < 1e-3  # alpha^2: millimetres


def test_length_losses_are_in_units_of_the_mean_bone_length(outputs, batch, discriminator):
    """L_P, L_S, L_R and L_FC measure lengths in units of the sample's mean bone length: scaling the whole scene
    (prediction and ground truth) leaves them unchanged."""
    _, terms = generator_loss(outputs, batch, discriminator)
    c = 1.7
    scaled_outputs = outputs._replace(joints_relative=c * outputs.joints_relative, joints=c * outputs.joints,
                                      bone_lengths=c * outputs.bone_lengths, root_depth=c * outputs.root_depth)
    scaled_batch = batch._replace(joints=c * batch.joints, bone_lengths=c * batch.bone_lengths,
                                  root_position=c * batch.root_position)
    _, scaled = generator_loss(scaled_outputs, scaled_batch, discriminator)
    for name in ("position", "skeleton", "root", "contact_velocity"):
        assert float(terms[name]) > 0, name
        assert_allclose(scaled[name], terms[name], rtol=1e-5, err_msg=name)  # bones are float32


ADVERSARIAL_ONLY = LossWeights(position=0.0, skeleton=0.0, adversarial=1.0, root=0.0, contact=0.0,
                               contact_velocity=0.0)


def dropout_key(seed: int) -> jax.Array:
    """XLA's RngBitGenerator draws the dropout masks: the training step compiles several seconds faster on CPU
    than with one threefry kernel per dropout layer."""
    return jax.random.key(seed, impl="rbg")


@pytest.fixture(scope="module")
def training(model, discriminator, batch):
    """The states of the module's model and D, and one jitted AdamW step for each (pure: the fixtures' modules
    stay unchanged). The generator step takes the loss weights (Eq. 9's sum recomputed from the terms) and the
    dropout key as arguments, so every test shares one compilation."""
    graphdef, params, rest = nnx.split(model, nnx.Param, ...)
    d_graphdef, d_params = nnx.split(discriminator, nnx.Param)
    optimiser = optax.adamw(1e-3)

    @jax.jit
    def generator_step(params, rest, opt_state, d_params, key, weights):
        def loss(params):
            # copy: fresh variables at this trace level, which batch norm may update inside the gradient.
            model = nnx.merge(graphdef, params, rest, copy=True)
            outputs = model(batch.points_2d, batch.confidences, key=key)
            _, terms = generator_loss(outputs, batch, nnx.merge(d_graphdef, d_params))
            total = sum(w * terms[f.name] for w, f in zip(weights, dataclasses.fields(LossWeights)))
            return total, (outputs, nnx.state(model, nnx.Not(nnx.Param)))

        (total, (outputs, rest)), grads = jax.value_and_grad(loss, has_aux=True)(params)
        updates, opt_state = optimiser.update(grads, opt_state, params)
        return optax.apply_updates(params, updates), rest, opt_state, total, grads, outputs

    @jax.jit
    def discriminator_step(d_params, opt_state, outputs):
        def loss(d_params):
            return discriminator_loss(nnx.merge(d_graphdef, d_params), outputs, batch)

        value, grads = jax.value_and_grad(loss)(d_params)
        updates, opt_state = optimiser.update(grads, opt_state, d_params)
        return optax.apply_updates(d_params, updates), opt_state, value

    return params, rest, d_params, optimiser, generator_step, discriminator_step


def _weights(weights: LossWeights):
    return jnp.asarray(dataclasses.astuple(weights))


def test_adversarial_gradient_reaches_the_generator(training, batch, outputs, discriminator):
    params, rest, d_params, optimiser, generator_step, _ = training
    step = generator_step(params, rest, optimiser.init(params), d_params, dropout_key(0), _weights(ADVERSARIAL_ONLY))
    grads = step[4]
    assert float(step[3]) > 0 and all(bool(jnp.all(jnp.isfinite(g))) for g in jax.tree.leaves(grads))
    # Through D into E_Q's output layer and on into F_Q's first layer; rotations do not depend on the bone branch.
    assert float(optax.tree.norm(grads["rotation_branch"]["shrink"])) > 0
    assert float(optax.tree.norm(grads["rotation_branch"]["expand"])) > 0
    assert float(optax.tree.norm(grads["bone_branch"])) == 0
    # D's own loss sees the predictions detached: no gradient for the generator from it.
    def d_loss(rotations, root_rotations):
        fake = outputs._replace(rotations=rotations, root_rotations=root_rotations)
        return discriminator_loss(discriminator, fake, batch)

    grads = jax.grad(d_loss, argnums=(0, 1))(outputs.rotations, outputs.root_rotations)
    assert all(float(jnp.max(jnp.abs(g))) == 0 for g in grads)


def test_a_few_adamw_steps_reduce_the_losses(training):
    params, rest, d_params, optimiser, generator_step, discriminator_step = training
    weights = _weights(LossWeights())
    key = dropout_key(7)  # one dropout mask for every step: the objective stays fixed
    opt_state = optimiser.init(params)
    other = generator_step(params, rest, opt_state, d_params, dropout_key(8), weights)
    losses = []
    for _ in range(8):
        params, rest, opt_state, total, _, outputs = generator_step(params, rest, opt_state, d_params, key, weights)
        losses.append(float(total))
    assert losses[-1] < 0.9 * losses[0], losses
    assert float(other[3]) != losses[0]  # training mode: the dropout key matters

    d_state = optimiser.init(d_params)
    d_losses = []
    for _ in range(8):
        d_params, d_state, value = discriminator_step(d_params, d_state, outputs)
        d_losses.append(float(value))
    assert d_losses[-1] < d_losses[0], d_losses


def test_rotating_joint_table_matches_the_skeleton():
    # 14 rotating joints: every non-root joint with a child (end effectors carry no rotation).
    with_child = {p for p in FLEX20.parents if p > 0}
    assert set(FLEX20_ROTATING) == with_child and len(FLEX20_ROTATING) == 14

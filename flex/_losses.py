"""FLEX's losses (paper Eq. 3-9) as pure functions of the model's :class:`~flex.FlexOutputs` and a :class:`~flex.Batch`.

Each term is the mean over the batch (the paper's expectation) and over the entries it repeats over (views,
frames, joints) of a squared Euclidean norm of the paper's natural vector: a joint's xyz for L_P, the skeleton's
10 lengths for L_S, a scalar for L_R, a frame's 2 contacts for L_F, a foot's velocity for L_FC. Lengths are in
units of the sample's scale ``alpha``, the mean of its 10 true bone lengths (about 0.23 m), as the official code
normalises its 3D targets (``docs/flex.md``): in metres the squared position errors would be about 20 times
smaller and the adversarial term, an order of magnitude larger than all of them, would outweigh them. Readings
of the paper, on purpose (``docs/flex.md``):

- L_P (Eq. 3) compares the 17 Human3.6M joints (the FLEX20 duplicates dropped: they repeat the root and the
  thorax), root-relative, in each view's camera frame with the root rotation kept.
- L_Q-GAN (Eq. 5) is LSGAN as in the official trainer: the generator term ``(1 - D(fake))^2`` back-propagates
  through D into E_Q (the official code detaches it); D minimises ``(1 - D(real))^2 + D(fake)^2`` with the
  fakes detached (Eq. 5 prints ``D(real)^2``, which read literally would make real and fake the same target).
  Eq. 9 sums the terms over the 14 joints and over the K views' root rotations.
- L_FC (Eq. 8) penalises a contact foot's camera-frame velocity relative to the ground truth's,
  ``f_i |Delta_t FK_i - Delta_t P_i|^2``: with static cameras the ground-truth foot is still during contact and
  this is Eq. 8, while with moving cameras (the dynamic setting) a foot on the ground moves in the camera
  frame and only the difference stays zero. Both positions include the root position, in the normalised
  camera frame of :mod:`flex._model`.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

import geometry
from geometry import FLEX20, STRUCTRI17

from ._data import Batch
from ._model import Discriminator, FlexOutputs

__all__ = [
    "LossWeights", "position_loss", "skeleton_loss", "root_loss", "contact_loss", "contact_velocity_loss",
    "adversarial_loss", "discriminator_loss", "generator_loss",
]

_FEET = (FLEX20.index("r_ankle"), FLEX20.index("l_ankle"))


@dataclasses.dataclass(frozen=True)
class LossWeights:
    """The weights of Eq. 9 (the paper's values: "in most experiments")."""

    position: float = 1.0
    skeleton: float = 0.1
    adversarial: float = 1.0
    root: float = 1.3
    contact: float = 0.5
    contact_velocity: float = 0.5


def _squared_norm(v: Float[Array, "*b d"]) -> Float[Array, "*b"]:
    return jnp.sum(v * v, axis=-1)


def _scaled(v: Float[Array, "batch *rest"], batch: Batch) -> Float[Array, "batch *rest"]:
    """Lengths ``v`` (metres) in units of each sample's mean true bone length ``alpha``."""
    alpha = jnp.mean(batch.bone_lengths, axis=-1).astype(v.dtype)
    return v / alpha.reshape(-1, *(1,) * (v.ndim - 1))


def position_loss(outputs: FlexOutputs, batch: Batch) -> Float[Array, ""]:
    """L_P (Eq. 3): mean squared distance (alpha^2) of the root-relative camera-frame STRUCTRI17 joints, all views."""
    predicted = geometry.remap_joints(outputs.joints_relative, FLEX20, STRUCTRI17)
    return jnp.mean(_squared_norm(_scaled(predicted - batch.joints.astype(predicted.dtype), batch)))


def skeleton_loss(outputs: FlexOutputs, batch: Batch) -> Float[Array, ""]:
    """L_S (Eq. 4): squared error of the 10 bone lengths (alpha^2), summed over the bones."""
    return jnp.mean(_squared_norm(
        _scaled(outputs.bone_lengths - batch.bone_lengths.astype(outputs.bone_lengths.dtype), batch)))


def root_loss(outputs: FlexOutputs, batch: Batch) -> Float[Array, ""]:
    """L_R (Eq. 6): squared error of the normalised root depth (alpha^2), all views and frames."""
    target = batch.root_position[..., 2].astype(outputs.root_depth.dtype)
    return jnp.mean(jnp.square(_scaled(outputs.root_depth - target, batch)))


def contact_loss(outputs: FlexOutputs, batch: Batch) -> Float[Array, ""]:
    """L_F (Eq. 7): squared error of the two foot-contact probabilities per frame."""
    return jnp.mean(_squared_norm(outputs.contacts - batch.contacts.astype(outputs.contacts.dtype)))


def contact_velocity_loss(outputs: FlexOutputs, batch: Batch) -> Float[Array, ""]:
    """L_FC (Eq. 8): ``f_i |Delta_t foot_i - Delta_t foot_i^gt|^2`` (alpha^2 per frame), ground-truth contacts ``f``."""
    feet = outputs.joints[..., _FEET, :]  # (B, K, T, 2, 3)
    true_feet = (batch.root_position[..., None, :] + geometry.flex20_from_structri17(batch.joints)[..., _FEET, :])
    velocity = jnp.diff(feet, axis=2) - jnp.diff(true_feet.astype(feet.dtype), axis=2)
    contact = batch.contacts[:, None, 1:, :].astype(feet.dtype)  # (B, 1, T - 1, 2)
    return jnp.mean(contact * _squared_norm(_scaled(velocity, batch)))


def adversarial_loss(outputs: FlexOutputs, discriminator: Discriminator) -> Float[Array, ""]:
    """The generator's L_Q-GAN (Eq. 5 and 9): ``sum_j mean (1 - D_j)^2`` over the 14 joints and the K roots.

    D's parameters are constants here, but the gradient reaches E_Q through D's input."""
    joint_scores, root_scores = discriminator(outputs.rotations, outputs.root_rotations)
    return jnp.sum(jnp.mean(jnp.square(1.0 - joint_scores), axis=0)) + jnp.sum(
        jnp.mean(jnp.square(1.0 - root_scores), axis=0))


def discriminator_loss(discriminator: Discriminator, outputs: FlexOutputs, batch: Batch) -> Float[Array, ""]:
    """D's LSGAN loss: real ground-truth rotations towards 1, the (detached) predictions towards 0."""
    real_joints, real_roots = discriminator(batch.rotations, batch.root_rotations)
    fake_joints, fake_roots = discriminator(
        jax.lax.stop_gradient(outputs.rotations), jax.lax.stop_gradient(outputs.root_rotations))

    def terms(real: Array, fake: Array) -> Array:
        return jnp.sum(jnp.mean(jnp.square(1.0 - real), axis=0) + jnp.mean(jnp.square(fake), axis=0))

    return terms(real_joints, fake_joints) + terms(real_roots, fake_roots)


def generator_loss(
    outputs: FlexOutputs, batch: Batch, discriminator: Discriminator, weights: LossWeights = LossWeights()
) -> tuple[Float[Array, ""], dict[str, Float[Array, ""]]]:
    """Eq. 9: the weighted sum of all terms, and each unweighted term by name."""
    terms = {
        "position": position_loss(outputs, batch),
        "skeleton": skeleton_loss(outputs, batch),
        "adversarial": adversarial_loss(outputs, discriminator),
        "root": root_loss(outputs, batch),
        "contact": contact_loss(outputs, batch),
        "contact_velocity": contact_velocity_loss(outputs, batch),
    }
    total = sum(getattr(weights, name) * value.astype(jnp.result_type(float)) for name, value in terms.items())
    return total, terms

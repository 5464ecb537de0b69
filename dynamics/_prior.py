"""The adversarial pose and shape prior of HMR / HMMR (Kanazawa et al. 2018, 2019; thesis Sect. 3.2.4, spec
sections 2 and 3): 25 least-squares GAN discriminators on SMPL parameters.

Following HMR's ``Discriminator_separable_rotations``: the 23 non-root rotation matrices (the root's global
orientation carries no pose prior) go through a shared embedding of two 1x1 convolutions (9 -> 32 -> 32, ReLU,
i.e. the same two layers for every joint); then

- 23 joint heads: one linear score per joint from its own embedding;
- 1 full-pose head: FC -> ReLU -> FC -> ReLU -> 1 on the 23 embeddings concatenated (HMR: 1024 units);
- 1 shape head: FC -> ReLU -> FC -> ReLU -> 1 on the betas (HMR: 10 then 5 units).

Scores are unbounded (LSGAN: no sigmoid); the column order is [23 joints, full pose, shape].
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import nnx
from jaxtyping import Array, Float

__all__ = ["PosePrior", "lsgan_discriminator_loss", "lsgan_generator_loss"]

NUM_PRIOR_JOINTS = 23
"""SMPL's joints without the root."""


class PosePrior(nnx.Module):
    """Rotation matrices and shape -> 25 discriminator scores (module docstring); ``pose_hidden`` defaults to a
    CPU size (HMR: 1024)."""

    def __init__(
        self,
        num_shapes: int = 10,
        joint_channels: int = 32,
        pose_hidden: int = 512,
        shape_hidden: tuple[int, int] = (10, 5),
        *,
        rngs: nnx.Rngs,
    ) -> None:
        self.embed1 = nnx.Linear(9, joint_channels, rngs=rngs)
        self.embed2 = nnx.Linear(joint_channels, joint_channels, rngs=rngs)
        # The 23 joint heads, vectorised: row j is joint j's linear score.
        init = nnx.initializers.lecun_normal(in_axis=1, out_axis=2, batch_axis=(0,))
        self.joint_heads = nnx.Param(init(rngs.params(), (NUM_PRIOR_JOINTS, joint_channels, 1), jnp.float32)[..., 0])
        self.joint_heads_bias = nnx.Param(jnp.zeros((NUM_PRIOR_JOINTS,), jnp.float32))
        self.pose_fc1 = nnx.Linear(NUM_PRIOR_JOINTS * joint_channels, pose_hidden, rngs=rngs)
        self.pose_fc2 = nnx.Linear(pose_hidden, pose_hidden, rngs=rngs)
        self.pose_out = nnx.Linear(pose_hidden, 1, rngs=rngs)
        self.shape_fc1 = nnx.Linear(num_shapes, shape_hidden[0], rngs=rngs)
        self.shape_fc2 = nnx.Linear(shape_hidden[0], shape_hidden[1], rngs=rngs)
        self.shape_out = nnx.Linear(shape_hidden[1], 1, rngs=rngs)

    def __call__(
        self, rotations: Float[Array, "*b 24 3 3"], betas: Float[Array, "*b S"]
    ) -> Float[Array, "*b 25"]:
        """Scores of SMPL24 local rotation matrices (the root's is ignored) and shape coefficients."""
        batch = rotations.shape[:-3]
        joints = rotations[..., 1:, :, :].reshape(*batch, NUM_PRIOR_JOINTS, 9)
        embedded = jax.nn.relu(self.embed2(jax.nn.relu(self.embed1(joints))))  # (*b, 23, channels)
        joint_scores = (jnp.einsum("...jc,jc->...j", embedded, self.joint_heads[...])
                        + self.joint_heads_bias[...].reshape((1,) * len(batch) + (NUM_PRIOR_JOINTS,)))
        pose = embedded.reshape(*batch, -1)
        pose_score = self.pose_out(jax.nn.relu(self.pose_fc2(jax.nn.relu(self.pose_fc1(pose)))))
        shape_score = self.shape_out(jax.nn.relu(self.shape_fc2(jax.nn.relu(self.shape_fc1(betas)))))
        return jnp.concatenate([joint_scores, pose_score, shape_score], axis=-1)


def lsgan_discriminator_loss(
    real_scores: Float[Array, "*real 25"], fake_scores: Float[Array, "*fake 25"]
) -> Float[Array, ""]:
    """LSGAN discriminator loss (thesis Eq. 3.11): ``mean (D(real) - 1)^2 + mean D(fake)^2``, each mean over the
    samples and the 25 heads. HMR sums over the heads instead: its loss is 25 times this one."""
    return jnp.mean(jnp.square(real_scores - 1.0)) + jnp.mean(jnp.square(fake_scores))


def lsgan_generator_loss(fake_scores: Float[Array, "*fake 25"]) -> Float[Array, ""]:
    """LSGAN adversarial loss of the regressor (thesis Eq. 3.12): ``mean (D(fake) - 1)^2`` over the samples and
    the 25 heads (HMR sums over the heads: 25 times this)."""
    return jnp.mean(jnp.square(fake_scores - 1.0))

"""The Joint-Aware Bias of JAT and MPJAT (thesis Sect. 4.3.2 and 4.4.3): canonicalised joints and poses of a key
frame relative to the query frame (Eq. 4.23-4.26, 4.37-4.38) and the MLP f_JAB that maps them to an attention
bias (Eq. 4.27; MPJAT trains two of them, f_JABS and f_JABO, Eq. 4.39).

The query frame ``t`` of person ``n`` defines an egocentric frame ``H_t = [R_t^0, J_t^0]``: its pelvis
orientation (SMPL's global root rotation) and pelvis position. A key frame ``j`` of person ``o`` (``o = n`` for
JAT) is expressed in it: joints ``H_t^-1 J_j = (R_t^0)^T (J_j - J_t^0)`` and, per joint, the rotation from the
query's to the key's.

**Root rotation, a decision:** for joints 1..23 (local rotations) the relative rotation is ``R_j R_t^-1`` as
Eq. 4.25 / 4.38 print it. For the root it is ``R_t^-1 R_j = (R_t^0)^T R_j^0``: the key's pelvis orientation
expressed in the query's egocentric frame, like the joints. The printed ``R_j R_t^-1`` is that rotation
conjugated by ``R_t^0`` (a camera-frame quantity); unlike it, ours is invariant to a global rigid motion of the
scene, so the bias depends on the people's relative poses only.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import nnx
from jaxtyping import Array, Float

__all__ = ["JointAwareBias", "canonical_features", "canonicalise"]

CANONICAL_FEATURES = 24 * 3 + 24 * 9
"""One row of ``Lambda`` (Eq. 4.26): 72 joint coordinates and 216 rotation entries."""


def canonicalise(
    query_joints: Float[Array, "24 3"],
    query_rotations: Float[Array, "24 3 3"],
    key_joints: Float[Array, "24 3"],
    key_rotations: Float[Array, "24 3 3"],
) -> tuple[Float[Array, "24 3"], Float[Array, "24 3 3"]]:
    """The key frame's joints and rotations in the query frame's egocentric frame (module docstring).

    Joints: camera-frame positions, the pelvis (joint 0) at the root ``gamma``. Rotations: SMPL's, joint 0 the
    camera-frame pelvis orientation, 1..23 local. At ``key == query``: all rotations are the identity and the
    pelvis is at the origin."""
    root_rotation = query_rotations[0]
    # Row vectors: R^T (J - J0) for each joint is (J - J0) @ R.
    joints = (key_joints - query_joints[:1]) @ root_rotation
    # Rotations are orthogonal: their inverse is their transpose.
    root = root_rotation.T @ key_rotations[0]
    local = key_rotations[1:] @ jnp.swapaxes(query_rotations[1:], -1, -2)
    return joints, jnp.concatenate([root[None], local], axis=0)


def canonical_features(
    query_joints: Float[Array, "24 3"],
    query_rotations: Float[Array, "24 3 3"],
    key_joints: Float[Array, "24 3"],
    key_rotations: Float[Array, "24 3 3"],
) -> Float[Array, "288"]:
    """One row of ``Lambda`` (Eq. 4.26): the flattened canonical joints, then the flattened rotations. ``vmap``
    it over query-key pairs."""
    joints, rotations = canonicalise(query_joints, query_rotations, key_joints, key_rotations)
    return jnp.concatenate([joints.reshape(-1), rotations.reshape(-1)])


class JointAwareBias(nnx.Module):
    """f_JAB (Eq. 4.27): ``C = gelu(Lambda W1) W2``, one scalar bias per row of features. No activation on the
    output, so the bias can raise or lower an attention weight (thesis: 576 hidden units)."""

    def __init__(self, hidden: int = 576, *, rngs: nnx.Rngs) -> None:
        self.fc1 = nnx.Linear(CANONICAL_FEATURES, hidden, rngs=rngs)
        self.fc2 = nnx.Linear(hidden, 1, rngs=rngs)

    def __call__(self, features: Float[Array, "*b 288"]) -> Float[Array, "*b"]:
        return self.fc2(jax.nn.gelu(self.fc1(features), approximate=False))[..., 0]

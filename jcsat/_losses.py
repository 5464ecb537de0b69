"""The JCSAT training losses (paper Sec. 3.4, Eq. 11-15) as pure functions of a prediction and a :class:`Batch`.

All terms work in the batch's model frame (metres) and on Shelf15 joints; 2D terms use each view's
``Batch.projections`` (which already undo the augmentation) and divide pixels by the image size, so
one unit is the image width or height (the official code's "resolution-normalised" coordinates).
Means run over the valid (window, frame, joint) entries of the whole batch; a batch without any
valid target contributes 0 rather than NaN. Differences from the paper's text, on purpose:

- The paper's normalisers ``1 / (N + I)`` are read as the mean over the ``N x I`` entries.
- L_bone (Eq. 14) uses the Shelf15 limbs (upper/lower arms and legs, 8 bones, 4 left/right pairs):
  the model outputs Shelf15, which has no eyes or ears. It needs no ground truth, so it covers every
  frame of every window; the symmetry term sums over all N frames (Eq. 14 prints n = 2..N).
- Projections clamp the depth at ``min_depth`` metres, so a prediction behind a camera gives a large
  but finite loss and gradient instead of a division by ~0.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

import geometry
from geometry import SHELF15

from ._data import Batch

__all__ = [
    "LossConfig",
    "project_normalised",
    "reconstruction_loss",
    "projection_loss",
    "pcp_hinge_loss",
    "bone_losses",
    "jcsat_loss",
]


@dataclasses.dataclass(frozen=True)
class LossConfig:
    """Weights of the terms of Eq. 15 (the paper uses 1 for all) and the projection's depth clamp."""

    rec: float = 1.0
    """L_rec, Eq. 11 (m^2)."""
    proj: float = 1.0
    """L_proj, Eq. 12 (image units, summed over views)."""
    pcp: float = 1.0
    """L_pcp, Eq. 13, in 3D (m)."""
    pcp_proj: float = 1.0
    """The projected L_pcp (image units, summed over views)."""
    bone_temporal: float = 1.0
    """First term of L_bone, Eq. 14 (m^2)."""
    bone_symmetry: float = 1.0
    """Second term of L_bone, Eq. 14 (m^2)."""
    min_depth: float = 0.1
    """Metres: depths are clamped to at least this before the perspective division."""

    def __post_init__(self) -> None:
        if self.min_depth <= 0:
            raise ValueError(f"min_depth must be positive (metres), got {self.min_depth}")


def _masked_mean(values: Float[Array, "*b"], mask: Bool[Array, "*b"]) -> Float[Array, ""]:
    return jnp.sum(jnp.where(mask, values, 0.0)) / jnp.maximum(jnp.sum(mask), 1)


def project_normalised(
    projections: Float[Array, "B V 3 4"],
    image_size: Float[Array, "B V 2"],
    points: Float[Array, "B N K 3"],
    min_depth: float,
) -> Float[Array, "B V N K 2"]:
    """Pixels divided by the image size, ``(u / width, v / height)``, of model-frame points in every view.

    ``projections`` are ``K [R | t]``-type matrices whose third row gives the depth in metres, which
    is clamped at ``min_depth`` (see the module docstring).
    """
    homogeneous = jnp.concatenate([points, jnp.ones_like(points[..., :1])], axis=-1)
    image = jnp.einsum("bvij,bnkj->bvnki", projections, homogeneous)
    depth = jnp.maximum(image[..., 2:], min_depth)
    size = image_size[:, :, None, None, :]
    return image[..., :2] / depth / size


def reconstruction_loss(
    pred: Float[Array, "B N K 3"], target: Float[Array, "B N K 3"], valid: Bool[Array, "B N"]
) -> Float[Array, ""]:
    """L_rec (Eq. 11): mean squared Euclidean error (m^2) over the joints of the valid frames."""
    squared = jnp.sum((pred - target) ** 2, axis=-1)
    return _masked_mean(squared, jnp.broadcast_to(valid[:, :, None], squared.shape))


def projection_loss(
    pred_2d: Float[Array, "B V N K 2"], target_2d: Float[Array, "B V N K 2"], valid: Bool[Array, "B N"]
) -> Float[Array, ""]:
    """L_proj (Eq. 12) on projected points (:func:`project_normalised`): per view the mean 2D distance
    (image units) over the joints of the valid frames, summed over views."""
    distance = geometry.safe_norm(pred_2d - target_2d)  # (B, V, N, K)
    mask = jnp.broadcast_to(valid[:, None, :, None], distance.shape)
    total = jnp.sum(jnp.where(mask, distance, 0.0), axis=(0, 2, 3))
    return jnp.sum(total / jnp.maximum(jnp.sum(mask, axis=(0, 2, 3)), 1))


_PCP_START, _PCP_END = (np.array(ix) for ix in zip(*SHELF15.pcp_index))


def pcp_hinge_loss(
    pred: Float[Array, "*b N K d"], target: Float[Array, "*b N K d"], valid: Bool[Array, "*b N"]
) -> Float[Array, ""]:
    """L_pcp (Eq. 13) over the ten Shelf15 PCP parts (a, b): mean of ``relu(|p_a - g_a| + |p_b - g_b| - |g_a - g_b|)``.

    Zero exactly when every part is correct under the strict PCP rule at alpha 0.5. Works in 3D
    (``d = 3``, metres) and, with a leading view axis in ``*b`` and ``valid`` broadcast to it, on
    projections (``d = 2``); the mean then runs over views too, so multiply by V for a per-view sum.
    """
    error = geometry.safe_norm(pred - target)
    limb = geometry.safe_norm(target[..., _PCP_START, :] - target[..., _PCP_END, :])
    hinge = jnp.maximum(error[..., _PCP_START] + error[..., _PCP_END] - limb, 0.0)
    return _masked_mean(hinge, jnp.broadcast_to(valid[..., None], hinge.shape))


_LIMB_PARTS = [(name, a, b) for name, a, b in SHELF15.pcp_parts if name.startswith(("l_", "r_"))]
_BONE_OF = {bone: k for k, bone in enumerate(SHELF15.bones)}
_LIMB_BONES = np.array([_BONE_OF[SHELF15.index(a), SHELF15.index(b)] for _, a, b in _LIMB_PARTS])
"""Indices into ``SHELF15.bones`` (== geometry.bone_lengths order) of the 8 arm and leg bones."""
_LIMB_NAMES = [name for name, _, _ in _LIMB_PARTS]
_LEFT, _RIGHT = (np.array(ix) for ix in zip(*[
    (_LIMB_NAMES.index(name), _LIMB_NAMES.index("r_" + name[2:])) for name in _LIMB_NAMES if name.startswith("l_")
]))


def bone_losses(pred: Float[Array, "B N 15 3"]) -> tuple[Float[Array, ""], Float[Array, ""]]:
    """The two terms of L_bone (Eq. 14) on the predicted limb lengths (m^2), without ground truth.

    Returns (temporal, symmetry): the mean squared change of each limb's length between consecutive
    frames, and the mean squared left/right difference of the paired limbs.
    """
    lengths = geometry.bone_lengths(pred, SHELF15)[..., _LIMB_BONES]  # (B, N, 8)
    change = lengths[:, 1:] - lengths[:, :-1]
    temporal = jnp.sum(change**2) / max(change.size, 1)  # a one-frame window has no change: 0, not NaN
    symmetry = jnp.mean((lengths[..., _LEFT] - lengths[..., _RIGHT]) ** 2)
    return temporal, symmetry


def jcsat_loss(
    pred: Float[Array, "B N 15 3"], batch: Batch, config: LossConfig = LossConfig()
) -> tuple[Float[Array, ""], dict[str, Float[Array, ""]]]:
    """Eq. 15: the weighted sum of all terms, and each (unweighted) term by name."""
    valid = batch.target_valid
    pred = pred.astype(batch.target.dtype)
    pred_2d = project_normalised(batch.projections, batch.image_size, pred, config.min_depth)
    target_2d = project_normalised(batch.projections, batch.image_size, batch.target, config.min_depth)
    views = batch.projections.shape[1]
    view_valid = jnp.broadcast_to(valid[:, None, :], pred_2d.shape[:3])
    temporal, symmetry = bone_losses(pred)
    terms = {
        "rec": reconstruction_loss(pred, batch.target, valid),
        "proj": projection_loss(pred_2d, target_2d, valid),
        "pcp": pcp_hinge_loss(pred, batch.target, valid),
        "pcp_proj": views * pcp_hinge_loss(pred_2d, target_2d, view_valid),
        "bone_temporal": temporal,
        "bone_symmetry": symmetry,
    }
    total = sum(getattr(config, name) * value for name, value in terms.items())
    return total, terms

"""FLEX's input normalisation: 2D joints in pixels -> calibration-free features, one view at a time.

FLEX uses no intrinsic or extrinsic parameters (paper Sec. 3 and App. E.2). Where the official code divides
pixels by the image resolution and z-scores them with dataset statistics (``docs/flex.md``),
this normalisation uses only statistics of the view's own 2D sequence, so that it is unchanged when a view's
image coordinates are shifted and scaled (another principal point, focal length, image size or crop):

- ``centre`` (pixels): the confidence-weighted mean over the frames of the root joint's position;
- ``scale`` (pixels): the confidence-weighted RMS distance of the other joints from the root, over the whole
  sequence (one value per view and sequence, so the changing image size of a person walking towards the camera
  stays visible as depth information);
- features per frame and joint: the joint minus that frame's root, divided by ``scale``; in the root's slot
  (which would be zero) the root minus ``centre``, divided by ``scale`` (its image trajectory, from which the
  root position is back-projected); then the confidence.

A joint is missing where its confidence is <= 0 or its position not finite; a non-root joint is also unusable
where the root is missing in that frame. Unusable entries get zero features (position and confidence). A view
with no usable pair gets ``scale`` 1 and a view without any root ``centre`` 0, so the output is always finite.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

__all__ = ["NormalisedInput", "normalise_view", "normalise_2d"]


class NormalisedInput(NamedTuple):
    """Normalised 2D input of any leading batch axes (``*b`` = batch, views)."""

    features: Float[Array, "*b frames joints 3"]
    """(x, y, confidence); x, y in units of ``scale`` (see the module docstring), 0 where unusable."""
    centre: Float[Array, "*b 2"]
    """Pixels: the mean root position the root trajectory is relative to."""
    scale: Float[Array, "*b"]
    """Pixels per normalised unit."""


def normalise_view(
    points: Float[Array, "frames joints 2"], confidences: Float[Array, "frames joints"], root: int
) -> NormalisedInput:
    """Normalise one view's 2D sequence (pixels, confidences in [0, 1]); ``root`` is the root joint's index."""
    valid = (confidences > 0) & jnp.all(jnp.isfinite(points), axis=-1)
    confidence = jnp.where(valid, confidences, 0.0)
    points = jnp.where(valid[..., None], points, 0.0)
    root_xy, root_confidence = points[:, root], confidence[:, root]
    relative = points - root_xy[:, None, :]
    pair = confidence * root_confidence[:, None]
    pair = pair.at[:, root].set(0.0)
    pair_total = jnp.sum(pair)
    mean_square = jnp.sum(pair * jnp.sum(relative * relative, axis=-1)) / jnp.where(pair_total > 0, pair_total, 1.0)
    usable_scale = (pair_total > 0) & (mean_square > 0)
    scale = jnp.where(usable_scale, jnp.sqrt(jnp.where(usable_scale, mean_square, 1.0)), 1.0)
    root_total = jnp.sum(root_confidence)
    centre = jnp.sum(root_confidence[:, None] * root_xy, axis=0) / jnp.where(root_total > 0, root_total, 1.0)

    usable = (pair > 0).at[:, root].set(valid[:, root])
    xy = relative.at[:, root].set(root_xy - centre[None, :]) / scale
    features = jnp.concatenate([xy, confidence[..., None]], axis=-1)
    return NormalisedInput(jnp.where(usable[..., None], features, 0.0), centre, scale)


def normalise_2d(
    points: Float[ArrayLike, "*b frames joints 2"], confidences: Float[ArrayLike, "*b frames joints"], root: int
) -> NormalisedInput:
    """:func:`normalise_view` over any leading axes (e.g. batch and views); ``root`` is static."""
    points, confidences = jnp.asarray(points), jnp.asarray(confidences)
    if points.ndim < 3 or points.shape[-1] != 2 or confidences.shape != points.shape[:-1]:
        raise ValueError(f"points must be (*b, frames, joints, 2) and confidences (*b, frames, joints), got "
                         f"{points.shape} and {confidences.shape}")
    if not 0 <= root < points.shape[-2]:
        raise ValueError(f"root {root} is not a joint index (joints: {points.shape[-2]})")
    dtype = jnp.result_type(points.dtype, confidences.dtype, jnp.float32)
    return _normalise_batch(points.astype(dtype), confidences.astype(dtype), root)


@functools.partial(jax.jit, static_argnums=2)
def _normalise_batch(points: Array, confidences: Array, root: int) -> NormalisedInput:
    batch = points.shape[:-3]
    flat = jax.vmap(normalise_view, in_axes=(0, 0, None))(
        points.reshape(-1, *points.shape[-3:]), confidences.reshape(-1, *confidences.shape[-2:]), root)
    return NormalisedInput(*(x.reshape(*batch, *x.shape[1:]) for x in flat))

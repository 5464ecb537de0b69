"""Vector norms that stay differentiable where a vector vanishes."""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

__all__ = ["safe_norm"]


def safe_norm(v: Float[ArrayLike, "*b d"]) -> Float[Array, "*b"]:
    """Euclidean norm over the last axis, with a zero (not NaN) gradient at the zero vector.

    ``jnp.linalg.norm``'s gradient there is NaN, and a loss meets it whenever a prediction is exactly on target (an
    untrained forecaster repeating a pose that holds still, a bone of length zero): one such entry turns every
    parameter NaN. The one guarded norm of the project; the metrics' distances are this norm of the difference."""
    v = jnp.asarray(v)
    squared = jnp.sum(v * v, axis=-1)
    positive = squared > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, squared, 1.0)), 0.0)

"""The pinhole camera with OpenCV's distortion model, as a pytree.

__all__ = ["Camera"]

Conventions used across the project: world coordinates in metres with z up; a world point X maps to
camera coordinates ``x_cam = R @ X + t`` (OpenCV), then to normalised image coordinates
``x_cam[:2] / x_cam[2]``, then through the Brown-Conrady distortion ``(k1, k2, p1, p2, k3)`` and the
intrinsic matrix K to pixels. Pixel (0, 0) is the centre of the top-left pixel.

A batch of cameras (a rig) is a :class:`Camera` whose leaves carry a leading ``views`` axis; per-camera
kernels are written for one camera and mapped with ``jax.vmap``.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float


class Camera(NamedTuple):
    """One camera (or a stack of cameras when every leaf has a leading axis)."""

    K: Float[Array, "*views 3 3"]
    """Intrinsics in pixels: ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]``."""
    R: Float[Array, "*views 3 3"]
    """World-to-camera rotation."""
    t: Float[Array, "*views 3"]
    """World-to-camera translation in metres (``x_cam = R X + t``)."""
    dist: Float[Array, "*views 5"]
    """OpenCV distortion coefficients ``(k1, k2, p1, p2, k3)``."""
    image_size: Float[Array, "*views 2"]
    """Image width and height in pixels."""

    @classmethod
    def create(
        cls,
        K: ArrayLike,
        R: ArrayLike,
        t: ArrayLike,
        dist: ArrayLike | None = None,
        image_size: ArrayLike = (0.0, 0.0),
        dtype=None,
    ) -> "Camera":
        """Build a camera from array-likes, filling zero distortion; checks shapes and finiteness."""
        K, R, t = (jnp.asarray(a, dtype) for a in (K, R, t))
        dtype = K.dtype
        batch = K.shape[:-2]
        dist = jnp.zeros(batch + (5,), dtype) if dist is None else jnp.asarray(dist, dtype)
        image_size = jnp.broadcast_to(jnp.asarray(image_size, dtype), batch + (2,))
        cam = cls(K, R, t.reshape(batch + (3,)), dist, image_size)
        for field, value, tail in zip(cls._fields, cam, ((3, 3), (3, 3), (3,), (5,), (2,))):
            if value.shape != batch + tail:
                raise ValueError(f"Camera.{field} has shape {value.shape}, expected {batch + tail}")
            if not bool(jnp.all(jnp.isfinite(value))):
                raise ValueError(f"Camera.{field} contains NaN or inf")
        return cam

    @property
    def num_views(self) -> int:
        """Number of cameras in a stacked rig (1 for a single camera)."""
        return 1 if self.K.ndim == 2 else self.K.shape[0]

    def select(self, index) -> "Camera":
        """Index a stacked rig: ``rig.select(2)`` is camera 2, ``rig.select(jnp.array([0, 3]))`` a sub-rig."""
        return Camera(*(leaf[index] for leaf in self))

"""The HMR regressor f_HMR (Kanazawa et al. 2018; thesis Sect. 3.2.1, spec section 3 "HMR head"): image or
temporal features -> SMPL pose (6D), shape and weak-perspective crop camera, by iterative error feedback.

Differences from the original, as in the thesis: rotations are regressed in Zhou et al.'s 6D representation
(:func:`geometry.rotation_6d_to_matrix` maps them to matrices) instead of axis-angle, and the crop camera feeds a
full-perspective translation (:func:`geometry.crop_camera_to_translation`). Widths are constructor arguments
(HMR: 1024 hidden units; the default here is CPU-sized).
"""

from __future__ import annotations

from typing import Literal, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx
from jaxtyping import Array, Float

import geometry
import training

__all__ = ["DecodeFrom", "HMRHead", "SMPLParams", "decoding_start", "mean_params"]

NUM_JOINTS = 24
"""SMPL's joints (:data:`geometry.SMPL24`); joint 0 is the root, whose rotation is global."""


class SMPLParams(NamedTuple):
    """One person's SMPL parameters as HMR regresses them (any leading batch axes, shared by the three)."""

    rot6d: Float[Array, "*b 24 6"]
    """Local joint rotations in 6D (:func:`geometry.rotation_6d_to_matrix`); the root's maps the body frame (y up,
    facing +z) to the OpenCV camera frame (x right, y down, z forward)."""
    betas: Float[Array, "*b S"]
    """Shape coefficients."""
    camera: Float[Array, "*b 3"]
    """Weak-perspective crop camera ``[s, x, y]`` (:func:`geometry.crop_camera_to_translation`)."""


def mean_params(num_shapes: int) -> SMPLParams:
    """HMR's starting point: every joint at rest, the root turning an upright rest body to face the camera (a
    half turn about x: body y up -> camera y down, body forward +z -> towards the camera, -z), zero shape and
    the crop camera ``[0.9, 0, 0]`` (a body filling 90 % of the crop, centred)."""
    rotations = np.broadcast_to(np.eye(3), (NUM_JOINTS, 3, 3)).copy()
    rotations[0] = np.diag([1.0, -1.0, -1.0])
    dtype = jnp.result_type(float)
    return SMPLParams(
        rot6d=geometry.matrix_to_rotation_6d(jnp.asarray(rotations, dtype)),
        betas=jnp.zeros((num_shapes,), dtype),
        camera=jnp.asarray([0.9, 0.0, 0.0], dtype),
    )


DecodeFrom = Literal["mean", "previous", "extrapolated"]
"""Where an autoregressive model's f_HMR starts each predicted frame: HMR's mean pose (the thesis), the previous
frame's pose, or the previous frame's pose moved on by (a fraction of) its last step (:func:`decoding_start`)."""


def _check_extrapolation(extrapolation: float) -> None:
    """Refuse a fraction of the last step outside [0, 1] (the models' configs call it)."""
    if not 0.0 <= extrapolation <= 1.0:
        raise ValueError(f"extrapolation is a fraction of the last step, in [0, 1], got {extrapolation}")


def decoding_start(decode_from: DecodeFrom, before: SMPLParams, previous: SMPLParams, extrapolation: float = 1.0
                   ) -> SMPLParams | None:
    """The parameters f_HMR refines into the frame after ``previous`` (``before`` is the frame before that): None
    for the mean pose; ``previous``; or, ``"extrapolated"``, each joint's rotation turned on by the fraction
    ``extrapolation`` of its last step, ``(R_t R_{t-1}^T)^e R_t`` (at 1 a constant angular velocity, the same in the
    parent's and the joint's own frame; below 1 a silent decoder's motion slows down geometrically and comes to
    rest), with the shape and crop camera of ``previous``."""
    if decode_from == "mean":
        return None
    if decode_from == "previous":
        return previous
    current, last = (geometry.rotation_6d_to_matrix(p.rot6d) for p in (previous, before))
    step = current @ jnp.swapaxes(last, -1, -2)
    if extrapolation != 1.0:
        step = geometry.axis_angle_to_matrix(extrapolation * geometry.matrix_to_axis_angle(step))
    return previous._replace(rot6d=geometry.matrix_to_rotation_6d(step @ current).astype(previous.rot6d.dtype))


def _flatten(params: SMPLParams) -> Float[Array, "*b P"]:
    """``[rot6d (144); betas (S); camera (3)]`` along the last axis."""
    batch = params.camera.shape[:-1]
    return jnp.concatenate([params.rot6d.reshape(*batch, NUM_JOINTS * 6), params.betas, params.camera], axis=-1)


def _unflatten(vector: Float[Array, "*b P"], num_shapes: int) -> SMPLParams:
    batch, pose = vector.shape[:-1], NUM_JOINTS * 6
    return SMPLParams(vector[..., :pose].reshape(*batch, NUM_JOINTS, 6), vector[..., pose:pose + num_shapes],
                      vector[..., pose + num_shapes:])


class ParameterMean(nnx.Variable):
    """HMR's fixed starting parameters (flattened :class:`SMPLParams`): state, never trained."""


def _small_xavier(key: jax.Array, shape: tuple[int, ...], dtype=jnp.float32) -> Array:
    """Xavier (Glorot) uniform x 0.01 (HMR's decoder): the first updates are tiny, so an untrained head stays
    near its starting parameters."""
    return 0.01 * nnx.initializers.xavier_uniform()(key, shape, dtype)


class HMRHead(nnx.Module):
    """Iterative error feedback: ``iterations`` times ``params += decoder(MLP([features; params]))``.

    The MLP is FC ``hidden`` -> ReLU -> dropout -> FC ``hidden`` -> ReLU -> dropout; one linear decoder
    (Xavier x 0.01) outputs the whole parameter update, which equals HMR's separate pose / shape / camera
    decoders stacked. ``mean`` (unbatched :class:`SMPLParams`) is the default start, stored float32 as the rest
    of the state."""

    def __init__(
        self,
        feature_dim: int,
        mean: SMPLParams,
        hidden: int = 512,
        iterations: int = 3,
        dropout: float = 0.5,
        *,
        rngs: nnx.Rngs,
    ) -> None:
        num_shapes = mean.betas.shape[-1]
        if mean.rot6d.shape != (NUM_JOINTS, 6) or mean.betas.shape != (num_shapes,) or mean.camera.shape != (3,):
            raise ValueError(f"mean must be one person's parameters ((24, 6), (S,), (3,)), got "
                             f"{mean.rot6d.shape}, {mean.betas.shape} and {mean.camera.shape}")
        if iterations < 1 or not 0.0 <= dropout < 1.0:
            raise ValueError(f"need iterations >= 1 and dropout in [0, 1), got {iterations} and {dropout}")
        self.num_shapes, self.iterations, self.rate = num_shapes, iterations, dropout
        self.mean = ParameterMean(jnp.asarray(_flatten(mean), jnp.float32))
        size = self.mean.shape[-1]
        self.fc1 = nnx.Linear(feature_dim + size, hidden, rngs=rngs)
        self.fc2 = nnx.Linear(hidden, hidden, rngs=rngs)
        self.decoder = nnx.Linear(hidden, size, kernel_init=_small_xavier, rngs=rngs)

    def __call__(
        self, features: Float[Array, "*b D"], start: SMPLParams | None = None, key: jax.Array | None = None
    ) -> SMPLParams:
        """Parameters for each feature vector, refined from ``start`` (batched like ``features``) or the mean.
        ``key``: training mode (dropout); ``None``: deterministic."""
        batch = features.shape[:-1]
        if start is None:
            params = jnp.broadcast_to(self.mean[...].astype(features.dtype), (*batch, self.mean.shape[-1]))
        else:
            params = _flatten(start)
        keys = [None] * (2 * self.iterations) if key is None else list(jax.random.split(key, 2 * self.iterations))
        for step in range(self.iterations):
            hidden = jax.nn.relu(self.fc1(jnp.concatenate([features, params.astype(features.dtype)], axis=-1)))
            hidden = training.dropout(hidden, self.rate, keys[2 * step])
            hidden = training.dropout(jax.nn.relu(self.fc2(hidden)), self.rate, keys[2 * step + 1])
            params = params + self.decoder(hidden)
        return _unflatten(params, self.num_shapes)

"""The per-frame loss ``L_t`` (thesis Eq. 3.9-3.11, 4.10-4.11) and the sequence terms of Eq. 4.9 and 4.12.

The thesis gives no loss weights (it tuned learning rates only); :class:`LossWeights` defaults to HMMR's
(``docs/dynamics.md``: 60 for the 2D, 3D-joint and SMPL terms, 1 for the adversarial term), with
two deviations stated on the fields: a weak shape prior, because our bodies' shapes are drawn from N(0, 1)
and a unit prior would pull them to the mean; and the translation term on the same scale as the 3D terms.

Units: joints in metres (the 3D joint error after aligning the pelvises, as HMMR), 2D keypoints in
crop-normalised units (pixels over half the crop box side, so a person's size in the image does not weight
their frames), rotations as matrices (6D in, matrices compared: Zhou et al.'s recommendation).
"""

from __future__ import annotations

import dataclasses
from typing import Literal, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

import geometry

from ._hmr import SMPLParams
from ._phdt import params_to_joints
from ._prior import PosePrior, lsgan_generator_loss

__all__ = ["PENETRATION_POINTS", "FrameTargets", "LossWeights", "PenetrationSurfaces", "frame_losses",
           "interpenetration", "penetration_depths", "penetration_surfaces", "shape_consistency"]

PENETRATION_POINTS = 128
"""Vertices sampled from each mesh for the interpenetration terms (:func:`geometry.surface_points`)."""


@dataclasses.dataclass(frozen=True)
class LossWeights:
    keypoints_2d: float = 60.0
    joints_3d: float = 60.0
    joints_3d_error: Literal["squared", "distance"] = "squared"
    """What the 3D-joint term averages: half the squared error of every coordinate (HMMR's), or every joint's
    Euclidean distance (MPJPE, the metric the forecasts are scored by), which weighs a frame's error in proportion
    to its size instead of its square."""
    smpl: float = 60.0
    adversarial: float = 1.0
    shape_prior: float = 0.01
    """lambda_reg of Eq. 4.11 (HMMR: 1): our shapes are drawn from N(0, 1), so the prior stays weak."""
    shape_consistency: float = 1.0
    """lambda_const of Eq. 4.9 and 4.12."""
    temporal: float = 1.0
    """lambda_temp of Eq. 4.12, on the mean squared feature difference."""
    translation: float = 60.0
    """lambda_transl of Eq. 4.12, on the squared root distance in metres (the 3D terms' scale)."""
    delta: float = 1.0
    """Weight of each delta predictor's frame loss relative to the present frame's (Eq. 4.9: 1)."""
    interpenetration: float = 1.0
    """Weight of ``P_t`` (Eq. 4.42, metres summed over :data:`PENETRATION_POINTS` sampled vertices) in scenes of
    several people (the thesis adds it unweighted)."""

    def __post_init__(self) -> None:
        if self.joints_3d_error not in ("squared", "distance"):
            raise ValueError(f"joints_3d_error must be 'squared' or 'distance', got {self.joints_3d_error!r}")


class FrameTargets(NamedTuple):
    """Ground truth of frames (``*b`` leading axes), camera frame, as :class:`~dynamics.Frames` holds it."""

    rotations: Float[Array, "*b 24 3 3"]
    betas: Float[Array, "*b S"]
    joints3d: Float[Array, "*b 24 3"]
    joints2d: Float[Array, "*b 24 2"]
    boxes: Float[Array, "*b 4"]
    K: Float[Array, "*b 3 3"]


def frame_losses(body: geometry.BodyModel, params: SMPLParams, root: Float[Array, "*b 3"] | None,
                 targets: FrameTargets, prior: PosePrior | None, weights: LossWeights) -> dict[str, Array]:
    """The weighted terms of ``L_t`` averaged over the frames: ``smpl``, ``joints_3d``, ``adversarial``,
    ``shape_prior`` and, when ``root`` (the predicted pelvis, camera frame) is given, ``keypoints_2d``."""
    targets = jax.tree.map(jnp.asarray, targets)
    rotations = geometry.rotation_6d_to_matrix(params.rot6d)
    joints = params_to_joints(body, params, jnp.zeros_like(params.camera))
    truth = targets.joints3d - targets.joints3d[..., :1, :]
    terms = {
        "smpl": weights.smpl * 0.5 * (jnp.mean((rotations - targets.rotations) ** 2)
                                      + jnp.mean((params.betas - targets.betas) ** 2)),
        "joints_3d": weights.joints_3d * (0.5 * jnp.mean((joints - truth) ** 2) if weights.joints_3d_error == "squared"
                                          else jnp.mean(geometry.mpjpe(joints, truth))),
        "shape_prior": weights.shape_prior * jnp.mean(jnp.sum(params.betas ** 2, axis=-1)),
    }
    if root is not None:
        half_side = 0.5 * (targets.boxes[..., 2] - targets.boxes[..., 0])
        error = jnp.abs(geometry.project_pinhole(targets.K, joints + root[..., None, :]) - targets.joints2d)
        terms["keypoints_2d"] = weights.keypoints_2d * jnp.mean(error / half_side[..., None, None])
    if prior is not None and weights.adversarial:
        terms["adversarial"] = weights.adversarial * lsgan_generator_loss(prior(rotations, params.betas))
    return terms


def shape_consistency(betas: Float[Array, "*b T S"], weights: LossWeights) -> Array:
    """lambda_const times the mean over consecutive frames of ``|beta_t - beta_{t+1}|^2``."""
    return weights.shape_consistency * jnp.mean(jnp.sum((betas[..., 1:, :] - betas[..., :-1, :]) ** 2, axis=-1))


class PenetrationSurfaces(NamedTuple):
    """What the interpenetration terms take from a body model (:func:`penetration_surfaces`)."""

    capsules: geometry.Capsules
    vertices: Int[np.ndarray, "V"]
    """The sampled template vertices (:data:`PENETRATION_POINTS` of them)."""


def penetration_surfaces(body: geometry.BodyModel) -> PenetrationSurfaces:
    """The bone capsules and sampled vertices of a concrete ``body`` (NumPy: close over them in a jitted loss that
    takes the body model as an argument)."""
    return PenetrationSurfaces(geometry.body_capsules(body), geometry.surface_points(body, PENETRATION_POINTS))


def penetration_depths(body: geometry.BodyModel, params: SMPLParams, root: Float[Array, "*b N T 3"],
                       surfaces: PenetrationSurfaces | None = None) -> Float[Array, "*b N T V"]:
    """How deep (metres) each of :data:`PENETRATION_POINTS` sampled vertices of each person lies inside the other
    people of its scene (``N`` people, axis -3), summed over them: ``sum_{n != o} rho^n(v)`` for ``v`` of person
    ``o`` (Eq. 4.41), each body the union of its bone capsules (:func:`geometry.body_capsules`). ``surfaces``:
    :func:`penetration_surfaces` of ``body``, needed when ``body`` is traced (an argument of a jitted function)."""
    if surfaces is None:
        with jax.ensure_compile_time_eval():  # constants of a body model closed over
            surfaces = penetration_surfaces(body)
    capsules, vertices = surfaces
    rotations = geometry.rotation_6d_to_matrix(params.rot6d)
    batch = rotations.shape[:-3]
    flat_rotations, flat_betas = rotations.reshape(-1, 24, 3, 3), params.betas.reshape(-1, params.betas.shape[-1])
    origin = jnp.zeros(3, rotations.dtype)
    joints = jax.vmap(geometry.body_joints, in_axes=(None, 0, 0, None))(body, flat_rotations, flat_betas, origin)
    points = jax.vmap(geometry.body_points, in_axes=(None, 0, 0, None, None))(body, flat_rotations, flat_betas,
                                                                             origin, vertices)
    shift = root.reshape(-1, 3) - joints[:, 0]  # the pelvis at the root, as params_to_joints places it
    joints = (joints + shift[:, None]).reshape(*batch, 24, 3)
    points = (points + shift[:, None]).reshape(*batch, len(vertices), 3)
    people = root.shape[-3]
    depth = jax.vmap(geometry.penetration, in_axes=(0, None, 0))
    flat_points = points.reshape(-1, len(vertices), 3)
    total = jnp.zeros(flat_points.shape[:-1], points.dtype)
    for other in range(1, people):  # the body of person (o - other) mod N against the vertices of person o
        total = total + depth(jnp.roll(joints, other, axis=-4).reshape(-1, 24, 3), capsules, flat_points)
    return total.reshape(points.shape[:-1])


def interpenetration(body: geometry.BodyModel, params: SMPLParams, root: Float[Array, "*b N T 3"],
                     surfaces: PenetrationSurfaces | None = None) -> Float[Array, "*b T"]:
    """``P_t`` of Eq. 4.42 for each scene and frame: the depths of :func:`penetration_depths` summed over the
    sampled vertices of every person (metres)."""
    return jnp.sum(penetration_depths(body, params, root, surfaces), axis=(-3, -1))

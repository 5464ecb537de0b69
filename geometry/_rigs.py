"""Synthetic camera rigs and the extrinsic perturbations used by the papers' robustness studies.

All rigs are stacked :class:`~geometry.Camera` pytrees in the project convention (metres, z-up world,
``x_cam = R X + t``, OpenCV camera axes: x right, y down, z forward), with zero distortion.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from typing import Literal

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike, Float, PRNGKeyArray

from ._camera import Camera, camera_centre, look_at
from ._rotations import axis_angle_to_matrix, matrix_to_axis_angle

__all__ = [
    "ring_angles",
    "ring_rig",
    "structri_virtual_rig",
    "perturb_extrinsics_relative",
    "perturb_extrinsics_bounded",
]


def ring_angles(num_views: int, pattern: Literal["round", "half"] = "round") -> np.ndarray:
    """Azimuths (radians) of a ring of cameras: round ``2 pi i / C``, half ``pi i / C`` (endpoint excluded)."""
    if num_views < 1:
        raise ValueError(f"num_views must be at least 1, got {num_views}")
    if pattern not in ("round", "half"):
        raise ValueError(f"pattern must be 'round' or 'half', got {pattern!r}")
    span = 2.0 * math.pi if pattern == "round" else math.pi
    return span * np.arange(num_views) / num_views


def ring_rig(
    num_views: int,
    *,
    radius: float,
    target: Float[ArrayLike, "3"] | Sequence[float | int],
    height: float,
    focal: float,
    image_size: Sequence[float | int] | np.ndarray,
    pattern: Literal["round", "half"] = "round",
    start_angle: float = 0.0,
    dtype=None,
) -> Camera:
    """Cameras on a horizontal circle around a target in a z-up world, each aimed at the target.

    Camera i sits at ``target_xy + radius * (cos a_i, sin a_i)`` at world height ``height`` (metres,
    absolute z), with ``a_i = start_angle + ring_angles(num_views, pattern)[i]``, and looks at
    ``target`` (metres) with the image upright (world +z appears up). Intrinsics: focal length
    ``focal`` pixels for both axes, no skew, principal point at the image centre
    ``((width - 1) / 2, (height_px - 1) / 2)`` for ``image_size = [width, height_px]``; the target
    therefore projects to the image centre."""
    if radius <= 0:
        raise ValueError(f"radius must be positive, got {radius}")
    if focal <= 0:
        raise ValueError(f"focal must be positive, got {focal}")
    target = np.asarray(target, np.float64)
    if target.shape != (3,):
        raise ValueError(f"target must be a 3-vector in metres, got shape {target.shape}")
    width, height_px = np.asarray(image_size, np.float64)
    angles = start_angle + ring_angles(num_views, pattern)
    eyes = np.stack([target[0] + radius * np.cos(angles), target[1] + radius * np.sin(angles),
                     np.full(num_views, height)], axis=-1)
    R = np.asarray(jax.vmap(look_at, in_axes=(0, None))(eyes, target))
    K = np.array([[focal, 0.0, (width - 1.0) / 2.0], [0.0, focal, (height_px - 1.0) / 2.0], [0.0, 0.0, 1.0]])
    return Camera.create(
        np.broadcast_to(K, (num_views, 3, 3)), R, -np.einsum("vij,vj->vi", R, eyes),
        image_size=np.broadcast_to([width, height_px], (num_views, 2)), dtype=dtype,
    )


def structri_virtual_rig(
    num_views: int,
    pattern: Literal["round", "half"] = "round",
    *,
    up_axis: Literal["y", "z"] = "y",
    distance: float = 2.0,
    dtype=None,
) -> Camera:
    """The virtual camera rig of Structural Triangulation's synthetic test (Chen et al., ECCV 2022).

    Exactly the official ``generate_cam_systems``: ``R_i = R_y(theta_i)`` with ``theta_i`` from
    :func:`ring_angles`, ``t = [0, 0, distance]`` (2 m; the code's 2000 mm), and
    ``K = [[900, 0.5, 500], [0, 900, 500], [0, 0, 1]]`` (skew 0.5); image size 1000 x 1000 px
    (nominal: the test clips nothing). Every centre is ``distance`` from the world origin and every
    camera looks at it; camera 0 is at ``(0, 0, -distance)`` looking along +z.

    Caveat: the ring lies in the plane normal to world y, which is horizontal only for y-up data.
    The official code applies it to Human3.6M's z-up world, so there the ring is VERTICAL (camera 0
    looks up at the subject from below). ``up_axis="y"`` (default) reproduces that literally;
    ``up_axis="z"`` pre-rotates the world by +90 degrees about x (``R_i = R_y(theta_i) R_x(90 deg)``)
    so that a z-up world gets a horizontal ring at the origin's height with upright images
    (camera 0 at ``(0, -distance, 0)`` looking along +y). Same intrinsics and distances either way."""
    if up_axis not in ("y", "z"):
        raise ValueError(f"up_axis must be 'y' or 'z', got {up_axis!r}")
    angles = ring_angles(num_views, pattern)
    cos, sin, zeros, ones = np.cos(angles), np.sin(angles), np.zeros(num_views), np.ones(num_views)
    R = np.stack([np.stack([cos, zeros, sin], -1), np.stack([zeros, ones, zeros], -1),
                  np.stack([-sin, zeros, cos], -1)], axis=-2)
    if up_axis == "z":
        z_up_to_y_up = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # R_x(+90 deg)
        R = R @ z_up_to_y_up
    K = np.array([[900.0, 0.5, 500.0], [0.0, 900.0, 500.0], [0.0, 0.0, 1.0]])
    return Camera.create(
        np.broadcast_to(K, (num_views, 3, 3)), R, np.broadcast_to([0.0, 0.0, distance], (num_views, 3)),
        image_size=np.broadcast_to([1000.0, 1000.0], (num_views, 2)), dtype=dtype,
    )


@functools.partial(jax.jit, static_argnums=0)
def _per_view(perturb_one, key: PRNGKeyArray, camera: Camera, *args) -> Camera:
    """Apply a one-camera perturbation to a camera or, with independent keys, to every view of a rig."""
    if camera.K.ndim == 2:
        return perturb_one(key, camera, *args)
    keys = jax.random.split(key, camera.K.shape[0])
    return jax.vmap(perturb_one, in_axes=(0, 0) + (None,) * len(args))(keys, camera, *args)


def _relative_one(key: PRNGKeyArray, camera: Camera, scale: Float[ArrayLike, ""]) -> Camera:
    rotation_key, translation_key = jax.random.split(key)
    rotvec = matrix_to_axis_angle(camera.R)
    rotvec = rotvec * (1.0 + scale * jax.random.normal(rotation_key, (3,), rotvec.dtype))
    t = camera.t * (1.0 + scale * jax.random.normal(translation_key, (3,), camera.t.dtype))
    return camera._replace(R=axis_angle_to_matrix(rotvec), t=t)


def perturb_extrinsics_relative(key: PRNGKeyArray, camera: Camera, scale: Float[ArrayLike, ""] | float) -> Camera:
    """FLEX's perturbed-camera baseline: relative Gaussian noise on every extrinsic parameter.

    FLEX (Gordon et al., ECCV 2022, Sec. 4) perturbs each extrinsic parameter p of the Iskakov
    baseline as ``p~ ~ N(p, (scale * p)^2)`` with ``scale`` = 0.03 or 0.04; the paper does not say how
    the rotation is parametrised and its code has no perturbation. Here the six parameters are the
    rotation vector of R (axis-angle, radians, as ``cv2.Rodrigues``) and the translation t (so R
    stays a rotation; perturbing the nine entries of R would not): each is multiplied by
    ``1 + scale * N(0, 1)`` independently. Being relative, the noise vanishes on zero parameters
    (e.g. a camera with R = I gets no rotation noise). Intrinsics and distortion are unchanged.

    Works on one camera or a stacked rig (independent noise per view from ``jax.random.split``);
    deterministic given ``key``; jittable."""
    return _per_view(_relative_one, key, camera, jnp.asarray(scale, camera.R.dtype))


def _bounded_one(
    key: PRNGKeyArray, camera: Camera, max_translation: Float[ArrayLike, ""], max_rotation: Float[ArrayLike, ""]
) -> Camera:
    translation_key, axis_key, angle_key = jax.random.split(key, 3)
    dtype = camera.R.dtype
    offset = jax.random.uniform(translation_key, (3,), dtype, -max_translation, max_translation)
    axis = jax.random.normal(axis_key, (3,), dtype)
    axis = axis / jnp.linalg.norm(axis)
    angle = jax.random.uniform(angle_key, (), dtype, -max_rotation, max_rotation)
    R = jnp.sum(camera.R[:, :, None] * axis_angle_to_matrix(angle * axis)[None, :, :], axis=1)
    centre = camera_centre(camera) + offset
    return camera._replace(R=R, t=-jnp.sum(R * centre[None, :], axis=-1))


def perturb_extrinsics_bounded(
    key: PRNGKeyArray,
    camera: Camera,
    max_translation: Float[ArrayLike, ""] | float = 0.0025,
    max_rotation_deg: Float[ArrayLike, ""] | float = 2.5,
) -> Camera:
    """JCSAT's calibration-noise study (Table 8): bounded translation and rotation errors.

    The camera CENTRE moves by an offset uniform in ``[-max_translation, max_translation]`` metres
    per world axis (0.0025 m = the paper's 0.25 cm), and the camera turns about its own centre by an
    angle uniform in ``[-max_rotation_deg, max_rotation_deg]`` degrees about an axis uniform on the
    sphere: ``R~ = R dR``, ``t~ = -R~ (C + offset)``. So the centre moves by exactly the offset and
    the orientation by exactly |angle| (geodesic), whereas perturbing R with t fixed would also
    swing the centre by up to ``|C| * angle`` (about 15 cm for Shelf's 3.5 m cameras). The official
    code's unused helper instead adds N(0, 0.025) m to T and mixes rotations elementwise; the paper's
    text is followed here.

    Works on one camera or a stacked rig (independent noise per view); deterministic given ``key``;
    jittable."""
    dtype = camera.R.dtype
    max_rotation = jnp.deg2rad(jnp.asarray(max_rotation_deg, dtype))
    return _per_view(_bounded_one, key, camera, jnp.asarray(max_translation, dtype), max_rotation)

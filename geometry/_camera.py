"""The pinhole camera with OpenCV's distortion model, as a pytree, and its per-camera kernels.

Conventions used across the project: world coordinates in metres with z up; a world point X maps to
camera coordinates ``x_cam = R @ X + t`` (OpenCV: x right, y down, z forward, metres), then to
normalised image coordinates ``x_cam[:2] / x_cam[2]`` (unitless), then through the Brown-Conrady
distortion ``(k1, k2, p1, p2, k3)`` and the intrinsic matrix K to pixels. Pixel (0, 0) is the centre
of the top-left pixel.

A batch of cameras (a rig) is a :class:`Camera` whose leaves carry a leading ``views`` axis; per-camera
kernels are written for one camera and mapped with ``jax.vmap`` (:func:`project_to_views` does it for
projection).

Differences from OpenCV, on purpose: the skew ``K[0, 1]`` is honoured everywhere (``cv2.projectPoints``
and ``cv2.undistortPoints`` ignore it; with zero skew the results agree), and
:func:`undistort_points` refines OpenCV's fixed-point iteration with Newton steps so it converges
to machine precision for strong distortion (with k1 = -0.3, f = 900 px, OpenCV's default of 5
fixed-point steps leaves up to 6e-5 normalised units at the image corners, which re-distort 0.04 px
away from the input; 2 Newton steps bring that to 2e-13 px).
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from typing import Literal, NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

__all__ = [
    "Camera",
    "to_camera_frame",
    "point_depth",
    "depth",
    "project_point",
    "project",
    "project_to_views",
    "undistort_points",
    "camera_centre",
    "projection_matrix",
    "camera_from_projection",
    "look_at",
    "crop_camera_to_translation",
    "translation_to_crop_camera",
    "project_pinhole",
]


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
        image_size: ArrayLike | Sequence[float | int] = (0.0, 0.0),
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


def _check_single(camera: Camera, name: str) -> None:
    if camera.K.ndim != 2:
        raise ValueError(
            f"{name} takes one camera, got a rig of {camera.K.shape[0]} views "
            "(use project_to_views, or jax.vmap over the rig)"
        )


def _check_last_axis(array, size: int, name: str) -> None:
    # Shapes are static under jit, so this check is free and also guards traced calls.
    if array.ndim == 0 or array.shape[-1] != size:
        raise ValueError(f"{name} must have a last axis of size {size}, got shape {array.shape}")


def to_camera_frame(camera: Camera, point: Float[ArrayLike, "3"]) -> Float[Array, "3"]:
    """World point (metres) to camera coordinates ``R X + t`` (metres; z is the depth along the axis)."""
    point = jnp.asarray(point)
    return jnp.sum(camera.R * point[None, :], axis=-1) + camera.t


def point_depth(camera: Camera, point: Float[ArrayLike, "3"]) -> Float[Array, ""]:
    """Depth (metres) of a world point along the optical axis; <= 0 means at or behind the camera."""
    point = jnp.asarray(point)
    return jnp.sum(camera.R[2] * point) + camera.t[2]


def _distort(dist: Float[Array, "5"], xy: Float[Array, "2"]) -> Float[Array, "2"]:
    """OpenCV's Brown-Conrady model on normalised coordinates (unitless in, unitless out)."""
    k1, k2, p1, p2, k3 = dist
    x, y = xy
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    return jnp.stack([
        x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
        y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
    ])


def _normalised_to_pixels(K: Float[Array, "3 3"], xy: Float[Array, "2"]) -> Float[Array, "2"]:
    x, y = xy
    return jnp.stack([K[0, 0] * x + K[0, 1] * y + K[0, 2], K[1, 1] * y + K[1, 2]])


def project_point(camera: Camera, point: Float[ArrayLike, "3"]) -> Float[Array, "2"]:
    """Pixel coordinates of one world point (metres), with distortion and skew.

    No clipping or visibility test: points behind the camera get the mirrored projection and a
    point in the camera plane gives inf; check :func:`point_depth` where that matters."""
    x_cam = to_camera_frame(camera, point)
    return _normalised_to_pixels(camera.K, _distort(camera.dist, x_cam[:2] / x_cam[2]))


@functools.partial(jax.jit, static_argnums=(0, 3))
def _map_points(kernel: Callable, camera: Camera, points: Array, options: tuple = ()) -> Array:
    """Apply a one-point kernel over any leading point axes (``(*n, d) -> (*n, *out)``).

    Jitted so that eager calls compile once per shape instead of dispatching op by op."""
    flat = points.reshape(-1, points.shape[-1])
    out = jax.vmap(lambda point: kernel(camera, point, *options))(flat)
    return out.reshape(points.shape[:-1] + out.shape[1:])


def project(camera: Camera, points: Float[ArrayLike, "*n 3"]) -> Float[Array, "*n 2"]:
    """Pixel coordinates of world points (metres) with any leading point axes, for one camera."""
    _check_single(camera, "project")
    points = jnp.asarray(points)
    _check_last_axis(points, 3, "points")
    return _map_points(project_point, camera, points)


def depth(camera: Camera, points: Float[ArrayLike, "*n 3"]) -> Float[Array, "*n"]:
    """Depths (metres, camera z) of world points with any leading point axes, for one camera."""
    _check_single(camera, "depth")
    points = jnp.asarray(points)
    _check_last_axis(points, 3, "points")
    return _map_points(point_depth, camera, points)


def project_to_views(rig: Camera, points: Float[ArrayLike, "*n 3"]) -> Float[Array, "views *n 2"]:
    """Pixel coordinates of the same world points (metres) in every camera of a stacked rig."""
    if rig.K.ndim != 3:
        raise ValueError(f"project_to_views takes a stacked rig, got camera leaves of shape {rig.K.shape}")
    return jax.vmap(project, in_axes=(0, None))(rig, jnp.asarray(points))


def _solve_2x2(A: Float[Array, "2 2"], b: Float[Array, "2"]) -> Float[Array, "2"]:
    det = A[0, 0] * A[1, 1] - A[0, 1] * A[1, 0]
    return jnp.stack([A[1, 1] * b[0] - A[0, 1] * b[1], A[0, 0] * b[1] - A[1, 0] * b[0]]) / det


def _distortion_jacobian(dist: Float[Array, "5"], xy: Float[Array, "2"]) -> Float[Array, "2 2"]:
    """d distort / d xy, written out: a smaller graph than ``jax.jacfwd`` inside the Newton loop."""
    k1, k2, p1, p2, k3 = dist
    x, y = xy
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    radial_slope = 2.0 * (k1 + r2 * (2.0 * k2 + 3.0 * r2 * k3))  # d radial / d r2, times 2
    cross = x * y * radial_slope + 2.0 * (p1 * x + p2 * y)
    return jnp.stack([
        jnp.stack([radial + x * x * radial_slope + 2.0 * p1 * y + 6.0 * p2 * x, cross]),
        jnp.stack([cross, radial + y * y * radial_slope + 6.0 * p1 * y + 2.0 * p2 * x]),
    ])


def _undistort_normalised(
    dist: Float[Array, "5"], distorted: Float[Array, "2"], fixed_point_iterations: int, newton_iterations: int
) -> Float[Array, "2"]:
    k1, k2, p1, p2, k3 = dist

    # OpenCV's scheme (cvUndistortPointsInternal): invert the radial factor, subtract the tangential term.
    def fixed_point_step(_, xy):
        x, y = xy
        r2 = x * x + y * y
        inverse_radial = 1.0 / (1.0 + r2 * (k1 + r2 * (k2 + r2 * k3)))
        tangential = jnp.stack([2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x), p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y])
        return (distorted - tangential) * inverse_radial

    # Newton on distort(xy) = distorted converges quadratically from the fixed-point estimate.
    def newton_step(_, xy):
        return xy - _solve_2x2(_distortion_jacobian(dist, xy), _distort(dist, xy) - distorted)

    xy = jax.lax.fori_loop(0, fixed_point_iterations, fixed_point_step, distorted)
    return jax.lax.fori_loop(0, newton_iterations, newton_step, xy)


def undistort_points(
    camera: Camera,
    pixels: Float[ArrayLike, "*n 2"],
    *,
    output: Literal["normalised", "pixels"] = "normalised",
    fixed_point_iterations: int = 5,
    newton_iterations: int = 3,
) -> Float[Array, "*n 2"]:
    """Remove lens distortion from observed pixels (any leading axes) of one camera.

    ``output="normalised"`` returns ideal normalised coordinates ``x_cam[:2] / x_cam[2]`` (unitless),
    like ``cv2.undistortPoints(px, K, dist)``; ``output="pixels"`` returns the ideal (undistorted)
    pixels ``K @ [x, y, 1]``, like ``cv2.undistortPoints(px, K, dist, P=K)``.

    The inverse is computed with a fixed number of steps (jittable and differentiable): OpenCV's
    fixed-point iteration (5 steps is OpenCV's default), then Newton steps on the 2x2 distortion
    Jacobian. With ``newton_iterations=0`` the result equals ``cv2.undistortPoints`` with zero skew;
    the default re-distorts to the input pixels within 1e-12 px in float64 over the whole image of a
    strongly distorted lens (k1 = -0.3). The skew ``K[0, 1]`` is inverted exactly (OpenCV ignores
    it). OpenCV's fallback for a negative radial factor (a point outside the lens model's valid
    range) is not reproduced: such points give meaningless values, as the model has no inverse there."""
    _check_single(camera, "undistort_points")
    if output not in ("normalised", "pixels"):
        raise ValueError(f"output must be 'normalized' or 'pixels', got {output!r}")

    pixels = jnp.asarray(pixels)
    _check_last_axis(pixels, 2, "pixels")
    return _map_points(_undistort_pixel, camera, pixels, (output, fixed_point_iterations, newton_iterations))


def _undistort_pixel(
    camera: Camera, pixel: Float[Array, "2"], output: str, fixed_point_iterations: int, newton_iterations: int
) -> Float[Array, "2"]:
    K = camera.K
    y = (pixel[1] - K[1, 2]) / K[1, 1]
    x = (pixel[0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
    xy = _undistort_normalised(camera.dist, jnp.stack([x, y]), fixed_point_iterations, newton_iterations)
    return _normalised_to_pixels(K, xy) if output == "pixels" else xy


def camera_centre(camera: Camera) -> Float[Array, "*views 3"]:
    """Camera centre in world coordinates (metres), ``-R^T t``; works for one camera or a rig."""
    return -jnp.sum(camera.R * camera.t[..., :, None], axis=-2)


def projection_matrix(camera: Camera) -> Float[Array, "*views 3 4"]:
    """``P = K [R | t]`` (pixels per metre; no distortion); works for one camera or a rig."""
    Rt = jnp.concatenate([camera.R, camera.t[..., :, None]], axis=-1)
    return jnp.sum(camera.K[..., :, :, None] * Rt[..., None, :, :], axis=-2)


def camera_from_projection(
    P: Float[ArrayLike, "3 4"],
    *,
    image_size: Float[ArrayLike, "2"] | Sequence[float | int] = (0.0, 0.0),
    dist: Float[ArrayLike, "5"] | None = None,
) -> Camera:
    """Decompose a 3x4 projection matrix (acting on metres) into K, R, t by an RQ decomposition.

    P is homogeneous, so its overall scale and sign are free: the sign is chosen so that points in
    front of the camera have positive depth (``det(P[:, :3]) > 0``), then K gets positive focal
    lengths, det(R) = +1 and ``K[2, 2] = 1``. Jittable; ``image_size`` is [width, height] in pixels
    and ``dist`` the OpenCV coefficients to attach (P cannot carry them; zero by default)."""
    P = jnp.asarray(P)
    if P.shape != (3, 4):
        raise ValueError(f"projection matrix must have shape (3, 4), got {P.shape}")
    P = P * jnp.sign(jnp.linalg.det(P[:, :3]))
    M = P[:, :3]
    # RQ from QR: with J the row reversal, (J M)^T = Q R  gives  M = (J R^T J)(J Q^T).
    Q, upper = jnp.linalg.qr(M[::-1].T)
    K = upper.T[::-1, ::-1]
    R = Q.T[::-1]
    signs = jnp.sign(jnp.diagonal(K))
    K = K * signs[None, :]
    R = R * signs[:, None]
    t = jnp.linalg.solve(K, P[:, 3])
    dist = jnp.zeros(5, P.dtype) if dist is None else jnp.asarray(dist, P.dtype)
    image_size = jnp.asarray(image_size, P.dtype)
    return Camera(K / K[2, 2], R, t, dist, image_size)


def look_at(
    eye: Float[ArrayLike, "3"],
    target: Float[ArrayLike, "3"],
    up: Float[ArrayLike, "3"] | Sequence[float | int] = (0.0, 0.0, 1.0),
) -> Float[Array, "3 3"]:
    """World-to-camera rotation of an OpenCV camera at ``eye`` looking at ``target`` (metres).

    The optical axis (camera z) points at the target and the image "up" (camera -y) is as close to
    ``up`` as possible; ``up`` must not be parallel to the viewing direction. The matching
    translation is ``t = -R @ eye``."""
    eye, target, up = (jnp.asarray(a) for a in (eye, target, up))
    forward = target - eye
    forward = forward / jnp.linalg.norm(forward)
    right = jnp.cross(forward, up)
    right = right / jnp.linalg.norm(right)
    down = jnp.cross(forward, right)
    return jnp.stack([right, down, forward])


# --------------------------------------------------------------------------------------------
# The weak-perspective crop camera of HMR-style regressors and full-perspective translation


def _crop_frame(box: Array, K: Array) -> tuple[Float[Array, "2"], Float[Array, ""], Float[Array, ""]]:
    """The square crop around a box (x0, y0, x1, y1) in pixels: its centre, its side ``b = max(w, h)`` and the
    focal length ``F`` along the box's longer side (``f_y`` if ``h > w``, else ``f_x``)."""
    if box.shape != (4,) or K.shape != (3, 3):
        raise ValueError(f"need a box (4,) and K (3, 3), got {box.shape} and {K.shape}")
    width, height = box[2] - box[0], box[3] - box[1]
    centre = 0.5 * (box[:2] + box[2:])
    return centre, jnp.maximum(width, height), jnp.where(height > width, K[1, 1], K[0, 0])


def project_pinhole(K: Float[ArrayLike, "*b 3 3"], points: Float[ArrayLike, "*b n 3"]) -> Float[Array, "*b n 2"]:
    """Pixels of camera-frame points through the intrinsics ``K`` alone (no distortion, no extrinsics): the
    rendered videos' cameras, where a full :class:`Camera` is not at hand."""
    K, points = jnp.asarray(K), jnp.asarray(points)
    pixels = jnp.einsum("...ij,...nj->...ni", K, points)
    return pixels[..., :2] / pixels[..., 2:]


def crop_camera_to_translation(
    camera: Float[ArrayLike, "3"], box: Float[ArrayLike, "4"], K: Float[ArrayLike, "3 3"]
) -> Float[Array, "3"]:
    """Camera-frame root translation (metres) whose full perspective projection matches a weak-perspective crop
    camera to first order at the root (Jiang et al. 2020, thesis Sect. 3.2.2).

    Crop frame: ``box`` is (x0, y0, x1, y1) in pixels with centre ``c`` and ``b = max(w, h)``; the regressor sees
    the ``b x b`` square around ``c``, whose normalised coordinates ``u`` in [-1, 1] are the pixels
    ``c + (b / 2) u``. The crop camera ``[s, x, y]`` projects a root-relative point ``X`` (metres) to
    ``u = s X_xy + (x, y)``: the root lands at ``(x, y)`` and a metre spans ``s b / 2`` pixels.

    Full perspective with the root at ``gamma`` puts the root at pixel ``K gamma / gamma_z`` and, around it,
    spans ``f / gamma_z`` pixels per metre. Equating the two:

    - scale: ``F / gamma_z = s b / 2``, so ``gamma_z = 2 F / (s b)``, with ``F`` the focal length along the box's
      longer side (``f_y`` if ``h > w`` else ``f_x``; with non-square pixels only one axis can match);
    - root: ``K gamma / gamma_z = c + (b / 2) (x, y)``, so ``gamma = gamma_z K^-1 [c + (b / 2) (x, y); 1]``, i.e.
      without skew ``gamma_x = gamma_z ((b / 2) x + c_x - p_x) / f_x`` (``y`` alike), ``p`` the principal point.

    The thesis prints ``gamma_x = gamma_z (x w + c_x - W / 2) / F``: its ``W / 2`` is the principal point of its
    K (Eq. 3.5), taken here from ``K``. The factor is ``b / 2`` because a unit of ``u`` is ``b / 2`` pixels, the
    same normalisation that gives its own ``gamma_z = 2 F / (s b)``; ``x w`` would place the root elsewhere
    than the crop camera projects it. What no weak camera has is the perspective term ``-(root pixel - p)
    X_z / gamma_z`` (an off-axis body is seen a little from the side); it vanishes as the body moves away.
    """
    camera, box, K = (jnp.asarray(a) for a in (camera, box, K))
    if camera.shape != (3,):
        raise ValueError(f"camera must be [s, x, y], got shape {camera.shape}")
    centre, size, focal = _crop_frame(box, K)
    depth = 2.0 * focal / (camera[0] * size)
    root_pixel = centre + 0.5 * size * camera[1:]
    # K^-1 on the root's pixel, written out: K is upper triangular (skew honoured as everywhere in this module).
    y = (root_pixel[1] - K[1, 2]) / K[1, 1]
    x = (root_pixel[0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
    return depth * jnp.stack([x, y, jnp.ones_like(x)])


def translation_to_crop_camera(
    translation: Float[ArrayLike, "3"], box: Float[ArrayLike, "4"], K: Float[ArrayLike, "3 3"]
) -> Float[Array, "3"]:
    """The crop camera ``[s, x, y]`` of a root at camera-frame ``translation`` (metres, in front of the camera)
    seen in ``box``: the inverse of :func:`crop_camera_to_translation` (see there for the crop frame)."""
    translation, box, K = (jnp.asarray(a) for a in (translation, box, K))
    if translation.shape != (3,):
        raise ValueError(f"translation must have shape (3,), got {translation.shape}")
    centre, size, focal = _crop_frame(box, K)
    root_pixel = _normalised_to_pixels(K, translation[:2] / translation[2])
    scale = 2.0 * focal / (translation[2] * size)
    return jnp.concatenate([scale[None], (root_pixel - centre) / (0.5 * size)])

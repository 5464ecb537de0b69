"""A z-buffered triangle rasteriser for synthetic video of body meshes (NumPy, vectorised over fragments).

:func:`rasterise` turns camera-frame triangles into a per-pixel face index and depth: every triangle's bounding
box is expanded into candidate pixels at once, pixel centres are tested against the edge functions, depth is
interpolated perspective-correctly (1/z is linear in the image), and the nearest fragment wins each pixel. A
pixel centre exactly on an edge shared by two triangles counts for both, so a closed mesh has no cracks.
The triangles' vertices are projected once and their pixels found together; :func:`covered_pixels` counts
the pixels a mesh covers without the z-buffer (a person's area alone, for the visibility of synthetic video).

:func:`render_people` draws posed body meshes (:func:`geometry.body_forward`) seen by a pinhole
:class:`geometry.Camera`: one colour per body part (:func:`face_parts`, from the skinning weights), a tint per
person, and Lambert shading under a light at the camera, with mutual occlusion through the shared z-buffer.
Cameras must be undistorted (``dist`` all zero): straight edges stay straight only under a pinhole.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from jaxtyping import ArrayLike, Float, Int, UInt8

from geometry import BodyModel, Camera

__all__ = ["Raster", "Rendering", "covered_pixels", "face_parts", "rasterise", "render_people"]

_PART_COLOURS = np.array([  # RGB per SMPL24 joint: warm trunk, distinct limbs, left and right apart
    (200, 170, 140), (60, 120, 220), (220, 90, 60), (210, 180, 150), (80, 150, 240), (240, 120, 80),
    (215, 185, 155), (100, 170, 250), (250, 150, 100), (220, 190, 160), (120, 190, 255), (255, 170, 120),
    (230, 200, 170), (170, 110, 200), (110, 190, 120), (240, 210, 180), (190, 120, 220), (120, 210, 130),
    (205, 140, 235), (135, 225, 145), (220, 160, 245), (150, 235, 160), (230, 180, 250), (170, 245, 180),
], float)
_PERSON_TINTS = np.array([(1.0, 1.0, 1.0), (0.75, 0.85, 0.7), (0.85, 0.7, 0.8), (0.7, 0.8, 0.9)])
_BACKGROUND = np.array([40, 44, 52], np.uint8)


class Raster(NamedTuple):
    face: Int[np.ndarray, "height width"]
    """Index of the visible triangle, -1 where none is."""
    depth: Float[np.ndarray, "height width"]
    """Camera-frame z of the visible surface (the input's unit), inf where none is."""


class Rendering(NamedTuple):
    image: UInt8[np.ndarray, "height width 3"]
    """RGB, uint8."""
    person: Int[np.ndarray, "height width"]
    """Index of the visible person, -1 on the background."""
    depth: Float[np.ndarray, "height width"]
    """Metres along the optical axis, inf on the background."""


def rasterise(
    points: Float[ArrayLike, "vertices 3"],
    faces: Int[ArrayLike, "faces 3"],
    K: Float[ArrayLike, "3 3"],
    size: tuple[int, int],
    near: float = 0.05,
) -> Raster:
    """The visible triangle and its depth at every pixel of a ``size = (width, height)`` image.

    ``points`` are camera-frame (x right, y down, z forward). Pixel (column c, row r) is sampled at image
    coordinates (c, r), OpenCV's convention (``cv2.projectPoints`` puts a point projecting there on that pixel).
    A triangle with a vertex nearer than ``near`` is dropped rather than clipped; either winding is drawn.
    """
    points, faces, K = _checked(points, faces, K)
    width, height = size
    face_index = np.full((height, width), -1, np.int64)
    depth = np.full((height, width), np.inf)
    face, pixel, barycentric, z = _fragments(points, faces, K, size, near)
    fragment_depth = 1.0 / np.sum(barycentric / z, axis=1)  # 1/z is affine in the image
    order = np.lexsort((fragment_depth, pixel))  # by pixel, nearest first
    first = order[np.r_[True, pixel[order][1:] != pixel[order][:-1]]] if order.size else order
    face_index.reshape(-1)[pixel[first]] = face[first]
    depth.reshape(-1)[pixel[first]] = fragment_depth[first]
    return Raster(face_index, depth)


def covered_pixels(
    points: Float[ArrayLike, "vertices 3"],
    faces: Int[ArrayLike, "faces 3"],
    K: Float[ArrayLike, "3 3"],
    size: tuple[int, int],
    near: float = 0.05,
) -> int:
    """How many pixels of a ``size`` image :func:`rasterise` would draw (its ``face >= 0``), without the z-buffer."""
    points, faces, K = _checked(points, faces, K)
    _, pixel, _, _ = _fragments(points, faces, K, size, near)
    covered = np.zeros(size[0] * size[1], bool)
    covered[pixel] = True
    return int(np.count_nonzero(covered))


def _checked(points, faces, K) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    points, faces, K = np.asarray(points, float), np.asarray(faces), np.asarray(K, float)
    if points.ndim != 2 or points.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3 or K.shape != (3, 3):
        raise ValueError(f"need points (V, 3), faces (F, 3) and K (3, 3), got {points.shape}, {faces.shape}, {K.shape}")
    if not np.all(np.isfinite(points)):
        raise ValueError("points contain NaN or inf")
    if faces.size and (faces.min() < 0 or faces.max() >= len(points)):
        raise ValueError(f"faces index vertices outside 0..{len(points) - 1}")
    return points, faces, K


def _fragments(points: np.ndarray, faces: np.ndarray, K: np.ndarray, size: tuple[int, int], near: float
               ) -> tuple[Int[np.ndarray, "n"], Int[np.ndarray, "n"], Float[np.ndarray, "n 3"], Float[np.ndarray, "n 3"]]:
    """Every (triangle, pixel) pair whose pixel centre lies in the triangle (edges included): the index into
    ``faces``, the flat pixel index (row * width + column), the barycentric weights and the corners' depths.

    Each triangle's bounding box is expanded into candidate pixels. The edge functions' coordinate differences are
    taken once per triangle and gathered per candidate as flat arrays, which does the same floating-point operations
    in the same order as differences of gathered corners (the same bits, with less memory traffic); triangles with
    no candidate pixel or no area are dropped before the expansion."""
    width, height = size
    corner_z = points[:, 2][faces]  # (F, 3)
    keep = np.flatnonzero((corner_z[:, 0] > near) & (corner_z[:, 1] > near) & (corner_z[:, 2] > near))
    with np.errstate(divide="ignore", invalid="ignore"):  # vertices of dropped triangles may sit at z <= 0
        projected = (points @ K.T)[:, :2] / points[:, 2:]
    kept = faces[keep]
    ax, ay, bx, by, cx, cy = (np.ascontiguousarray(projected[kept[:, k], axis]) for k in range(3) for axis in range(2))
    low_x = np.clip(np.ceil(np.minimum(np.minimum(ax, bx), cx)), 0, width).astype(np.int64)
    low_y = np.clip(np.ceil(np.minimum(np.minimum(ay, by), cy)), 0, height).astype(np.int64)
    high_x = np.clip(np.floor(np.maximum(np.maximum(ax, bx), cx)), -1, width - 1).astype(np.int64)
    high_y = np.clip(np.floor(np.maximum(np.maximum(ay, by), cy)), -1, height - 1).astype(np.int64)
    span = np.maximum(high_x - low_x + 1, 0)
    counts = span * np.maximum(high_y - low_y + 1, 0)
    area = (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)  # twice the signed area of (a, b, c)
    sign = np.sign(area)
    drawn = np.flatnonzero((counts > 0) & (area != 0))
    owner = np.repeat(drawn, counts[drawn])  # one candidate per pixel of each bounding box
    offset = np.arange(owner.size) - np.repeat(np.cumsum(counts[drawn]) - counts[drawn], counts[drawn])
    column = low_x[owner] + offset % span[owner]
    row = low_y[owner] + offset // span[owner]
    x, y = column.astype(float), row.astype(float)

    def edge(px, py, qx, qy):  # twice the signed area of (p, q, pixel centre) per candidate, in either winding
        return ((qx - px)[owner] * (y - py[owner]) - (qy - py)[owner] * (x - px[owner])) * sign[owner]

    weights = np.stack([edge(bx, by, cx, cy), edge(cx, cy, ax, ay), edge(ax, ay, bx, by)], axis=1)
    inside = np.flatnonzero((weights[:, 0] >= 0) & (weights[:, 1] >= 0) & (weights[:, 2] >= 0))
    owner = owner[inside]
    return (keep[owner], row[inside] * width + column[inside], weights[inside] / np.abs(area)[owner][:, None],
            corner_z[keep[owner]])


def face_parts(model: BodyModel) -> Int[np.ndarray, "faces"]:
    """The body part (joint of ``model.skeleton``) of each triangle: the joint with the most skinning weight
    over its corners."""
    weights = np.asarray(model.weights)[np.asarray(model.faces)]  # (F, 3, joints)
    return np.argmax(weights.sum(axis=1), axis=1)


def render_people(
    camera: Camera,
    vertices: Sequence[Float[ArrayLike, "vertices 3"]],
    model: BodyModel,
    size: tuple[int, int],
    ambient: float = 0.35,
) -> Rendering:
    """One frame of posed meshes of ``model`` (world metres, one array per person) seen by ``camera``.

    Shading is Lambertian with the light at the camera: a face's colour is its part colour times the person's
    tint times ``ambient + (1 - ambient) |cos|`` of the angle between its normal and the ray to it."""
    K, R, t, dist = (np.asarray(x, float) for x in (camera.K, camera.R, camera.t, camera.dist))
    if K.shape != (3, 3):
        raise ValueError(f"render one camera at a time, got K of shape {K.shape}")
    if np.any(dist != 0):
        raise ValueError("render_people needs an undistorted camera (dist all zero)")
    faces = np.asarray(model.faces)
    parts = face_parts(model)
    in_camera = [np.asarray(v, float) @ R.T + t for v in vertices]
    if not in_camera:
        width, height = size
        return Rendering(np.broadcast_to(_BACKGROUND, (height, width, 3)).copy(), np.full((height, width), -1),
                         np.full((height, width), np.inf))
    if any(v.shape != np.shape(model.v_template) for v in in_camera):
        raise ValueError(f"every person must be a posed mesh of the model, {np.shape(model.v_template)}, got "
                         f"{[v.shape for v in in_camera]}")
    all_points = np.concatenate(in_camera)
    all_faces = np.concatenate([faces + i * len(in_camera[0]) for i in range(len(in_camera))])
    raster = rasterise(all_points, all_faces, K, size)
    visible = raster.face >= 0
    face = raster.face[visible]
    corners = all_points[all_faces[face]]
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    ray = corners.mean(axis=1)
    cosine = np.abs(np.sum(normal * ray, axis=1)) / np.maximum(
        np.linalg.norm(normal, axis=1) * np.linalg.norm(ray, axis=1), 1e-12)
    person = np.full(raster.face.shape, -1)
    person[visible] = face // len(faces)
    colour = (_PART_COLOURS[parts[face % len(faces)]] * _PERSON_TINTS[person[visible] % len(_PERSON_TINTS)]
              * (ambient + (1 - ambient) * cosine)[:, None])
    image = np.broadcast_to(_BACKGROUND, raster.face.shape + (3,)).copy()
    image[visible] = np.clip(np.round(colour), 0, 255).astype(np.uint8)
    return Rendering(image, person, raster.depth)

"""The z-buffered rasteriser and body rendering (mocap/_render.py)."""

import cv2
import jax
import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal

from geometry import Camera, body_forward, look_at, stand_in_body_model
from mocap import covered_pixels, face_parts, rasterise, render_people

K = np.array([[80.0, 0.0, 31.5], [0.0, 80.0, 23.5], [0.0, 0.0, 1.0]])
SIZE = (64, 48)
BODY = stand_in_body_model()


def brute_force(points, faces, K, size):
    """Every pixel against every triangle, one at a time: the nearest covering triangle (barycentric
    coordinates of the pixel in the image triangle, perspective-correct depth)."""
    width, height = size
    face_index, depth = np.full((height, width), -1), np.full((height, width), np.inf)
    for f, corners in enumerate(points[faces]):
        uv = (corners @ K.T)[:, :2] / corners[:, 2:]
        T = np.array([uv[0] - uv[2], uv[1] - uv[2]]).T
        if abs(np.linalg.det(T)) < 1e-12:
            continue
        for r in range(height):
            for c in range(width):
                l0, l1 = np.linalg.solve(T, np.array([c, r], float) - uv[2])
                bary = np.array([l0, l1, 1 - l0 - l1])
                if np.all(bary >= -1e-12):
                    z = 1.0 / np.sum(bary / corners[:, 2])
                    if z < depth[r, c]:
                        face_index[r, c], depth[r, c] = f, z
    return face_index, depth


def test_matches_a_per_pixel_brute_force():
    rng = np.random.default_rng(0)
    centres = np.column_stack([rng.uniform(-0.8, 0.8, 12), rng.uniform(-0.6, 0.6, 12), rng.uniform(2.0, 4.0, 12)])
    points = (centres[:, None] + rng.normal(scale=0.25, size=(12, 3, 3))).reshape(-1, 3)
    faces = np.arange(36).reshape(12, 3)
    raster = rasterise(points, faces, K, SIZE)
    expected_face, expected_depth = brute_force(points, faces, K, SIZE)
    differs = raster.face != expected_face
    assert differs.mean() < 0.002  # only pixel centres on an edge, within rounding, may go either way
    assert_allclose(raster.depth[~differs], expected_depth[~differs], rtol=1e-10)
    assert 0.05 < np.mean(raster.face >= 0) < 0.9


def test_depth_is_perspective_correct_on_a_tilted_plane():
    corners = np.array([[-2.0, -3.0, 2.0], [4.0, -3.0, 8.0], [4.0, 3.0, 8.0], [-2.0, 3.0, 2.0]])
    raster = rasterise(corners, np.array([[0, 1, 2], [0, 2, 3]]), K, SIZE)
    assert np.all(raster.face >= 0)  # the quad covers the image, with no crack along its diagonal
    rows, columns = np.mgrid[:SIZE[1], :SIZE[0]]
    rays = np.stack([(columns - K[0, 2]) / K[0, 0], (rows - K[1, 2]) / K[1, 1], np.ones(rows.shape)], -1)
    # The plane z = 4 + x: along the ray (x, y, 1) s, s = 4 / (1 - x).
    assert_allclose(raster.depth, 4.0 / (1.0 - rays[..., 0]), rtol=1e-12)


def test_nearer_surfaces_hide_farther_ones_and_the_camera_culls_what_is_behind():
    square = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]])
    quads = np.array([[0, 1, 2], [0, 2, 3]])
    points = np.concatenate([square + [0, 0, 5.0], 0.3 * square + [0, 0, 3.0], square + [0, 0, -1.0]])
    faces = np.concatenate([quads, quads + 4, quads + 8])
    raster = rasterise(points, faces, K, SIZE)
    centre = raster.face[SIZE[1] // 2, SIZE[0] // 2]
    assert centre in (2, 3) and raster.depth[SIZE[1] // 2, SIZE[0] // 2] == pytest.approx(3.0)
    assert set(np.unique(raster.face)) == {-1, 0, 1, 2, 3}  # the plane behind the camera is never drawn
    assert np.all(rasterise(points[8:], quads, K, SIZE).face == -1)


def test_a_projected_point_lands_on_its_pixel_as_in_opencv():
    vertex = np.array([0.31, -0.22, 3.0])
    points = np.stack([vertex, vertex + [0.04, 0.0, 0.0], vertex + [0.0, 0.04, 0.0]])
    pixel = cv2.projectPoints(vertex[None], np.zeros(3), np.zeros(3), K, np.zeros(5))[0].ravel()
    raster = rasterise(points, np.array([[0, 1, 2]]), K, SIZE)
    r, c = np.argwhere(raster.face == 0).min(axis=0)  # the triangle's top-left covered pixel
    assert (c, r) == tuple(np.ceil(pixel).astype(int))


def test_covered_pixels_counts_what_rasterise_draws():
    """Triangles overlapping, half outside the image and behind the camera: the count of pixels drawn, without
    the z-buffer."""
    rng = np.random.default_rng(1)
    centres = np.column_stack([rng.uniform(-1.5, 1.5, 40), rng.uniform(-1.0, 1.0, 40), rng.uniform(-1.0, 4.0, 40)])
    points = (centres[:, None] + rng.normal(scale=0.3, size=(40, 3, 3))).reshape(-1, 3)
    faces = np.arange(120).reshape(40, 3)
    drawn = np.count_nonzero(rasterise(points, faces, K, SIZE).face >= 0)
    assert 0.05 * np.prod(SIZE) < drawn < np.prod(SIZE)
    assert covered_pixels(points, faces, K, SIZE) == drawn
    assert covered_pixels(points, faces[:0], K, SIZE) == 0
    with pytest.raises(ValueError, match="outside"):
        covered_pixels(points, faces + 1, K, SIZE)


def test_pixel_centres_on_an_edge_belong_to_the_triangle_in_either_winding():
    """A square with corners on pixel centres (2, 2) and (6, 6), cut along its diagonal: each half, drawn alone in
    either winding, covers the 15 centres on or inside its three edges, and the two halves cover the square's 25
    (the diagonal's 5 in both)."""
    corners = np.array([[2.0, 2.0, 1.0], [6.0, 2.0, 1.0], [6.0, 6.0, 1.0], [2.0, 6.0, 1.0]])  # z = 1: (x, y) is the pixel
    halves = np.array([[0, 1, 2], [0, 2, 3]])
    for half in (*halves, *halves[:, ::-1]):
        assert covered_pixels(corners, half[None], np.eye(3), (10, 10)) == 15, half
    raster = rasterise(corners, halves, np.eye(3), (10, 10))
    assert_array_equal(np.argwhere(raster.face >= 0), np.argwhere(np.pad(np.ones((5, 5)), ((2, 3), (2, 3)))))


@pytest.fixture(scope="module")
def two_people():
    rest = np.broadcast_to(np.eye(3), (24, 3, 3))
    near = np.asarray(body_forward(BODY, rest, np.zeros(3), np.array([0.0, 1.0, 0.0])).vertices)
    far = np.asarray(body_forward(BODY, rest, np.array([1.0, 0.0, 0.0]), np.array([0.3, 1.0, -2.0])).vertices)
    eye = np.array([0.0, 1.0, 4.0])
    R = np.asarray(look_at(eye, np.array([0.0, 1.0, 0.0]), (0.0, 1.0, 0.0)))
    camera = Camera(K=np.array([[300.0, 0, 160], [0, 300.0, 120], [0, 0, 1]]), R=R, t=-R @ eye, dist=np.zeros(5),
                    image_size=np.array([320.0, 240.0]))
    return camera, near, far


def test_people_occlude_each_other_and_shading_follows_the_parts(two_people):
    camera, near, far = two_people
    both = render_people(camera, [near, far], BODY, (320, 240))
    alone = render_people(camera, [far], BODY, (320, 240))
    assert both.image.dtype == np.uint8 and both.image.shape == (240, 320, 3)
    hidden = (alone.person == 0) & (both.person == 0)
    assert hidden.sum() > 100  # the far person is behind the near one there
    assert_array_equal(both.person[(alone.person == 0) & ~hidden & (both.person >= 0)], 1)
    assert np.all(both.depth[both.person == 0] < 4.5) and np.all(both.depth[both.person == 1] > 5.0)
    assert_array_equal(both.image[both.person < 0], np.broadcast_to([40, 44, 52], both.image[both.person < 0].shape))
    assert len(np.unique(both.image[both.person == 0].reshape(-1, 3), axis=0)) > 20  # parts and shading
    parts = face_parts(BODY)  # a capsule belongs to the joint it leaves, as SMPL's segments do
    assert parts.shape == (len(BODY.faces),)
    assert {BODY.skeleton.index("neck"), BODY.skeleton.index("l_ankle")} <= set(parts)
    assert BODY.skeleton.index("head") not in set(parts)
    empty = render_people(camera, [], BODY, (320, 240))
    assert np.all(empty.person == -1)


def test_jax_arrays_are_accepted_and_errors_are_clear(two_people):
    camera, near, _ = two_people
    jax_camera = jax.tree.map(jax.numpy.asarray, camera)
    assert_array_equal(render_people(jax_camera, [near], BODY, (320, 240)).person,
                       render_people(camera, [near], BODY, (320, 240)).person)
    with pytest.raises(ValueError, match="undistorted"):
        render_people(camera._replace(dist=np.array([0.1, 0, 0, 0, 0])), [near], BODY, (320, 240))
    with pytest.raises(ValueError, match="posed mesh of the model"):
        render_people(camera, [near[:-1]], BODY, (320, 240))
    with pytest.raises(ValueError, match="NaN"):
        rasterise(np.full((3, 3), np.nan), np.array([[0, 1, 2]]), K, SIZE)
    with pytest.raises(ValueError, match="outside"):
        rasterise(np.ones((3, 3)), np.array([[0, 1, 3]]), K, SIZE)

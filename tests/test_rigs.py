"""Synthetic rigs point where they should; perturbations have the documented size and statistics."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jaxtyping import TypeCheckError
from numpy.testing import assert_allclose
from scipy.spatial.transform import Rotation

from geometry import (
    Camera,
    camera_centre,
    perturb_extrinsics_bounded,
    perturb_extrinsics_relative,
    point_depth,
    project,
    project_to_views,
    projection_matrix,
    ring_angles,
    ring_rig,
    structri_virtual_rig,
)

SHELF_LIKE = dict(radius=3.5, target=(0.3, -0.2, 1.0), height=2.2, focal=1000.0, image_size=(1032, 776))


def test_ring_angles():
    assert_allclose(ring_angles(4, "round"), [0, np.pi / 2, np.pi, 3 * np.pi / 2])
    assert_allclose(ring_angles(4, "half"), [0, np.pi / 4, np.pi / 2, 3 * np.pi / 4])
    with pytest.raises((ValueError, TypeCheckError)):  # jaxtyping checks the Literal first under pytest
        ring_angles(3, "full")
    with pytest.raises(ValueError, match="num_views"):
        ring_angles(0)


@pytest.mark.parametrize("pattern", ["round", "half"])
def test_ring_rig_geometry(pattern):
    rig = ring_rig(5, pattern=pattern, start_angle=0.4, **SHELF_LIKE)
    assert rig.num_views == 5
    target = np.array(SHELF_LIKE["target"])
    centres = np.asarray(camera_centre(rig))
    offsets = centres[:, :2] - target[:2]
    assert_allclose(np.linalg.norm(offsets, axis=-1), 3.5, rtol=1e-12)
    assert_allclose(centres[:, 2], 2.2, rtol=1e-12)
    azimuths = np.unwrap(np.arctan2(offsets[:, 1], offsets[:, 0]) - 0.4)
    step = (2 if pattern == "round" else 1) * np.pi / 5
    assert_allclose(azimuths, step * np.arange(5), atol=1e-12)
    # The target projects to the principal point, which is the image centre, in front of every camera.
    assert_allclose(project_to_views(rig, target), np.tile([515.5, 387.5], (5, 1)), atol=1e-9)
    for view in range(5):
        camera = rig.select(view)
        assert float(point_depth(camera, target)) > 0
        # Upright: a point straight above the target appears higher in the image.
        assert float(project(camera, target + np.array([0.0, 0.0, 0.3]))[1]) < 387.5
    assert_allclose(np.linalg.det(np.asarray(rig.R)), 1.0, atol=1e-12)


def test_ring_rig_half_covers_half_circle():
    half, round_ = ring_rig(6, pattern="half", **SHELF_LIKE), ring_rig(6, pattern="round", **SHELF_LIKE)
    target = np.array(SHELF_LIKE["target"])
    for rig, extent in ((half, np.pi * 5 / 6), (round_, 2 * np.pi * 5 / 6)):
        d = np.asarray(camera_centre(rig))[:, :2] - target[:2]
        azimuths = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
        assert azimuths[-1] - azimuths[0] == pytest.approx(extent)


def test_ring_rig_rejects_bad_arguments():
    with pytest.raises(ValueError, match="radius"):
        ring_rig(3, **{**SHELF_LIKE, "radius": 0.0})
    with pytest.raises((ValueError, TypeCheckError)):
        ring_rig(3, **{**SHELF_LIKE, "target": np.zeros(2)})


def reference_structri_projections(num_views: int, span: float) -> list[np.ndarray]:
    """The official ``generate_cam_systems`` (millimetres), transcribed."""
    K = np.array([[900, 0.5, 500], [0, 900, 500], [0, 0, 1]])
    T = np.array([[0], [0], [2000]])
    Ps = []
    for i in range(num_views):
        theta = i * span / num_views
        R = np.array([[np.cos(theta), 0, np.sin(theta)], [0, 1, 0], [-np.sin(theta), 0, np.cos(theta)]])
        Ps.append(K @ np.concatenate([R, T], axis=1))
    return Ps


@pytest.mark.parametrize(("pattern", "span"), [("round", 2 * np.pi), ("half", np.pi)])
def test_structri_rig_matches_official_code(pattern, span):
    rig = structri_virtual_rig(7, pattern)
    points_m = np.random.default_rng(0).uniform(-0.8, 0.8, (20, 3))
    ours = np.asarray(project_to_views(rig, points_m))
    for view, P in enumerate(reference_structri_projections(7, span)):
        homogeneous = np.concatenate([points_m * 1000.0, np.ones((20, 1))], axis=-1) @ P.T
        assert_allclose(ours[view], homogeneous[:, :2] / homogeneous[:, 2:], atol=1e-9)
    assert_allclose(np.linalg.norm(np.asarray(camera_centre(rig)), axis=-1), 2.0, rtol=1e-12)
    # Literal R_y: a vertical ring for z-up data, the ring's axis is world y.
    assert_allclose(np.asarray(camera_centre(rig))[:, 1], 0.0, atol=1e-12)
    assert_allclose(camera_centre(rig)[0], [0.0, 0.0, -2.0], atol=1e-12)


def test_structri_rig_z_up_is_horizontal_and_upright():
    rig = structri_virtual_rig(6, "round", up_axis="z")
    centres = np.asarray(camera_centre(rig))
    assert_allclose(centres[:, 2], 0.0, atol=1e-12)
    assert_allclose(np.linalg.norm(centres, axis=-1), 2.0, rtol=1e-12)
    assert_allclose(centres[0], [0.0, -2.0, 0.0], atol=1e-12)
    assert_allclose(rig.K, np.asarray(structri_virtual_rig(6).K))
    origin = np.zeros(3)
    assert_allclose(project_to_views(rig, origin), np.tile([500.0, 500.0], (6, 1)), atol=1e-9)
    above = np.asarray(project_to_views(rig, np.array([0.0, 0.0, 0.5])))
    assert np.all(above[:, 1] < 500.0)
    with pytest.raises((ValueError, TypeCheckError)):
        structri_virtual_rig(3, up_axis="x")


COPIES = 500
"""Statistics come from one perturbation of a rig tiled COPIES times (one compile, independent views)."""


def tiled(rig: Camera) -> Camera:
    return jax.tree.map(lambda leaf: jnp.tile(leaf, (COPIES,) + (1,) * (leaf.ndim - 1)), rig)


def per_copy(array) -> np.ndarray:
    """(COPIES * views, ...) -> (COPIES, views, ...)."""
    array = np.asarray(array)
    return array.reshape((COPIES, -1) + array.shape[1:])


def test_relative_perturbation_statistics():
    # Rotation angles well below pi, where the rotation vector is unambiguous after 3 % noise.
    rotvecs = np.array([[0.3, -0.5, 0.8], [1.0, 0.2, -0.4], [-0.6, 0.9, 0.5], [0.2, 0.3, -1.2]])
    rig = Camera.create(np.broadcast_to(np.eye(3), (4, 3, 3)), Rotation.from_rotvec(rotvecs).as_matrix(),
                        np.array([[0.5, -1.0, 4.0], [2.0, 0.3, 3.0], [-1.0, 1.5, 5.0], [0.7, 0.8, -3.5]]))
    perturbed = perturb_extrinsics_relative(jax.random.key(0), tiled(rig), 0.03)
    rotvec_noisy = per_copy(Rotation.from_matrix(np.asarray(perturbed.R)).as_rotvec())
    t_ratio = (per_copy(perturbed.t) - np.asarray(rig.t)) / np.asarray(rig.t)
    for ratio in ((rotvec_noisy - rotvecs) / rotvecs, t_ratio):
        flat = ratio.reshape(COPIES, -1)
        # A sample std of 500 normals has a relative spread of 3.2 %: 15 % is a 4.7-sigma bound.
        assert_allclose(flat.std(axis=0), 0.03, rtol=0.15)
        assert_allclose(ratio.std(), 0.03, rtol=0.03)
        assert np.abs(flat.mean(axis=0)).max() < 5 * 0.03 / np.sqrt(COPIES)
    # Views get independent noise; intrinsics untouched; R stays a rotation.
    assert abs(np.corrcoef(t_ratio[:, 0, 0], t_ratio[:, 1, 0])[0, 1]) < 0.2
    assert_allclose(perturbed.K, np.broadcast_to(np.eye(3), perturbed.K.shape))
    assert_allclose(np.einsum("vij,vkj->vik", perturbed.R, perturbed.R), np.broadcast_to(np.eye(3), perturbed.R.shape),
                    atol=1e-12)


def test_bounded_perturbation_within_bounds_and_spread():
    rig = ring_rig(4, **SHELF_LIKE)
    perturbed = perturb_extrinsics_bounded(jax.random.key(1), tiled(rig))
    offsets = per_copy(camera_centre(perturbed)) - np.asarray(camera_centre(rig))
    assert np.abs(offsets).max() <= 0.0025 + 1e-12
    assert np.abs(offsets).max() > 0.0024  # the bound is reached, not just respected
    assert_allclose(offsets.reshape(-1, 3).std(axis=0), 0.0025 / np.sqrt(3), rtol=0.05)  # uniform
    relative = np.einsum("vji,nvjk->nvik", np.asarray(rig.R), per_copy(perturbed.R))
    axes = Rotation.from_matrix(relative.reshape(-1, 3, 3)).as_rotvec()
    angles = np.degrees(np.linalg.norm(axes, axis=-1))
    assert angles.max() <= 2.5 + 1e-9
    assert angles.max() > 2.45
    assert np.mean(angles) == pytest.approx(1.25, rel=0.05)  # |U(-2.5, 2.5)| has mean 1.25
    # Random axis: the rotation axes (in the camera-relative frame) average to ~0.
    unit = axes / np.linalg.norm(axes, axis=-1, keepdims=True)
    assert np.abs(unit.mean(axis=0)).max() < 0.06
    # The target stays near the image centre: 2.5 deg at f = 1000 px is at most ~44 px.
    target = np.array(SHELF_LIKE["target"])
    x_cam = np.einsum("vij,j->vi", np.asarray(perturbed.R), target) + np.asarray(perturbed.t)
    pixels = 1000.0 * x_cam[:, :2] / x_cam[:, 2:] + np.array([515.5, 387.5])
    assert np.abs(pixels - np.array([515.5, 387.5])).max() < 50.0


@pytest.mark.parametrize("perturb", [perturb_extrinsics_relative, perturb_extrinsics_bounded])
def test_perturbation_deterministic_single_and_rig(perturb):
    rig = tiled(ring_rig(4, **SHELF_LIKE))  # same shapes as the statistics tests: no new compile
    args = (0.04,) if perturb is perturb_extrinsics_relative else ()
    a = perturb(jax.random.key(3), rig, *args)
    b = perturb(jax.random.key(3), rig, *args)
    c = perturb(jax.random.key(4), rig, *args)
    for leaf_a, leaf_b in zip(a, b):
        np.testing.assert_array_equal(leaf_a, leaf_b)
    assert not np.allclose(a.t, c.t)
    single = perturb(jax.random.key(3), rig.select(1), *args)
    assert single.R.shape == (3, 3) and single.t.shape == (3,)
    assert not np.allclose(single.t, rig.t[1])


def test_structri_rig_projection_matrix_units():
    P = np.asarray(projection_matrix(structri_virtual_rig(2)))
    # Metres here, millimetres in the official code: the last column is scaled by 1/1000.
    assert_allclose(P[:, :, 3], np.tile([1000.0, 1000.0, 2.0], (2, 1)), atol=1e-12)
    assert jnp.all(jnp.isfinite(P))

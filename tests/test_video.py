"""Retargeting the shipped clips to the body model (mocap/_retarget.py) and the synthetic monocular video
(mocap/_video.py): bone directions, grounding, camera-frame ground truth, the horizontal flip (mirrored pixels or
redrawn), box jitter."""

import dataclasses

import cv2
import jax
import numpy as np
import pytest
from numpy.testing import assert_allclose, assert_array_equal
from scipy.spatial.transform import Rotation

from geometry import BODY25, SMPL24, STRUCTRI17, Camera, body_forward, stand_in_body_model
from mocap import (BodyMotion, VideoConfig, flip_video, jitter_boxes, load_clip, rasterise, render_people,
                   retarget_clip, synthesise_video)

MODEL = stand_in_body_model()
CONFIG = VideoConfig(image_size=(96, 72), focal=100.0)
_pose = jax.vmap(body_forward, in_axes=(None, 0, None, 0))


def pose(rotations, betas, translation):
    """Vertices and joints of one person over frames, NumPy."""
    out = _pose(MODEL, rotations, betas, translation)
    return np.asarray(out.vertices), np.asarray(out.joints)


def unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def angle_degrees(a, b):
    return np.degrees(np.arccos(np.clip(np.sum(unit(a) * unit(b), axis=-1), -1.0, 1.0)))


def turn_degrees(a, b):
    """Angle of the rotation between rotation matrices a and b."""
    cosine = 0.5 * (np.trace(np.swapaxes(a, -1, -2) @ b, axis1=-2, axis2=-1) - 1.0)
    return np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0)))


def frames_of(motion: BodyMotion, start: int, stride: int, count: int) -> BodyMotion:
    chosen = slice(start, start + stride * count, stride)
    return motion._replace(fps=motion.fps / stride, rotations=motion.rotations[:, chosen],
                           translation=motion.translation[:, chosen])


def motion_globals(motion: BodyMotion) -> np.ndarray:
    """Global rotations from the local ones, (P, T, 24, 3, 3)."""
    out = motion.rotations.copy()
    for joint in SMPL24.topological_order[1:]:
        out[:, :, joint] = out[:, :, SMPL24.parents[joint]] @ motion.rotations[:, :, joint]
    return out


@pytest.fixture(scope="module")
def run():
    clip = load_clip("02_03_run")
    return clip, retarget_clip(clip, MODEL)


@pytest.fixture(scope="module")
def salsa_video():
    motion = retarget_clip(load_clip("60_03_61_03_salsa"), MODEL)
    return synthesise_video(frames_of(motion, 60, 10, 6), MODEL, CONFIG, np.random.default_rng(3))


# ------------------------------------------------------------------------------------------------
# Retargeting


def test_retarget_reproduces_the_clips_bone_directions(run):
    clip, motion = run
    _, joints = pose(motion.rotations[0], motion.betas[0], motion.translation[0])
    body = lambda name: clip.body25[0, :, BODY25.index(name)]  # noqa: E731
    smpl = lambda name: joints[:, SMPL24.index(name)]  # noqa: E731
    errors = {}
    for bone, (a, b) in {"thigh": ("hip", "knee"), "shin": ("knee", "ankle"), "upper arm": ("shoulder", "elbow"),
                         "forearm": ("elbow", "wrist")}.items():
        errors[bone] = np.mean([angle_degrees(smpl(f"{s}_{b}") - smpl(f"{s}_{a}"), body(f"{s}_{b}") - body(f"{s}_{a}"))
                                for s in "lr"])
    hips, model_hips = 0.5 * (body("l_hip") + body("r_hip")), 0.5 * (smpl("l_hip") + smpl("r_hip"))
    errors["spine"] = angle_degrees(smpl("neck") - model_hips,
                                    clip.structri17[0, :, STRUCTRI17.index("thorax")] - hips).mean()
    # Each limb's bone is matched exactly (its twist references are perpendicular to it); the spine only through
    # interpolated targets.
    assert max(errors[bone] for bone in ("thigh", "shin", "upper arm", "forearm")) < 0.01, errors
    assert errors["spine"] < 2.0, errors
    # The head looks where the nose points, and the pelvis faces the clip's forward (hips' left x up).
    head = motion_globals(motion)[0, :, SMPL24.index("head")]
    nose = body("nose") - 0.5 * (body("l_ear") + body("r_ear"))
    assert angle_degrees(head[..., :, 2], nose).mean() < 10.0
    forward = np.cross(body("l_hip") - body("r_hip"), [0.0, 0.0, 1.0])
    assert angle_degrees(motion.rotations[0, :, 0, :, 2], forward).max() < 30.0


def test_retarget_rotations_are_proper_and_twist_like_hinges(run):
    _, motion = run
    rotations = motion.rotations
    assert rotations.shape == (1, 44, 24, 3, 3) and motion.betas.shape == (1, MODEL.num_shapes)
    assert_allclose(rotations @ np.swapaxes(rotations, -1, -2), np.broadcast_to(np.eye(3), rotations.shape), atol=1e-12)
    assert_allclose(np.linalg.det(rotations), 1.0, atol=1e-12)
    for name in ("l_wrist", "r_wrist", "l_foot", "r_foot", "l_hand", "r_hand"):  # nothing known: identity
        assert_allclose(rotations[:, :, SMPL24.index(name)], np.broadcast_to(np.eye(3), (1, 44, 3, 3)), atol=1e-12)
    # Knees flex about their x axis and elbows about their y axis (twist from the bend plane), and no joint
    # flips between frames (the clip runs at 30 fps).
    for name, hinge, bound in (("l_knee", 0, 20.0), ("r_knee", 0, 20.0), ("l_elbow", 1, 10.0), ("r_elbow", 1, 10.0)):
        rotvec = Rotation.from_matrix(rotations[0, :, SMPL24.index(name)]).as_rotvec()
        bent = np.linalg.norm(rotvec, axis=-1) > np.radians(20)
        assert bent.sum() > 10
        assert np.degrees(np.arccos(np.abs(unit(rotvec[bent])[:, hinge]))).mean() < bound, name
    assert turn_degrees(rotations[:, :-1], rotations[:, 1:]).max() < 35.0


def test_retarget_keeps_the_feet_on_the_ground_and_follows_the_hips(run):
    clip, motion = run
    vertices, joints = pose(motion.rotations[0], motion.betas[0], motion.translation[0])
    lowest = vertices[..., 2].min(axis=1)
    assert abs(lowest.min()) < 0.02  # the lowest foot over the clip touches z = 0
    assert np.mean(lowest < 0.1) > 0.3  # a runner's feet are down a good part of the time
    hips = 0.5 * (clip.body25[0, :, BODY25.index("l_hip")] + clip.body25[0, :, BODY25.index("r_hip")])
    model_hips = 0.5 * (joints[:, SMPL24.index("l_hip")] + joints[:, SMPL24.index("r_hip")])
    assert_allclose(model_hips[:, :2], hips[:, :2], atol=1e-9)  # horizontally exact, heights scaled
    assert np.std(model_hips[:, 2] - hips[:, 2]) < 0.02


def test_retarget_betas_and_bad_input(run):
    clip, _ = run
    betas = np.array([1.0, 0.0, -1.0])
    motion = retarget_clip(clip, MODEL, betas)
    assert_array_equal(motion.betas, betas[None])
    vertices, _ = pose(motion.rotations[0, :6], motion.betas[0], motion.translation[0, :6])
    assert abs(vertices[..., 2].min()) < 0.1  # taller legs, still on the ground
    with pytest.raises(ValueError, match="betas must have shape"):
        retarget_clip(clip, MODEL, np.zeros(4))
    with pytest.raises(ValueError, match="betas contain NaN"):
        retarget_clip(clip, MODEL, np.array([np.nan, 0.0, 0.0]))
    body25 = clip.body25.copy()
    body25[0, 3, 5, 1] = np.nan
    with pytest.raises(ValueError, match="body25 contains NaN"):
        retarget_clip(clip._replace(body25=body25), MODEL)
    with pytest.raises(ValueError, match=r"need body25 \(P, T, 25, 3\)"):
        retarget_clip(clip._replace(body25=clip.body25[..., :24, :]), MODEL)
    with pytest.raises(ValueError, match="same non-zero people and frame counts"):
        retarget_clip(clip._replace(structri17=clip.structri17[:, :10]), MODEL)


# ------------------------------------------------------------------------------------------------
# The video


def camera_of(video, t):
    return Camera(*(np.asarray(leaf)[t] for leaf in video.camera))


def camera_frame_meshes(video):
    """Per person, vertices and joints (T, ., 3) of body_forward with the video's camera-frame parameters."""
    return [pose(video.rotations[p], video.betas[p], video.translation[p]) for p in range(len(video.betas))]


def test_video_ground_truth_is_self_consistent(salsa_video):
    video = salsa_video
    width, height = CONFIG.image_size
    assert video.frames.shape == (6, height, width, 3) and video.frames.dtype == np.uint8
    assert video.rotations.shape == (2, 6, 24, 3, 3) and video.joints2d.shape == (2, 6, 24, 2)
    assert_array_equal(np.asarray(video.camera.dist), 0.0)
    assert_array_equal(np.asarray(video.camera.image_size), np.broadcast_to([width, height], (6, 2)))
    for p, (vertices, joints) in enumerate(camera_frame_meshes(video)):
        assert_allclose(joints, video.joints3d[p], atol=1e-9)
        for t in range(6):
            K = np.asarray(video.camera.K[t])
            expected, _ = cv2.projectPoints(video.joints3d[p, t], np.zeros(3), np.zeros(3), K, np.zeros(5))
            assert_allclose(video.joints2d[p, t], expected[:, 0], atol=1e-7)
            pixels = (vertices[t] @ K.T)[:, :2] / vertices[t, :, 2:]
            assert_allclose(video.boxes[p, t, :2], pixels.min(axis=0), atol=1e-7)  # tight ...
            assert_allclose(video.boxes[p, t, 2:], pixels.max(axis=0), atol=1e-7)
    # The people are drawn inside their boxes.
    background = render_people(camera_of(video, 0), [], MODEL, CONFIG.image_size).image[0, 0]
    rows, columns = np.mgrid[:height, :width]
    for t in range(6):
        in_a_box = np.zeros((height, width), bool)
        for x0, y0, x1, y1 in video.boxes[:, t]:
            in_a_box |= (columns >= x0 - 1) & (columns <= x1 + 1) & (rows >= y0 - 1) & (rows <= y1 + 1)
        drawn = np.any(video.frames[t] != background, axis=-1)
        assert drawn.sum() > 50 and not np.any(drawn & ~in_a_box)
    # Everyone stays inside the image, and is seen.
    assert np.all(video.boxes[..., :2] >= 0) and np.all(video.boxes[..., 2] <= width - 1)
    assert np.all(video.boxes[..., 3] <= height - 1)
    assert np.all((video.visibility > 0) & (video.visibility <= 1))


def test_a_rest_pelvis_off_the_origin_is_carried_by_the_translation(run):
    """SMPL's rest pelvis J0 is not at the origin: retargeting, the camera-frame translation
    R (translation + J0) + t - J0 and the flip must all account for it."""
    clip, motion = run
    shifted = dataclasses.replace(MODEL, v_template=MODEL.v_template + np.array([[0.0, 0.3, -0.05]]))
    offset = frames_of(retarget_clip(clip, shifted), 0, 10, 3)
    assert_allclose(offset.rotations, frames_of(motion, 0, 10, 3).rotations, atol=1e-12)  # same rest directions
    video = synthesise_video(offset, shifted, CONFIG, np.random.default_rng(1))
    R = np.asarray(video.camera.R)
    assert_allclose(video.rotations[0, :, 0], R @ offset.rotations[0, :, 0], atol=1e-12)
    for v in (video, flip_video(video, shifted)):
        joints = np.asarray(_pose(shifted, v.rotations[0], v.betas[0], v.translation[0]).joints)
        assert_allclose(joints, v.joints3d[0], atol=1e-9)


def test_camera_is_upright_and_moves_slowly(salsa_video):
    video = salsa_video
    R, t = np.asarray(video.camera.R), np.asarray(video.camera.t)
    assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    assert np.abs(R[:, 0, 2]).max() < 0.02  # image rows stay level: hardly any roll
    centres = -np.einsum("tji,tj->ti", R, t)
    steps = np.linalg.norm(np.diff(centres, axis=0), axis=-1)
    turns = turn_degrees(R[:-1], R[1:])
    fps = 3.0  # 30 fps strided by 10
    wobble_rate = 2 * np.pi * CONFIG.wobble_frequency  # per second, relative to the wobble's amplitude
    people = np.einsum("tji,ptj->pti", R, video.joints3d[:, :, 0] - t[None]).mean(axis=(0, 1))  # world pelvis
    distance = np.linalg.norm(centres[:, :2] - people[:2], axis=-1).max()
    assert steps.max() < (np.radians(CONFIG.orbit_speed) * distance + CONFIG.dolly_speed
                          + 2 * wobble_rate * CONFIG.wobble_shift) / fps
    assert turns.max() < 1.5 * (CONFIG.orbit_speed + 2 * wobble_rate * CONFIG.wobble_angle) / fps
    assert steps.min() > 1e-4 and turns.min() > 1e-3  # it does move


def test_visibility_counts_the_pixels_others_hide():
    """Two coincident people share one silhouette (visibilities sum to 1); alone, a person in view is whole."""
    motion = frames_of(retarget_clip(load_clip("02_03_run"), MODEL), 0, 10, 3)
    twins = BodyMotion(motion.name, motion.fps, np.concatenate([motion.rotations] * 2),
                       np.concatenate([motion.betas] * 2), np.concatenate([motion.translation] * 2))
    video = synthesise_video(twins, MODEL, CONFIG, np.random.default_rng(0))
    assert_allclose(video.visibility.sum(axis=0), 1.0, atol=0.02)
    alone = synthesise_video(motion, MODEL, CONFIG, np.random.default_rng(0))
    assert_allclose(alone.visibility, 1.0, atol=0.02)
    # Cross-check one frame: the person's pixels against a raster of their mesh alone.
    vertices, _ = pose(alone.rotations[0], alone.betas[0], alone.translation[0])
    alone_area = np.count_nonzero(rasterise(vertices[1], MODEL.faces, np.asarray(alone.camera.K[1]),
                                            CONFIG.image_size).face >= 0)
    drawn = np.count_nonzero(np.any(alone.frames[1] != alone.frames[1, 0, 0], axis=-1))
    assert abs(drawn - alone_area) <= 2


def test_video_is_deterministic_from_the_rng():
    motion = frames_of(retarget_clip(load_clip("02_03_run"), MODEL), 0, 10, 2)
    a, b = (synthesise_video(motion, MODEL, CONFIG, np.random.default_rng(5)) for _ in range(2))
    c = synthesise_video(motion, MODEL, CONFIG, np.random.default_rng(6))
    assert_array_equal(a.frames, b.frames) and np.array_equal(a.joints2d, b.joints2d)
    assert not np.allclose(a.joints3d, c.joints3d)


def test_video_rejects_bad_input(run):
    _, motion = run
    short = frames_of(motion, 0, 10, 2)
    with pytest.raises(ValueError, match="rotations must be"):
        synthesise_video(short._replace(rotations=short.rotations[:, :, :23]), MODEL, CONFIG, np.random.default_rng(0))
    with pytest.raises(ValueError, match="translation must be"):
        synthesise_video(short._replace(translation=short.translation[:, :1]), MODEL, CONFIG, np.random.default_rng(0))
    translation = short.translation.copy()
    translation[0, 1, 2] = np.nan
    with pytest.raises(ValueError, match="translation contain NaN"):
        synthesise_video(short._replace(translation=translation), MODEL, CONFIG, np.random.default_rng(0))
    with pytest.raises(ValueError, match="distance must be a range"):
        VideoConfig(distance=(5.0, 2.0))
    with pytest.raises(ValueError, match="margin"):
        VideoConfig(margin=0.6)


# ------------------------------------------------------------------------------------------------
# Flipping and box jitter


def test_flip_mirrors_every_field_and_twice_is_the_identity(salsa_video):
    video = salsa_video
    flipped = flip_video(video, MODEL)
    width = CONFIG.image_size[0]
    mirror = list(SMPL24.mirror)
    assert_array_equal(flipped.frames, video.frames[:, :, ::-1])
    # Pixel centres at integer coordinates, principal point (W - 1) / 2: x -> W - 1 - x.
    assert_allclose(flipped.joints2d[..., 0], width - 1 - video.joints2d[:, :, mirror, 0], atol=1e-12)
    assert_allclose(flipped.joints2d[..., 1], video.joints2d[:, :, mirror, 1], atol=1e-12)
    assert_allclose(flipped.boxes[..., [0, 2]], width - 1 - video.boxes[..., [2, 0]], atol=1e-12)
    twice = flip_video(flipped, MODEL)
    for field, a, b in zip(video._fields, twice, video):
        if field == "camera":
            for leaf_a, leaf_b in zip(a, b):
                assert_allclose(np.asarray(leaf_a), np.asarray(leaf_b), atol=1e-12)
        else:
            assert_allclose(a, b, atol=1e-12, err_msg=field)


def test_flipped_parameters_pose_the_flipped_people(salsa_video):
    video = salsa_video
    flipped = flip_video(video, MODEL)
    assert_allclose(np.linalg.det(flipped.rotations), 1.0, atol=1e-12)
    meshes = camera_frame_meshes(flipped)
    for p, (vertices, joints) in enumerate(meshes):
        assert_allclose(joints, flipped.joints3d[p], atol=1e-9)
        for t in range(0, 6, 2):
            K = np.asarray(flipped.camera.K[t])
            expected, _ = cv2.projectPoints(flipped.joints3d[p, t], np.zeros(3), np.zeros(3), K, np.zeros(5))
            assert_allclose(flipped.joints2d[p, t], expected[:, 0], atol=1e-7)
    # The flipped meshes, rendered, cover the mirrored silhouettes (part colours swap sides, so compare masks).
    identity = Camera(np.asarray(flipped.camera.K[2]), np.eye(3), np.zeros(3), np.zeros(5), np.zeros(2))
    drawn = render_people(identity, [vertices[2] for vertices, _ in meshes], MODEL, CONFIG.image_size).person
    original = render_people(camera_of(video, 2), [], MODEL, CONFIG.image_size).image
    expected = np.any(video.frames[2] != original, axis=-1)[:, ::-1]
    assert np.mean((drawn >= 0) != expected) < 0.005
    # The mirrored camera sees the mirrored world: its centre mirrors too.
    centre = lambda v, t: -np.asarray(v.camera.R[t]).T @ np.asarray(v.camera.t[t])  # noqa: E731
    assert_allclose(centre(flipped, 4), centre(video, 4) * [-1.0, 1.0, 1.0], atol=1e-12)


def _blue_over_red(video, side: str) -> float:
    """Over the frames and people, the fraction of one side's limb joints (``l_`` or ``r_``) whose pixel is bluer
    than it is red, less the fraction redder than blue: the renders colour the left limbs bluish, the right reddish."""
    limbs = [j for j, name in enumerate(SMPL24.joints) if name.startswith(side)
             and name[2:] in ("shoulder", "elbow", "wrist", "knee", "ankle")]
    x, y = np.moveaxis(np.round(video.joints2d[:, :, limbs]).astype(int), -1, 0)  # (P, T, joints)
    frame = np.broadcast_to(np.arange(video.frames.shape[0])[None, :, None], x.shape)
    pixels = video.frames[frame, y, x].astype(int)
    return float(np.mean(np.sign(pixels[..., 2] - pixels[..., 0])))


def test_a_redrawn_flip_has_the_mirrored_silhouettes_and_the_labels_colours(salsa_video):
    """Mirrored pixels keep each part colour on its side while the labels swap; redrawn, the mirrored people carry
    their own labels' colours: left limbs as bluish as in the original video, the same silhouettes as the mirrored
    pixels (a symmetric body), and the same ground truth."""
    video = salsa_video
    pixels, redrawn = flip_video(video, MODEL), flip_video(video, MODEL, redraw=True)
    for field, a, b in zip(video._fields, redrawn, pixels):
        if field not in ("frames", "camera"):
            assert_array_equal(a, b, err_msg=field)
    background = video.frames[0, 0, 0]
    assert np.mean(np.any(redrawn.frames != background, -1) != np.any(pixels.frames != background, -1)) < 0.001
    for side in ("l_", "r_"):
        assert abs(_blue_over_red(redrawn, side) - _blue_over_red(video, side)) < 0.15, side
    assert _blue_over_red(video, "l_") - _blue_over_red(video, "r_") > 0.5  # the statistic tells the sides apart
    assert _blue_over_red(pixels, "l_") - _blue_over_red(pixels, "r_") < -0.5  # and the mirrored pixels swap them
    assert np.mean(flip_video(redrawn, MODEL, redraw=True).frames != video.frames) < 1e-4  # twice: the original

def test_jitter_boxes_is_bounded_smooth_and_deterministic():
    rng = np.random.default_rng(0)
    corners = rng.uniform(0, 200, (3, 40, 2))
    boxes = np.concatenate([corners, corners + rng.uniform(20, 80, (3, 40, 2))], axis=-1)
    jittered = jitter_boxes(boxes, np.random.default_rng(1), scale=0.2, shift=0.1)
    assert jittered.shape == boxes.shape
    assert_array_equal(jittered, jitter_boxes(boxes, np.random.default_rng(1), scale=0.2, shift=0.1))
    assert not np.allclose(jittered, jitter_boxes(boxes, np.random.default_rng(2), scale=0.2, shift=0.1))
    size, new_size = boxes[..., 2:] - boxes[..., :2], jittered[..., 2:] - jittered[..., :2]
    ratio = new_size / size
    assert_allclose(ratio[..., 0], ratio[..., 1], rtol=1e-12)  # one scale factor per box keeps the aspect
    assert np.all((ratio >= 0.8) & (ratio <= 1.2)) and np.ptp(ratio) > 0.1
    moved = (0.5 * (jittered[..., :2] + jittered[..., 2:]) - 0.5 * (boxes[..., :2] + boxes[..., 2:])) / size
    assert np.all(np.abs(moved) <= 0.1 + 1e-12) and np.abs(moved).max() > 0.03
    # Smooth-ish: the scale drifts by less from frame to frame than independent draws would.
    assert np.abs(np.diff(ratio[..., 0], axis=-1)).mean() < 0.5 * np.abs(np.diff(rng.uniform(0.8, 1.2, 40))).mean()
    assert jitter_boxes(boxes[0, :1], np.random.default_rng(1)).shape == (1, 4)  # a single frame
    with pytest.raises(ValueError, match="NaN"):
        jitter_boxes(np.full((2, 4), np.nan), rng)
    with pytest.raises(ValueError, match="scale"):
        jitter_boxes(boxes, rng, scale=1.5)

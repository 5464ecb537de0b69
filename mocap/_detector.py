"""A model of a real bottom-up 2D pose detector (OpenPose BODY25) seen through a camera rig.

Given the 3D BODY25 joints of several people over time and a rig, :func:`detect` produces what
OpenPose would report in every view and frame, as :class:`~mocap.Detections` (the structure of the
real Shelf loader). The model is built from geometry, not from uniform dropout:

- **Occlusion by limbs.** Every body is a set of 3D capsules (torso, head, upper/lower arms and legs,
  feet; :data:`BODY25_CAPSULES`). A joint is occluded in a view when a capsule of another person, or
  a non-adjacent capsule of the same person, covers the joint's projection and lies in front of it
  along the camera's depth. Occlusion lowers confidences, PAF scores and position accuracy. Occlusion
  by another person makes the joint likely to be dropped; self-occlusion rarely does (OpenPose infers
  hidden body joints from the visible limbs), except for the face seen from behind.
- **Image geometry.** Joints behind the camera or outside the image are not reported; confidences drop
  near the image border and for small (distant) people; pixel noise scales with the person's apparent
  height in the image.
- **Detector failures.** Left/right label swaps of the arms, legs or face (more likely when the person
  is seen from the side); whole people missed (more when small, heavily occluded or truncated);
  identity swaps (a PAF linking a joint to the nearby joint of another person); spurious low-score
  candidates; occasional position outliers.

The geometric part (projection, depth ordering of capsules) is one jitted JAX kernel per camera and
frame, mapped over views and frames; the random part draws fixed-shape NumPy arrays from a generator
seeded by the JAX key, so the output is a pure function of the key, the rig, the joints and the config.
Defaults are tuned so a 4-person Shelf-like scene resembles the real Shelf OpenPose detections (about
57-61 candidates per view and frame, confidences >= 0.15 with median about 0.77, PAF matrices with
one clear non-zero per row).
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int

import geometry
from geometry import BODY25, Camera

from ._detections import BODY25_PAF_PAIRS, Detections
from ._motion import _pad

__all__ = [
    "DetectorConfig",
    "PERFECT_DETECTOR",
    "Capsule",
    "BODY25_CAPSULES",
    "SWAP_GROUPS",
    "ViewGeometry",
    "DetectorEvents",
    "view_geometry",
    "detect",
    "detect_with_events",
]

_NUM_JOINTS = BODY25.num_joints
_NUM_PAIRS = len(BODY25_PAF_PAIRS)
_PAIR_A = np.array([a for a, _ in BODY25_PAF_PAIRS])  # the joint types each PAF pair links
_PAIR_B = np.array([b for _, b in BODY25_PAF_PAIRS])
_J = BODY25.index
_FACE = ("nose", "r_eye", "l_eye", "r_ear", "l_ear")
_OCCLUDED_DROP = tuple(
    0.95 if name in _FACE else 0.45 if name.endswith("hip") else 0.8 for name in BODY25.joints
)
# OpenPose infers a body joint hidden behind the person's own body from the visible limbs (real
# Shelf: shoulders and hips are reported in ~90% of (person, view) pairs, wrists ~70%), but never
# reports a face seen from behind.
_SELF_OCCLUDED_DROP = tuple(0.95 if name in _FACE else 0.4 for name in BODY25.joints)

# Mean confidence per BODY25 joint type of an unoccluded, large, central joint. Chosen so that the
# simulated per-type means track the real Shelf OpenPose means (torso/face ~0.78-0.80, hips ~0.63,
# knees/ankles ~0.71, feet ~0.60-0.65) once occlusion and distance are applied.
_BASE_SCORES = (
    0.88, 0.87, 0.85, 0.85, 0.82, 0.85, 0.85, 0.82,  # nose, neck, r arm, l arm
    0.78, 0.76, 0.79, 0.78, 0.76, 0.79, 0.78,  # mid_hip, r leg, l leg
    0.86, 0.86, 0.84, 0.84,  # eyes, ears
    0.72, 0.72, 0.70, 0.72, 0.72, 0.70,  # l foot, r foot
)


@dataclasses.dataclass(frozen=True)
class DetectorConfig:
    """Every knob of the detector model. Defaults resemble the real Shelf OpenPose detections.

    Sizes called "fraction of height" are relative to the person's apparent height in the image
    (:attr:`ViewGeometry.apparent_height`, pixels), so noise and offsets scale with distance.
    Probabilities are per event (per person, view and frame unless stated).
    """

    # --- positions
    pixel_noise: float = 0.012
    """Standard deviation of the Gaussian pixel noise per axis, as a fraction of the apparent height
    (0.012 x 350 px = 4 px for a Shelf person)."""
    occluded_noise_gain: float = 2.0
    """The noise standard deviation is multiplied by ``1 + occluded_noise_gain * occlusion``."""
    noise_correlation: float = 0.0
    """Correlation of each joint's pixel noise between consecutive frames, in [0, 1): a first-order autoregressive
    sequence per person, view, joint and axis whose standard deviation per frame stays the one above. 0: white
    noise, independent per frame; a real detector's errors persist while the image changes little (e.g. 0.9 keeps
    about a third of an error after 10 frames)."""
    outlier_probability: float = 0.02
    """Probability per joint that the position is an outlier (a wrong peak on the same limb)."""
    outlier_scale: float = 0.06
    """Standard deviation per axis of an outlier's extra offset, fraction of the apparent height."""

    # --- confidences
    base_scores: tuple[float, ...] = _BASE_SCORES
    """Mean confidence of each of the 25 BODY25 joint types when fully visible, large and central."""
    score_noise: float = 0.07
    """Standard deviation of the Gaussian noise added to every confidence (unitless)."""
    occlusion_score_drop: float = 0.6
    """A fully occluded joint's mean confidence is multiplied by ``1 - occlusion_score_drop``."""
    small_height: float = 120.0
    """Apparent height (pixels) at and below which confidences are lowest and people often missed."""
    reference_height: float = 300.0
    """Apparent height (pixels) from which on the size no longer lowers confidences."""
    small_score_factor: float = 0.7
    """Confidence factor at :attr:`small_height` (linear up to 1 at :attr:`reference_height`)."""
    border_margin: float = 0.04
    """Joints closer than this fraction of the apparent height to the image border lose confidence,
    linearly down to :attr:`border_score_factor` on the border."""
    border_score_factor: float = 0.6
    """Confidence factor of a joint lying exactly on the image border."""
    score_threshold: float = 0.15
    """Candidates below this confidence are not reported (the real Shelf files have none below 0.15)."""
    max_score: float = 0.97
    """Confidences are clipped to at most this value."""

    # --- dropped joints and people
    joint_dropout: float = 0.03
    """Probability that a visible joint is not reported at all (missed peak)."""
    occluded_drop_probabilities: tuple[float, ...] = _OCCLUDED_DROP
    """Extra drop probability of each BODY25 joint type when fully hidden by OTHER people (scaled by
    :attr:`ViewGeometry.others_occlusion` in [0, 1]). OpenPose hallucinates hidden hips from context
    but never reports a hidden face: by default 0.45 for the hips, 0.95 for the eyes, ears and nose,
    0.8 otherwise."""
    self_occluded_drop_probabilities: tuple[float, ...] = _SELF_OCCLUDED_DROP
    """Drop probability of each BODY25 joint type when fully hidden by the person's OWN body
    (:attr:`ViewGeometry.self_occlusion`); the drop probability is the larger of this term and the
    :attr:`occluded_drop_probabilities` term for the occlusion by other people. By default 0.95 for
    the face (seen from behind) and 0.4 otherwise."""
    person_miss_probability: float = 0.03
    """Probability that a clearly visible person is missing entirely from one view."""
    small_person_miss_probability: float = 0.3
    """Extra miss probability at :attr:`small_height` (linear to 0 at :attr:`reference_height`)."""
    occluded_person_miss_probability: float = 0.4
    """Extra miss probability when every joint is occluded (scaled by the mean joint occlusion above
    one half, linearly)."""
    truncated_person_miss_probability: float = 0.5
    """Extra miss probability when every joint is outside the image (scaled by the fraction of
    joints outside)."""

    # --- left/right and identity swaps
    left_right_swap_probability: float = 0.01
    """Probability that the labels of one swap group (:data:`SWAP_GROUPS`: arms, legs, face) are
    mirrored when the person faces the camera."""
    side_view_swap_probability: float = 0.08
    """Extra swap probability when the person is seen exactly from the side (scaled by the square of
    :attr:`ViewGeometry.sideness`)."""
    identity_swap_probability: float = 0.3
    """Probability per PAF pair, person and other person that the PAF links this person's joint a to
    the other's joint b, when the other's joint b lies exactly on this person's joint b in the image;
    it decays as a Gaussian of their distance with scale :attr:`identity_swap_radius`."""
    identity_swap_radius: float = 0.08
    """Length scale (fraction of the apparent height) of the identity-swap proximity."""

    # --- part affinity fields
    paf_mean: float = 0.86
    """Mean PAF score of a true same-person pair, both joints visible."""
    paf_noise: float = 0.1
    """Standard deviation of the Gaussian noise on true PAF scores."""
    occlusion_paf_drop: float = 0.5
    """The mean PAF of a pair is multiplied by ``1 - occlusion_paf_drop * max(occlusion a, b)``."""
    paf_miss_probability: float = 0.03
    """Probability that a true pair's PAF is exactly 0 (no field found along the line)."""
    paf_clutter_probability: float = 0.02
    """Probability that a wrong pair (different people, or a spurious candidate) gets a non-zero
    PAF, uniform in [0.15, 0.8]."""
    max_paf: float = 1.05
    """Upper clip of PAF scores (OpenPose's line integral can slightly exceed 1; real Shelf max 1.18)."""

    # --- spurious candidates
    spurious_per_view: float = 2.0
    """Mean number of spurious (false-positive) candidates per view and frame (Poisson), spread
    uniformly over the joint types, each type capped at :attr:`max_spurious_per_joint`."""
    max_spurious_per_joint: int = 2
    """At most this many spurious candidates per joint type, view and frame."""
    spurious_near_person: float = 0.7
    """Fraction of spurious candidates placed near a random person's joint (offset std 0.15 of the
    apparent height) rather than uniformly in the image."""
    spurious_score_range: tuple[float, float] = (0.15, 0.45)
    """Spurious confidences are uniform in this range."""

    # --- occlusion geometry
    occlusion_depth_margin: float = 0.25
    """A capsule starts to occlude a joint when its axis is this many radii nearer to the camera than
    the joint (full occlusion at this plus 0.5 radii)."""
    occlusion_edge: float = 0.3
    """Soft edge of a capsule's silhouette: coverage falls linearly from 1 at ``1 - occlusion_edge``
    radii from the axis to 0 at 1 radius."""

    def __post_init__(self) -> None:
        if len(self.base_scores) != _NUM_JOINTS:
            raise ValueError(f"base_scores needs {_NUM_JOINTS} values (BODY25), got {len(self.base_scores)}")
        if len(self.occluded_drop_probabilities) != _NUM_JOINTS or not all(
            0.0 <= p <= 1.0 for p in self.occluded_drop_probabilities
        ):
            raise ValueError(f"occluded_drop_probabilities needs {_NUM_JOINTS} values in [0, 1] (BODY25)")
        if len(self.self_occluded_drop_probabilities) != _NUM_JOINTS or not all(
            0.0 <= p <= 1.0 for p in self.self_occluded_drop_probabilities
        ):
            raise ValueError(f"self_occluded_drop_probabilities needs {_NUM_JOINTS} values in [0, 1] (BODY25)")
        probabilities = (
            "outlier_probability", "joint_dropout", "person_miss_probability",
            "small_person_miss_probability", "occluded_person_miss_probability",
            "truncated_person_miss_probability", "left_right_swap_probability", "side_view_swap_probability",
            "identity_swap_probability", "paf_miss_probability", "paf_clutter_probability",
            "spurious_near_person", "occlusion_score_drop", "occlusion_paf_drop",
        )
        for name in probabilities:
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"DetectorConfig.{name} must be in [0, 1], got {value}")
        nonnegative = ("pixel_noise", "occluded_noise_gain", "outlier_scale", "score_noise", "spurious_per_view",
                       "paf_noise", "score_threshold", "identity_swap_radius", "border_margin")
        for name in nonnegative:
            if not getattr(self, name) >= 0.0:
                raise ValueError(f"DetectorConfig.{name} must be >= 0, got {getattr(self, name)}")
        if not 0.0 <= self.noise_correlation < 1.0:
            raise ValueError(f"DetectorConfig.noise_correlation must be in [0, 1), got {self.noise_correlation}")
        if not 0 < self.small_height < self.reference_height:
            raise ValueError("DetectorConfig needs 0 < small_height < reference_height (pixels)")
        low, high = self.spurious_score_range
        if not 0.0 <= low <= high <= 1.0:
            raise ValueError(f"DetectorConfig.spurious_score_range must satisfy 0 <= low <= high <= 1, got {low, high}")

    @classmethod
    def perfect(cls) -> "DetectorConfig":
        """No noise, drops, swaps, misses or spurious candidates: every joint inside the image is reported
        at its exact projection (confidences and PAFs still follow the geometry, noise-free)."""
        return cls(
            pixel_noise=0.0, outlier_probability=0.0, score_noise=0.0, score_threshold=0.0,
            joint_dropout=0.0, occluded_drop_probabilities=(0.0,) * _NUM_JOINTS,
            self_occluded_drop_probabilities=(0.0,) * _NUM_JOINTS, person_miss_probability=0.0,
            small_person_miss_probability=0.0, occluded_person_miss_probability=0.0,
            truncated_person_miss_probability=0.0, left_right_swap_probability=0.0,
            side_view_swap_probability=0.0, identity_swap_probability=0.0, paf_noise=0.0,
            paf_miss_probability=0.0, paf_clutter_probability=0.0, spurious_per_view=0.0,
        )


PERFECT_DETECTOR = DetectorConfig.perfect()
"""The noise-free detector: reports exactly the projected ground truth of every joint in the image."""


class Capsule(NamedTuple):
    name: str
    start: tuple[str, ...]
    """The axis starts at the mean of these joints."""
    end: tuple[str, ...]
    radius: float
    """Metres."""
    exempt: tuple[str, ...]
    """Joints of the same person this capsule never occludes (those it is attached to)."""


BODY25_CAPSULES: tuple[Capsule, ...] = (
    Capsule("head", ("l_ear", "r_ear"), ("l_ear", "r_ear"), 0.11, ()),
    Capsule("torso", ("neck",), ("mid_hip",), 0.10, ("neck", "mid_hip")),
    Capsule("r_flank", ("r_shoulder",), ("r_hip",), 0.09, ("r_shoulder", "r_hip", "neck", "mid_hip")),
    Capsule("l_flank", ("l_shoulder",), ("l_hip",), 0.09, ("l_shoulder", "l_hip", "neck", "mid_hip")),
    Capsule("r_upper_arm", ("r_shoulder",), ("r_elbow",), 0.05, ("r_shoulder", "r_elbow")),
    Capsule("l_upper_arm", ("l_shoulder",), ("l_elbow",), 0.05, ("l_shoulder", "l_elbow")),
    Capsule("r_forearm", ("r_elbow",), ("r_wrist",), 0.04, ("r_elbow", "r_wrist")),
    Capsule("l_forearm", ("l_elbow",), ("l_wrist",), 0.04, ("l_elbow", "l_wrist")),
    Capsule("r_thigh", ("r_hip",), ("r_knee",), 0.075, ("r_hip", "r_knee", "mid_hip")),
    Capsule("l_thigh", ("l_hip",), ("l_knee",), 0.075, ("l_hip", "l_knee", "mid_hip")),
    Capsule("r_shin", ("r_knee",), ("r_ankle",), 0.055, ("r_knee", "r_ankle", "r_heel")),
    Capsule("l_shin", ("l_knee",), ("l_ankle",), 0.055, ("l_knee", "l_ankle", "l_heel")),
    Capsule("r_foot", ("r_ankle",), ("r_big_toe",), 0.04, ("r_ankle", "r_big_toe", "r_small_toe", "r_heel")),
    Capsule("l_foot", ("l_ankle",), ("l_big_toe",), 0.04, ("l_ankle", "l_big_toe", "l_small_toe", "l_heel")),
)
"""The body as 3D capsules (axis between joint means, radius in metres) for the occlusion test."""


def _mean_weights(names: tuple[str, ...]) -> np.ndarray:
    w = np.zeros(_NUM_JOINTS)
    w[[_J(n) for n in names]] = 1.0 / len(names)
    return w


_CAPSULE_START = np.stack([_mean_weights(c.start) for c in BODY25_CAPSULES])  # (C, 25)
_CAPSULE_END = np.stack([_mean_weights(c.end) for c in BODY25_CAPSULES])
_CAPSULE_RADIUS = np.array([c.radius for c in BODY25_CAPSULES])
_SELF_EXEMPT = np.array([[name in c.exempt for c in BODY25_CAPSULES] for name in BODY25.joints])  # (25, C)

SWAP_GROUPS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("arms", ("shoulder", "elbow", "wrist")),
    ("legs", ("hip", "knee", "ankle", "big_toe", "small_toe", "heel")),
    ("face", ("eye", "ear")),
)
"""Left/right swap groups: the joints (without ``l_``/``r_``) whose labels are mirrored together."""


def _swap_source_table() -> np.ndarray:
    """(groups, 25) int: the joint whose position is reported under label j when group g is swapped."""
    table = np.tile(np.arange(_NUM_JOINTS), (len(SWAP_GROUPS), 1))
    for g, (_, parts) in enumerate(SWAP_GROUPS):
        for j, name in enumerate(BODY25.joints):
            if name[2:] in parts and name[:2] in ("l_", "r_"):
                table[g, j] = BODY25.mirror[j]
    return table


_SWAP_SOURCE = _swap_source_table()
_STATURE_CHAINS = (("nose", "neck"), ("neck", "mid_hip"))
_LEG_BONES = (("r_hip", "r_knee"), ("r_knee", "r_ankle"), ("l_hip", "l_knee"), ("l_knee", "l_ankle"))
_HEAD_AND_FEET_M = 0.25
"""Height (metres) above the nose plus below the ankles, added to the bone chain for the stature."""


class ViewGeometry(NamedTuple):
    """What a camera sees of each person, before any detector error (all frames, views, people)."""

    pixels: Float[np.ndarray, "frames views people 25 2"]
    """Projection of every joint (pixels; meaningless where ``in_front`` is False)."""
    depth: Float[np.ndarray, "frames views people 25"]
    """Camera depth of every joint (metres)."""
    in_front: Bool[np.ndarray, "frames views people 25"]
    """The joint is at least 0.1 m in front of the camera."""
    inside: Bool[np.ndarray, "frames views people 25"]
    """In front of the camera and projected inside the image ([0, W-1] x [0, H-1])."""
    occlusion: Float[np.ndarray, "frames views people 25"]
    """How much the joint is hidden by capsules nearer to the camera, in [0, 1]."""
    apparent_height: Float[np.ndarray, "frames views people"]
    """The person's stature seen at the depth of its mid-hip, in pixels (``fy * stature / depth``)."""
    sideness: Float[np.ndarray, "frames views people"]
    """``|cos|`` of the angle between the person's left-right axis and the viewing ray, in [0, 1]:
    0 seen from the front or back, 1 from the side."""

    self_occlusion: Float[np.ndarray, "frames views people 25"]
    """Occlusion by the person's own capsules, in [0, 1] (``occlusion`` is the larger of the two parts)."""
    others_occlusion: Float[np.ndarray, "frames views people 25"]
    """Occlusion by other people's capsules, in [0, 1]."""

    @property
    def visible(self) -> Bool[np.ndarray, "frames views people 25"]:
        """Inside the image and less than half occluded: what an ideal detector could see."""
        return self.inside & (self.occlusion < 0.5)


def _camera_frame_kernel(
    camera: Camera, people: Float[Array, "people 25 3"], depth_margin: Float[ArrayLike, ""], edge: Float[ArrayLike, ""]
) -> tuple[
    Float[Array, "people 25 2"], Float[Array, "people 25"], Float[Array, "people 25"], Float[Array, "people 25"],
    Float[Array, " people"], Float[Array, " people"],
]:
    """Pixels, depths (metres), occlusion by the person's own and by other people's capsules (each
    in [0, 1]), apparent height (pixels) and sideness of every person in one camera and one frame."""
    dtype = people.dtype
    pixels = geometry.project(camera, people)
    depth = geometry.depth(camera, people)
    fy = camera.K[1, 1]

    start = jnp.sum(jnp.asarray(_CAPSULE_START, dtype)[None, :, :, None] * people[:, None, :, :], axis=2)
    end = jnp.sum(jnp.asarray(_CAPSULE_END, dtype)[None, :, :, None] * people[:, None, :, :], axis=2)
    start_px, end_px = geometry.project(camera, start), geometry.project(camera, end)  # (P, C, 2)
    start_z, end_z = geometry.depth(camera, start), geometry.depth(camera, end)
    # Closest point of every projected capsule axis to every joint, axes (P, 25, P, C).
    axis = (end_px - start_px)[None, None]
    rel = pixels[:, :, None, None, :] - start_px[None, None]
    length2 = jnp.maximum(jnp.sum(axis * axis, axis=-1), 1e-9)
    along = jnp.clip(jnp.sum(rel * axis, axis=-1) / length2, 0.0, 1.0)
    offset = rel - along[..., None] * axis
    distance_px = jnp.sqrt(jnp.sum(offset * offset, axis=-1))
    capsule_z = start_z[None, None] + along * (end_z - start_z)[None, None]
    radius = jnp.asarray(_CAPSULE_RADIUS, dtype)[None, None, None, :]
    radius_px = fy * radius / jnp.maximum(capsule_z, 1e-3)
    coverage = jnp.clip((1.0 - distance_px / radius_px) / edge, 0.0, 1.0)
    # Depth test in units of the capsule radius: the capsule must be in front of the joint, and in
    # front of the camera.
    in_front_by = (depth[:, :, None, None] - capsule_z) / radius
    behind = jnp.clip((in_front_by - depth_margin) / 0.5, 0.0, 1.0) * (capsule_z > 0.1)
    n_people = people.shape[0]
    same_person = jnp.eye(n_people, dtype=bool)[:, None, :, None]
    allowed = jnp.logical_not(same_person & jnp.asarray(_SELF_EXEMPT)[None, :, None, :])
    covered = jnp.where(allowed, coverage * behind, 0.0)
    self_occlusion = jnp.max(jnp.where(same_person, covered, 0.0), axis=(2, 3))
    others_occlusion = jnp.max(jnp.where(same_person, 0.0, covered), axis=(2, 3))

    def bone(a: str, b: str) -> Float[Array, " people"]:
        d = people[:, _J(a)] - people[:, _J(b)]
        return jnp.sqrt(jnp.sum(d * d, axis=-1))

    stature = sum(bone(a, b) for a, b in _STATURE_CHAINS) + 0.5 * sum(bone(a, b) for a, b in _LEG_BONES)
    stature = stature + _HEAD_AND_FEET_M
    hip_depth = jnp.maximum(depth[:, _J("mid_hip")], 1e-3)
    apparent_height = fy * stature / hip_depth

    lateral = (people[:, _J("l_shoulder")] - people[:, _J("r_shoulder")]) + (people[:, _J("l_hip")] - people[:, _J("r_hip")])
    ray = people[:, _J("mid_hip")] - geometry.camera_centre(camera)[None, :]
    cosine = jnp.sum(lateral * ray, axis=-1) / jnp.maximum(
        jnp.sqrt(jnp.sum(lateral * lateral, axis=-1) * jnp.sum(ray * ray, axis=-1)), 1e-12
    )
    return pixels, depth, self_occlusion, others_occlusion, apparent_height, jnp.abs(cosine)


_FRAME_CHUNK = 32
_view_geometry_jit = jax.jit(
    jax.vmap(jax.vmap(_camera_frame_kernel, in_axes=(None, 0, None, None)), in_axes=(0, None, None, None))
)


def view_geometry(
    rig: Camera, joints: Float[ArrayLike, "frames people joints 3"], config: DetectorConfig = DetectorConfig()
) -> ViewGeometry:
    """Project every person into every view and compute occlusion, size and viewing angle.

    ``joints`` are BODY25 positions in metres, world z up. Occlusion uses :data:`BODY25_CAPSULES`
    and the config's ``occlusion_depth_margin`` and ``occlusion_edge``."""
    joints = np.asarray(joints, np.float64 if jax.config.jax_enable_x64 else np.float32)
    if joints.ndim != 4 or joints.shape[2:] != (_NUM_JOINTS, 3):
        raise ValueError(f"joints must have shape (frames, people, {_NUM_JOINTS}, 3), got {joints.shape}")
    if 0 in joints.shape[:2]:
        raise ValueError(f"joints must hold at least one frame and one person, got shape {joints.shape}")
    if not np.all(np.isfinite(joints)):
        raise ValueError("joints contain NaN or inf")
    if rig.K.ndim != 3:
        raise ValueError(f"rig must be a stacked rig (views, ...), got camera leaves of shape {rig.K.shape}")
    # Fixed-size chunks of frames (the last one padded by repeating its final frame) so the kernel
    # compiles once per rig size and number of people, whatever the number of frames.
    n_frames = joints.shape[0]
    chunks = []
    for first in range(0, n_frames, _FRAME_CHUNK):
        chunk = _pad(joints[first:first + _FRAME_CHUNK], _FRAME_CHUNK)
        out = _view_geometry_jit(rig, chunk, config.occlusion_depth_margin, config.occlusion_edge)
        chunks.append([np.asarray(a)[:, : n_frames - first] for a in out])
    pixels, depth, self_occlusion, others_occlusion, height, side = (np.concatenate(parts, axis=1).swapaxes(0, 1) for parts in zip(*chunks))
    size = np.asarray(rig.image_size)[None, :, None, None, :]
    in_front = depth > 0.1
    inside = in_front & np.all((pixels >= 0.0) & (pixels <= size - 1.0), axis=-1)
    occlusion = np.maximum(self_occlusion, others_occlusion)
    return ViewGeometry(pixels, depth, in_front, inside, occlusion, height, side, self_occlusion, others_occlusion)


class DetectorEvents(NamedTuple):
    """What the detector model did, for tests and error analysis (label-level, per person)."""

    geometry: ViewGeometry
    reported: Bool[np.ndarray, "frames views people 25"]
    """A candidate labelled joint j of this person was reported (after any left/right swap, so it
    may sit at the mirrored joint's position)."""
    missed: Bool[np.ndarray, "frames views people"]
    """The whole person was dropped from the view."""
    miss_probability: Float[np.ndarray, "frames views people"]
    left_right_swapped: Bool[np.ndarray, "frames views people groups"]
    """The labels of swap group g (:data:`SWAP_GROUPS`) were mirrored."""
    swap_probability: Float[np.ndarray, "frames views people groups"]
    identity_swapped: Bool[np.ndarray, "frames views people people pairs"]
    """``[f, v, p, q, k]``: the PAF of pair k links person p's joint a to person q's joint b (q != p)."""
    identity_swap_probability: Float[np.ndarray, "frames views people people pairs"]
    num_spurious: Float[np.ndarray, "frames views 25"]
    """Spurious candidates reported per joint type."""


def _numpy_rng(key: ArrayLike) -> np.random.Generator:
    """A NumPy generator that is a pure function of a JAX key (typed or raw uint32)."""
    key = jnp.asarray(key)
    data = jax.random.key_data(key) if jnp.issubdtype(key.dtype, jax.dtypes.prng_key) else key
    return np.random.default_rng(np.asarray(data).astype(np.uint64).ravel().tolist())


def _autoregressive(white: Float[np.ndarray, "frames ..."], correlation: float) -> Float[np.ndarray, "frames ..."]:
    """Unit-variance white noise made a stationary AR(1) sequence over axis 0 with lag-1 ``correlation``
    (returned unchanged for 0)."""
    if correlation == 0.0:
        return white
    out = np.empty_like(white)
    out[0] = white[0]
    innovation = np.sqrt(1.0 - correlation**2)
    for frame in range(1, len(white)):
        out[frame] = correlation * out[frame - 1] + innovation * white[frame]
    return out


def _ramp(x: np.ndarray) -> np.ndarray:
    return np.clip(x, 0.0, 1.0)


def detect(
    key: ArrayLike, rig: Camera, joints: Float[ArrayLike, "frames people joints 3"], config: DetectorConfig = DetectorConfig()
) -> list[list[Detections]]:
    """Simulated OpenPose BODY25 detections ``[frame][view]`` of people with 3D BODY25 ``joints``.

    ``joints`` are in metres (world z up), ``rig`` a stacked :class:`~geometry.Camera`. Each
    :class:`~mocap.Detections` carries ``person_ids`` (index into the people axis, -1 for a spurious
    candidate); candidates of a joint type are in raster order (by row, then column) as OpenPose's
    peak search returns them. See :func:`detect_with_events` for what happened."""
    return detect_with_events(key, rig, joints, config)[0]


def detect_with_events(
    key: ArrayLike, rig: Camera, joints: Float[ArrayLike, "frames people joints 3"], config: DetectorConfig = DetectorConfig()
) -> tuple[list[list[Detections]], DetectorEvents]:
    """:func:`detect` plus the :class:`DetectorEvents` (swaps, misses, visibility) behind the output."""
    geo = view_geometry(rig, joints, config)
    rng = _numpy_rng(key)  # every step below draws from it in turn: the output is a pure function of the key
    height = geo.apparent_height
    image_size = np.asarray(rig.image_size, np.float64)[None, :, None, None, :]  # (1, V, 1, 1, 2)
    # 0 at small_height and below, 1 from reference_height on: small people are missed more, with lower scores.
    size = _ramp((height - config.small_height) / (config.reference_height - config.small_height))
    labelled, swapped, swap_probability = _swap_left_right(rng, geo, config)
    missed, miss_probability = _miss_people(rng, geo, size, config)
    noisy, in_image = _noisy_positions(rng, labelled, height, image_size, config)
    score, reported = _confidences(rng, labelled, noisy, in_image, missed, height, size, image_size, config)
    true_paf = _true_pafs(rng, labelled.occlusion, config)
    identity_swapped, identity_swap_probability = _identity_swaps(rng, noisy, reported, height, config)
    spurious_xy, spurious_score, spurious_ok = _spurious_candidates(rng, geo, image_size, config)
    paf = _paf_matrices(rng, true_paf, identity_swapped, config)

    # Candidate slots (F, V, 25, slots) of each joint type: people first, then spurious.
    slot_xy = np.concatenate([noisy.transpose(0, 1, 3, 2, 4), spurious_xy], axis=3)
    slot_score = np.concatenate([score.transpose(0, 1, 3, 2), spurious_score], axis=3)
    slot_valid = np.concatenate([reported.transpose(0, 1, 3, 2), spurious_ok], axis=3)
    slot_person = np.concatenate([np.arange(height.shape[2]), np.full(config.max_spurious_per_joint, -1)])
    frames = _reported_candidates(image_size, slot_xy, slot_score, slot_valid, slot_person, paf)
    events = DetectorEvents(
        geo, reported, missed, miss_probability, swapped, swap_probability, identity_swapped,
        identity_swap_probability, (spurious_ok.sum(-1)).astype(np.float64),
    )
    return frames, events


class _Labelled(NamedTuple):
    """The geometry behind each reported label: label j of a person shows joint j, or the mirrored joint when
    its swap group was swapped."""

    pixels: Float[np.ndarray, "frames views people 25 2"]
    occlusion: Float[np.ndarray, "frames views people 25"]
    self_occlusion: Float[np.ndarray, "frames views people 25"]
    others_occlusion: Float[np.ndarray, "frames views people 25"]
    in_front: Bool[np.ndarray, "frames views people 25"]


def _swap_left_right(
    rng: np.random.Generator, geo: ViewGeometry, config: DetectorConfig
) -> tuple[_Labelled, Bool[np.ndarray, "frames views people groups"], Float[np.ndarray, "frames views people groups"]]:
    """Left/right swaps of each :data:`SWAP_GROUPS` group (more likely seen from the side): the labelled geometry,
    which groups were swapped and their probability."""
    n_f, n_v, n_p = geo.apparent_height.shape
    n_g = len(SWAP_GROUPS)
    swap_probability = np.broadcast_to(
        _ramp(config.left_right_swap_probability + config.side_view_swap_probability * geo.sideness**2)[..., None],
        (n_f, n_v, n_p, n_g),
    ).copy()
    swapped = rng.random((n_f, n_v, n_p, n_g)) < swap_probability
    source = np.broadcast_to(np.arange(_NUM_JOINTS), (n_f, n_v, n_p, _NUM_JOINTS))
    for g in range(n_g):
        in_group = _SWAP_SOURCE[g] != np.arange(_NUM_JOINTS)
        source = np.where(swapped[..., g, None] & in_group, _SWAP_SOURCE[g], source)
    labelled = _Labelled(
        pixels=np.take_along_axis(geo.pixels, source[..., None], axis=3),
        occlusion=np.take_along_axis(geo.occlusion, source, axis=3),
        self_occlusion=np.take_along_axis(geo.self_occlusion, source, axis=3),
        others_occlusion=np.take_along_axis(geo.others_occlusion, source, axis=3),
        in_front=np.take_along_axis(geo.in_front, source, axis=3),
    )
    return labelled, swapped, swap_probability


def _miss_people(
    rng: np.random.Generator, geo: ViewGeometry, size: Float[np.ndarray, "frames views people"], config: DetectorConfig
) -> tuple[Bool[np.ndarray, "frames views people"], Float[np.ndarray, "frames views people"]]:
    """Whole people missed from a view (more when small, occluded or truncated): which, and the probability.
    ``size`` is 0 at :attr:`~DetectorConfig.small_height` and below, 1 from the reference height on."""
    visible_count = np.maximum(geo.inside.sum(-1), 1)
    mean_occlusion = np.where(geo.inside, geo.occlusion, 0.0).sum(-1) / visible_count
    outside = 1.0 - geo.inside.mean(-1)
    miss_probability = _ramp(
        config.person_miss_probability
        + config.small_person_miss_probability * (1.0 - size)
        + config.occluded_person_miss_probability * _ramp(2.0 * mean_occlusion - 1.0)
        + config.truncated_person_miss_probability * outside
    )
    missed = rng.random(miss_probability.shape) < miss_probability
    return missed, miss_probability


def _noisy_positions(
    rng: np.random.Generator, labelled: _Labelled, height: Float[np.ndarray, "frames views people"],
    image_size: Float[np.ndarray, "1 views 1 1 2"], config: DetectorConfig,
) -> tuple[Float[np.ndarray, "frames views people 25 2"], Bool[np.ndarray, "frames views people 25"]]:
    """Reported positions: noise scaled by the apparent height (more when occluded) and rare outliers; and
    whether each lies in front of the camera and inside the image."""
    shape = labelled.occlusion.shape
    sigma = config.pixel_noise * height[..., None] * (1.0 + config.occluded_noise_gain * labelled.occlusion)
    noisy = labelled.pixels + _autoregressive(rng.standard_normal(shape + (2,)), config.noise_correlation) * sigma[..., None]
    outlier = rng.random(shape) < config.outlier_probability
    outlier_offset = rng.standard_normal(shape + (2,)) * (config.outlier_scale * height)[..., None, None]
    noisy = noisy + np.where(outlier[..., None], outlier_offset, 0.0)
    in_image = labelled.in_front & np.all((noisy >= 0.0) & (noisy <= image_size - 1.0), axis=-1)
    return noisy, in_image


def _confidences(
    rng: np.random.Generator, labelled: _Labelled, noisy: Float[np.ndarray, "frames views people 25 2"],
    in_image: Bool[np.ndarray, "frames views people 25"], missed: Bool[np.ndarray, "frames views people"],
    height: Float[np.ndarray, "frames views people"], size: Float[np.ndarray, "frames views people"],
    image_size: Float[np.ndarray, "1 views 1 1 2"], config: DetectorConfig,
) -> tuple[Float[np.ndarray, "frames views people 25"], Bool[np.ndarray, "frames views people 25"]]:
    """Confidences (joint type, size, image border, occlusion, noise) and which joints are reported: in the
    image, person not missed, not dropped (more when occluded) and above the score threshold."""
    shape = labelled.occlusion.shape
    border_distance = np.minimum(noisy, image_size - 1.0 - noisy).min(-1)
    border = _ramp(border_distance / np.maximum(config.border_margin * height[..., None], 1e-9))
    score = (
        np.asarray(config.base_scores)
        * (config.small_score_factor + (1.0 - config.small_score_factor) * size)[..., None]
        * (config.border_score_factor + (1.0 - config.border_score_factor) * border)
        * (1.0 - config.occlusion_score_drop * labelled.occlusion)
        + config.score_noise * rng.standard_normal(shape)
    )
    score = np.clip(score, 0.0, config.max_score)
    drop_probability = config.joint_dropout + np.maximum(
        np.asarray(config.occluded_drop_probabilities) * labelled.others_occlusion,
        np.asarray(config.self_occluded_drop_probabilities) * labelled.self_occlusion,
    )
    drop = rng.random(shape) < drop_probability
    reported = in_image & ~missed[..., None] & ~drop & (score >= config.score_threshold)
    return score, reported


def _true_pafs(
    rng: np.random.Generator, occlusion: Float[np.ndarray, "frames views people 25"], config: DetectorConfig
) -> Float[np.ndarray, "frames views people pairs"]:
    """The PAF score of each person's own pairs: lower when occluded, noisy, sometimes missing (0)."""
    pair_occlusion = np.maximum(occlusion[..., _PAIR_A], occlusion[..., _PAIR_B])
    true_paf = config.paf_mean * (1.0 - config.occlusion_paf_drop * pair_occlusion)
    true_paf = np.clip(true_paf + config.paf_noise * rng.standard_normal(true_paf.shape), 0.0, config.max_paf)
    return np.where(rng.random(true_paf.shape) < config.paf_miss_probability, 0.0, true_paf)


def _identity_swaps(
    rng: np.random.Generator, noisy: Float[np.ndarray, "frames views people 25 2"],
    reported: Bool[np.ndarray, "frames views people 25"], height: Float[np.ndarray, "frames views people"],
    config: DetectorConfig,
) -> tuple[Bool[np.ndarray, "frames views people people pairs"], Float[np.ndarray, "frames views people people pairs"]]:
    """``[f, v, p, q, k]``: whether the PAF of pair k links person p's joint a to person q's joint b, likely when
    q's joint b lies close to p's joint b in the image; and its probability."""
    gap = noisy[:, :, :, None, _PAIR_B, :] - noisy[:, :, None, :, _PAIR_B, :]  # (F, V, P, Q, K, 2)
    gap = np.sqrt(np.sum(gap * gap, axis=-1)) / np.maximum(config.identity_swap_radius * height, 1e-9)[..., None, None]
    both = reported[:, :, :, None, _PAIR_A] & reported[:, :, None, :, _PAIR_B]
    n_p = noisy.shape[2]
    identity_swap_probability = np.where(
        both & ~np.eye(n_p, dtype=bool)[:, :, None], config.identity_swap_probability * np.exp(-0.5 * gap**2), 0.0
    )
    identity_swapped = rng.random(identity_swap_probability.shape) < identity_swap_probability
    return identity_swapped, identity_swap_probability


def _spurious_candidates(
    rng: np.random.Generator, geo: ViewGeometry, image_size: Float[np.ndarray, "1 views 1 1 2"],
    config: DetectorConfig,
) -> tuple[
    Float[np.ndarray, "frames views 25 spurious 2"], Float[np.ndarray, "frames views 25 spurious"],
    Bool[np.ndarray, "frames views 25 spurious"],
]:
    """Up to :attr:`~DetectorConfig.max_spurious_per_joint` false candidates per joint type, view and frame, near
    a random person's joint or uniform in the image: positions, scores, and which are reported."""
    n_f, n_v, n_p = geo.apparent_height.shape
    n_s = config.max_spurious_per_joint
    n_spurious = np.minimum(rng.poisson(config.spurious_per_view / _NUM_JOINTS, (n_f, n_v, _NUM_JOINTS)), n_s)
    host = rng.integers(0, max(n_p, 1), (n_f, n_v, _NUM_JOINTS, n_s))
    host_joint = rng.integers(0, _NUM_JOINTS, (n_f, n_v, _NUM_JOINTS, n_s))
    near = rng.random((n_f, n_v, _NUM_JOINTS, n_s)) < config.spurious_near_person
    uniform_xy = rng.random((n_f, n_v, _NUM_JOINTS, n_s, 2)) * (image_size[:, :, :, 0] - 1.0)[..., None, :]
    jitter = rng.standard_normal((n_f, n_v, _NUM_JOINTS, n_s, 2))
    low, high = config.spurious_score_range
    spurious_score = rng.uniform(low, high, (n_f, n_v, _NUM_JOINTS, n_s))
    if n_p:
        f_idx, v_idx = np.ogrid[:n_f, :n_v]
        f_idx, v_idx = f_idx[:, :, None, None], v_idx[:, :, None, None]
        host_xy = geo.pixels[f_idx, v_idx, host, host_joint]
        host_ok = geo.in_front[f_idx, v_idx, host, host_joint]
        near_xy = host_xy + 0.15 * geo.apparent_height[f_idx, v_idx, host][..., None] * jitter
        near = near & host_ok
    else:
        near_xy = uniform_xy
    spurious_xy = np.where(near[..., None], near_xy, uniform_xy)
    spurious_ok = (np.arange(n_s) < n_spurious[..., None]) & np.all(
        (spurious_xy >= 0.0) & (spurious_xy <= image_size[:, :, :, 0][..., None, :] - 1.0), axis=-1
    )
    return spurious_xy, spurious_score, spurious_ok


def _paf_matrices(
    rng: np.random.Generator, true_paf: Float[np.ndarray, "frames views people pairs"],
    identity_swapped: Bool[np.ndarray, "frames views people people pairs"], config: DetectorConfig,
) -> Float[np.ndarray, "frames views pairs slots slots"]:
    """Dense PAFs between candidate slots (people first, then spurious): ``[.., k, s, t]`` links slot s's joint a
    to slot t's joint b. A person's own pair gets its true PAF (weakened when identity-swapped), a swapped pair
    the true PAF across people, everything else rare clutter."""
    n_f, n_v, n_p, _ = true_paf.shape
    n_slots = n_p + config.max_spurious_per_joint
    clutter = rng.random((n_f, n_v, _NUM_PAIRS, n_slots, n_slots)) < config.paf_clutter_probability
    paf = np.where(clutter, rng.uniform(0.15, 0.8, clutter.shape), 0.0)
    people_paf = paf[..., :n_p, :n_p]
    diagonal = np.arange(n_p)
    weakened = true_paf * np.where(identity_swapped.any(axis=3), rng.uniform(0.0, 0.6, true_paf.shape), 1.0)
    cross = np.where(identity_swapped, true_paf[:, :, :, None, :], people_paf.transpose(0, 1, 3, 4, 2))
    people_paf = cross.transpose(0, 1, 4, 2, 3)
    people_paf[..., diagonal, diagonal] = weakened.transpose(0, 1, 3, 2)
    paf[..., :n_p, :n_p] = people_paf
    return paf


def _reported_candidates(
    image_size: Float[np.ndarray, "1 views 1 1 2"], slot_xy: Float[np.ndarray, "frames views 25 slots 2"],
    slot_score: Float[np.ndarray, "frames views 25 slots"], slot_valid: Bool[np.ndarray, "frames views 25 slots"],
    slot_person: Int[np.ndarray, " slots"], paf: Float[np.ndarray, "frames views pairs slots slots"],
) -> list[list[Detections]]:
    """The valid slots as :class:`~mocap.Detections` ``[frame][view]``, each joint type's candidates in raster
    order (as OpenPose's peak search returns them), the PAF matrices reordered to match."""
    n_f, n_v = slot_valid.shape[:2]
    width = image_size[0, :, 0, 0, 0][None, :, None, None]
    raster = np.where(slot_valid, np.round(slot_xy[..., 1]) * width + slot_xy[..., 0], np.inf)
    order = np.argsort(raster, axis=-1, kind="stable")
    counts = slot_valid.sum(-1)
    candidates = np.take_along_axis(
        np.concatenate([slot_xy, slot_score[..., None]], axis=-1), order[..., None], axis=3
    )
    person_ids = slot_person[order]
    paf = np.take_along_axis(paf, order[:, :, _PAIR_A, :, None], axis=3)
    paf = np.take_along_axis(paf, order[:, :, _PAIR_B, None, :], axis=4)

    frames = []
    for f in range(n_f):
        views = []
        for v in range(n_v):
            n = counts[f, v]
            views.append(Detections(
                joints=tuple(candidates[f, v, j, : n[j]].copy() for j in range(_NUM_JOINTS)),
                pafs=tuple(paf[f, v, k, : n[a], : n[b]].copy() for k, (a, b) in enumerate(BODY25_PAF_PAIRS)),
                person_ids=tuple(person_ids[f, v, j, : n[j]].copy() for j in range(_NUM_JOINTS)),
            ))
        frames.append(views)
    return frames

"""Retarget the shipped CMU clips (joint positions only) to the body model's 24 joints by position-based IK.

A :class:`~mocap.Clip` holds BODY25 and STRUCTRI17 joint POSITIONS (metres, z-up world) and no rotations.
:func:`retarget_clip` turns them into :data:`geometry.SMPL24` local rotations and a translation for
:func:`geometry.body_forward`, so the model's bones point where the clip's do:

1. **Targets.** A position for each SMPL24 joint that carries information: pelvis = mid of the hips; hips,
   knees, ankles, shoulders, elbows, wrists from BODY25; neck = H36M ``thorax``; spine1/2/3 along the
   polyline pelvis -> H36M ``spine`` -> thorax at the model's own rest arc-length fractions; collars on
   the neck -> shoulder segment at the model's rest fraction; head = mid of the ears; foot = mid of the
   big and small toes.
2. **Global rotations**, joint by joint in topological order, each by weighted Kabsch (orthogonal
   Procrustes, batched over people and frames) mapping the model's rest directions (from
   ``J_regressor @ v_shaped`` at the given betas) to the target directions:

   - the pelvis and spine3 from all their children (hips and spine1; neck and collars);
   - a joint with one child from its bone, matched exactly, plus twist references made perpendicular to
     it: the next bone of a limb (a bent knee or elbow fixes the
     thigh's or upper arm's twist; the foot fixes the shin's), the toes' left-right axis for the ankle,
     and a weak hint equal to the parent's axes, so a straight limb inherits its parent's twist
     instead of flipping;
   - the head from the ears (left-right), the nose (forward) and the H36M head top (up);
   - wrists, hands and feet ends, about which a clip says nothing, keep their parent's orientation
     (local identity).

3. **Local** rotations ``parent_global^T @ global``; the root's stays global (z-up world).
4. **Translation**: the model's hip centre follows the clip's, horizontally as is and vertically scaled
   by the ratio of the model's leg length to the clip's, then shifted so the model's lowest foot point
   over the clip touches z = 0 (the clip's own lowest foot point is its ground). The hip centre rather
   than the pelvis joint is matched because how far the pelvis joint sits above the hips differs
   between the model and the capture.

Rest frame of the model (SMPL's): y up, facing +z, the person's left at +x.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from jaxtyping import ArrayLike, Float

from geometry import BODY25, SMPL24, STRUCTRI17, BodyModel

from ._clips import Clip

__all__ = ["BodyMotion", "retarget_clip"]


class BodyMotion(NamedTuple):
    """Body-model motion of ``P`` people over ``T`` frames (NumPy, float64), z-up world."""

    name: str
    fps: float
    """Frames per second."""
    rotations: Float[np.ndarray, "P T 24 3 3"]
    """Local rotations in :data:`geometry.SMPL24` order; the root's (pelvis) is global in the z-up world."""
    betas: Float[np.ndarray, "P S"]
    """Shape coefficients per person."""
    translation: Float[np.ndarray, "P T 3"]
    """Metres, z-up world: ``body_forward``'s translation argument."""

    @property
    def num_people(self) -> int:
        return self.rotations.shape[0]

    @property
    def num_frames(self) -> int:
        return self.rotations.shape[1]


_LEFT = np.array([1.0, 0.0, 0.0])
_UP = np.array([0.0, 1.0, 0.0])
_FORWARD = np.array([0.0, 0.0, 1.0])
# Rest-frame directions a flexing hinge swings the next bone towards: knee flexion swings the shin
# backward; elbow flexion swings the forearm forward from SMPL's T-pose (palms down).
_KNEE_FLEXION = -_FORWARD
_ELBOW_FLEXION = _FORWARD

_WEIGHT_HINT = 0.1
"""Weight of each of the parent's axes as a twist reference, against 1 for a bone or a bent limb."""

_NO_INFORMATION = ("l_wrist", "r_wrist", "l_hand", "r_hand", "l_foot", "r_foot")
"""Joints whose rotation the clip's joints do not constrain: local identity."""

_FOOT_POINTS = ("l_big_toe", "l_small_toe", "l_heel", "r_big_toe", "r_small_toe", "r_heel")
"""The clip's lowest points of a foot (BODY25): its ground is the lowest of them over the clip."""
_FOOT_JOINTS = ("l_ankle", "r_ankle", "l_foot", "r_foot")
"""The model's joints nearest the soles."""


def _index(name: str) -> int:
    return SMPL24.index(name)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def _reject(v: np.ndarray, unit_axis: np.ndarray) -> np.ndarray:
    """The part of ``v`` perpendicular to ``unit_axis`` (both ``(..., 3)``)."""
    return v - np.sum(v * unit_axis, axis=-1, keepdims=True) * unit_axis


def _kabsch(rest: Float[np.ndarray, "*batch K 3"], target: Float[np.ndarray, "*batch K 3"],
            weights: Float[np.ndarray, "K"]) -> Float[np.ndarray, "*batch 3 3"]:
    """The rotations ``R`` minimising ``sum_k w_k |R rest_k - target_k|^2`` (weighted orthogonal Procrustes)."""
    covariance = np.einsum("k,...ki,...kj->...ij", weights, target, rest)
    u, _, vt = np.linalg.svd(covariance)
    # Flip the least significant axis where the best orthogonal map is a reflection.
    fix = np.ones(u.shape[:-1])
    fix[..., 2] = np.sign(np.linalg.det(u @ vt))
    return (u * fix[..., None, :]) @ vt


def _shaped_vertices(model: BodyModel, betas: Float[np.ndarray, "P S"]) -> Float[np.ndarray, "P V 3"]:
    """Rest vertices ``v_template + shapedirs . betas`` per person, metres, the model's y-up frame."""
    return np.asarray(model.v_template) + np.einsum("vcs,ps->pvc", np.asarray(model.shapedirs), betas)


def _rest_joints(model: BodyModel, betas: Float[np.ndarray, "P S"]) -> Float[np.ndarray, "P 24 3"]:
    """Rest joints ``J_regressor @ v_shaped`` per person, metres, the model's y-up frame."""
    return np.einsum("jv,pvc->pjc", np.asarray(model.J_regressor), _shaped_vertices(model, betas))


def _rest_sole_clearance(model: BodyModel, betas: Float[np.ndarray, "P S"], rest: Float[np.ndarray, "P 24 3"]
                         ) -> Float[np.ndarray, "P"]:
    """How far the rest mesh reaches below its lowest ankle or foot joint (metres): the sole's depth."""
    feet = [_index(name) for name in _FOOT_JOINTS]
    return rest[:, feet, 1].min(axis=1) - _shaped_vertices(model, betas)[..., 1].min(axis=1)


def _along_polyline(points: Float[np.ndarray, "P T N 3"], fraction: Float[np.ndarray, "P"]
                    ) -> Float[np.ndarray, "P T 3"]:
    """The point at ``fraction`` of the arc length along each polyline (0 = first point, 1 = last)."""
    segments = np.diff(points, axis=-2)
    lengths = np.linalg.norm(segments, axis=-1)
    start = np.cumsum(lengths, axis=-1) - lengths
    wanted = fraction[:, None, None] * lengths.sum(axis=-1, keepdims=True)
    covered = np.clip((wanted - start) / np.maximum(lengths, 1e-12), 0.0, 1.0)
    return points[..., 0, :] + np.einsum("ptn,ptnc->ptc", covered, segments)


def _target_positions(clip: Clip, rest: Float[np.ndarray, "P 24 3"]) -> dict[str, np.ndarray]:
    """Target position ``(P, T, 3)`` of each SMPL24 joint the clip informs (module docstring), metres."""
    body = {name: clip.body25[..., k, :] for k, name in enumerate(BODY25.joints)}
    h36m = {name: clip.structri17[..., k, :] for k, name in enumerate(STRUCTRI17.joints)}
    pelvis, neck = 0.5 * (body["l_hip"] + body["r_hip"]), h36m["thorax"]
    targets = {"mid_hip": pelvis, "neck": neck, "head": 0.5 * (body["l_ear"] + body["r_ear"])}
    for side in "lr":
        for joint in ("hip", "knee", "ankle", "shoulder", "elbow", "wrist"):
            targets[f"{side}_{joint}"] = body[f"{side}_{joint}"]
        targets[f"{side}_foot"] = 0.5 * (body[f"{side}_big_toe"] + body[f"{side}_small_toe"])
        # The collar sits where the model's rest collar projects onto its neck -> shoulder segment.
        rest_neck, rest_shoulder = rest[:, _index("neck")], rest[:, _index(f"{side}_shoulder")]
        span = rest_shoulder - rest_neck
        along = np.sum((rest[:, _index(f"{side}_collar")] - rest_neck) * span, -1) / np.sum(span * span, -1)
        targets[f"{side}_collar"] = neck + along[:, None, None] * (body[f"{side}_shoulder"] - neck)
    # Spine joints at the model's rest arc-length fractions from the hip centre up to the neck.
    rest_chain = np.stack([0.5 * (rest[:, _index("l_hip")] + rest[:, _index("r_hip")])]
                          + [rest[:, _index(name)] for name in ("spine1", "spine2", "spine3", "neck")], axis=1)
    rest_arc = np.concatenate([np.zeros((len(rest), 1)),
                               np.cumsum(np.linalg.norm(np.diff(rest_chain, axis=1), axis=-1), axis=1)], axis=1)
    spine_line = np.stack([pelvis, h36m["spine"], neck], axis=-2)
    for k, name in enumerate(("spine1", "spine2", "spine3"), start=1):
        targets[name] = _along_polyline(spine_line, rest_arc[:, k] / rest_arc[:, -1])
    return targets


def _twist_references(clip: Clip, targets: dict[str, np.ndarray], rest: Float[np.ndarray, "P 24 3"]
                      ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Joint -> (rest direction ``(P, 1, 3)``, target vector ``(P, T, 3)``) fixing the twist about its bone."""
    body = {name: clip.body25[..., k, :] for k, name in enumerate(BODY25.joints)}
    references = {}
    for side in "lr":
        ankle, foot = f"{side}_ankle", f"{side}_foot"
        rest_foot = rest[:, _index(foot)] - rest[:, _index(ankle)]
        toes_leftward = body[f"{side}_small_toe"] - body[f"{side}_big_toe"]  # small toe is lateral
        references[f"{side}_hip"] = (np.broadcast_to(_KNEE_FLEXION, rest_foot.shape),
                                     targets[ankle] - targets[f"{side}_knee"])
        references[f"{side}_knee"] = (rest_foot, targets[foot] - targets[ankle])
        references[ankle] = (np.broadcast_to(_LEFT, rest_foot.shape),
                             toes_leftward if side == "l" else -toes_leftward)
        references[f"{side}_shoulder"] = (np.broadcast_to(_ELBOW_FLEXION, rest_foot.shape),
                                          targets[f"{side}_wrist"] - targets[f"{side}_elbow"])
    return {joint: (rest_direction[:, None], target) for joint, (rest_direction, target) in references.items()}


def _head_rotation(clip: Clip) -> Float[np.ndarray, "P T 3 3"]:
    """The head's global rotation from the ears (rest left), the nose (rest forward) and the head top (rest up)."""
    body = {name: clip.body25[..., k, :] for k, name in enumerate(BODY25.joints)}
    ears = 0.5 * (body["l_ear"] + body["r_ear"])
    target = _unit(np.stack([body["l_ear"] - body["r_ear"], body["nose"] - ears,
                             clip.structri17[..., STRUCTRI17.index("head"), :] - ears], axis=-2))
    rest = np.broadcast_to(np.stack([_LEFT, _FORWARD, _UP]), target.shape)
    return _kabsch(rest, target, np.ones(3))


def _bone_rotation(rest_bone: np.ndarray, target_bone: np.ndarray, rest_references: np.ndarray,
                   target_references: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Global rotation of a one-child joint: its bone exactly, the twist about it from the references.

    Bones ``(P, 1 or T, 3)``, references ``(P, 1 or T, K, 3)`` with weights ``(K,)``. References are reduced
    to their parts perpendicular to the bone, so they only turn the joint about it; a reference nearly along
    the bone (a straight limb) thereby fades out."""
    rest_axis, target_axis = np.broadcast_arrays(_unit(rest_bone), _unit(target_bone))
    rest_references = _reject(_unit(rest_references), rest_axis[..., None, :])
    target_references = _reject(_unit(target_references), target_axis[..., None, :])
    rest_pairs, target_pairs = np.broadcast_arrays(np.concatenate([rest_axis[..., None, :], rest_references], -2),
                                                   np.concatenate([target_axis[..., None, :], target_references], -2))
    # Every reference is perpendicular to the bone in both frames, so the best fit maps the bone onto the bone
    # exactly and the references only choose the twist.
    return _kabsch(rest_pairs, target_pairs, np.concatenate([[1.0], weights]))


def _one_child_references(name: str, parent_rotation: np.ndarray, references: dict[str, tuple[np.ndarray, np.ndarray]]
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Twist references of a one-child joint: rest ``(P, 1, K, 3)``, target ``(P, T, K, 3)``, weights ``(K,)``.

    Always the parent's axes (weakly: inherit its twist), plus the joint's own reference if it has one."""
    num_people = parent_rotation.shape[0]
    rest = np.broadcast_to(np.eye(3), (num_people, 1, 3, 3))
    target = np.swapaxes(parent_rotation, -1, -2)  # row i = the parent's axis i in the world
    weights = np.full(3, _WEIGHT_HINT)
    if name in references:
        rest_direction, target_vector = references[name]
        rest = np.concatenate([rest, rest_direction[..., None, :]], axis=-2)
        target = np.concatenate([target, target_vector[..., None, :]], axis=-2)
        weights = np.append(weights, 1.0)
    return rest, target, weights


def _global_rotations(clip: Clip, rest: Float[np.ndarray, "P 24 3"]) -> Float[np.ndarray, "P T 24 3 3"]:
    """Every SMPL24 joint's global rotation (rest model frame -> z-up world), in topological order."""
    targets = _target_positions(clip, rest)
    references = _twist_references(clip, targets, rest)
    num_people, num_frames = clip.body25.shape[:2]
    rotations = np.zeros((num_people, num_frames, SMPL24.num_joints, 3, 3))
    for joint in SMPL24.topological_order:
        name, parent = SMPL24.joints[joint], SMPL24.parents[joint]
        children = [c for c, p in enumerate(SMPL24.parents) if p == joint]
        if name in _NO_INFORMATION:
            rotations[:, :, joint] = rotations[:, :, parent]
        elif name == "head":
            rotations[:, :, joint] = _head_rotation(clip)
        elif len(children) == 1:
            child = children[0]
            rotations[:, :, joint] = _bone_rotation(
                (rest[:, child] - rest[:, joint])[:, None], targets[SMPL24.joints[child]] - targets[name],
                *_one_child_references(name, rotations[:, :, parent], references))
        else:
            rest_pairs = np.stack([rest[:, c] - rest[:, joint] for c in children], axis=-2)[:, None]
            target_pairs = np.stack([targets[SMPL24.joints[c]] - targets[name] for c in children], axis=-2)
            rest_pairs, target_pairs = np.broadcast_arrays(_unit(rest_pairs), _unit(target_pairs))
            rotations[:, :, joint] = _kabsch(rest_pairs, target_pairs, np.ones(len(children)))
    return rotations


def _local_rotations(global_rotations: Float[np.ndarray, "P T 24 3 3"]) -> Float[np.ndarray, "P T 24 3 3"]:
    """``parent_global^T @ global`` per joint; the root keeps its global rotation."""
    parents = np.array(SMPL24.parents)
    parent_rotations = global_rotations[:, :, np.maximum(parents, 0)]
    local = np.swapaxes(parent_rotations, -1, -2) @ global_rotations
    local[:, :, SMPL24.root] = global_rotations[:, :, SMPL24.root]
    return local


def _posed_joints(global_rotations: Float[np.ndarray, "P T 24 3 3"], rest: Float[np.ndarray, "P 24 3"]
                  ) -> Float[np.ndarray, "P T 24 3"]:
    """Joint positions of ``body_forward`` with zero translation (the root stays at its rest position)."""
    posed = np.zeros(global_rotations.shape[:-1])
    posed[:, :, SMPL24.root] = rest[:, None, SMPL24.root]
    for joint in SMPL24.topological_order[1:]:
        parent = SMPL24.parents[joint]
        offset = rest[:, joint] - rest[:, parent]
        posed[:, :, joint] = posed[:, :, parent] + np.einsum("ptij,pj->pti", global_rotations[:, :, parent], offset)
    return posed


def _leg_length(hips: np.ndarray, knees: np.ndarray, ankles: np.ndarray) -> np.ndarray:
    """Thigh plus shin length (metres), averaged over every axis but the first (people)."""
    length = np.linalg.norm(knees - hips, axis=-1) + np.linalg.norm(ankles - knees, axis=-1)
    return length.reshape(len(length), -1).mean(axis=1)


def _translation(clip: Clip, model: BodyModel, betas: np.ndarray, rest: np.ndarray,
                 global_rotations: np.ndarray) -> Float[np.ndarray, "P T 3"]:
    """``body_forward``'s translation: the model's hip centre follows the clip's, heights scaled and grounded.

    (Module docstring, step 4.)"""
    body = {name: clip.body25[..., k, :] for k, name in enumerate(BODY25.joints)}
    sides = ("l", "r")
    clip_legs = _leg_length(*(np.stack([body[f"{s}_{j}"] for s in sides], 2) for j in ("hip", "knee", "ankle")))
    model_legs = _leg_length(*(rest[:, [_index(f"{s}_{j}") for s in sides]] for j in ("hip", "knee", "ankle")))
    clip_ground = np.stack([body[name][..., 2] for name in _FOOT_POINTS], -1).min(axis=(1, 2))
    clip_hips = 0.5 * (body["l_hip"] + body["r_hip"])
    wanted_hips = clip_hips.copy()
    wanted_hips[..., 2] = (model_legs / clip_legs)[:, None] * (clip_hips[..., 2] - clip_ground[:, None])
    posed = _posed_joints(global_rotations, rest)
    translation = wanted_hips - 0.5 * (posed[:, :, _index("l_hip")] + posed[:, :, _index("r_hip")])
    feet = [_index(name) for name in _FOOT_JOINTS]
    lowest_foot = (posed[:, :, feet, 2] + translation[..., None, 2]).min(axis=(1, 2))
    ground_shift = _rest_sole_clearance(model, betas, rest) - lowest_foot
    return translation + ground_shift[:, None, None] * np.array([0.0, 0.0, 1.0])


def _checked_betas(betas: ArrayLike | None, num_people: int, num_shapes: int) -> Float[np.ndarray, "P S"]:
    if betas is None:
        return np.zeros((num_people, num_shapes))
    betas = np.asarray(betas, dtype=np.float64)
    if betas.shape == (num_shapes,):
        betas = np.broadcast_to(betas, (num_people, num_shapes)).copy()
    if betas.shape != (num_people, num_shapes):
        raise ValueError(f"betas must have shape ({num_shapes},) or ({num_people}, {num_shapes}) for the model's "
                         f"{num_shapes} shape directions and the clip's {num_people} people, got {betas.shape}")
    if not np.all(np.isfinite(betas)):
        raise ValueError("betas contain NaN or inf")
    return betas


def _check_clip(clip: Clip) -> None:
    body25, structri17 = np.asarray(clip.body25), np.asarray(clip.structri17)
    if body25.ndim != 4 or body25.shape[2:] != (25, 3) or structri17.ndim != 4 or structri17.shape[2:] != (17, 3):
        raise ValueError(f"clip {clip.name!r}: need body25 (P, T, 25, 3) and structri17 (P, T, 17, 3), got "
                         f"{body25.shape} and {structri17.shape}")
    if body25.shape[:2] != structri17.shape[:2] or 0 in body25.shape[:2]:
        raise ValueError(f"clip {clip.name!r}: body25 and structri17 need the same non-zero people and frame counts, "
                         f"got {body25.shape[:2]} and {structri17.shape[:2]}")
    for field, joints in (("body25", body25), ("structri17", structri17)):
        if not np.all(np.isfinite(joints)):
            raise ValueError(f"clip {clip.name!r}: {field} contains NaN or inf")
    if not clip.fps > 0:
        raise ValueError(f"clip {clip.name!r}: frame rate must be positive, got {clip.fps}")


def retarget_clip(clip: Clip, model: BodyModel, betas: ArrayLike | None = None) -> BodyMotion:
    """Rotations and translations that make ``model`` follow ``clip`` (module docstring).

    Args:
        clip: ``P`` people over ``T`` frames of BODY25 and STRUCTRI17 joint positions (metres, z-up world).
        model: a body model on :data:`geometry.SMPL24`.
        betas: shape coefficients ``(S,)`` for everyone or ``(P, S)`` per person; ``None``: zeros.

    Returns:
        a :class:`BodyMotion` with ``body_forward(model, rotations[p, t], betas[p], translation[p, t])`` the
        posed person ``p`` at frame ``t`` in the clip's z-up world.
    """
    if model.skeleton != SMPL24:
        raise ValueError(f"retargeting needs a body model on SMPL24, got {model.skeleton.name}")
    _check_clip(clip)
    clip = clip._replace(body25=np.asarray(clip.body25, np.float64), structri17=np.asarray(clip.structri17, np.float64))
    betas = _checked_betas(betas, clip.body25.shape[0], model.num_shapes)
    rest = _rest_joints(model, betas)
    global_rotations = _global_rotations(clip, rest)
    translation = _translation(clip, model, betas, rest, global_rotations)
    return BodyMotion(clip.name, float(clip.fps), _local_rotations(global_rotations), betas, translation)

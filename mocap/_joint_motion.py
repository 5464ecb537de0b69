"""A skeletal motion (joint rotations, fixed bone lengths) fitted to a person's 3D joint positions, for BVH export.

:func:`motion_from_joints` turns the joints of one tracked person, ``(frames, J, 3)`` in metres in the z-up world
of any :class:`geometry.Skeleton`, into a :class:`~mocap.Motion` that :func:`mocap.write_bvh` writes:

- **Bone lengths** are fixed: each bone's median length over the frames where both its joints are valid
  (0 for a bone never seen: its joint sits on its parent).
- **Rest pose**: the bones' directions in the reference frame (the first frame with the most valid bones), so
  the BVH's rest pose is the person as seen there; the root's rotation is the identity in that frame.
- **Rotations** match every bone's direction exactly. A joint with several children (the pelvis, the neck) gets
  the least-squares rotation (Kabsch) of its child bones, and one extra node per child, ``<joint>_to_<child>``,
  with a zero offset and the rotation that turns that child's bone onto its direction: one rotation per joint
  cannot turn several rigid child offsets onto directions whose angles change from frame to frame (a shrug). A
  joint with one child turns by the smallest rotation that takes its bone onto the target direction, so twist
  is inherited from the parent, never invented.
- **Missing joints**: a bone invalid in a frame takes its direction from the nearest frame where it is valid;
  a bone never valid keeps its parent's orientation (a local identity).

So the motion's forward kinematics reproduce every valid bone direction, and the joints within the difference
between each bone's length in that frame and its fixed length, summed along the path from the root
(:func:`motion_from_joints` documents the exact statement; the BVH round trip is tested against it).
"""

from __future__ import annotations

import jax
import numpy as np
from jaxtyping import ArrayLike, Bool, Float

import geometry

from ._motion import Motion, _pad, _padded_frames, build_motion

__all__ = ["motion_from_joints"]

_rotation_between = jax.jit(geometry.rotation_between)
"""Compiled once per padded frame count (``_padded_frames``): people tracked for different spans share it."""


def _unit(v: np.ndarray) -> np.ndarray:
    norm = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.where(norm > 0, v / np.where(norm > 0, norm, 1.0), 0.0)


def _nearest_valid(values: Float[np.ndarray, "T ..."], valid: Bool[np.ndarray, " T"]) -> Float[np.ndarray, "T ..."]:
    """``values`` with every invalid frame replaced by the nearest valid one (the earlier on ties)."""
    seen = np.flatnonzero(valid)
    if len(seen) == 0 or len(seen) == len(valid):
        return values
    frames = np.arange(len(valid))
    after = np.clip(np.searchsorted(seen, frames), 0, len(seen) - 1)
    before = np.clip(after - 1, 0, len(seen) - 1)
    nearer = np.where(np.abs(seen[before] - frames) <= np.abs(seen[after] - frames), seen[before], seen[after])
    return values[nearer]


def _kabsch(rest: Float[np.ndarray, "K 3"], target: Float[np.ndarray, "T K 3"],
            weight: Float[np.ndarray, "T K"]) -> Float[np.ndarray, "T 3 3"]:
    """Per frame the rotation R minimising sum_k weight_k |R rest_k - target_k|^2 (identity with no weight)."""
    covariance = np.einsum("tk,tki,kj->tij", weight, target, rest)
    u, _, vt = np.linalg.svd(covariance)
    reflection = np.tile(np.eye(3), (len(u), 1, 1))
    reflection[:, 2, 2] = np.where(np.linalg.det(u @ vt) < 0, -1.0, 1.0)  # a proper rotation, never a mirror
    rotation = u @ reflection @ vt
    return np.where((weight.sum(axis=1) > 0)[:, None, None], rotation, np.eye(3))


def motion_from_joints(
    joints: Float[ArrayLike, "T J 3"],
    skeleton: geometry.Skeleton,
    *,
    fps: float,
    valid: Bool[ArrayLike, "T J"] | None = None,
    name: str = "",
) -> Motion:
    """The skeletal motion whose bones follow ``joints`` (metres, z-up world) with fixed lengths (module docstring).

    Nodes: the skeleton's joints (same names) and, after them, one ``<joint>_to_<child>`` node per child of every
    joint with several children. ``valid`` (default: every finite joint) marks the joints to fit.

    Guarantee (tested through a BVH round trip): for every frame and valid joint whose path from the root is
    valid, the motion's node position equals the root plus the sum of the fixed-length bones along that path in
    their observed directions, so it is off the input by at most the sum, along the path, of each bone's
    length deviation from its fixed length in that frame.

    Raises:
        ValueError: wrong shapes, no frames, a root that is never valid, or a non-positive ``fps``.
    """
    joints = np.asarray(joints, dtype=np.float64)
    if joints.ndim != 3 or joints.shape[1:] != (skeleton.num_joints, 3) or len(joints) == 0:
        raise ValueError(f"{name or 'motion'}: joints must have shape (frames >= 1, {skeleton.num_joints}, 3) for "
                         f"{skeleton.name}, got {joints.shape}")
    valid = np.isfinite(joints).all(axis=-1) if valid is None else np.asarray(valid, bool) & np.isfinite(joints).all(-1)
    if valid.shape != joints.shape[:2]:
        raise ValueError(f"{name or 'motion'}: valid must have shape {joints.shape[:2]}, got {valid.shape}")
    root, parents = skeleton.root, skeleton.parents
    if not valid[:, root].any():
        raise ValueError(f"{name or 'motion'}: the root joint {skeleton.joints[root]!r} is never valid")
    joints = np.where(valid[..., None], joints, 0.0)
    children = {j: [c for c in range(skeleton.num_joints) if parents[c] == j] for j in range(skeleton.num_joints)}

    bones = [c for c in range(skeleton.num_joints) if c != root]  # bone c: parents[c] -> c
    bone_valid = {c: valid[:, c] & valid[:, parents[c]] for c in bones}
    vector = {c: joints[:, c] - joints[:, parents[c]] for c in bones}
    length = {c: float(np.median(np.linalg.norm(vector[c][bone_valid[c]], axis=-1))) if bone_valid[c].any() else 0.0
              for c in bones}
    direction = {c: _nearest_valid(_unit(vector[c]), bone_valid[c]) for c in bones}
    seen = {c: bool(bone_valid[c].any()) for c in bones}
    reference = int(np.argmax(np.stack([bone_valid[c] for c in bones], axis=1).sum(axis=1)))
    rest = {c: direction[c][reference] if seen[c] else np.zeros(3) for c in bones}

    # Node table: the skeleton's joints, then one zero-offset node per child of a branching joint.
    names, node_parent, offsets = list(skeleton.joints), [-1] * skeleton.num_joints, np.zeros((skeleton.num_joints, 3))
    bone_node = {}  # bone c -> the node whose rotation turns it (the node c's offset hangs from)
    for c in bones:
        p = parents[c]
        if len(children[p]) > 1:
            names.append(f"{skeleton.joints[p]}_to_{skeleton.joints[c]}")
            node_parent.append(p)
            offsets = np.concatenate([offsets, np.zeros((1, 3))])
            bone_node[c] = len(names) - 1
        else:
            bone_node[c] = p
        node_parent[c] = bone_node[c]
        offsets[c] = length[c] * rest[c]

    num_frames = len(joints)
    world = np.zeros((num_frames, len(names), 3, 3))

    def solve(node: int) -> None:
        parent = node_parent[node]
        parent_rotation = np.broadcast_to(np.eye(3), (num_frames, 3, 3)) if parent < 0 else world[:, parent]
        turned = [c for c in bones if bone_node[c] == node]
        if node < skeleton.num_joints and len(children[node]) > 1:  # a branching joint: best fit of its child bones
            branch = children[node]
            weight = np.array([length[c] for c in branch]) * np.ones((num_frames, 1))
            world[:, node] = _kabsch(np.stack([rest[c] for c in branch]),
                                     np.stack([direction[c] for c in branch], axis=1), weight)
        elif turned and seen[turned[0]]:
            size = _padded_frames(num_frames)
            now, target = _pad(parent_rotation @ rest[turned[0]], size), _pad(direction[turned[0]], size)
            world[:, node] = np.asarray(_rotation_between(now, target))[:num_frames] @ parent_rotation
        else:  # a leaf, or a bone never seen
            world[:, node] = parent_rotation
        for child, its_parent in enumerate(node_parent):
            if its_parent == node:
                solve(child)

    solve(root)
    local = world.copy()
    for node, parent in enumerate(node_parent):
        if parent >= 0:
            local[:, node] = np.swapaxes(world[:, parent], -1, -2) @ world[:, node]
    root_positions = _nearest_valid(joints[:, root], valid[:, root])
    return build_motion(tuple(names), tuple(node_parent), offsets, local, root_positions, fps, 1.0, y_up=False,
                        name=name)

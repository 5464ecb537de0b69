"""BVH export of one FLEX prediction: the symmetric skeleton and its rotations, seen from one view.

World frame: FLEX predicts no world, only each view's camera frame (OpenCV: x right, y down, z forward). The
file is written in the chosen view's camera frame turned half a turn about its x axis: x right, y up (image up),
z towards the viewer (OpenGL's camera frame), so a y-up importer (Blender, :func:`mocap.read_bvh`) shows the
person upright as the camera saw them. Both turn the file into their z-up world by :data:`mocap.Y_UP_TO_Z_UP`,
where a camera-frame point ``(x, y, z)`` lands at ``(x, z, -y)``: the camera sits at the origin looking along +y,
with image right along +x and image up along +z. A person standing upright and facing the camera has the
identity root rotation in the file (the BVH rest pose: y up, facing +z).
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike, Float

import geometry
import mocap
from geometry import FLEX20, FLEX20_REST_DIRECTIONS, FLEX20_ROTATING

from ._model import NUM_BONES, NUM_ROTATING, _rest_offsets, _unit_quaternion

__all__ = ["to_bvh"]

_WORLD_FROM_CAMERA = mocap.Y_UP_TO_Z_UP @ np.diag([1.0, -1.0, -1.0])
"""OpenCV camera frame -> the z-up world that :func:`mocap.write_bvh` takes: the half turn about x (to the y-up
file frame), then the reader's y-up -> z-up turn, which the writer undoes. ``(x, y, z) -> (x, z, -y)``."""


def to_bvh(
    path: str | Path,
    bone_lengths: Float[ArrayLike, "10"],
    rotations: Float[ArrayLike, "frames 14 4"],
    root_rotation: Float[ArrayLike, "frames 4"],
    root_position: Float[ArrayLike, "frames 3"],
    *,
    fps: float,
    rest_pose: Literal["totem", "tpose"] = "totem",
    metres_per_unit: float = 1.0,
) -> tuple[str, ...]:
    """Write one FLEX sequence, seen from one view, as a BVH file of :data:`geometry.FLEX20` (see the module
    docstring for the file's frame).

    Args:
        path: the file to write (replaced if it exists).
        bone_lengths: the symmetric skeleton, :data:`geometry.FLEX20_BONES` (metres, positive).
        rotations: (w, x, y, z) local quaternions of :data:`geometry.FLEX20_ROTATING`, normalised here as
            :func:`~flex.flex_forward_kinematics` does (zero -> identity).
        root_rotation: the view's root rotation, body frame -> camera (w, x, y, z), e.g. ``root_rotations[b, k]``.
        root_position: the root in the view's camera frame (metres), e.g. ``FlexOutputs.root_position[b, k]``,
            the normalised camera's (depth scaled by ``scale / f``, see :mod:`flex._model`); zeros for a
            root-relative motion.
        fps: frames per second of the sequence.
        rest_pose: the rest pose the model was trained with; it is the file's rest pose (offsets).
        metres_per_unit: the file's length unit (1.0: metres, Blender's default import scale; 0.01: centimetres).

    Returns:
        The name :func:`mocap.read_bvh` gives each FLEX20 joint (FLEX20 order): the joint's own name, except the
        end effectors (:data:`geometry.FLEX20_END_EFFECTORS`), which are end sites named ``<parent>_end``
        (``r_ankle`` -> ``r_knee_end``, ``head`` -> ``neck_nose_end``, ``l_wrist`` -> ``l_elbow_end``, ...).
        Read back, node ``names[j]`` is at the camera-frame position ``flex_forward_kinematics(...)[j] +
        root_position`` mapped by ``(x, y, z) -> (x, z, -y)``.

    Raises:
        ValueError: wrong shapes, non-finite values, non-positive bone lengths or ``fps``, or an unknown
            ``rest_pose``.
    """
    bone_lengths, rotations, root_rotation, root_position = (
        np.asarray(a, dtype=np.float64) for a in (bone_lengths, rotations, root_rotation, root_position))
    frames = rotations.shape[0] if rotations.ndim == 3 else "T"
    for name, array, shape in (("bone_lengths", bone_lengths, (NUM_BONES,)),
                               ("rotations", rotations, (frames, NUM_ROTATING, 4)),
                               ("root_rotation", root_rotation, (frames, 4)),
                               ("root_position", root_position, (frames, 3))):
        if array.shape != shape:
            raise ValueError(f"{name} must have shape ({', '.join(map(str, shape))}), got {array.shape}")
    if not all(np.isfinite(a).all() for a in (bone_lengths, rotations, root_rotation, root_position)):
        raise ValueError("non-finite bone lengths, rotations, root rotation or root position")
    if not (bone_lengths > 0).all():
        raise ValueError(f"bone lengths must be positive, got {bone_lengths}")
    if rest_pose not in FLEX20_REST_DIRECTIONS:
        raise ValueError(f"rest_pose must be one of {tuple(FLEX20_REST_DIRECTIONS)}, got {rest_pose!r}")

    def matrices(quaternions: np.ndarray) -> np.ndarray:
        unit = _unit_quaternion(jnp.asarray(quaternions))
        return np.asarray(geometry.quaternion_to_matrix(unit), dtype=np.float64)

    local = np.broadcast_to(np.eye(3), (rotations.shape[0], FLEX20.num_joints, 3, 3)).copy()  # end effectors: I
    local[:, np.asarray(FLEX20_ROTATING)] = matrices(rotations)
    local[:, FLEX20.root] = _WORLD_FROM_CAMERA @ matrices(root_rotation)
    offsets = np.asarray(_rest_offsets(jnp.asarray(bone_lengths), rest_pose), dtype=np.float64)
    return mocap.write_bvh(path, FLEX20.joints, FLEX20.parents, offsets, local, root_position @ _WORLD_FROM_CAMERA.T,
                           fps=fps, metres_per_unit=metres_per_unit)

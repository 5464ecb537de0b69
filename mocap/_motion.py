"""Skeletal motion: one structure for every source (CMU ASF/AMC, BVH, procedural), and its mapping
to the project's joint sets.

World frame
-----------
Every :class:`Motion` lives in the project's world: metres, **z up**, right-handed. The CMU sources
are y up, also right-handed, with the body's rest frame x = the person's left, y = up, z = forward.
They are turned into the world by the proper rotation :data:`Y_UP_TO_Z_UP` (+90 degrees about x,
determinant +1: ``(x, y, z) -> (x, -z, y)``), never by a reflection, so left stays left. A person in
the rest pose therefore faces world -y with their left along world +x.

Kinematic convention
--------------------
Node ``j`` is a point of the skeleton (a joint or an end site). ``offsets[j]`` is its rest offset
from its parent in the parent's frame, ``global_R[j] = global_R[parent] @ local_R[j]`` and
``pos[j] = pos[parent] + global_R[parent] @ offsets[j]`` (:func:`geometry.forward_kinematics`): a
node's rotation moves the bones that START at it, as in BVH. The rest pose (all local rotations the
identity, root included) is the source's rest pose in its own y-up body frame; the y-up -> z-up turn
is folded into the root's local rotation. End sites are named ``<parent>_end``.

Joint mappings (joint = position of the named node; ``mid(a, b)`` = midpoint; ``a + v`` = node
``a`` plus the rest-frame offset ``v`` in metres, (left, up, forward), carried by ``a``'s global rotation)
-----------------------------------------------------------------------------------------------------

Rigs: **cmu** = CMU ASF/AMC read by :func:`read_asf_amc` (nodes = bone starts, so node ``rfemur`` is
the end of bone ``rhipjoint``, i.e. CMU's "joint = end of the named bone") and the 18_01 BVH, whose
nodes carry the same ASF names (root ``hip`` instead of ``root``). **daz** = the Daz/Poser rig of the
60/61 salsa BVHs.

================  =======================================  ==========================================
target joint      cmu (ASF / 18_01 BVH)                    daz (60/61 salsa)
================  =======================================  ==========================================
mid_hip (H36M)    root (``hip`` in the BVH)                hip
mid_hip (BODY25)  mid(lfemur, rfemur)                      mid(lThigh, rThigh)
r_hip             rfemur (end of rhipjoint)                rThigh
r_knee            rtibia                                   rShin
r_ankle           rfoot                                    rFoot
spine             upperback (end of lowerback)             chest
thorax            lowerneck (end of thorax)                neck
neck (H36M)       upperneck (end of lowerneck)             head
head (H36M)       head_end (end of head bone)              head + (0, 0.19, 0.02)
r_shoulder        rhumerus (end of rclavicle)              rShldr
r_elbow           rradius                                  rForeArm
r_wrist           rwrist                                   rHand
neck (BODY25)     mid(lhumerus, rhumerus)                  mid(lShldr, rShldr)
nose              head_end + (0, -0.10, 0.10)              head + (0, 0.06, 0.11)
r_eye             head_end + (-0.032, -0.07, 0.08)         rightEye
r_ear             head_end + (-0.075, -0.09, 0.0)          head + (-0.075, 0.085, 0.0)
r_big_toe         rtoes_end + (0.015, 0, 0)                rFoot_end + (0.01, 0, 0.04)
r_small_toe       rtoes_end + (-0.045, 0, -0.03)           rFoot_end + (-0.035, 0, 0)
r_heel            rfoot + (0, -0.05, -0.05)                rFoot + (0, -0.05, -0.05)
================  =======================================  ==========================================

Left joints mirror the right ones (``l`` names, x offset negated). The face and foot offsets are
anthropometric guesses for an adult (eye 7 cm below the crown, ears 7.5 cm to the side, heel 5 cm
behind and below the ankle centre); they give the 2D detector model keypoints that move with the
head and feet, not anatomy to the centimetre. SHELF15/SHELF14 come from STRUCTRI17 through
``geometry.to_shelf15(structri17, STRUCTRI17)`` (head rule ``"h36m"``: ``head_bottom`` = H36M ``neck_nose``,
``head_top`` = H36M ``head``).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import numpy as np
from jaxtyping import Float

import geometry
from geometry import STRUCTRI17, Skeleton, to_shelf15

__all__ = [
    "Y_UP_TO_Z_UP",
    "Motion",
    "build_motion",
    "euler_matrices",
    "resample_motion",
    "motion_joint_positions",
]

Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
"""+90 degrees about x: maps y-up source coordinates to the z-up world (det +1)."""


def malformed(path: str | Path, line: int, message: str) -> ValueError:
    """The error every reader raises for a malformed file: ``"<file>:<line>: <message>"``."""
    return ValueError(f"{path}:{line}: {message}")


@dataclasses.dataclass(frozen=True, eq=False)
class Motion:
    """A skeletal motion of one person (NumPy). See the module docstring for the conventions."""

    joint_names: tuple[str, ...]
    parents: tuple[int, ...]
    offsets: Float[np.ndarray, "J 3"]
    """Rest offset of each node from its parent, in the parent's frame, metres (root: zeros)."""
    local_rotations: Float[np.ndarray, "T J 3 3"]
    root_positions: Float[np.ndarray, "T 3"]
    """Root node position, metres, z-up world."""
    fps: float
    positions: Float[np.ndarray, "T J 3"]
    """Node positions from forward kinematics, metres, z-up world."""
    global_rotations: Float[np.ndarray, "T J 3 3"]
    rig: str
    """Which mapping table applies: ``"cmu"``, ``"daz"``, ``"procedural"`` or ``"unknown"``."""
    name: str = ""

    @property
    def num_frames(self) -> int:
        return self.positions.shape[0]

    @property
    def duration(self) -> float:
        """Seconds from the first to the last frame."""
        return (self.num_frames - 1) / self.fps

    def node(self, name: str) -> int:
        try:
            return self.joint_names.index(name)
        except ValueError:
            raise KeyError(f"motion {self.name!r} has no node {name!r}") from None


def _rig_of(joint_names: tuple[str, ...]) -> str:
    names = set(joint_names)
    if {"lfemur", "rfemur", "lowerneck", "rhumerus"} <= names:
        return "cmu"
    if {"lThigh", "rThigh", "rShldr", "leftEye"} <= names:
        return "daz"
    if {"pelvis", "r_hip_joint", "head_top"} <= names:  # mocap._procedural
        return "procedural"
    return "unknown"


def _padded_frames(num_frames: int) -> int:
    """Frame counts are padded to powers of two (at least 1024) so jitted kernels compile once per bucket."""
    return max(1024, 1 << (num_frames - 1).bit_length())


def _pad(array: np.ndarray, size: int) -> np.ndarray:
    """``array`` (frames first) with its last frame repeated up to ``size`` frames: finite filler the callers drop."""
    return np.concatenate([array, np.broadcast_to(array[-1:], (size - len(array),) + array.shape[1:])])


_jit_forward_kinematics = jax.jit(geometry.forward_kinematics, static_argnums=3)
_jit_euler_to_matrix = jax.jit(geometry.euler_to_matrix, static_argnums=1)
_jit_matrix_to_euler = jax.jit(geometry.matrix_to_euler, static_argnums=1)


def euler_matrices(angles: Float[np.ndarray, "T K 3"], order: str) -> Float[np.ndarray, "T K 3 3"]:
    """:func:`geometry.euler_to_matrix` over frames (radians), jitted on padded frame counts."""
    num = angles.shape[0]
    padded = _pad(np.asarray(angles, dtype=np.float64), _padded_frames(num))
    return np.asarray(_jit_euler_to_matrix(padded, order), dtype=np.float64)[:num]


def euler_angles(matrices: Float[np.ndarray, "T K 3 3"], order: str) -> Float[np.ndarray, "T K 3"]:
    """:func:`geometry.matrix_to_euler` over frames (radians), jitted on padded frame counts."""
    num = matrices.shape[0]
    padded = _pad(np.asarray(matrices, dtype=np.float64), _padded_frames(num))
    return np.asarray(_jit_matrix_to_euler(padded, order), dtype=np.float64)[:num]


def _forward_kinematics(local_rotations, offsets, root_positions, parents):
    num = local_rotations.shape[0]
    size = _padded_frames(num)
    positions, global_rotations = _jit_forward_kinematics(
        _pad(local_rotations, size), np.asarray(offsets), _pad(root_positions, size), tuple(parents))
    return (np.asarray(positions, dtype=np.float64)[:num],
            np.asarray(global_rotations, dtype=np.float64)[:num])


def build_motion(
    joint_names: tuple[str, ...],
    parents: tuple[int, ...],
    offsets: Float[np.ndarray, "J 3"],
    local_rotations: Float[np.ndarray, "T J 3 3"],
    root_positions: Float[np.ndarray, "T 3"],
    fps: float,
    metres_per_unit: float,
    *,
    y_up: bool = True,
    name: str = "",
) -> Motion:
    """Make a :class:`Motion` from a source's own units and frame.

    ``offsets`` and ``root_positions`` are in source units (scaled by ``metres_per_unit``);
    ``local_rotations`` are the source's. With ``y_up`` the y-up -> z-up turn is applied to the root
    (its position and its local rotation), which keeps every other local rotation and offset.
    """
    root = parents.index(-1)
    if not fps > 0:
        raise ValueError(f"{name}: frame rate must be positive, got {fps}")
    if not (np.isfinite(metres_per_unit) and metres_per_unit > 0):  # a negative scale mirrors the motion
        raise ValueError(f"{name}: metres_per_unit must be a finite number > 0, got {metres_per_unit}")
    local = np.array(local_rotations, dtype=np.float64)
    root_positions = np.asarray(root_positions, dtype=np.float64) * metres_per_unit
    if y_up:
        local[:, root] = Y_UP_TO_Z_UP @ local[:, root]
        root_positions = root_positions @ Y_UP_TO_Z_UP.T
    offsets = np.asarray(offsets, dtype=np.float64) * metres_per_unit
    if not (np.isfinite(local).all() and np.isfinite(root_positions).all() and np.isfinite(offsets).all()):
        raise ValueError(f"{name}: non-finite rotations, offsets or root positions")
    positions, global_rotations = _forward_kinematics(local, offsets, root_positions, parents)
    return Motion(tuple(joint_names), tuple(parents), offsets, local, root_positions, float(fps),
                  positions, global_rotations, _rig_of(tuple(joint_names)), name)


@jax.jit
def _slerp_kernel(r0, r1, w):
    q = geometry.quaternion_slerp(geometry.matrix_to_quaternion(r0), geometry.matrix_to_quaternion(r1), w)
    return geometry.quaternion_to_matrix(q)


def _slerp_rotations(r0: np.ndarray, r1: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Spherical interpolation between rotation matrices (T, J, 3, 3) with weights ``w`` (T, J)."""
    num = r0.shape[0]
    size = _padded_frames(num)
    out = _slerp_kernel(_pad(r0, size), _pad(r1, size), _pad(w, size))
    return np.asarray(out, dtype=np.float64)[:num]


def resample_motion(motion: Motion, fps: float) -> Motion:
    """Resample to ``fps`` frames per second over the same time span (starting at frame 0).

    Rotations are slerped (through quaternions), root positions linearly interpolated, and positions
    recomputed by forward kinematics, so bone lengths stay exact. The last new frame is the last one
    at or before the original end time.
    """
    if not fps > 0:
        raise ValueError(f"target frame rate must be positive, got {fps}")
    num_new = int(np.floor(motion.duration * fps + 1e-9)) + 1
    source_index = np.arange(num_new) * (motion.fps / fps)
    lower = np.minimum(np.floor(source_index + 1e-9).astype(int), motion.num_frames - 1)
    upper = np.minimum(lower + 1, motion.num_frames - 1)
    w = np.clip(source_index - lower, 0.0, 1.0)
    if np.all(w < 1e-9):  # an integer ratio: pick frames exactly
        local = motion.local_rotations[lower]
    else:
        weights = np.repeat(w[:, None], len(motion.joint_names), axis=1)
        local = _slerp_rotations(motion.local_rotations[lower], motion.local_rotations[upper], weights)
    root = (1.0 - w)[:, None] * motion.root_positions[lower] + w[:, None] * motion.root_positions[upper]
    positions, global_rotations = _forward_kinematics(local, motion.offsets, root, motion.parents)
    return dataclasses.replace(motion, local_rotations=local, root_positions=root, fps=float(fps),
                               positions=positions, global_rotations=global_rotations)


# Mapping tables: target joint -> ("node", name) | ("mid", a, b) | ("offset", node, (left, up, forward) m)
def _sided(table_right: dict[str, tuple], left_name) -> dict[str, tuple]:
    """Add the left-side entries mirrored from the right-side ones (``r_`` targets)."""
    out = dict(table_right)
    for target, spec in table_right.items():
        if not target.startswith("r_"):
            continue
        if spec[0] == "node":
            mirrored = ("node", left_name(spec[1]))
        else:
            x, y, z = spec[2]
            mirrored = ("offset", left_name(spec[1]), (-x, y, z))
        out["l_" + target[2:]] = mirrored
    return out


def _cmu_table(root: str) -> dict[str, dict[str, tuple]]:
    limbs = {
        "r_hip": ("node", "rfemur"), "r_knee": ("node", "rtibia"), "r_ankle": ("node", "rfoot"),
        "r_shoulder": ("node", "rhumerus"), "r_elbow": ("node", "rradius"), "r_wrist": ("node", "rwrist"),
    }
    h36m = {**limbs, "mid_hip": ("node", root), "spine": ("node", "upperback"),
            "thorax": ("node", "lowerneck"), "neck_nose": ("node", "upperneck"), "head": ("node", "head_end")}
    body25 = {
        **limbs, "mid_hip": ("mid", "lfemur", "rfemur"), "neck": ("mid", "lhumerus", "rhumerus"),
        "nose": ("offset", "head_end", (0.0, -0.10, 0.10)),
        "r_eye": ("offset", "head_end", (-0.032, -0.07, 0.08)),
        "r_ear": ("offset", "head_end", (-0.075, -0.09, 0.0)),
        "r_big_toe": ("offset", "rtoes_end", (0.015, 0.0, 0.0)),
        "r_small_toe": ("offset", "rtoes_end", (-0.045, 0.0, -0.03)),
        "r_heel": ("offset", "rfoot", (0.0, -0.05, -0.05)),
    }
    left = lambda n: "l" + n[1:] if n[0] == "r" and n != "root" else n  # noqa: E731
    return {"STRUCTRI17": _sided(h36m, left), "BODY25": _sided(body25, left)}


def _daz_table() -> dict[str, dict[str, tuple]]:
    limbs = {
        "r_hip": ("node", "rThigh"), "r_knee": ("node", "rShin"), "r_ankle": ("node", "rFoot"),
        "r_shoulder": ("node", "rShldr"), "r_elbow": ("node", "rForeArm"), "r_wrist": ("node", "rHand"),
    }
    h36m = {**limbs, "mid_hip": ("node", "hip"), "spine": ("node", "chest"), "thorax": ("node", "neck"),
            "neck_nose": ("node", "head"), "head": ("offset", "head", (0.0, 0.19, 0.02))}
    body25 = {
        **limbs, "mid_hip": ("mid", "lThigh", "rThigh"), "neck": ("mid", "lShldr", "rShldr"),
        "nose": ("offset", "head", (0.0, 0.06, 0.11)),
        "r_eye": ("node", "rightEye"),
        "r_ear": ("offset", "head", (-0.075, 0.085, 0.0)),
        "r_big_toe": ("offset", "rFoot_end", (0.01, 0.0, 0.04)),
        "r_small_toe": ("offset", "rFoot_end", (-0.035, 0.0, 0.0)),
        "r_heel": ("offset", "rFoot", (0.0, -0.05, -0.05)),
    }
    left = lambda n: "leftEye" if n == "rightEye" else "l" + n[1:] if n[0] == "r" else n  # noqa: E731
    return {"STRUCTRI17": _sided(h36m, left), "BODY25": _sided(body25, left)}


def _procedural_table() -> dict[str, dict[str, tuple]]:
    """The rig of :func:`mocap.procedural_motion` (node names in ``mocap/_procedural.py``)."""
    limbs = {f"r_{j}": ("node", f"r_{j}_joint") for j in ("hip", "knee", "ankle", "shoulder", "elbow", "wrist")}
    h36m = {**limbs, "mid_hip": ("node", "pelvis"), "spine": ("node", "spine"), "thorax": ("node", "thorax"),
            "neck_nose": ("node", "neck"), "head": ("node", "head_top")}
    body25 = {
        **limbs, "mid_hip": ("mid", "l_hip_joint", "r_hip_joint"),
        "neck": ("mid", "l_shoulder_joint", "r_shoulder_joint"),
        "nose": ("offset", "head_top", (0.0, -0.10, 0.10)),
        "r_eye": ("offset", "head_top", (-0.032, -0.07, 0.08)),
        "r_ear": ("offset", "head_top", (-0.075, -0.09, 0.0)),
        "r_big_toe": ("offset", "r_toe", (0.015, 0.0, 0.0)),
        "r_small_toe": ("offset", "r_toe", (-0.045, 0.0, -0.03)),
        "r_heel": ("offset", "r_ankle_joint", (0.0, -0.05, -0.05)),
    }
    left = lambda n: "l" + n[1:] if n.startswith("r_") else n  # noqa: E731
    return {"STRUCTRI17": _sided(h36m, left), "BODY25": _sided(body25, left)}


def _mapping(motion: Motion, skeleton_name: str) -> dict[str, tuple]:
    if motion.rig == "cmu":
        tables = _cmu_table(motion.joint_names[motion.parents.index(-1)])
    elif motion.rig == "daz":
        tables = _daz_table()
    elif motion.rig == "procedural":
        tables = _procedural_table()
    else:
        raise ValueError(f"motion {motion.name!r}: no joint mapping for an unknown rig "
                         f"(nodes {motion.joint_names[:6]}...)")
    return tables[skeleton_name]


def motion_joint_positions(motion: Motion, skeleton: Skeleton) -> Float[np.ndarray, "T K 3"]:
    """Positions of ``skeleton``'s joints (STRUCTRI17, BODY25, SHELF15 or SHELF14), metres, z-up world.

    See the module docstring for the table of which source node feeds which joint.
    """
    if skeleton.name in ("SHELF15", "SHELF14"):
        shelf = np.asarray(to_shelf15(motion_joint_positions(motion, STRUCTRI17), STRUCTRI17))
        return shelf if skeleton.name == "SHELF15" else shelf[:, :14]
    if skeleton.name not in ("STRUCTRI17", "BODY25"):
        raise ValueError(f"no mapping to {skeleton.name}; use STRUCTRI17, BODY25, SHELF15 or SHELF14")
    table = _mapping(motion, skeleton.name)
    out = np.empty((motion.num_frames, skeleton.num_joints, 3))
    for k, joint in enumerate(skeleton.joints):
        spec = table[joint]
        if spec[0] == "node":
            out[:, k] = motion.positions[:, motion.node(spec[1])]
        elif spec[0] == "mid":
            out[:, k] = 0.5 * (motion.positions[:, motion.node(spec[1])] + motion.positions[:, motion.node(spec[2])])
        else:
            j = motion.node(spec[1])
            out[:, k] = motion.positions[:, j] + motion.global_rotations[:, j] @ np.asarray(spec[2])
    return out



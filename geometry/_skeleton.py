"""Skeleton formats as data: joint names, parents, mirror pairs and PCP parts.

Joint names follow one vocabulary across formats (``l_``/``r_`` prefixes for the person's left and
right), so mirror pairs are derived from the names rather than listed by hand. Parents describe a tree
rooted at the joint whose parent is -1; a parent may have a larger index than its child (STRUCTRI17 in the
Structural Triangulation order), so code must use :attr:`Skeleton.topological_order`, never index order.
"""

from __future__ import annotations

import dataclasses
from functools import cached_property


@dataclasses.dataclass(frozen=True)
class Skeleton:
    """A joint set. Static (hashable) metadata, safe to close over in jitted code."""

    name: str
    joints: tuple[str, ...]
    parents: tuple[int, ...]
    pcp_parts: tuple[tuple[str, str, str], ...] = ()
    """(part name, start joint name, end joint name) for the PCP metric."""

    def __post_init__(self) -> None:
        n = len(self.joints)
        if len(self.parents) != n:
            raise ValueError(f"{self.name}: {n} joints but {len(self.parents)} parents")
        if len(set(self.joints)) != n:
            raise ValueError(f"{self.name}: duplicate joint names")
        roots = [i for i, p in enumerate(self.parents) if p == -1]
        if len(roots) != 1:
            raise ValueError(f"{self.name}: a skeleton needs exactly one root, found {roots}")
        if any(not (-1 <= p < n) or p == i for i, p in enumerate(self.parents)):
            raise ValueError(f"{self.name}: parent index out of range or self-parent")
        self.topological_order  # raises on cycles
        for part, a, b in self.pcp_parts:
            if a not in self.joints or b not in self.joints:
                raise ValueError(f"{self.name}: PCP part {part!r} names unknown joints {a!r}, {b!r}")

    @property
    def num_joints(self) -> int:
        return len(self.joints)

    @property
    def root(self) -> int:
        return self.parents.index(-1)

    def index(self, joint: str) -> int:
        try:
            return self.joints.index(joint)
        except ValueError:
            raise KeyError(f"{self.name} has no joint {joint!r}; joints: {self.joints}") from None

    @cached_property
    def topological_order(self) -> tuple[int, ...]:
        """Joint indices such that every parent comes before its children (root first)."""
        children: dict[int, list[int]] = {i: [] for i in range(self.num_joints)}
        for i, p in enumerate(self.parents):
            if p >= 0:
                children[p].append(i)
        order, stack = [], [self.root]
        while stack:
            j = stack.pop()
            order.append(j)
            stack.extend(reversed(children[j]))
        if len(order) != self.num_joints:
            raise ValueError(f"{self.name}: parents do not form a tree (cycle or disconnected joints)")
        return tuple(order)

    @cached_property
    def bones(self) -> tuple[tuple[int, int], ...]:
        """(parent, child) pairs, one per non-root joint, in increasing child index.

        With the root at index 0 (STRUCTRI17, SMPL24, SKEL19), bone k ends at joint k + 1, the
        convention of Structural Triangulation's bone vector."""
        return tuple((p, c) for c, p in enumerate(self.parents) if p >= 0)

    @cached_property
    def mirror(self) -> tuple[int, ...]:
        """Index of the left/right counterpart of each joint (itself for central joints)."""
        out = []
        for name in self.joints:
            if name.startswith(("l_", "r_")):
                other = ("r_" if name[0] == "l" else "l_") + name[2:]
                out.append(self.index(other))
            else:
                out.append(self.joints.index(name))
        return tuple(out)

    @cached_property
    def mirror_bones(self) -> tuple[int, ...]:
        """Index in :attr:`bones` of the left/right counterpart of each bone (itself for central bones)."""
        bone_of_child = {child: k for k, (_, child) in enumerate(self.bones)}
        return tuple(bone_of_child[self.mirror[child]] for _, child in self.bones)

    @cached_property
    def left_right_pairs(self) -> tuple[tuple[int, int], ...]:
        return tuple((i, m) for i, m in enumerate(self.mirror) if self.joints[i].startswith("l_"))

    @cached_property
    def pcp_index(self) -> tuple[tuple[int, int], ...]:
        return tuple((self.index(a), self.index(b)) for _, a, b in self.pcp_parts)


def _tree(name: str, joints: tuple[str, ...], edges: dict[str, str | None], **kw) -> Skeleton:
    """Build a skeleton from a ``child -> parent`` name map (readable and order independent)."""
    if set(edges) != set(joints):
        raise ValueError(f"{name}: parent map does not cover exactly the joints")
    parents = tuple(-1 if edges[j] is None else joints.index(edges[j]) for j in joints)
    return Skeleton(name, joints, parents, **kw)


_LIMBS = {
    "l_upper_arm": ("l_shoulder", "l_elbow"),
    "r_upper_arm": ("r_shoulder", "r_elbow"),
    "l_lower_arm": ("l_elbow", "l_wrist"),
    "r_lower_arm": ("r_elbow", "r_wrist"),
    "l_upper_leg": ("l_hip", "l_knee"),
    "r_upper_leg": ("r_hip", "r_knee"),
    "l_lower_leg": ("l_knee", "l_ankle"),
    "r_lower_leg": ("r_knee", "r_ankle"),
}
_LIMB_PARTS = tuple((part, a, b) for part, (a, b) in _LIMBS.items())

_ARMS_LEGS = {
    "r_elbow": "r_shoulder", "r_wrist": "r_elbow", "l_elbow": "l_shoulder", "l_wrist": "l_elbow",
    "r_knee": "r_hip", "r_ankle": "r_knee", "l_knee": "l_hip", "l_ankle": "l_knee",
}

BODY25 = _tree(
    "BODY25",
    ("nose", "neck", "r_shoulder", "r_elbow", "r_wrist", "l_shoulder", "l_elbow", "l_wrist",
     "mid_hip", "r_hip", "r_knee", "r_ankle", "l_hip", "l_knee", "l_ankle", "r_eye", "l_eye",
     "r_ear", "l_ear", "l_big_toe", "l_small_toe", "l_heel", "r_big_toe", "r_small_toe", "r_heel"),
    {"mid_hip": None, "neck": "mid_hip", "nose": "neck", "r_shoulder": "neck", "l_shoulder": "neck",
     "r_hip": "mid_hip", "l_hip": "mid_hip", **_ARMS_LEGS, "r_eye": "nose", "l_eye": "nose",
     "r_ear": "r_eye", "l_ear": "l_eye", "l_big_toe": "l_ankle", "l_small_toe": "l_big_toe",
     "l_heel": "l_ankle", "r_big_toe": "r_ankle", "r_small_toe": "r_big_toe", "r_heel": "r_ankle"},
    pcp_parts=_LIMB_PARTS,
)
"""OpenPose BODY_25, the joint set of the real Shelf detections."""

COCO17 = _tree(
    "COCO17",
    ("nose", "l_eye", "r_eye", "l_ear", "r_ear", "l_shoulder", "r_shoulder", "l_elbow", "r_elbow",
     "l_wrist", "r_wrist", "l_hip", "r_hip", "l_knee", "r_knee", "l_ankle", "r_ankle"),
    {"nose": None, "l_eye": "nose", "r_eye": "nose", "l_ear": "l_eye", "r_ear": "r_eye",
     "l_shoulder": "nose", "r_shoulder": "nose", "l_hip": "l_shoulder", "r_hip": "r_shoulder",
     **_ARMS_LEGS},
    pcp_parts=_LIMB_PARTS,
)
"""MS-COCO keypoints. COCO has no pelvis; the tree is rooted at the nose for drawing and FK only."""

_SHELF_JOINTS = ("r_ankle", "r_knee", "r_hip", "l_hip", "l_knee", "l_ankle", "r_wrist", "r_elbow",
                 "r_shoulder", "l_shoulder", "l_elbow", "l_wrist", "head_bottom", "head_top")

SHELF14 = _tree(
    "SHELF14",
    _SHELF_JOINTS,
    {"head_bottom": None, "head_top": "head_bottom", "r_shoulder": "head_bottom",
     "l_shoulder": "head_bottom", "r_hip": "r_shoulder", "l_hip": "l_shoulder", **_ARMS_LEGS},
    pcp_parts=_LIMB_PARTS + (("head", "head_bottom", "head_top"),),
)
"""Shelf/Campus ground-truth joints (the dataset ReadMe's order, 0-based). Its torso PCP part needs
the mid-hip: convert to :data:`SHELF15` first."""

SHELF15 = _tree(
    "SHELF15",
    _SHELF_JOINTS + ("mid_hip",),
    {"mid_hip": None, "r_hip": "mid_hip", "l_hip": "mid_hip", "head_bottom": "mid_hip",
     "head_top": "head_bottom", "r_shoulder": "head_bottom", "l_shoulder": "head_bottom",
     **_ARMS_LEGS},
    pcp_parts=_LIMB_PARTS + (("head", "head_bottom", "head_top"), ("torso", "mid_hip", "head_bottom")),
)
"""Shelf14 plus joint 14 = mid-hip (4D-association, JCSAT); carries the ten standard PCP parts."""

SKEL19 = _tree(
    "SKEL19",
    ("mid_hip", "neck", "r_hip", "l_hip", "nose", "r_shoulder", "l_shoulder", "r_knee", "l_knee",
     "r_ear", "l_ear", "r_elbow", "l_elbow", "r_ankle", "l_ankle", "r_wrist", "l_wrist",
     "l_big_toe", "r_big_toe"),
    {"mid_hip": None, "neck": "mid_hip", "r_hip": "mid_hip", "l_hip": "mid_hip", "nose": "neck",
     "r_shoulder": "neck", "l_shoulder": "neck", **_ARMS_LEGS, "r_ear": "nose", "l_ear": "nose",
     "l_big_toe": "l_ankle", "r_big_toe": "r_ankle"},
    pcp_parts=_LIMB_PARTS,
)
"""4D-association's 19-joint skeleton (joint 0 is the pelvis)."""

STRUCTRI17 = _tree(
    "STRUCTRI17",
    ("mid_hip", "r_knee", "r_hip", "l_hip", "l_knee", "l_ankle", "r_ankle", "spine", "thorax",
     "head", "r_wrist", "r_elbow", "r_shoulder", "l_shoulder", "l_elbow", "l_wrist", "neck_nose"),
    {"mid_hip": None, "r_hip": "mid_hip", "l_hip": "mid_hip", "spine": "mid_hip",
     "thorax": "spine", "neck_nose": "thorax", "head": "neck_nose", "r_shoulder": "thorax",
     "l_shoulder": "thorax", **_ARMS_LEGS},
    pcp_parts=_LIMB_PARTS,
)
"""Human3.6M's 17 joints in Structural Triangulation's order (Chen et al., ECCV 2022),
NOT in Human3.6M's own order: root first, and bone k ends at joint k + 1 (parents
``[-1, 2, 0, 0, 3, 4, 1, 0, 7, 16, 11, 12, 8, 8, 13, 14, 8]``), so a parent may come after its child.
Human3.6M's own order is pelvis, r_hip, r_knee, r_foot, l_hip, l_knee, l_foot, spine, thorax, neck/nose, head,
l_shoulder, l_elbow, l_wrist, r_shoulder, r_elbow, r_wrist; only ``mid_hip`` (index 0), ``spine`` (7) and
``thorax`` (8) sit at the same indices, so arrays in Human3.6M's order must be reordered by joint name
before they are used with this skeleton. ``neck_nose`` is
H36M's "Neck/Nose" point (above OpenPose's neck, which is nearer H36M's ``thorax``), and
``l_ankle``/``r_ankle`` its "Foot" joints."""

SMPL24 = _tree(
    "SMPL24",
    ("mid_hip", "l_hip", "r_hip", "spine1", "l_knee", "r_knee", "spine2", "l_ankle", "r_ankle",
     "spine3", "l_foot", "r_foot", "neck", "l_collar", "r_collar", "head", "l_shoulder",
     "r_shoulder", "l_elbow", "r_elbow", "l_wrist", "r_wrist", "l_hand", "r_hand"),
    {"mid_hip": None, "l_hip": "mid_hip", "r_hip": "mid_hip", "spine1": "mid_hip",
     "l_knee": "l_hip", "r_knee": "r_hip", "spine2": "spine1", "l_ankle": "l_knee",
     "r_ankle": "r_knee", "spine3": "spine2", "l_foot": "l_ankle", "r_foot": "r_ankle",
     "neck": "spine3", "l_collar": "spine3", "r_collar": "spine3", "head": "neck",
     "l_shoulder": "l_collar", "r_shoulder": "r_collar", "l_elbow": "l_shoulder",
     "r_elbow": "r_shoulder", "l_wrist": "l_elbow", "r_wrist": "r_elbow", "l_hand": "l_wrist",
     "r_hand": "r_wrist"},
    pcp_parts=_LIMB_PARTS,
)
"""SMPL's 24-joint kinematic tree (joint 0 is the pelvis)."""

FLEX20 = _tree(
    "FLEX20",
    ("mid_hip", "r_hip", "r_knee", "r_ankle", "l_hip", "l_knee", "l_ankle", "spine_base", "spine", "thorax",
     "neck_nose", "head", "l_thorax", "l_shoulder", "l_elbow", "l_wrist", "r_thorax", "r_shoulder", "r_elbow",
     "r_wrist"),
    {"mid_hip": None, "r_hip": "mid_hip", "l_hip": "mid_hip", "spine_base": "mid_hip", "spine": "spine_base",
     "thorax": "spine", "neck_nose": "thorax", "head": "neck_nose", "l_thorax": "spine", "r_thorax": "spine",
     "l_shoulder": "l_thorax", "r_shoulder": "r_thorax", **_ARMS_LEGS},
    pcp_parts=_LIMB_PARTS,
)
"""FLEX's kinematic skeleton (Gordon et al., ECCV 2022, App. C; official parents
``[-1, 0, 1, 2, 0, 4, 5, 0, 7, 8, 9, 10, 8, 12, 13, 14, 8, 16, 17, 18]``): the 17 Human3.6M joints plus three
duplicates that let the bones next to the root and the neck turn independently. ``spine_base`` sits on
``mid_hip`` (zero offset) and carries the spine; ``l_thorax`` and ``r_thorax`` sit on ``thorax`` (children of
``spine`` with the thorax's offset) and carry the arms, so the shoulders move independently of the neck.
:data:`FLEX20_DUPLICATE_OF` names the joint each duplicate coincides with. The other joints have their
:data:`STRUCTRI17` names, so ``geometry.remap_joints(points, FLEX20, STRUCTRI17)`` drops the duplicates (the
17-joint MPJPE) and :func:`~geometry.flex20_from_structri17` adds them. ``mid_hip`` is the Human3.6M pelvis,
the centre of the hips in FLEX's rest pose (hips at +-x)."""

FLEX20_DUPLICATE_OF: dict[str, str] = {"spine_base": "mid_hip", "l_thorax": "thorax", "r_thorax": "thorax"}
"""FLEX20 duplicate joint -> the joint it coincides with in every pose."""

FLEX20_BONES: tuple[str, ...] = (
    "pelvis_hip", "thigh", "shin", "pelvis_spine", "spine_thorax", "thorax_neck", "neck_head",
    "thorax_shoulder", "upper_arm", "forearm",
)
"""FLEX's symmetric skeleton: the 10 bone lengths its E_S predicts (official order), each shared by the left
and right bone and by the duplicates' copies."""

FLEX20_BONE_OF_JOINT: tuple[int, ...] = (-1, 0, 1, 2, 0, 1, 2, -1, 3, 4, 5, 6, 4, 7, 8, 9, 4, 7, 8, 9)
"""For each FLEX20 joint, the index in :data:`FLEX20_BONES` of the length of its offset from its parent;
-1 for the root and ``spine_base`` (zero offset). Mirrored joints share a bone, so any 10 lengths give a
left/right-symmetric skeleton."""

FLEX20_END_EFFECTORS: tuple[int, ...] = (3, 6, 11, 15, 19)
"""Joints without children (ankles, head, wrists): their rotation moves nothing, so FLEX predicts none."""

FLEX20_ROTATING: tuple[int, ...] = tuple(
    j for j in range(1, FLEX20.num_joints) if j not in FLEX20_END_EFFECTORS)
"""The 14 non-root joints whose local rotations FLEX predicts (shared by all views), in index order."""

_LEFT, _UP = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)
_RIGHT, _DOWN, _ZERO = (-1.0, 0.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, 0.0)
FLEX20_REST_DIRECTIONS: dict[str, tuple[tuple[float, float, float], ...]] = {
    "totem": (_ZERO, _RIGHT, _DOWN, _DOWN, _LEFT, _DOWN, _DOWN, _ZERO, _UP, _UP, _UP, _UP,
              _UP, _UP, _UP, _UP, _UP, _UP, _UP, _UP),
    "tpose": (_ZERO, _RIGHT, _DOWN, _DOWN, _LEFT, _DOWN, _DOWN, _ZERO, _UP, _UP, _UP, _UP,
              _UP, _LEFT, _LEFT, _LEFT, _UP, _RIGHT, _RIGHT, _RIGHT),
}
"""Unit direction of each FLEX20 joint's rest offset from its parent, in the parent's frame, for the official
code's two rest poses; the offset is this direction times the joint's bone length. Body frame: x = the
person's left, y = up, z = forward (right-handed). ``"totem"`` (the released model's) points every upper-body
bone, arms included, up; ``"tpose"`` points the shoulders and arms sideways. Zero for the root and
``spine_base``."""

SKELETONS: dict[str, Skeleton] = {
    s.name: s for s in (BODY25, COCO17, SHELF14, SHELF15, SKEL19, STRUCTRI17, SMPL24, FLEX20)}

__all__ = [
    "Skeleton", "SKELETONS", "BODY25", "COCO17", "SHELF14", "SHELF15", "SKEL19", "STRUCTRI17", "SMPL24", "FLEX20",
    "FLEX20_DUPLICATE_OF", "FLEX20_BONES", "FLEX20_BONE_OF_JOINT", "FLEX20_END_EFFECTORS", "FLEX20_ROTATING",
    "FLEX20_REST_DIRECTIONS",
]

"""Forward kinematics and the joint <-> bone-vector maps of a skeleton tree.

Forward kinematics follows BVH: each joint's ``offset`` is its rest position relative to its parent,
expressed in the PARENT's frame, and its local rotation turns its own frame relative to the parent's:

    global_R[j] = global_R[parent(j)] @ local_R[j]
    pos[j]      = pos[parent(j)] + global_R[parent(j)] @ offset[j]

The root's position is given directly and its offset is ignored. Parents may have larger indices
than their children (STRUCTRI17), so joints are visited in :attr:`Skeleton.topological_order`.

Bone vectors follow :attr:`Skeleton.bones`: bone k is ``x_child - x_parent`` for the k-th
(parent, child) pair in increasing child index; with the root at index 0 bone k ends at joint k + 1
(Structural Triangulation's layout).
"""

from __future__ import annotations

import functools

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ._rotations import _as_float, _broadcast_batch, _matmul, _matvec
from ._skeleton import Skeleton
from ._vectors import safe_norm

__all__ = [
    "forward_kinematics",
    "bone_vectors",
    "bone_lengths",
    "joints_from_bones",
    "joints_to_bones_matrix",
    "bones_to_joints_matrix",
]


@functools.lru_cache(maxsize=None)
def _skeleton_from_parents(parents: tuple[int, ...]) -> Skeleton:
    return Skeleton(f"tree{len(parents)}", tuple(f"joint{i}" for i in range(len(parents))), parents)


def _as_skeleton(tree: Skeleton | tuple[int, ...]) -> Skeleton:
    """A bare parents tuple becomes an anonymous Skeleton, which validates it and orders it."""
    if isinstance(tree, Skeleton):
        return tree
    return _skeleton_from_parents(tuple(int(p) for p in tree))


def forward_kinematics(
    local_rotations: Float[ArrayLike, "*#batch joints 3 3"],
    offsets: Float[ArrayLike, "*#batch joints 3"],
    root_position: Float[ArrayLike, "*#batch 3"],
    parents: Skeleton | tuple[int, ...],
) -> tuple[Float[Array, "*#batch joints 3"], Float[Array, "*#batch joints 3 3"]]:
    """Joint positions and global rotations from local rotations and rest offsets (BVH convention).

    Args:
        local_rotations: each joint's rotation relative to its parent's frame (the root's is global).
        offsets: each joint's offset from its parent in the parent's frame (units of the output,
            e.g. metres); the root's entry is ignored. Typically unbatched ``(joints, 3)``.
        root_position: world position of the root joint.
        parents: a static parents tuple (-1 for the root) or a :class:`Skeleton`.

    The leading batch axes of the three arrays broadcast against each other.

    Returns:
        ``(positions (*batch, joints, 3), global_rotations (*batch, joints, 3, 3))``.
    """
    skeleton = _as_skeleton(parents)
    n = skeleton.num_joints
    local_rotations, offsets, root_position = map(_as_float, (local_rotations, offsets, root_position))
    for name, array, trailing in (("local_rotations", local_rotations, (n, 3, 3)),
                                  ("offsets", offsets, (n, 3)), ("root_position", root_position, (3,))):
        if array.ndim < len(trailing) or array.shape[array.ndim - len(trailing):] != trailing:
            raise ValueError(f"{name} must have shape (*batch, {', '.join(map(str, trailing))}) for "
                             f"{skeleton.name} ({n} joints), got {array.shape}")
    local_rotations, offsets, root_position = _broadcast_batch(
        (local_rotations, 3), (offsets, 2), (root_position, 1))
    rotations: list[Array | None] = [None] * n
    positions: list[Array | None] = [None] * n
    for j in skeleton.topological_order:
        p = skeleton.parents[j]
        if p < 0:
            rotations[j], positions[j] = local_rotations[..., j, :, :], root_position
        else:
            rotations[j] = _matmul(rotations[p], local_rotations[..., j, :, :])
            positions[j] = positions[p] + _matvec(rotations[p], offsets[..., j, :])
    return jnp.stack(positions, axis=-2), jnp.stack(rotations, axis=-3)


def _bone_endpoints(skeleton: Skeleton) -> tuple[np.ndarray, np.ndarray]:
    bones = np.asarray(skeleton.bones, dtype=np.int64).reshape(-1, 2)
    return bones[:, 0], bones[:, 1]


def bone_vectors(joints: Float[ArrayLike, "*batch joints 3"], skeleton: Skeleton) -> Float[Array, "*batch bones 3"]:
    """``x_child - x_parent`` for each bone in ``skeleton.bones`` order (units of ``joints``)."""
    joints = _as_float(joints)
    if joints.ndim < 2 or joints.shape[-2:] != (skeleton.num_joints, 3):
        raise ValueError(f"joints must have shape (*batch, {skeleton.num_joints}, 3) for {skeleton.name}, "
                         f"got {joints.shape}")
    parent, child = _bone_endpoints(skeleton)
    return joints[..., child, :] - joints[..., parent, :]


def bone_lengths(joints: Float[ArrayLike, "*batch joints 3"], skeleton: Skeleton) -> Float[Array, "*batch bones"]:
    """Length of each bone in ``skeleton.bones`` order (units of ``joints``; zero-length bones have zero gradient)."""
    return safe_norm(bone_vectors(joints, skeleton))


@functools.lru_cache(maxsize=None)
def _path_matrix(skeleton: Skeleton) -> np.ndarray:
    """(joints, bones) 0/1 matrix: entry (j, k) is 1 when bone k lies on the path from the root to joint j."""
    bone_of_child = {child: k for k, (_, child) in enumerate(skeleton.bones)}
    path = np.zeros((skeleton.num_joints, len(skeleton.bones)))
    for j in range(skeleton.num_joints):
        node = j
        while skeleton.parents[node] >= 0:
            path[j, bone_of_child[node]] = 1.0
            node = skeleton.parents[node]
    path.flags.writeable = False
    return path


def joints_from_bones(
    root: Float[ArrayLike, "*#batch 3"], bones: Float[ArrayLike, "*#batch bones 3"], skeleton: Skeleton
) -> Float[Array, "*#batch joints 3"]:
    """Inverse of :func:`bone_vectors`: each joint is the root plus the bones on its path from the root."""
    root, bones = _as_float(root), _as_float(bones)
    n_bones = len(skeleton.bones)
    if root.ndim < 1 or root.shape[-1] != 3:
        raise ValueError(f"root must have shape (*batch, 3), got {root.shape}")
    if bones.ndim < 2 or bones.shape[-2:] != (n_bones, 3):
        raise ValueError(f"bones must have shape (*batch, {n_bones}, 3) for {skeleton.name}, got {bones.shape}")
    root, bones = _broadcast_batch((root, 1), (bones, 2))
    relative = jnp.einsum("jk,...kd->...jd", jnp.asarray(_path_matrix(skeleton), dtype=bones.dtype), bones)
    return root[..., None, :] + relative


def joints_to_bones_matrix(skeleton: Skeleton) -> Float[np.ndarray, "dim dim"]:
    """NumPy ``B`` (3J x 3J) with ``[x_root; b_0; ...; b_{J-2}] = B @ X``.

    ``X`` stacks the joints in index order, three rows per joint (``X[3j:3j+3] = x_j``); the output
    stacks the root position then the bone vectors in ``skeleton.bones`` order. For a root at index 0
    (STRUCTRI17) this is Structural Triangulation's ``conv_J2B``: block k >= 1 is the bone ending at joint k."""
    parent, child = _bone_endpoints(skeleton)
    small = np.zeros((skeleton.num_joints, skeleton.num_joints))
    small[0, skeleton.root] = 1.0
    rows = np.arange(1, skeleton.num_joints)
    small[rows, child] = 1.0
    small[rows, parent] = -1.0
    return np.kron(small, np.eye(3))


def bones_to_joints_matrix(skeleton: Skeleton) -> Float[np.ndarray, "dim dim"]:
    """NumPy ``G`` (3J x 3J) with ``X = G @ [x_root; b_0; ...; b_{J-2}]``: the inverse of
    :func:`joints_to_bones_matrix`, built from the tree (each joint = root + the bones on its path).

    This is Structural Triangulation's ``conv_B2J``; with the root at index 0, ``G[3:, 3:]`` maps
    the bones to root-relative joints."""
    small = np.concatenate([np.ones((skeleton.num_joints, 1)), _path_matrix(skeleton)], axis=1)
    return np.kron(small, np.eye(3))

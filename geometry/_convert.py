"""Joint-set conversions: renaming by joint name, and the Shelf15 evaluation skeleton with its head rules.

Every conversion here is a fixed table built once per (source skeleton, rule) in NumPy and applied to
points with leading batch dimensions, so the code has no per-format branches and compiles to one
contraction. The public functions are jitted with their skeleton and rule arguments static (skeletons
are hashable metadata).

Shelf15 (:data:`~geometry.SHELF15`) is the joint set in which Shelf and Campus are scored: the 14
dataset joints plus joint 14, the mid-hip. Detector formats have no "bottom of head" / "top of head"
joints, so every published method derives them with its own rule (``docs/protocols.md``, "Head and neck");
the rule changes the Head PCP part and the Torso end, so it is an explicit argument, :data:`HeadRule`.
"""

from __future__ import annotations

import functools
import typing
from typing import Literal, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Shaped

from ._skeleton import FLEX20, FLEX20_DUPLICATE_OF, SHELF15, STRUCTRI17, Skeleton

__all__ = ["HeadRule", "HEAD_RULES", "remap_joints", "flex20_from_structri17", "shelf15_conversion_matrix",
           "to_shelf15", "to_shelf15_validity"]

HeadRule = Literal["4da", "voxelpose_shelf", "voxelpose_campus", "mvpose", "h36m"]
"""How Shelf15 joints 12 (bottom of head) and 13 (top of head) are derived (metres, world z up).

``"4da"``
    4D Association ``MappingToShelf`` (SKEL19) and JCSAT ``convert_openpose_shelf`` (BODY25) and
    ``convert_SKEL17_to_SHELF14`` (COCO17): ``face = normalise((neck - pelvis) x (r_sho - l_sho))``,
    ``s12 = sho_c + 0.5 (ear_c - sho_c)``, ``s13 = s12 + 0.125 face + 0.145 z_hat``. Without a neck
    joint (COCO17) the neck is the shoulder centre and the pelvis the hip centre, as in JCSAT. The
    0.125 m and 0.145 m offsets are in metres, our unit. A degenerate face direction (zero cross
    product) gives ``face = 0``, as Eigen's ``normalized()`` does.
``"voxelpose_shelf"``
    VoxelPose ``coco2shelf3D`` (also Faster-VoxelPose): from the shoulder centre ``c``, the nose and
    the ear centre, ``hb = (c + ear_c) / 2``, ``ht = 2 ear_c - hb``; then ``s13 = 0.75 (c + (nose - c)
    * [0.75, 0.75, 1.5]) + 0.25 ht`` and ``s12 = 0.75 (c + nose) / 2 + 0.25 hb``.
``"voxelpose_campus"``
    VoxelPose ``coco2campus3D``: ``s12 = hb``, ``s13 = ht`` (ears and shoulders only).
``"mvpose"``
    MVPose ``coco2shelf3D`` (both datasets): the VoxelPose Shelf rule without the final 0.75/0.25 blend.
``"h36m"``
    For ground truth on the STRUCTRI17 joint set (our synthetic scenes): ``s12`` = H36M's "Neck/Nose"
    joint, ``s13`` = its head top, and ``s14`` = the centre of the hips as in Shelf's ground truth
    (H36M's pelvis joint sits higher). Independent of the face keypoints detectors see.

VoxelPose and MVPose compute in millimetres, but every output of their rules is an affine combination
of input points (per axis: weights summing to one), so it commutes with the mm -> m scale and the rule
applies unchanged to metres. The per-axis factors [0.75, 0.75, 1.5] stretch the nose offset along the
third axis, which their Shelf/Campus world takes as vertical, the same z-up world as ours; they are
not meaningful for y-up data.
"""

HEAD_RULES: tuple[str, ...] = typing.get_args(HeadRule)

_DEFAULT_HEAD_RULE: dict[str, str] = {"BODY25": "4da", "SKEL19": "4da", "STRUCTRI17": "h36m"}
"""Source skeletons with a default head rule (their own method's). COCO17 has none: VoxelPose, MVPose
and JCSAT all score COCO17 predictions, each with its own rule, so the caller must name one."""

_FACE_OFFSET_M = 0.125
_UP_OFFSET_M = 0.145
_VP_NOSE_STRETCH = np.array([0.75, 0.75, 1.5])
_VP_BLEND = 0.75


def _check_points(points, source: Skeleton, what: str = "points") -> None:
    shape = jnp.shape(points)
    if len(shape) < 2 or shape[-2] != source.num_joints:
        raise ValueError(f"{what} must have shape (..., {source.num_joints}, C) for {source.name}, got {shape}")


@functools.partial(jax.jit, static_argnames=("source", "target"))
def remap_joints(
    points: Shaped[ArrayLike, "*b J C"], source: Skeleton, target: Skeleton
) -> Shaped[Array, "*b K C"]:
    """Reorder joints of ``source`` into ``target`` by joint name (any trailing channel count C).

    Names are matched literally; they are one vocabulary across formats, but datasets place some
    joints differently (STRUCTRI17's ``neck`` is its "Neck/Nose" point, SMPL24 hips sit inside the pelvis),
    so a remap across datasets is exact only for the joints whose definitions agree. For a validity
    mask ``(*b, J)`` pass ``mask[..., None]`` and take ``[..., 0]``.

    Raises:
        KeyError: naming the target joints the source lacks (use :func:`to_shelf15` for Shelf15).
    """
    _check_points(points, source)
    missing = [name for name in target.joints if name not in source.joints]
    if missing:
        raise KeyError(f"{source.name} -> {target.name}: the source has no joints {missing}")
    index = np.array([source.index(name) for name in target.joints], dtype=np.int32)
    return jnp.take(jnp.asarray(points), index, axis=-2)


_FLEX20_FROM_STRUCTRI17 = np.array(
    [STRUCTRI17.index(FLEX20_DUPLICATE_OF.get(name, name)) for name in FLEX20.joints], dtype=np.int32)


@jax.jit
def flex20_from_structri17(points: Shaped[ArrayLike, "*b 17 C"]) -> Shaped[Array, "*b 20 C"]:
    """:data:`~geometry.STRUCTRI17` joints in :data:`~geometry.FLEX20` order, the duplicates copied from the joints
    they coincide with (:data:`~geometry.FLEX20_DUPLICATE_OF`); any trailing channel count C.

    The inverse, dropping the duplicates, is ``remap_joints(points, FLEX20, STRUCTRI17)``."""
    _check_points(points, STRUCTRI17)
    return jnp.take(jnp.asarray(points), _FLEX20_FROM_STRUCTRI17, axis=-2)


class _Shelf15Table(NamedTuple):
    weights: np.ndarray
    """(15, J, 3): output joint k, axis c = sum_j weights[k, j, c] * source[j, c]."""
    face_axes: np.ndarray | None
    """(2, J) weights of the two vectors whose cross product is the face direction (4DA rule only)."""
    depends: np.ndarray
    """(15, J) bool: which source joints each output joint is computed from."""


def _combination(source: Skeleton, terms: dict[str, float]) -> np.ndarray:
    """(J,) weights of a linear combination of named source joints."""
    w = np.zeros(source.num_joints)
    for name, coef in terms.items():
        w[source.index(name)] += coef
    return w


def _joint_or_centre(source: Skeleton, name: str, pair: str) -> np.ndarray:
    """The source joint ``name``, or the centre of ``l_<pair>`` and ``r_<pair>`` when it has none."""
    if name in source.joints:
        return _combination(source, {name: 1.0})
    return _combination(source, {f"l_{pair}": 0.5, f"r_{pair}": 0.5})


@functools.lru_cache(maxsize=None)
def _shelf15_table(source: Skeleton, head_rule: str | None) -> _Shelf15Table:
    has_head = {"head_bottom", "head_top"} <= set(source.joints)
    if has_head and head_rule is not None:
        raise ValueError(f"{source.name} has head joints; pass head_rule=None (got {head_rule!r})")
    if not has_head:
        if head_rule is None:
            if source.name not in _DEFAULT_HEAD_RULE:
                raise ValueError(
                    f"{source.name} has no default head rule; choose head_rule from {HEAD_RULES} "
                    "(the method you compare against, docs/protocols.md, 'Head and neck')")
            head_rule = _DEFAULT_HEAD_RULE[source.name]
        if head_rule not in HEAD_RULES:
            raise ValueError(f"unknown head_rule {head_rule!r}; choose from {HEAD_RULES}")

    # Head rules are written per axis (VoxelPose stretches z), so every row is a (J, 3) weight map.
    def per_axis(w: np.ndarray) -> np.ndarray:
        return np.repeat(w[:, None], 3, axis=1)

    rows: dict[str, np.ndarray] = {}
    for name in SHELF15.joints:
        if name in source.joints:
            rows[name] = per_axis(_combination(source, {name: 1.0}))
    if "mid_hip" not in rows:
        rows["mid_hip"] = per_axis(_combination(source, {"l_hip": 0.5, "r_hip": 0.5}))

    face_axes = None
    if not has_head and head_rule == "h36m":
        rows["head_bottom"] = per_axis(_combination(source, {"neck_nose": 1.0}))
        rows["head_top"] = per_axis(_combination(source, {"head": 1.0}))
        # Shelf's ground-truth mid-hip is the centre of the hips; H36M's pelvis sits ~10 cm higher.
        rows["mid_hip"] = per_axis(_combination(source, {"l_hip": 0.5, "r_hip": 0.5}))
    elif not has_head:
        shoulder_c = _combination(source, {"l_shoulder": 0.5, "r_shoulder": 0.5})
        ear_c = _combination(source, {"l_ear": 0.5, "r_ear": 0.5})
        head_bottom = 0.5 * shoulder_c + 0.5 * ear_c  # 4DA's s12 and VoxelPose's hb coincide
        if head_rule == "4da":
            rows["head_bottom"] = rows["head_top"] = per_axis(head_bottom)
            neck = _joint_or_centre(source, "neck", "shoulder")
            pelvis = _joint_or_centre(source, "mid_hip", "hip")
            face_axes = np.stack([neck - pelvis, _combination(source, {"r_shoulder": 1.0, "l_shoulder": -1.0})])
        else:
            head_top = 2.0 * ear_c - head_bottom
            if head_rule == "voxelpose_campus":
                rows["head_bottom"], rows["head_top"] = per_axis(head_bottom), per_axis(head_top)
            else:
                nose = _combination(source, {"nose": 1.0})
                mvp_top = shoulder_c[:, None] + (nose - shoulder_c)[:, None] * _VP_NOSE_STRETCH
                mvp_bottom = per_axis(0.5 * shoulder_c + 0.5 * nose)
                if head_rule == "mvpose":
                    rows["head_bottom"], rows["head_top"] = mvp_bottom, mvp_top
                else:
                    rows["head_bottom"] = _VP_BLEND * mvp_bottom + (1 - _VP_BLEND) * per_axis(head_bottom)
                    rows["head_top"] = _VP_BLEND * mvp_top + (1 - _VP_BLEND) * per_axis(head_top)

    missing = [name for name in SHELF15.joints if name not in rows]
    if missing:
        raise KeyError(f"{source.name} -> SHELF15: cannot derive {missing}")
    weights = np.stack([rows[name] for name in SHELF15.joints])
    depends = np.any(weights != 0, axis=-1)
    if face_axes is not None:
        depends[SHELF15.index("head_top")] |= np.any(face_axes != 0, axis=0)
    return _Shelf15Table(weights, face_axes, depends)


def _safe_normalise(v: Float[Array, "*b 3"]) -> Float[Array, "*b 3"]:
    """Unit vector, or zero for a zero vector (with finite gradients there)."""
    sq = jnp.sum(v * v, axis=-1, keepdims=True)
    positive = sq > 0
    return jnp.where(positive, v / jnp.sqrt(jnp.where(positive, sq, 1.0)), 0.0)


@functools.partial(jax.jit, static_argnames=("source", "head_rule"))
def to_shelf15(
    points: Float[ArrayLike, "*b J 3"], source: Skeleton, head_rule: HeadRule | None = None
) -> Float[Array, "*b 15 3"]:
    """Convert 3D joints (metres, world z up) of ``source`` to :data:`~geometry.SHELF15`.

    Joints 0-11 are taken by name, joint 14 (mid-hip) is the source's ``mid_hip`` when it has one
    (4DA pelvis, BODY25 MidHip: the 4DA/JCSAT torso start) and the centre of the hips otherwise.
    A VoxelPose/MVPose-protocol evaluator recomputes the torso start from joints 2 and 3 itself.
    Joints 12 and 13 are the source's own when it has them (SHELF14, SHELF15; ``head_rule`` must then
    be None), else derived by ``head_rule`` (see :data:`HeadRule`); None picks the source method's
    rule (``"4da"`` for BODY25 and SKEL19) and raises for COCO17, which has no single convention.

    Missing source joints are not detected here: outputs computed from them are meaningless. Get the
    output validity with :func:`to_shelf15_validity` from a source mask (for 4DA/JCSAT files: the
    activity row, or "joint is not exactly (0, 0, 0)").
    """
    _check_points(points, source)
    if jnp.shape(points)[-1] != 3:
        raise ValueError(f"points must be 3D (..., {source.num_joints}, 3), got {jnp.shape(points)}")
    table = _shelf15_table(source, head_rule)
    points = jnp.asarray(points)
    dtype = jnp.result_type(points.dtype, jnp.float32)
    out = jnp.einsum("kjc,...jc->...kc", table.weights.astype(dtype), points.astype(dtype))
    if table.face_axes is not None:
        # The face direction is not linear in the joints; it is the one non-table term.
        axes = jnp.einsum("aj,...jc->...ac", table.face_axes.astype(dtype), points.astype(dtype))
        face = _safe_normalise(jnp.cross(axes[..., 0, :], axes[..., 1, :]))
        top = SHELF15.index("head_top")
        out = out.at[..., top, :].add(_FACE_OFFSET_M * face).at[..., top, 2].add(_UP_OFFSET_M)
    return out


def shelf15_conversion_matrix(source: Skeleton, head_rule: HeadRule | None = None) -> Float[np.ndarray, "15 J"]:
    """The linear part of :func:`to_shelf15` as a ``(15, J)`` matrix: output joint k = sum_j M[k, j] source[j].

    Exact for every rule that treats the three axes alike, except that the ``"4da"`` top of head also
    has its face and up offsets (non-linear, left out here); raises ``ValueError`` for the VoxelPose
    and MVPose rules, which stretch z. A learned joint-type conversion can start from it.
    """
    weights = _shelf15_table(source, head_rule).weights
    if not np.array_equal(weights, np.repeat(weights[..., :1], 3, axis=-1)):
        raise ValueError(f"the {head_rule!r} rule weights the axes differently: it has no single joint matrix")
    return weights[..., 0].copy()


@functools.partial(jax.jit, static_argnames=("source", "head_rule"))
def to_shelf15_validity(
    valid: Bool[ArrayLike, "*b J"], source: Skeleton, head_rule: HeadRule | None = None
) -> Bool[Array, "*b 15"]:
    """Which :func:`to_shelf15` outputs are computed only from valid source joints.

    An output joint is valid iff every source joint it depends on (with the same ``head_rule``) is;
    for the 4DA rule the top of head also depends on the neck, pelvis and shoulders of the face
    direction.
    """
    _check_points(jnp.asarray(valid)[..., None], source, "valid")
    table = _shelf15_table(source, head_rule)
    invalid = jnp.logical_not(jnp.asarray(valid)).astype(jnp.int32)
    return (invalid @ table.depends.T.astype(np.int32)) == 0

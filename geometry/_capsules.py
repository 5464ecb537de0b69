"""A posed body as a union of capsules, and its signed distance: the interpenetration loss of the thesis
(Eq. 4.41-4.42, after Jiang et al. 2020)

    rho_t^n(v) = -min(SDF_n(v), 0),    P_t = sum_n sum_{o != n} sum_{v in V_t^o} rho_t^n(v)

with person n's SDF approximated by capsules instead of a voxelised mesh: one capsule per bone of the 24-joint
tree, its axis the segment between the bone's two posed joints and its radius fitted once to the rest mesh
(:func:`body_capsules`). The union's signed distance (:func:`capsule_sdf`) is the minimum over capsules of
``distance to segment - radius``: exact outside the body; inside, the depth into the deepest capsule. It needs
only the posed joints, so it is cheap and differentiable everywhere; what it does not see is the surface detail
and the shape's girth (radii are fitted at zero betas). The other person's vertices ``V_t^o`` are a fixed sample
of template vertices (:func:`surface_points`), posed without the rest of the mesh by
:func:`~geometry.body_points`.

One person's loss term is ``penetration(joints_n, capsules, body_points(model, ..., vertices)).sum()``; sum
over ordered pairs ``n != o``.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from ._body import BodyModel
from ._rotations import _as_float

__all__ = ["Capsules", "body_capsules", "capsule_sdf", "penetration", "surface_points"]

_MIN_BONE = 1e-6
"""Rest bones shorter than this (metres) get no capsule."""


class Capsules(NamedTuple):
    """Capsules on a skeleton's joints. Close over it in jitted code (or pass it: its arrays then trace as
    index arrays)."""

    starts: Int[np.ndarray, "C"]
    """Joint at one end of each capsule (its bone's parent joint)."""
    ends: Int[np.ndarray, "C"]
    """Joint at the other end (the bone's child joint)."""
    radii: Float[np.ndarray, "C"]
    """Metres."""


@jax.jit  # one compilation instead of one per operation when called eagerly
def _segment_distances(points: Array, starts: Array, ends: Array) -> Array:
    """(P, C) distances from each point to each segment ``starts -> ends``; finite gradients everywhere."""
    axis = ends - starts
    offset = points[:, None, :] - starts[None, :, :]
    length2 = jnp.sum(axis * axis, axis=-1)
    degenerate = length2 <= 1e-24  # a zero-length segment is its start point
    t = jnp.sum(offset * axis[None], axis=-1) / jnp.where(degenerate, 1.0, length2)[None]
    t = jnp.where(degenerate[None], 0.0, jnp.clip(t, 0.0, 1.0))
    gap = offset - t[..., None] * axis[None]
    gap2 = jnp.sum(gap * gap, axis=-1)
    # sqrt'(0) is infinite: a point exactly on an axis gets distance 0 with a zero gradient instead of NaN.
    on_axis = gap2 <= 0.0
    return jnp.where(on_axis, 0.0, jnp.sqrt(jnp.where(on_axis, 1.0, gap2)))


@jax.jit
def _capsule_sdf(joints: Array, starts: Array, ends: Array, radii: Array, points: Array) -> Array:
    distances = _segment_distances(points, joints[starts], joints[ends])
    return jnp.min(distances - radii.astype(joints.dtype)[None], axis=1)


def capsule_sdf(
    joints: Float[ArrayLike, "joints 3"],
    capsules: Capsules,
    points: Float[ArrayLike, "P 3"],
) -> Float[Array, "P"]:
    """Signed distance (metres, negative inside) from each point to the union of ``capsules`` placed on the
    posed ``joints`` (module docstring)."""
    return _capsule_sdf(_as_float(joints), *capsules, _as_float(points))


def penetration(
    joints: Float[ArrayLike, "joints 3"],
    capsules: Capsules,
    points: Float[ArrayLike, "P 3"],
) -> Float[Array, "P"]:
    """rho of Eq. 4.41: how deep (metres, >= 0) each point lies inside the capsule body; 0 outside."""
    return jnp.maximum(-capsule_sdf(joints, capsules, points), 0.0)


def body_capsules(model: BodyModel) -> Capsules:
    """One capsule per bone of ``model.skeleton`` between its rest joints (bones shorter than a micrometre are
    skipped), its radius the median distance from the segment to the rest-mesh vertices (zero betas) that the
    bone carries.

    A vertex belongs to the joint with its largest skinning weight (none on a tie, as where the stand-in blends
    half-and-half), and from there to one of the bones leaving that joint (or, at a leaf, the bone arriving):
    SMPL's joint j moves the limb segment between j and its child, and its leaf joints (hands, toes, head) carry
    the ends of their parts. Where a joint has several such bones, a vertex goes to the capsule whose surface it
    is nearest, alternating with the radius fit until the assignment settles. A bone that gets no vertex this
    way takes all those of its two joints. Deterministic, NumPy (on concrete model arrays).
    """
    skeleton = model.skeleton
    template = np.asarray(model.v_template, dtype=np.float64)
    weights = np.asarray(model.weights, dtype=np.float64)
    rest = np.asarray(model.J_regressor, dtype=np.float64) @ template
    bones = np.array([(p, c) for p, c in skeleton.bones if np.linalg.norm(rest[c] - rest[p]) >= _MIN_BONE],
                     dtype=np.int64).reshape(-1, 2)
    starts, ends = bones[:, 0], bones[:, 1]
    distances = np.asarray(_segment_distances(jnp.asarray(template), jnp.asarray(rest[starts]),
                                              jnp.asarray(rest[ends])))

    top2 = np.sort(weights, axis=1)[:, -2:]
    owner = np.where(top2[:, 1] > top2[:, 0], np.argmax(weights, axis=1), -1)
    carries = np.zeros((skeleton.num_joints, len(bones)), dtype=bool)  # joint -> the bones its vertices go to
    for joint in range(skeleton.num_joints):
        carries[joint] = starts == joint
        if not carries[joint].any():
            carries[joint] = ends == joint
    candidates = np.where(owner[:, None] >= 0, carries[np.maximum(owner, 0)], False)
    fallback = [(owner == parent) | (owner == child) for parent, child in bones]
    for k, rows in enumerate(fallback):
        if not rows.any():
            raise ValueError(f"{skeleton.name} bone {skeleton.joints[starts[k]]}->{skeleton.joints[ends[k]]}: no "
                             "vertex is skinned mostly to either of its joints, so no radius can be fitted")

    # Alternate: each vertex to the candidate capsule whose surface is nearest, each radius the median distance
    # of its vertices. Nearest axes first would hand a thin capsule's end cap to a fat neighbour sharing the
    # joint (the stand-in's hips to its spine), shrinking it.
    radii, assigned = np.zeros(len(bones)), None
    for _ in range(20):
        gap = np.where(candidates, np.abs(distances - radii[None]), np.inf)
        update = np.where(candidates.any(axis=1), np.argmin(gap, axis=1), -1)
        if assigned is not None and np.array_equal(update, assigned):
            break
        assigned = update
        for k in range(len(bones)):
            rows = assigned == k
            radii[k] = np.median(distances[rows if rows.any() else fallback[k], k])
    return Capsules(starts, ends, radii)


def surface_points(model: BodyModel, count: int, seed: int = 0) -> Int[np.ndarray, "count"]:
    """Indices of ``count`` distinct template vertices spread over the whole body: farthest-point sampling on
    the rest mesh from a vertex chosen by ``seed``. Deterministic; the first ``k`` of ``count`` are the sample
    of ``k``."""
    template = np.asarray(model.v_template, dtype=np.float64)
    if not 1 <= count <= len(template):
        raise ValueError(f"count must lie in [1, {len(template)}] (the model's vertices), got {count}")
    chosen = np.empty(count, dtype=np.int64)
    chosen[0] = np.random.default_rng(seed).integers(len(template))
    nearest = np.full(len(template), np.inf)
    for i in range(1, count):
        nearest = np.minimum(nearest, np.sum((template - template[chosen[i - 1]]) ** 2, axis=1))
        nearest[chosen[i - 1]] = -1.0  # below every distance: never chosen again, even among coincident vertices
        chosen[i] = np.argmax(nearest)
    return chosen

"""A parametric body model with SMPL's interface: shape and pose blend shapes, a joint regressor and linear
blend skinning over the 24-joint kinematic tree (:data:`SMPL24`).

:func:`body_forward` is SMPL's forward function for one person (Loper et al. 2015, Eq. 1-10):

    v_shaped = v_template + shapedirs . betas
    J        = J_regressor v_shaped                       (rest joints)
    v_posed  = v_shaped + posedirs . vec(R_j - I, j >= 1)  (pose correctives)
    G_j      = forward kinematics of the local rotations R_j with rest offsets J_j - J_parent(j)
    v        = sum_j W_vj (G_j (v_posed - J_j)) + translation

Joints out are the posed joints ``G_j`` (SMPL's ``J_transformed``). Rotations come in as matrices; the thesis'
6D rotations convert through :func:`rotation_6d_to_matrix`. :func:`body_joints` skips the skinning and
:func:`body_points` skins only chosen vertices (the same code path as :func:`body_forward`).

Two sources of a :class:`BodyModel`:

- :func:`load_body_model`: the official SMPL model files (``.pkl`` as distributed, or ``.npz`` with the same
  keys) when a user has them; nothing is downloaded.
- :func:`stand_in_body_model`: a body the project generates itself, documented as a **stand-in for SMPL**, not a
  fit of it: one closed capsule around each bone of a T-posed SMPL24 skeleton (metres, y up, facing +z, the
  person's left at +x like SMPL), skinning weights that blend each capsule's ends with the neighbouring joints,
  a joint regressor that averages the vertex ring around each joint (so regressed joints are the skeleton's
  joints exactly), three shape directions (height, girth, leg length; one unit of beta is 10 %) and no pose
  correctives (zero ``posedirs``).
"""

from __future__ import annotations

import dataclasses
import pickle
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from ._kinematics import forward_kinematics
from ._rotations import _as_float
from ._skeleton import SMPL24, Skeleton

__all__ = [
    "BodyModel", "BodyOutput", "body_forward", "body_joints", "body_points", "load_body_model",
    "stand_in_body_model",
]


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class BodyModel:
    """A body model's arrays (a pytree: pass it through ``jit`` and ``vmap`` as an argument)."""

    v_template: Float[Array, "vertices 3"]
    """Rest vertices, metres."""
    shapedirs: Float[Array, "vertices 3 shapes"]
    """Shape blend shapes: vertex displacement per unit of each beta."""
    posedirs: Float[Array, "vertices 3 pose_features"]
    """Pose blend shapes over ``vec(R_j - I)`` of the non-root joints (9 (joints - 1) features)."""
    J_regressor: Float[Array, "joints vertices"]
    weights: Float[Array, "vertices joints"]
    """Skinning weights; each row sums to 1."""
    faces: Int[Array, "faces 3"]
    """Triangles, counter-clockwise seen from outside."""
    skeleton: Skeleton = dataclasses.field(default=SMPL24, metadata=dict(static=True))

    @property
    def num_shapes(self) -> int:
        return self.shapedirs.shape[-1]


class BodyOutput(NamedTuple):
    vertices: Float[Array, "vertices 3"]
    joints: Float[Array, "joints 3"]
    """Posed joints (the origins of the skinning transforms), metres."""


def _check_body_inputs(model: BodyModel, rotations, betas, translation) -> tuple[Array, Array, Array]:
    rotations, betas, translation = map(_as_float, (rotations, betas, translation))
    joints, shapes = model.J_regressor.shape[0], model.shapedirs.shape[-1]
    if rotations.shape != (joints, 3, 3) or betas.shape != (shapes,) or translation.shape != (3,):
        raise ValueError(f"need rotations ({joints}, 3, 3), betas ({shapes},) and translation (3,), got "
                         f"{rotations.shape}, {betas.shape} and {translation.shape}")
    for name, value in (("rotations", rotations), ("betas", betas), ("translation", translation)):
        # Concrete inputs only: under jit or vmap the values are not known here.
        if not isinstance(value, jax.core.Tracer) and not bool(jnp.all(jnp.isfinite(value))):
            raise ValueError(f"{name} contains NaN or inf")
    return rotations, betas, translation


def _pose_skeleton(model: BodyModel, rotations: Array, rest_joints: Array) -> tuple[Array, Array]:
    parents = np.asarray(model.skeleton.parents)
    offsets = rest_joints - jnp.where((parents >= 0)[:, None], rest_joints[np.maximum(parents, 0)], 0.0)
    return forward_kinematics(rotations, offsets, rest_joints[model.skeleton.root], model.skeleton)


def _shaped_vertices(model: BodyModel, betas: Array) -> Array:
    return model.v_template + jnp.einsum("vcs,s->vc", model.shapedirs, betas)


def _pose_vertices(model: BodyModel, rotations, betas, translation, rows: Array | None) -> BodyOutput:
    """SMPL's forward function (module docstring) for the vertices ``rows`` (None: all of them): shared by
    :func:`body_forward` and :func:`body_points`. The rest joints regress the whole shaped mesh either way; the
    pose correctives and the skinning touch only the chosen rows."""
    rotations, betas, translation = _check_body_inputs(model, rotations, betas, translation)
    v_shaped = _shaped_vertices(model, betas)
    rest_joints = model.J_regressor @ v_shaped
    posed_joints, global_rotations = _pose_skeleton(model, rotations, rest_joints)
    posedirs, weights = model.posedirs, model.weights
    if rows is not None:
        v_shaped, posedirs, weights = v_shaped[rows], posedirs[rows], weights[rows]
    pose_features = (rotations[1:] - jnp.eye(3, dtype=rotations.dtype)[None]).reshape(-1)
    v_posed = v_shaped + jnp.einsum("vcp,p->vc", posedirs, pose_features)
    # Skin with the blended transforms v -> R_j (v - J_j) + G_j.
    blended_R = jnp.einsum("vj,jab->vab", weights, global_rotations)
    blended_t = weights @ (posed_joints - jnp.einsum("jab,jb->ja", global_rotations, rest_joints))
    vertices = jnp.einsum("vab,vb->va", blended_R, v_posed) + blended_t
    return BodyOutput(vertices + translation[None], posed_joints + translation[None])


def body_forward(
    model: BodyModel,
    rotations: Float[ArrayLike, "joints 3 3"],
    betas: Float[ArrayLike, "shapes"],
    translation: Float[ArrayLike, "3"],
) -> BodyOutput:
    """Posed vertices and joints of one person (module docstring); ``vmap`` over people or frames.

    Args:
        model: a :class:`BodyModel`.
        rotations: local joint rotations in ``model.skeleton`` order (the root's is global).
        betas: shape coefficients, as many as ``model.shapedirs`` has directions.
        translation: added to every vertex and joint (metres).
    """
    return _pose_vertices(model, rotations, betas, translation, None)


def body_points(
    model: BodyModel,
    rotations: Float[ArrayLike, "joints 3 3"],
    betas: Float[ArrayLike, "shapes"],
    translation: Float[ArrayLike, "3"],
    vertices: Int[ArrayLike, "V"],
) -> Float[Array, "V 3"]:
    """``body_forward(...).vertices[vertices]`` without posing the rest of the mesh: a loss over a few hundred
    sampled vertices (e.g. :func:`surface_points`) pays for those, plus the joint regression."""
    if not isinstance(vertices, jax.core.Tracer):
        chosen, count = np.asarray(vertices), model.v_template.shape[0]
        if chosen.size and (chosen.min() < 0 or chosen.max() >= count):
            raise ValueError(f"vertex indices must lie in [0, {count}), got {chosen.min()}..{chosen.max()}")
    return _pose_vertices(model, rotations, betas, translation, jnp.asarray(vertices)).vertices


def body_joints(
    model: BodyModel,
    rotations: Float[ArrayLike, "joints 3 3"],
    betas: Float[ArrayLike, "shapes"],
    translation: Float[ArrayLike, "3"],
) -> Float[Array, "joints 3"]:
    """``body_forward(...).joints`` without skinning the vertices, so a training loss over thousands of frames
    costs joints (and one regression of the shaped mesh), not meshes."""
    rotations, betas, translation = _check_body_inputs(model, rotations, betas, translation)
    rest_joints = model.J_regressor @ _shaped_vertices(model, betas)
    return _pose_skeleton(model, rotations, rest_joints)[0] + translation[None]


# ----------------------------------------------------------------------------------------------
# The official model files.

_SMPL_KEYS = ("v_template", "shapedirs", "posedirs", "J_regressor", "weights", "f", "kintree_table")


def load_body_model(path: str | Path, num_shapes: int | None = None) -> BodyModel:
    """The official SMPL model (``.pkl`` as distributed, or ``.npz`` with the same keys: ``v_template``,
    ``shapedirs``, ``posedirs``, ``J_regressor``, ``weights``, ``f``, ``kintree_table``), keeping the first
    ``num_shapes`` shape directions (default all). Its kinematic tree must be SMPL24's."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no body model file at {path}")
    if path.suffix == ".npz":
        with np.load(path, allow_pickle=False) as data:
            raw = {key: data[key] for key in data.files}
    elif path.suffix == ".pkl":
        try:
            with open(path, "rb") as file:
                raw = pickle.load(file, encoding="latin1")
        except ModuleNotFoundError as error:
            raise ValueError(f"{path} holds {error.name} objects (the original SMPL release pickles chumpy "
                             "arrays): install that package, or save the arrays to an .npz with the same keys") from None
    else:
        raise ValueError(f"{path}: a body model is a .pkl or .npz file")
    missing = [key for key in _SMPL_KEYS if key not in raw]
    if missing:
        raise ValueError(f"{path} lacks the SMPL keys {missing}")
    arrays = {key: np.asarray(raw[key].toarray() if hasattr(raw[key], "toarray") else raw[key])  # scipy sparse
              for key in _SMPL_KEYS}
    parents = tuple(int(p) if p < 2**31 else -1 for p in arrays["kintree_table"][0])
    if parents != SMPL24.parents:
        raise ValueError(f"{path}: kinematic tree {parents} is not SMPL24's {SMPL24.parents}")
    vertices, joints = arrays["v_template"].shape[0], SMPL24.num_joints
    expected = {"v_template": (vertices, 3), "shapedirs": (vertices, 3, arrays["shapedirs"].shape[-1]),
                "posedirs": (vertices, 3, 9 * (joints - 1)), "J_regressor": (joints, vertices),
                "weights": (vertices, joints), "f": (arrays["f"].shape[0], 3)}
    for key, shape in expected.items():
        if arrays[key].shape != shape:
            raise ValueError(f"{path}: {key} has shape {arrays[key].shape}, expected {shape} ({vertices} vertices)")
    floats = {key: jnp.asarray(arrays[key].astype(np.float64)) for key in ("v_template", "posedirs", "J_regressor",
                                                                            "weights")}
    return BodyModel(**floats, shapedirs=jnp.asarray(arrays["shapedirs"][..., :num_shapes].astype(np.float64)),
                     faces=jnp.asarray(arrays["f"].astype(np.int32)))


# ----------------------------------------------------------------------------------------------
# The generated stand-in.

_REST_JOINTS = {  # metres, y up, facing +z, the person's left at +x (SMPL's template frame)
    "mid_hip": (0.0, 0.0, 0.0), "l_hip": (0.07, -0.09, 0.0), "r_hip": (-0.07, -0.09, 0.0),
    "spine1": (0.0, 0.11, -0.01), "l_knee": (0.10, -0.47, 0.0), "r_knee": (-0.10, -0.47, 0.0),
    "spine2": (0.0, 0.25, -0.01), "l_ankle": (0.09, -0.87, -0.03), "r_ankle": (-0.09, -0.87, -0.03),
    "spine3": (0.0, 0.31, 0.0), "l_foot": (0.11, -0.93, 0.10), "r_foot": (-0.11, -0.93, 0.10),
    "neck": (0.0, 0.52, -0.01), "l_collar": (0.07, 0.43, -0.01), "r_collar": (-0.07, 0.43, -0.01),
    "head": (0.0, 0.62, 0.03), "l_shoulder": (0.18, 0.45, -0.02), "r_shoulder": (-0.18, 0.45, -0.02),
    "l_elbow": (0.44, 0.45, -0.03), "r_elbow": (-0.44, 0.45, -0.03), "l_wrist": (0.69, 0.45, -0.02),
    "r_wrist": (-0.69, 0.45, -0.02), "l_hand": (0.78, 0.45, -0.02), "r_hand": (-0.78, 0.45, -0.02),
}
_RADIUS = {  # capsule radius of the bone ending at each joint, metres
    "hip": 0.08, "knee": 0.065, "ankle": 0.048, "foot": 0.035, "spine1": 0.12, "spine2": 0.13, "spine3": 0.13,
    "neck": 0.05, "collar": 0.055, "head": 0.095, "shoulder": 0.05, "elbow": 0.042, "wrist": 0.034, "hand": 0.03,
}
_BLEND = 0.25
"""Fraction of a capsule's length at each end over which its weights blend with the neighbouring joint."""


def _capsule(start: np.ndarray, end: np.ndarray, radius: float, around: int, rings: int, cap_rings: int):
    """A closed capsule around the segment: vertices, faces (outward, counter-clockwise), each vertex's axial
    coordinate u (0 at ``start``, 1 at ``end``, beyond on the caps) and its point on the axis."""
    axis = end - start
    length = float(np.linalg.norm(axis))
    direction = axis / length
    helper = np.array([0.0, 0.0, 1.0]) if abs(direction[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    side = np.cross(direction, helper)
    side /= np.linalg.norm(side)
    up = np.cross(direction, side)
    # Rings from the start pole to the end pole: (axial position, ring radius).
    cap = [(-radius * np.cos(a), radius * np.sin(a)) for a in np.linspace(0, np.pi / 2, cap_rings + 1)[1:]]
    body = [(length * s, radius) for s in np.linspace(0, 1, rings)[1:-1]]
    profile = cap + body + [(length - x, r) for x, r in reversed(cap)]
    angles = 2 * np.pi * np.arange(around) / around
    circle = np.cos(angles)[:, None] * side + np.sin(angles)[:, None] * up
    vertices = [start - radius * direction]
    axial = [-radius]
    for x, r in profile:
        vertices.extend(start + x * direction + r * circle)
        axial.extend([x] * around)
    vertices.append(end + radius * direction)
    axial.append(length + radius)
    faces = []
    n_rings = len(profile)
    for k in range(around):  # start pole fan
        faces.append((0, 1 + (k + 1) % around, 1 + k))
    for i in range(n_rings - 1):
        a, b = 1 + i * around, 1 + (i + 1) * around
        for k in range(around):
            k1 = (k + 1) % around
            faces += [(a + k, a + k1, b + k), (a + k1, b + k1, b + k)]
    last, pole = 1 + (n_rings - 1) * around, 1 + n_rings * around
    for k in range(around):  # end pole fan
        faces.append((last + k, last + (k + 1) % around, pole))
    axial = np.asarray(axial) / length
    on_axis = start + np.clip(axial, 0, 1)[:, None] * axis
    return np.asarray(vertices), np.asarray(faces), axial, on_axis


def _radius(joint: str) -> float:
    return _RADIUS[joint.removeprefix("l_").removeprefix("r_")]


@dataclasses.dataclass(frozen=True)
class _Part:
    bone: int
    parent_joint: int
    child_joint: int
    vertices: slice


def stand_in_body_model(around: int = 12, rings: int = 5, cap_rings: int = 3) -> BodyModel:
    """The generated stand-in for SMPL (module docstring): 23 closed capsules of ``around (rings - 2 + 2 cap_rings)
    + 2`` vertices each, ``around`` vertices per ring, ``rings`` rings along the bone (both ends included) and
    ``cap_rings`` on each hemispherical cap."""
    skeleton = SMPL24
    rest = np.array([_REST_JOINTS[name] for name in skeleton.joints])
    pieces, faces, parts, offset = [], [], [], 0
    for bone, (parent, child) in enumerate(skeleton.bones):
        v, f, u, on_axis = _capsule(rest[parent], rest[child], _radius(skeleton.joints[child]), around, rings,
                                    cap_rings)
        pieces.append((v, u, on_axis))
        faces.append(f + offset)
        parts.append(_Part(bone, parent, child, slice(offset, offset + len(v))))
        offset += len(v)
    v_template = np.concatenate([p[0] for p in pieces])
    u = np.concatenate([p[1] for p in pieces])
    on_axis = np.concatenate([p[2] for p in pieces])
    n_vertices, n_joints = len(v_template), skeleton.num_joints

    # A capsule moves with its parent joint (SMPL: joint j's rotation moves the segments leaving j), blending to
    # half-and-half with the joint before it at its start and with its child joint at its end.
    weights = np.zeros((n_vertices, n_joints))
    children = {j: [c for c in range(n_joints) if skeleton.parents[c] == j] for j in range(n_joints)}
    for part in parts:
        rows = np.arange(n_vertices)[part.vertices]
        t = u[part.vertices]
        grand = skeleton.parents[part.parent_joint]
        to_start = 0.5 * np.clip(1 - t / _BLEND, 0, 1) if grand >= 0 else np.zeros_like(t)
        to_end = 0.5 * np.clip((t - 1 + _BLEND) / _BLEND, 0, 1) if children[part.child_joint] else np.zeros_like(t)
        weights[rows, part.parent_joint] += 1 - to_start - to_end
        if grand >= 0:
            weights[rows, grand] += to_start
        weights[rows, part.child_joint] += to_end

    # Each joint: the mean of the equator rings at its end of the capsules that start there (or, at a leaf,
    # end there); a ring around the axis averages to the axis point, so regressed joints are the skeleton's.
    regressor = np.zeros((n_joints, n_vertices))
    for j in range(n_joints):
        ends = [(p, 0.0) for p in parts if p.parent_joint == j] or [(p, 1.0) for p in parts if p.child_joint == j]
        for part, at in ends:
            rows = np.arange(n_vertices)[part.vertices]
            ring = rows[np.isclose(u[part.vertices], at)]
            regressor[j, ring] = 1.0 / (len(ring) * len(ends))

    hip_height = rest[skeleton.index("l_hip"), 1]
    shapedirs = np.stack([
        0.1 * v_template,  # height: scale about the pelvis
        0.1 * (v_template - on_axis),  # girth: radial, joints unchanged
        0.1 * np.minimum(v_template - np.array([0.0, hip_height, 0.0]), 0.0) * np.array([0.0, 1.0, 0.0]),  # legs
    ], axis=-1)
    return BodyModel(v_template=jnp.asarray(v_template), shapedirs=jnp.asarray(shapedirs),
                     posedirs=jnp.zeros((n_vertices, 3, 9 * (n_joints - 1))), J_regressor=jnp.asarray(regressor),
                     weights=jnp.asarray(weights), faces=jnp.asarray(np.concatenate(faces).astype(np.int32)),
                     skeleton=skeleton)

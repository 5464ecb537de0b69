"""The FLEX network (Gordon et al., ECCV 2022, Sec. 3.1, App. D, Table 6) in Flax NNX.

Input: K views x T frames of 2D joints in pixels (:data:`geometry.STRUCTRI17` order) with confidences, and nothing
else: no intrinsic or extrinsic parameters. :func:`~flex.normalise_2d` turns each view into calibration-free
features ``V`` (``3J`` channels per view and frame). Then (Fig. 3, 14, 15):

- **F_Q** (rotation branch): a channel-wise expansion (1x1 conv, shared by the views) -> the multi-view
  convolution: parallel 2D convolutions over (frames, views) with temporal kernels ``stage1_kernels``, no
  temporal padding and circular padding over the views, each average-pooled back to T frames, summed -> the
  cross-view attention: per frame, a learned fusion token attends to itself and the K view features
  (multi-head attention over views) and only its output is kept: one fused feature per frame.
- **E_Q**: parallel temporal convolutions ``stage2_kernels`` (pooled back to T, summed) -> a 1x1 shrink to,
  per frame, the 14 shared joint quaternions (:data:`geometry.FLEX20_ROTATING`) and 2 foot contacts; and per
  frame and view, from that view's features beside the fused one (:class:`RotationBranch`), the root rotation
  (6D: its quaternion would have to jump somewhere as the heading goes round) and the root depth.
- **F_S / E_S** (bone branch): per view a 1x1 expansion and ``bone_stages`` x sequential temporal convolutions
  ``bone_kernels`` (no padding) -> cross-view attention per frame -> max over time -> a 1x1 shrink to the 10
  symmetric bone lengths of :data:`geometry.FLEX20_BONES` (one skeleton per sequence).
- **FK** (:func:`flex_forward_kinematics`): the bones, the shared rotations and each view's root rotation give K
  root-relative camera-frame pose sequences of :data:`geometry.FLEX20`, through :func:`geometry.forward_kinematics`.
- **D** (:class:`Discriminator`): one discriminator per joint on temporal rotation differences ``q[t + delta] -
  q[t]``; the root's is applied to each view's root rotation.

Every convolution and expansion is followed by batch normalisation, a leaky ReLU and dropout (App. D). Sizes
follow Table 6 and the official code (``docs/flex.md``); :data:`CONFIGS` has the paper's and a CPU one.

Camera model (weak perspective, no calibration): the root depth is predicted in the normalised camera of each
view, whose image coordinates are the normalised ones (origin at the view's mean root image position ``centre``,
one unit = ``scale`` pixels, focal length 1): a root at metric depth ``Z`` seen with focal length ``f`` pixels has
normalised depth ``d = Z * scale / f`` (metres; at the truth ``d`` is about the body's RMS joint spread times
``Z / mean Z``). Its position is the back-projection of the detected root, ``(x d, y d, d)`` with ``(x, y)`` the
root's normalised image coordinates. Under weak perspective that frame is the camera frame with depth scaled by
``scale / f``, which is FLEX's "global position up to scale" (Sec. 3 and 4).

Training mode (``key`` given) draws dropout from the key and normalises with batch statistics (updating the
running averages); without a key the model is deterministic and uses the running averages. A training step
that merges the model inside ``jax.grad`` must merge with ``nnx.merge(..., copy=True)``: batch norm may only
update variables created at the gradient's trace level.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Any, Literal, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import nnx
from jaxtyping import Array, ArrayLike, Float

import geometry
import training
from geometry import FLEX20, FLEX20_BONE_OF_JOINT, FLEX20_BONES, FLEX20_REST_DIRECTIONS, FLEX20_ROTATING, STRUCTRI17

from . import _data
from ._normalise import normalise_2d

__all__ = [
    "CONFIGS", "Discriminator", "Flex", "FlexConfig", "FlexOutputs", "INDEPENDENT_ROTATIONS", "RotationDiscriminator",
    "averaged_monocular", "flex_forward_kinematics", "parameter_count", "predict", "tie_duplicates",
]

NUM_ROTATING = len(FLEX20_ROTATING)
NUM_BONES = len(FLEX20_BONES)
INPUT_ROOT = STRUCTRI17.index("mid_hip")

_REFERENCE_BONES_M = (0.13, 0.44, 0.44, 0.23, 0.25, 0.12, 0.12, 0.15, 0.28, 0.25)
"""Typical adult lengths of :data:`geometry.FLEX20_BONES` (metres, about Human3.6M's means). Only the origin of
E_S's output, ``bones = reference * exp(raw)``, so that an untrained model already has a human-sized, positive
skeleton; training moves it anywhere."""


_FACING_CAMERA_6D = (1.0, 0.0, 0.0, 0.0, -1.0, 0.0)
"""The root rotation of an upright person facing the camera, body (x left, y up, z forward) to OpenCV camera
(x right, y down, z away), a half turn about x, as the 6D vector of its first two columns."""


@functools.cache
def _standing_rotations(rest_pose: str) -> np.ndarray:
    """(14, 4) quaternions of :data:`geometry.FLEX20_ROTATING` that pose the rest skeleton standing: legs and
    spine straight, shoulders sideways, arms hanging down (the origin of E_Q's joint rotations)."""
    down = (0.0, -1.0, 0.0)
    directions = np.array(FLEX20_REST_DIRECTIONS["tpose"])
    for arm in ("l_elbow", "l_wrist", "r_elbow", "r_wrist"):
        directions[FLEX20.index(arm)] = down
    lengths = np.array([0.0 if b < 0 else _REFERENCE_BONES_M[b] for b in FLEX20_BONE_OF_JOINT])
    standing = np.zeros((FLEX20.num_joints, 3))
    for joint in FLEX20.topological_order[1:]:
        standing[joint] = standing[FLEX20.parents[joint]] + lengths[joint] * directions[joint]
    with jax.ensure_compile_time_eval():  # a constant, also when first needed inside a trace
        local = _data.local_rotations(standing, rest_pose)[np.asarray(FLEX20_ROTATING)]
        return np.asarray(geometry.matrix_to_quaternion(local))


@dataclasses.dataclass(frozen=True)
class FlexConfig:
    """Every hyperparameter of :class:`Flex` and :class:`Discriminator` (paper Table 6, spec section 3)."""

    views: int = 4
    """K: the number of input views (the output has a root rotation and depth per view)."""
    channels: int = 1024
    """Feature width of F_Q, E_Q, F_S and E_S (Table 6 and the README; the official default.json has 512)."""
    heads: int = 64
    """Heads of the cross-view attention (Table 4's best, head width 1024 / 64 = 16)."""
    view_kernel: int = 5
    """Width over views of the multi-view convolution, with circular padding ``view_kernel // 2``."""
    stage1_kernels: tuple[int, ...] = (5, 3, 1)
    """Temporal kernels of F_Q's parallel multi-view convolutions."""
    stage2_kernels: tuple[int, ...] = (5, 3, 1)
    """Temporal kernels of E_Q's parallel convolutions."""
    bone_kernels: tuple[int, ...] = (5, 3, 1)
    """Temporal kernels of one F_S stage (sequential, no padding)."""
    bone_stages: int = 2
    dropout: float = 0.25
    """Dropout after every convolution block (the official code's 0.25)."""
    batch_norm_momentum: float = 0.9
    """Decay of the running averages (PyTorch's default momentum 0.1)."""
    leaky_slope: float = 0.01
    input_joints: int = STRUCTRI17.num_joints
    fusion: Literal["early", "late"] = "early"
    """Where F_Q fuses the views (Table 5c): "early" is FLEX (multi-view convolution, then cross-view attention
    before E_Q); "late" processes each view alone (view kernel 1, E_Q's temporal convolutions per view) and fuses
    with the same attention just before the output layer."""
    rest_pose: Literal["totem", "tpose"] = "totem"
    """Rest pose of the FK skeleton (:data:`geometry.FLEX20_REST_DIRECTIONS`; "totem" as the released model)."""
    duplicate_joints: bool = True
    """False: the skeleton without App. C's duplicate joints, the paper's ablation (:func:`tie_duplicates`): the
    spine turns with the pelvis and the shoulders with the neck. Needs ``rest_pose="tpose"``, whose thorax
    children point their own ways at rest (the totem's all point up)."""
    discriminator_channels: int = 500
    discriminator_kernel: int = 4
    discriminator_frames: int = 24
    """D's temporal average pool size (the official code's 24)."""
    rotation_delta: int = 5
    """D's temporal difference ``q[t + rotation_delta] - q[t]`` (the official code's frame offset 5)."""

    def __post_init__(self) -> None:
        for name in ("views", "channels", "heads", "view_kernel", "bone_stages", "input_joints",
                     "discriminator_channels", "discriminator_kernel", "discriminator_frames", "rotation_delta"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        for name in ("stage1_kernels", "stage2_kernels", "bone_kernels"):
            kernels = getattr(self, name)
            if not kernels or min(kernels) < 1:
                raise ValueError(f"{name} must be a non-empty tuple of positive kernel sizes, got {kernels}")
        if self.channels % self.heads:
            raise ValueError(f"channels ({self.channels}) must be a multiple of heads ({self.heads})")
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"dropout must be in [0, 1), got {self.dropout}")
        if self.fusion not in ("early", "late"):
            raise ValueError(f"fusion must be 'early' or 'late', got {self.fusion!r}")
        if self.rest_pose not in FLEX20_REST_DIRECTIONS:
            raise ValueError(f"rest_pose must be one of {sorted(FLEX20_REST_DIRECTIONS)}, got {self.rest_pose!r}")
        if not self.duplicate_joints and self.rest_pose != "tpose":
            raise ValueError(f"duplicate_joints=False needs rest_pose 'tpose' (the totem's shoulders and neck point "
                             f"the same way at rest), got {self.rest_pose!r}")

    @property
    def min_frames(self) -> int:
        """The shortest input: F_S's unpadded convolutions and D's difference and kernel must fit in it."""
        bone = 1 + self.bone_stages * sum(k - 1 for k in self.bone_kernels)
        rotation = max(self.stage1_kernels + self.stage2_kernels)
        return max(bone, rotation, self.rotation_delta + self.discriminator_kernel)


CONFIGS: dict[str, FlexConfig] = {
    "paper": FlexConfig(),
    # Tests and CPU experiments: the paper's structure (kernels, stages, attention, D) at width 32 with 4 heads
    # of 8; about 0.1 M generator parameters instead of 0.1 G.
    "cpu": FlexConfig(channels=32, heads=4, discriminator_channels=16),
    # CPU training runs: width 128 with the paper's head width 16 and less dropout for short runs (1.3 M
    # generator parameters, flex.parameter_count): width 32 fits even one fixed batch poorly.
    "small": FlexConfig(channels=128, heads=8, dropout=0.1, discriminator_channels=64),
}
"""Named configurations: the paper's (Table 6), a tiny one for tests and the shipped CPU one."""


def parameter_count(model: nnx.Module) -> int:
    """Number of trainable scalars (``nnx.Param``); works on real and on ``nnx.eval_shape`` models."""
    return sum(math.prod(leaf.shape) for leaf in jax.tree.leaves(nnx.state(model, nnx.Param)))


class FlexOutputs(NamedTuple):
    """What :class:`Flex` predicts for a batch (metres; camera frames are OpenCV's or, for the root position,
    the normalised camera's, see the module docstring)."""

    rotations: Float[Array, "batch frames 14 4"]
    """Unit (w, x, y, z) local quaternions of :data:`geometry.FLEX20_ROTATING`, shared by all views."""
    root_rotations: Float[Array, "batch views frames 4"]
    """Unit quaternion of the root's rotation from the body frame (x left, y up, z forward) to each camera."""
    contacts: Float[Array, "batch frames 2"]
    """Probability that the right / left foot (FLEX20 joints 3 / 6) touches the ground."""
    root_depth: Float[Array, "batch views frames"]
    """Root depth ``d`` in each view's normalised camera (metres, see the module docstring)."""
    root_position: Float[Array, "batch views frames 3"]
    """``(x d, y d, d)``: the detected root back-projected at depth ``d`` (normalised camera frame)."""
    bone_lengths: Float[Array, "batch 10"]
    """The symmetric skeleton, :data:`geometry.FLEX20_BONES` (metres, positive)."""
    joints_relative: Float[Array, "batch views frames 20 3"]
    """FK of the bones and rotations with the root at the origin: each view's camera-frame pose (FLEX20)."""
    joints: Float[Array, "batch views frames 20 3"]
    """``joints_relative`` plus ``root_position``."""
    scale: Float[Array, "batch views"]
    """The input normalisation's pixels per unit (:func:`~flex.normalise_2d`): metric depth is ``d f / scale``."""
    centre: Float[Array, "batch views 2"]
    """The input normalisation's origin in pixels (:func:`~flex.normalise_2d`); with ``scale`` and the intrinsics,
    :func:`~flex.camera_root` turns ``root_position`` into metres."""


_SPINE_BASE, _THORAX, _L_THORAX, _R_THORAX = (
    FLEX20_ROTATING.index(FLEX20.index(name)) for name in ("spine_base", "thorax", "l_thorax", "r_thorax"))
INDEPENDENT_ROTATIONS = tuple(i for i in range(NUM_ROTATING) if i not in (_SPINE_BASE, _L_THORAX, _R_THORAX))
"""Positions in :data:`geometry.FLEX20_ROTATING` of the 11 rotations that the skeleton without duplicate joints
(:func:`tie_duplicates`) leaves free."""


def tie_duplicates(rotations: Float[Array, "*b 14 4"]) -> Float[Array, "*b 14 4"]:
    """The skeleton without FLEX's duplicate joints (paper App. C, the baseline skeleton of Shi et al.): the root
    and the thorax each rigidly carry all their child bones. ``spine_base`` gets the identity (the spine turns
    with the pelvis), ``l_thorax`` and ``r_thorax`` get ``thorax``'s local rotation (they share its parent and
    rest offset, so the shoulders turn with the neck). Quaternions in :data:`geometry.FLEX20_ROTATING` order."""
    rotations = rotations.at[..., _SPINE_BASE, :].set(jnp.array([1.0, 0.0, 0.0, 0.0], rotations.dtype))
    thorax = rotations[..., _THORAX, :]
    return rotations.at[..., _L_THORAX, :].set(thorax).at[..., _R_THORAX, :].set(thorax)


def _unit_quaternion(q: Float[Array, "*b 4"]) -> Float[Array, "*b 4"]:
    """``q / |q|``; a zero or non-finite quaternion becomes the identity (spec section 2)."""
    squared = jnp.sum(q * q, axis=-1, keepdims=True)
    ok = jnp.isfinite(squared) & (squared > 1e-12)
    identity = jnp.zeros_like(q).at[..., 0].set(1.0)
    return jnp.where(ok, q / jnp.sqrt(jnp.where(ok, squared, 1.0)), identity)


def _rest_offsets(bone_lengths: Float[Array, "*b 10"], rest_pose: str) -> Float[Array, "*b 20 3"]:
    """Each FLEX20 joint's offset from its parent (parent frame, metres): rest direction x its bone length."""
    directions = np.asarray(FLEX20_REST_DIRECTIONS[rest_pose])  # (20, 3)
    bone = np.asarray(FLEX20_BONE_OF_JOINT)
    assign = (bone[:, None] == np.arange(NUM_BONES)[None, :]).astype(np.float64)  # (20, 10), zero rows: no bone
    length = jnp.einsum("jb,...b->...j", jnp.asarray(assign, bone_lengths.dtype), bone_lengths)
    directions = jnp.asarray(directions, bone_lengths.dtype).reshape((1,) * (length.ndim - 1) + directions.shape)
    return length[..., None] * directions


@functools.partial(jax.jit, static_argnames="rest_pose")
def flex_forward_kinematics(
    bone_lengths: Float[ArrayLike, "*b 10"],
    rotations: Float[ArrayLike, "*b frames 14 4"],
    root_rotations: Float[ArrayLike, "*b views frames 4"],
    rest_pose: Literal["totem", "tpose"] = "totem",
) -> Float[Array, "*b views frames 20 3"]:
    """FLEX's FK layer: K root-relative camera-frame pose sequences of :data:`geometry.FLEX20` (metres).

    Every view uses the same skeleton ``bone_lengths`` (:data:`geometry.FLEX20_BONES`) and the same local
    ``rotations`` of :data:`geometry.FLEX20_ROTATING` ((w, x, y, z), normalised here; zero -> identity), and
    its own ``root_rotations``; end effectors carry none. Computed in the widest enabled float (the spec's
    float64 chain) by :func:`geometry.forward_kinematics`; the root is at the origin.
    """
    dtype = jnp.result_type(float)
    bone_lengths, rotations, root_rotations = (jnp.asarray(a, dtype) for a in (bone_lengths, rotations, root_rotations))
    views, frames = root_rotations.shape[-3], root_rotations.shape[-2]
    batch = bone_lengths.shape[:-1]
    if rotations.shape != (*batch, frames, NUM_ROTATING, 4) or root_rotations.shape != (*batch, views, frames, 4):
        raise ValueError(f"expected rotations {(*batch, frames, NUM_ROTATING, 4)} and root rotations "
                         f"{(*batch, views, frames, 4)}, got {rotations.shape} and {root_rotations.shape}")
    joint_matrices = geometry.quaternion_to_matrix(_unit_quaternion(rotations))  # (*b, T, 14, 3, 3)
    root_matrices = geometry.quaternion_to_matrix(_unit_quaternion(root_rotations))  # (*b, K, T, 3, 3)
    shape = (*batch, views, frames, FLEX20.num_joints, 3, 3)
    local = jnp.broadcast_to(jnp.eye(3, dtype=dtype), shape)
    local = local.at[..., 0, :, :].set(root_matrices)
    shared = jnp.broadcast_to(joint_matrices[..., None, :, :, :, :], (*batch, views, frames, NUM_ROTATING, 3, 3))
    local = local.at[..., np.asarray(FLEX20_ROTATING), :, :].set(shared)
    offsets = _rest_offsets(bone_lengths, rest_pose)[..., None, None, :, :]
    positions, _ = geometry.forward_kinematics(local, offsets, jnp.zeros(3, dtype), FLEX20)
    return positions


def _adaptive_average(length_in: int, length_out: int) -> np.ndarray:
    """(out, in) matrix of PyTorch's ``adaptive_avg_pool1d``: output i averages inputs
    floor(i n / m) .. ceil((i + 1) n / m) - 1."""
    matrix = np.zeros((length_out, length_in))
    for i in range(length_out):
        start, end = (i * length_in) // length_out, -((-(i + 1) * length_in) // length_out)
        matrix[i, start:end] = 1.0 / (end - start)
    return matrix


def _pool_time(x: Float[Array, "batch time *rest"], length: int) -> Float[Array, "batch length *rest"]:
    """Adaptive average pooling of axis 1 to ``length`` (a fixed averaging matrix: shapes are static)."""
    matrix = jnp.asarray(_adaptive_average(x.shape[1], length), x.dtype)
    return jnp.einsum("st,bt...->bs...", matrix, x)


class Block(nnx.Module):
    """A linear map (1x1 expansion or a convolution) -> batch norm over the features -> leaky ReLU -> dropout."""

    def __init__(self, layer: nnx.Module, features: int, config: FlexConfig, *, rngs: nnx.Rngs) -> None:
        self.layer = layer
        self.norm = nnx.BatchNorm(features, momentum=config.batch_norm_momentum, rngs=rngs)
        self.rate = config.dropout
        self.slope = config.leaky_slope

    def __call__(self, x: Float[Array, "*shape"], key: jax.Array | None) -> Float[Array, "*out"]:
        x = self.norm(self.layer(x), use_running_average=key is None)
        return training.dropout(jax.nn.leaky_relu(x, self.slope), self.rate, key)


class ViewAttention(nnx.Module):
    """Cross-view attention (App. D, Fig. 15): a learned fusion token attends to itself and the K view
    features of a frame through multi-head attention; its output is the frame's fused feature.

    Linear query/key/value projections split into ``heads`` heads, scaled dot-product attention, heads
    concatenated and projected; no residual, norm or feed-forward (as in the official code). Only the fusion
    token's query is computed, since the views' outputs are dropped."""

    def __init__(self, channels: int, heads: int, *, rngs: nnx.Rngs) -> None:
        self.heads = heads
        self.token = nnx.Param(0.02 * jax.random.normal(rngs.params(), (channels,), jnp.float32))
        self.query = nnx.Linear(channels, channels, rngs=rngs)
        self.key = nnx.Linear(channels, channels, rngs=rngs)
        self.value = nnx.Linear(channels, channels, rngs=rngs)
        self.out = nnx.Linear(channels, channels, rngs=rngs)

    def __call__(self, views: Float[Array, "*b views c"]) -> Float[Array, "*b c"]:
        *batch, _, channels = views.shape
        token = jnp.broadcast_to(self.token[...].astype(views.dtype), (*batch, 1, channels))
        tokens = jnp.concatenate([token, views], axis=-2)  # (*b, K + 1, C)
        query = self.query(token).reshape(*batch, self.heads, -1)
        key = self.key(tokens).reshape(*batch, -1, self.heads, query.shape[-1])
        value = self.value(tokens).reshape(*key.shape)
        logits = jnp.einsum("...he,...khe->...hk", query, key) / math.sqrt(query.shape[-1])
        mixed = jnp.einsum("...hk,...khe->...he", jax.nn.softmax(logits, axis=-1), value)
        return self.out(mixed.reshape(*batch, channels))


def _keys(key: jax.Array | None, count: int) -> list[jax.Array | None]:
    return [None] * count if key is None else list(jax.random.split(key, count))


class RotationBranch(nnx.Module):
    """F_Q and E_Q: normalised views ``(B, K, T, 3J)`` -> raw outputs per frame ``(B, T, 4 x 14 + 2)`` (shared
    rotations, contacts) and per view and frame ``(B, K, T, 7)`` (root rotation in 6D, depth).

    The per-view outputs come from each view's own features (after the multi-view convolution, which has seen
    its neighbours; for late fusion after E_Q's per-view convolutions) together with the frame's fused feature,
    through one layer shared by the views: an attention-pooled feature is a weighted sum of the views' values
    under one projection and cannot keep K orientations apart. Permuting the views cyclically permutes them."""

    def __init__(self, config: FlexConfig, *, rngs: nnx.Rngs) -> None:
        c = config.channels
        self.config = config
        self.expand = Block(nnx.Linear(3 * config.input_joints, c, rngs=rngs), c, config, rngs=rngs)
        self.view_kernel = config.view_kernel if config.fusion == "early" else 1
        self.multi_view = nnx.List([
            Block(nnx.Conv(c, c, (k, self.view_kernel), padding="VALID", rngs=rngs), c, config, rngs=rngs)
            for k in config.stage1_kernels])
        self.fusion = ViewAttention(c, config.heads, rngs=rngs)
        self.temporal = nnx.List([
            Block(nnx.Conv(c, c, (k,), padding="VALID", rngs=rngs), c, config, rngs=rngs)
            for k in config.stage2_kernels])
        # Zero-initialised, so that an untrained model predicts the standing pose of Flex.__call__ rather than
        # random rotations around it.
        self.shrink = nnx.Linear(c, 4 * NUM_ROTATING + 2, kernel_init=nnx.initializers.zeros, rngs=rngs)
        self.view_head = nnx.Linear(2 * c, 7, kernel_init=nnx.initializers.zeros, rngs=rngs)

    def __call__(self, x: Float[Array, "B K T F"], key: jax.Array | None
                 ) -> tuple[Float[Array, "B T O"], Float[Array, "B K T 7"]]:
        frames, views = x.shape[2], x.shape[1]
        keys = _keys(key, 1 + len(self.multi_view) + len(self.temporal))
        x = jnp.swapaxes(self.expand(x, keys[0]), 1, 2)  # (B, T, K, C)
        pad = self.view_kernel // 2
        wrapped = jnp.take(x, np.arange(-pad, views + self.view_kernel - 1 - pad) % views, axis=2)
        x = sum(_pool_time(block(wrapped, k), frames) for block, k in zip(self.multi_view, keys[1:]))

        def temporal(x):
            return sum(_pool_time(block(x, k), frames)
                       for block, k in zip(self.temporal, keys[1 + len(self.multi_view):]))

        if self.config.fusion == "late":
            channels = x.shape[-1]
            per_view = temporal(jnp.swapaxes(x, 1, 2).reshape(-1, frames, channels))  # (B K, T, C): E_Q per view
            per_view = jnp.swapaxes(per_view.reshape(-1, views, frames, channels), 1, 2)  # (B, T, K, C)
            fused = self.fusion(per_view)
        else:
            per_view = x
            fused = temporal(self.fusion(x))  # (B, T, C)
        both = jnp.concatenate([per_view, jnp.broadcast_to(fused[:, :, None], per_view.shape)], axis=-1)
        return self.shrink(fused), jnp.swapaxes(self.view_head(both), 1, 2)


class BoneBranch(nnx.Module):
    """F_S and E_S: normalised views ``(B, K, T, 3J)`` -> one symmetric skeleton ``(B, 10)`` (metres)."""

    def __init__(self, config: FlexConfig, *, rngs: nnx.Rngs) -> None:
        c = config.channels
        self.expand = Block(nnx.Linear(3 * config.input_joints, c, rngs=rngs), c, config, rngs=rngs)
        self.temporal = nnx.List([
            Block(nnx.Conv(c, c, (k,), padding="VALID", rngs=rngs), c, config, rngs=rngs)
            for _ in range(config.bone_stages) for k in config.bone_kernels])
        self.fusion = ViewAttention(c, config.heads, rngs=rngs)
        self.shrink = nnx.Linear(c, NUM_BONES, rngs=rngs)

    def __call__(self, x: Float[Array, "B K T F"], key: jax.Array | None) -> Float[Array, "B 10"]:
        keys = _keys(key, 1 + len(self.temporal))
        x = self.expand(x, keys[0])  # (B, K, T, C): the temporal convolutions run per view
        for block, k in zip(self.temporal, keys[1:]):
            x = block(x, k)
        fused = self.fusion(jnp.swapaxes(x, 1, 2))  # (B, T', C)
        raw = self.shrink(jnp.max(fused, axis=1))
        return jnp.asarray(_REFERENCE_BONES_M, raw.dtype)[None, :] * jnp.exp(raw)


class Flex(nnx.Module):
    """FLEX: K views of 2D joints and confidences -> one motion (rotations, skeleton) and K camera-frame poses.

    See the module docstring for the architecture, the camera model and the training mode. Parameters are
    float32 (NNX default); FK runs in the widest enabled float.
    """

    def __init__(self, config: FlexConfig, *, rngs: nnx.Rngs) -> None:
        self.config = config
        self.rotation_branch = RotationBranch(config, rngs=rngs)
        self.bone_branch = BoneBranch(config, rngs=rngs)

    def __call__(
        self,
        points_2d: Float[ArrayLike, "batch views frames joints 2"],
        confidences: Float[ArrayLike, "batch views frames joints"],
        *,
        key: jax.Array | None = None,
    ) -> FlexOutputs:
        """Predict from pixels (any image coordinates: only their per-view normalisation is used) and
        confidences in [0, 1] (0 = missing). ``key``: training mode (see the module docstring)."""
        config = self.config
        points_2d, confidences = jnp.asarray(points_2d), jnp.asarray(confidences)
        expected = (config.views, config.input_joints)
        if points_2d.ndim != 5 or (points_2d.shape[1], points_2d.shape[3]) != expected or points_2d.shape[-1] != 2:
            raise ValueError(f"points_2d must be (batch, {config.views} views, frames, {config.input_joints} joints, "
                             f"2), got {points_2d.shape}")
        if confidences.shape != points_2d.shape[:-1]:
            raise ValueError(f"confidences must be {points_2d.shape[:-1]}, got {confidences.shape}")
        batch, views, frames = points_2d.shape[:3]
        if frames < config.min_frames:
            raise ValueError(f"FLEX needs at least {config.min_frames} frames with this config, got {frames}")

        normalised = normalise_2d(points_2d, confidences, INPUT_ROOT)
        dtype = self.rotation_branch.shrink.kernel.dtype
        x = normalised.features.reshape(batch, views, frames, -1).astype(dtype)
        rotation_key, bone_key = _keys(key, 2)
        raw, per_view = self.rotation_branch(x, rotation_key)
        bone_lengths = self.bone_branch(x, bone_key)

        # Quaternions are offsets from a person standing upright and facing the camera (as HMR starts from the
        # mean parameters): from the rest pose (the totem's arms point up, the camera's y axis down) every
        # real pose would be about a half turn away, where the position loss has no gradient.
        rotations = raw[..., : 4 * NUM_ROTATING].reshape(batch, frames, NUM_ROTATING, 4) + jnp.asarray(
            _standing_rotations(config.rest_pose), raw.dtype)[None, None]
        if not config.duplicate_joints:
            rotations = tie_duplicates(rotations)
        contacts = jax.nn.sigmoid(raw[..., 4 * NUM_ROTATING: 4 * NUM_ROTATING + 2])
        # The root rotation goes round every heading relative to a camera, a loop that no continuous map can
        # follow with quaternions (q and -q, Zhou et al. 2019): it is predicted in the continuous 6D form.
        root_matrices = geometry.rotation_6d_to_matrix(
            per_view[..., :6] + jnp.asarray(_FACING_CAMERA_6D, raw.dtype).reshape(1, 1, 1, 6))
        root_rotations = jnp.moveaxis(
            _data.sign_continuous(jnp.moveaxis(geometry.matrix_to_quaternion(root_matrices), 2, 0)), 0, 2)
        depth = jax.nn.softplus(per_view[..., 6])

        relative = flex_forward_kinematics(bone_lengths, rotations, root_rotations, config.rest_pose)
        # Outputs in FK's float, so that they describe its poses exactly.
        rotations, root_rotations, depth = (a.astype(relative.dtype) for a in (rotations, root_rotations, depth))
        root_xy = normalised.features[..., INPUT_ROOT, :2].astype(relative.dtype)  # (B, K, T, 2)
        root_position = jnp.concatenate([root_xy * depth[..., None], depth[..., None]], axis=-1)
        return FlexOutputs(
            rotations=_unit_quaternion(rotations), root_rotations=_unit_quaternion(root_rotations),
            contacts=contacts, root_depth=depth, root_position=root_position, bone_lengths=bone_lengths,
            joints_relative=relative, joints=relative + root_position[..., None, :], scale=normalised.scale,
            centre=normalised.centre,
        )


class RotationDiscriminator(nnx.Module):
    """Independent discriminators D_j, one per joint (paper Sec. 3.1), vectorised over the joints.

    Each takes a joint's sequence of quaternion differences ``(T', 4)``: a temporal convolution
    (``kernel``, 4 -> ``channels``) + ReLU -> a 1x1 convolution to one channel + leaky ReLU (slope 0.2) ->
    adaptive average pool to ``pooled`` frames -> a linear layer to one score -> sigmoid. This is the official
    ``rotation_D`` with weights of its own per joint instead of channels mixing all joints, and a leaky second
    activation: with a ReLU on the single channel, a D_j whose channel turns negative everywhere outputs the
    constant sigmoid(bias) with no gradient to anything else. Trained that way every D_j sat at 0.5."""

    def __init__(self, joints: int, channels: int, kernel: int, pooled: int, *, rngs: nnx.Rngs) -> None:
        self.kernel = kernel
        self.pooled = pooled
        init = nnx.initializers.lecun_normal(in_axis=1, out_axis=2, batch_axis=(0,))
        self.conv_in = nnx.Param(init(rngs.params(), (joints, 4 * kernel, channels), jnp.float32))
        self.conv_in_bias = nnx.Param(jnp.zeros((joints, channels), jnp.float32))
        self.conv_out = nnx.Param(init(rngs.params(), (joints, channels, 1), jnp.float32)[..., 0])
        self.conv_out_bias = nnx.Param(jnp.zeros((joints,), jnp.float32))
        self.head = nnx.Param(init(rngs.params(), (joints, pooled, 1), jnp.float32)[..., 0])
        self.head_bias = nnx.Param(jnp.zeros((joints,), jnp.float32))

    def __call__(self, deltas: Float[Array, "*b T J 4"]) -> Float[Array, "*b J"]:
        *batch, frames, joints, _ = deltas.shape
        if frames < self.kernel:
            raise ValueError(f"D's temporal kernel needs {self.kernel} differences, got {frames} (too few frames)")
        deltas = deltas.reshape(-1, frames, joints, 4)
        out = frames - self.kernel + 1
        windows = jnp.stack([deltas[:, i: i + out] for i in range(self.kernel)], axis=-2)  # (N, T'', J, k, 4)
        windows = windows.reshape(*windows.shape[:3], -1).astype(self.conv_in.dtype)
        hidden = jnp.einsum("ntji,jic->ntjc", windows, self.conv_in[...]) + self.conv_in_bias[...][None, None]
        score = jnp.einsum("ntjc,jc->ntj", jax.nn.relu(hidden), self.conv_out[...]) + self.conv_out_bias[...][None, None]
        score = jax.nn.leaky_relu(score, 0.2)
        pooled = _pool_time(score, self.pooled)  # (N, pooled, J)
        logit = jnp.einsum("npj,jp->nj", pooled, self.head[...]) + self.head_bias[...][None]
        return jax.nn.sigmoid(logit).reshape(*batch, joints)


class Discriminator(nnx.Module):
    """D (Eq. 5): D_j for the 14 shared joints (the 11 free ones of a skeleton without duplicate joints:
    :data:`INDEPENDENT_ROTATIONS`), and D_0 applied to every view's root rotation."""

    def __init__(self, config: FlexConfig, *, rngs: nnx.Rngs) -> None:
        self.delta = config.rotation_delta
        self.judged = tuple(range(NUM_ROTATING)) if config.duplicate_joints else INDEPENDENT_ROTATIONS
        sizes = (config.discriminator_channels, config.discriminator_kernel, config.discriminator_frames)
        self.joints = RotationDiscriminator(len(self.judged), *sizes, rngs=rngs)
        self.root = RotationDiscriminator(1, *sizes, rngs=rngs)

    def __call__(
        self, rotations: Float[ArrayLike, "batch frames 14 4"], root_rotations: Float[ArrayLike, "batch views frames 4"]
    ) -> tuple[Float[Array, "batch judged"], Float[Array, "batch views"]]:
        """Scores in (0, 1) (1 = natural) of the temporal differences ``q[t + delta] - q[t]`` of unit quaternions,
        for the joints D judges (``judged``, positions in :data:`geometry.FLEX20_ROTATING`) and the roots."""
        delta = self.delta
        rotations, root_rotations = jnp.asarray(rotations)[:, :, list(self.judged)], jnp.asarray(root_rotations)
        joint_deltas = rotations[:, delta:] - rotations[:, :-delta]
        root_deltas = (root_rotations[:, :, delta:] - root_rotations[:, :, :-delta])[..., None, :]
        return self.joints(joint_deltas), self.root(root_deltas)[..., 0]


def predict(
    model: Flex, points_2d: Float[ArrayLike, "batch views frames joints 2"],
    confidences: Float[ArrayLike, "batch views frames joints"],
) -> FlexOutputs:
    """``model(points_2d, confidences)``, deterministic and compiled: one compilation per model structure and input
    shape serves every call (called directly, the network runs op by op, several times slower on a CPU)."""
    graphdef, state = nnx.split(model)
    return _predict(graphdef, state, jnp.asarray(points_2d), jnp.asarray(confidences))


@functools.partial(jax.jit, static_argnums=0)
def _predict(graphdef: nnx.GraphDef, state: Any, points_2d: jax.Array, confidences: jax.Array) -> FlexOutputs:
    return nnx.merge(graphdef, state)(points_2d, confidences)


def averaged_monocular(model: Flex, batch: _data.Batch) -> jax.Array:
    """Table 5c's averaged monocular fusion: a 1-view ``model`` runs on each view alone; the views' shared joint
    rotations (sign-aligned quaternion mean) and bone lengths are averaged, each view keeps its own root rotation.
    Returns the FLEX20 camera-frame poses ``(batch, views, frames, 20, 3)`` (metres, root-relative)."""
    if model.config.views != 1:
        raise ValueError(f"averaged monocular fusion needs a 1-view model, got {model.config.views} views")
    views = batch.points_2d.shape[1]
    outputs = [predict(model, batch.points_2d[:, k:k + 1], batch.confidences[:, k:k + 1]) for k in range(views)]
    rotations = jnp.stack([o.rotations for o in outputs], axis=1)  # (B, K, T, 14, 4)
    sign = jnp.where(jnp.sum(rotations * rotations[:, :1], axis=-1, keepdims=True) < 0, -1.0, 1.0)
    mean_rotation = jnp.mean(sign * rotations, axis=1)
    bones = jnp.mean(jnp.stack([o.bone_lengths for o in outputs], axis=1), axis=1)
    roots = jnp.concatenate([o.root_rotations for o in outputs], axis=1)
    return flex_forward_kinematics(bones, mean_rotation, roots, model.config.rest_pose)

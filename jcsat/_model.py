"""The JCSAT network (Jiang et al., TVCG 2025, Sec. 3.2-3.3 and supplementary Sec. 2) in Flax NNX.

Input: one person's Joint Cloud window, ``points`` ``(N, P, M, J, 3)`` (frames, view pairs, candidate slots,
BODY25 joint types; metres, centred on the person, 0 where padded) with ``mask`` ``(N, P, M, J)``, as built by
:func:`association.person_joint_cloud` and :func:`association.window_frames`. Output: Shelf15 joints
``(N, 15, 3)`` in the same centred frame (:data:`geometry.SHELF15` order: Shelf14 plus the mid-hip).

Pipeline (Fig. 3):

1. **Trajectory branch** (Eq. 3, 7): for each (view pair, joint) a sequence of ``N x M`` candidate tokens
   ``Linear(xyz) + PosEnc(xyz) + PosEnc(frame)`` -> ViT -> Linear -> ReLU -> T-OTAP to ``N`` tokens.
2. **Structure branch** (Eq. 4, 8): for each (view pair, frame) a sequence of ``J x M`` tokens with
   ``PosEnc(joint type)`` -> same structure, separate weights -> S-OTAP to ``J`` tokens.
3. **Cross-embedding**: both rearranged to ``(N, J, P, D)`` and summed.
4. **View branch** (Eq. 5, 9): for each (frame, joint) the ``P`` tokens ``Linear(token) + PosEnc(view pair)``
   -> ViT -> ReLU -> V-OTAP over all view pairs to one token -> Linear head to xyz: BODY25 ``(N, 25, 3)``.
5. **Joint-type conversion** (Sec. 3.2.2, supp. 2.1): ``Linear(25 -> 20) -> Linear(20 -> 15)`` over the joint
   axis, no activation.

Masking (the official code's; ``docs/jcsat.md``): padded keys are excluded inside the softmax, OTAP gives padded
tokens no mass, and a fully padded sequence aggregates to zeros. A view-pair token of a (frame, joint) is masked
in the view branch when it carries nothing, i.e. when neither its trajectory sequence (same view pair and joint,
any frame) nor its structure sequence (same view pair and frame, any joint) holds a candidate: such a token is
exactly zero. A token whose own (frame, joint) slot is empty but whose sequences are not stays valid, because
filling such gaps from the trajectory and the skeleton is what the two branches are for. A (frame, joint) with
no informative view pair at all gets the zero V-OTAP output and a finite, data-independent prediction.

Random candidate masking (Sec. 3.2.3) runs only when a PRNG ``key`` is passed (training): one ratio per batch
from ``config.mask_ratio``, drawn separately for the trajectory and the structure inputs, each valid candidate
then dropped with that probability.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Literal

import jax
import jax.numpy as jnp
from flax import nnx
from jaxtyping import Array, ArrayLike, Bool, Float

import geometry
import training
from geometry import BODY25, SHELF15

from ._otap import OTAP

__all__ = ["CONFIGS", "JCSAT", "JCSATConfig", "SHIPPED_MODEL", "aggregation_variant", "load_model", "parameter_count"]


@dataclasses.dataclass(frozen=True)
class JCSATConfig:
    """Every hyperparameter of :class:`JCSAT`. The trajectory and structure encoders share these sizes.

    The Fourier encodings have no size of their own: Eq. 3-5 add ``PosEnc`` to the projected token, so an
    encoding has as many features as that token (``dim // 2`` frequencies, each as cos and sin; ``view_dim // 2``
    in the view branch), hence both widths must be even.
    """

    dim: int
    """Token width of the trajectory/structure ViTs."""
    depth: int
    heads: int
    head_dim: int
    mlp_dim: int
    out_dim: int
    """Width after the encoders' Linear + ReLU: T/S-OTAP features and the cross-embedding."""
    view_dim: int
    """Token width of the view ViT (V-OTAP features and the head's input)."""
    view_depth: int
    view_heads: int
    view_head_dim: int
    view_mlp_dim: int
    fourier_sigma: float = 1.0
    """Standard deviation of the fixed Gaussian frequencies ``B`` (Eq. 6)."""
    otap_epsilon: float = 0.1
    otap_iterations: int = 100
    otap_position_filter: Literal["hard", "gaussian"] | None = None
    """T/S-OTAP position filter, an ablation only (spec section 5 item 6); V-OTAP never filters."""
    otap_filter_sigma: float = 0.1
    trajectory_selective: bool = True
    """OT aggregation (T-OTAP) if True, else the non-selective masked mean (see :func:`aggregation_variant`)."""
    structure_selective: bool = True
    view_selective: bool = True
    mask_ratio: tuple[float, float] = (0.0, 0.4)
    """Training-only candidate masking: the ratio is drawn from ``U(low, high)`` per batch."""
    dropout: float = 0.0
    """Training-only dropout on every ViT residual branch (attention and MLP outputs)."""
    frames: int = 10
    """Window length N."""
    view_pairs: int = 10
    candidates: int = 4
    """Candidate slots M per (frame, view pair, joint)."""
    joints: int = 25
    """BODY25 joint types J."""
    conversion_hidden: int = 20
    candidate_anchor: bool = False
    """Not in the paper: add to each BODY25 joint a learned softmax selection of its candidates over all view
    pairs and slots (scores from the structure encoder's candidate features), so that the head regresses a
    correction to a chosen candidate instead of an absolute position; the head starts at zero. For the ``"cpu"``
    model (36 minutes of training on 2 cores) it raised synthetic validation PCP at step 400 from 27 % to 50 %;
    the paper's configurations leave it off."""
    output_joints: int = 15
    """Shelf15."""

    def __post_init__(self) -> None:
        values = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        if small := [name for name, v in values.items() if type(v) is int and v < 1]:
            raise ValueError(f"sizes must be >= 1: {small}")
        if self.dim % 2 or self.view_dim % 2:
            raise ValueError(f"dim and view_dim must be even (Fourier cos/sin pairs), got {self.dim}, {self.view_dim}")
        low, high = self.mask_ratio
        if not 0.0 <= low <= high < 1.0:
            raise ValueError(f"mask_ratio must satisfy 0 <= low <= high < 1, got {self.mask_ratio}")
        if not 0.0 <= self.dropout < 1.0:
            raise ValueError(f"dropout must be in [0, 1), got {self.dropout}")


CONFIGS: dict[str, JCSATConfig] = {
    # T/S encoders: 16 heads of 16 (supp. Table 2). Table 10's "Hidden Dim" (128/256/512) is the T/S output
    # width and MLP width; the ViT token width is the official code's (128 for medium, 256 for large). The view
    # encoder (8 heads of 4, depth 8) works at the cross-embedding width, as in the official code. "small" is
    # not in the code: ViT width 128 is the choice that reproduces Table 10's 1.33 M parameters per encoder
    # (width 64 would give 0.67 M), and its view MLP is medium's. One T encoder (with its T-OTAP) has
    # 1.336 / 3.198 / 8.559 M parameters.
    "small": JCSATConfig(
        dim=128, depth=8, heads=16, head_dim=16, mlp_dim=128, out_dim=128,
        view_dim=128, view_depth=8, view_heads=8, view_head_dim=4, view_mlp_dim=32,
    ),
    # The released model (official code's 'medium').
    "medium": JCSATConfig(
        dim=128, depth=16, heads=16, head_dim=16, mlp_dim=256, out_dim=256,
        view_dim=256, view_depth=8, view_heads=8, view_head_dim=4, view_mlp_dim=32,
    ),
    "large": JCSATConfig(
        dim=256, depth=16, heads=16, head_dim=16, mlp_dim=512, out_dim=512,
        view_dim=512, view_depth=8, view_heads=8, view_head_dim=4, view_mlp_dim=128,
    ),
    # For CPU experiments and tests. A batch of 8 windows holds 64k trajectory and 64k structure tokens (plus
    # 20k view tokens), and on CPU the exponentials cost as much as the matmuls (about 2.7 ns each here): the
    # attention's grow with heads x sequence length^2 (100 tokens per structure sequence), the Sinkhorn's with
    # iterations x n x p (100 x 25 for S-OTAP), and the unrolled Sinkhorn dominates the backward pass. Hence
    # width 32, two layers with a single 16-wide head (two heads of 8 cost twice the exponentials for the same
    # parameters) and 10 Sinkhorn iterations: about 0.3 s forward and 1-1.5 s forward+backward for 8 windows
    # on 2 shared cores. At epsilon 0.1 and initialisation-scale features, 10 iterations leave the plan's row
    # marginals off by a median 0.01-13% (columns are exact, so outputs stay weighted averages); the model
    # learns with the plan it has. The candidate anchor (not in the paper) is on.
    "cpu": JCSATConfig(
        dim=32, depth=2, heads=1, head_dim=16, mlp_dim=64, out_dim=32,
        view_dim=32, view_depth=1, view_heads=2, view_head_dim=8, view_mlp_dim=32,
        otap_iterations=10, candidate_anchor=True,
    ),
    # The shipped model: "cpu" twice as wide and one layer deeper in each encoder, with the same single-head
    # attention (the same number of exponentials per token pair); trained on a GPU (jcsat.TRAIN_CONFIGS["gpu"]).
    "cpu_wide": JCSATConfig(
        dim=64, depth=3, heads=1, head_dim=32, mlp_dim=128, out_dim=64,
        view_dim=64, view_depth=2, view_heads=2, view_head_dim=16, view_mlp_dim=64,
        otap_iterations=10, candidate_anchor=True,
    ),
}
"""Named configurations (supp. Table 10 and the official code; ``docs/jcsat.md``)."""

_VARIANTS = {
    # Table 7: which of (T-OTAP, S-OTAP, V-OTAP) keep the selective OT aggregation.
    "otap_a": (False, False, False),
    "otap_b": (False, False, True),
    "otap_c": (True, True, False),
}


def aggregation_variant(config: JCSATConfig, name: str) -> JCSATConfig:
    """``config`` with Table 7's aggregation ablation ``name``: "otap_a", "otap_b" or "otap_c".

    The non-selective aggregation that replaces an OTAP (Sec. 3.3, Remark 2) pools every candidate inclusively,
    trusting the encoder's self-attention to have weighed them: here the **mean of the valid tokens of each
    output's group** (the ``M`` candidates of a frame for T, of a joint type for S, the ``P`` view pairs for V),
    a parameter-free average where OTAP learns a peaked transport plan. It keeps the outputs' meaning (token n =
    frame n, token i = joint i), and a fully padded group gives zeros, as OTAP does.
    """
    if name not in _VARIANTS:
        raise ValueError(f"unknown aggregation variant {name!r}; expected one of {sorted(_VARIANTS)}")
    trajectory, structure, view = _VARIANTS[name]
    return dataclasses.replace(
        config, trajectory_selective=trajectory, structure_selective=structure, view_selective=view
    )


def parameter_count(model: nnx.Module) -> int:
    """Number of trainable scalars (``nnx.Param``); works on real and on ``nnx.eval_shape`` models."""
    return sum(math.prod(leaf.shape) for leaf in jax.tree.leaves(nnx.state(model, nnx.Param)))


class FourierBasis(nnx.Variable):
    """The fixed random frequencies of a Fourier encoding: drawn at initialisation, never trained."""


class FourierEncoding(nnx.Module):
    """Eq. 6: ``PosEnc(x) = [cos(2 pi B x), sin(2 pi B x)]`` with a fixed ``B ~ N(0, sigma^2)``."""

    def __init__(self, in_features: int, features: int, sigma: float, *, rngs: nnx.Rngs) -> None:
        self.basis = FourierBasis(sigma * jax.random.normal(rngs.params(), (in_features, features // 2), jnp.float32))

    def __call__(self, x: Float[Array, "*batch i"]) -> Float[Array, "*batch f"]:
        angle = 2.0 * jnp.pi * jnp.einsum("...i,if->...f", x, self.basis[...].astype(x.dtype))
        return jnp.concatenate([jnp.cos(angle), jnp.sin(angle)], axis=-1)


class ViTBlock(nnx.Module):
    """Pre-LN Transformer block (supp. Sec. 2): ``x + MSA(LN(x))``, then ``x + MLP(LN(x))`` with GELU.

    The attention has ``heads`` heads of width ``head_dim`` (their total need not equal ``dim``), a bias-free
    query/key/value projection and a biased output projection. Padded keys are replaced by the most negative
    float before the softmax (spec section 5 item 3), which equals an additive -inf for any query with a valid
    key and leaves a query with none a finite uniform average instead of NaN.
    """

    def __init__(
        self, dim: int, heads: int, head_dim: int, mlp_dim: int, dropout: float, *, rngs: nnx.Rngs
    ) -> None:
        self.heads = heads
        self.dropout = dropout
        self.attention_norm = nnx.LayerNorm(dim, rngs=rngs)
        self.qkv = nnx.Linear(dim, 3 * heads * head_dim, use_bias=False, rngs=rngs)
        self.attention_out = nnx.Linear(heads * head_dim, dim, rngs=rngs)
        self.mlp_norm = nnx.LayerNorm(dim, rngs=rngs)
        self.mlp_in = nnx.Linear(dim, mlp_dim, rngs=rngs)
        self.mlp_out = nnx.Linear(mlp_dim, dim, rngs=rngs)

    def attention(self, x: Float[Array, "*batch n d"], mask: Bool[Array, "*batch n"]) -> Float[Array, "*batch n d"]:
        """Masked multi-head self-attention; ``mask`` marks the valid keys."""
        qkv = self.qkv(x).reshape(*x.shape[:-1], 3, self.heads, -1)
        query, key, value = qkv[..., 0, :, :], qkv[..., 1, :, :], qkv[..., 2, :, :]
        logits = jnp.einsum("...qhe,...khe->...hqk", query, key) / math.sqrt(query.shape[-1])
        logits = jnp.where(mask[..., None, None, :], logits, jnp.finfo(logits.dtype).min)
        mixed = jnp.einsum("...hqk,...khe->...qhe", jax.nn.softmax(logits, axis=-1), value)
        return self.attention_out(mixed.reshape(*x.shape[:-1], -1))

    def __call__(
        self, x: Float[Array, "*batch n d"], mask: Bool[Array, "*batch n"], key: jax.Array | None = None
    ) -> Float[Array, "*batch n d"]:
        attention_key, mlp_key = (None, None) if key is None else jax.random.split(key)
        x = x + training.dropout(self.attention(self.attention_norm(x), mask), self.dropout, attention_key)
        hidden = jax.nn.gelu(self.mlp_in(self.mlp_norm(x)), approximate=False)
        return x + training.dropout(self.mlp_out(hidden), self.dropout, mlp_key)


class ViT(nnx.Module):
    """A stack of :class:`ViTBlock` (no final norm: the supplementary places LN only before MSA and FFN)."""

    def __init__(
        self, dim: int, depth: int, heads: int, head_dim: int, mlp_dim: int, dropout: float, *, rngs: nnx.Rngs
    ) -> None:
        self.blocks = nnx.List([ViTBlock(dim, heads, head_dim, mlp_dim, dropout, rngs=rngs) for _ in range(depth)])

    def __call__(
        self, x: Float[Array, "*batch n d"], mask: Bool[Array, "*batch n"], key: jax.Array | None = None
    ) -> Float[Array, "*batch n d"]:
        for index, block in enumerate(self.blocks):
            x = block(x, mask, None if key is None else jax.random.fold_in(key, index))
        return x


class MaskedMean(nnx.Module):
    """Non-selective aggregation: ``n = groups x size`` tokens -> the mean of each group's valid tokens.

    A group with no valid token gives zeros.
    """

    def __init__(self, groups: int) -> None:
        self.groups = groups

    def __call__(self, tokens: Float[Array, "*batch n d"], mask: Bool[Array, "*batch n"]) -> Float[Array, "*batch p d"]:
        grouped = tokens.reshape(*tokens.shape[:-2], self.groups, -1, tokens.shape[-1])
        valid = mask.reshape(*mask.shape[:-1], self.groups, -1)
        total = jnp.sum(jnp.where(valid[..., None], grouped, 0.0), axis=-2)
        count = jnp.sum(valid, axis=-1, keepdims=True).astype(tokens.dtype)
        return total / jnp.maximum(count, 1.0)


def _aggregation(
    config: JCSATConfig, features: int, outputs: int, selective: bool, filtered: bool, *, rngs: nnx.Rngs
) -> OTAP | MaskedMean:
    """An OTAP (Sec. 3.3, Eq. 10) with ``outputs`` tokens, or its non-selective stand-in."""
    if not selective:
        return MaskedMean(outputs)
    return OTAP(
        features, outputs, epsilon=config.otap_epsilon, iterations=config.otap_iterations,
        position_filter=config.otap_position_filter if filtered else None, sigma=config.otap_filter_sigma,
        rngs=rngs,
    )


class CandidateEncoder(nnx.Module):
    """T-Enc + T-OTAP (Eq. 3, 7) or S-Enc + S-OTAP (Eq. 4, 8): ``K x M`` candidates -> ``K`` tokens.

    ``K`` is the indexed axis (frames for T, joint types for S) whose index is Fourier-encoded; the candidate
    slot itself gets no encoding, so the output does not depend on the order of the slots (unless the
    ablation's position filter is on). A token is ``Linear(xyz) + PosEnc(xyz) + PosEnc(k)``.
    """

    def __init__(self, config: JCSATConfig, groups: int, selective: bool, *, rngs: nnx.Rngs) -> None:
        c = config
        self.embed = nnx.Linear(3, c.dim, rngs=rngs)
        self.position = FourierEncoding(3, c.dim, c.fourier_sigma, rngs=rngs)
        self.index = FourierEncoding(1, c.dim, c.fourier_sigma, rngs=rngs)
        self.encoder = ViT(c.dim, c.depth, c.heads, c.head_dim, c.mlp_dim, c.dropout, rngs=rngs)
        self.out = nnx.Linear(c.dim, c.out_dim, rngs=rngs)
        self.aggregate = _aggregation(c, c.out_dim, groups, selective, filtered=True, rngs=rngs)

    def features(
        self, points: Float[Array, "*batch K M 3"], mask: Bool[Array, "*batch K M"], key: jax.Array | None = None
    ) -> Float[Array, "*batch KM D"]:
        """The encoder's output for every candidate, ``(K * M, D)`` (after Linear + ReLU), before aggregation."""
        *batch, k, m, _ = points.shape
        index_code = self.index(jnp.arange(k, dtype=points.dtype)[:, None])
        tokens = self.embed(points) + self.position(points)
        tokens = tokens + index_code.reshape((1,) * len(batch) + (k, 1, -1))
        tokens = tokens.reshape(*batch, k * m, -1)
        return jax.nn.relu(self.out(self.encoder(tokens, mask.reshape(*batch, k * m), key)))

    def __call__(
        self, points: Float[Array, "*batch K M 3"], mask: Bool[Array, "*batch K M"], key: jax.Array | None = None
    ) -> Float[Array, "*batch K D"]:
        return self.aggregate(self.features(points, mask, key), mask.reshape(*mask.shape[:-2], -1))


class ViewEncoder(nnx.Module):
    """V-Enc + V-OTAP (Eq. 5, 9): the ``P`` cross-embedding tokens of one (frame, joint) -> one token.

    A token is ``Linear(cross-embedding) + PosEnc(view pair)``; V-OTAP pools all view pairs (no filter).
    """

    def __init__(self, config: JCSATConfig, *, rngs: nnx.Rngs) -> None:
        c = config
        self.embed = nnx.Linear(c.out_dim, c.view_dim, rngs=rngs)
        self.index = FourierEncoding(1, c.view_dim, c.fourier_sigma, rngs=rngs)
        self.encoder = ViT(
            c.view_dim, c.view_depth, c.view_heads, c.view_head_dim, c.view_mlp_dim, c.dropout, rngs=rngs
        )
        self.aggregate = _aggregation(c, c.view_dim, 1, c.view_selective, filtered=False, rngs=rngs)

    def __call__(
        self, tokens: Float[Array, "*batch P D"], mask: Bool[Array, "*batch P"], key: jax.Array | None = None
    ) -> Float[Array, "*batch E"]:
        *batch, p, _ = tokens.shape
        index_code = self.index(jnp.arange(p, dtype=tokens.dtype)[:, None])
        x = self.embed(tokens) + index_code.reshape((1,) * len(batch) + (p, -1))
        features = jax.nn.relu(self.encoder(x, mask, key))
        return self.aggregate(features, mask)[..., 0, :]


def _drop_candidates(
    key: jax.Array, mask: Bool[Array, "*shape"], ratio_range: tuple[float, float]
) -> Bool[Array, "*shape"]:
    """Sec. 3.2.3: draw one ratio ``r ~ U(ratio_range)``, then drop each valid candidate with probability ``r``."""
    ratio_key, drop_key = jax.random.split(key)
    ratio = jax.random.uniform(ratio_key, (), minval=ratio_range[0], maxval=ratio_range[1])
    return mask & (jax.random.uniform(drop_key, mask.shape) >= ratio)


class JCSAT(nnx.Module):
    """Joint Cloud Selection and Aggregation Transformer: a person's Joint Cloud window -> Shelf15 joints.

    See the module docstring for the pipeline and the masking rules. Parameters are float32 (NNX default);
    the points are cast to the parameters' dtype.
    """

    def __init__(self, config: JCSATConfig, *, rngs: nnx.Rngs) -> None:
        self.config = config
        self.trajectory = CandidateEncoder(config, config.frames, config.trajectory_selective, rngs=rngs)
        self.structure = CandidateEncoder(config, config.joints, config.structure_selective, rngs=rngs)
        self.view = ViewEncoder(config, rngs=rngs)
        zeros = nnx.initializers.zeros_init()
        self.head = (nnx.Linear(config.view_dim, 3, kernel_init=zeros, bias_init=zeros, rngs=rngs)
                     if config.candidate_anchor else nnx.Linear(config.view_dim, 3, rngs=rngs))
        self.anchor_score = nnx.Linear(config.out_dim, 1, rngs=rngs) if config.candidate_anchor else None
        self.convert_hidden = nnx.Linear(config.joints, config.conversion_hidden, rngs=rngs)
        self.convert_out = nnx.Linear(config.conversion_hidden, config.output_joints, rngs=rngs)
        if (config.joints, config.output_joints) == (BODY25.num_joints, SHELF15.num_joints) and (
                config.conversion_hidden >= SHELF15.num_joints):
            self._start_conversion_from_the_head_rule()

    def _start_conversion_from_the_head_rule(self) -> None:
        """Initialise the learned conversion at the hand-made BODY25 -> Shelf15 map (the linear part of
        :func:`geometry.to_shelf15`): the first 15 hidden units carry the 15 output joints, the rest and the
        biases start near zero (0.01 x their random initialisation, so that they still learn). A random
        initialisation instead mixes all 25 joint types into every output, which a short training run spends
        most of its steps undoing."""
        num = SHELF15.num_joints
        matrix = geometry.shelf15_conversion_matrix(BODY25)  # (15, 25)
        hidden, out = self.convert_hidden.kernel, self.convert_out.kernel
        hidden[...] = (0.01 * hidden[...]).at[:, :num].set(jnp.asarray(matrix.T, hidden.dtype))
        out[...] = (0.01 * out[...]).at[:num, :].set(jnp.eye(num, dtype=out.dtype))

    def body25(
        self,
        points: Float[ArrayLike, "*batch N P M J 3"],
        mask: Bool[ArrayLike, "*batch N P M J"],
        *,
        key: jax.Array | None = None,
        last_frame_only: bool = False,
    ) -> Float[Array, "*batch n J 3"]:
        """The prediction head's BODY25 joints ``(N, J, 3)`` (metres, input frame), before the type conversion.

        ``key`` (training only) enables the random candidate masking and dropout. ``last_frame_only``
        returns ``(1, J, 3)``, the last frame's joints, equal to the full output's last frame: the
        structure and view encoders work per frame, so only the trajectory encoder needs the whole
        window (inference keeps only that frame, and this skips 90 % of the structure work).
        """
        points, mask = jnp.asarray(points, self.head.kernel.dtype), jnp.asarray(mask)
        batch = points.shape[:-5]
        mask = mask.reshape(-1, *mask.shape[-4:])
        points = points.reshape(-1, *points.shape[-5:])  # (B, N, P, M, J, 3)
        # Padding is 0 by construction; zeroing it anyway keeps inf/NaN there from leaking through the
        # attention's zero weights (0 * NaN).
        points = jnp.where(mask[..., None], points, 0.0)
        trajectory_mask = structure_mask = mask
        trajectory_key = structure_key = view_key = None
        if key is not None:
            keys = jax.random.split(key, 5)
            trajectory_mask = _drop_candidates(keys[0], mask, self.config.mask_ratio)
            structure_mask = _drop_candidates(keys[1], mask, self.config.mask_ratio)
            trajectory_key, structure_key, view_key = keys[2], keys[3], keys[4]

        # Trajectory sequences per (view pair, joint): (B, P, J, N, M, ...) -> (B, P, J, N, D).
        trajectory = self.trajectory(
            points.transpose(0, 2, 4, 1, 3, 5), trajectory_mask.transpose(0, 2, 4, 1, 3), trajectory_key
        )
        if last_frame_only:
            trajectory, points, structure_mask = trajectory[..., -1:, :], points[:, -1:], structure_mask[:, -1:]
        # Structure sequences per (view pair, frame): (B, P, N, J, M, ...) -> (B, P, N, J, D).
        structure_points = points.transpose(0, 2, 1, 4, 3, 5)
        structure_slots = structure_mask.transpose(0, 2, 1, 4, 3)
        candidate_features = self.structure.features(structure_points, structure_slots, structure_key)
        structure = self.structure.aggregate(candidate_features, structure_slots.reshape(*structure_slots.shape[:-2], -1))
        cross = trajectory.transpose(0, 3, 2, 1, 4) + structure.transpose(0, 2, 3, 1, 4)  # (B, N, J, P, D)
        trajectory_seen = jnp.any(trajectory_mask, axis=(1, 3)).transpose(0, 2, 1)  # (B, J, P)
        structure_seen = jnp.any(structure_mask, axis=(3, 4))  # (B, N, P)
        view_mask = trajectory_seen[:, None, :, :] | structure_seen[:, :, None, :]  # (B, N, J, P)
        joints = self.head(self.view(cross, view_mask, view_key))  # (B, N, J, 3)
        if self.anchor_score is not None:
            joints = joints + self._anchor(candidate_features, structure_points, structure_slots)
        return joints.reshape(*batch, *joints.shape[1:])

    def _anchor(
        self, features: Float[Array, "B P N JM D"], points: Float[Array, "B P N J M 3"], mask: Bool[Array, "B P N J M"]
    ) -> Float[Array, "B N J 3"]:
        """``sum_c w_c x_c`` over the candidates c of each (frame, joint) in every view pair, ``w = softmax`` of
        the scores of the valid ones (see ``JCSATConfig.candidate_anchor``); 0 where none is valid."""
        b, p, n, j, m = mask.shape
        logits = jnp.moveaxis(self.anchor_score(features)[..., 0].reshape(b, p, n, j, m), 1, 3).reshape(b, n, j, p * m)
        valid = jnp.moveaxis(mask, 1, 3).reshape(b, n, j, p * m)
        xyz = jnp.moveaxis(points, 1, 3).reshape(b, n, j, p * m, 3)
        weight = jax.nn.softmax(jnp.where(valid, logits, jnp.finfo(logits.dtype).min), axis=-1) * valid
        return jnp.sum(weight[..., None] * xyz, axis=-2)

    def convert(self, body25: Float[Array, "*batch N J 3"]) -> Float[Array, "*batch N K 3"]:
        """Learned joint-type conversion (Sec. 3.2.2): ``Linear(25 -> 20) -> Linear(20 -> 15)`` over the joints."""
        over_joints = jnp.swapaxes(body25, -1, -2)
        return jnp.swapaxes(self.convert_out(self.convert_hidden(over_joints)), -1, -2)

    def __call__(
        self,
        points: Float[ArrayLike, "*batch N P M J 3"],
        mask: Bool[ArrayLike, "*batch N P M J"],
        *,
        key: jax.Array | None = None,
        last_frame_only: bool = False,
    ) -> Float[Array, "*batch n K 3"]:
        """Shelf15 joints ``(N, K = config.output_joints, 3)``, metres, in the input's centred frame.

        Without ``key`` the model is deterministic (inference); with it, training-time candidate masking and
        dropout are drawn from it. ``last_frame_only``: see :meth:`body25`.
        """
        return self.convert(self.body25(points, mask, key=key, last_frame_only=last_frame_only))


SHIPPED_MODEL = Path(__file__).parent / "assets" / "shelf_wide_4da"
"""The trained default model (``config.json`` + ``state.npz``; ``jcsat/assets/README.md`` has the command that made it)."""


def load_model(path: str | Path) -> JCSAT:
    """The model folder written by :func:`~jcsat.train` to ``<workdir>/model``, with the trained parameters."""
    return training.load_model_state(path, lambda fields: JCSAT(JCSATConfig(**fields), rngs=nnx.Rngs(0)))

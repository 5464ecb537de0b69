"""The transformer blocks of JAT and MPJAT (thesis Sect. 3.4, 4.3 and 4.4): sinusoidal positional encoding, the
input encoder, and a one-head pre-LayerNorm GPT layer whose attention is optionally agent-aware (AgentFormer,
Yuan et al. 2021) and takes additive biases (the Joint-Aware Bias, Eq. 4.21 and 4.40).

Tokens are ``(person, time)`` pairs; :func:`agent_masks` builds, from each token's person and frame, which
query-key pairs are of the same person (``1_self``, Eq. 4.35) and which are allowed (causal, optionally within a
receptive field, and not padding; the tiled mask ``M`` of Eq. 4.34). Attention logits are

    A = where(same_person, (Q_s K_s^T + C_self) / sqrt(d), (Q_o K_o^T + C_other) / sqrt(d)),

the bias added before the scaling as Eq. 4.21 and 4.40 print it. Without agent awareness ``Q_o = Q_s`` and
``K_o = K_s`` (JAT's plain GPT attention); the two biases still apply to their own pairs.

Keys and values are computed apart from the attention (:meth:`GPTLayer.key_values`) so that an autoregressive
caller caches them and computes only the newest frame's per step, and queries may be a subset of the tokens (f_AR
queries the latest frame only, Eq. 4.20). Full self-attention is ``layer(x, layer.key_values(x), ...)``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
from flax import nnx
from jaxtyping import Array, ArrayLike, Bool, Float, Int

__all__ = ["AgentAttention", "GPTLayer", "InputEncoder", "KeyValues", "agent_masks", "sinusoidal_encoding"]


def _gelu(x: Array) -> Array:
    # The exact (erf) GELU, as PyTorch's nn.GELU that minGPT and AgentFormer use.
    return jax.nn.gelu(x, approximate=False)


def sinusoidal_encoding(positions: Int[ArrayLike, "*n"], dim: int) -> Float[Array, "*n dim"]:
    """Vaswani et al.'s encoding (Eq. 3.20): ``PE[p, 2i] = sin(p / 10000^(2i/dim))``, ``PE[p, 2i+1] = cos(...)``
    of the same angle; ``dim`` must be even."""
    if dim <= 0 or dim % 2:
        raise ValueError(f"the sinusoidal encoding needs a positive even dim, got {dim}")
    dtype = jnp.result_type(float)
    positions = jnp.asarray(positions).astype(dtype)
    frequencies = 10000.0 ** (-jnp.arange(0, dim, 2, dtype=dtype) / dim)
    angles = positions[..., None] * frequencies.reshape((1,) * positions.ndim + (dim // 2,))
    # [sin, cos] pairs interleaved: columns 2i and 2i + 1.
    return jnp.stack([jnp.sin(angles), jnp.cos(angles)], axis=-1).reshape(*positions.shape, dim)


class InputEncoder(nnx.Module):
    """``E = gelu([gelu(x W1), P] W2)`` (Eq. 4.15 / 4.19; Eq. 3.22 as AgentFormer): compresses the inputs to
    ``dim`` channels and mixes in the sinusoidal encoding ``P`` of each token's frame."""

    def __init__(self, in_features: int, dim: int, *, rngs: nnx.Rngs) -> None:
        self.dim = dim
        self.fc1 = nnx.Linear(in_features, dim, rngs=rngs)
        self.fc2 = nnx.Linear(2 * dim, dim, rngs=rngs)

    def __call__(self, x: Float[Array, "*b L in"], positions: Int[ArrayLike, "*p L"]) -> Float[Array, "*b L dim"]:
        """``positions``: each token's frame index; leading axes broadcastable to ``x``'s (e.g. one ``(L,)`` for
        the whole batch). Each person is encoded with its own frame indices, so the same frame of different
        people gets the same encoding (Sect. 4.4.1)."""
        hidden = _gelu(self.fc1(x))
        encoding = sinusoidal_encoding(positions, self.dim).astype(hidden.dtype)
        encoding = jnp.broadcast_to(encoding, hidden.shape)
        return _gelu(self.fc2(jnp.concatenate([hidden, encoding], axis=-1)))


class KeyValues(NamedTuple):
    """Keys and values of ``K`` tokens for one attention layer (cacheable across autoregressive steps)."""

    keys_self: Float[Array, "*b K d"]
    """Keys for query-key pairs of the same person."""
    keys_other: Float[Array, "*b K d"]
    """Keys for pairs of different people; the same array as ``keys_self`` when the attention is not
    agent-aware."""
    values: Float[Array, "*b K d"]


def agent_masks(
    query_person: Int[Array, "*b Q"],
    query_time: Int[Array, "*b Q"],
    key_person: Int[Array, "*b K"],
    key_time: Int[Array, "*b K"],
    key_valid: Bool[Array, "*b K"],
    receptive_field: int | None = None,
) -> tuple[Bool[Array, "*b Q K"], Bool[Array, "*b Q K"]]:
    """``(same_person, allowed)`` for every query-key pair.

    ``same_person`` is ``1_self`` of Eq. 4.35 (``1_other`` of Eq. 4.36 is its negation). ``allowed``: the key is
    not in the query's future (the causal mask tiled over people, Eq. 4.34 and Fig. 4.8), is valid (padding:
    absent people, padded frames), and, with ``receptive_field`` r, is one of the query's last r frames
    (``w .. t`` of Eq. 4.17)."""
    same_person = query_person[..., :, None] == key_person[..., None, :]
    allowed = (key_time[..., None, :] <= query_time[..., :, None]) & key_valid[..., None, :]
    if receptive_field is not None:
        if receptive_field < 1:
            raise ValueError(f"the receptive field must be at least one frame, got {receptive_field}")
        allowed &= key_time[..., None, :] > query_time[..., :, None] - receptive_field
    return same_person, allowed


def _scores(queries: Float[Array, "*b Q d"], keys: Float[Array, "*b K d"]) -> Float[Array, "*b Q K"]:
    return jnp.einsum("...qd,...kd->...qk", queries, keys)


class AgentAttention(nnx.Module):
    """One-head attention with ``same_person``-gated self / other logits and biases (module docstring)."""

    def __init__(self, dim: int, *, agent_aware: bool, rngs: nnx.Rngs) -> None:
        self.dim, self.agent_aware = dim, agent_aware
        self.query = nnx.Linear(dim, dim, rngs=rngs)
        self.key = nnx.Linear(dim, dim, rngs=rngs)
        self.value = nnx.Linear(dim, dim, rngs=rngs)
        self.out = nnx.Linear(dim, dim, rngs=rngs)
        if agent_aware:
            self.query_other = nnx.Linear(dim, dim, rngs=rngs)
            self.key_other = nnx.Linear(dim, dim, rngs=rngs)

    def key_values(self, x: Float[Array, "*b K dim"]) -> KeyValues:
        keys = self.key(x)
        return KeyValues(keys, self.key_other(x) if self.agent_aware else keys, self.value(x))

    def __call__(
        self,
        queries: Float[Array, "*b Q dim"],
        kv: KeyValues,
        same_person: Bool[Array, "*b Q K"],
        allowed: Bool[Array, "*b Q K"],
        bias_self: Float[Array, "*b Q K"] | None = None,
        bias_other: Float[Array, "*b Q K"] | None = None,
    ) -> Float[Array, "*b Q dim"]:
        """Attention of ``queries`` over the keys in ``kv``; a query with no allowed key gets a zero mix of
        values (its output is the output projection's bias), with finite gradients."""
        logits_self = _scores(self.query(queries), kv.keys_self)
        logits_other = _scores(self.query_other(queries), kv.keys_other) if self.agent_aware else logits_self
        if bias_self is not None:
            logits_self = logits_self + bias_self
        if bias_other is not None:
            logits_other = logits_other + bias_other
        logits = jnp.where(same_person, logits_self, logits_other) / math.sqrt(self.dim)
        # A finite fill, not -inf: a fully masked row must not compute inf - inf. Its maximum is then the fill,
        # exp gives ones, and multiplying by `allowed` zeroes them; other rows' masked entries underflow to 0.
        logits = jnp.where(allowed, logits, jnp.finfo(logits.dtype).min)
        shifted = logits - jax.lax.stop_gradient(jnp.max(logits, axis=-1, keepdims=True))
        weights = jnp.exp(shifted) * allowed
        total = jnp.sum(weights, axis=-1, keepdims=True)
        weights = weights / jnp.where(total > 0, total, 1)
        return self.out(jnp.einsum("...qk,...kd->...qd", weights, kv.values))


class GPTLayer(nnx.Module):
    """Pre-LayerNorm GPT block (Fig. 3.8) with one head: ``h = q + attn(LN1(q), kv)``, ``h + MLP(LN2(h))``, the
    MLP ``dim -> mlp_ratio * dim -> dim`` with GELU."""

    def __init__(self, dim: int, *, agent_aware: bool, mlp_ratio: int = 4, rngs: nnx.Rngs) -> None:
        self.norm1 = nnx.LayerNorm(dim, rngs=rngs)
        self.attention = AgentAttention(dim, agent_aware=agent_aware, rngs=rngs)
        self.norm2 = nnx.LayerNorm(dim, rngs=rngs)
        self.fc1 = nnx.Linear(dim, mlp_ratio * dim, rngs=rngs)
        self.fc2 = nnx.Linear(mlp_ratio * dim, dim, rngs=rngs)

    def key_values(self, x: Float[Array, "*b K dim"]) -> KeyValues:
        """Keys and values of the layer's input tokens ``x`` (normalised by LN1 as the queries are)."""
        return self.attention.key_values(self.norm1(x))

    def __call__(
        self,
        queries: Float[Array, "*b Q dim"],
        kv: KeyValues,
        same_person: Bool[Array, "*b Q K"],
        allowed: Bool[Array, "*b Q K"],
        bias_self: Float[Array, "*b Q K"] | None = None,
        bias_other: Float[Array, "*b Q K"] | None = None,
    ) -> Float[Array, "*b Q dim"]:
        """``queries``: the layer's input at the query tokens (not normalised); see :class:`AgentAttention`."""
        h = queries + self.attention(self.norm1(queries), kv, same_person, allowed, bias_self, bias_other)
        return h + self.fc2(_gelu(self.fc1(self.norm2(h))))

"""PHD's causal temporal convolution network (Zhang et al. 2019; thesis Sect. 3.3 and 4.2.1, spec sections 1 and 3):
f_movie, and f_AR with weights of its own.

Each residual block is GN -> ReLU -> causal conv(k) -> GN -> ReLU -> causal conv(k) -> + input. A causal
convolution pads the sequence on the left with ``k - 1`` copies of its first frame (PHD's hard-coded edge
padding) and convolves VALID, so output ``t`` sees inputs ``t - (k - 1) .. t`` and the length is kept. Three
blocks with k = 3 see 13 frames.

**Deviation from the official code, on purpose:** PHD's GroupNorm takes its statistics over time as well as over
a group's channels, so every output depends on future frames through the normalisation (the tester feeds the
first 40 frames to hide it). Here GroupNorm normalises each frame over its own channel groups only, which makes
the network strictly causal: perturbing frame ``t`` changes no output before ``t``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import nnx
from jaxtyping import Array, Float

__all__ = ["CausalTCN"]


def _tiny_xavier(key: jax.Array, shape: tuple[int, ...], dtype=jnp.float32) -> Array:
    """Xavier (Glorot) uniform x 0.001 (PHD's second convolution of a block): each block starts as nearly the
    identity."""
    return 0.001 * nnx.initializers.xavier_uniform()(key, shape, dtype)


class CausalConv(nnx.Module):
    """1D convolution over the time axis (-2) with left edge padding: output ``t`` sees ``t - (k - 1) .. t``."""

    def __init__(self, channels: int, kernel: int, *, rngs: nnx.Rngs, **conv_options) -> None:
        self.kernel = kernel
        self.conv = nnx.Conv(channels, channels, (kernel,), padding="VALID", rngs=rngs, **conv_options)

    def __call__(self, x: Float[Array, "N T C"]) -> Float[Array, "N T C"]:
        first = jnp.broadcast_to(x[:, :1], (x.shape[0], self.kernel - 1, x.shape[2]))
        padded = jnp.concatenate([first, x], axis=1)
        # The convolution as k matrix products of shifted frames: the same numbers as lax.conv, but XLA's CPU
        # backward pass of a convolution inside the autoregressive rollout was several times slower.
        frames = x.shape[1]
        kernel = self.conv.kernel[...]
        out = sum(padded[:, i: i + frames] @ kernel[i] for i in range(self.kernel))
        return out + self.conv.bias[...].reshape(1, 1, -1)


class TemporalBlock(nnx.Module):
    """GN -> ReLU -> causal conv -> GN -> ReLU -> causal conv (Xavier x 0.001) -> + input; GN per frame."""

    def __init__(self, channels: int, kernel: int, groups: int, *, rngs: nnx.Rngs) -> None:
        # reduction_axes=-1: statistics over one frame's channel groups, not over time (module docstring).
        self.norm1 = nnx.GroupNorm(channels, num_groups=groups, reduction_axes=-1, rngs=rngs)
        self.conv1 = CausalConv(channels, kernel, rngs=rngs)
        self.norm2 = nnx.GroupNorm(channels, num_groups=groups, reduction_axes=-1, rngs=rngs)
        self.conv2 = CausalConv(channels, kernel, kernel_init=_tiny_xavier, rngs=rngs)

    def __call__(self, x: Float[Array, "N T C"]) -> Float[Array, "N T C"]:
        hidden = self.conv1(jax.nn.relu(self.norm1(x)))
        return x + self.conv2(jax.nn.relu(self.norm2(hidden)))


class CausalTCN(nnx.Module):
    """``blocks`` causal residual blocks (module docstring) mapping ``(*b, T, C)`` to ``(*b, T, C)``.

    PHD: 3 blocks, k = 3, 2048 channels in 32 groups; the thesis' PHD+T uses 16 groups for f_movie (2048
    channels) and 17 for f_AR (2176), i.e. 128 channels per group. Outputs before ``receptive_field - 1`` see
    edge-padded copies of the first frame; PHD+T drops them."""

    def __init__(self, channels: int, blocks: int = 3, kernel: int = 3, *, groups: int, rngs: nnx.Rngs) -> None:
        if blocks < 1 or kernel < 1 or channels % groups:
            raise ValueError(f"need blocks, kernel >= 1 and channels divisible by groups, got blocks={blocks}, "
                             f"kernel={kernel}, channels={channels}, groups={groups}")
        self.kernel = kernel
        self.blocks = nnx.List([TemporalBlock(channels, kernel, groups, rngs=rngs) for _ in range(blocks)])

    @property
    def receptive_field(self) -> int:
        """Frames that one output sees: ``blocks * 2 (k - 1) + 1`` (13 for PHD's 3 blocks, k = 3)."""
        return len(self.blocks) * 2 * (self.kernel - 1) + 1

    def __call__(self, x: Float[Array, "*b T C"]) -> Float[Array, "*b T C"]:
        *batch, frames, channels = x.shape
        x = x.reshape(-1, frames, channels)
        for block in self.blocks:
            x = block(x)
        return x.reshape(*batch, frames, channels)

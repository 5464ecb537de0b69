"""A small ResNet for person crops: the image encoder phi of the dynamics models, sized for a CPU.

The thesis uses HMR's frozen ResNet-50 on 224 x 224 crops (2048 features, precomputed; spec section 3). This is
the same family at a fraction of the cost: a stride-2 3x3 stem, stages of residual basic blocks (each stage after
the first halves the resolution), then global average pooling (ResNet's) or the last feature map flattened, and a
linear map to ``feature_dim``. GroupNorm replaces batch norm, so the network has no batch statistics and no mutable
state: training and inference compute the same function, and per-person batches of any size (even one crop) are
fine.
"""

from __future__ import annotations

from typing import Literal, get_args

import jax
import jax.numpy as jnp
from flax import nnx
from jaxtyping import Array, Float

__all__ = ["Pooling", "ResNetBackbone"]

Pooling = Literal["mean", "flatten"]
"""How the last feature map becomes one vector: its mean over the positions (ResNet's global average pooling), or
all of it flattened, which keeps where in the crop each feature fired."""


def _group_norm(channels: int, groups: int, *, rngs: nnx.Rngs, zero_scale: bool = False) -> nnx.GroupNorm:
    groups = min(groups, channels)
    if channels % groups:
        raise ValueError(f"GroupNorm needs channels ({channels}) divisible by its groups ({groups})")
    scale_init = nnx.initializers.zeros if zero_scale else nnx.initializers.ones
    return nnx.GroupNorm(channels, num_groups=groups, scale_init=scale_init, rngs=rngs)


class BasicBlock(nnx.Module):
    """``relu(x' + GN(conv3x3(relu(GN(conv3x3_stride(x))))))`` with ``x'`` the input, or its 1x1 strided
    projection + GN where the width or resolution changes (He et al. 2016, "basic block").

    The residual branch's last GroupNorm starts with a zero scale (Goyal et al. 2017), so each block starts as
    the identity and the untrained network's features do not grow with depth."""

    def __init__(self, in_channels: int, out_channels: int, stride: int, groups: int, *, rngs: nnx.Rngs) -> None:
        self.conv1 = nnx.Conv(in_channels, out_channels, (3, 3), strides=stride, padding=1, use_bias=False, rngs=rngs)
        self.norm1 = _group_norm(out_channels, groups, rngs=rngs)
        self.conv2 = nnx.Conv(out_channels, out_channels, (3, 3), padding=1, use_bias=False, rngs=rngs)
        self.norm2 = _group_norm(out_channels, groups, rngs=rngs, zero_scale=True)
        if stride != 1 or in_channels != out_channels:
            self.projection = nnx.Conv(in_channels, out_channels, (1, 1), strides=stride, use_bias=False, rngs=rngs)
            self.projection_norm = _group_norm(out_channels, groups, rngs=rngs)
        else:
            self.projection = self.projection_norm = None

    def __call__(self, x: Float[Array, "N H W Ci"]) -> Float[Array, "N h w Co"]:
        residual = self.norm2(self.conv2(jax.nn.relu(self.norm1(self.conv1(x)))))
        shortcut = x if self.projection is None else self.projection_norm(self.projection(x))
        return jax.nn.relu(shortcut + residual)


class ResNetBackbone(nnx.Module):
    """RGB crops in [0, 1] -> one feature vector per crop (see the module docstring).

    With the defaults a 64 x 64 crop is 32 x 32 after the stem and 4 x 4 in the last stage (widths 16, 32, 64,
    128). ``norm_groups`` is GroupNorm's group count (fewer where a layer is narrower). ``crop_size`` is the side of
    the crops it takes: crops of another size are refused instead of being turned into features the head was never
    trained on. ``pooling`` (:data:`Pooling`): ``"mean"`` gives the head ``widths[-1]`` numbers per crop, ``"flatten"``
    the whole last map (``4 * 4 * 128`` with the defaults)."""

    def __init__(
        self,
        widths: tuple[int, ...] = (16, 32, 64, 128),
        blocks_per_stage: int = 1,
        feature_dim: int = 256,
        norm_groups: int = 8,
        *,
        crop_size: int = 64,
        pooling: Pooling = "mean",
        rngs: nnx.Rngs,
    ) -> None:
        if not widths or blocks_per_stage < 1:
            raise ValueError(f"need at least one stage and one block per stage, got {widths}, {blocks_per_stage}")
        if pooling not in get_args(Pooling):
            raise ValueError(f"pooling must be one of {get_args(Pooling)}, got {pooling!r}")
        self.feature_dim = feature_dim
        self.crop_size = crop_size
        self.pooling = pooling
        self.stem = nnx.Conv(3, widths[0], (3, 3), strides=2, padding=1, use_bias=False, rngs=rngs)
        self.stem_norm = _group_norm(widths[0], norm_groups, rngs=rngs)
        blocks, previous = [], widths[0]
        for stage, width in enumerate(widths):
            for index in range(blocks_per_stage):
                stride = 2 if stage > 0 and index == 0 else 1
                blocks.append(BasicBlock(previous, width, stride, norm_groups, rngs=rngs))
                previous = width
        self.blocks = nnx.List(blocks)
        side = crop_size
        for _ in widths:  # the stem and each later stage halve the side (3x3, stride 2, padding 1: rounded up)
            side = -(-side // 2)
        self.head = nnx.Linear(previous * (side * side if pooling == "flatten" else 1), feature_dim, rngs=rngs)

    def __call__(self, crops: Float[Array, "*batch H W 3"]) -> Float[Array, "*batch feature_dim"]:
        *batch, height, width, _ = crops.shape
        if (height, width) != (self.crop_size, self.crop_size):
            raise ValueError(f"the backbone takes {self.crop_size} x {self.crop_size} crops, got {height} x {width}")
        # Centred on mid-grey: zero-mean inputs for the first convolution, which has no bias.
        x = 2.0 * crops.reshape(-1, height, width, 3) - 1.0
        x = jax.nn.relu(self.stem_norm(self.stem(x)))
        for block in self.blocks:
            x = block(x)
        pooled = jnp.mean(x, axis=(1, 2)) if self.pooling == "mean" else x.reshape(x.shape[0], -1)
        return self.head(pooled).reshape(*batch, self.feature_dim)

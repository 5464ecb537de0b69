"""PHD+T (thesis Sect. 4.2): PHD's causal temporal encoders with the HMR head, plus a translation branch.

For one person track (``*b`` leading axes batch tracks):

- ``f_movie`` (:class:`~dynamics.CausalTCN`, receptive field 13) turns image features ``phi_t`` into temporal
  features ``Phi_t`` (Eq. 4.2); ``f_HMR`` (:class:`~dynamics.HMRHead`, 3 IEF iterations) regresses the SMPL
  parameters and the crop camera from them (Eq. 4.3); the crop camera and the track's box give the root's
  camera-frame position ``gamma_t`` (:func:`geometry.crop_camera_to_translation`).
- Delta predictors: one more HMR head per offset in ``delta_offsets`` ({-5, -10}, Sect. 4.2.2) regresses the
  parameters of frame ``t + delta`` from ``Phi_t``, starting from frame t's estimate.
- ``f_JE`` (Eq. 4.5) encodes the 24 camera-frame joints into ``Gamma_t``; ``f_AR`` (a second causal TCN over
  ``[Phi; Gamma]``, Eq. 4.6) maps the last 13 of them to ``[Phi; Gamma]_{t+1}``; ``f_transl`` (Eq. 4.7) maps
  ``Gamma_{t+1}`` to the step ``Delta gamma`` and ``gamma_{t+1} = gamma_t + Delta gamma`` (Eq. 4.8).
  :meth:`PHDT.rollout` appends each prediction to the window and repeats (PHD's autoregression).

Sizes are CPU-sized (``PHDTConfig``): features of 256 channels instead of ResNet-50's 2048, 128 channels per
normalisation group as Table C.1.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
from flax import nnx
from jaxtyping import Array, ArrayLike, Bool, Float

import geometry

from ._hmr import DecodeFrom, HMRHead, SMPLParams, _check_extrapolation, decoding_start, mean_params
from ._tcn import CausalTCN

__all__ = ["Observation", "PHDT", "PHDTConfig", "Rollout", "crop_roots", "last_frame", "params_to_joints"]


@dataclasses.dataclass(frozen=True)
class PHDTConfig:
    feature_dim: int = 256
    """Channels of the image features ``phi`` and the temporal features ``Phi``."""
    joint_dim: int = 128
    """Channels of the joint features ``Gamma`` (the thesis' 128)."""
    hmr_hidden: int = 512
    hmr_iterations: int = 3
    hmr_dropout: float = 0.5
    tcn_blocks: int = 3
    tcn_kernel: int = 3
    channels_per_group: int = 128
    delta_offsets: tuple[int, ...] = (-5, -10)
    num_shapes: int = 3
    decode_from: DecodeFrom = "mean"
    """Where the rollout's f_HMR starts each predicted frame (:data:`~dynamics.DecodeFrom`): the thesis' mean pose,
    or, for the 3D forecasters whose observed poses are exact, the previous frame's pose, plain or moved on by its
    last step (each frame is then the last plus a change, as HMMR's delta predictors start from the current
    estimate)."""
    extrapolation: float = 1.0
    """With ``decode_from="extrapolated"``: the fraction of its last step the previous pose is moved on by
    (:func:`~dynamics.decoding_start`)."""

    def __post_init__(self) -> None:
        _check_extrapolation(self.extrapolation)
        for channels in (self.feature_dim, self.feature_dim + self.joint_dim):
            if channels % self.channels_per_group:
                raise ValueError(f"{channels} channels do not split into groups of {self.channels_per_group}")
        if any(offset >= 0 for offset in self.delta_offsets):
            raise ValueError(f"delta predictors look into the past: offsets must be negative, got {self.delta_offsets}")


class Observation(NamedTuple):
    """The reconstruction of ``T`` observed frames."""

    temporal: Float[Array, "*b T D"]
    """``Phi^``."""
    params: SMPLParams
    root: Float[Array, "*b T 3"]
    """``gamma^``: the pelvis in the camera frame, metres."""
    joint_features: Float[Array, "*b T G"]
    """``Gamma^``."""


class Rollout(NamedTuple):
    """``horizon`` predicted frames."""

    features: Float[Array, "*b horizon D"]
    """``Phi~``."""
    joint_features: Float[Array, "*b horizon G"]
    """``Gamma~``."""
    params: SMPLParams
    root: Float[Array, "*b horizon 3"]
    """``gamma~``: the pelvis in the camera frame, metres."""


def params_to_joints(body: geometry.BodyModel, params: SMPLParams, root: Float[Array, "*b 3"]) -> Float[Array, "*b 24 3"]:
    """Camera-frame joints of ``params`` with the pelvis at ``root`` (metres)."""
    rotations = geometry.rotation_6d_to_matrix(params.rot6d)
    batch = rotations.shape[:-3]
    flat = jax.vmap(geometry.body_joints, in_axes=(None, 0, 0, None))(
        body, rotations.reshape(-1, 24, 3, 3), params.betas.reshape(-1, params.betas.shape[-1]),
        jnp.zeros(3, rotations.dtype))
    joints = flat.reshape(*batch, 24, 3)
    return joints - joints[..., :1, :] + root[..., None, :]


def last_frame(params: SMPLParams, back: int = 1) -> SMPLParams:
    """The parameters of the last frame of ``params`` (frames on the axis before each field's own), or of the frame
    ``back`` frames from the end."""
    return SMPLParams(params.rot6d[..., -back, :, :], params.betas[..., -back, :], params.camera[..., -back, :])


def crop_roots(params: SMPLParams, boxes: Float[Array, "*b 4"], K: Float[Array, "*b 3 3"]) -> Float[Array, "*b 3"]:
    """The camera-frame pelvis of each frame from its crop camera and square crop box, metres."""
    flat = jax.vmap(geometry.crop_camera_to_translation)(params.camera.reshape(-1, 3), boxes.reshape(-1, 4),
                                                         K.reshape(-1, 3, 3))
    return flat.reshape(boxes.shape[:-1] + (3,))


class PHDT(nnx.Module):
    """The PHD+T networks (module docstring); the body model is an argument of the methods that need joints."""

    def __init__(self, config: PHDTConfig, *, rngs: nnx.Rngs):
        self.config = config
        mean = mean_params(config.num_shapes)
        head = dict(mean=mean, hidden=config.hmr_hidden, iterations=config.hmr_iterations,
                    dropout=config.hmr_dropout, rngs=rngs)
        groups = config.feature_dim // config.channels_per_group
        self.movie = CausalTCN(config.feature_dim, blocks=config.tcn_blocks, kernel=config.tcn_kernel,
                               groups=groups, rngs=rngs)
        self.hmr = HMRHead(config.feature_dim, **head)
        self.deltas = nnx.List([HMRHead(config.feature_dim, **head) for _ in config.delta_offsets])
        self.joint_encoder = nnx.Sequential(nnx.Linear(72, config.joint_dim, rngs=rngs), jax.nn.relu,
                                            nnx.Linear(config.joint_dim, config.joint_dim, rngs=rngs))
        channels = config.feature_dim + config.joint_dim
        self.ar = CausalTCN(channels, blocks=config.tcn_blocks, kernel=config.tcn_kernel,
                            groups=channels // config.channels_per_group, rngs=rngs)
        # Zero-initialised output: an untrained f_transl predicts no motion (ZeroMotion's root), not metres per frame.
        self.translation = nnx.Sequential(nnx.Linear(config.joint_dim, config.joint_dim, rngs=rngs), jax.nn.relu,
                                          nnx.Linear(config.joint_dim, 3, kernel_init=nnx.initializers.zeros,
                                                     rngs=rngs))

    @property
    def receptive_field(self) -> int:
        return self.movie.receptive_field

    def condition(self, features: Float[Array, "*b T D"]) -> Float[Array, "*b T D"]:
        """``Phi_t`` for every frame (causal: frame t sees frames t-12..t)."""
        return self.movie(features)

    def regress(self, temporal: Float[Array, "*b D"], key: jax.Array | None = None) -> SMPLParams:
        return self.hmr(temporal, key=key)

    def regress_deltas(self, temporal: Float[Array, "*b D"], current: SMPLParams,
                       key: jax.Array | None = None) -> list[SMPLParams]:
        """The parameters of frames ``t + delta`` for each of ``delta_offsets``, starting from ``current``."""
        keys = [None] * len(self.deltas) if key is None else list(jax.random.split(key, len(self.deltas)))
        return [head(temporal, start=current, key=k) for head, k in zip(self.deltas, keys)]

    def encode_joints(self, joints: Float[Array, "*b 24 3"]) -> Float[Array, "*b G"]:
        return self.joint_encoder(joints.reshape(*joints.shape[:-2], 72))

    def observe(self, body: geometry.BodyModel, features: Float[ArrayLike, "*b T D"], boxes: Float[ArrayLike, "*b T 4"],
                K: Float[ArrayLike, "*b T 3 3"], present: Bool[ArrayLike, "..."] | None = None,
                key: jax.Array | None = None) -> Observation:
        """Reconstruct the observed frames of a track: ``Phi^``, ``Theta^``, ``gamma^`` (from the crop camera and
        the square crop boxes) and the joint features ``Gamma^`` of the reconstructed camera-frame joints.

        ``present`` (which people of a scene exist) is accepted for the interface :class:`~dynamics.JAT` shares
        and ignored: PHD+T treats every track on its own, so a scene's people axis is one more batch axis."""
        features, boxes, K = map(jnp.asarray, (features, boxes, K))
        frames = features.shape[:-1]
        if features.shape[-1] != self.config.feature_dim or boxes.shape != frames + (4,) or K.shape != frames + (3, 3):
            raise ValueError(f"need features (*b, T, {self.config.feature_dim}), boxes (*b, T, 4) and K (*b, T, 3, 3) "
                             f"for the same frames, got {features.shape}, {boxes.shape} and {K.shape}")
        temporal = self.condition(features)
        params = self.regress(temporal, key)
        root = crop_roots(params, boxes, K)
        joints = params_to_joints(body, params, root)
        return Observation(temporal, params, root, self.encode_joints(joints))

    def rollout(self, body: geometry.BodyModel, observed: Observation, horizon: int,
                present: Bool[ArrayLike, "..."] | None = None, key: jax.Array | None = None) -> Rollout:
        """Predict ``horizon`` frames after ``observed`` (at least one receptive field of frames): ``f_AR`` on the
        last 13 ``[Phi; Gamma]``, its output appended to the window, ``horizon`` times (no teacher forcing).

        ``body`` and ``present`` are unused (the interface shared with :class:`~dynamics.JAT`): PHD+T's
        autoregression stays in feature space and its tracks are independent."""
        del body, present
        width = self.receptive_field
        if observed.temporal.shape[-2] < width:
            raise ValueError(f"rollout needs at least {width} observed frames, got {observed.temporal.shape[-2]}")
        window = jnp.concatenate([observed.temporal, observed.joint_features], axis=-1)[..., -width:, :]

        decode_from = self.config.decode_from

        def advance(carry, _):
            window, root, before, params = carry
            # The carry keeps its dtypes whatever the parameters' (float32 shipped models under jax_enable_x64).
            following = self.ar(window)[..., -1, :].astype(window.dtype)
            joint_features = following[..., self.config.feature_dim:]
            root = root + self.translation(joint_features).astype(root.dtype)
            window = jnp.concatenate([window[..., 1:, :], following[..., None, :]], axis=-2)
            if decode_from != "mean":
                start = decoding_start(decode_from, before, params, self.config.extrapolation)
                before, params = params, jax.tree.map(lambda new, old: new.astype(old.dtype),
                                                      self.hmr(following[..., :self.config.feature_dim], start=start),
                                                      params)
            return (window, root, before, params), (following, root, params)

        carry = (window, observed.root[..., -1, :], last_frame(observed.params, 2), last_frame(observed.params))
        _, (predicted, roots, decoded) = jax.lax.scan(advance, carry, length=horizon)
        predicted, roots = jnp.moveaxis(predicted, 0, -2), jnp.moveaxis(roots, 0, -2)
        temporal = predicted[..., :self.config.feature_dim]
        if decode_from != "mean":
            params = SMPLParams(jnp.moveaxis(decoded.rot6d, 0, -3), jnp.moveaxis(decoded.betas, 0, -2),
                                jnp.moveaxis(decoded.camera, 0, -2))
        else:
            params = self.regress(temporal, key)
        return Rollout(temporal, predicted[..., self.config.feature_dim:], params, roots)

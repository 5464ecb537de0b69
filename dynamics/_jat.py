"""The Joint-Aware Transformer (JAT, thesis Sect. 4.3) and the Multi-Person JAT (MPJAT, Sect. 4.4) as one module.

Inputs are scenes: ``*b`` batches of ``N`` people (axis -3 of features, -2 of ``present``) over ``T`` frames,
tokens laid out person-major as the thesis (row ``i`` belongs to person ``i // T``). With ``agent_aware=False``
(JAT) a person's tokens attend only to their own, so the people of a scene are independent; with it (MPJAT)
every attention layer is agent-aware (Eq. 4.34-4.36) and people attend to each other's past.

- ``f_movie``: the input encoder of Eq. 4.15 on ``[phi_t; B_t]`` (features and the box in normalised camera
  coordinates, each person's positional code from their own frame index), one causal GPT layer (one head) ->
  ``Phi_t``; ``f_HMR`` regresses the SMPL parameters and the crop camera (the root ``gamma_t`` as PHD+T).
- ``f_JE`` encodes the camera-frame joints into ``Gamma_t``.
- ``f_AR``: the input encoder of Eq. 4.19 on ``[Phi; Gamma]``, one GPT layer whose query is the latest frame of
  each person only (Eq. 4.20) and whose keys are the frames ``w..t`` of the receptive field ``r`` (Eq. 4.17), with
  the Joint-Aware Bias (Eq. 4.21-4.27; per person pair, 4.37-4.40 with ``f_JABS`` and ``f_JABO``) added to its
  logits. Its output maps to ``[Phi~; Gamma~]_{t+1}``; ``f_transl`` (PHD+T's Eq. 4.7-4.8) moves the root.
  Each predicted frame's parameters give its joints, poses and a new ``Gamma`` (Sect. 4.3.2's autoregression).

Deviation, stated: ``f_AR``'s output is a *residual* ``[Phi~; Gamma~]_{t+1} = [Phi; Gamma]_t + W z`` with ``W``
zero-initialised (as PHD's TCN blocks add a near-zero-initialised branch to their input), so an untrained
``f_AR`` predicts ZeroMotion and training moves it only where the data says the future differs. Sizes are
CPU-sized (:class:`JATConfig`).

Positions are frame indices from the window's first frame, so the keys and values of a frame never change once
computed: :meth:`JAT.rollout` caches them and computes one new frame's per step (``cached=False`` recomputes
every frame every step, the naive reference of ``experiments.bench_dynamics``).
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
from flax import nnx
from jaxtyping import Array, ArrayLike, Bool, Float, Int

import geometry

from ._attention import GPTLayer, InputEncoder, KeyValues, agent_masks
from ._canonical import JointAwareBias, canonical_features
from ._hmr import DecodeFrom, HMRHead, SMPLParams, _check_extrapolation, decoding_start, mean_params
from ._phdt import Observation, Rollout, crop_roots, last_frame, params_to_joints

__all__ = ["JAT", "JATConfig", "box_features", "scene_tokens"]


@dataclasses.dataclass(frozen=True)
class JATConfig:
    feature_dim: int = 256
    """Channels of the image features ``phi`` (the backbone's)."""
    temporal_dim: int = 256
    """Channels of ``Phi`` (the thesis: 512)."""
    joint_dim: int = 64
    """Channels of ``Gamma`` (the thesis: 128)."""
    hmr_hidden: int = 512
    hmr_iterations: int = 3
    hmr_dropout: float = 0.5
    bias_hidden: int = 128
    """Hidden units of each Joint-Aware Bias encoder (the thesis: 576)."""
    receptive_field: int = 46
    """r of Eq. 4.17: keys of the frames ``t - r + 1 .. t``."""
    agent_aware: bool = False
    """MPJAT: agent-aware attention in f_movie and f_AR, and f_JABO beside f_JABS."""
    joint_aware_bias: bool = True
    """False: f_AR's attention without the bias (Table 5.5's ablation)."""
    num_shapes: int = 3
    decode_from: DecodeFrom = "mean"
    """Where the rollout's f_HMR starts each predicted frame (as :attr:`~dynamics.PHDTConfig.decode_from`)."""
    extrapolation: float = 1.0
    """With ``decode_from="extrapolated"``: the fraction of its last step the previous pose is moved on by
    (:func:`~dynamics.decoding_start`)."""

    def __post_init__(self) -> None:
        _check_extrapolation(self.extrapolation)
        if self.receptive_field < 1:
            raise ValueError(f"receptive_field must be >= 1, got {self.receptive_field}")
        for name in ("temporal_dim", "joint_dim"):
            if getattr(self, name) % 2:
                raise ValueError(f"{name} must be even (sinusoidal positional codes), got {getattr(self, name)}")

    @property
    def ar_dim(self) -> int:
        return self.temporal_dim + self.joint_dim


class _Tokens(NamedTuple):
    person: Int[Array, "*b L"]
    time: Int[Array, "*b L"]
    valid: Bool[Array, "*b L"]


def scene_tokens(present: Bool[Array, "*b N"], frames: int) -> _Tokens:
    """Person, frame and validity of every token of ``N`` people over ``frames`` frames, person-major."""
    people = present.shape[-1]
    person = jnp.repeat(jnp.arange(people), frames)
    time = jnp.tile(jnp.arange(frames), people)
    batch = present.shape[:-1]
    return _Tokens(jnp.broadcast_to(person, batch + person.shape), jnp.broadcast_to(time, batch + time.shape),
                   jnp.repeat(present, frames, axis=-1))


def box_features(boxes: Float[Array, "*b 4"], K: Float[Array, "*b 3 3"]) -> Float[Array, "*b 4"]:
    """The box corners in normalised camera coordinates ``(x - c_x) / f_x``: ``B_t`` of Eq. 4.13, independent of
    the image size."""
    centre = jnp.stack([K[..., 0, 2], K[..., 1, 2]], axis=-1)
    focal = jnp.stack([K[..., 0, 0], K[..., 1, 1]], axis=-1)
    corners = (boxes.reshape(*boxes.shape[:-1], 2, 2) - centre[..., None, :]) / focal[..., None, :]
    return corners.reshape(boxes.shape)


def _flatten_people(x: Array, trailing: int) -> Array:
    """``(*b, N, T, *trailing)`` -> ``(*b, N T, *trailing)``."""
    shape = x.shape
    split = len(shape) - trailing
    return x.reshape(*shape[:split - 2], shape[split - 2] * shape[split - 1], *shape[split:])


class JAT(nnx.Module):
    """JAT, or MPJAT with ``config.agent_aware`` (module docstring)."""

    def __init__(self, config: JATConfig, *, rngs: nnx.Rngs):
        self.config = config
        aware = config.agent_aware
        self.movie_encoder = InputEncoder(config.feature_dim + 4, config.temporal_dim, rngs=rngs)
        self.movie = GPTLayer(config.temporal_dim, agent_aware=aware, rngs=rngs)
        self.hmr = HMRHead(config.temporal_dim, mean_params(config.num_shapes), hidden=config.hmr_hidden,
                           iterations=config.hmr_iterations, dropout=config.hmr_dropout, rngs=rngs)
        self.joint_encoder = nnx.Sequential(nnx.Linear(72, config.joint_dim, rngs=rngs), jax.nn.relu,
                                            nnx.Linear(config.joint_dim, config.joint_dim, rngs=rngs))
        self.ar_encoder = InputEncoder(config.ar_dim, config.ar_dim, rngs=rngs)
        self.ar = GPTLayer(config.ar_dim, agent_aware=aware, rngs=rngs)
        self.ar_output = nnx.Linear(config.ar_dim, config.ar_dim, kernel_init=nnx.initializers.zeros, rngs=rngs)
        if config.joint_aware_bias:
            self.bias_self = JointAwareBias(config.bias_hidden, rngs=rngs)
            if aware:
                self.bias_other = JointAwareBias(config.bias_hidden, rngs=rngs)
        # Zero-initialised output: an untrained f_transl predicts no motion (ZeroMotion's root).
        self.translation = nnx.Sequential(nnx.Linear(config.joint_dim, config.joint_dim, rngs=rngs), jax.nn.relu,
                                          nnx.Linear(config.joint_dim, 3, kernel_init=nnx.initializers.zeros,
                                                     rngs=rngs))

    def _masks(self, queries: _Tokens, keys: _Tokens) -> tuple[Array, Array]:
        same, allowed = agent_masks(queries.person, queries.time, keys.person, keys.time, keys.valid,
                                    self.config.receptive_field)
        # JAT: people of a scene are independent (each person's own past only).
        return same, allowed if self.config.agent_aware else allowed & same

    def encode_joints(self, joints: Float[Array, "*b 24 3"]) -> Float[Array, "*b G"]:
        return self.joint_encoder(joints.reshape(*joints.shape[:-2], 72))

    def condition(self, features: Float[Array, "*b N T D"], boxes: Float[Array, "*b N T 4"],
                  K: Float[Array, "*b N T 3 3"], present: Bool[Array, "*b N"]) -> Float[Array, "*b N T P"]:
        """``Phi_t`` of every person and frame (f_movie, causal)."""
        people, frames = features.shape[-3:-1]
        encoded = self.movie_encoder(jnp.concatenate([features, box_features(boxes, K).astype(features.dtype)], -1),
                                     jnp.arange(frames))
        tokens = _flatten_people(encoded, 1)
        positions = scene_tokens(present, frames)
        same, allowed = self._masks(positions, positions)
        temporal = self.movie(tokens, self.movie.key_values(tokens), same, allowed)
        return temporal.reshape(*temporal.shape[:-2], people, frames, temporal.shape[-1])

    def observe(self, body: geometry.BodyModel, features: Float[ArrayLike, "*b N T D"],
                boxes: Float[ArrayLike, "*b N T 4"], K: Float[ArrayLike, "*b N T 3 3"],
                present: Bool[ArrayLike, "*b N"] | None = None, key: jax.Array | None = None) -> Observation:
        """Reconstruct the observed frames: ``Phi^``, ``Theta^``, ``gamma^`` (crop camera and square boxes) and
        ``Gamma^``. ``present``: which of the ``N`` people exist (padding; default all)."""
        features, boxes, K = map(jnp.asarray, (features, boxes, K))
        scene = features.shape[:-1]
        if (features.ndim < 3 or features.shape[-1] != self.config.feature_dim or boxes.shape != scene + (4,)
                or K.shape != scene + (3, 3)):
            raise ValueError(f"need features (*b, N, T, {self.config.feature_dim}), boxes (*b, N, T, 4) and K "
                             f"(*b, N, T, 3, 3), got {features.shape}, {boxes.shape} and {K.shape}")
        present = self._present(present, scene[:-1])
        temporal = self.condition(features, boxes, K, present)
        params = self.hmr(temporal, key=key)
        root = crop_roots(params, boxes, K)
        return Observation(temporal, params, root, self.encode_joints(params_to_joints(body, params, root)))

    @staticmethod
    def _present(present: ArrayLike | None, shape: tuple[int, ...]) -> Array:
        if present is None:
            return jnp.ones(shape, bool)
        present = jnp.asarray(present, bool)
        if present.shape != shape:
            raise ValueError(f"present must have the scene's (*b, N) shape {shape}, got {present.shape}")
        return present

    def _bias(self, joints: Array, rotations: Array, latest: Array) -> tuple[Array | None, Array | None]:
        """f_JABS's and f_JABO's biases of each person's latest frame (the queries) against every key token
        (Eq. 4.26-4.27, 4.39): ``joints`` ``(*b, N, L, 24, 3)``, ``rotations`` ``(*b, N, L, 24, 3, 3)``."""
        if not self.config.joint_aware_bias:
            return None, None
        batch = joints.shape[:-4]
        flat = lambda x: x.reshape(-1, *x.shape[len(batch):])  # noqa: E731  (one batch axis for vmap)
        query_joints = jax.lax.dynamic_index_in_dim(joints, latest, axis=-3, keepdims=False)
        query_rotations = jax.lax.dynamic_index_in_dim(rotations, latest, axis=-4, keepdims=False)
        pairs = jax.vmap(canonical_features, in_axes=(None, None, 0, 0))  # over key tokens
        pairs = jax.vmap(jax.vmap(pairs, in_axes=(0, 0, None, None)))      # over query people, then the batch
        features = pairs(flat(query_joints), flat(query_rotations), flat(_flatten_people(joints, 2)),
                         flat(_flatten_people(rotations, 3)))
        features = features.reshape(*batch, *features.shape[1:])
        # The attention takes f_JABS's value for a same-person pair and f_JABO's for the others (Eq. 4.40).
        return self.bias_self(features), self.bias_other(features) if self.config.agent_aware else None

    def rollout(self, body: geometry.BodyModel, observed: Observation, horizon: int,
                present: Bool[ArrayLike, "*b N"] | None = None, key: jax.Array | None = None,
                cached: bool = True) -> Rollout:
        """Predict ``horizon`` frames after ``observed`` without teacher forcing (module docstring).

        ``cached``: keep every frame's keys and values and compute only the newest frame's per step; False:
        re-encode every frame at every step (the same numbers, slower). ``key`` is unused: the prediction is
        deterministic (f_HMR is frozen and without dropout while f_AR trains)."""
        del key
        observed_frames = observed.temporal.shape[-2]
        if horizon < 1:
            raise ValueError(f"horizon must be >= 1, got {horizon}")
        if self.config.decode_from == "extrapolated" and observed_frames < 2:
            raise ValueError("decoding from the extrapolated pose needs at least 2 observed frames, got 1")
        length = observed_frames + horizon
        scene = observed.temporal.shape[:-2]
        present = self._present(present, scene)
        D = self.config.temporal_dim
        pad = lambda x, axis: jnp.concatenate(  # noqa: E731
            [x, jnp.zeros(x.shape[:axis] + (horizon,) + x.shape[axis + 1:], x.dtype)], axis=axis)
        inputs = jnp.concatenate([observed.temporal, observed.joint_features], axis=-1)
        dtype = inputs.dtype
        rotations = geometry.rotation_6d_to_matrix(observed.params.rot6d)
        joints = params_to_joints(body, observed.params, observed.root)
        history = pad(inputs, -2)
        encoded = self.ar_encoder(history, jnp.arange(length))
        kv = jax.tree.map(lambda x: x.astype(dtype), self.ar.key_values(encoded))
        keys = scene_tokens(present, length)
        query_people = jnp.broadcast_to(jnp.arange(scene[-1]), present.shape)

        def advance(carry, step):
            history, encoded, kv, joints, rotations, root, before, previous = carry
            latest = observed_frames - 1 + step
            if not cached:
                encoded = self.ar_encoder(history, jnp.arange(length))
                kv = self.ar.key_values(encoded)
            queries = jax.lax.dynamic_index_in_dim(encoded, latest, axis=-2, keepdims=False)
            query_tokens = _Tokens(query_people, jnp.full(present.shape, latest), present)
            same, allowed = self._masks(query_tokens, keys)
            bias_self, bias_other = self._bias(joints, rotations, latest)
            flat_kv = KeyValues(*(_flatten_people(x, 1) for x in kv))
            z = self.ar(queries, flat_kv, same, allowed, bias_self, bias_other)
            current = jax.lax.dynamic_index_in_dim(history, latest, axis=-2, keepdims=False)
            following = (current + self.ar_output(z)).astype(dtype)
            temporal, joint_features = following[..., :D], following[..., D:]
            root = root + self.translation(joint_features).astype(root.dtype)
            params = self.hmr(temporal, start=decoding_start(self.config.decode_from, before, previous,
                                                                    self.config.extrapolation))
            params = jax.tree.map(lambda new, old: new.astype(old.dtype), params, previous)
            new_joints = params_to_joints(body, params, root)
            new_inputs = jnp.concatenate([temporal, self.encode_joints(new_joints).astype(dtype)], axis=-1)
            new_encoded = self.ar_encoder(new_inputs[..., None, :], latest + 1 + jnp.zeros((1,), int))
            write = lambda cache, value, axis: jax.lax.dynamic_update_index_in_dim(  # noqa: E731
                cache, value.astype(cache.dtype), latest + 1, axis)
            history = write(history, new_inputs, -2)
            joints = write(joints, new_joints, -3)
            rotations = write(rotations, geometry.rotation_6d_to_matrix(params.rot6d), -4)
            if cached:
                new_kv = self.ar.key_values(new_encoded)
                kv = KeyValues(*(write(cache, value[..., 0, :], -2) for cache, value in zip(kv, new_kv)))
                encoded = write(encoded, new_encoded[..., 0, :], -2)
            return ((history, encoded, kv, joints, rotations, root, previous, params),
                    (temporal, joint_features, params, root))

        carry = (history, encoded, kv, pad(joints, -3), pad(rotations, -4), observed.root[..., -1, :],
                 last_frame(observed.params, min(2, observed_frames)), last_frame(observed.params))
        _, (temporal, joint_features, params, roots) = jax.lax.scan(advance, carry, jnp.arange(horizon))
        move = lambda x, axis: jnp.moveaxis(x, 0, axis)  # noqa: E731
        params = SMPLParams(move(params.rot6d, -3), move(params.betas, -2), move(params.camera, -2))
        return Rollout(move(temporal, -2), move(joint_features, -2), params, move(roots, -2))

"""The thesis' autoregressive models conditioned on observed 3D poses instead of video, and the two baselines.

:class:`PoseForecaster` is PHD+T's ``f_JE``/``f_AR`` path or JAT (with or without the Joint-Aware Bias) with a pose
encoder in the backbone's place: each observed frame's pose (:func:`~dynamics.pose_features`, in the window's
frame) becomes the feature ``phi_t`` that ``f_movie`` turns into ``Phi_t``. What the video models reconstruct
from the crops, the observed frames give exactly: their SMPL rotations, shape and pelvis ``gamma_t`` enter the
rollout as they are, and ``f_JE`` encodes their joints. The rollout is the thesis model's own
(:meth:`~dynamics.PHDT.rollout`, :meth:`~dynamics.JAT.rollout`); ``f_HMR`` decodes the predicted ``Phi~`` into
poses, each refining the previous frame's pose, plain or moved on by its last step (``decode_from`` of the model
config, :func:`~dynamics.decoding_start`; a stated deviation: decoded from the mean pose, the first predicted frame
was tens of millimetres off the observed one after a CPU training, so the thesis' decoding could not beat the
baselines at short horizons). The 3D setting has no person
box: JAT's four box features are zero.

Baselines on the observed joints: :func:`zero_motion_forecast` (the last observed pose, repeated) and
:func:`constant_velocity_forecast` (each joint keeps its last observed velocity).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from flax import nnx
from jaxtyping import Array, ArrayLike, Bool, Float

import geometry

from ._hmr import SMPLParams
from ._jat import JAT, JATConfig
from ._phdt import PHDT, Observation, PHDTConfig, Rollout, params_to_joints
from ._poses import POSE_FEATURES, pose_features

__all__ = ["ForecasterConfig", "PoseForecaster", "constant_velocity_forecast", "forecast_joints",
           "zero_motion_forecast"]


_WIDTHS = {PHDTConfig: ("feature_dim", "joint_dim", "hmr_hidden", "channels_per_group"),
           JATConfig: ("feature_dim", "temporal_dim", "joint_dim", "hmr_hidden", "bias_hidden")}


@dataclasses.dataclass(frozen=True)
class ForecasterConfig:
    """A :class:`PoseForecaster`: exactly one of ``phdt`` (PHD+T's path) and ``jat`` (JAT, or MPJAT when
    ``agent_aware``)."""

    phdt: PHDTConfig | None = None
    jat: JATConfig | None = None

    def __post_init__(self) -> None:
        if (self.phdt is None) == (self.jat is None):
            raise ValueError("a forecaster is PHD+T or JAT: give exactly one of phdt and jat")

    @property
    def model(self) -> PHDTConfig | JATConfig:
        return self.phdt if self.phdt is not None else self.jat

    @property
    def num_shapes(self) -> int:
        return self.model.num_shapes

    def widened(self, factor: int) -> ForecasterConfig:
        """The same forecaster with every width of its networks (features, hidden units, groups) ``factor`` times
        larger: at 2, :data:`~dynamics.FORECASTERS`' PHD+T has the video PHD+T's sizes."""
        if factor < 1:
            raise ValueError(f"the width factor must be >= 1, got {factor}")
        return self.replace_model(**{name: factor * getattr(self.model, name) for name in _WIDTHS[type(self.model)]})

    def replace_model(self, **changes) -> ForecasterConfig:
        """The same forecaster with ``changes`` to its model's config (e.g. ``decode_from``)."""
        if self.phdt is not None:
            return ForecasterConfig(phdt=dataclasses.replace(self.phdt, **changes))
        return ForecasterConfig(jat=dataclasses.replace(self.jat, **changes))

    @classmethod
    def from_fields(cls, fields: dict) -> ForecasterConfig:
        """The config a ``config.json`` holds (nested dicts, lists for tuples)."""
        tuples = lambda d: {k: tuple(v) if isinstance(v, list) else v for k, v in d.items()}  # noqa: E731
        return cls(phdt=None if fields.get("phdt") is None else PHDTConfig(**tuples(fields["phdt"])),
                   jat=None if fields.get("jat") is None else JATConfig(**tuples(fields["jat"])))


class PoseForecaster(nnx.Module):
    """A thesis model forecasting from observed 3D poses (module docstring). Inputs are scenes: ``*b`` batches of
    ``N`` people over ``T`` frames, as :class:`~dynamics.JAT` takes them (PHD+T treats ``N`` as a batch axis)."""

    def __init__(self, config: ForecasterConfig, *, rngs: nnx.Rngs):
        self.config = config
        self.pose_encoder = nnx.Linear(POSE_FEATURES, config.model.feature_dim, rngs=rngs)
        self.model = PHDT(config.phdt, rngs=rngs) if config.phdt is not None else JAT(config.jat, rngs=rngs)

    def observe(self, rotations: Float[ArrayLike, "*b N T 24 3 3"], betas: Float[ArrayLike, "*b N T S"],
                joints: Float[ArrayLike, "*b N T 24 3"], present: Bool[ArrayLike, "*b N"] | None = None
                ) -> Observation:
        """The observed frames as the rollout takes them: ``Phi^`` from the poses, the true rotations, shape and
        pelvis, and ``Gamma^ = f_JE(joints)``."""
        rotations, betas, joints = map(jnp.asarray, (rotations, betas, joints))
        scene = joints.shape[:-2]
        if (joints.ndim < 5 or joints.shape[-2:] != (24, 3) or rotations.shape != scene + (24, 3, 3)
                or betas.shape != scene + (self.config.num_shapes,)):
            raise ValueError(f"need rotations (*b, N, T, 24, 3, 3), betas (*b, N, T, {self.config.num_shapes}) and "
                             f"joints (*b, N, T, 24, 3), got {rotations.shape}, {betas.shape} and {joints.shape}")
        features = jax.nn.gelu(self.pose_encoder(pose_features(rotations, joints)), approximate=False)
        if isinstance(self.model, JAT):
            present = jnp.ones(scene[:-1], bool) if present is None else jnp.asarray(present, bool)
            no_box = jnp.zeros(scene + (4,), features.dtype)
            temporal = self.model.condition(features, no_box, jnp.broadcast_to(jnp.eye(3, dtype=features.dtype),
                                                                               scene + (3, 3)), present)
        else:
            temporal = self.model.condition(features)
        params = SMPLParams(geometry.matrix_to_rotation_6d(rotations), betas,
                            jnp.zeros(scene + (3,), rotations.dtype))
        return Observation(temporal, params, joints[..., 0, :], self.model.encode_joints(joints))

    def decode(self, temporal: Float[Array, "*b D"], start: SMPLParams | None = None, key: jax.Array | None = None
               ) -> SMPLParams:
        """``f_HMR``: the poses of temporal features, refined from ``start`` (the previous frames' poses, when the
        model decodes from the previous frame) or the mean pose (``key``: dropout, training)."""
        return self.model.hmr(temporal, start=start, key=key)

    def rollout(self, body: geometry.BodyModel, observed: Observation, horizon: int,
                present: Bool[ArrayLike, "*b N"] | None = None) -> Rollout:
        """``horizon`` frames after ``observed``, the thesis model's autoregression without teacher forcing."""
        return self.model.rollout(body, observed, horizon, present)


def forecast_joints(model: PoseForecaster, body: geometry.BodyModel, rotations: Float[ArrayLike, "*b N T 24 3 3"],
                    betas: Float[ArrayLike, "*b N T S"], joints: Float[ArrayLike, "*b N T 24 3"], horizon: int,
                    present: Bool[ArrayLike, "*b N"] | None = None) -> Float[Array, "*b N horizon 24 3"]:
    """The joints of the ``horizon`` frames ``model`` predicts after the observed ones (metres, the pelvis at
    the predicted root)."""
    rollout = model.rollout(body, model.observe(rotations, betas, joints, present), horizon, present)
    return params_to_joints(body, rollout.params, rollout.root)


def zero_motion_forecast(joints: Float[ArrayLike, "*b T J 3"], horizon: int) -> Float[Array, "*b horizon J 3"]:
    """ZeroMotion: the last observed pose, ``horizon`` times."""
    joints = jnp.asarray(joints)
    last = joints[..., -1:, :, :]
    return jnp.broadcast_to(last, (*joints.shape[:-3], horizon, *joints.shape[-2:]))


def constant_velocity_forecast(joints: Float[ArrayLike, "*b T J 3"], horizon: int) -> Float[Array, "*b horizon J 3"]:
    """Constant velocity: every joint moves on by its last observed step per frame (needs two observed frames)."""
    joints = jnp.asarray(joints)
    if joints.shape[-3] < 2:
        raise ValueError(f"constant velocity needs at least 2 observed frames, got {joints.shape[-3]}")
    step = joints[..., -1:, :, :] - joints[..., -2:-1, :, :]
    ahead = jnp.arange(1, horizon + 1, dtype=joints.dtype).reshape((1,) * (joints.ndim - 3) + (horizon, 1, 1))
    return joints[..., -1:, :, :] + ahead * step

"""A procedural walking-and-turning person: a stand-in for the CMU clips in tests and on machines
without them. Deterministic for a given seed (NumPy ``default_rng``).

The rig is H36M-like with adult bone lengths (thigh 0.43 m, shin 0.42 m, upper arm 0.29 m, forearm
0.25 m, stature about 1.75 m, all scaled by one random factor in [0.92, 1.08]), built in the same
y-up body frame as the CMU rigs (x left, y up, z forward) and turned into the z-up world by
:func:`~mocap.build_motion`. The gait is sinusoidal (hip and shoulder swing in antiphase, knee and
elbow flexion, pelvis bob) at a random cadence, while the heading turns at a slowly varying rate.
"""

from __future__ import annotations

import numpy as np

from ._clips import Clip, clip_from_motions
from ._motion import Motion, build_motion, euler_matrices

__all__ = ["procedural_motion", "procedural_clip"]

# node: (parent, rest offset in metres in the body frame: x left, y up, z forward)
_RIG: dict[str, tuple[str | None, tuple[float, float, float]]] = {
    "pelvis": (None, (0.0, 0.0, 0.0)),
    "r_hip_joint": ("pelvis", (-0.10, -0.07, 0.0)),
    "r_knee_joint": ("r_hip_joint", (0.0, -0.43, 0.0)),
    "r_ankle_joint": ("r_knee_joint", (0.0, -0.42, 0.0)),
    "r_toe": ("r_ankle_joint", (0.0, -0.05, 0.16)),
    "l_hip_joint": ("pelvis", (0.10, -0.07, 0.0)),
    "l_knee_joint": ("l_hip_joint", (0.0, -0.43, 0.0)),
    "l_ankle_joint": ("l_knee_joint", (0.0, -0.42, 0.0)),
    "l_toe": ("l_ankle_joint", (0.0, -0.05, 0.16)),
    "spine": ("pelvis", (0.0, 0.21, 0.0)),
    "thorax": ("spine", (0.0, 0.25, 0.0)),
    "neck": ("thorax", (0.0, 0.10, 0.02)),
    "head": ("neck", (0.0, 0.07, 0.0)),
    "head_top": ("head", (0.0, 0.17, 0.0)),
    "r_shoulder_joint": ("thorax", (-0.18, 0.0, 0.0)),
    "r_elbow_joint": ("r_shoulder_joint", (0.0, -0.29, 0.0)),
    "r_wrist_joint": ("r_elbow_joint", (0.0, -0.25, 0.0)),
    "l_shoulder_joint": ("thorax", (0.18, 0.0, 0.0)),
    "l_elbow_joint": ("l_shoulder_joint", (0.0, -0.29, 0.0)),
    "l_wrist_joint": ("l_elbow_joint", (0.0, -0.25, 0.0)),
}
_NAMES = tuple(_RIG)
_PARENTS = tuple(-1 if p is None else _NAMES.index(p) for p, _ in _RIG.values())
_ANKLE_HEIGHT = 0.07  # ankle centre above the floor at rest, metres


def procedural_motion(seed: int = 0, num_frames: int = 240, fps: float = 30.0,
                      start: tuple[float, float] = (0.0, 0.0)) -> Motion:
    """A walking, turning person (metres, z-up world), starting at world ``start`` (x, y)."""
    if num_frames < 1:
        raise ValueError(f"num_frames must be positive, got {num_frames}")
    rng = np.random.default_rng(seed)
    scale = rng.uniform(0.92, 1.08)
    cadence = rng.uniform(0.8, 1.0)  # strides per second
    speed = rng.uniform(0.9, 1.4) * scale  # metres per second
    turn_amplitude, turn_period = rng.uniform(0.2, 0.6), rng.uniform(4.0, 8.0)  # rad/s, s
    heading0, phase0, turn_phase = rng.uniform(-np.pi, np.pi, size=3)
    t = np.arange(num_frames) / fps
    phase = 2 * np.pi * cadence * t + phase0
    turn_rate = turn_amplitude * np.sin(2 * np.pi * t / turn_period + turn_phase)
    heading = heading0 + np.concatenate([[0.0], np.cumsum(turn_rate[:-1]) / fps])

    angles = {name: np.zeros((num_frames, 3)) for name in _NAMES}  # (x, y, z) applied as Rz Ry Rx
    hip = 0.45 * np.sin(phase)
    angles["r_hip_joint"][:, 0] = -hip
    angles["l_hip_joint"][:, 0] = hip
    angles["r_knee_joint"][:, 0] = 0.1 + 0.55 * np.clip(np.sin(phase - 1.2), 0, None)
    angles["l_knee_joint"][:, 0] = 0.1 + 0.55 * np.clip(np.sin(phase + np.pi - 1.2), 0, None)
    angles["r_shoulder_joint"][:, 0] = 0.35 * np.sin(phase)
    angles["l_shoulder_joint"][:, 0] = -0.35 * np.sin(phase)
    angles["r_shoulder_joint"][:, 2] = -0.12
    angles["l_shoulder_joint"][:, 2] = 0.12
    angles["r_elbow_joint"][:, 0] = -0.3 - 0.15 * np.sin(phase)
    angles["l_elbow_joint"][:, 0] = -0.3 + 0.15 * np.sin(phase)
    angles["spine"][:, 1] = 0.08 * np.sin(phase)
    angles["pelvis"][:, 1] = heading - 0.06 * np.sin(phase)
    local = euler_matrices(np.stack([angles[n][:, ::-1] for n in _NAMES], axis=1), "ZYX")

    offsets = np.array([o for _, o in _RIG.values()]) * scale
    leg = -(offsets[_NAMES.index("r_hip_joint"), 1] + offsets[_NAMES.index("r_knee_joint"), 1]
            + offsets[_NAMES.index("r_ankle_joint"), 1])
    forward = np.stack([np.sin(heading), np.zeros_like(heading), np.cos(heading)], axis=-1)
    travelled = np.concatenate([np.zeros((1, 3)), np.cumsum(forward[:-1], axis=0) * speed / fps])
    # body frame y-up: x = world x, z = -world y, so start (x, y) -> (x, ., -y)
    root = travelled + np.array([start[0], 0.0, -start[1]])
    root[:, 1] = leg * np.cos(0.45) ** 0.5 + _ANKLE_HEIGHT * scale + 0.015 * np.cos(2 * phase)
    return build_motion(_NAMES, _PARENTS, offsets, local, root, fps, 1.0, name=f"procedural_{seed}")


def procedural_clip(seed: int = 0, num_frames: int = 240, fps: float = 30.0, num_people: int = 1,
                    spacing: float = 2.0) -> Clip:
    """A :class:`~mocap.Clip` of ``num_people`` procedural walkers (seeds ``seed, seed + 1, ...``)
    starting ``spacing`` metres apart along world x."""
    motions = [procedural_motion(seed + k, num_frames, fps, start=(spacing * k, 0.0)) for k in range(num_people)]
    return clip_from_motions(f"procedural_{seed}", motions, fps, "procedural walking and turning",
                             ("procedural",) * num_people)

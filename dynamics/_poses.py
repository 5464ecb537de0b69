"""3D motion for forecasting from observed poses: the CMU-Mocap benchmark's exp-map files on the body model, cut
into windows that are expressed in their last observed frame.

Each file (:func:`mocap.cmu_expmap_files`) is resampled to :data:`FORECAST_FPS` (25 Hz, so the benchmark's
horizons of 80, 160, 320, 400 and 1000 ms are whole frames: :data:`FORECAST_HORIZONS_MS`), its BODY25 joints are
retargeted to the body model with the mean shape (:func:`mocap.retarget_clip`) and posed
(:func:`geometry.body_joints`). The models and the scores see the body model's 24 joints, not the benchmark's
25 CMU joints: the same skeleton as the video models, and a stated deviation from the benchmark's joint set.

A window is expressed in a *virtual camera* frame of its last observed frame (:func:`canonical_window`): the
pelvis of that frame at the origin, the camera's y axis pointing down and its z axis into the person's front, as
if a camera at their eye line looked at them. It is the frame the HMR head's mean parameters start from (the
body upright, facing the camera: :func:`~dynamics.mean_params`), and it takes away the heading and the place of
the window, which a forecast should not depend on. MPJPE is the same in it as in the world (a rigid motion).
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import tqdm
from jaxtyping import Array, Float, Int

import geometry
import mocap
import training

__all__ = ["FORECAST_FPS", "FORECAST_HORIZONS_MS", "POSE_FEATURES", "PoseFrames", "canonical_window", "mirror_frames",
           "pose_features", "pose_frames"]

FORECAST_FPS = 25.0
"""Frames per second of the forecasting data (the CMU files are 120 Hz)."""
FORECAST_HORIZONS_MS: tuple[int, ...] = (80, 160, 320, 400, 1000)
"""The benchmark's horizons; at :data:`FORECAST_FPS` the predicted frames 2, 4, 8, 10 and 25."""
POSE_FEATURES = 24 * 6 + 24 * 3 + 3
"""One frame's input to a forecaster (:func:`pose_features`): 6D rotations, pelvis-relative joints, pelvis."""
_LEFT_HIP, _RIGHT_HIP = 1, 2  # SMPL24


class PoseFrames(NamedTuple):
    """One row per person and frame of every recording, each person's rows contiguous and in time order (as
    :class:`~dynamics.Frames`: :func:`~dynamics.window_starts`, :func:`~dynamics.scene_windows` and
    :func:`~dynamics.gather_windows` cut them)."""

    rotations: Float[np.ndarray, "F 24 3 3"]
    """Local rotations of :data:`geometry.SMPL24`; the root's (pelvis) global."""
    betas: Float[np.ndarray, "F S"]
    joints3d: Float[np.ndarray, "F 24 3"]
    """Posed joints, metres (z-up world; a window's virtual camera frame after :func:`canonical_window`)."""
    track: Int[np.ndarray, "F"]
    """Which person of which recording the row belongs to (numbered over all of them)."""
    video: Int[np.ndarray, "F"]
    """Which recording (source) the row comes from; people captured together share it (the name
    :class:`~dynamics.Frames` gives it)."""
    person: Int[np.ndarray, "F"]
    """The person's index in the recording."""
    frame: Int[np.ndarray, "F"]
    """Frame index in the recording."""

    @property
    def num_frames(self) -> int:
        return self.track.shape[0]


def _cache_file(files: Sequence[Path], body: geometry.BodyModel, fps: float, cache_dir: Path) -> Path:
    digest = hashlib.sha1(f"{fps!r} {len(files)}".encode())
    for file in files:
        digest.update(os.fsencode(file.resolve()) + file.read_bytes())
    digest.update(np.asarray(body.v_template).tobytes() + np.asarray(body.J_regressor).tobytes())
    return cache_dir / f"pose_frames_{digest.hexdigest()[:16]}.npz"


def pose_frames(sources: Sequence[str | os.PathLike], body: geometry.BodyModel, fps: float = FORECAST_FPS,
                cache_dir: str | os.PathLike | None = None, progress: bool = False) -> PoseFrames:
    """The motion of ``sources`` on ``body`` at ``fps`` (module docstring), in the order given: each a motion file of
    one person (a CMU-Mocap exp-map ``.txt``, an ``.amc``, a ``.bvh``) or the files of people captured together
    joined by ``+`` (:func:`mocap.load_clip_file`, which reads them). Cached in ``cache_dir`` when given (keyed by
    the files' contents, ``fps`` and the body)."""
    if not sources:
        raise ValueError("no motion files")
    groups = [mocap.clip_files(source) for source in sources]
    if not all(groups):
        raise ValueError(f"{sources[groups.index(())]!r} is a shipped clip (30 Hz joints), not motion files")
    path = None if cache_dir is None else _cache_file([f for group in groups for f in group], body, fps,
                                                      Path(cache_dir))
    if path is not None and path.is_file():
        with np.load(path) as stored:
            return PoseFrames(**{name: stored[name] for name in PoseFrames._fields})
    columns, track = [], 0
    for video, source in enumerate(tqdm.tqdm(sources, desc="pose frames", disable=not progress)):
        motion = mocap.retarget_clip(mocap.load_clip_file(source, fps=fps), body)
        for person in range(motion.num_people):
            rotations = motion.rotations[person].astype(np.float32)
            betas = np.broadcast_to(motion.betas[person], (len(rotations), body.num_shapes)).astype(np.float32)
            joints = _posed(body, rotations, betas[0], motion.translation[person].astype(np.float32))
            ids = [np.full(len(rotations), value, np.int32) for value in (track, video, person)]
            columns.append(PoseFrames(rotations, betas, joints, *ids, np.arange(len(rotations), dtype=np.int32)))
            track += 1
    frames = PoseFrames(*(np.concatenate(column) for column in zip(*columns)))
    if path is not None:
        training.write_atomically(path, lambda file: np.savez(file, **frames._asdict()))
    return frames


_POSE_CHUNK = 256
"""Frames posed per call of the jitted kernel (the last chunk padded): one compilation serves every recording."""


@jax.jit
def _pose_chunk(body, rotations, betas, translation):
    return jax.vmap(geometry.body_joints, in_axes=(None, 0, None, 0))(body, rotations, betas, translation)


def _posed(body: geometry.BodyModel, rotations: np.ndarray, betas: np.ndarray, translation: np.ndarray
           ) -> np.ndarray:
    """The joints ``(F, 24, 3)`` of one person's frames (float32)."""
    chunks = []
    for first in range(0, len(rotations), _POSE_CHUNK):
        size = min(_POSE_CHUNK, len(rotations) - first)
        pad = lambda x: np.concatenate([x[first:first + size],  # noqa: E731
                                        np.repeat(x[first:first + 1], _POSE_CHUNK - size, 0)])
        chunks.append(np.asarray(_pose_chunk(body, pad(rotations), betas, pad(translation)), np.float32)[:size])
    return np.concatenate(chunks)


def mirror_frames(frames: PoseFrames, body: geometry.BodyModel) -> PoseFrames:
    """The motion of ``frames`` in a mirrored world, every person's left and right swapped
    (:func:`mocap.mirror_pose`), in the frames' own precision. The mirrored rotations pose ``body`` into the mirrored
    joints when it is left-right symmetric (the stand-in body is); mirroring twice is the identity."""
    rotations, joints = mocap.mirror_pose(frames.rotations, frames.joints3d, body.skeleton)
    return frames._replace(rotations=rotations.astype(frames.rotations.dtype),
                           joints3d=joints.astype(frames.joints3d.dtype))


def canonical_window(rotations: Float[Array, "N L 24 3 3"], joints: Float[Array, "N L 24 3"], last_observed: int
                     ) -> tuple[Float[Array, "N L 24 3 3"], Float[Array, "N L 24 3"]]:
    """One window of ``N`` people (z-up world) in the virtual camera frame of the first person's frame
    ``last_observed`` (module docstring): the joints moved and turned, the root rotations turned, the local rotations
    as they are. Everyone moves together, so the people keep their places relative to each other. ``vmap`` it over
    windows."""
    up = jnp.asarray([0.0, 0.0, 1.0], joints.dtype)
    reference = joints[0, last_observed]
    hips = reference[_LEFT_HIP] - reference[_RIGHT_HIP]
    forward = jnp.cross(hips, up)  # the body's front (SMPL: left hip +x, up +y, front +z = x cross y)
    forward = forward.at[2].set(0.0)
    forward = forward / jnp.linalg.norm(forward)
    # Camera axes in world coordinates: y down, z into the person's front (the camera faces them), x = y cross z.
    y_axis, z_axis = -up, -forward
    axes = jnp.stack([jnp.cross(y_axis, z_axis), y_axis, z_axis], axis=1)  # columns
    # Row vectors: C^T (p - o) for each point is (p - o) @ C.
    moved = (joints - reference[0][None, None, None]) @ axes
    root = jnp.swapaxes(axes, 0, 1) @ rotations[:, :, 0]
    return rotations.at[:, :, 0].set(root), moved


def pose_features(rotations: Float[Array, "*b 24 3 3"], joints: Float[Array, "*b 24 3"]) -> Float[Array, "*b F"]:
    """A frame's input to a forecaster (:data:`POSE_FEATURES` values): the 6D rotations, the joints relative to the
    pelvis and the pelvis, all in the window's frame."""
    root = joints[..., 0, :]
    batch = joints.shape[:-2]
    return jnp.concatenate([geometry.matrix_to_rotation_6d(rotations).reshape(*batch, 144),
                            (joints - root[..., None, :]).reshape(*batch, 72), root], axis=-1)

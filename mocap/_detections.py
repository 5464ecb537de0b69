"""The one structure for bottom-up 2D detections, real (Shelf OpenPose files) or synthetic.

A bottom-up detector reports, per view and frame, a variable number of candidates for every joint
type, and part-affinity scores between candidates of the joint pairs in :data:`BODY25_PAF_PAIRS`.
Real and synthetic sources return the same :class:`Detections`; :func:`pad_detections` turns a
sequence of them into fixed-shape arrays for jitted code.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["BODY25_PAF_PAIRS", "Detections", "PaddedDetections", "oracle_keypoints", "pad_detections"]

BODY25_PAF_PAIRS: tuple[tuple[int, int], ...] = tuple(zip(
    (1, 9, 10, 8, 8, 12, 13, 1, 2, 3, 2, 1, 5, 6, 5, 1, 0, 0, 15, 16, 14, 19, 14, 11, 22, 11),
    (8, 10, 11, 9, 12, 13, 14, 2, 3, 4, 17, 5, 6, 7, 18, 0, 15, 16, 17, 18, 19, 20, 21, 22, 23, 24),
))
"""OpenPose BODY25 part-affinity pairs (joint a, joint b), in the order of the 4D-association files."""


class Detections(NamedTuple):
    """Bottom-up detections of one view in one frame (NumPy; variable sizes)."""

    joints: tuple[np.ndarray, ...]
    """One ``(n_j, 3)`` float array per joint type: x, y in pixels and a confidence in [0, 1]."""
    pafs: tuple[np.ndarray, ...]
    """One ``(n_a, n_b)`` array per pair in :data:`BODY25_PAF_PAIRS`: affinity of candidate i of
    joint a with candidate k of joint b."""
    person_ids: tuple[np.ndarray, ...] | None = None
    """Synthetic data only: per joint type ``(n_j,)`` int, the ground-truth person behind each
    candidate, -1 for a spurious one. ``None`` for real detections."""

    @property
    def num_joint_types(self) -> int:
        return len(self.joints)


class PaddedDetections(NamedTuple):
    """A sequence of detections as fixed-shape arrays; ``mask`` marks real candidates."""

    xy: np.ndarray  # (frames, views, joint types, candidates, 2) pixels
    score: np.ndarray  # (frames, views, joint types, candidates)
    mask: np.ndarray  # (frames, views, joint types, candidates) bool
    person_ids: np.ndarray | None  # (frames, views, joint types, candidates) int, -1 where unknown


def pad_detections(frames: list[list[Detections]], max_candidates: int | None = None) -> PaddedDetections:
    """Pad ``frames[f][v]`` detections to ``max_candidates`` per joint type (default: the largest count).

    Raises ``ValueError`` if views disagree on the number of joint types or a frame has more
    candidates than ``max_candidates``.
    """
    if not frames or not frames[0]:
        raise ValueError("pad_detections needs at least one frame with at least one view")
    n_f, n_v, n_j = len(frames), len(frames[0]), frames[0][0].num_joint_types
    largest = max(len(c) for frame in frames for det in frame for c in det.joints)
    n_c = largest if max_candidates is None else max_candidates
    if largest > n_c:
        raise ValueError(f"a view has {largest} candidates of one joint type, more than max_candidates={n_c}")
    xy = np.zeros((n_f, n_v, n_j, n_c, 2))
    score = np.zeros((n_f, n_v, n_j, n_c))
    mask = np.zeros((n_f, n_v, n_j, n_c), bool)
    has_ids = all(det.person_ids is not None for frame in frames for det in frame)
    ids = np.full((n_f, n_v, n_j, n_c), -1, np.int32)
    for f, frame in enumerate(frames):
        if len(frame) != n_v:
            raise ValueError(f"frame {f} has {len(frame)} views, frame 0 has {n_v}")
        for v, det in enumerate(frame):
            if det.num_joint_types != n_j:
                raise ValueError(f"frame {f} view {v}: {det.num_joint_types} joint types, expected {n_j}")
            for j, cand in enumerate(det.joints):
                n = len(cand)
                xy[f, v, j, :n] = cand[:, :2]
                score[f, v, j, :n] = cand[:, 2]
                mask[f, v, j, :n] = True
                if has_ids:
                    ids[f, v, j, :n] = det.person_ids[j]
    return PaddedDetections(xy, score, mask, ids if has_ids else None)


def oracle_keypoints(padded: PaddedDetections, num_people: int) -> np.ndarray:
    """Per person the best-scoring candidate of every joint type, using synthetic ground-truth ids.

    This is the *oracle* association (it reads ``person_ids``), for training targets and for
    separating triangulation error from association error; it is unavailable for real detections.
    Returns ``(frames, views, people, joint types, 3)``: x, y in pixels and the score, with zeros
    where the person has no candidate of that joint type in that view.
    """
    if padded.person_ids is None:
        raise ValueError("oracle_keypoints needs synthetic detections with person_ids")
    people = np.arange(num_people)[:, None]  # (people, 1) against candidates on the last axis
    own = padded.person_ids[..., None, :] == people  # (F, V, J, P, C)
    score = np.where(own & padded.mask[..., None, :], padded.score[..., None, :], -1.0)
    best = score.argmax(-1)  # (F, V, J, P)
    xy = np.take_along_axis(padded.xy[..., None, :, :], best[..., None, None], axis=-2)[..., 0, :]
    conf = np.take_along_axis(score, best[..., None], axis=-1)[..., 0]
    found = conf >= 0.0
    out = np.where(found[..., None], np.concatenate([xy, conf[..., None]], axis=-1), 0.0)  # (F, V, J, P, 3)
    return np.moveaxis(out, 3, 2)

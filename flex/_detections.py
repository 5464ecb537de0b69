"""FLEX on a 2D detector's keypoints (OpenPose BODY25, or its SKEL19 subset): the model's input joints.

FLEX reads :data:`geometry.STRUCTRI17` 2D joints, the Human3.6M-style set its training samples project from the
body model (spine, thorax and head top included), which no detector outputs. Each of them is taken as an affine
combination (weights summing to one) of a few nearby detector joints (:data:`INPUT_SUPPORT`), the weights fitted by
least squares on the 3D joints of the training clips (:data:`~flex.TRAIN_CLIPS`), which hold both joint sets of the
same motion. Affine combinations of 3D points project to the same combinations of their 2D points up to the
perspective division, which changes little over the span of a few joints; the 2D input is therefore made by the
same weights. A combined joint's confidence is the smallest of its support's (a missed support joint misses it).
"""

from __future__ import annotations

import functools

import numpy as np
from jaxtyping import Float

import geometry
import mocap
from geometry import STRUCTRI17, Skeleton

from ._clips import TRAIN_CLIPS

__all__ = ["INPUT_SUPPORT", "input_joint_weights", "input_from_detections"]

_SIDES = {f"{side}_{part}": tuple(f"{side}_{name}" for name in names) for side in ("r", "l") for part, names in (
    ("hip", ("hip", "knee")), ("knee", ("knee", "hip", "ankle")), ("ankle", ("ankle", "knee", "big_toe")),
    ("shoulder", ("shoulder", "elbow")), ("elbow", ("elbow", "shoulder", "wrist")), ("wrist", ("wrist", "elbow")))}

INPUT_SUPPORT: dict[str, tuple[str, ...]] = {
    "mid_hip": ("mid_hip", "r_hip", "l_hip", "neck"),
    "spine": ("mid_hip", "neck"),
    "thorax": ("neck", "r_shoulder", "l_shoulder"),
    "neck_nose": ("nose", "neck", "r_ear", "l_ear"),
    "head": ("nose", "neck", "r_ear", "l_ear"),
    **{name: (*support, "mid_hip") if name.endswith("hip") else support for name, support in _SIDES.items()},
}
"""Per STRUCTRI17 joint, the detector joints (names of :data:`geometry.SKEL19`, so of BODY25 too) whose affine
combination stands for it."""


@functools.lru_cache(maxsize=None)
def input_joint_weights(source: Skeleton = geometry.BODY25) -> Float[np.ndarray, "17 J"]:
    """The affine weights from ``source`` joints (BODY25 or SKEL19) to :data:`geometry.STRUCTRI17`, fitted on the
    training clips (module docstring); each row sums to one and is zero outside :data:`INPUT_SUPPORT`."""
    clips = [mocap.shared_clip(name) for name in TRAIN_CLIPS]
    body25 = np.concatenate([c.body25.reshape(-1, 25, 3) for c in clips])
    structri17 = np.concatenate([c.structri17.reshape(-1, 17, 3) for c in clips])
    weights = np.zeros((STRUCTRI17.num_joints, source.num_joints))
    for j, name in enumerate(STRUCTRI17.joints):
        first, *rest = INPUT_SUPPORT[name]
        base = body25[:, geometry.BODY25.index(first)]
        if rest:  # target - first = sum_k w_k (joint_k - first): the weights then sum to one with 1 - sum w_k
            design = np.stack([body25[:, geometry.BODY25.index(n)] - base for n in rest], axis=-1)
            design = design.reshape(-1, len(rest))
            w, *_ = np.linalg.lstsq(design, (structri17[:, j] - base).reshape(-1), rcond=None)
        else:
            w = np.zeros(0)
        weights[j, source.index(first)] = 1.0 - w.sum()
        for n, wk in zip(rest, w):
            weights[j, source.index(n)] = wk
    return weights


def input_from_detections(
    points: Float[np.ndarray, "*b J 2"], confidences: Float[np.ndarray, "*b J"], source: Skeleton = geometry.BODY25
) -> tuple[Float[np.ndarray, "*b 17 2"], Float[np.ndarray, "*b 17"]]:
    """Detector keypoints of ``source`` (pixels, scores >= 0 with 0 = missed) -> FLEX's STRUCTRI17 input."""
    points, confidences = np.asarray(points, np.float64), np.asarray(confidences, np.float64)
    if points.shape[-2:] != (source.num_joints, 2) or confidences.shape != points.shape[:-1]:
        raise ValueError(f"points must be (..., {source.num_joints}, 2) {source.name} pixels and confidences "
                         f"(..., {source.num_joints}), got {points.shape} and {confidences.shape}")
    if not np.all(confidences >= 0):  # NaN fails too; OpenPose's scores reach slightly above 1, which is kept
        raise ValueError("confidences must be finite detector scores >= 0 (0 = missed)")
    if not np.isfinite(points[confidences > 0]).all():
        raise ValueError("points must be finite where the confidence is positive")
    weights = input_joint_weights(source)
    support = weights != 0
    seen = np.where(confidences[..., None] > 0, points, 0.0)  # a missed joint's pixels (NaN, say) are not read
    combined = np.einsum("kj,...jc->...kc", weights, seen)
    confidence = np.min(np.where(support, confidences[..., None, :], np.inf), axis=-1)
    return combined, confidence

"""The shipped FLEX models: the synthetic experiment's main model and its ablations, saved in ``flex/assets``."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from ._model import Flex
from ._train import load_flex

__all__ = ["DETECTION_MODELS", "MAIN_MODEL", "MODELS", "RIG_MODELS", "SHIPPED_MODELS", "SKELETON_MODELS", "load_models"]

SHIPPED_MODELS = Path(__file__).parent / "assets"
MODELS: dict[str, tuple[int, Literal["early", "late"]]] = {
    "flex_4views": (4, "early"),
    "flex_3views": (3, "early"),
    "flex_2views": (2, "early"),
    "flex_1view": (1, "early"),
    "late_fusion_4views": (4, "late"),
}
"""The experiment's models: name -> (views, fusion), each the ``"small"`` config otherwise."""
RIG_MODELS: dict[str, str] = {"flex_4views_h36m_ring": "h36m_ring", "flex_4views_shelf": "shelf"}
"""FLEX (4 views, early fusion, the ``"small"`` config) trained on one fixed rig (:attr:`~flex.DataConfig.rig`), the
paper's protocol: name -> rig."""
DETECTION_MODELS: dict[str, str] = {"flex_4views_shelf_detected": "shelf"}
"""The same on one fixed rig with the 2D input made from detected BODY25 keypoints
(:attr:`~flex.DataConfig.input_joints` ``"detected"``), for a real detector's output: name -> rig."""
SKELETON_MODELS: dict[str, tuple[str, bool]] = {
    "flex_4views_h36m_ring_tpose": ("h36m_ring", True), "flex_4views_h36m_ring_no_duplicates": ("h36m_ring", False)}
"""The duplicate-joint ablation (paper App. C): a rig model of :data:`RIG_MODELS` with the T-pose rest skeleton, with
and without the duplicate joints (:attr:`~flex.FlexConfig.duplicate_joints`): name -> (rig, duplicate joints)."""
MAIN_MODEL = "flex_4views"
"""The model of :data:`MODELS` that the experiment cannot run without (FLEX, 4 views, early fusion)."""


def load_models(model_dir: str | Path = SHIPPED_MODELS) -> dict[str, Flex]:
    """The :data:`MODELS`, :data:`RIG_MODELS`, :data:`DETECTION_MODELS` and :data:`SKELETON_MODELS` saved in
    ``model_dir/<name>`` (:func:`~flex.load_flex`); absent ablation, rig, detection and skeleton models are left out,
    an absent main model is an error."""
    if not (Path(model_dir) / MAIN_MODEL / "state.npz").is_file():
        raise FileNotFoundError(f"{model_dir} has no saved main model {MAIN_MODEL}/ (config.json, state.npz)")
    names = (*MODELS, *RIG_MODELS, *DETECTION_MODELS, *SKELETON_MODELS)
    return {name: load_flex(Path(model_dir) / name) for name in names
            if (Path(model_dir) / name / "state.npz").is_file()}

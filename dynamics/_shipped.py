"""The shipped dynamics models, trained by the commands in ``dynamics/assets/README.md``."""

from __future__ import annotations

from pathlib import Path

__all__ = ["SHIPPED_FORECASTERS", "SHIPPED_MODEL", "SHIPPED_TRANSFORMERS"]

SHIPPED_MODEL = Path(__file__).resolve().parent / "assets" / "phdt"
"""The shipped backbone and PHD+T (``backbone/``, ``phdt/``), trained by the command in ``assets/README.md``."""
SHIPPED_TRANSFORMERS = Path(__file__).resolve().parent / "assets" / "transformers"
"""The shipped JAT, MPJAT and their ablations on the shipped backbone (:func:`~dynamics.load_transformers`)."""
SHIPPED_FORECASTERS = Path(__file__).resolve().parent / "assets" / "forecasters"
"""The shipped 3D forecasters (PHD+T's path, JAT, JAT without the bias) on CMU-Mocap motion
(:func:`~dynamics.load_forecasters`)."""

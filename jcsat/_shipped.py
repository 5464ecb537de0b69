"""The shipped JCSAT model."""

from __future__ import annotations

from pathlib import Path

__all__ = ["SHIPPED_MODEL"]

SHIPPED_MODEL = Path(__file__).parent / "assets" / "shelf_wide_4da"
"""The trained default model (``config.json`` + ``state.npz``; the README has the command that made it)."""

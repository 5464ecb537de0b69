"""Summary statistics shared by the studies: a mean and its spread over seeds, draws or runs."""

from __future__ import annotations

import numpy as np


def mean_and_sd(*values: float | list[float]) -> dict[str, float | list[float]]:
    """Mean and sample standard deviation (0 for one value) of numbers, or of per-frame lists frame by frame."""
    stacked = np.asarray(values, dtype=float)  # (runs,) or (runs, frames)
    sd = stacked.std(0, ddof=1) if len(stacked) > 1 else np.zeros_like(stacked[0])
    return {"mean": stacked.mean(0).tolist(), "sd": sd.tolist()}

"""The evaluation's outputs: the tables of Tables 5.2-5.11's layout, the plot of Fig. 5.1, and a strip of observed
and predicted meshes rendered into the video frames."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from matplotlib.figure import Figure

import geometry
import mocap
from dynamics import HORIZONS

__all__ = ["markdown_table", "overlay_meshes", "plot_prediction", "results_markdown"]

_NAMES = {"pa_mpjpe": "PA-MPJPE (mm) ↓", "mpjpe": "MPJPE (mm) ↓", "pck": "PCK@0.05 (%) ↑", "root": "root (mm) ↓"}
_CONDITIONING = {**_NAMES, "depth_ratio": "depth / true depth"}
PENETRATION_TITLE = "Interpenetration: mean depth of a person's sampled vertices inside the other (mm)"
GROUP_TITLES = {"single_person": "single-person samples", "two_person": "two-person samples", "all": "all samples"}


def results_markdown(summary: Mapping[str, dict]) -> str:
    """Per sample group: a conditioning table (Table 5.2's layout, and the depth ratio), one prediction table per
    metric of :data:`~dynamics.METRICS` but the depth ratio at :data:`HORIZONS` (Tables 5.4-5.11's), and for
    two-person samples the mean interpenetration depth of every method and of the ground truth."""
    frames = [f"@{k}" for k in HORIZONS]
    lines = []
    for group, result in summary.items():
        lines.append(f"## {GROUP_TITLES[group]} ({result['samples']} samples)")
        lines += markdown_table("Conditioning", list(_CONDITIONING.values()), {
            method: [f"{metrics[m]:.{digits(m)}f}" for m in _CONDITIONING]
            for method, metrics in result["conditioning"].items()}, level=3)
        for metric, title in _NAMES.items():
            lines += markdown_table(f"Prediction: {title} at future frame", frames, {
                method: [f"{metrics[metric][k - 1]:.1f}" for k in HORIZONS]
                for method, metrics in result["prediction"].items()}, level=3)
        if "penetration" in result:
            lines += markdown_table(f"{PENETRATION_TITLE} ↓", frames, {
                method: [f"{values[k - 1]:.2f}" for k in HORIZONS] for method, values in result["penetration"].items()},
                level=3)
        lines.append("")
    return "\n".join(lines)


def markdown_table(title: str, headings: Sequence[str], rows: Mapping[str, Sequence[str]], level: int = 2
                   ) -> list[str]:
    """The lines of a report's section: a blank line, ``title`` as a heading of ``level``, a blank line and a table
    with a ``method`` column holding the names of ``rows`` and a column per heading, each row's cells as formatted.
    Every table of the dynamics reports is laid out by it."""
    return ["", f"{'#' * level} {title}", "", "| method | " + " | ".join(headings) + " |", "|---|" + "---|" * len(headings),
            *(f"| {name} | " + " | ".join(cells) + " |" for name, cells in rows.items())]


def digits(metric: str) -> int:
    """Decimals a table prints of ``metric``: millimetres and percentages to 0.1, the depth ratio to 0.001."""
    return 3 if metric == "depth_ratio" else 1


def plot_prediction(summary: Mapping[str, dict], group: str, path) -> None:
    """Fig. 5.1: every metric against the future frame, one line per method."""
    result = summary[group]["prediction"]
    figure = Figure(figsize=(4 * len(_NAMES), 3.2))
    axes = figure.subplots(1, len(_NAMES))
    for axis, metric in zip(axes, _NAMES):
        for method, metrics in result.items():
            values = metrics[metric]
            axis.plot(np.arange(1, len(values) + 1), values, label=method)
        axis.set_xlabel("future frame")
        axis.set_title(_NAMES[metric])
        axis.grid(alpha=0.3)
    axes[0].legend()
    figure.suptitle(f"Prediction, {GROUP_TITLES[group]}")
    figure.tight_layout()
    figure.savefig(path, dpi=100)


def overlay_meshes(frame: np.ndarray, K: np.ndarray, vertices: Sequence[np.ndarray], body: geometry.BodyModel,
                   opacity: float = 0.7) -> np.ndarray:
    """``frame`` with the camera-frame meshes ``vertices`` (one array per person) rendered over it."""
    height, width = frame.shape[:2]
    camera = geometry.Camera(np.asarray(K, float), np.eye(3), np.zeros(3), np.zeros(5), np.array([width, height], float))
    rendering = mocap.render_people(camera, list(vertices), body, (width, height))
    covered = rendering.person >= 0
    out = frame.astype(float)
    out[covered] = (1 - opacity) * out[covered] + opacity * rendering.image[covered]
    return np.round(out).astype(np.uint8)

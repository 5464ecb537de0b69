"""One-frame figure: a person's Joint Cloud, the baseline skeletons and the ground truth in 3D, and their
reprojection into every view (matplotlib, Agg backend)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

import geometry
from geometry import SHELF15, Camera

from ._pipeline import BaselineResult

__all__ = ["plot_frame"]

_SHELF_LINES = [(SHELF15.index(a), SHELF15.index(b)) for _, a, b in SHELF15.pcp_parts]


def _skeleton_lines(ax, joints: np.ndarray, dims: int, **style) -> None:
    for a, b in _SHELF_LINES:
        if np.any(joints[a] != 0) and np.any(joints[b] != 0):
            ax.plot(*(joints[[a, b], d] for d in range(dims)), **style)


def plot_frame(
    path: str | Path,
    rig: Camera,
    padded,
    result: BaselineResult,
    frame: int,
    ground_truth: np.ndarray,
    title: str = "",
) -> None:
    """Write the figure for ``frame`` (index into the run's frames) to ``path`` (PNG).

    ``padded`` are the run's :class:`mocap.PaddedDetections`, ``ground_truth`` the annotated
    people's SHELF15 joints in that frame ``(people, 15, 3)``. The Joint Cloud shown is that of the
    track with the most clustered candidates in the frame, coloured by BODY25 joint type.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    present = np.flatnonzero(result.present[:, frame])
    label = np.asarray(result.clusters.label[frame])  # (P, J, C, C)
    slots = np.flatnonzero(np.asarray(result.clusters.active[frame]))
    counts = [(label == s).sum() for s in slots]
    slot = int(slots[int(np.argmax(counts))]) if len(slots) else -1
    chosen = label == slot
    points = np.asarray(result.cloud.point[frame])[chosen]  # (n, 3)
    joint_type = np.nonzero(chosen)[1]
    shelf15 = np.asarray(geometry.to_shelf15(result.body25[:, frame], geometry.BODY25))
    shelf15 = np.where(np.asarray(geometry.to_shelf15_validity(result.body25_valid[:, frame], geometry.BODY25))[..., None],
                       shelf15, 0.0)

    num_views = rig.K.shape[0]
    fig = plt.figure(figsize=(16, 9))
    colours = plt.get_cmap("tab20", 25)(np.arange(25))
    ax = fig.add_subplot(2, 3, 1, projection="3d")
    ax.scatter(*points.T, c=colours[joint_type], s=6, alpha=0.6, label="Joint Cloud (one person)")
    for i, t in enumerate(present):
        _skeleton_lines(ax, shelf15[t], 3, color=f"C{i}", linewidth=2)
    for person in ground_truth:
        _skeleton_lines(ax, person, 3, color="k", linestyle="--", linewidth=1)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    ax.set_title("3D: cloud (by joint type), baseline (colour), GT (black dashed)", fontsize=9)

    for v in range(min(num_views, 5)):  # the grid has room for five views (Shelf)
        camera = rig.select(v)
        width, height = np.asarray(camera.image_size)
        axv = fig.add_subplot(2, 3, 2 + v)
        real = padded.mask[frame, v]
        xy = padded.xy[frame, v][real]
        axv.scatter(xy[:, 0], xy[:, 1], s=4, c="0.6")
        for i, t in enumerate(present):
            _skeleton_lines(axv, np.asarray(geometry.project(camera, shelf15[t])), 2, color=f"C{i}", linewidth=2)
        for person in ground_truth:
            _skeleton_lines(axv, np.asarray(geometry.project(camera, person)), 2, color="k", linestyle="--", linewidth=1)
        axv.set_xlim(0, width)
        axv.set_ylim(height, 0)
        axv.set_aspect("equal")
        axv.set_title(f"view {v}: detections (grey), baseline, GT", fontsize=9)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)

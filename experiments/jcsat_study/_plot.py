"""One-frame figure: a person's Joint Cloud, the baseline skeletons and the ground truth in 3D, and their
reprojection into every view (matplotlib's object API: no backend, no pyplot).

Ground truth is drawn thick and black under the predictions; a predicted track is coloured when it
matches a ground-truth person (mean joint distance below :data:`MATCH_DISTANCE_M`) and drawn thin,
grey and dotted (labelled "unmatched") otherwise. Without ground truth (a user's own recording), every output
track takes the colour of its rank among the output tracks, as in the interactive viewer
(:func:`mocap.person_colour`).
"""

from __future__ import annotations

from pathlib import Path

import matplotlib
import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

import geometry
from association import BaselineResult
from geometry import SHELF15, Camera
from mocap import person_colour

__all__ = ["plot_frame", "MATCH_DISTANCE_M", "matched_tracks"]

MATCH_DISTANCE_M = 0.5
"""Metres: a track matches a ground-truth person when their mean Shelf15 joint distance is below this
(the JCSAT protocol's gate)."""

_SHELF_LINES = [(SHELF15.index(a), SHELF15.index(b)) for _, a, b in SHELF15.pcp_parts]


def _skeleton_lines(ax, joints: np.ndarray, dims: int, **style) -> None:
    for a, b in _SHELF_LINES:
        if np.any(joints[a] != 0) and np.any(joints[b] != 0):
            ax.plot(*(joints[[a, b], d] for d in range(dims)), **style)


def _track_shelf15(result: BaselineResult, frame: int) -> np.ndarray:
    """(T, 15, 3) Shelf15 joints of every track in ``frame`` (0 where the track lacks the joint)."""
    shelf15 = np.asarray(geometry.to_shelf15(result.body25[:, frame], geometry.BODY25))
    valid = np.asarray(geometry.to_shelf15_validity(result.body25_valid[:, frame], geometry.BODY25))
    return np.where(valid[..., None], shelf15, 0.0)


def matched_tracks(
    result: BaselineResult, frame: int, ground_truth: np.ndarray, track_poses: np.ndarray | None = None
) -> dict[int, int]:
    """Output tracks present in ``frame`` that match a ground-truth person: ``{track: person}``.

    Only tracks in the predictions count (short-lived tracks are not output); each ground-truth
    person takes its nearest track by mean joint distance if below :data:`MATCH_DISTANCE_M`.
    ``track_poses`` are the Shelf15 poses ``(T, 15, 3)`` judged (default: the baseline's).
    """
    output = set(np.unique(result.predictions.person).tolist())
    tracks = [t for t in np.flatnonzero(result.present[:, frame]) if int(t) in output]
    if not tracks or not len(ground_truth):
        return {}
    joints = (_track_shelf15(result, frame) if track_poses is None else track_poses)[tracks]
    distance = np.linalg.norm(joints[:, None] - ground_truth[None], axis=-1).mean(-1)  # (tracks, people)
    matches = {}
    for person in range(len(ground_truth)):
        best = int(np.argmin(distance[:, person]))
        if distance[best, person] < MATCH_DISTANCE_M:
            matches[int(tracks[best])] = person
    return matches


def plot_frame(
    path: str | Path,
    rig: Camera,
    padded,
    result: BaselineResult,
    frame: int,
    ground_truth: np.ndarray | None,
    title: str = "",
    track_poses: np.ndarray | None = None,
) -> None:
    """Write the figure for ``frame`` (index into the run's frames) to ``path`` (PNG).

    ``padded`` are the run's :class:`mocap.PaddedDetections`, ``ground_truth`` the annotated
    people's SHELF15 joints in that frame ``(people, 15, 3)`` or None. The Joint Cloud shown is that of the
    track with the most clustered candidates in the frame, coloured by BODY25 joint type. The
    skeletons drawn are ``track_poses`` ``(T, 15, 3)`` (default: the baseline's poses).
    """
    output = np.unique(result.predictions.person).tolist()
    present = [int(t) for t in np.flatnonzero(result.present[:, frame]) if int(t) in output]
    shelf15 = _track_shelf15(result, frame) if track_poses is None else track_poses
    if ground_truth is None:  # colour by output rank, as the viewer does
        ground_truth, colour_of = np.zeros((0, 15, 3)), {t: output.index(t) for t in present}
    else:
        colour_of = matched_tracks(result, frame, ground_truth, shelf15)
    label = np.asarray(result.clusters.label[frame])  # (P, J, C, C)
    slots = np.flatnonzero(np.asarray(result.clusters.active[frame]))
    counts = [(label == s).sum() for s in slots]
    slot = int(slots[int(np.argmax(counts))]) if len(slots) else -1
    chosen = label == slot
    points = np.asarray(result.cloud.point[frame])[chosen]  # (n, 3)
    joint_type = np.nonzero(chosen)[1]

    def track_style(t: int) -> dict:
        if t in colour_of:
            return {"color": person_colour(colour_of[t]), "linewidth": 1.8}
        return {"color": "0.5", "linestyle": ":", "linewidth": 1.0}

    gt_style = {"color": "k", "linewidth": 4.0, "alpha": 0.45}

    num_views = rig.K.shape[0]
    fig = Figure(figsize=(16, 9))
    colours = matplotlib.colormaps["tab20"].resampled(25)(np.arange(25))
    ax = fig.add_subplot(2, 3, 1, projection="3d")
    ax.scatter(*points.T, c=colours[joint_type], s=6, alpha=0.6, label="Joint Cloud (one person)")
    for person in ground_truth:
        _skeleton_lines(ax, person, 3, **gt_style)
    for t in present:
        _skeleton_lines(ax, shelf15[t], 3, **track_style(t))
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    legend = [Line2D([], [], linestyle="", marker="o", markersize=4, color=colours[1], label="Joint Cloud")]
    if len(ground_truth):
        spurious = len(present) - len(colour_of)
        ax.set_title(f"3D: one person's Joint Cloud (by joint type); GT (thick black); tracks matched to GT "
                     f"(colour of the GT person: {len(colour_of)}/{len(ground_truth)}); unmatched (grey dotted): "
                     f"{spurious}", fontsize=8, wrap=True)
        legend.append(Line2D([], [], label="ground truth", **gt_style))
        legend += [Line2D([], [], label=f"track {t} = GT person {colour_of[t] + 1}", **track_style(t))
                   for t in present if t in colour_of]
        legend += [Line2D([], [], label="unmatched track", **track_style(-1))] if spurious else []
    else:
        ax.set_title("3D: one person's Joint Cloud (by joint type) and every person", fontsize=8)
        legend += [Line2D([], [], label=f"person {t}", **track_style(t)) for t in present]
    ax.legend(handles=legend, fontsize=7, loc="upper left")

    for v in range(min(num_views, 5)):  # the grid has room for five views (Shelf)
        camera = rig.select(v)
        width, height = np.asarray(camera.image_size)
        axv = fig.add_subplot(2, 3, 2 + v)
        real = padded.mask[frame, v]
        xy = padded.xy[frame, v][real]
        axv.scatter(xy[:, 0], xy[:, 1], s=4, c="0.6")
        for person in ground_truth:
            _skeleton_lines(axv, np.asarray(geometry.project(camera, person)), 2, **gt_style)
        for t in present:
            _skeleton_lines(axv, np.asarray(geometry.project(camera, shelf15[t])), 2, **track_style(t))
        axv.set_xlim(0, width)
        axv.set_ylim(height, 0)
        axv.set_aspect("equal")
        axv.set_title(f"view {v}: detections (grey dots)" + (", GT (thick black), matched tracks (colour)"
                                                             if len(ground_truth) else ", people (colour)"), fontsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=80)

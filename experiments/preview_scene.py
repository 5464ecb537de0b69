"""Draw one frame of a synthetic scene or of the real Shelf data: 2D detections per view and 3D truth.

Usage::

    python -m experiments.preview_scene --source synthetic --frame 10 --out synthetic.png --seed 0
    python -m experiments.preview_scene --source shelf --frame 10 --out shelf.png --data-root PATH

One panel per view shows the detections on a blank canvas of the view's image size (candidates as
dots whose area grows with the score, coloured by person when known, by joint type otherwise; BODY25
limbs joined between candidates of the same person, or between the best-PAF candidates for real
data; the ground truth projected as thin grey lines). The last panel shows the ground-truth
skeletons in the world (metres, z up) with the cameras.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path
from typing import BinaryIO, Literal

import jax
import numpy as np

import geometry
import mocap
import training
from experiments import _cli
from geometry import BODY25, SHELF14, SHELF15


def _paf_limbs(det, pair_index: int, a: int, b: int, min_paf: float = 0.1) -> list[tuple[int, int]]:
    """Greedy one-to-one matching of the candidates of joints a and b by decreasing PAF score."""
    paf = det.pafs[pair_index]
    order = np.argsort(-paf, axis=None)
    used_a, used_b, out = set(), set(), []
    for flat in order:
        i, k = np.unravel_index(flat, paf.shape)
        if paf[i, k] < min_paf:
            break
        if i not in used_a and k not in used_b:
            used_a.add(i)
            used_b.add(k)
            out.append((int(i), int(k)))
    return out


def _person_limbs(det, a: int, b: int) -> list[tuple[int, int]]:
    """Pairs (i, k) of candidates of joints a and b with the same person id (best score of each)."""
    out = []
    ids_a, ids_b = det.person_ids[a], det.person_ids[b]
    for person in np.intersect1d(ids_a[ids_a >= 0], ids_b[ids_b >= 0]):
        i = np.flatnonzero(ids_a == person)[np.argmax(det.joints[a][ids_a == person, 2])]
        k = np.flatnonzero(ids_b == person)[np.argmax(det.joints[b][ids_b == person, 2])]
        out.append((int(i), int(k)))
    return out


def draw_frame(
    out: str | os.PathLike | BinaryIO,
    rig,
    detections,
    truth: np.ndarray,
    truth_skeleton,
    title: str,
    area: tuple[float, float, float, float] | None = None,
) -> None:
    """Write a PNG of one frame: ``detections[view]`` (:class:`~mocap.Detections`) and ``truth``
    ``(people, joints, 3)`` metres in ``truth_skeleton``'s joint order."""
    # A bare Figure draws with Agg without pyplot, so the caller's matplotlib backend stays as it was.
    from matplotlib import colormaps
    from matplotlib.figure import Figure
    from matplotlib.patches import Rectangle

    from mocap._detections import BODY25_PAF_PAIRS

    n_views = len(detections)
    n_cols = 3
    n_rows = -(-(n_views + 1) // n_cols)
    fig = Figure(figsize=(6.0 * n_cols, 4.8 * n_rows), dpi=80)
    joint_colours = colormaps["hsv"]
    sizes = np.asarray(rig.image_size)
    truth_px = np.asarray(geometry.project_to_views(rig, truth)) if len(truth) else np.zeros((n_views, 0, 1, 2))
    truth_depth = np.stack([np.asarray(geometry.depth(rig.select(v), truth)) for v in range(n_views)]) if len(truth) else None
    for v, det in enumerate(detections):
        ax = fig.add_subplot(n_rows, n_cols, v + 1)
        width, height = sizes[v]
        ax.add_patch(Rectangle((0, 0), width, height, facecolor="#f4f4f4", edgecolor="black", lw=0.8))
        for p in range(truth_px.shape[1]):
            for parent, child in truth_skeleton.bones:
                if truth_depth[v, p, parent] > 0.1 and truth_depth[v, p, child] > 0.1:
                    seg = truth_px[v, p, [parent, child]]
                    ax.plot(seg[:, 0], seg[:, 1], color="0.55", lw=0.8, ls="--", zorder=1)
        known = det.person_ids is not None
        for k, (a, b) in enumerate(BODY25_PAF_PAIRS):
            pairs = _person_limbs(det, a, b) if known else _paf_limbs(det, k, a, b)
            for i, m in pairs:
                seg = np.stack([det.joints[a][i, :2], det.joints[b][m, :2]])
                colour = mocap.person_colour(det.person_ids[a][i]) if known else joint_colours(k / len(BODY25_PAF_PAIRS))
                ax.plot(seg[:, 0], seg[:, 1], color=colour, lw=1.6, alpha=0.8, zorder=2)
        for j, cand in enumerate(det.joints):
            if not len(cand):
                continue
            if known:
                ids = det.person_ids[j]
                colours = [mocap.person_colour(i) if i >= 0 else (0.2, 0.2, 0.2, 1.0) for i in ids]
                markers = np.where(ids >= 0, "o", "x")
            else:
                colours = [joint_colours(j / BODY25.num_joints)] * len(cand)
                markers = np.full(len(cand), "o")
            for marker in ("o", "x"):
                sel = markers == marker
                if sel.any():
                    ax.scatter(cand[sel, 0], cand[sel, 1], s=4 + 40 * cand[sel, 2], c=[colours[i] for i in np.flatnonzero(sel)],
                               marker=marker, edgecolors="none" if marker == "o" else None, zorder=3)
        n_cand = sum(len(c) for c in det.joints)
        ax.set_title(f"view {v}: {n_cand} candidates", fontsize=10)
        ax.set_xlim(-0.02 * width, 1.02 * width)
        ax.set_ylim(1.02 * height, -0.02 * height)
        ax.set_aspect("equal")
        ax.tick_params(labelsize=7)

    ax = fig.add_subplot(n_rows, n_cols, n_views + 1, projection="3d")
    centres = np.asarray(geometry.camera_centre(rig))
    axes = np.asarray(rig.R)[:, 2]
    for v in range(n_views):
        tip = centres[v] + 0.6 * axes[v]
        ax.plot(*np.stack([centres[v], tip]).T, color="black", lw=1.2)
        ax.text(*centres[v], f" {v}", fontsize=8)
    ax.scatter(*centres.T, color="black", marker="^", s=25)
    for p, person in enumerate(truth):
        for parent, child in truth_skeleton.bones:
            ax.plot(*person[[parent, child]].T, color=mocap.person_colour(p), lw=2)
    if area is not None:
        x0, y0, x1, y1 = area
        ax.plot([x0, x1, x1, x0, x0], [y0, y0, y1, y1, y0], [0, 0, 0, 0, 0], color="0.6", lw=0.8)
    points = np.concatenate([centres, truth.reshape(-1, 3)]) if len(truth) else centres
    low, high = points.min(0), points.max(0)
    low[2] = min(low[2], 0.0)
    middle, half = (low + high) / 2, (high - low).max() / 2 + 0.2
    ax.set_xlim(middle[0] - half, middle[0] + half)
    ax.set_ylim(middle[1] - half, middle[1] + half)
    ax.set_zlim(max(middle[2] - half, low[2] - 0.1), middle[2] + half)
    ax.set_box_aspect((1, 1, 1))
    ax.set_xlabel("x (m)", fontsize=8)
    ax.set_ylabel("y (m)", fontsize=8)
    ax.set_zlabel("z (m)", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.view_init(elev=25, azim=-60)
    ax.set_title("ground truth (z up) and cameras", fontsize=10)
    fig.suptitle(title, fontsize=12)
    fig.tight_layout()
    fig.savefig(out, format="png")


@dataclasses.dataclass(frozen=True)
class Config:
    out: Path
    """Output PNG path."""
    source: Literal["synthetic", "shelf"] = "synthetic"
    """synthetic: a scene from mocap.synthesise_scene on the Shelf rig; shelf: the real Shelf OpenPose detections
    and actorsGT ground truth (needs a data folder)."""
    frame: int = 0
    """Frame index: scene frame for synthetic; detection frame k (0..300) for shelf, shown with actorsGT frame
    300 + k."""
    data_root: Path | None = None
    """Folder with shelf/ (the real data; default $MVMOCAP_DATA_ROOT)."""
    seed: int = 0
    """Synthetic only: the PRNG seed of the scene."""
    num_people: int = 4
    """Synthetic only: people in the scene."""
    num_frames: int | None = None
    """Synthetic only: frames simulated (default frame + 1; the scene depends on it)."""
    rig: Literal["shelf", "campus"] = "shelf"
    """Synthetic only: the camera rig the scene is seen by."""

    def __post_init__(self) -> None:
        if self.frame < 0:
            raise ValueError(f"--frame must be >= 0, got {self.frame}")
        if self.source == "synthetic" and self.num_frames is not None and self.frame >= self.num_frames:
            raise ValueError(f"--frame {self.frame} is outside the {self.num_frames} simulated frames")
        if self.source == "shelf":
            root = mocap.find_data_root(self.data_root)
            needed = [] if root is None else [root / "shelf" / "actorsGT.mat",
                                              root / "shelf" / "4d_association" / "detection" / "0.txt"]
            missing = [str(p) for p in needed if not p.is_file()]
            if root is None or missing:
                raise ValueError("--source shelf needs the real Shelf data; "
                                 + (f"missing: {', '.join(missing)}" if missing else "no data folder")
                                 + " (pass --data-root or set $MVMOCAP_DATA_ROOT to the folder with shelf/)")


def main(config: Config) -> None:
    if config.source == "synthetic":
        num_frames = config.frame + 1 if config.num_frames is None else config.num_frames
        rig = mocap.shelf_cameras() if config.rig == "shelf" else mocap.campus_cameras()
        scene = mocap.synthesise_scene(jax.random.key(config.seed), rig, num_people=config.num_people,
                                       num_frames=num_frames)
        f = config.frame
        title = (f"synthetic scene, seed {config.seed}, frame {f}: "
                 + ", ".join(sorted(set(n.split("[")[0] for n in scene.placement.names))))
        figure = (rig, scene.detections[f], scene.shelf15[f], SHELF15, title, mocap.capture_area(rig))
    else:
        root = mocap.find_data_root(config.data_root)
        frames, gt_index = mocap.load_shelf_detections(root)
        if config.frame >= len(frames):
            raise ValueError(f"--frame {config.frame} is outside the {len(frames)} Shelf detection frames")
        positions, annotated = mocap.load_shelf_ground_truth(root)
        g = int(gt_index[config.frame])
        truth = positions[annotated[:, g], g]
        title = (f"Shelf, detection frame {config.frame} = actorsGT frame {g}: "
                 f"{len(truth)} annotated actors (OpenPose BODY25, limbs by best PAF)")
        figure = (mocap.shelf_cameras(root), frames[config.frame], truth, SHELF14, title)
    training.write_atomically(config.out, lambda file: draw_frame(file, *figure))
    print(f"wrote {config.out}")


if __name__ == "__main__":
    _cli.run(main, Config, description=__doc__, float64=True)

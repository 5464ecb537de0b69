"""A reconstructed multi-person scene seen in 3D: an interactive page and an animation.

:func:`write_scene_html` writes one self-contained HTML file (inline script, style and data; it opens
from disk without network access) that draws, on a 2D canvas with its own perspective projection, the
skeletons of the people present at the current frame (bones as lines, joints as dots, one colour per
person), the ground grid at z = 0 (1 m spacing), the cameras as frusta from their centre toward the
image corners at :data:`FRUSTUM_DEPTH_M` (distortion ignored) with their names, a legend (people absent
from the frame are greyed out), a frame slider, a play/pause button and a frame counter. Drag orbits,
shift-drag or right-drag pans, the wheel zooms, space plays and the arrow keys step. ``?frame=k`` in the
URL opens frame k; after the first draw the page sets ``window.viewerReady = true`` and
``<body data-ready="1">``, and script errors are written into ``<div id="errors">`` (for headless checks).

:func:`write_scene_animation` writes a GIF (or an MP4 when ffmpeg is installed) of the same scene with
matplotlib's object API on an Agg canvas (no pyplot, no backend change).

Data conventions: ``joints (people, frames, J, 3)`` in metres, world z up, in ``skeleton``'s joint order;
``present (people, frames)`` bool says which poses exist (absent poses may hold anything, NaN included);
``rig`` a :class:`geometry.Camera` with a leading views axis. Person i is drawn in :func:`person_colour`
(i), the colour the project's static figures give person i. The page stores positions as integer
millimetres (1 mm rounding keeps the file small).
"""

from __future__ import annotations

import html
import json
import math
import os
import shutil
import subprocess
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np
from jaxtyping import ArrayLike

import geometry
from geometry import Camera, Skeleton

__all__ = ["FRUSTUM_DEPTH_M", "person_colour", "write_scene_html", "write_scene_animation"]

FRUSTUM_DEPTH_M = 0.3
"""Metres from a camera's centre to the image rectangle of its drawn frustum."""

# matplotlib's tab10 (its default colour cycle "C0".."C9"), written out so that the page needs no matplotlib;
# tests/test_scene_viewer.py checks the two agree.
_TAB10 = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf")


def person_colour(index: int | np.integer) -> str:
    """Hex colour (``"#rrggbb"``) of person or track ``index``: matplotlib's tab10, cycling after 10."""
    return _TAB10[int(index) % len(_TAB10)]


class _Scene(NamedTuple):
    joints: np.ndarray
    """(people, frames, J, 3) metres; absent poses set to 0."""
    present: np.ndarray
    names: list[str]
    centres: np.ndarray
    """(views, 3) camera centres, metres."""
    corners: np.ndarray
    """(views, 4, 3) frustum corners (image top-left, top-right, bottom-right, bottom-left), metres."""
    camera_names: list[str]


def _checked(joints, present, skeleton: Skeleton, rig: Camera | None, names, camera_names, fps: float) -> _Scene:
    """The inputs as NumPy arrays, or a one-line ``ValueError`` saying what is wrong."""
    joints = np.asarray(joints, float)
    present = np.asarray(present)
    if joints.ndim != 4 or joints.shape[-1] != 3:
        raise ValueError(f"joints must have shape (people, frames, joints, 3), got {joints.shape}")
    if joints.shape[2] != skeleton.num_joints:
        raise ValueError(f"joints have {joints.shape[2]} joints per pose but {skeleton.name} has {skeleton.num_joints}")
    if present.shape != joints.shape[:2]:
        raise ValueError(f"present has shape {present.shape}, expected (people, frames) = {joints.shape[:2]}")
    if present.dtype != bool:
        raise ValueError(f"present must be boolean, got dtype {present.dtype}")
    if joints.shape[1] == 0:
        raise ValueError("the scene has no frames")
    bad = present & ~np.isfinite(joints).all(axis=(2, 3))
    if bad.any():
        person, frame = np.argwhere(bad)[0]
        raise ValueError(f"person {person} is present at frame {frame} but its joints hold NaN or inf")
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be positive, got {fps}")
    names = [f"person {p}" for p in range(len(joints))] if names is None else [str(n) for n in names]
    if len(names) != len(joints):
        raise ValueError(f"{len(names)} names for {len(joints)} people")
    centres, corners = _frusta(rig)
    if camera_names is None:
        camera_names = [f"camera {v}" for v in range(len(centres))]
    camera_names = [str(n) for n in camera_names]
    if len(camera_names) != len(centres):
        raise ValueError(f"{len(camera_names)} camera names for {len(centres)} cameras")
    return _Scene(np.where(present[..., None, None], joints, 0.0), present, names, centres, corners, camera_names)


def _frusta(rig: Camera | None) -> tuple[np.ndarray, np.ndarray]:
    """Centres (views, 3) and image corners at :data:`FRUSTUM_DEPTH_M` (views, 4, 3), world metres."""
    if rig is None:
        return np.zeros((0, 3)), np.zeros((0, 4, 3))
    K, R, t, size = (np.asarray(a, float) for a in (rig.K, rig.R, rig.t, rig.image_size))
    if K.ndim == 2:  # one camera
        K, R, t, size = K[None], R[None], t[None], size[None]
    w, h = size[:, 0], size[:, 1]
    pixels = np.stack([np.stack([u, v, np.ones_like(u)], -1)
                       for u, v in ((0 * w, 0 * h), (w, 0 * h), (w, h), (0 * w, h))], 1)  # (views, 4, 3)
    rays = np.einsum("vij,vcj->vci", np.linalg.inv(K), pixels)  # camera frame, z = 1
    camera_points = FRUSTUM_DEPTH_M * rays - t[:, None]
    corners = np.einsum("vji,vcj->vci", R, camera_points)  # R^T (x_cam - t)
    return np.asarray(geometry.camera_centre(rig), float).reshape(-1, 3), corners


def _millimetres(points: np.ndarray) -> list:
    return np.round(np.asarray(points) * 1000).astype(int).tolist()


def write_scene_html(
    path: str | os.PathLike,
    joints: ArrayLike,
    present: ArrayLike,
    skeleton: Skeleton,
    rig: Camera | None = None,
    *,
    names: Sequence[str] | None = None,
    camera_names: Sequence[str] | None = None,
    fps: float = 25.0,
    title: str = "",
) -> None:
    """Write the interactive viewer of the scene to ``path`` (one HTML file, see the module docstring).

    ``names`` label the people (default ``"person i"``), ``camera_names`` the cameras (default
    ``"camera v"``); ``fps`` sets the playback rate and the time shown beside the frame number."""
    scene = _checked(joints, present, skeleton, rig, names, camera_names, fps)
    people = [
        {"name": name, "colour": person_colour(p),
         "poses": [_millimetres(pose.ravel()) if here else None
                   for pose, here in zip(scene.joints[p], scene.present[p])]}
        for p, name in enumerate(scene.names)
    ]
    cameras = [{"name": name, "centre": _millimetres(centre), "corners": _millimetres(corners)}
               for name, centre, corners in zip(scene.camera_names, scene.centres, scene.corners)]
    data = {
        "title": title, "fps": float(fps), "frames": scene.joints.shape[1],
        "bones": [list(bone) for bone in skeleton.bones], "people": people, "cameras": cameras,
        **_framing(scene),
    }
    # "</" would end the <script> element that holds the data (a name such as "</script>").
    text = _PAGE.replace("__TITLE__", html.escape(title or "scene")).replace(
        "__DATA__", json.dumps(data, separators=(",", ":")).replace("</", "<\\/"))
    geometry.replace_file(Path(path), lambda temporary: temporary.write_text(text, encoding="utf-8"))


def _framing(scene: _Scene) -> dict:
    """The grid's extent and the opening view (millimetres): aimed at the people, everything in sight."""
    people = scene.joints[scene.present].reshape(-1, 3)
    cameras = np.concatenate([scene.centres, scene.corners.reshape(-1, 3)])
    everything = np.concatenate([people, cameras, np.zeros((1, 3))])
    focus = people if len(people) else everything
    target = (focus.min(0) + focus.max(0)) / 2
    radius = max(float(np.linalg.norm(everything - target, axis=1).max()), 1.0)
    low = np.floor(everything[:, :2].min(0) - 0.5)
    high = np.ceil(everything[:, :2].max(0) + 0.5)
    # The page's vertical field of view is 45 degrees; sin(22.5 deg) = 0.38 fits a sphere of that radius.
    return {"grid": {"min": _millimetres(low), "max": _millimetres(high), "step": 1000},
            "view": {"target": _millimetres(target), "distance": round(1000 * radius / 0.38),
                     "azimuth": math.radians(-60.0), "elevation": math.radians(25.0)}}


def _frame_indices(num_frames: int, max_frames: int | None) -> np.ndarray:
    """All frames, or ``max_frames`` of them evenly spread from the first to the last."""
    if max_frames is None or max_frames >= num_frames:
        return np.arange(num_frames)
    if max_frames < 1:
        raise ValueError(f"max_frames must be at least 1, got {max_frames}")
    return np.unique(np.round(np.linspace(0, num_frames - 1, max_frames)).astype(int))


def write_scene_animation(
    path: str | os.PathLike,
    joints: ArrayLike,
    present: ArrayLike,
    skeleton: Skeleton,
    rig: Camera | None = None,
    *,
    fps: float = 25.0,
    names: Sequence[str] | None = None,
    max_frames: int | None = None,
) -> None:
    """Write the scene over time to ``path``: a GIF for ``.gif``, an MP4 for ``.mp4`` (needs ffmpeg).

    Fixed axes covering every frame and camera, one colour per person (:func:`person_colour`) with a
    legend, cameras as black triangles. With ``max_frames`` the animation shows that many frames spread
    over the whole scene and still plays in real time (each lasts longer)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".gif", ".mp4"):
        raise ValueError(f"the animation's file must end in .gif or .mp4, got {path.name!r}")
    if suffix == ".mp4" and shutil.which("ffmpeg") is None:
        raise RuntimeError(f"writing {path.name} needs ffmpeg on the PATH, which is missing; write a .gif instead")
    scene = _checked(joints, present, skeleton, rig, names, None, fps)
    frames = _frame_indices(scene.joints.shape[1], max_frames)
    frame_fps = fps * len(frames) / scene.joints.shape[1]

    # A bare Figure draws with Agg without pyplot, so the caller's matplotlib backend stays as it was.
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6.4, 5.2), dpi=80)
    canvas = FigureCanvasAgg(fig)
    ax = fig.add_subplot(projection="3d")
    fig.subplots_adjust(left=0, right=0.97, bottom=0.03, top=1)
    points = np.concatenate([scene.joints[scene.present].reshape(-1, 3), scene.centres, np.zeros((1, 3))])
    low, high = points.min(0) - 0.2, points.max(0) + 0.2
    low[2] = min(0.0, low[2] + 0.2)  # down to the floor
    ax.set_xlim(low[0], high[0])
    ax.set_ylim(low[1], high[1])
    ax.set_zlim(low[2], high[2])
    ax.set_box_aspect(high - low)  # a metre as long on every axis
    ax.set_xlabel("x (m)", fontsize=8)
    ax.set_ylabel("y (m)", fontsize=8)
    ax.set_zlabel("z (m)", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.view_init(elev=25, azim=-60)
    if len(scene.centres):
        ax.scatter(*scene.centres.T, color="black", marker="^", s=20)
        for centre, name in zip(scene.centres, scene.camera_names):
            ax.text(*centre, f" {name}", fontsize=6)
    # Per person, one line for all bones (NaN rows break it between bones) and one for the joints; they and
    # the frame number are "animated": drawn over a saved picture of the rest, since the axes' ticks, panes
    # and labels take most of a full draw and never change.
    bones = np.array(skeleton.bones)
    bone_lines = [ax.plot([], [], [], color=person_colour(p), lw=2, label=name, animated=True)[0]
                  for p, name in enumerate(scene.names)]
    joint_dots = [ax.plot([], [], [], color=person_colour(p), ls="", marker="o", ms=2.5, animated=True)[0]
                  for p in range(len(scene.names))]
    if scene.names:
        fig.legend(loc="upper left", fontsize=7)
    caption = fig.text(0.5, 0.95, "", ha="center", fontsize=9, animated=True)
    canvas.draw()
    background = canvas.copy_from_bbox(fig.bbox)

    def rendered() -> Iterator[np.ndarray]:
        """Each chosen frame as an RGBA image (height, width, 4) uint8."""
        for frame in frames:
            canvas.restore_region(background)
            for p in np.flatnonzero(scene.present[:, frame]):
                pose = scene.joints[p, frame]
                segments = np.concatenate([pose[bones], np.full((len(bones), 1, 3), np.nan)], axis=1).reshape(-1, 3)
                bone_lines[p].set_data_3d(*segments.T)
                joint_dots[p].set_data_3d(*pose.T)
                ax.draw_artist(bone_lines[p])
                ax.draw_artist(joint_dots[p])
            caption.set_text(f"frame {frame} ({frame / fps:.2f} s)")
            fig.draw_artist(caption)
            yield np.array(canvas.buffer_rgba())  # a copy: the canvas buffer is reused

    def write_gif(temporary: Path) -> None:
        from PIL import Image

        images = [Image.fromarray(rgba[..., :3]) for rgba in rendered()]
        images[0].save(temporary, save_all=True, append_images=images[1:], duration=round(1000 / frame_fps), loop=0)

    def write_mp4(temporary: Path) -> None:
        width, height = canvas.get_width_height()  # even, as H.264's 4:2:0 needs
        command = ["ffmpeg", "-loglevel", "error", "-y", "-f", "rawvideo", "-pix_fmt", "rgba",
                   "-s", f"{width}x{height}", "-r", f"{frame_fps}", "-i", "-",
                   "-pix_fmt", "yuv420p", "-vcodec", "libx264", str(temporary)]
        with subprocess.Popen(command, stdin=subprocess.PIPE, stderr=subprocess.PIPE) as ffmpeg:
            try:
                for rgba in rendered():
                    ffmpeg.stdin.write(rgba.tobytes())
            except BrokenPipeError:  # ffmpeg stopped early; its log below says why
                pass
            _, log = ffmpeg.communicate()
        if ffmpeg.returncode:
            raise RuntimeError(f"ffmpeg failed writing {temporary.name}: {log.decode(errors='replace').strip()}")

    geometry.replace_file(path, write_gif if suffix == ".gif" else write_mp4)


# The page. Positions in the data are millimetres and so is every length below.
_PAGE = r"""<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>__TITLE__</title>
<style>
html, body { margin: 0; height: 100%; font: 13px system-ui, sans-serif; color: #222; background: #fff; }
body { display: flex; flex-direction: column; }
#view { flex: 1; position: relative; min-height: 0; }
#canvas { display: block; width: 100%; height: 100%; cursor: grab; touch-action: none; }
#legend { position: absolute; top: 8px; left: 8px; padding: 6px 8px; background: rgba(255, 255, 255, 0.85);
          border: 1px solid #ccc; border-radius: 4px; }
#legend .title { font-weight: bold; margin-bottom: 2px; }
#legend .person { display: flex; align-items: center; gap: 6px; line-height: 18px; }
#legend .person.absent { opacity: 0.3; }
#legend .swatch { width: 14px; height: 4px; border-radius: 2px; }
#help { position: absolute; right: 8px; bottom: 6px; color: #888; font-size: 11px; }
#controls { display: flex; align-items: center; gap: 10px; padding: 6px 10px; border-top: 1px solid #ccc; }
#slider { flex: 1; }
#counter { min-width: 15em; font-variant-numeric: tabular-nums; }
#errors { color: #b00; white-space: pre-wrap; }
</style>
</head>
<body>
<div id="view">
  <canvas id="canvas"></canvas>
  <div id="legend"></div>
  <div id="help">drag: orbit &middot; shift/right drag: pan &middot; wheel: zoom &middot; space: play &middot;
    grid: 1 m</div>
</div>
<div id="controls">
  <button id="play" type="button">Play</button>
  <input id="slider" type="range" min="0" value="0" step="1">
  <span id="counter"></span>
</div>
<div id="errors"></div>
<script>
// Before the viewer's script, so that its errors (syntax errors included) reach the page for headless checks.
window.onerror = function (message, source, line) {
  document.getElementById("errors").textContent += "error: " + message + " (line " + line + ")\n";
};
window.addEventListener("unhandledrejection", function (event) {
  document.getElementById("errors").textContent += "unhandled rejection: " + event.reason + "\n";
});
</script>
<script id="scene-data" type="application/json">__DATA__</script>
<script>
"use strict";
(function () {
  const scene = JSON.parse(document.getElementById("scene-data").textContent);
  const canvas = document.getElementById("canvas");
  const context = canvas.getContext("2d");
  const slider = document.getElementById("slider");
  const playButton = document.getElementById("play");
  const counter = document.getElementById("counter");
  const FIELD_OF_VIEW = 45 * Math.PI / 180;  // vertical; the opening distance is computed for it
  const NEAR = 50;  // mm in front of the eye: lines are clipped there
  const view = Object.assign({}, scene.view, {target: scene.view.target.slice()});
  let frame = 0, playing = false, lastTime = null, elapsed = 0, width = 1, height = 1;

  const asked = parseInt(new URLSearchParams(location.search).get("frame"), 10);
  if (Number.isFinite(asked)) frame = Math.min(Math.max(asked, 0), scene.frames - 1);
  slider.max = scene.frames - 1;
  slider.value = frame;
  document.title = scene.title || document.title;

  const legend = document.getElementById("legend");
  const legendTitle = document.createElement("div");
  legendTitle.className = "title";
  legendTitle.textContent = scene.title || "people";
  legend.appendChild(legendTitle);
  const legendRows = scene.people.map(function (person) {
    const row = document.createElement("div"), swatch = document.createElement("span");
    row.className = "person";
    swatch.className = "swatch";
    swatch.style.background = person.colour;
    row.appendChild(swatch);
    row.appendChild(document.createTextNode(person.name));
    legend.appendChild(row);
    return row;
  });

  // The orbit camera: the eye on a sphere around the target, z up.
  function eyeFrame() {
    const ca = Math.cos(view.azimuth), sa = Math.sin(view.azimuth);
    const ce = Math.cos(view.elevation), se = Math.sin(view.elevation);
    const back = [ce * ca, ce * sa, se];
    const eye = view.target.map(function (c, i) { return c + view.distance * back[i]; });
    const right = [-sa, ca, 0];
    const up = [-se * ca, -se * sa, ce];
    const forward = back.map(function (c) { return -c; });
    return {eye: eye, right: right, up: up, forward: forward,
            focal: 0.5 * height / Math.tan(FIELD_OF_VIEW / 2)};
  }

  function toEye(frame3, p) {
    const d = [p[0] - frame3.eye[0], p[1] - frame3.eye[1], p[2] - frame3.eye[2]];
    const dot = function (a) { return a[0] * d[0] + a[1] * d[1] + a[2] * d[2]; };
    return [dot(frame3.right), dot(frame3.up), dot(frame3.forward)];
  }

  function toScreen(frame3, q) {
    return [width / 2 + frame3.focal * q[0] / q[2], height / 2 - frame3.focal * q[1] / q[2]];
  }

  // A segment between eye-frame points, clipped to the near plane; false when wholly behind it.
  function segment(frame3, a, b) {
    if (a[2] < NEAR && b[2] < NEAR) return false;
    if (a[2] < NEAR || b[2] < NEAR) {
      const s = (NEAR - a[2]) / (b[2] - a[2]);
      const cut = [a[0] + s * (b[0] - a[0]), a[1] + s * (b[1] - a[1]), NEAR];
      if (a[2] < NEAR) a = cut; else b = cut;
    }
    const p = toScreen(frame3, a), q = toScreen(frame3, b);
    context.moveTo(p[0], p[1]);
    context.lineTo(q[0], q[1]);
    return true;
  }

  function line(frame3, a, b) { segment(frame3, toEye(frame3, a), toEye(frame3, b)); }

  function label(frame3, p, text) {
    const q = toEye(frame3, p);
    if (q[2] < NEAR) return;
    const s = toScreen(frame3, q);
    context.fillText(text, s[0] + 4, s[1] - 4);
  }

  function drawGrid(frame3) {
    const g = scene.grid;
    context.lineWidth = 1;
    context.strokeStyle = "#dddddd";
    context.beginPath();
    for (let x = g.min[0]; x <= g.max[0]; x += g.step) line(frame3, [x, g.min[1], 0], [x, g.max[1], 0]);
    for (let y = g.min[1]; y <= g.max[1]; y += g.step) line(frame3, [g.min[0], y, 0], [g.max[0], y, 0]);
    context.stroke();
    context.strokeStyle = "#888888";
    context.fillStyle = "#888888";
    context.lineWidth = 1.5;
    context.beginPath();
    const axes = [[500, 0, 0], [0, 500, 0], [0, 0, 500]];
    axes.forEach(function (tip) { line(frame3, [0, 0, 0], tip); });
    context.stroke();
    ["x", "y", "z"].forEach(function (name, i) { label(frame3, axes[i], name); });
  }

  function drawCameras(frame3) {
    context.strokeStyle = "#555555";
    context.fillStyle = "#333333";
    context.lineWidth = 1.2;
    scene.cameras.forEach(function (camera) {
      const c = camera.corners;
      context.beginPath();
      for (let i = 0; i < 4; i++) {
        line(frame3, camera.centre, c[i]);
        line(frame3, c[i], c[(i + 1) % 4]);
      }
      context.stroke();
      label(frame3, camera.centre, camera.name);
    });
  }

  function drawPeople(frame3) {
    const shown = [];
    scene.people.forEach(function (person, index) {
      const pose = person.poses[frame];
      legendRows[index].classList.toggle("absent", pose === null);
      if (pose === null) return;
      const points = [];
      for (let j = 0; j < pose.length; j += 3) points.push(toEye(frame3, [pose[j], pose[j + 1], pose[j + 2]]));
      const depth = points.reduce(function (sum, q) { return sum + q[2]; }, 0) / points.length;
      shown.push({person: person, points: points, depth: depth});
    });
    shown.sort(function (a, b) { return b.depth - a.depth; });  // far first: the nearer person stays on top
    context.lineCap = "round";
    shown.forEach(function (item) {
      context.strokeStyle = item.person.colour;
      context.fillStyle = item.person.colour;
      context.lineWidth = 3;
      context.beginPath();
      scene.bones.forEach(function (bone) { segment(frame3, item.points[bone[0]], item.points[bone[1]]); });
      context.stroke();
      item.points.forEach(function (q) {
        if (q[2] < NEAR) return;
        const s = toScreen(frame3, q);
        context.beginPath();
        context.arc(s[0], s[1], 3.5, 0, 2 * Math.PI);
        context.fill();
      });
    });
    return shown.length;
  }

  function draw() {
    const frame3 = eyeFrame();
    context.clearRect(0, 0, width, height);
    context.font = "12px system-ui, sans-serif";
    drawGrid(frame3);
    drawCameras(frame3);
    const count = drawPeople(frame3);
    counter.textContent = "frame " + frame + " / " + (scene.frames - 1) + " \u00b7 "
      + (frame / scene.fps).toFixed(2) + " s \u00b7 " + count + " of " + scene.people.length + " people";
  }

  function resize() {
    const box = canvas.getBoundingClientRect(), ratio = window.devicePixelRatio || 1;
    width = Math.max(box.width, 1);
    height = Math.max(box.height, 1);
    canvas.width = Math.round(width * ratio);
    canvas.height = Math.round(height * ratio);
    context.setTransform(ratio, 0, 0, ratio, 0, 0);
    draw();
  }

  function showFrame(k) {
    frame = (k + scene.frames) % scene.frames;
    slider.value = frame;
    draw();
  }

  function setPlaying(on) {
    playing = on;
    playButton.textContent = on ? "Pause" : "Play";
    lastTime = null;
    elapsed = 0;
    if (on) requestAnimationFrame(tick);
  }

  function tick(time) {
    if (!playing) return;
    if (lastTime !== null) elapsed += (time - lastTime) / 1000;
    lastTime = time;
    const steps = Math.floor(elapsed * scene.fps);
    if (steps > 0) {
      elapsed -= steps / scene.fps;
      showFrame(frame + steps);
    }
    requestAnimationFrame(tick);
  }

  playButton.addEventListener("click", function () { setPlaying(!playing); });
  slider.addEventListener("input", function () { showFrame(parseInt(slider.value, 10)); });
  document.addEventListener("keydown", function (event) {
    if (event.target.tagName === "INPUT" || event.target.tagName === "BUTTON") return;
    if (event.key === " ") setPlaying(!playing);
    else if (event.key === "ArrowRight") showFrame(frame + 1);
    else if (event.key === "ArrowLeft") showFrame(frame - 1);
    else return;
    event.preventDefault();
  });

  let drag = null;
  canvas.addEventListener("contextmenu", function (event) { event.preventDefault(); });
  canvas.addEventListener("pointerdown", function (event) {
    drag = {x: event.clientX, y: event.clientY, pan: event.shiftKey || event.button === 2};
    canvas.setPointerCapture(event.pointerId);
  });
  canvas.addEventListener("pointermove", function (event) {
    if (drag === null) return;
    const dx = event.clientX - drag.x, dy = event.clientY - drag.y;
    drag.x = event.clientX;
    drag.y = event.clientY;
    if (drag.pan) {
      const frame3 = eyeFrame(), scale = view.distance / frame3.focal;  // mm per pixel at the target
      for (let i = 0; i < 3; i++) view.target[i] += scale * (-dx * frame3.right[i] + dy * frame3.up[i]);
    } else {
      view.azimuth -= 0.01 * dx;
      view.elevation = Math.min(Math.max(view.elevation + 0.01 * dy, -1.55), 1.55);
    }
    draw();
  });
  canvas.addEventListener("pointerup", function () { drag = null; });
  canvas.addEventListener("wheel", function (event) {
    event.preventDefault();
    view.distance = Math.min(Math.max(view.distance * Math.exp(0.001 * event.deltaY), 200), 1e6);
    draw();
  }, {passive: false});
  window.addEventListener("resize", resize);

  resize();
  window.viewerReady = true;
  document.body.dataset.ready = "1";
})();
</script>
</body>
</html>
"""

"""The scene viewer (``mocap._scene_viewer``): input checks, a page that needs no network, the page in a
real headless Chromium (no script error, the chosen frame drawn, each present person's colour on the
screenshot and an absent person's not) and the GIF animation.

The browser tests need Debian's ``chromium``: they are skipped without it, except under CI (``CI=true``),
where ``.ci/run`` installs it and its absence fails the run.
"""

import json
import os
import re
import shutil
import subprocess

import jax
import matplotlib.colors
import numpy as np
import pytest
from PIL import Image, ImageSequence

import geometry
import mocap
from mocap._scene_viewer import person_colour, write_scene_animation, write_scene_html

PRESENT_PIXELS = 200
"""A drawn skeleton covers some 800 pixels of its exact colour at 1000x700; the legend's swatch 56."""
ABSENT_PIXELS = 20


@pytest.fixture(scope="module")
def scene():
    """(people, frames, 15, 3) Shelf15 joints of three people over 30 frames, all present, and the Shelf rig."""
    rig = mocap.shelf_cameras()
    synthetic = mocap.synthesise_scene(jax.random.key(0), rig, num_people=3, num_frames=30)
    joints = np.asarray(synthetic.shelf15).transpose(1, 0, 2, 3)
    return joints, np.ones(joints.shape[:2], bool), rig


@pytest.fixture(scope="module")
def chromium():
    binary = shutil.which("chromium") or ("/usr/bin/chromium" if os.path.exists("/usr/bin/chromium") else None)
    if binary is None:
        reason = "chromium is not installed (Debian: apt-get install chromium); the browser tests need it"
        if os.environ.get("CI") == "true":
            pytest.fail(f"{reason}, and CI must run them (.ci/run installs it)")
        pytest.skip(reason)
    return binary


def _run_chromium(binary, tmp_path, *args) -> subprocess.CompletedProcess:
    command = [binary, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
               "--disable-background-networking", "--disable-component-update", "--disable-sync",
               f"--user-data-dir={tmp_path / 'chromium-profile'}", *args]
    done = subprocess.run(command, capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 0, f"chromium failed ({done.returncode}): {done.stderr[-2000:]}"
    return done


def _screenshot(binary, tmp_path, page, frame: int) -> np.ndarray:
    shot = tmp_path / f"{page.stem}_{frame}.png"
    _run_chromium(binary, tmp_path, "--hide-scrollbars", f"--screenshot={shot}", "--window-size=1000,700",
                  f"{page.as_uri()}?frame={frame}")
    return np.asarray(Image.open(shot).convert("RGB")).astype(int)


def _pixels_of(image: np.ndarray, colour: str, tolerance: int = 8) -> int:
    rgb = np.array(matplotlib.colors.to_rgb(colour)) * 255
    return int((np.abs(image - rgb).max(-1) <= tolerance).sum())


def _page_data(page) -> dict:
    text = page.read_text(encoding="utf-8")
    return json.loads(re.search(r'<script id="scene-data" type="application/json">(.*?)</script>', text, re.DOTALL)[1])


def test_person_colour_is_matplotlibs_colour_cycle():
    # The static figures (experiments/preview_scene.py, experiments/jcsat_study/_plot.py) draw person i in "Ci".
    for i in range(13):
        assert person_colour(i) == matplotlib.colors.to_hex(f"C{i}")


@pytest.mark.parametrize("change, message", [
    (lambda j, p, s: (j[..., :2], p, s), r"shape \(people, frames, joints, 3\)"),
    (lambda j, p, s: (j[:, :, :14], p, s), "14 joints per pose but SHELF15 has 15"),
    (lambda j, p, s: (j, p, geometry.BODY25), "15 joints per pose but BODY25 has 25"),
    (lambda j, p, s: (j, p[:, :-1], s), r"present has shape \(3, 29\)"),
    (lambda j, p, s: (j, p.astype(int), s), "present must be boolean"),
    (lambda j, p, s: (np.where(np.arange(30)[:, None, None] == 7, np.nan, j), p, s),
     "person 0 is present at frame 7 but its joints hold NaN"),
])
def test_bad_inputs_fail_in_one_line(scene, tmp_path, change, message):
    joints, present, rig = scene
    joints, present, skeleton = change(joints, present, geometry.SHELF15)
    for write in (write_scene_html, write_scene_animation):
        with pytest.raises(ValueError, match=message) as raised:
            write(tmp_path / "out.gif", joints, present, skeleton, rig)
        assert "\n" not in str(raised.value)
    assert not list(tmp_path.iterdir())


def test_names_must_match_people_and_cameras(scene, tmp_path):
    joints, present, rig = scene
    with pytest.raises(ValueError, match="2 names for 3 people"):
        write_scene_html(tmp_path / "out.html", joints, present, geometry.SHELF15, rig, names=["a", "b"])
    with pytest.raises(ValueError, match="1 camera names for 5 cameras"):
        write_scene_html(tmp_path / "out.html", joints, present, geometry.SHELF15, rig, camera_names=["a"])


def test_page_is_self_contained_and_holds_the_scene(scene, tmp_path):
    joints, present, rig = scene
    present = present.copy()
    present[1, 5:] = False
    absent_joints = np.where(present[..., None, None], joints, np.nan)  # absent poses may be NaN
    name = "</script><script>alert(1)</script>"  # must stay a name, not end the data
    page = tmp_path / "scene.html"
    write_scene_html(page, absent_joints, present, geometry.SHELF15, rig, names=["a", name, "c"], title="t")
    text = page.read_text(encoding="utf-8")
    assert not re.search(r"""(src|href)\s*=\s*["']?\s*(https?:)?//""", text)
    assert not re.search(r"https?://|<link|@import|url\(", text)
    data = _page_data(page)
    assert data["people"][1]["name"] == name
    assert data["people"][1]["poses"][5] is None
    assert np.array_equal(data["people"][1]["poses"][4], np.round(joints[1, 4] * 1000).ravel())
    assert len(data["cameras"]) == 5 and data["bones"] == [list(bone) for bone in geometry.SHELF15.bones]
    centre = np.asarray(geometry.camera_centre(rig))[2] * 1000
    assert np.abs(np.asarray(data["cameras"][2]["centre"]) - centre).max() <= 0.5
    assert [p.name for p in tmp_path.iterdir()] == ["scene.html"]  # no temporary left behind


def test_page_runs_without_errors_in_chromium(scene, tmp_path, chromium):
    joints, present, rig = scene
    page = tmp_path / "scene.html"
    write_scene_html(page, joints, present, geometry.SHELF15, rig)
    done = _run_chromium(chromium, tmp_path, "--enable-logging=stderr", "--v=0", "--dump-dom",
                         "--virtual-time-budget=5000", f"{page.as_uri()}?frame=10")
    console = [line for line in done.stderr.splitlines() if ":CONSOLE" in line]
    assert not console, "the page wrote to the console:\n" + "\n".join(console)
    errors = re.search(r'<div id="errors">(.*?)</div>', done.stdout, re.DOTALL)
    assert errors is not None and errors[1].strip() == "", f"script errors: {errors and errors[1]}"
    assert re.search(r'<body[^>]* data-ready="1"', done.stdout), "the page never finished its first draw"
    assert "frame 10 / 29" in done.stdout


def test_screenshot_shows_present_people_in_their_colours(scene, tmp_path, chromium):
    joints, present, rig = scene
    everyone = tmp_path / "everyone.html"
    write_scene_html(everyone, joints, present, geometry.SHELF15, rig)
    image = _screenshot(chromium, tmp_path, everyone, 10)
    counts = [_pixels_of(image, person_colour(p)) for p in range(3)]
    assert min(counts) > PRESENT_PIXELS, counts

    present = present.copy()
    present[1] = False  # never there
    present[2, :15] = False  # arrives at frame 15
    some = tmp_path / "some.html"
    write_scene_html(some, joints, present, geometry.SHELF15, rig)
    for frame, shown in ((10, [0]), (20, [0, 2])):
        image = _screenshot(chromium, tmp_path, some, frame)
        for p in range(3):
            count = _pixels_of(image, person_colour(p))
            if p in shown:
                assert count > PRESENT_PIXELS, (frame, p, count)
            else:
                assert count < ABSENT_PIXELS, (frame, p, count)


def test_gif_has_every_frame(scene, tmp_path):
    joints, present, rig = scene
    path = tmp_path / "scene.gif"
    write_scene_animation(path, joints[:, :20], present[:, :20], geometry.SHELF15, rig)
    with Image.open(path) as gif:
        assert gif.n_frames == 20 and gif.info["duration"] == 40  # 25 frames per second
        frames = [np.asarray(frame.convert("RGB")).astype(int) for frame in ImageSequence.Iterator(gif)]
    assert len(np.unique(frames[0].reshape(-1, 3), axis=0)) > 20  # more than a blank canvas
    assert not np.array_equal(frames[0], frames[19])
    for p in range(3):
        assert _pixels_of(frames[0], person_colour(p), tolerance=24) > 40, p


def test_gif_with_max_frames_keeps_real_time(scene, tmp_path):
    joints, present, rig = scene
    path = tmp_path / "scene.gif"
    write_scene_animation(path, joints[:, :20], present[:, :20], geometry.SHELF15, rig, max_frames=5)
    with Image.open(path) as gif:
        assert gif.n_frames == 5 and gif.info["duration"] == 160  # 20 frames at 25 fps last 0.8 s


def test_animation_format_comes_from_the_suffix(scene, tmp_path, monkeypatch):
    joints, present, rig = scene
    with pytest.raises(ValueError, match="must end in .gif or .mp4"):
        write_scene_animation(tmp_path / "scene.png", joints, present, geometry.SHELF15, rig)
    monkeypatch.setattr(shutil, "which", lambda name: None)
    with pytest.raises(RuntimeError, match="needs ffmpeg"):
        write_scene_animation(tmp_path / "scene.mp4", joints, present, geometry.SHELF15, rig)


@pytest.mark.skipif(shutil.which("ffmpeg") is None, reason="ffmpeg is not installed")
def test_mp4(scene, tmp_path):
    joints, present, rig = scene
    path = tmp_path / "scene.mp4"
    write_scene_animation(path, joints, present, geometry.SHELF15, rig, max_frames=10)
    assert path.read_bytes()[4:8] == b"ftyp"


def test_failed_write_keeps_the_previous_file(scene, tmp_path, monkeypatch):
    joints, present, rig = scene
    path = tmp_path / "scene.gif"
    path.write_bytes(b"previous")

    def fail(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(Image.Image, "save", fail)
    with pytest.raises(OSError, match="disk full"):
        write_scene_animation(path, joints[:, :3], present[:, :3], geometry.SHELF15, rig)
    assert path.read_bytes() == b"previous" and [p.name for p in tmp_path.iterdir()] == ["scene.gif"]

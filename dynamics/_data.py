"""The dynamics data: synthetic videos of CMU clips (shipped, or motion files), cut into person tracks of crops and
ground truth.

Each clip is retargeted to the body model with random shapes (:func:`mocap.retarget_clip`) and rendered
``renders`` times with a slowly moving camera (:func:`mocap.synthesise_video`). Every rendered video gives
``augmented_epochs`` variants, as the thesis caches eight augmented epochs (Sect. 5.2): its boxes jittered like a
noisy tracker's (:func:`mocap.jitter_boxes`) and every second variant mirrored (:func:`mocap.flip_video`, ground
truth mirrored with it; its pixels, or with ``redraw_flips`` a render of the mirrored people). A person's frames in
one variant form a *track*.

A track's crops are square: side ``box_margin * max(w, h)`` of its (jittered) tight box, centred on it, resized
to ``crop_size`` pixels. That square is the track's box everywhere else too: the crop camera of the HMR head is
defined on it (:func:`geometry.crop_camera_to_translation`) and the 2D losses are normalised by it.

:class:`Frames` holds one row per person and frame, every track's rows contiguous and in time order, so a
window of a track is a slice of rows (:func:`window_starts`, :func:`gather_windows`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
from pathlib import Path
from typing import Any, NamedTuple, TypeVar

import cv2
import jax
import numpy as np
from jaxtyping import Bool, Float, Int, UInt8

import geometry
import mocap
import training

from ._poses import PoseFrames

__all__ = ["TEST_MULTI_PERSON_CLIPS", "TEST_SINGLE_PERSON_CLIPS", "TRAIN_CLIPS", "VALIDATION_DATA", "DataConfig",
           "Frames", "build_frames", "check_validation_apart", "crop_square", "gather_windows", "scene_windows", "square_boxes", "video_tracks",
           "window_starts", "without_crops"]

Columns = TypeVar("Columns", bound=Any)
"""A pytree of per-row arrays (a :class:`Frames`, or a tuple of features and frames)."""

TEST_SINGLE_PERSON_CLIPS: tuple[str, ...] = ("03_01_uneven", "01_01_jumps")
"""Held out: the single-person test samples, of subjects 03 and 01, who appear in no training clip."""
TEST_MULTI_PERSON_CLIPS: tuple[str, ...] = ("60_05_61_05_salsa",)
"""Held out: the two-person test samples (the second salsa take; the first one trains). The only two-person
recordings at hand are two takes of one pair of subjects (60 and 61), so this split cannot be subject-disjoint."""
TRAIN_CLIPS: tuple[str, ...] = tuple(c for c in mocap.list_clips()
                                     if c not in TEST_SINGLE_PERSON_CLIPS + TEST_MULTI_PERSON_CLIPS)


@dataclasses.dataclass(frozen=True)
class DataConfig:
    """What a set of tracks is made of (written into every run's ``config.json``)."""

    clips: tuple[str, ...] = TRAIN_CLIPS
    """Shipped clip names, motion files of one person, or the files of two people captured together joined by ``+``
    (:func:`mocap.load_clip_file`; relative paths from the working directory)."""
    renders: int = 16
    """Videos per clip, each with its own camera path and body shapes (16, chosen on validation over 2, 4 and 8 by
    ``python -m experiments.dynamics_renders``: docs/dynamics.md)."""
    augmented_epochs: int = 4
    """Variants of each video (box jitter; every second one mirrored)."""
    jitter: bool = True
    """Jitter the boxes (training); False: the tight boxes (testing)."""
    flip: bool = True
    """Mirror every second variant (training)."""
    redraw_flips: bool = True
    """Render the mirrored variants anew (:func:`mocap.flip_video`'s ``redraw``), so that the renders' part colours
    follow the swapped left and right; False mirrors the pixels, which keeps each colour on its side of the image and
    so makes a mirrored person facing the camera look like one facing away (the models shipped before 2026-12-07;
    True won on validation by ``python -m experiments.dynamics_renders --flips pixels redraw``: docs/dynamics.md)."""
    crop_size: int = 64
    """Crop side, pixels (the thesis: 224 for ResNet-50; this CPU-sized backbone takes 64)."""
    box_margin: float = 1.2
    """Crop side over the longer side of the tight box."""
    shape_std: float = 1.0
    """Body shapes are drawn from N(0, shape_std^2) per coefficient."""
    video: mocap.VideoConfig = mocap.VideoConfig()
    seed: int = 0

    def __post_init__(self) -> None:
        for clip in self.clips:  # clip_files refuses what is neither shipped nor files; shipped clips hold 1-2 people
            people = len(mocap.clip_files(clip))
            if people > 2:
                raise ValueError(f"clip {clip!r} joins {people} people; the models take one or two")
        for name in ("renders", "augmented_epochs", "crop_size"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.box_margin < 1.0:
            raise ValueError(f"box_margin must be >= 1 (a crop holds its whole box), got {self.box_margin}")


VALIDATION_DATA = DataConfig(clips=("02_01_walk", "60_03_61_03_salsa"), renders=1, augmented_epochs=1, jitter=False,
                             flip=False, seed=1_000)
"""What the video models validate on: fresh renders (new cameras and shapes) of two training clips, one of them
two-person; never a test clip."""


def check_validation_apart(data: DataConfig, validation: DataConfig) -> None:
    """Refuse a validation set that renders a training clip with training's seed (the same videos)."""
    shared = set(data.clips) & set(validation.clips)
    if shared and data.seed == validation.seed:
        raise ValueError(f"validation renders of {sorted(shared)} must use another seed than training's")


class Frames(NamedTuple):
    """One row per person and frame (see the module docstring); float32, metres and pixels, camera frame."""

    crops: UInt8[np.ndarray, "F size size 3"]
    boxes: Float[np.ndarray, "F 4"]
    """The square crop box ``(x0, y0, x1, y1)``, pixels."""
    K: Float[np.ndarray, "F 3 3"]
    rotations: Float[np.ndarray, "F 24 3 3"]
    """Local joint rotations, the root's global in the camera frame."""
    betas: Float[np.ndarray, "F S"]
    root: Float[np.ndarray, "F 3"]
    """The pelvis in the camera frame, metres: the translation the models predict."""
    joints3d: Float[np.ndarray, "F 24 3"]
    joints2d: Float[np.ndarray, "F 24 2"]
    tight_boxes: Float[np.ndarray, "F 4"]
    """The un-jittered tight box of the projected body (PCK's box size)."""
    track: Int[np.ndarray, "F"]
    """Track index; a track's rows are contiguous and in time order."""
    video: Int[np.ndarray, "F"]
    """Index of the rendered video variant the row comes from (people of one variant share it)."""
    person: Int[np.ndarray, "F"]
    """The person's index in its video."""
    clip: Int[np.ndarray, "F"]
    """Index into the config's ``clips``."""
    frame: Int[np.ndarray, "F"]
    """Frame index in the video."""

    @property
    def num_frames(self) -> int:
        return self.track.shape[0]


def square_boxes(boxes: Float[np.ndarray, "*n 4"], margin: float) -> Float[np.ndarray, "*n 4"]:
    """Squares of side ``margin * max(w, h)`` centred on ``boxes`` (``(x0, y0, x1, y1)`` pixels)."""
    centre = 0.5 * (boxes[..., :2] + boxes[..., 2:])
    half = 0.5 * margin * np.max(boxes[..., 2:] - boxes[..., :2], axis=-1, keepdims=True)
    return np.concatenate([centre - half, centre + half], axis=-1)


def crop_square(image: UInt8[np.ndarray, "H W 3"], box: Float[np.ndarray, "4"], size: int) -> UInt8[np.ndarray, "size size 3"]:
    """The square ``box`` of ``image`` resampled to ``size`` x ``size`` pixels (zeros outside the image).

    Crop pixel ``i`` (its centre) is image point ``x0 + (i + 0.5) b / size - 0.5`` with ``b`` the box side, so
    crop-normalised coordinates ``(i + 0.5) / size * 2 - 1`` in [-1, 1] span the box: the crop camera's frame."""
    side = box[2] - box[0]
    if not side > 0:
        raise ValueError(f"crop box {box} has no area")
    scale = size / side
    transform = np.array([[scale, 0.0, -box[0] * scale + 0.5 * scale - 0.5],
                          [0.0, scale, -box[1] * scale + 0.5 * scale - 0.5]])
    return cv2.warpAffine(image, transform, (size, size), flags=cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0))


_RENDERING_VERSION = 2
"""Part of every render cache's key, raised whenever rendering changes what a config gives, so that a cache of older
renders is never reused (2: one generator per render, 2026-11-27)."""


def _cache_file(config: DataConfig, clips: list[mocap.Clip], cache_dir: Path) -> Path:
    # jax's version and XLA's flags join the key: they change the renders' rounding (a notebook that skips
    # geometry.disable_faulty_cpu_fusion renders other bits than the command line), so neither reuses the other's.
    xla_flags = " ".join(sorted(os.environ.get("XLA_FLAGS", "").split()))
    name = (f"rendering {_RENDERING_VERSION} jax {jax.__version__} XLA_FLAGS {xla_flags} "
            + json.dumps(training.to_jsonable(config), sort_keys=True))
    # A motion file is named by its path only: its joints join the key, so that a render of another file at that
    # path (or of an .amc beside another .asf) is never reused.
    name += "".join(hashlib.sha1(clip.body25.tobytes() + clip.structri17.tobytes()).hexdigest()
                    for spec, clip in zip(config.clips, clips) if mocap.clip_files(spec))
    return cache_dir / f"dynamics_frames_{hashlib.sha1(name.encode()).hexdigest()[:16]}.npz"


def build_frames(config: DataConfig, model: geometry.BodyModel, cache_dir: str | Path | None = None,
                 progress: bool = True, workers: int = 1) -> Frames:
    """Render, augment and crop every clip of ``config`` (module docstring); cached in ``cache_dir`` when given
    (a file named by a hash of the config, of its motion files' joints, of jax's version and of XLA's flags,
    written atomically).

    Each render draws from its own generator, seeded by ``(config.seed, clip, render)``, so ``workers`` CPU
    processes (:func:`training.process_map`) give the same frames as one."""
    clips = [mocap.shared_clip(spec) for spec in config.clips]
    path = None if cache_dir is None else _cache_file(config, clips, Path(cache_dir))
    if path is not None and path.is_file():
        with np.load(path) as stored:
            return Frames(**{name: stored[name] for name in Frames._fields})
    jobs, track, variant = [], 0, 0
    for clip_index, clip in enumerate(clips):
        for render in range(config.renders):
            jobs.append((config, clip_index, render, model, track, variant))
            track += clip.num_people * config.augmented_epochs
            variant += config.augmented_epochs
    rendered = training.process_map(_render, jobs, workers, progress="render videos" if progress else None)
    frames = Frames(*(np.concatenate(column) for column in zip(*rendered)))
    if path is not None:
        training.write_atomically(path, lambda file: np.savez(file, **frames._asdict()))
    return frames


def _render(config: DataConfig, clip_index: int, render: int, model: geometry.BodyModel, first_track: int,
            first_variant: int) -> Frames:
    """The ``augmented_epochs`` variants of one render of clip ``clip_index``, tracks and variants numbered from
    ``first_track`` and ``first_variant``."""
    clip = mocap.shared_clip(config.clips[clip_index])
    rng = np.random.default_rng((config.seed, clip_index, render))
    betas = rng.normal(0.0, config.shape_std, (clip.num_people, model.num_shapes))
    video = mocap.synthesise_video(mocap.retarget_clip(clip, model, betas), model, config.video, rng)
    rows = []
    mirrors = config.flip and config.augmented_epochs > 1
    flipped = mocap.flip_video(video, model, config.redraw_flips) if mirrors else None
    for epoch in range(config.augmented_epochs):
        shown = flipped if flipped is not None and epoch % 2 == 1 else video
        rows.append(video_tracks(shown, config, rng, first_track=first_track + epoch * clip.num_people,
                                 variant=first_variant + epoch, clip=clip_index))
    return Frames(*(np.concatenate(column) for column in zip(*rows)))


def video_tracks(video: mocap.Video, config: DataConfig, rng: np.random.Generator, first_track: int = 0,
                 variant: int = 0, clip: int = 0) -> Frames:
    """The tracks of every person of ``video`` (boxes jittered with ``rng`` if ``config.jitter``), person after
    person, numbered from ``first_track``."""
    noisy = mocap.jitter_boxes(video.boxes, rng) if config.jitter else video.boxes
    boxes = square_boxes(noisy, config.box_margin)
    tracks = [_track_rows(video, person, boxes[person], config.crop_size, first_track + person, variant, clip)
              for person in range(video.boxes.shape[0])]
    return Frames(*(np.concatenate(column) for column in zip(*tracks)))


def _track_rows(video: mocap.Video, person: int, boxes: np.ndarray, size: int, track: int, variant: int,
                clip: int) -> Frames:
    length = video.frames.shape[0]
    crops = np.stack([crop_square(video.frames[t], boxes[t], size) for t in range(length)])
    ids = [np.full(length, value, np.int32) for value in (track, variant, person, clip)]
    return Frames(crops, boxes.astype(np.float32), np.asarray(video.camera.K, np.float32),
                  video.rotations[person].astype(np.float32),
                  np.broadcast_to(video.betas[person], (length, video.betas.shape[1])).astype(np.float32),
                  video.joints3d[person, :, 0].astype(np.float32), video.joints3d[person].astype(np.float32),
                  video.joints2d[person].astype(np.float32), video.boxes[person].astype(np.float32),
                  *ids, np.arange(length, dtype=np.int32))


def without_crops(frames: Frames) -> Frames:
    """``frames`` with an empty ``crops`` column (one byte per row), for the stages that read cached features."""
    return frames._replace(crops=np.zeros(frames.num_frames, np.uint8))


def window_starts(frames: Frames | PoseFrames, length: int, stride: int = 1) -> Int[np.ndarray, "N"]:
    """First rows of every window of ``length`` consecutive frames of one track (video frames, or 3D motion),
    every ``stride`` frames."""
    if length < 1 or stride < 1:
        raise ValueError(f"length and stride must be >= 1, got {length} and {stride}")
    starts = []
    boundaries = np.flatnonzero(np.diff(frames.track)) + 1
    for first, end in zip(np.r_[0, boundaries], np.r_[boundaries, frames.num_frames]):
        starts.extend(range(first, end - length + 1, stride))
    return np.asarray(starts, np.int64)


def gather_windows(columns: Columns, starts: Int[np.ndarray, "B"], length: int) -> Columns:
    """``columns`` (any NamedTuple of per-row arrays, e.g. :class:`Frames`) at rows ``starts[b] + 0..length-1``:
    every array gains a ``(B, length)`` leading shape."""
    index = np.asarray(starts)[:, None] + np.arange(length)[None]
    return jax.tree.map(lambda column: column[index], columns)


def scene_windows(frames: Frames | PoseFrames, length: int, stride: int = 1, people: int | None = None,
                  ) -> tuple[Int[np.ndarray, "W N length"], Bool[np.ndarray, "W N"]]:
    """Windows of ``length`` consecutive frames of every video variant with all its people, every ``stride``
    frames: the rows of each person and frame (person-major, as the multi-person models take scenes) and which
    people exist. ``N`` is ``people`` (videos with more are refused) or the most people in any video; the rows
    of an absent person repeat the first person's (finite inputs the models mask out)."""
    if length < 1 or stride < 1:
        raise ValueError(f"length and stride must be >= 1, got {length} and {stride}")
    videos = [np.flatnonzero(frames.video == v) for v in np.unique(frames.video)]
    most = max(len(np.unique(frames.person[rows])) for rows in videos)
    people = most if people is None else people
    if most > people:
        raise ValueError(f"a video has {most} people, more than people={people}")
    windows, present = [], []
    for rows in videos:
        tracks = [rows[frames.person[rows] == p] for p in np.unique(frames.person[rows])]
        if any(not np.array_equal(frames.frame[t], frames.frame[tracks[0]]) for t in tracks):
            raise ValueError(f"the people of video {frames.video[rows[0]]} are not seen in the same frames")
        exists = np.arange(people) < len(tracks)
        tracks += [tracks[0]] * (people - len(tracks))
        for start in range(0, len(tracks[0]) - length + 1, stride):
            windows.append(np.stack([t[start: start + length] for t in tracks]))
            present.append(exists)
    if not windows:
        return np.zeros((0, people, length), np.int64), np.zeros((0, people), bool)
    return np.stack(windows).astype(np.int64), np.stack(present)


"""One way to name the motion of a clip: a shipped clip, a motion file of one person in any CMU format, or the files
of people captured together joined by ``+``."""

from __future__ import annotations

import functools
import os
from pathlib import Path

import numpy as np

from ._asf_amc import read_asf_amc
from ._bvh import CMU_METRES_PER_UNIT, SALSA_METRES_PER_UNIT, read_bvh
from ._clips import Clip, clip_from_motions, list_clips, load_clip
from ._cmu_expmap import cmu_expmap_clip, read_cmu_expmap
from ._motion import Motion

__all__ = ["clip_files", "load_clip_file", "resolve_clip", "shared_clip"]

_STANDING_HEIGHT_M = (1.0, 2.3)
"""Range of a person's rest-pose height (metres) a clip file must give, so a BVH in other units is refused."""
_TOGETHER = "+"
"""Joins the files of people captured together (``60_03.bvh+61_03.bvh``)."""


def clip_files(spec: str | os.PathLike, data_root: str | os.PathLike | None = None) -> tuple[Path, ...]:
    """The motion files ``spec`` names, one per person: none for a shipped clip, one for a file, several for files
    of people captured together joined by ``+``. A relative path is looked up under ``data_root`` first; a
    ValueError ``"'<spec>' is neither a shipped clip (...) nor a file"`` (or, in a group, ``"'<file>' of '<spec>' is
    not a file"``) otherwise."""
    spec = str(spec)
    if spec in list_clips():
        return ()
    files = []
    for part in spec.split(_TOGETHER):
        path = Path(part)
        if not path.is_absolute() and data_root is not None and (Path(data_root) / path).is_file():
            path = Path(data_root) / path
        if not path.is_file():
            raise ValueError(f"{spec!r} is neither a shipped clip ({', '.join(list_clips())}) nor a file"
                             if part == spec else f"{part!r} of {spec!r} is not a file")
        files.append(path)
    return tuple(files)


def resolve_clip(spec: str | os.PathLike, data_root: str | os.PathLike | None = None) -> str:
    """``spec`` if it names a shipped clip, else the path of the file it names, or the paths of a group of files
    joined by ``+`` (:func:`clip_files`: a relative path is looked up under ``data_root`` first; the ValueError
    names what is not a file)."""
    files = clip_files(spec, data_root)
    return _TOGETHER.join(str(path) for path in files) if files else str(spec)


def load_clip_file(spec: str | os.PathLike, data_root: str | os.PathLike | None = None, fps: float = 30.0) -> Clip:
    """A clip from a shipped clip name (:func:`load_clip`), from a motion file of one person: a CMU exp-map
    ``.txt`` (:func:`read_cmu_expmap`), an ``.amc`` beside its subject's ``.asf`` (``02_01.amc`` -> ``02.asf``,
    :func:`read_asf_amc`) or a ``.bvh`` in CMU's units (:func:`read_bvh`, ``CMU_METRES_PER_UNIT``), or from such
    files of people captured together joined by ``+`` (same frame count and rate): one clip of them all in their
    common frame, made as the shipped salsa clips are (:func:`clip_from_motions`). In a group, the rescaled salsa
    files ``*_scaled.bvh`` (the shipped salsa clips' sources) are read in ``SALSA_METRES_PER_UNIT``. A relative path
    is looked up under ``data_root`` first (:func:`clip_files`). Files are resampled to ``fps``; a person whose rest
    pose is not 1.0-2.3 m tall (a BVH in other units) is refused, as is a name that is neither a shipped clip nor a
    file."""
    files = clip_files(spec, data_root)
    if not files:
        return load_clip(str(spec))
    if len(files) == 1 and files[0].suffix.lower() == ".txt":
        return cmu_expmap_clip(files[0], fps)
    motions = [_read_person(path, salsa=len(files) > 1 and path.name.endswith("_scaled.bvh")) for path in files]
    name = _TOGETHER.join(path.stem for path in files)
    description = (f"motion file {files[0].name}" if len(files) == 1
                   else f"people captured together: motion files {', '.join(path.name for path in files)}")
    return clip_from_motions(name, motions, fps=fps, description=description, sources=tuple(p.name for p in files))


def _read_person(path: Path, salsa: bool) -> Motion:
    """The motion of one person's file at its own rate; ``salsa``: a BVH in ``SALSA_METRES_PER_UNIT``."""
    suffix = path.suffix.lower()
    if suffix == ".txt":
        motion = read_cmu_expmap(path, name=path.stem)
    elif suffix == ".amc":
        asf = path.with_name(path.stem.split("_")[0] + ".asf")
        if not asf.is_file():
            raise ValueError(f"{path}: no skeleton file {asf.name} beside it")
        motion = read_asf_amc(asf, path, name=path.stem)
    elif suffix == ".bvh":
        motion = read_bvh(path, SALSA_METRES_PER_UNIT if salsa else CMU_METRES_PER_UNIT, name=path.stem)
    else:
        raise ValueError(f"{path}: not a motion file this reads (.txt exp-map, .amc + .asf, .bvh)")
    rest = np.zeros_like(motion.offsets)  # the rest pose in the source's y-up frame: offsets summed down the tree
    for node, parent in enumerate(motion.parents):
        if parent >= 0:
            rest[node] = rest[parent] + motion.offsets[node]
    height = float(np.ptp(rest[:, 1]))
    if not _STANDING_HEIGHT_M[0] <= height <= _STANDING_HEIGHT_M[1]:
        raise ValueError(f"{path}: its rest pose is {height:.2f} m tall; a BVH must be in CMU's units "
                         f"(1 unit = 1/0.45 inch), or be a rescaled salsa *_scaled.bvh joined with its partner's")
    return motion


@functools.lru_cache(maxsize=None)
def shared_clip(spec: str) -> Clip:
    """:func:`load_clip_file` of ``spec`` (a shipped name or resolved files, :func:`resolve_clip`), read once per
    process and shared: scene and sample builders draw the same clips many times. Do not modify its arrays."""
    return load_clip_file(spec)

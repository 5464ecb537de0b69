"""One way to name the motion of a clip: a shipped clip, or a motion file of one person in any CMU format."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ._asf_amc import read_asf_amc
from ._bvh import CMU_METRES_PER_UNIT, read_bvh
from ._clips import Clip, clip_from_motions, list_clips, load_clip
from ._cmu_expmap import cmu_expmap_clip

__all__ = ["load_clip_file", "resolve_clip"]

_STANDING_HEIGHT_M = (1.0, 2.3)
"""Range of a person's rest-pose height (metres) a clip file must give, so a BVH in other units is refused."""


def resolve_clip(spec: str | os.PathLike, data_root: str | os.PathLike | None = None) -> str:
    """``spec`` if it names a shipped clip, else the path of the file it names (a relative path is looked up under
    ``data_root`` first); a ValueError ``"'<spec>' is neither a shipped clip (...) nor a file"`` otherwise."""
    spec = str(spec)
    if spec in list_clips():
        return spec
    path = Path(spec)
    if not path.is_absolute() and data_root is not None and (Path(data_root) / path).is_file():
        path = Path(data_root) / path
    if not path.is_file():
        raise ValueError(f"{spec!r} is neither a shipped clip ({', '.join(list_clips())}) nor a file")
    return str(path)


def load_clip_file(spec: str | os.PathLike, data_root: str | os.PathLike | None = None, fps: float = 30.0) -> Clip:
    """A clip from a shipped clip name (:func:`load_clip`) or from a motion file of one person: a CMU exp-map
    ``.txt`` (:func:`read_cmu_expmap`), an ``.amc`` beside its subject's ``.asf`` (``02_01.amc`` -> ``02.asf``,
    :func:`read_asf_amc`) or a ``.bvh`` in CMU's units (:func:`read_bvh`, ``CMU_METRES_PER_UNIT``). A relative path
    is looked up under ``data_root`` first (:func:`resolve_clip`). Files are resampled to ``fps``; a person whose rest
    pose is not 1.0-2.3 m tall (a BVH in other units) is refused, as is a name that is neither a shipped clip nor a
    file."""
    resolved = resolve_clip(spec, data_root)
    if resolved in list_clips():
        return load_clip(resolved)
    path = Path(resolved)
    suffix = path.suffix.lower()
    if suffix == ".txt":
        return cmu_expmap_clip(path, fps)
    if suffix == ".amc":
        asf = path.with_name(path.stem.split("_")[0] + ".asf")
        if not asf.is_file():
            raise ValueError(f"{path}: no skeleton file {asf.name} beside it")
        motion = read_asf_amc(asf, path, name=path.stem)
    elif suffix == ".bvh":
        motion = read_bvh(path, CMU_METRES_PER_UNIT, name=path.stem)
    else:
        raise ValueError(f"{path}: not a motion file this reads (.txt exp-map, .amc + .asf, .bvh)")
    rest = np.zeros_like(motion.offsets)  # the rest pose in the source's y-up frame: offsets summed down the tree
    for node, parent in enumerate(motion.parents):
        if parent >= 0:
            rest[node] = rest[parent] + motion.offsets[node]
    height = float(np.ptp(rest[:, 1]))
    if not _STANDING_HEIGHT_M[0] <= height <= _STANDING_HEIGHT_M[1]:
        raise ValueError(f"{path}: its rest pose is {height:.2f} m tall; a BVH must be in CMU's units "
                         f"(1 unit = 1/0.45 inch)")
    return clip_from_motions(path.stem, [motion], fps=fps, description=f"motion file {path.name}",
                             sources=(path.name,))

"""Compact CMU clips shipped in ``mocap/assets`` (joint positions only), and the conversion that makes them.

A shipped clip ``<name>.npz`` holds, for each of its ``P`` people (2 for the salsa pair, captured
together and kept in their common frame, 1 otherwise):

- ``body25``: int16 ``(P, T, 25, 3)`` millimetres, z-up world (:data:`geometry.BODY25` order),
- ``h36m17``: int16 ``(P, T, 17, 3)`` millimetres, z-up world (:data:`geometry.STRUCTRI17` order; the key keeps
  the files' original name, :attr:`Clip.structri17` in memory),
- ``fps`` (30), ``trials`` (CMU trial per person, e.g. ``"60_03"``), ``sources`` (data files per
  person), ``description``.

:func:`load_clip` returns a :class:`Clip` in float64 METRES; SHELF15/SHELF14 come from the STRUCTRI17
joints (``geometry.to_shelf15`` with the ``"h36m"`` head rule). Positions are quantised to 1 mm (error <= 0.5 mm).
The data was obtained from mocap.cs.cmu.edu (see ``mocap/assets/ACKNOWLEDGEMENTS.md``).
"""

from __future__ import annotations

import io
import zipfile
from pathlib import Path
from typing import BinaryIO, NamedTuple

import numpy as np
from jaxtyping import Float

from geometry import BODY25, STRUCTRI17, Skeleton, to_shelf15

from ._asf_amc import read_asf_amc
from ._bvh import CMU_METRES_PER_UNIT, SALSA_METRES_PER_UNIT, read_bvh
from ._motion import Motion, motion_joint_positions, resample_motion

__all__ = ["ASSETS", "CLIP_SOURCES", "Clip", "clip_from_motions", "list_clips", "load_clip",
           "read_clip_sources", "save_clip"]

ASSETS = Path(__file__).resolve().parent / "assets"

CLIP_SOURCES: dict[str, tuple[str, tuple[tuple[str, ...], ...]]] = {
    "02_01_walk": ("subject 02 walks", (("02.asf", "02_01.amc"),)),
    "02_03_run": ("subject 02 runs/jogs", (("02.asf", "02_03.amc"),)),
    "02_05_punch": ("subject 02 punches and strikes", (("02.asf", "02_05.amc"),)),
    "01_01_jumps": ("subject 01 jumps forward and turns around (playground)", (("01.asf", "01_01.amc"),)),
    "18_01_handshake": ("subject 18 walks and shakes hands (partner 19_01 not available)",
                        (("18_01.bvh",),)),
    "60_03_61_03_salsa": ("salsa pair captured together: 60 leads, 61 follows (Daz template rig)",
                          (("60_03_scaled.bvh",), ("61_03_scaled.bvh",))),
    "60_05_61_05_salsa": ("salsa pair captured together: 60 leads, 61 follows (Daz template rig)",
                          (("60_05_scaled.bvh",), ("61_05_scaled.bvh",))),
    "02_04_jump": ("subject 02 jumps and balances", (("02.asf", "02_04.amc"),)),
    "03_01_uneven": ("subject 03 walks on uneven terrain", (("03.asf", "03_01.amc"),)),
}
"""Clip name -> (description, files per person under ``<data_root>/cmu_mocap``)."""


class Clip(NamedTuple):
    """Joint positions of one or more people over time (NumPy, metres, z-up world)."""

    name: str
    fps: float
    body25: Float[np.ndarray, "P T 25 3"]
    structri17: Float[np.ndarray, "P T 17 3"]
    trials: tuple[str, ...]
    sources: tuple[str, ...]
    description: str

    @property
    def num_people(self) -> int:
        return self.body25.shape[0]

    @property
    def num_frames(self) -> int:
        return self.body25.shape[1]

    def joints(self, skeleton: Skeleton) -> Float[np.ndarray, "P T K 3"]:
        """Positions for BODY25, STRUCTRI17, SHELF15 or SHELF14 (metres)."""
        if skeleton.name == "BODY25":
            return self.body25
        if skeleton.name == "STRUCTRI17":
            return self.structri17
        if skeleton.name in ("SHELF15", "SHELF14"):
            shelf = np.asarray(to_shelf15(self.structri17, STRUCTRI17))
            return shelf if skeleton.name == "SHELF15" else shelf[..., :14, :]
        raise ValueError(f"a clip has no {skeleton.name} joints; use BODY25, STRUCTRI17, SHELF15 or SHELF14")


def read_clip_sources(data_root: str | Path, name: str) -> list[Motion]:
    """Read the source motions of clip ``name`` from ``<data_root>/cmu_mocap`` (native 120 Hz)."""
    folder = Path(data_root) / "cmu_mocap"
    try:
        _, people = CLIP_SOURCES[name]
    except KeyError:
        raise KeyError(f"unknown clip {name!r}; known: {sorted(CLIP_SOURCES)}") from None
    motions = []
    for files in people:
        if files[0].endswith(".asf"):
            motions.append(read_asf_amc(folder / files[0], folder / files[1]))
        elif files[0].startswith("18_01"):
            motions.append(read_bvh(folder / files[0], CMU_METRES_PER_UNIT, fps=120.0))
        else:
            motions.append(read_bvh(folder / files[0], SALSA_METRES_PER_UNIT))
    return motions


def clip_from_motions(name: str, motions: list[Motion], fps: float = 30.0, description: str = "",
                      sources: tuple[str, ...] = ()) -> Clip:
    """Resample the motions (people captured together, same frame count) to ``fps`` and map their joints."""
    if len({m.num_frames for m in motions}) != 1 or len({m.fps for m in motions}) != 1:
        raise ValueError(f"{name}: people of one clip need the same frame count and rate")
    resampled = [resample_motion(m, fps) if m.fps != fps else m for m in motions]
    return Clip(name, float(fps),
                np.stack([motion_joint_positions(m, BODY25) for m in resampled]),
                np.stack([motion_joint_positions(m, STRUCTRI17) for m in resampled]),
                tuple(m.name.replace("_scaled", "")[:5] for m in motions), tuple(sources), description)


def _millimetres(positions: np.ndarray, name: str) -> np.ndarray:
    mm = np.round(positions * 1000.0)
    if not np.isfinite(mm).all() or np.abs(mm).max() > np.iinfo(np.int16).max:
        raise ValueError(f"{name}: positions beyond +-32.7 m (or non-finite) do not fit int16 millimetres")
    return mm.astype(np.int16)


def save_clip(clip: Clip, path: str | Path | BinaryIO) -> None:
    """Write ``clip`` as int16 millimetres in a byte-for-byte deterministic ``.npz`` (fixed zip dates) to a path or
    an open binary file (as :func:`training.write_atomically` hands it)."""
    arrays = {
        "body25": _millimetres(clip.body25, clip.name),
        "h36m17": _millimetres(clip.structri17, clip.name),
        "fps": np.float64(clip.fps),
        "trials": np.array(clip.trials),
        "sources": np.array(clip.sources),
        "description": np.array(clip.description),
    }
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for key, value in arrays.items():
            buffer = io.BytesIO()
            np.lib.format.write_array(buffer, np.asarray(value), allow_pickle=False)
            info = zipfile.ZipInfo(key + ".npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            archive.writestr(info, buffer.getvalue())


def list_clips(assets: str | Path = ASSETS) -> list[str]:
    """Names of the shipped clips (``.npz`` files in ``assets``)."""
    return sorted(p.stem for p in Path(assets).glob("*.npz"))


def load_clip(name: str, assets: str | Path = ASSETS) -> Clip:
    """Load a shipped clip as float64 metres (z-up world). See the module docstring for its fields."""
    path = Path(assets) / f"{name}.npz"
    if not path.is_file():
        raise KeyError(f"no shipped clip {name!r} in {assets}; available: {list_clips(assets)}")
    with np.load(path, allow_pickle=False) as data:
        try:
            body25, structri17 = data["body25"], data["h36m17"]
            fps, trials, sources = float(data["fps"]), data["trials"], data["sources"]
            description = str(data["description"])
        except KeyError as e:
            raise ValueError(f"{path}: missing array {e}") from None
    if body25.shape[-2:] != (25, 3) or structri17.shape[-2:] != (17, 3) or body25.shape[:2] != structri17.shape[:2]:
        raise ValueError(f"{path}: bad shapes body25 {body25.shape}, structri17 {structri17.shape}")
    return Clip(name, fps, body25.astype(np.float64) / 1000.0, structri17.astype(np.float64) / 1000.0,
                tuple(str(t) for t in trials), tuple(str(s) for s in sources), description)

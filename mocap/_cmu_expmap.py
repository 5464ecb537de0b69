"""CMU motion in exponential-map form: the train/test split of the CMU-Mocap motion-prediction benchmark.

The files (``<data_root>/cmu_expmap/{train,test}/<action>/<action>_<k>.txt``, see that folder's README) hold one
120 Hz frame per line: 117 comma-separated numbers, the root position (values 0-2, CMU ASF length units, y up)
and the exponential map (axis-angle, radians) of each of 38 joints, joint 0 the root's global orientation. The
source's forward kinematics is in row-vector form, ``R_i = E(r_i) R_parent``, ``x_i = o_i R_parent + x_parent``
with ``E`` the Rodrigues matrix; in the column form of :class:`Motion` (``global_R[i] = global_R[parent] @
local_R[i]``) that is ``local_R[i] = E(r_i)^T``, and the offsets are the same vectors.

The 38 nodes carry the CMU ASF names of the bones that start at them (as :func:`read_asf_amc` names its
nodes), so the joint mappings of the ``"cmu"`` rig apply (:func:`motion_joint_positions`): node ``lfemur`` is
the left hip, ``head_end`` the top of the head. The source's thorax has zero length (``lowerneck`` sits on
``thorax``), and the zero-offset nodes (``lhipjoint``, ``lowerback``, ``lclavicle``, ``lhand``, ``lthumb`` and
their right counterparts) start a chain at their parent. Left and right follow the ASF: the chains with +x rest
offsets (nodes 1-6 and 20-28) are the left leg and arm.
"""

from __future__ import annotations

import os
from pathlib import Path

import jax
import numpy as np

from geometry import axis_angle_to_matrix

from ._bvh import CMU_METRES_PER_UNIT
from ._clips import Clip, clip_from_motions
from ._data_root import find_data_root
from ._motion import Motion, _pad, _padded_frames, build_motion, malformed

__all__ = ["CMU_EXPMAP_FPS", "CMU_EXPMAP_NODES", "CMU_EXPMAP_OFFSETS", "CMU_EXPMAP_PARENTS", "cmu_expmap_clip",
           "cmu_expmap_files", "cmu_expmap_split", "cmu_expmap_validation_files", "read_cmu_expmap"]

_jit_axis_angle_to_matrix = jax.jit(axis_angle_to_matrix)

CMU_EXPMAP_FPS = 120.0
"""Frames per second of the files (a walk advances about 1 cm per line)."""

CMU_EXPMAP_NODES: tuple[str, ...] = (
    "root",
    "lhipjoint", "lfemur", "ltibia", "lfoot", "ltoes", "ltoes_end",
    "rhipjoint", "rfemur", "rtibia", "rfoot", "rtoes", "rtoes_end",
    "lowerback", "upperback", "thorax", "lowerneck", "upperneck", "head", "head_end",
    "lclavicle", "lhumerus", "lradius", "lwrist", "lhand", "lfingers", "lfingers_end", "lthumb", "lthumb_end",
    "rclavicle", "rhumerus", "rradius", "rwrist", "rhand", "rfingers", "rfingers_end", "rthumb", "rthumb_end",
)
"""Node names in file order (ASF bone names; ``_end`` marks an end site)."""

CMU_EXPMAP_PARENTS: tuple[int, ...] = (-1, 0, 1, 2, 3, 4, 5, 0, 7, 8, 9, 10, 11, 0, 13, 14, 15, 16, 17, 18, 15, 20, 21,
                                       22, 23, 24, 25, 23, 27, 15, 29, 30, 31, 32, 33, 34, 32, 36)
"""Parent of each node (the folder README's kinematic tree)."""

CMU_EXPMAP_OFFSETS = np.array([
    [0, 0, 0], [0, 0, 0], [1.65674, -1.80282, 0.62477], [2.5972, -7.13576, 0], [2.49236, -6.8477, 0],
    [0.19704, -0.54136, 2.14581], [0, 0, 1.11249], [0, 0, 0], [-1.6107, -1.80282, 0.62476],
    [-2.59502, -7.12977, 0], [-2.4678, -6.78024, 0], [-0.23024, -0.63258, 2.13368], [0, 0, 1.11569], [0, 0, 0],
    [0.01961, 2.0545, -0.14112], [0.01021, 2.06436, -0.05921], [0, 0, 0], [0.00713, 1.56711, 0.14968],
    [0.03429, 1.56041, -0.10006], [0.01305, 1.6256, -0.05265], [0, 0, 0], [3.54205, 0.90436, -0.17364],
    [4.86513, 0, 0], [3.35554, 0, 0], [0, 0, 0], [0.66117, 0, 0], [0.53306, 0, 0], [0, 0, 0], [0.5412, 0, 0.5412],
    [0, 0, 0], [-3.49802, 0.75994, -0.32616], [-5.02649, 0, 0], [-3.36431, 0, 0], [0, 0, 0], [-0.73041, 0, 0],
    [-0.58887, 0, 0], [0, 0, 0], [-0.59786, 0, 0.59786],
])
"""Rest offset of each node from its parent (CMU ASF units, y up; 1 unit = 1/0.45 inch)."""

_VALUES_PER_FRAME = 3 + 3 * len(CMU_EXPMAP_NODES)
_SPLITS = ("train", "test")


def read_cmu_expmap(path: str | os.PathLike, name: str | None = None) -> Motion:
    """One exponential-map file as a :class:`Motion` (metres, z-up world, 120 Hz, the ``"cmu"`` rig).

    A line that does not hold 117 finite numbers (a trailing comma is allowed) is a ValueError
    ``"<file>:<line>: ..."``; so is a file without frames."""
    path = Path(path)
    rows = []
    with open(path) as lines:
        for number, line in enumerate(lines, start=1):
            fields = line.strip().removesuffix(",").split(",")
            if fields == [""]:
                continue
            if len(fields) != _VALUES_PER_FRAME:
                raise malformed(path, number, f"expected {_VALUES_PER_FRAME} comma-separated values, got {len(fields)}")
            try:
                values = [float(field) for field in fields]
            except ValueError:
                raise malformed(path, number, "a value is not a number") from None
            if not np.all(np.isfinite(values)):
                raise malformed(path, number, "a value is not finite")
            rows.append(values)
    if not rows:
        raise malformed(path, 1, "no frames")
    frames = np.asarray(rows)
    rotvecs = frames[:, 3:].reshape(len(frames), len(CMU_EXPMAP_NODES), 3)
    # Row-vector source: R_i = E(r_i) R_parent, so the column-form local rotation is E(r_i)^T = E(-r_i). Jitted on
    # padded frames: op by op, every file's length compiled each operation anew (15 s for the 24 test files).
    padded = _pad(-rotvecs, _padded_frames(len(rotvecs)))
    local_rotations = np.asarray(_jit_axis_angle_to_matrix(padded), dtype=np.float64)[:len(rotvecs)]
    return build_motion(CMU_EXPMAP_NODES, CMU_EXPMAP_PARENTS, CMU_EXPMAP_OFFSETS, local_rotations, frames[:, :3],
                        CMU_EXPMAP_FPS, CMU_METRES_PER_UNIT, name=name or path.stem)


def cmu_expmap_files(data_root: str | os.PathLike | None = None, split: str = "train") -> list[Path]:
    """The files of one split (``"train"`` or ``"test"``) of ``<data_root>/cmu_expmap``, sorted by action and
    number. The data folder is found as :func:`find_data_root` finds it; a missing one is a ValueError."""
    if split not in _SPLITS:
        raise ValueError(f"split must be one of {_SPLITS}, got {split!r}")
    root = find_data_root(data_root, "cmu_expmap")
    if root is None:
        raise ValueError("no data folder: pass data_root (--data-root on the command line) or set $MVMOCAP_DATA_ROOT "
                         "(a folder with cmu_expmap/)")
    files = sorted((root / "cmu_expmap" / split).glob("*/*.txt"))
    if not files:
        raise ValueError(f"{root / 'cmu_expmap' / split} holds no <action>/<file>.txt")
    return files


def cmu_expmap_validation_files(data_root: str | os.PathLike | None = None) -> list[Path]:
    """The project's validation files of the benchmark: the highest-numbered file of each action of the train split
    (in :func:`cmu_expmap_files`' order). A model trained on the rest of the train split is chosen on these; the
    test split is never used for a choice."""
    files = cmu_expmap_files(data_root, "train")
    actions: dict[str, list[Path]] = {}
    for file in files:
        actions.setdefault(file.parent.name, []).append(file)
    last = {max(group, key=lambda f: int(f.stem.rsplit("_", 1)[1])) for group in actions.values()}
    return [f for f in files if f in last]


def cmu_expmap_split(path: str | os.PathLike) -> str | None:
    """``"train"`` or ``"test"`` for a file of the CMU-Mocap benchmark (``.../cmu_expmap/<split>/<action>/<file>``),
    None for any other path: what training code checks to keep the test split out."""
    parts = Path(path).parts
    return parts[-3] if len(parts) >= 4 and parts[-4] == "cmu_expmap" and parts[-3] in _SPLITS else None


def cmu_expmap_clip(path: str | os.PathLike, fps: float = 30.0) -> Clip:
    """One exponential-map file as a :class:`Clip` (one person, resampled to ``fps``, BODY25 and STRUCTRI17
    joints), which :func:`synthesise_scene` takes beside the shipped clips. Named ``<split>/<action>/<file>``."""
    path = Path(path)
    name = "/".join(path.with_suffix("").parts[-3:])
    return clip_from_motions(name, [read_cmu_expmap(path, name=path.stem)], fps=fps,
                             description=f"CMU-Mocap benchmark file {name}", sources=(path.name,))

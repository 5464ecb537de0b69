"""BVH reader: hierarchy (``ROOT``/``JOINT``/``End Site``, ``OFFSET``, ``CHANNELS`` in any order),
then ``MOTION`` with ``Frames:``, ``Frame Time:`` and one line of channel values per frame.

A joint's rotation is the product of its rotation channels in the order listed
(``Zrotation Yrotation Xrotation`` -> ``Rz @ Ry @ Rx``), angles in degrees; position channels are
allowed on the root only and add to its offset. End sites become nodes named ``<parent>_end``.

Units: BVH has none. Pass ``metres_per_unit``: :data:`CMU_METRES_PER_UNIT` for CMU-unit files such
as 18_01.bvh (1/0.45 inch), :data:`SALSA_METRES_PER_UNIT` for the rescaled 60/61 salsa files.
A header rate within 0.01 % of an integer is snapped to it (``0.008333`` -> 120 Hz).
Some headers give a wrong ``Frame Time`` (18_01.bvh says 30 fps, the clip is 120 Hz): pass ``fps``.

Writer: :func:`write_bvh` writes a motion given as :class:`~mocap.Motion`'s fields (z-up world, metres) as a
y-up BVH that :func:`read_bvh`, with the same ``metres_per_unit``, reads back to the same node positions.
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np
from jaxtyping import ArrayLike, Float

import geometry

from ._motion import Y_UP_TO_Z_UP, Motion, build_motion, euler_angles, euler_matrices, malformed

__all__ = ["CMU_METRES_PER_UNIT", "SALSA_METRES_PER_UNIT", "read_bvh", "write_bvh"]

CMU_METRES_PER_UNIT = 0.0254 / 0.45
"""CMU's length unit (ASF ``length 0.45``): 1/0.45 inch = 56.44 mm."""

SALSA_METRES_PER_UNIT = 1.325
"""Scale for the ``*_scaled`` 60/61 salsa BVHs (shared Daz template rig, arbitrary units). In the rest
pose the eye nodes are 1.193 units above the foot end sites; 1.325 m/unit puts the eyes at 1.58 m,
the eye height of a person about 1.70 m tall (eye height ~ 0.93 x stature)."""

_POSITION = {"xposition": 0, "yposition": 1, "zposition": 2}
_ROTATION = {"xrotation": "X", "yrotation": "Y", "zrotation": "Z"}


def read_bvh(path: str | Path, metres_per_unit: float, fps: float | None = None, name: str = "") -> Motion:
    """Read a BVH file into a :class:`~mocap.Motion` (metres, z-up world; the file is taken as y-up).

    ``fps`` overrides the header's ``Frame Time``. Malformed input raises
    ``ValueError("<file>:<line>: ...")``. CRLF and LF files both parse.
    """
    path = Path(path)
    try:
        lines = path.read_text(encoding="latin-1").splitlines()
    except OSError as e:
        raise ValueError(f"{path}: cannot read ({e})") from None
    hierarchy = _parse_hierarchy(path, lines)
    num_frames, frame_time_line, frame_time = _parse_motion_header(path, lines, hierarchy.motion_line)
    if fps is None:
        fps = _header_fps(path, frame_time_line, frame_time)
    width = sum(len(c) for c in hierarchy.channels)
    values = _parse_frames(path, lines, hierarchy.motion_line + 3, num_frames, width)
    local_rotations, root_positions = _apply_channels(hierarchy, values)
    offsets = hierarchy.offsets.copy()
    offsets[0] = 0.0  # the root's offset is in root_positions
    return build_motion(hierarchy.names, hierarchy.parents, offsets, local_rotations, root_positions, fps,
                        metres_per_unit, name=name or path.stem)


class _Hierarchy(NamedTuple):
    """The ``HIERARCHY`` section: nodes in file order (depth first), their rest offsets (file units) and
    lower-case channel names, and the number of the ``MOTION`` line."""

    names: tuple[str, ...]
    parents: tuple[int, ...]
    offsets: Float[np.ndarray, "J 3"]
    channels: tuple[tuple[str, ...], ...]
    motion_line: int


@dataclasses.dataclass
class _HierarchyParser:
    """The nodes declared so far, and where the parser is in the nesting of ``{ }`` blocks."""

    path: Path
    names: list[str] = dataclasses.field(default_factory=list)
    parents: list[int] = dataclasses.field(default_factory=list)
    offsets: list[np.ndarray | None] = dataclasses.field(default_factory=list)
    channels: list[tuple[str, ...]] = dataclasses.field(default_factory=list)
    stack: list[int] = dataclasses.field(default_factory=list)  # the open blocks, innermost last
    pending: int | None = None  # node declared, waiting for its '{'

    def declare(self, n: int, key: str, tokens: list[str]) -> None:
        """A ``ROOT``, ``JOINT`` or ``End Site`` line."""
        if self.pending is not None:
            raise malformed(self.path, n, "expected '{' after a joint declaration")
        if key == "ROOT":
            if self.names:
                raise malformed(self.path, n, "only one ROOT is supported")
            if len(tokens) != 2:
                raise malformed(self.path, n, "ROOT needs one name")
            parent, node_name = -1, tokens[1]
        else:
            if not self.stack:
                raise malformed(self.path, n, f"{tokens[0]} outside the ROOT block")
            parent = self.stack[-1]
            if key == "END":
                node_name = self.names[parent] + "_end"
            else:
                if len(tokens) != 2:
                    raise malformed(self.path, n, "JOINT needs one name")
                node_name = tokens[1]
        if node_name in self.names:
            raise malformed(self.path, n, f"duplicate joint name {node_name!r}")
        self.names.append(node_name)
        self.parents.append(parent)
        self.offsets.append(None)
        self.channels.append(())
        self.pending = len(self.names) - 1

    def open_block(self, n: int) -> None:
        if self.pending is None:
            raise malformed(self.path, n, "unexpected '{'")
        self.stack.append(self.pending)
        self.pending = None

    def close_block(self, n: int) -> None:
        if not self.stack:
            raise malformed(self.path, n, "unbalanced '}'")
        j = self.stack.pop()
        if self.offsets[j] is None:
            raise malformed(self.path, n, f"joint {self.names[j]!r} has no OFFSET")

    def offset(self, n: int, tokens: list[str], raw: str) -> None:
        if not self.stack or self.pending is not None:
            raise malformed(self.path, n, "OFFSET outside a joint block")
        if len(tokens) != 4:
            raise malformed(self.path, n, f"OFFSET needs 3 numbers, got {len(tokens) - 1}")
        try:
            self.offsets[self.stack[-1]] = np.array([float(t) for t in tokens[1:]])
        except ValueError:
            raise malformed(self.path, n, f"OFFSET: not a number in {raw.strip()!r}") from None

    def declare_channels(self, n: int, tokens: list[str]) -> None:
        if not self.stack or self.pending is not None:
            raise malformed(self.path, n, "CHANNELS outside a joint block")
        j = self.stack[-1]
        try:
            count = int(tokens[1])
        except (IndexError, ValueError):
            raise malformed(self.path, n, "CHANNELS needs a count") from None
        chans = tuple(t.lower() for t in tokens[2:])
        if count != len(chans):
            raise malformed(self.path, n, f"CHANNELS says {count} but lists {len(chans)}")
        unknown = [c for c in chans if c not in _POSITION and c not in _ROTATION]
        if unknown or len(set(chans)) != len(chans):
            raise malformed(self.path, n, f"unknown or repeated channels {unknown or chans}")
        if self.parents[j] != -1 and any(c in _POSITION for c in chans):
            raise malformed(self.path, n, f"position channels are supported on the root only ({self.names[j]!r})")
        self.channels[j] = chans

    def finish(self, n: int) -> _Hierarchy:
        """At the ``MOTION`` line ``n``."""
        if self.stack or self.pending is not None or not self.names:
            raise malformed(self.path, n, "MOTION before the hierarchy is complete")
        return _Hierarchy(tuple(self.names), tuple(self.parents), np.stack(self.offsets), tuple(self.channels), n)


def _parse_hierarchy(path: Path, lines: list[str]) -> _Hierarchy:
    """Read lines up to ``MOTION``: the skeleton's nodes, their offsets and channels."""
    parser = _HierarchyParser(path)
    n = 0
    for n, raw in enumerate(lines, 1):
        tokens = raw.split()
        if not tokens:
            continue
        key = tokens[0].upper()
        if key == "HIERARCHY" and not parser.names:
            continue
        if key in ("ROOT", "JOINT") or (key == "END" and len(tokens) > 1 and tokens[1].upper() == "SITE"):
            parser.declare(n, key, tokens)
        elif key == "{":
            parser.open_block(n)
        elif key == "}":
            parser.close_block(n)
        elif key == "OFFSET":
            parser.offset(n, tokens, raw)
        elif key == "CHANNELS":
            parser.declare_channels(n, tokens)
        elif key == "MOTION":
            return parser.finish(n)
        else:
            raise malformed(path, n, f"unexpected {tokens[0]!r} in the hierarchy")
    raise malformed(path, n, "no MOTION section (truncated file?)")


def _parse_motion_header(path: Path, lines: list[str], motion_line: int) -> tuple[int, int, float]:
    """The ``Frames:`` and ``Frame Time:`` lines after ``MOTION``: the frame count, and the frame time's line and
    value (seconds)."""

    def header(index: int, label: str) -> tuple[int, str]:
        line_no = motion_line + index
        text = lines[line_no - 1].strip() if line_no <= len(lines) else ""
        if not text.lower().startswith(label.lower()):
            raise malformed(path, line_no, f"expected {label!r}")
        return line_no, text[len(label):].strip()

    line_no, text = header(1, "Frames:")
    try:
        num_frames = int(text)
    except ValueError:
        raise malformed(path, line_no, f"bad frame count {text!r}") from None
    line_no, text = header(2, "Frame Time:")
    try:
        frame_time = float(text)
    except ValueError:
        raise malformed(path, line_no, f"bad frame time {text!r}") from None
    return num_frames, line_no, frame_time


def _header_fps(path: Path, line_no: int, frame_time: float) -> float:
    """The rate a header's ``Frame Time`` stands for."""
    if not frame_time > 0:
        raise malformed(path, line_no, f"frame time must be positive, got {frame_time}")
    # headers round the frame time (0.008333): snap to the integer rate it stands for
    fps = 1.0 / frame_time
    return float(round(fps)) if abs(fps - round(fps)) < 1e-4 * fps else fps


def _parse_frames(path: Path, lines: list[str], first_line: int, num_frames: int,
                  width: int) -> Float[np.ndarray, "T C"]:
    """The frame lines from ``first_line`` on: ``num_frames`` lines of ``width`` channel values each."""
    data = [(i, l.split()) for i, l in enumerate(lines[first_line - 1:], first_line) if l.strip()]
    if len(data) < num_frames:
        raise malformed(path, len(lines), f"header says {num_frames} frames, file has {len(data)} (truncated?)")
    if len(data) > num_frames:
        raise malformed(path, data[num_frames][0], f"more frame lines than the {num_frames} in the header")
    for i, tok in data:
        if len(tok) != width:
            raise malformed(path, i, f"frame line has {len(tok)} values, the hierarchy has {width} channels")
    try:
        values = np.array(list(itertools.chain.from_iterable(tok for _, tok in data)), dtype=np.float64)
    except ValueError:
        for i, tok in data:
            for t in tok:
                try:
                    float(t)
                except ValueError:
                    raise malformed(path, i, f"not a number: {t!r}") from None
        raise
    values = values.reshape(num_frames, width)
    bad_rows = np.flatnonzero(~np.isfinite(values).all(axis=1))
    if bad_rows.size:
        raise malformed(path, data[bad_rows[0]][0], "non-finite value")
    return values


def _apply_channels(
    hierarchy: _Hierarchy, values: Float[np.ndarray, "T C"],
) -> tuple[Float[np.ndarray, "T J 3 3"], Float[np.ndarray, "T 3"]]:
    """Each node's local rotation per frame (its rotation channels multiplied in the listed order, identity without
    any) and the root's position (its offset plus its position channels), file units."""
    num_frames = len(values)
    local = np.broadcast_to(np.eye(3), (num_frames, len(hierarchy.names), 3, 3)).copy()
    root_positions = np.broadcast_to(hierarchy.offsets[0], (num_frames, 3)).copy()
    by_order: dict[str, list[tuple[int, list[int]]]] = {}  # Euler order -> (node, its rotation columns)
    column = 0
    for j, chans in enumerate(hierarchy.channels):
        rotation_columns, axes = [], ""
        for c in chans:
            if c in _POSITION:
                root_positions[:, _POSITION[c]] += values[:, column]
            else:
                rotation_columns.append(column)
                axes += _ROTATION[c]
            column += 1
        if axes:
            missing = [a for a in "XYZ" if a not in axes]
            by_order.setdefault(axes + "".join(missing), []).append((j, rotation_columns))
    for order, items in by_order.items():
        joints = [j for j, _ in items]
        angles = np.zeros((num_frames, len(items), 3))
        for k, (_, cols) in enumerate(items):
            angles[:, k, :len(cols)] = np.deg2rad(values[:, cols])
        local[:, joints] = euler_matrices(angles, order)
    return local, root_positions


_WRITE_ORDER = "ZYX"
"""Euler order of the written rotation channels (``Zrotation Yrotation Xrotation``: ``R = Rz @ Ry @ Rx``, the
most common BVH order), as :func:`geometry.matrix_to_euler` and the reader's :func:`~mocap.euler_matrices`."""
_ROTATION_TOLERANCE = 1e-5
"""Largest accepted ``|R^T R - I|`` entry: float32 rotations pass, matrices that are not rotations do not."""


def write_bvh(
    path: str | Path,
    joint_names: Sequence[str],
    parents: Sequence[int],
    offsets: Float[ArrayLike, "J 3"],
    local_rotations: Float[ArrayLike, "T J 3 3"],
    root_positions: Float[ArrayLike, "T 3"],
    *,
    fps: float,
    metres_per_unit: float,
) -> tuple[str, ...]:
    """Write a skeletal motion as a BVH file; ``read_bvh(path, metres_per_unit)`` returns the same node positions.

    The inputs follow :class:`~mocap.Motion` (a motion's fields can be passed as they are): ``offsets`` are the
    rest offsets from the parent in the parent's frame (metres; the root's is ignored), ``local_rotations`` the
    rotations relative to the parent's frame (the root's relative to the z-up world) and ``root_positions`` the
    root in the z-up world (metres). The file is y-up, as the reader assumes: the root's position and rotation
    get the inverse of :data:`Y_UP_TO_Z_UP`; offsets and the other rotations are written as they are, so the
    file's rest pose is the offsets read in a y-up frame.

    Layout: nodes depth first (children in index order). ``ROOT`` has ``OFFSET 0 0 0`` and the channels
    ``Xposition Yposition Zposition Zrotation Yrotation Xrotation``; every other joint with children has
    ``Zrotation Yrotation Xrotation`` (degrees, :func:`geometry.matrix_to_euler` order ``"ZYX"``). Joints with
    zero offsets (e.g. FLEX20's duplicates) are ordinary joints. A joint without children becomes an
    ``End Site`` with its offset: BVH gives end sites neither a name nor channels, so its rotation, which moves
    no node, is dropped and the reader names the node ``<parent>_end``. Lengths are written in units of
    ``metres_per_unit``, all values with 8 decimals.

    Returns:
        The name :func:`read_bvh` gives each input joint (input order): its own, or ``<parent>_end`` for a joint
        without children.

    Raises:
        ValueError: inconsistent shapes or names (not a tree, whitespace in a name, two childless joints under
            one parent: their end sites would get the same name), no frames, non-finite values, matrices that are
            not rotations, or a non-positive ``fps`` or ``metres_per_unit``.
    """
    path = Path(path)
    skeleton = geometry.Skeleton(path.name, tuple(joint_names), tuple(int(p) for p in parents))  # checks the tree
    offsets, local_rotations, root_positions = _checked_motion(
        path.name, skeleton, offsets, local_rotations, root_positions, fps, metres_per_unit)
    children = {j: [c for c, p in enumerate(skeleton.parents) if p == j] for j in range(skeleton.num_joints)}
    end_sites = {j for j, c in children.items() if not c and j != skeleton.root}
    read_names = tuple(skeleton.joints[skeleton.parents[j]] + "_end" if j in end_sites else name
                       for j, name in enumerate(skeleton.joints))
    if len(set(read_names)) != len(read_names):
        clashes = sorted({n for n in read_names if read_names.count(n) > 1})
        raise ValueError(f"{path.name}: the reader would name several nodes {clashes} (an end site is named "
                         f"'<parent>_end'; one childless joint per parent, and no joint named like an end site)")

    lines, channel_joints = _hierarchy(skeleton, children, end_sites, offsets / metres_per_unit)
    file_rotations = local_rotations[:, channel_joints].copy()
    file_rotations[:, 0] = Y_UP_TO_Z_UP.T @ file_rotations[:, 0]  # the root comes first; the reader turns it back
    degrees = np.rad2deg(euler_angles(file_rotations, _WRITE_ORDER))
    file_root = root_positions @ Y_UP_TO_Z_UP / metres_per_unit  # row-vector form of Y_UP_TO_Z_UP.T @ p
    num_frames = len(root_positions)
    lines += ["MOTION", f"Frames: {num_frames}", f"Frame Time: {1.0 / fps:.10f}"]
    with path.open("w", encoding="latin-1", newline="\n") as file:
        file.write("\n".join(lines) + "\n")
        np.savetxt(file, np.concatenate([file_root, degrees.reshape(num_frames, -1)], axis=1), fmt="%.8f")
    return read_names


def _checked_motion(
    file: str, skeleton: geometry.Skeleton, offsets: ArrayLike, local_rotations: ArrayLike, root_positions: ArrayLike,
    fps: float, metres_per_unit: float,
) -> tuple[Float[np.ndarray, "J 3"], Float[np.ndarray, "T J 3 3"], Float[np.ndarray, "T 3"]]:
    """:func:`write_bvh`'s arrays as float64 NumPy, after checking everything that would make a bad file."""
    offsets, local_rotations, root_positions = (
        np.asarray(a, dtype=np.float64) for a in (offsets, local_rotations, root_positions))
    num_joints = skeleton.num_joints
    num_frames = local_rotations.shape[0] if local_rotations.ndim == 4 else "T"
    for name, array, shape in (("offsets", offsets, (num_joints, 3)),
                               ("local_rotations", local_rotations, (num_frames, num_joints, 3, 3)),
                               ("root_positions", root_positions, (num_frames, 3))):
        if array.shape != shape:
            raise ValueError(f"{file}: {name} must have shape ({', '.join(map(str, shape))}) for "
                             f"{num_joints} joints, got {array.shape}")
    if num_frames < 1:
        raise ValueError(f"{file}: no frames to write")
    if not (np.isfinite(offsets).all() and np.isfinite(local_rotations).all() and np.isfinite(root_positions).all()):
        raise ValueError(f"{file}: non-finite offsets, rotations or root positions")
    gram_error = np.abs(np.swapaxes(local_rotations, -1, -2) @ local_rotations - np.eye(3)).max()
    if gram_error > _ROTATION_TOLERANCE or (np.linalg.det(local_rotations) <= 0).any():
        raise ValueError(f"{file}: local_rotations are not rotation matrices (|R^T R - I| up to {gram_error:.2g})")
    if not (np.isfinite(fps) and fps > 0 and np.isfinite(metres_per_unit) and metres_per_unit > 0):
        raise ValueError(f"{file}: fps and metres_per_unit must be positive, got {fps} and {metres_per_unit}")
    if any(not name.isascii() or name.split() != [name] for name in skeleton.joints):
        raise ValueError(f"{file}: BVH names must be non-empty ASCII without whitespace, got {skeleton.joints}")
    return offsets, local_rotations, root_positions


def _hierarchy(
    skeleton: geometry.Skeleton, children: dict[int, list[int]], end_sites: set[int],
    offsets: Float[np.ndarray, "J 3"],
) -> tuple[list[str], list[int]]:
    """The ``HIERARCHY`` lines (``offsets`` in file units) and the joints with channels in the order the frame
    lines list them: depth first from the root, children in index order."""
    lines, channel_joints = ["HIERARCHY"], []
    rotation = " ".join(f"{axis}rotation" for axis in _WRITE_ORDER)

    def node(j: int, depth: int) -> None:
        indent, offset = "  " * depth, offsets[j] if j != skeleton.root else np.zeros(3)
        if j in end_sites:
            lines.append(f"{indent}End Site")
        else:
            lines.append(f"{indent}{'ROOT' if j == skeleton.root else 'JOINT'} {skeleton.joints[j]}")
            channel_joints.append(j)
        lines.append(indent + "{")
        lines.append(f"{indent}  OFFSET {offset[0]:.8f} {offset[1]:.8f} {offset[2]:.8f}")
        if j == skeleton.root:
            lines.append(f"{indent}  CHANNELS 6 Xposition Yposition Zposition {rotation}")
        elif j not in end_sites:
            lines.append(f"{indent}  CHANNELS 3 {rotation}")
        for child in children[j]:
            node(child, depth + 1)
        lines.append(indent + "}")

    node(skeleton.root, 0)
    return lines, channel_joints

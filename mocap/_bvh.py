"""BVH reader: hierarchy (``ROOT``/``JOINT``/``End Site``, ``OFFSET``, ``CHANNELS`` in any order),
then ``MOTION`` with ``Frames:``, ``Frame Time:`` and one line of channel values per frame.

A joint's rotation is the product of its rotation channels in the order listed
(``Zrotation Yrotation Xrotation`` -> ``Rz @ Ry @ Rx``), angles in degrees; position channels are
allowed on the root only and add to its offset. End sites become nodes named ``<parent>_end``.

Units: BVH has none. Pass ``metres_per_unit``: :data:`CMU_METRES_PER_UNIT` for CMU-unit files such
as 18_01.bvh (1/0.45 inch), :data:`SALSA_METRES_PER_UNIT` for the rescaled 60/61 salsa files.
A header rate within 0.01 % of an integer is snapped to it (``0.008333`` -> 120 Hz).
Some headers give a wrong ``Frame Time`` (18_01.bvh says 30 fps, the clip is 120 Hz): pass ``fps``.
"""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np

from ._motion import Motion, build_motion, euler_matrices, malformed

__all__ = ["CMU_METRES_PER_UNIT", "SALSA_METRES_PER_UNIT", "read_bvh"]

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
    names: list[str] = []
    parents: list[int] = []
    offsets: list[np.ndarray | None] = []
    channels: list[tuple[str, ...]] = []
    stack: list[int] = []
    pending: int | None = None  # node declared, waiting for its '{'
    n = 0
    motion_line = None
    for n, raw in enumerate(lines, 1):
        tokens = raw.split()
        if not tokens:
            continue
        key = tokens[0].upper()
        if key == "HIERARCHY" and not names:
            continue
        if key in ("ROOT", "JOINT") or (key == "END" and len(tokens) > 1 and tokens[1].upper() == "SITE"):
            if pending is not None:
                raise malformed(path, n, "expected '{' after a joint declaration")
            if key == "ROOT":
                if names:
                    raise malformed(path, n, "only one ROOT is supported")
                if len(tokens) != 2:
                    raise malformed(path, n, "ROOT needs one name")
                parent, node_name = -1, tokens[1]
            else:
                if not stack:
                    raise malformed(path, n, f"{tokens[0]} outside the ROOT block")
                parent = stack[-1]
                if key == "END":
                    node_name = names[parent] + "_end"
                else:
                    if len(tokens) != 2:
                        raise malformed(path, n, "JOINT needs one name")
                    node_name = tokens[1]
            if node_name in names:
                raise malformed(path, n, f"duplicate joint name {node_name!r}")
            names.append(node_name)
            parents.append(parent)
            offsets.append(None)
            channels.append(())
            pending = len(names) - 1
        elif key == "{":
            if pending is None:
                raise malformed(path, n, "unexpected '{'")
            stack.append(pending)
            pending = None
        elif key == "}":
            if not stack:
                raise malformed(path, n, "unbalanced '}'")
            j = stack.pop()
            if offsets[j] is None:
                raise malformed(path, n, f"joint {names[j]!r} has no OFFSET")
        elif key == "OFFSET":
            if not stack or pending is not None:
                raise malformed(path, n, "OFFSET outside a joint block")
            if len(tokens) != 4:
                raise malformed(path, n, f"OFFSET needs 3 numbers, got {len(tokens) - 1}")
            try:
                offsets[stack[-1]] = np.array([float(t) for t in tokens[1:]])
            except ValueError:
                raise malformed(path, n, f"OFFSET: not a number in {raw.strip()!r}") from None
        elif key == "CHANNELS":
            if not stack or pending is not None:
                raise malformed(path, n, "CHANNELS outside a joint block")
            j = stack[-1]
            try:
                count = int(tokens[1])
            except (IndexError, ValueError):
                raise malformed(path, n, "CHANNELS needs a count") from None
            chans = tuple(t.lower() for t in tokens[2:])
            if count != len(chans):
                raise malformed(path, n, f"CHANNELS says {count} but lists {len(chans)}")
            unknown = [c for c in chans if c not in _POSITION and c not in _ROTATION]
            if unknown or len(set(chans)) != len(chans):
                raise malformed(path, n, f"unknown or repeated channels {unknown or chans}")
            if parents[j] != -1 and any(c in _POSITION for c in chans):
                raise malformed(path, n, f"position channels are supported on the root only ({names[j]!r})")
            channels[j] = chans
        elif key == "MOTION":
            if stack or pending is not None or not names:
                raise malformed(path, n, "MOTION before the hierarchy is complete")
            motion_line = n
            break
        else:
            raise malformed(path, n, f"unexpected {tokens[0]!r} in the hierarchy")
    if motion_line is None:
        raise malformed(path, n, "no MOTION section (truncated file?)")

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
    if fps is None:
        if not frame_time > 0:
            raise malformed(path, line_no, f"frame time must be positive, got {frame_time}")
        # headers round the frame time (0.008333): snap to the integer rate it stands for
        fps = 1.0 / frame_time
        if abs(fps - round(fps)) < 1e-4 * fps:
            fps = float(round(fps))
    first_data = motion_line + 3
    data = [(i, l.split()) for i, l in enumerate(lines[first_data - 1:], first_data) if l.strip()]
    if len(data) < num_frames:
        raise malformed(path, len(lines), f"header says {num_frames} frames, file has {len(data)} (truncated?)")
    if len(data) > num_frames:
        raise malformed(path, data[num_frames][0], f"more frame lines than the {num_frames} in the header")
    width = sum(len(c) for c in channels)
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

    num_nodes = len(names)
    local = np.broadcast_to(np.eye(3), (num_frames, num_nodes, 3, 3)).copy()
    root_positions = np.broadcast_to(offsets[0], (num_frames, 3)).copy()
    by_order: dict[str, list[tuple[int, list[int]]]] = {}
    column = 0
    for j, chans in enumerate(channels):
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
    offsets_array = np.stack(offsets)
    offsets_array[0] = 0.0
    return build_motion(tuple(names), tuple(parents), offsets_array, local, root_positions, fps,
                        metres_per_unit, name=name or path.stem)

"""Acclaim ASF/AMC reader (the original CMU motion-capture format).

ASF: ``:units`` (``mass``, ``length``, ``angle deg|rad``), ``:root`` (``order`` of the AMC root
values, ``axis`` order, ``position``, ``orientation``), ``:bonedata`` (per bone ``name``,
``direction``, ``length``, ``axis a b c ORDER``, ``dof``), ``:hierarchy``. AMC: optional ``#``
comments and ``:FULLY-SPECIFIED`` / ``:DEGREES`` / ``:RADIANS`` flags, then per frame its number and
one line per bone with the values of its ``dof`` in order.

Kinematics (as CMU's own ``amc2mat``): with ``C_b`` the bone's axis rotation and ``M_b`` its motion
rotation, both composed in the order given (``XYZ`` means rotate about x, then y, then z, i.e.
``Rz @ Ry @ Rx``), the bone's world rotation is ``W_b = W_parent @ C_b @ M_b @ C_b^-1`` and its end is
``end(parent) + W_b @ (length_b * direction_b)``. :func:`read_asf_amc` expresses this in the
:class:`~mocap.Motion` node convention: node ``b`` is the START of bone ``b`` with local rotation
``C_b @ M_b @ C_b^-1`` and offset = its parent bone's vector (leaf bones get an end site
``<bone>_end``), so "joint = end of the named bone" is node ``<child bone>`` or ``<bone>_end``.

One ASF length unit is ``0.0254 / length`` metres (CMU: ``length 0.45``, so 1/0.45 inch, 56.44 mm).
AMC files store no frame rate: CMU captured at 120 Hz.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
from jaxtyping import Float

from ._motion import Motion, build_motion, euler_matrices, malformed

__all__ = ["AsfSkeleton", "read_asf", "read_amc", "read_asf_amc"]

_AXIS_DOFS = ("rx", "ry", "rz")


class AsfSkeleton:
    """A parsed ASF skeleton (NumPy, source units).

    Attributes: ``bones`` (names, in file order), ``parent`` (bone -> parent bone or ``"root"``),
    ``vector`` (bone -> length * direction, (3,)), ``axis`` (bone -> (3, 3) ``C_b``), ``dof`` (bone
    -> tuple of ``rx``/``ry``/``rz``), ``root_order`` (AMC root channels, e.g. ``TX TY TZ RX RY RZ``),
    ``root_axis`` ((3, 3)), ``metres_per_unit``, ``degrees`` (angle unit of the file).
    """

    def __init__(self, path: Path):
        self.path = path
        self.bones: list[str] = []
        self.parent: dict[str, str] = {}
        self.vector: dict[str, np.ndarray] = {}
        self.axis: dict[str, np.ndarray] = {}
        self.dof: dict[str, tuple[str, ...]] = {}
        self.root_order: tuple[str, ...] = ("TX", "TY", "TZ", "RX", "RY", "RZ")
        self.root_axis = np.eye(3)
        self.root_axis_order = "XYZ"
        self.metres_per_unit = 0.0254
        self.degrees = True


def _application_order(axes: str) -> str:
    """A full application order (first axis applied first) containing ``axes`` as a subsequence;
    ``XYZ`` whenever possible, so that most bones share one jitted rotation call."""
    it = iter("XYZ")
    if all(a in it for a in axes):
        return "XYZ"
    return axes + "".join(a for a in "XYZ" if a not in axes)


def _full_angles(angles: np.ndarray, axes: str) -> tuple[np.ndarray, str]:
    """Angles (T, len(axes)) -> (T, 3) in :func:`_application_order`, zeros for absent axes."""
    order = _application_order(axes)
    full = np.zeros(angles.shape[:-1] + (3,))
    for k, a in enumerate(axes):
        full[..., order.index(a)] = angles[..., k]
    return full, order


def _rotations(items: list[tuple[np.ndarray, str]]) -> list[np.ndarray]:
    """Rotation matrices (T, 3, 3) for ``(angles (T, n) radians, axes)`` items, applying ``axes[0]``
    first (so ``XYZ`` gives ``Rz @ Ry @ Rx``); items sharing an order share one kernel call."""
    full = [_full_angles(a, axes) for a, axes in items]
    out: list[np.ndarray | None] = [None] * len(items)
    for order in {o for _, o in full}:
        members = [i for i, (_, o) in enumerate(full) if o == order]
        stacked = np.stack([full[i][0][..., ::-1] for i in members], axis=1)
        matrices = euler_matrices(stacked, order[::-1])
        for k, i in enumerate(members):
            out[i] = matrices[:, k]
    return out


def _floats(path, line_no, tokens, count, what):
    if len(tokens) != count:
        raise malformed(path, line_no, f"{what} needs {count} numbers, got {len(tokens)}")
    try:
        return np.array([float(t) for t in tokens])
    except ValueError:
        raise malformed(path, line_no, f"{what}: not a number in {' '.join(tokens)!r}") from None


def _lines(path: Path) -> list[str]:
    try:
        return path.read_text(encoding="latin-1").splitlines()
    except OSError as e:
        raise ValueError(f"{path}: cannot read ({e})") from None


_ASF_SECTIONS = (":units", ":root", ":bonedata", ":hierarchy", ":documentation", ":version", ":name")
"""Section keywords an ASF file may use; the parser reads the first four and skips the others' lines."""


@dataclasses.dataclass
class _BoneBlock:
    """The fields of one ``begin`` ... ``end`` bone block read so far (``start`` is the ``begin`` line)."""

    start: int
    name: str | None = None
    direction: Float[np.ndarray, "3"] | None = None
    length: float | None = None
    axis: tuple[Float[np.ndarray, "3"], str] | None = None  # angles in the file's unit, application order
    dof: tuple[str, ...] = ()


@dataclasses.dataclass
class _AsfParser:
    """The skeleton read so far, with one method per section keyword; :meth:`finish` checks and completes it."""

    asf: AsfSkeleton
    bone: _BoneBlock | None = None  # the open bone block
    root_axis_order: str = "XYZ"
    root_orientation: Float[np.ndarray, "3"] = dataclasses.field(default_factory=lambda: np.zeros(3))
    hierarchy_children: set[str] = dataclasses.field(default_factory=set)

    @property
    def path(self) -> Path:
        return self.asf.path

    def radians(self, angles: np.ndarray) -> np.ndarray:
        """Angles in the unit of the ``:units angle`` line read so far, in radians."""
        return np.deg2rad(angles) if self.asf.degrees else angles

    def units(self, n: int, tokens: list[str]) -> None:
        """A ``:units`` line: ``length`` and ``angle`` are used, others (``mass``) ignored."""
        key = tokens[0]
        if key == "length":
            length = _floats(self.path, n, tokens[1:], 1, "units length")[0]
            if length <= 0:
                raise malformed(self.path, n, "units length must be positive")
            self.asf.metres_per_unit = 0.0254 / length
        elif key == "angle":
            if len(tokens) != 2 or tokens[1].lower() not in ("deg", "rad"):
                raise malformed(self.path, n, "units angle must be 'deg' or 'rad'")
            self.asf.degrees = tokens[1].lower() == "deg"

    def root(self, n: int, tokens: list[str]) -> None:
        """A ``:root`` line: ``order``, ``axis`` and ``orientation`` are used, ``position`` only checked."""
        key = tokens[0]
        if key == "order":
            order = tuple(t.upper() for t in tokens[1:])
            if sorted(order) != sorted(("TX", "TY", "TZ", "RX", "RY", "RZ")):
                raise malformed(self.path, n, f"root order must list TX TY TZ RX RY RZ once each, got {order}")
            self.asf.root_order = order
        elif key == "axis":
            if len(tokens) != 2 or sorted(tokens[1].upper()) != ["X", "Y", "Z"]:
                raise malformed(self.path, n, "root axis must be a permutation of XYZ")
            self.root_axis_order = tokens[1].upper()
        elif key == "orientation":
            self.root_orientation = _floats(self.path, n, tokens[1:], 3, "root orientation")
        elif key == "position":
            _floats(self.path, n, tokens[1:], 3, "root position")

    def bonedata(self, n: int, tokens: list[str]) -> None:
        """A ``:bonedata`` line: ``begin``, ``end``, or a field of the open bone block (unknown fields such as
        ``id`` and ``limits`` are ignored)."""
        key = tokens[0]
        if key == "begin":
            self.bone = _BoneBlock(start=n)
        elif key == "end":
            self.end_bone(n)
        elif self.bone is None:
            raise malformed(self.path, n, f"{key!r} outside a bone 'begin' ... 'end' block")
        elif key == "name":
            if len(tokens) != 2:
                raise malformed(self.path, n, "bone name must be one word")
            self.bone.name = tokens[1]
        elif key == "direction":
            self.bone.direction = _floats(self.path, n, tokens[1:], 3, "direction")
        elif key == "length":
            self.bone.length = _floats(self.path, n, tokens[1:], 1, "length")[0]
        elif key == "axis":
            if len(tokens) != 5 or sorted(tokens[4].upper()) != ["X", "Y", "Z"]:
                raise malformed(self.path, n, "axis needs three angles and an order such as XYZ")
            self.bone.axis = (_floats(self.path, n, tokens[1:4], 3, "axis"), tokens[4].upper())
        elif key == "dof":
            dofs = tuple(t.lower() for t in tokens[1:])
            bad = [d for d in dofs if d not in _AXIS_DOFS]
            if bad or len(set(dofs)) != len(dofs):
                raise malformed(self.path, n, f"unsupported or repeated dof {bad or dofs} (only rx ry rz)")
            self.bone.dof = dofs

    def end_bone(self, n: int) -> None:
        """The ``end`` line ``n`` of a bone block: add the bone (its axis angles in the angle unit read so far)."""
        bone = self.bone
        if bone is None:
            raise malformed(self.path, n, "'end' without 'begin'")
        for field in ("name", "direction", "length", "axis"):
            if getattr(bone, field) is None:
                raise malformed(self.path, bone.start, f"bone block has no {field!r}")
        name = bone.name
        if name in self.asf.vector or name == "root":
            raise malformed(self.path, bone.start, f"duplicate bone {name!r}")
        norm = np.linalg.norm(bone.direction)
        if norm == 0:
            raise malformed(self.path, bone.start, f"bone {name!r} has a zero direction")
        self.asf.bones.append(name)
        self.asf.vector[name] = bone.length * bone.direction / norm
        angles, axis_order = bone.axis
        self.asf.axis[name] = _rotations([(self.radians(angles)[None], axis_order)])[0][0]
        self.asf.dof[name] = bone.dof
        self.bone = None

    def hierarchy(self, n: int, tokens: list[str]) -> None:
        """A ``:hierarchy`` line: ``parent child ...`` of bones already declared (``begin``/``end`` skipped)."""
        parent = tokens[0]
        if parent in ("begin", "end"):
            return
        if parent != "root" and parent not in self.asf.vector:
            raise malformed(self.path, n, f"unknown bone {parent!r} in hierarchy")
        for child in tokens[1:]:
            if child not in self.asf.vector:
                raise malformed(self.path, n, f"unknown bone {child!r} in hierarchy")
            if child in self.hierarchy_children:
                raise malformed(self.path, n, f"bone {child!r} has two parents")
            self.hierarchy_children.add(child)
            self.asf.parent[child] = parent

    def finish(self, last_line: int) -> AsfSkeleton:
        """At the end of the file (line ``last_line``): check that the skeleton is complete, add the root axis
        (its orientation in the file's final angle unit)."""
        if self.bone is not None:
            raise malformed(self.path, last_line, "file ends inside a bone block")
        if not self.asf.bones:
            raise malformed(self.path, last_line, "no :bonedata bones")
        orphans = [b for b in self.asf.bones if b not in self.asf.parent]
        if orphans:
            raise malformed(self.path, last_line, f"bones missing from :hierarchy: {orphans}")
        self.asf.root_axis = _rotations([(self.radians(self.root_orientation)[None], self.root_axis_order)])[0][0]
        self.asf.root_axis_order = self.root_axis_order
        return self.asf


def read_asf(path: str | Path) -> AsfSkeleton:
    """Parse an ASF skeleton; malformed input raises ``ValueError("<file>:<line>: ...")``."""
    path = Path(path)
    lines = _lines(path)
    parser = _AsfParser(AsfSkeleton(path))
    read_line = {":units": parser.units, ":root": parser.root, ":bonedata": parser.bonedata,
                 ":hierarchy": parser.hierarchy}
    section = ""
    for n, raw in enumerate(lines, 1):
        tokens = raw.split()
        if not tokens or tokens[0].startswith("#"):
            continue
        if tokens[0].startswith(":"):
            if tokens[0] not in _ASF_SECTIONS:
                raise malformed(path, n, f"unknown ASF section {tokens[0]!r}")
            section = tokens[0]
        elif section in read_line:
            read_line[section](n, tokens)
    return parser.finish(len(lines))


def read_amc(path: str | Path, asf: AsfSkeleton) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Parse AMC frames: ``(root values (T, 6) in the ASF root order, {bone: (T, n_dof)})``.

    Angles are returned in radians, translations in ASF units. Every frame must list the same bones
    in the same order (the first frame's), each with as many values as its ``dof``.
    """
    path = Path(path)
    lines = _lines(path)
    degrees = asf.degrees
    first = None
    for n, raw in enumerate(lines, 1):
        s = raw.strip()
        if not s or s.startswith("#"):
            continue
        if s.startswith(":"):
            flag = s.upper()
            if flag == ":DEGREES":
                degrees = True
            elif flag == ":RADIANS":
                degrees = False
            continue
        first = n - 1
        break
    if first is None:
        raise malformed(path, len(lines), "no frames")
    body = [(n, raw.split()) for n, raw in enumerate(lines[first:], first + 1) if raw.strip()]
    frame_starts = [i for i, (_, tok) in enumerate(body) if len(tok) == 1 and tok[0].isdigit()]
    if not frame_starts or frame_starts[0] != 0:
        raise malformed(path, body[0][0], f"expected a frame number, got {' '.join(body[0][1])!r}")
    block = frame_starts[1] - 1 if len(frame_starts) > 1 else len(body) - 1
    names = [tok[0] for _, tok in body[1:1 + block]]
    for (n, tok) in body[1:1 + block]:
        if tok[0] != "root" and tok[0] not in asf.dof:
            raise malformed(path, n, f"unknown bone {tok[0]!r}")
    if "root" not in names or len(set(names)) != len(names):
        raise malformed(path, body[0][0], "first frame must list 'root' and each bone once")
    expected_counts = [6 if b == "root" else len(asf.dof[b]) for b in names]
    num_frames = len(frame_starts)
    if len(body) != num_frames * (block + 1):
        # find the first frame whose block is not the right size
        for k, start in enumerate(frame_starts):
            end = frame_starts[k + 1] if k + 1 < num_frames else len(body)
            if end - start != block + 1:
                n = body[min(end, len(body)) - 1][0]
                raise malformed(path, n, f"frame {body[start][1][0]} has {end - start - 1} bone lines, "
                                f"expected {block} (truncated or extra lines?)")
    tokens = []
    first_frame_number = int(body[0][1][0])
    for k, start in enumerate(frame_starts):
        n, tok = body[start]
        if int(tok[0]) != first_frame_number + k:
            raise malformed(path, n, f"frame number {tok[0]} out of sequence, expected {first_frame_number + k}")
        for (n, tok), bone_name, count in zip(body[start + 1:start + 1 + block], names, expected_counts):
            if tok[0] != bone_name:
                if tok[0] != "root" and tok[0] not in asf.dof:
                    raise malformed(path, n, f"unknown bone {tok[0]!r}")
                raise malformed(path, n, f"bone {tok[0]!r} where {bone_name!r} was expected (bone order "
                                "must match the first frame)")
            if len(tok) != count + 1:
                raise malformed(path, n, f"bone {bone_name!r} needs {count} values, got {len(tok) - 1}")
            tokens.extend(tok[1:])
    try:
        values = np.array(tokens, dtype=np.float64)
    except ValueError:
        for start in frame_starts:
            for n, tok in body[start + 1:start + 1 + block]:
                for t in tok[1:]:
                    try:
                        float(t)
                    except ValueError:
                        raise malformed(path, n, f"not a number: {t!r}") from None
        raise
    if not np.isfinite(values).all():
        bad = int(np.flatnonzero(~np.isfinite(values))[0])
        row = bad // sum(expected_counts)
        raise malformed(path, body[frame_starts[row]][0], "non-finite value in this frame")
    values = values.reshape(num_frames, sum(expected_counts))
    columns = np.cumsum([0] + expected_counts)
    per_bone = {b: values[:, columns[i]:columns[i + 1]] for i, b in enumerate(names)}
    root = per_bone.pop("root").copy()
    rotation_columns = [i for i, c in enumerate(asf.root_order) if c.startswith("R")]
    if degrees:
        root[:, rotation_columns] = np.deg2rad(root[:, rotation_columns])
        per_bone = {b: np.deg2rad(v) for b, v in per_bone.items()}
    return root, per_bone


def read_asf_amc(asf_path: str | Path, amc_path: str | Path, fps: float = 120.0, name: str = "") -> Motion:
    """Read a CMU ASF skeleton and AMC motion into a :class:`~mocap.Motion` (metres, z-up).

    Nodes: ``root``, then one node per bone at the bone's START (root-first depth-first order), plus
    ``<bone>_end`` for each leaf bone. ``fps`` defaults to CMU's 120 Hz (AMC files store no rate).
    """
    asf = read_asf(asf_path)
    root_values, per_bone = read_amc(amc_path, asf)
    num_frames = root_values.shape[0]
    children: dict[str, list[str]] = {"root": []}
    for b in asf.bones:
        children.setdefault(b, [])
        children[asf.parent[b]].append(b)
    names, parents, offsets = ["root"], [-1], [np.zeros(3)]
    rotations = [None]
    stack = [(c, 0) for c in reversed(children["root"])]
    while stack:
        bone, parent_node = stack.pop()
        names.append(bone)
        parents.append(parent_node)
        parent_bone = names[parent_node]
        offsets.append(np.zeros(3) if parent_bone == "root" else asf.vector[parent_bone])
        node = len(names) - 1
        dofs = asf.dof[bone]
        if dofs and bone not in per_bone:
            raise malformed(amc_path, 1, f"bone {bone!r} has dof {dofs} in the ASF but no AMC values")
        rotations.append((per_bone[bone], "".join(d[1].upper() for d in dofs)) if dofs else None)
        if not children[bone]:
            names.append(bone + "_end")
            parents.append(node)
            offsets.append(asf.vector[bone])
            rotations.append(None)
        stack.extend((c_, node) for c_ in reversed(children[bone]))
    order = asf.root_order
    translation = root_values[:, [order.index("TX"), order.index("TY"), order.index("TZ")]]
    root_angles = root_values[:, [order.index("R" + a) for a in asf.root_axis_order]]
    rotations[0] = (root_angles, asf.root_axis_order)
    axis = [asf.root_axis] + [asf.axis.get(n, np.eye(3)) for n in names[1:]]
    moving = [j for j, r in enumerate(rotations) if r is not None]
    local = np.broadcast_to(np.eye(3), (num_frames, len(names), 3, 3)).copy()
    for j, motion in zip(moving, _rotations([rotations[j] for j in moving])):
        local[:, j] = axis[j] @ motion @ axis[j].T
    return build_motion(tuple(names), tuple(parents), np.stack(offsets), local, translation, fps,
                        asf.metres_per_unit, name=name or Path(amc_path).stem)

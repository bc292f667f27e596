"""Acclaim ASF skeleton reader.

Acclaim forward kinematics (column vectors), as in CMU's data: for ``axis ax ay az XYZ``
the bone's axis matrix is C = Rz(az)·Ry(ay)·Rx(ax); the AMC angles give
M = Rz(rz)·Ry(ry)·Rx(rx); the bone's local rotation is L = C·M·Cᵀ, its global rotation
G = G_parent·L, and its end point is the parent's end point + length·G·direction.
In :mod:`priortrack.data.skeleton` terms a bone becomes a joint at its start point whose
offset is the parent bone's vector and whose rotation axes are C's columns; leaf bones get
an extra ``<bone>_end`` joint at their end point.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from priortrack.data.skeleton import SLOTS, Skeleton, check_body
from priortrack.errors import PriortrackError

INCH = 0.0254
_AXES = {"x": 0, "y": 1, "z": 2}


def euler_matrix(angles: np.ndarray, order: str) -> np.ndarray:
    """Rotation for Euler angles (radians) in an ASF order string: "XYZ" → Rz·Ry·Rx.

    The first letter is applied first, i.e. is the rightmost factor.
    """
    R = np.eye(3)
    for letter in order.lower():
        R = axis_rotation(_AXES[letter], angles[_AXES[letter]]) @ R
    return R


def axis_rotation(axis: int, angle: float) -> np.ndarray:
    """(3, 3) rotation by ``angle`` radians about coordinate axis 0, 1 or 2."""
    c, s = np.cos(angle), np.sin(angle)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R = np.eye(3)
    R[i, i] = R[j, j] = c
    R[i, j], R[j, i] = -s, s
    return R


@dataclass
class _Bone:
    name: str
    line: int
    direction: np.ndarray | None = None
    length: float | None = None
    axis: np.ndarray | None = None
    order: str = "XYZ"
    dofs: list[str] = field(default_factory=list)


class _Lines:
    """Numbered, comment-free, non-empty lines of a text file."""

    def __init__(self, path: Path, kind: str):
        self.path = path
        try:
            text = path.read_text(encoding="utf-8", errors="replace")
        except OSError as exc:
            raise PriortrackError(f"cannot read {kind} file {path}: {exc.strerror}") from None
        self.items = [(n, kept) for n, line in enumerate(text.splitlines(), start=1)
                      if (kept := line.partition("#")[0].strip())]

    def fail(self, line: int, message: str) -> PriortrackError:
        return PriortrackError(f"{self.path}:{line}: {message}")


#: The longest bone a body file may declare, metres (CMU's longest is 0.46 m).
MAX_BONE_M = 3.0
#: The largest magnitude of any number in an ASF file (lengths, directions, angles, positions).
MAX_VALUE = 1e6


def _floats(lines: _Lines, line: int, words: list[str], count: int, what: str) -> np.ndarray:
    if len(words) < count:
        raise lines.fail(line, f"{what} needs {count} numbers, found {len(words)}")
    try:
        values = np.array([float(w) for w in words[:count]])
    except (ValueError, OverflowError):
        raise lines.fail(line, f"{what} has a value that is not a number: {' '.join(words)}") from None
    if not np.isfinite(values).all():
        raise lines.fail(line, f"{what} has a non-finite value: {' '.join(words[:count])}")
    if np.abs(values).max(initial=0.0) > MAX_VALUE:
        raise lines.fail(line, f"{what} is out of range (|value| > {MAX_VALUE:g}): {' '.join(words[:count])}")
    return values


def read_asf(path: str | Path) -> Skeleton:
    """Read an ASF file into a :class:`Skeleton` (metres, radians).

    Channels: the root's ``order`` (e.g. root.tx … root.rz), then each bone's ``dof`` in
    the order of ``:bonedata``, as an AMC file lists them.
    """
    lines = _Lines(Path(path), "ASF")
    length_unit: float | None = None
    angle_scale = np.pi / 180.0
    root_order: list[str] = []
    root_axis = "XYZ"
    root_position = np.zeros(3)
    root_orientation = np.zeros(3)
    bones: dict[str, _Bone] = {}
    children: dict[str, list[str]] = {}
    section = None
    bone: _Bone | None = None
    for n, text in lines.items:
        words = text.split()
        key = words[0]
        if key.startswith(":"):
            section = key[1:].lower()
            continue
        if section == "units":
            if key == "length":
                value = _floats(lines, n, words[1:], 1, "length unit")[0]
                if not 1e-6 <= value <= 1e6:
                    raise lines.fail(n, f"length unit {value:g} must be a positive number of units per inch")
                length_unit = INCH / value
            elif key == "angle":
                if words[1:2] not in (["deg"], ["rad"]):
                    raise lines.fail(n, f"unknown angle unit {' '.join(words[1:])!r} (deg or rad)")
                angle_scale = np.pi / 180.0 if words[1] == "deg" else 1.0
        elif section == "root":
            if key == "order":
                root_order = [w.lower() for w in words[1:]]
                bad = [w for w in root_order if w not in ("tx", "ty", "tz", "rx", "ry", "rz")]
                if bad:
                    raise lines.fail(n, f"root order has unknown channels {bad}")
            elif key == "axis":
                root_axis = words[1] if len(words) > 1 else root_axis
            elif key == "position":
                root_position = _floats(lines, n, words[1:], 3, "root position")
            elif key == "orientation":
                root_orientation = _floats(lines, n, words[1:], 3, "root orientation")
        elif section == "bonedata":
            if key == "begin":
                bone = _Bone(name="", line=n)
            elif key == "end":
                if bone is None or not bone.name:
                    raise lines.fail(n, "bone block without a name")
                for attr in ("direction", "length", "axis"):
                    if getattr(bone, attr) is None:
                        raise lines.fail(n, f"bone {bone.name!r} has no {attr}")
                bones[bone.name] = bone
                bone = None
            elif bone is None:
                raise lines.fail(n, f"{key!r} outside a begin/end bone block")
            elif key == "name":
                if len(words) < 2:
                    raise lines.fail(n, "bone name is missing")
                bone.name = words[1]
            elif key == "direction":
                bone.direction = _floats(lines, n, words[1:], 3, "direction")
            elif key == "length":
                bone.length = float(_floats(lines, n, words[1:], 1, "length")[0])
            elif key == "axis":
                bone.axis = _floats(lines, n, words[1:], 3, "axis")
                bone.order = words[4] if len(words) > 4 else "XYZ"
            elif key == "dof":
                bone.dofs = [w.lower() for w in words[1:]]
                bad = [d for d in bone.dofs if d not in ("rx", "ry", "rz")]
                if bad:
                    raise lines.fail(n, f"bone {bone.name!r}: unsupported dof {bad} (rx, ry, rz only)")
        elif section == "hierarchy":
            if key in ("begin", "end"):
                continue
            for name in words:
                if name != "root" and name not in bones:
                    raise lines.fail(n, f"hierarchy names unknown bone {name!r}")
            if key in children:
                children[key].extend(words[1:])
            else:
                children[key] = list(words[1:])
    if bone is not None:
        raise lines.fail(bone.line, f"bone block for {bone.name!r} is not closed (file truncated?)")
    if length_unit is None:
        raise PriortrackError(f"{lines.path}: no ':units length' line")
    if not root_order:
        raise PriortrackError(f"{lines.path}: no ':root order' line")
    if not children.get("root"):
        raise PriortrackError(f"{lines.path}: no ':hierarchy' section with the root's children")
    return _build(Path(path).stem, bones, children, root_order, root_axis, root_position,
                  root_orientation, length_unit, angle_scale, lines)


def _build(name, bones, children, root_order, root_axis, root_position, root_orientation,
           length_unit, angle_scale, lines) -> Skeleton:
    channel_names = [f"root.{c}" for c in root_order]
    for bone in bones.values():
        channel_names += [f"{bone.name}.{d}" for d in bone.dofs]
    channel_index = {c: i for i, c in enumerate(channel_names)}

    names, parents, offsets, axes, rot_ch, trans_ch = [], [], [], [], [], []

    def add(joint, parent, offset, axis_matrix, order, dofs, translations=()):
        names.append(joint)
        parents.append(parent)
        offsets.append(offset)
        slot_axes = np.zeros((SLOTS, 3))
        slot_ch = -np.ones(SLOTS, dtype=int)
        # order "XYZ": M = Rz·Ry·Rx, leftmost factor first in the slots.
        rotations = [f"r{a.lower()}" for a in reversed(order) if f"r{a.lower()}" in dofs]
        for k, dof in enumerate(rotations):
            slot_axes[k] = axis_matrix[:, _AXES[dof[1]]]
            slot_ch[k] = channel_index[f"{joint}.{dof}"]
        axes.append(slot_axes)
        rot_ch.append(slot_ch)
        t = -np.ones(3, dtype=int)
        for dof in translations:
            t[_AXES[dof[1]]] = channel_index[f"{joint}.{dof}"]
        trans_ch.append(t)
        return len(names) - 1

    root_axis_matrix = euler_matrix(root_orientation * angle_scale, root_axis)
    add("root", -1, root_position * length_unit, root_axis_matrix, root_axis, root_order,
        [d for d in root_order if d.startswith("t")])

    visited = set()

    def visit(bone_name: str, parent: int, offset: np.ndarray) -> None:
        if bone_name in visited:
            raise lines.fail(bones[bone_name].line, f"bone {bone_name!r} appears twice in the hierarchy")
        visited.add(bone_name)
        bone = bones[bone_name]
        length = bone.length * length_unit
        if not 0 <= length <= MAX_BONE_M:
            raise lines.fail(bone.line, f"bone {bone_name!r} is {length:.3g} m long; a body's bones are 0 to "
                                        f"{MAX_BONE_M:g} m")
        if length > 0 and not np.linalg.norm(bone.direction) > 1e-9:
            raise lines.fail(bone.line, f"bone {bone_name!r} has a length but no direction (0 0 0)")
        C = euler_matrix(bone.axis * angle_scale, bone.order)
        j = add(bone_name, parent, offset, C, bone.order, bone.dofs)
        # As CMU's own joint positions: the file's direction as written, not renormalised.
        vector = bone.length * length_unit * bone.direction
        kids = children.get(bone_name, [])
        for child in kids:
            visit(child, j, vector)
        if not kids:
            add(f"{bone_name}_end", j, vector, np.eye(3), "XYZ", [])

    for child in children["root"]:
        visit(child, 0, np.zeros(3))
    unreached = [b for b in bones if b not in visited]
    if unreached:
        raise lines.fail(bones[unreached[0]].line, f"bones not in the hierarchy: {unreached}")
    skeleton = Skeleton(
        name=name,
        names=tuple(names),
        parents=np.array(parents),
        offsets=np.array(offsets, dtype=float),
        rot_axes=np.array(axes),
        rot_channels=np.array(rot_ch),
        trans_channels=np.array(trans_ch),
        channel_names=tuple(channel_names),
        source="asf",
        length_unit=length_unit,
        angle_unit=angle_scale,
    )
    check_body(skeleton, str(lines.path))
    return skeleton

"""Biovision BVH reader and writer.

A BVH file is a HIERARCHY of joints (``ROOT``/``JOINT`` blocks with an ``OFFSET`` from
the parent and a list of ``CHANNELS``; ``End Site`` blocks with only an ``OFFSET``) and a
MOTION section with one row of channel values per frame. In :mod:`priortrack.data.skeleton`
terms (column vectors, G_root's parent = I)

    p_j = p_parent + G_parent · (o_j + T_j),    G_j = G_parent · L_j,
    L_j = R_{c_1}(θ_1) · R_{c_2}(θ_2) · R_{c_3}(θ_3),

where o_j is the OFFSET, T_j = (Xposition, Yposition, Zposition) (zero where absent) and
c_k is the coordinate axis of the k-th rotation channel *in the order the file lists them*:
"Zrotation Xrotation Yrotation" gives L = Rz·Rx·Ry. Lengths are converted with
``length_unit`` (metres per BVH unit), angles are degrees. **The root's position channels are
absolute** (Blender's convention, which the converters that write CMU BVH follow): along an axis
the root has a position channel for, its OFFSET is not added (o_root = 0 there; it only places the
rest pose).

Reading keeps the file's joints (parents first, depth-first in file order), joins a
ROOT/JOINT name of several words with "_" (as Blender does), names each ``End Site``
``<parent>_end`` and keeps every channel in the file's column order, named
``<joint>.tx|ty|tz|rx|ry|rz``. Keywords and channel names are matched case-insensitively;
``{`` and ``}`` may share a line with other statements.

Writing normalises the channel layout so that any :class:`~priortrack.data.motion.Motion`
(ASF- or BVH-derived) becomes a file Blender and MotionBuilder import:

* the root gets ``Xposition Yposition Zposition Zrotation Xrotation Yrotation``;
* every other joint with rotation channels gets ``Zrotation Xrotation Yrotation``, with
  the angles of the ZXY decomposition of its local rotation L_j (see :func:`zxy_angles`),
  which also covers ASF joints that rotate about non-coordinate axes;
* a joint with translation channels (the root always) is written with ``OFFSET 0 0 0``
  and position channels o_j + T_j, so that the file means the same whether an importer
  adds the position channels to OFFSET or replaces OFFSET with them (importers differ);
  a non-root joint with translation channels gets ``Xposition Yposition Zposition`` before
  its rotation channels;
* a joint without channels gets ``CHANNELS 0``;
* a childless joint named ``<parent>_end`` without channels becomes an ``End Site`` (so it
  reads back under the same name); any other childless joint keeps its ``JOINT`` block
  and gets an ``End Site`` with ``OFFSET 0 0 0`` (importers expect every branch to end
  in one), which reads back as an extra joint ``<joint>_end`` at the joint's own position.

Numbers are written as the shortest decimal that reads back to the same float64 (no
exponent notation), so a write → read round trip reproduces positions to rounding error.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from priortrack.data.skeleton import SLOTS, Skeleton, check_body, check_root
from priortrack.data.asf import _Lines
from priortrack.data.motion import Motion
from priortrack.errors import PriortrackError

#: BVH channel keyword (lower case) → (priortrack channel suffix, coordinate axis).
_CHANNELS = {
    "xposition": ("tx", 0), "yposition": ("ty", 1), "zposition": ("tz", 2),
    "xrotation": ("rx", 0), "yrotation": ("ry", 1), "zrotation": ("rz", 2),
}
#: Rotation channel keywords written for every rotating joint: L = Rz·Rx·Ry.
_ZXY = ("Zrotation", "Xrotation", "Yrotation")
_POSITION = ("Xposition", "Yposition", "Zposition")
#: fps is snapped to the nearest integer when 1/frame_time is this close to it (relative).
_FPS_SNAP = 1e-6
#: cos(x) below which the ZXY decomposition treats the rotation as gimbal-locked.
_GIMBAL_COS = 1e-12


@dataclass
class _Joint:
    """A joint while the hierarchy is parsed."""

    name: str
    parent: int
    line: int
    end_site: bool
    offset: np.ndarray | None = None
    channels: list[str] = field(default_factory=list)
    channels_line: int = 0


def zxy_angles(R: np.ndarray) -> np.ndarray:
    """ZXY Euler angles of rotation matrices: R = Rz(z) · Rx(x) · Ry(y).

    With column vectors, R = Rz·Rx·Ry has R[2,1] = sin x, R[0,1] = −sin z cos x,
    R[1,1] = cos z cos x, and (Rz(z)ᵀ·R)[0, :] = (cos y, 0, sin y). So

        x = atan2(R21, √(R01² + R11²))  ∈ [−π/2, π/2],
        z = atan2(−R01, R11),
        y = atan2(cos z·R02 + sin z·R12, cos z·R00 + sin z·R10).

    Near gimbal lock (cos x ≈ 0) only z ± y is defined and z, read from entries of size
    cos x, carries an error δ ~ 1e-16 / cos x; y is read from R with the computed z undone,
    so it absorbs δ and Rz·Rx·Ry recomposes R to ~δ·cos x, i.e. rounding error, however
    close to lock. At lock (cos x < 1e-12) z is set to 0 and y takes the whole z ± y.

    Args:
        R: (..., 3, 3) rotation matrices.

    Returns:
        (..., 3) angles (z, x, y) in radians; z, y ∈ (−π, π].
    """
    R = np.asarray(R, dtype=np.float64)
    cos_x = np.hypot(R[..., 0, 1], R[..., 1, 1])
    x = np.arctan2(R[..., 2, 1], cos_x)
    z = np.where(cos_x < _GIMBAL_COS, 0.0, np.arctan2(-R[..., 0, 1], R[..., 1, 1]))
    cz, sz = np.cos(z), np.sin(z)
    y = np.arctan2(cz * R[..., 0, 2] + sz * R[..., 1, 2], cz * R[..., 0, 0] + sz * R[..., 1, 0])
    return np.stack([z, x, y], axis=-1)


def _statements(lines: _Lines) -> tuple[list[tuple[int, list[str]]], int]:
    """The HIERARCHY part as (line, words) statements, braces split off as their own.

    Returns the statements up to and including ``MOTION`` and the index in
    ``lines.items`` of the first line after ``MOTION`` (len(items) if there is none).
    """
    statements: list[tuple[int, list[str]]] = []
    for i, (n, text) in enumerate(lines.items):
        words: list[str] = []
        for word in text.split():
            if word in ("{", "}"):
                if words:
                    statements.append((n, words))
                    words = []
                statements.append((n, [word]))
            else:
                words.append(word)
        if words:
            statements.append((n, words))
        if statements and statements[-1][1][0].upper() == "MOTION":
            return statements, i + 1
    return statements, len(lines.items)


def _offset(lines: _Lines, n: int, words: list[str]) -> np.ndarray:
    if len(words) != 4:
        raise lines.fail(n, f"OFFSET needs 3 numbers, found {len(words) - 1}: {' '.join(words)}")
    try:
        offset = np.array([float(w) for w in words[1:]])
    except ValueError:
        raise lines.fail(n, f"OFFSET has a value that is not a number: {' '.join(words)}") from None
    if not np.all(np.isfinite(offset)):
        raise lines.fail(n, f"OFFSET has a non-finite value: {' '.join(words)}")
    return offset


def _channel_list(lines: _Lines, n: int, words: list[str], joint: _Joint) -> list[str]:
    try:
        count = int(words[1]) if len(words) > 1 else -1
    except ValueError:
        count = -1
    if count < 0:
        raise lines.fail(n, f"CHANNELS needs a count and channel names: {' '.join(words)}")
    names = words[2:]
    if count != len(names):
        raise lines.fail(n, f"CHANNELS says {count} channels but lists {len(names)}: {' '.join(names)}")
    suffixes = []
    for name in names:
        if name.lower() not in _CHANNELS:
            raise lines.fail(n, f"unknown channel {name!r} (expected one of "
                                f"{', '.join(_POSITION)}, Xrotation, Yrotation, Zrotation)")
        suffixes.append(_CHANNELS[name.lower()][0])
    if len(set(suffixes)) != len(suffixes):
        raise lines.fail(n, f"joint {joint.name!r} lists a channel twice: {' '.join(names)}")
    return suffixes


def _parse_hierarchy(lines: _Lines, statements: list[tuple[int, list[str]]]) -> list[_Joint]:
    """Joints in file (depth-first) order from the HIERARCHY statements."""
    last_line = lines.items[-1][0] if lines.items else 1
    if not statements or statements[0][1] != ["HIERARCHY"]:
        raise lines.fail(statements[0][0] if statements else last_line,
                         "a BVH file starts with HIERARCHY")
    joints: list[_Joint] = []
    by_name: dict[str, _Joint] = {}
    stack: list[int] = []           # open blocks, innermost last
    pending: int | None = None      # joint declared, its '{' not yet seen
    for n, words in statements[1:]:
        key = words[0].upper()
        if pending is not None:
            if words != ["{"]:
                raise lines.fail(n, f"expected '{{' after {_what(joints[pending])} declared at line "
                                    f"{joints[pending].line}, found {' '.join(words)!r}")
            stack.append(pending)
            pending = None
        elif key in ("ROOT", "JOINT") or (key == "END" and len(words) == 2 and words[1].lower() == "site"):
            if key == "ROOT" and joints:
                raise lines.fail(n, "ROOT inside a joint block" if stack
                                 else "a second ROOT (one skeleton per file is supported)")
            if key != "ROOT" and (not stack or joints[stack[-1]].end_site):
                raise lines.fail(n, f"{' '.join(words)!r} outside a ROOT or JOINT block")
            if key == "END":
                name = f"{joints[stack[-1]].name}_end"
            elif len(words) < 2:
                raise lines.fail(n, f"{words[0]} needs a name")
            else:
                name = "_".join(words[1:])
            if name in by_name:
                raise lines.fail(n, f"duplicate joint name {name!r} (first at line {by_name[name].line})")
            joint = _Joint(name, stack[-1] if stack else -1, n, end_site=key == "END")
            by_name[name] = joint
            joints.append(joint)
            pending = len(joints) - 1
        elif key == "OFFSET":
            if not stack:
                raise lines.fail(n, "OFFSET outside a joint block")
            joint = joints[stack[-1]]
            if joint.offset is not None:
                raise lines.fail(n, f"second OFFSET for {_what(joint)}")
            joint.offset = _offset(lines, n, words)
        elif key == "CHANNELS":
            if not stack or joints[stack[-1]].end_site:
                raise lines.fail(n, "CHANNELS outside a ROOT or JOINT block")
            joint = joints[stack[-1]]
            if joint.channels_line:
                raise lines.fail(n, f"second CHANNELS for {_what(joint)} (first at line {joint.channels_line})")
            joint.channels = _channel_list(lines, n, words, joint)
            joint.channels_line = n
        elif words == ["}"]:
            if not stack:
                raise lines.fail(n, "unbalanced braces: '}' without a matching '{'")
            joint = joints[stack.pop()]
            if joint.offset is None:
                raise lines.fail(n, f"{_what(joint)} (line {joint.line}) has no OFFSET")
        elif key == "MOTION":
            if len(words) > 1:
                raise lines.fail(n, f"unexpected text after MOTION: {' '.join(words[1:])!r}")
            if pending is not None or stack:
                open_joint = joints[pending if pending is not None else stack[-1]]
                raise lines.fail(n, f"unbalanced braces: block of {_what(open_joint)} (line "
                                    f"{open_joint.line}) is not closed before MOTION")
            if not joints:
                raise lines.fail(n, "HIERARCHY has no ROOT")
            return joints
        elif words == ["{"]:
            raise lines.fail(n, "unbalanced braces: '{' without a ROOT, JOINT or End Site before it")
        else:
            raise lines.fail(n, f"unknown keyword {words[0]!r} in HIERARCHY")
    if pending is not None or stack:
        open_joint = joints[pending if pending is not None else stack[-1]]
        raise lines.fail(last_line, f"file ends inside the block of {_what(open_joint)} (line "
                                    f"{open_joint.line}): unbalanced braces or a truncated file")
    raise lines.fail(last_line, "no MOTION section (file truncated?)")


def _what(joint: _Joint) -> str:
    return f"End Site {joint.name!r}" if joint.end_site else f"joint {joint.name!r}"


def _skeleton(name: str, joints: list[_Joint], length_unit: float) -> Skeleton:
    channel_names: list[str] = []
    rot_axes = np.zeros((len(joints), SLOTS, 3))
    rot_channels = -np.ones((len(joints), SLOTS), dtype=int)
    trans_channels = -np.ones((len(joints), 3), dtype=int)
    for j, joint in enumerate(joints):
        slot = 0
        for suffix in joint.channels:
            axis = "xyz".index(suffix[1])
            if suffix[0] == "t":
                trans_channels[j, axis] = len(channel_names)
            else:
                rot_axes[j, slot, axis] = 1.0
                rot_channels[j, slot] = len(channel_names)
                slot += 1
            channel_names.append(f"{joint.name}.{suffix}")
    offsets = np.array([joint.offset for joint in joints]) * length_unit
    offsets[0, trans_channels[0] >= 0] = 0.0                 # absolute root positions (module docstring)
    return Skeleton(
        name=name,
        names=tuple(joint.name for joint in joints),
        parents=np.array([joint.parent for joint in joints]),
        offsets=offsets,
        rot_axes=rot_axes,
        rot_channels=rot_channels,
        trans_channels=trans_channels,
        channel_names=tuple(channel_names),
        source="bvh",
        length_unit=length_unit,
        angle_unit=np.pi / 180.0,
    )


def _header_value(lines: _Lines, items: list[tuple[int, str]], i: int, label: str,
                  after: int) -> tuple[int, str]:
    """Line number and value text of the MOTION header line ``label`` (e.g. "Frames:"),
    expected at ``items[i]``; ``after`` is the line to blame if the file ends first."""
    if i >= len(items):
        raise lines.fail(after, f"file ends before the {label!r} line (truncated?)")
    n, text = items[i]
    if not text.lower().startswith(label.lower()):
        raise lines.fail(n, f"expected {label!r}, found {text!r}")
    value = text[len(label):].strip()
    if not value:
        raise lines.fail(n, f"{label!r} has no value")
    return n, value


def _parse_motion(lines: _Lines, start: int, num_channels: int,
                  motion_line: int) -> tuple[np.ndarray, float]:
    """(T, C) channel values in file units and the frame time (s) of the MOTION section,
    whose header starts at ``lines.items[start]``."""
    items = lines.items
    n, value = _header_value(lines, items, start, "Frames:", motion_line)
    try:
        frames = int(value)
    except ValueError:
        raise lines.fail(n, f"Frames: {value!r} is not a whole number") from None
    if frames < 0:
        raise lines.fail(n, f"Frames: {frames} is negative")
    if frames and not num_channels:             # frames of nothing: sized by the header alone, not the file
        raise lines.fail(n, f"Frames: {frames}, but the hierarchy has no channels to animate")
    frames_line = n
    n, value = _header_value(lines, items, start + 1, "Frame Time:", n)
    try:
        frame_time = float(value)
    except ValueError:
        raise lines.fail(n, f"Frame Time: {value!r} is not a number") from None
    if not (np.isfinite(frame_time) and frame_time > 0):
        raise lines.fail(n, f"Frame Time: {value} must be a positive number of seconds")
    rows = items[start + 2:]
    # A file without channels has empty rows, which are not in ``items``.
    if len(rows) != (frames if num_channels else 0):
        where = rows[-1][0] if rows else n
        raise lines.fail(where, f"Frames: {frames} (line {frames_line}) but {len(rows)} rows of values "
                                f"follow (file truncated, or a wrong frame count)")
    values = np.zeros((frames, num_channels))
    for t, (n, text) in enumerate(rows):
        words = text.split()
        if len(words) != num_channels:
            raise lines.fail(n, f"frame {t} has {len(words)} values, the hierarchy has {num_channels} channels")
        try:
            values[t] = [float(w) for w in words]
        except ValueError:
            raise lines.fail(n, f"frame {t} has a value that is not a number") from None
        if not np.all(np.isfinite(values[t])):
            raise lines.fail(n, f"frame {t} has a non-finite value")
    return values, frame_time


def _check_length_unit(length_unit: float) -> None:
    if not (np.isfinite(length_unit) and length_unit > 0):
        raise PriortrackError(f"length_unit must be a positive number of metres per BVH unit, got {length_unit}")


def read_bvh(path: str | Path, length_unit: float = 0.01) -> Motion:
    """Read a BVH file into a :class:`Motion` (metres, radians).

    Args:
        path: the .bvh file.
        length_unit: metres per BVH length unit (0.01: the file is in centimetres).

    Returns:
        A Motion with channels (T, C) in the file's column order (translations × length_unit,
        degrees → radians), a skeleton with ``source="bvh"``, fps = 1 / Frame Time (snapped
        to the nearest integer when within 1e-6 relative of it), name = the file stem and
        subject "".

    Raises:
        PriortrackError: "path:line: ..." for malformed input (braces, keywords, channels,
            OFFSET, duplicate joints, missing or truncated MOTION, bad rows or frame time).
    """
    _check_length_unit(length_unit)
    path = Path(path)
    lines = _Lines(path, "BVH")
    statements, motion_start = _statements(lines)
    joints = _parse_hierarchy(lines, statements)
    skeleton = _skeleton(path.stem, joints, length_unit)
    check_body(skeleton, str(path))
    values, frame_time = _parse_motion(lines, motion_start, skeleton.num_channels, statements[-1][0])
    fps = 1.0 / frame_time
    if abs(fps - round(fps)) <= _FPS_SNAP * fps:
        fps = float(round(fps))
    channels = values * skeleton.channel_scale()
    check_root(skeleton, channels, str(path))
    return Motion(skeleton, channels, fps, path.stem, "")


def _number(value: float) -> str:
    """Shortest decimal that reads back to the same float64, without an exponent."""
    text = repr(value)
    return np.format_float_positional(value, unique=True, trim="-") if "e" in text else text


def _check_name(skeleton: Skeleton, name: str) -> None:
    if not name or name in ("{", "}") or any(c.isspace() for c in name):
        raise PriortrackError(f"skeleton {skeleton.name!r}: joint name {name!r} cannot be written to BVH "
                              f"(it must be one word)")


def write_bvh(motion: Motion, path: str | Path, length_unit: float = 0.01) -> None:
    """Write a Motion as a BVH file with a normalised channel layout (see the module doc).

    The local rotations L_j of every frame, (T, J, 3, 3), come from
    :meth:`Skeleton.local_rotations` in float64 and are written as the ZXY angles
    of :func:`zxy_angles` in degrees; a joint with translation channels is written with
    OFFSET 0 and positions (o_j + T_j) / length_unit, others with OFFSET o_j / length_unit.
    Reading the file back gives the same joint positions. Frame Time = 1 / fps.

    Args:
        motion: the motion, channels (T, C) in metres and radians.
        path: the .bvh file to write.
        length_unit: metres per BVH length unit (0.01: centimetres).
    """
    _check_length_unit(length_unit)
    skeleton = motion.skeleton
    channels = np.asarray(motion.channels, dtype=np.float64)
    if not np.all(np.isfinite(channels)):
        raise PriortrackError(f"motion {motion.name!r} has non-finite channel values; BVH cannot store them")
    for name in skeleton.names:
        _check_name(skeleton, name)
    T, J = len(channels), skeleton.num_joints
    L = skeleton.local_rotations(channels)
    degrees = np.degrees(zxy_angles(L))                                        # (T, J, 3) z, x, y
    # Index -1 (no translation channel) picks the appended zero column.
    translation = np.concatenate([channels, np.zeros((T, 1))], axis=1)[:, skeleton.trans_channels]  # (T, J, 3)
    positions = (skeleton.offsets + translation) / length_unit                 # (T, J, 3)

    has_translation = np.any(skeleton.trans_channels >= 0, axis=1)
    has_translation[0] = True
    rotates = np.any(skeleton.rot_channels >= 0, axis=1)
    rotates[0] = True
    children = [skeleton.children(j) for j in range(J)]
    header = ["HIERARCHY"]
    columns: list[np.ndarray] = []                                             # each (T, k)

    def end_site(offset: np.ndarray, indent: str) -> None:
        header.extend([f"{indent}End Site", f"{indent}{{",
                       f"{indent}\tOFFSET {' '.join(_number(v) for v in offset.tolist())}", f"{indent}}}"])

    def joint_block(j: int, indent: str) -> None:
        name = skeleton.names[j]
        header.append(f"{indent}{'ROOT' if j == 0 else 'JOINT'} {name}")
        header.append(f"{indent}{{")
        offset = np.zeros(3) if has_translation[j] else skeleton.offsets[j] / length_unit
        header.append(f"{indent}\tOFFSET {' '.join(_number(v) for v in offset.tolist())}")
        keywords = (_POSITION if has_translation[j] else ()) + (_ZXY if rotates[j] else ())
        header.append(f"{indent}\tCHANNELS {len(keywords)}{''.join(' ' + k for k in keywords)}")
        if has_translation[j]:
            columns.append(positions[:, j])
        if rotates[j]:
            columns.append(degrees[:, j])
        for c in children[j]:
            if _is_end_site(skeleton, c, children[c]):
                end_site(skeleton.offsets[c] / length_unit, indent + "\t")
            else:
                joint_block(c, indent + "\t")
        if not children[j]:
            end_site(np.zeros(3), indent + "\t")
        header.append(f"{indent}}}")

    joint_block(0, "")
    values = np.concatenate(columns, axis=1)                                   # root: ≥ 6 columns
    rows = [" ".join(_number(v) for v in row) for row in values.tolist()]
    text = "\n".join(header + ["MOTION", f"Frames: {T}", f"Frame Time: {_number(1.0 / motion.fps)}"] + rows)
    try:
        Path(path).write_text(text + "\n", encoding="utf-8")
    except OSError as exc:
        raise PriortrackError(f"cannot write BVH file {path}: {exc.strerror}") from None


def _is_end_site(skeleton: Skeleton, j: int, children: list[int]) -> bool:
    """Whether joint j is written as an End Site: a childless ``<parent>_end`` without channels."""
    return (not children
            and skeleton.names[j] == f"{skeleton.names[skeleton.parents[j]]}_end"
            and not np.any(skeleton.rot_channels[j] >= 0)
            and not np.any(skeleton.trans_channels[j] >= 0))

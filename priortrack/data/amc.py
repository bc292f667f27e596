"""Acclaim AMC motion reader: per frame, one line per bone with its dof values.

A file whose frames all list the same bones in the same order (as CMU's and every exporter's do) is read
a bone at a time: its lines of every frame joined and converted by numpy at once (18 CMU walks: 0.4 →
0.1 s). Anything else, or anything the fast read finds wrong, is read line by line, which says which
line is wrong and why.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from priortrack.data.skeleton import Skeleton, check_root
from priortrack.data.asf import _Lines


def read_amc(path: str | Path, skeleton: Skeleton) -> np.ndarray:
    """Read an AMC file against its ASF skeleton.

    Returns:
        (T, C) channels in ``skeleton.channel_names`` order, translations in metres and
        rotations in radians. Frames CMU left at all-zero angles are kept as they are.
    """
    lines = _Lines(Path(path), "AMC")
    by_bone: dict[str, list[int]] = {}
    for c, name in enumerate(skeleton.channel_names):
        by_bone.setdefault(name.split(".", 1)[0], []).append(c)
    channels = _regular_frames(lines, by_bone, skeleton.num_channels)
    if channels is None:
        channels = _line_by_line(lines, by_bone, skeleton)
    channels = channels * skeleton.channel_scale()
    check_root(skeleton, channels, str(path))
    return channels


def _regular_frames(lines: _Lines, by_bone: dict[str, list[int]], C: int) -> np.ndarray | None:
    """(T, C) unscaled channels of a file whose frames 1, 2, … each list every bone of ``by_bone`` once, in
    the first frame's order, with its dofs' finite values; else None."""
    items = [text for _, text in lines.items if not text.startswith(":")]
    if not items or not (items[0].isascii() and items[0].isdigit()):
        return None
    L = next((k for k, text in enumerate(items[1:], 1) if text.isascii() and text.isdigit()), len(items)) - 1
    T, rest = divmod(len(items), L + 1)
    order = [text.split(None, 1)[0] for text in items[1:L + 1]]
    if rest or sorted(order) != sorted(by_bone) or items[::L + 1] != [str(t) for t in range(1, T + 1)]:
        return None
    out = np.zeros((T, C))
    for j, bone in enumerate(order):
        column = items[j + 1::L + 1]
        words = " ".join(column).split()
        dofs = len(by_bone[bone])
        if len(words) != T * (dofs + 1) or words[::dofs + 1] != [bone] * T:
            return None
        del words[::dofs + 1]
        try:
            values = np.fromiter(map(float, words), dtype=np.float64, count=len(words))
        except ValueError:
            return None
        if not np.isfinite(values).all():
            return None
        out[:, by_bone[bone]] = values.reshape(T, dofs)
    return out


def _line_by_line(lines: _Lines, by_bone: dict[str, list[int]], skeleton: Skeleton) -> np.ndarray:
    """(T, C) unscaled channels, read and checked line by line: a wrong line raises, naming it."""
    # a bone's channels as a slice where they are consecutive (they are in ASF order): faster to fill
    by_bone = {b: slice(c[0], c[-1] + 1) if c == list(range(c[0], c[-1] + 1)) else c for b, c in by_bone.items()}
    frames: list[np.ndarray] = []
    current: np.ndarray | None = None
    seen: set[str] = set()
    start_line = 0

    def close(line: int) -> None:
        missing = [b for b in by_bone if b not in seen]
        if missing:
            raise lines.fail(line, f"frame {len(frames)} (starting line {start_line}) has no line for "
                                   f"{missing} (file truncated, or a skeleton that does not match)")
        frames.append(current)

    for n, text in lines.items:
        if text.startswith(":"):
            continue
        words = text.split()
        if len(words) == 1 and words[0].isascii() and words[0].isdigit():
            if current is not None:
                close(n)
            number = int(words[0])
            if number != len(frames) + 1:
                raise lines.fail(n, f"frame number {number}, expected {len(frames) + 1}")
            current = np.zeros(skeleton.num_channels)
            seen = set()
            start_line = n
            continue
        if current is None:
            raise lines.fail(n, f"bone line {words[0]!r} before the first frame number")
        bone = words[0]
        if bone not in by_bone:
            raise lines.fail(n, f"bone {bone!r} is not in skeleton {skeleton.name!r} "
                                f"(an AMC for another skeleton?)")
        channels = by_bone[bone]
        dofs = channels.stop - channels.start if isinstance(channels, slice) else len(channels)
        if len(words) - 1 != dofs:
            raise lines.fail(n, f"bone {bone!r} has {len(words) - 1} values, skeleton "
                                f"{skeleton.name!r} gives it {dofs} dofs")
        try:
            values = [float(w) for w in words[1:]]
        except ValueError:
            raise lines.fail(n, f"bone {bone!r} has a value that is not a number") from None
        if not all(map(math.isfinite, values)):          # (math, not numpy: a call per line of ~10⁵)
            raise lines.fail(n, f"bone {bone!r} has a non-finite value")
        current[channels] = values
        seen.add(bone)
    if current is None:
        raise lines.fail(lines.items[-1][0] if lines.items else 1, "no frames")
    close(lines.items[-1][0])
    return np.stack(frames)

"""Acclaim AMC motion reader: per frame, one line per bone with its dof values."""

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
    channels = np.stack(frames) * skeleton.channel_scale()
    check_root(skeleton, channels, str(path))
    return channels

"""The manual 3D truth of the Shelf and Campus benchmarks, as 4D Association (Zhang et al., CVPR 2020) ships it.

``gt.txt`` is whitespace-separated text: a header ``J T`` (joints, frames; J = 15), then for each of the T
frames a line with its number of people, and per person a line with their id and four lines of J numbers:
the joints' x, y and z (metres, the calibration's world) and whether each is valid (0 or 1). The joints are
:data:`SHELF15_NAMES`. The users download the benchmark; priortrack reads it where they keep it.

:func:`read_shelf_truth` gives a :class:`ShelfTruth`; :meth:`ShelfTruth.eval15` puts the joints in the
evaluation layout (``priortrack.data.eval15``): the twelve limb joints and the pelvis (Shelf's pelvis is the
hips' midpoint, the detectors' pelvis too); the neck and head are NaN (``head_bottom`` and ``head_top`` are
no detector's keypoints).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from priortrack.data.eval15 import EVAL15_NAMES
from priortrack.errors import PriortrackError

SHELF15_NAMES = ("r_ankle", "r_knee", "r_hip", "l_hip", "l_knee", "l_ankle", "r_wrist", "r_elbow", "r_shoulder",
                 "l_shoulder", "l_elbow", "l_wrist", "head_bottom", "head_top", "pelvis")
#: The Shelf joint of each eval15 joint (None: none).
_OF_EVAL15 = {"pelvis": "pelvis", "neck": None, "head": None,
              **{f"{s}{part}": f"{s}_{part}" for s in "lr" for part in ("shoulder", "elbow", "wrist", "hip", "knee",
                                                                       "ankle")}}
#: The most frames and people a truth file may hold (a guard against absurd headers).
MAX_FRAMES, MAX_PEOPLE = 10 ** 6, 64


@dataclass(frozen=True)
class ShelfTruth:
    """A benchmark's 3D truth.

    Attributes:
        ids: (A,) the actors' ids, ascending.
        joints: (T, A, 15, 3) each actor's :data:`SHELF15_NAMES` joints per frame, metres, NaN where the actor
            is not annotated at that frame or the joint is not valid.
        source: the file read.
    """

    ids: np.ndarray
    joints: np.ndarray
    source: str

    def eval15(self) -> np.ndarray:
        """(T, A, 15, 3) the joints in the eval15 layout (module docstring), NaN for the neck and head."""
        out = np.full(self.joints.shape[:2] + (15, 3), np.nan)
        for j, name in enumerate(EVAL15_NAMES):
            if _OF_EVAL15[name] is not None:
                out[:, :, j] = self.joints[:, :, SHELF15_NAMES.index(_OF_EVAL15[name])]
        return out


def read_shelf_truth(path: str | Path) -> ShelfTruth:
    """Read a ``gt.txt`` (module docstring); a malformed file is refused naming its line."""
    path = Path(path)
    if not path.is_file():
        raise PriortrackError(f"truth file {path} does not exist")
    try:
        lines = [line.split() for line in path.read_text().splitlines()]
    except (UnicodeDecodeError, OSError) as exc:
        raise PriortrackError(f"{path}: not a text file ({exc})") from None
    reader = _Lines(path, lines)
    J, T = reader.integers(2, "the header: joints and frames")
    if J != len(SHELF15_NAMES):
        raise PriortrackError(f"{path}, line {reader.number}: {J} joints; Shelf and Campus truth has "
                              f"{len(SHELF15_NAMES)} ({', '.join(SHELF15_NAMES)})")
    if not 1 <= T <= MAX_FRAMES:
        raise PriortrackError(f"{path}, line {reader.number}: {T} frames (1 to {MAX_FRAMES})")
    frames: list[dict[int, np.ndarray]] = []
    for t in range(T):
        (count,) = reader.integers(1, f"frame {t}'s number of people")
        if not 0 <= count <= MAX_PEOPLE:
            raise PriortrackError(f"{path}, line {reader.number}: frame {t} has {count} people (0 to {MAX_PEOPLE})")
        people: dict[int, np.ndarray] = {}
        for _ in range(count):
            (actor,) = reader.integers(1, f"a person's id in frame {t}")
            if actor < 0 or actor in people:
                raise PriortrackError(f"{path}, line {reader.number}: person id {actor} in frame {t} is "
                                      f"{'negative' if actor < 0 else 'given twice'}")
            rows = np.stack([reader.numbers(J, f"row {r} of person {actor} in frame {t}") for r in "xyzv"])
            valid = rows[3]
            if not np.isin(valid, (0, 1)).all():
                raise PriortrackError(f"{path}, line {reader.number}: person {actor}'s validity row in frame {t} "
                                      f"holds {valid[~np.isin(valid, (0, 1))][0]:g}; expected 0 or 1")
            people[actor] = np.where(valid[:, None] == 1, rows[:3].T, np.nan)
        frames.append(people)
    if reader.remaining():
        raise PriortrackError(f"{path}, line {reader.number + 1}: more lines after the header's {T} frames")
    ids = np.array(sorted({a for people in frames for a in people}), dtype=int)
    joints = np.full((T, len(ids), J, 3), np.nan)
    for t, people in enumerate(frames):
        for actor, X in people.items():
            joints[t, int(np.searchsorted(ids, actor))] = X
    return ShelfTruth(ids, joints, str(path))


class _Lines:
    """The file's non-empty lines read in turn, each refused by its number where it is not what is expected."""

    def __init__(self, path: Path, lines: list[list[str]]):
        self.path, self.lines, self.number = path, lines, 0

    def _next(self, what: str) -> list[str]:
        while self.number < len(self.lines):
            self.number += 1
            if self.lines[self.number - 1]:
                return self.lines[self.number - 1]
        raise PriortrackError(f"{self.path}: the file ends where {what} is expected")

    def numbers(self, n: int, what: str) -> np.ndarray:
        words = self._next(what)
        try:
            values = np.array([float(w) for w in words])
        except ValueError:
            values = None
        if values is None or len(values) != n or not np.isfinite(values).all():
            raise PriortrackError(f"{self.path}, line {self.number}: {what}: expected {n} finite numbers, got "
                                  f"{' '.join(words)[:80]!r}")
        return values

    def integers(self, n: int, what: str) -> list[int]:
        values = self.numbers(n, what)
        if not (values == np.round(values)).all():
            raise PriortrackError(f"{self.path}, line {self.number}: {what}: expected whole numbers")
        return [int(v) for v in values]

    def remaining(self) -> bool:
        return any(self.lines[self.number:])

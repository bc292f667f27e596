"""A motion: a skeleton, its channels over time, a frame rate and where it came from."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from priortrack.data.skeleton import Skeleton, check_channels
from priortrack.errors import PriortrackError

#: A channel whose spread over a set of motions is below this (radians) never moves in them: CMU's finger and thumb
#: bones carry no data, and CMU 35's clavicles (the template's and the walking priors') never turn.
CONSTANT_CHANNEL_STD = 1e-6


@dataclass(frozen=True, eq=False)
class Motion:
    """A motion clip.

    Attributes:
        skeleton: the body the channels drive.
        channels: (T, C) pose vectors in ``skeleton.channel_names`` order: root translation
            in metres, joint angles in radians.
        fps: frames per second.
        name: clip name (``"07_01"``).
        subject: subject id (``"07"``), "" when unknown.
    """

    skeleton: Skeleton
    channels: np.ndarray
    fps: float
    name: str
    subject: str = ""

    def __post_init__(self) -> None:
        if self.channels.ndim != 2:
            raise PriortrackError(f"motion {self.name!r}: channels has shape {self.channels.shape}; "
                                  f"expected (T, {self.skeleton.num_channels})")
        check_channels(self.channels, self.skeleton, f"motion {self.name!r} channels")
        if not 0 < self.fps < math.inf:
            raise PriortrackError(f"motion {self.name!r}: fps must be positive and finite, got {self.fps}")

    def __len__(self) -> int:
        return len(self.channels)

    def __getitem__(self, frames: slice) -> Motion:
        """Frames ``frames`` (a slice, step allowed: the fps follows the step)."""
        if not isinstance(frames, slice):
            raise PriortrackError(f"motion {self.name!r}: index with a slice of frames, got {frames!r}")
        step = frames.step or 1
        if step < 1:
            raise PriortrackError(f"motion {self.name!r}: slice step must be a positive integer, got {step}")
        return replace(self, channels=self.channels[frames], fps=self.fps / step)

    @property
    def duration(self) -> float:
        """Seconds from the first frame to the last."""
        return (len(self) - 1) / self.fps

    def resample(self, fps: float) -> Motion:
        """The motion at another frame rate, over the same time span.

        Frame k is at time k / fps. Channels are interpolated linearly between the two
        nearest source frames, each rotation along the shorter way round (angle
        differences wrapped to (−π, π]); a target instant that falls on a source frame
        takes that frame exactly, so 120 → 30 fps is every 4th frame.
        """
        if not 0 < fps < math.inf:
            raise PriortrackError(f"resample: fps must be positive and finite, got {fps}")
        count = int(np.floor(self.duration * fps + 1e-9)) + 1
        source = np.arange(count) * (self.fps / fps)
        lower = np.minimum(np.floor(source).astype(int), len(self) - 1)
        upper = np.minimum(lower + 1, len(self) - 1)
        weight = (source - lower)[:, None]
        a, b = self.channels[lower], self.channels[upper]
        step = b - a
        rotation = np.ones(self.skeleton.num_channels, dtype=bool)
        rotation[self.skeleton.trans_channels[self.skeleton.trans_channels >= 0]] = False
        step[:, rotation] = np.mod(step[:, rotation] + np.pi, 2 * np.pi) - np.pi
        return replace(self, channels=a + weight * step, fps=float(fps))

    def played_at(self, pace: float) -> Motion:
        """The motion played at ``pace`` × its speed, at its own frame rate (time-warped: sampled at
        fps / pace, then played at fps; pace 0.5 has twice the frames). Named ``<name>@<pace>``."""
        if isinstance(pace, bool) or not isinstance(pace, (int, float)) or not 0.2 <= pace <= 5:
            raise PriortrackError(f"pace must be a speed in [0.2, 5], got {pace!r}")
        return replace(self.resample(self.fps / pace), fps=self.fps, name=f"{self.name}@{pace:g}")

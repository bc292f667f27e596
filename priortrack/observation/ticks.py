"""A real run's observations tick by tick, built a block of ticks at a time from the detections.

Tick t of a run on detections consumes one detection frame, ``index[t]`` (−1: none;
:func:`~priortrack.tracking.person.schedule`), and observes z_t (C, 15, 3): each camera's eval15 pixels
and confidence of that frame (:meth:`~priortrack.data.detections.Detections.eval15`), NaN where the tick
has no frame, and NaN for the camera-ticks ``left_out`` (a camera following someone else there: the
cross-view check). :class:`TickObservations` is that (T, C, 15, 3) array without holding it: it reads
``BLOCK_TICKS`` ticks' frames at a time, from detections in memory or from a file
(:class:`~priortrack.data.detections.DetectionFile`), so that a long recording's run holds one block of
its observations, not all of them (issue 29: a ten-minute, 4-camera recording's would be 26 MB as
float64, its BODY_25 keypoints 43 MB as float32).
"""

from __future__ import annotations

import operator

import numpy as np

from priortrack.geometry.facing import image_forward

#: Ticks read at a time (a block of 4 cameras' observations: 1.4 MB as float64).
BLOCK_TICKS = 1000


class TickObservations:
    """z (T, C, 15, 3) float64 of a run on ``detections`` (module docstring), read a block at a time.

    Indexing: ``z[t]`` (C, 15, 3) (the block holding t is read once and kept until a tick outside it is
    asked), ``z[a:b]`` an array (b − a, C, 15, 3), ``z[t, c]`` and the like index ``z[t]``; iterating gives
    z_t in order; :meth:`blocks` gives (first tick, block) pairs.

    Args:
        detections: :class:`~priortrack.data.detections.Detections` or a
            :class:`~priortrack.data.detections.DetectionFile` (anything with ``camera_names`` and
            ``eval15(min_confidence, start, stop)``).
        index: (T,) the detection frame each tick consumes, −1 for none (increasing where ≥ 0).
        min_confidence: keypoints below it are missing.
        left_out: (T, C) bool, camera-ticks made NaN (None: none).
        block_ticks: ticks read at a time (None: BLOCK_TICKS).
    """

    def __init__(self, detections, index: np.ndarray, min_confidence: float, left_out: np.ndarray | None = None,
                 block_ticks: int | None = None):
        self.detections, self.min_confidence = detections, min_confidence
        self.block_ticks = block_ticks or BLOCK_TICKS
        self.index = np.asarray(index)
        cameras = len(detections.camera_names)
        self.left_out = np.zeros((len(self.index), cameras), dtype=bool) if left_out is None else left_out
        self._held: tuple[int, np.ndarray | None] = (0, None)

    def __len__(self) -> int:
        return len(self.index)

    @property
    def shape(self) -> tuple[int, int, int, int]:
        return (len(self), self.left_out.shape[1], 15, 3)

    def raw(self, start: int, stop: int) -> np.ndarray:
        """(stop − start, C, 15, 3) the ticks [start, stop) as detected, before ``left_out``."""
        index = self.index[start:stop]
        z = np.full((len(index),) + self.shape[1:], np.nan)
        used = index >= 0
        if used.any():
            lo, hi = int(index[used].min()), int(index[used].max()) + 1
            uv, confidence = self.detections.eval15(self.min_confidence, lo, hi)      # (C, hi − lo, 15, ·)
            z[used, :, :, :2] = uv[:, index[used] - lo].transpose(1, 0, 2, 3)
            z[used, :, :, 2] = confidence[:, index[used] - lo].transpose(1, 0, 2)
        return z

    def block(self, start: int, stop: int) -> np.ndarray:
        """(stop − start, C, 15, 3) the ticks [start, stop), the ``left_out`` camera-ticks NaN."""
        z = self.raw(start, stop)
        z[self.left_out[start:stop]] = np.nan
        return z

    def blocks(self, raw: bool = False):
        """(first tick, block) over the whole run, ``block_ticks`` at a time (``raw``: before ``left_out``)."""
        read = self.raw if raw else self.block
        for start in range(0, len(self), self.block_ticks):
            yield start, read(start, min(start + self.block_ticks, len(self)))

    def forward(self) -> np.ndarray:
        """(T, C, 3) each tick's detector's forward direction in each camera's image, from its feet and face
        (:func:`~priortrack.geometry.facing.image_forward`; 0 where the tick has no frame, the layout no such
        keypoints, or the camera-tick is ``left_out``), read a block of ticks at a time."""
        out = np.zeros(self.shape[:2] + (3,))
        read = getattr(self.detections, "keypoints_of", None)
        for start in range(0, len(self), self.block_ticks):
            index = self.index[start:start + self.block_ticks]
            used = np.flatnonzero(index >= 0)
            if not len(used):
                continue
            lo, hi = int(index[used].min()), int(index[used].max()) + 1
            keypoints = read(lo, hi) if read is not None else self.detections.keypoints[:, lo:hi]      # (C, ·, K, 3)
            cues = image_forward(keypoints[:, index[used] - lo], self.detections.keypoint_names, self.min_confidence)
            out[start + used] = cues.transpose(1, 0, 2)
        out[self.left_out] = 0.0
        return out

    def between(self, start: int, stop: int | None = None) -> "TickObservations":
        """The ticks [start, stop) as observations of their own (tick 0 is ``start``)."""
        return TickObservations(self.detections, self.index[start:stop], self.min_confidence,
                                self.left_out[start:stop], self.block_ticks)

    def __getitem__(self, key):
        if isinstance(key, tuple):
            head, rest = key[0], key[1:]
            return self[head][rest] if not isinstance(head, slice) else self[head][(slice(None),) + rest]
        if isinstance(key, slice):
            start, stop, step = key.indices(len(self))
            if step != 1:
                raise IndexError("tick observations are sliced with step 1")
            return self.block(start, max(start, stop))
        t = operator.index(key)
        t = t + len(self) if t < 0 else t
        if not 0 <= t < len(self):
            raise IndexError(f"tick {key} of {len(self)}")
        first, held = self._held
        if held is None or not first <= t < first + len(held):
            first = t - t % self.block_ticks
            held = self.block(first, min(first + self.block_ticks, len(self)))
            self._held = (first, held)
        return held[t - first]

    def __iter__(self):
        for _, z in self.blocks():
            yield from z

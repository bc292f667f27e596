"""Replay a motion and its synthetic 2D observations, or a tracking run, into a rerun recording."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from priortrack.body.fk import joint_positions
from priortrack.data.motion import Motion
from priortrack.filters.snapshot import KNOWN_FRAMES, Track
from priortrack.observation.synthetic import Observations
from priortrack.viz.logger import RerunLogger


def replay(motion: Motion, observations: Observations, path: str | Path, track: Track | None = None,
           smoothed: np.ndarray | None = None, name: str | None = None, likelihood=None,
           mismatch: np.ndarray | None = None) -> Path:
    """Write the ground-truth eval15 skeleton over time (joints missing from the observations grey),
    the camera and the 2D observations in its image to ``path`` (an ``.rrd`` file). With a tracking
    run ``track``, also the filter's estimate and its projection, its cloud and the per-frame
    scalars and flags of :class:`~priortrack.viz.logger.RerunLogger` (the cloud and ESS if ``track``
    kept its snapshots; the log-likelihood with ``likelihood``; the ``mismatch`` flags (T,) if given);
    with ``smoothed`` joints (T, 15, 3) the smoothed skeleton beside the filter's; ``name`` names the
    recording in the viewer. Returns the path."""
    positions = joint_positions(motion, "eval15")
    snapshots = {s.frame: s for s in track.snapshots or []} if track is not None else {}
    with RerunLogger(path, observations.camera, name, likelihood) as logger:
        for i, pose in enumerate(positions):
            tracked = track is not None and i >= KNOWN_FRAMES
            logger.log(i, snapshots.get(i), observations.uv[i], pose,
                       estimate=track.estimates[i] if tracked else None,
                       smoothed=smoothed[i] if smoothed is not None and i >= KNOWN_FRAMES else None,
                       mismatch=bool(mismatch[i]) if mismatch is not None and i >= KNOWN_FRAMES else None)
    return Path(path)

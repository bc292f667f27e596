"""Replay a motion and its synthetic 2D observations, or a tracking run, into a rerun recording."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from priortrack.data.motion import Motion
from priortrack.filters.snapshot import Track
from priortrack.observation.synthetic import Observations
from priortrack.viz.recording import Recording


def replay(motion: Motion, observations: Observations, path: str | Path) -> Path:
    """Write the ground-truth eval15 skeleton over time, the camera as a pinhole entity and
    the 2D observations in its image to ``path`` (an ``.rrd`` file). Returns the path."""
    positions = motion.positions("eval15")
    with Recording(path) as rec:
        rec.camera(observations.camera)
        for i, pose in enumerate(positions):
            rec.frame(i)
            rec.skeleton("truth", pose)
            rec.points_2d("observations", observations.uv[i])
    return Path(path)


def replay_track(motion: Motion, observations: Observations, track: Track, path: str | Path) -> Path:
    """Write a tracking run: the ground truth, the filter's estimate (from frame 2), the particle
    cloud or sigma points coloured by weight (``track`` must keep its snapshots), the 2D
    observations and the estimate's projection. Returns the path."""
    positions = motion.positions("eval15")
    snapshots = {s.frame: s for s in track.snapshots or []}
    with Recording(path) as rec:
        rec.camera(observations.camera)
        for i, pose in enumerate(positions):
            rec.frame(i)
            rec.skeleton("truth", pose)
            rec.points_2d("observations", observations.uv[i])
            if i >= 2 and np.isfinite(track.estimates[i]).all():
                rec.skeleton("estimate", track.estimates[i], color=(255, 90, 60))
                uv, _ = observations.camera.project(torch.as_tensor(track.estimates[i]))
                rec.points_2d("estimate", uv.numpy(), color=(255, 90, 60))
            if i in snapshots:
                rec.cloud("estimate", snapshots[i].joints.cpu().numpy(), snapshots[i].weights.cpu().numpy())
    return Path(path)

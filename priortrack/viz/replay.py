"""Replay a motion and its synthetic 2D observations, or a tracking run, into a rerun recording."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from priortrack.data.motion import Motion
from priortrack.filters.snapshot import KNOWN_FRAMES, Track
from priortrack.observation.synthetic import Observations
from priortrack.viz.recording import Recording
from priortrack.body.fk import joint_positions

ESTIMATE_COLOR, SMOOTHED_COLOR = (255, 90, 60), (120, 230, 90)


def replay(motion: Motion, observations: Observations, path: str | Path, track: Track | None = None,
           smoothed: np.ndarray | None = None, name: str | None = None) -> Path:
    """Write the ground-truth eval15 skeleton over time, the camera as a pinhole entity and the 2D
    observations in its image to ``path`` (an ``.rrd`` file). With a tracking run ``track``, also
    the filter's estimate (after the known frames) and its projection, and the particle cloud or
    sigma points coloured by weight (if ``track`` kept its snapshots), with the 1σ ellipsoid of the
    body's translation where the filter integrated it out; with ``smoothed`` joints (T, 15, 3) the
    smoothed skeleton beside the filter's; ``name`` names the recording in the viewer. Returns the path."""
    positions = joint_positions(motion, "eval15")
    snapshots = {s.frame: s for s in track.snapshots or []} if track is not None else {}
    with Recording(path, name=name) as rec:
        rec.camera(observations.camera)
        for i, pose in enumerate(positions):
            rec.frame(i)
            rec.skeleton("truth", pose)
            rec.points_2d("observations", observations.uv[i])
            if track is not None and i >= KNOWN_FRAMES and np.isfinite(track.estimates[i]).all():
                rec.skeleton("estimate", track.estimates[i], color=ESTIMATE_COLOR)
                uv, _ = observations.camera.project(torch.as_tensor(track.estimates[i]))
                rec.points_2d("estimate", uv.numpy(), color=ESTIMATE_COLOR)
            if smoothed is not None and i >= KNOWN_FRAMES:
                rec.skeleton("smoothed", smoothed[i], color=SMOOTHED_COLOR)
            if i in snapshots:
                rec.cloud("estimate", snapshots[i].joints.cpu().numpy(), snapshots[i].weights.cpu().numpy())
                spread = snapshots[i].translation_spread()
                if spread is not None:
                    rec.ellipsoid("estimate/translation", *spread, color=ESTIMATE_COLOR)
    return Path(path)

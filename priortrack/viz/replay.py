"""Replay a motion and its synthetic 2D observations into a rerun recording."""

from __future__ import annotations

from pathlib import Path

from priortrack.data.motion import Motion
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

"""priortrack: learned motion priors as transition models for Bayesian 3D human-pose tracking.

The motion data bundled with priortrack was obtained from mocap.cs.cmu.edu.
The database was created with funding from NSF EIA-0196217.
"""

from priortrack.errors import PriortrackError
from priortrack.data.skeleton import Skeleton
from priortrack.data.motion import Motion
from priortrack.data.load import load_motion
from priortrack.data.bundled import load_walkjog, bundled_clips

__all__ = ["PriortrackError", "Skeleton", "Motion", "load_motion", "load_walkjog", "bundled_clips"]
__version__ = "0.1.0"

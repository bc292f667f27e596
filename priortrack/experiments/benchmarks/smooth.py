"""``priortrack bench smooth``: the smoother's cost against the forward pass it smooths, side by side
in the same run: 100 filtered frames of a held-out walk (walkjog 35_29, 5 px noise) at the presets'
1000 particles, smoothed with M = 100 trajectories (the MCMC backward kernel, its default moves), and
the unscented RTS smoother for the unscented presets. Reported as smoothing seconds / forward seconds.
"""

from __future__ import annotations

from priortrack.errors import PriortrackError
from priortrack.experiments.benchmarks.timing import load_average
from priortrack.experiments.tracking import track
from priortrack.filters.snapshot import KNOWN_FRAMES

MOTION, SCENARIO = "walkjog:35_29", "noise"
PRESETS = ("pf-diffusion-local", "pf-gpdm", "pf-lie", "ukf-gpdm")


def bench_smooth(presets=PRESETS, frames: int = 100, trajectories: int = 100, seed: int = 0) -> dict:
    """{preset: {"forward_seconds", "smoothing_seconds", "ratio"}} for ``frames`` filtered frames."""
    if not 1 <= frames <= 120:
        raise PriortrackError(f"bench smooth: frames must be in [1, 120] ({MOTION} has 125 at 30 fps), got {frames}")
    rows = {}
    for preset in presets:
        run = track(MOTION, preset, SCENARIO, seed, frames=frames + KNOWN_FRAMES, smooth=True,
                    trajectories=trajectories)
        rows[preset] = {"forward_seconds": run.track.seconds, "smoothing_seconds": run.smoothed.seconds,
                        "ratio": run.smoothed.seconds / run.track.seconds}
    return {"frames": frames, "trajectories": trajectories, "motion": MOTION, "presets": rows,
            "load_average": load_average()}

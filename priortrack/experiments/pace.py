"""``priortrack eval pace``: filters on held-out walks played slower and faster than the training
walks (issue 19: a learned prior must hold paces it was not trained on).

A walk at pace p is the bundled walk at the prior's rate resampled at fps / p and played at fps
(p = 0.6: 0.6× the speed, 1/0.6 as many frames); tracked under each scenario (default: 5 px noise,
and the one-gait-cycle blackout) with each preset and seed; the table is the mean world MPJPE.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from priortrack.data.load import load_motion
from priortrack.data.motion import Motion
from priortrack.errors import PriortrackError
from priortrack.experiments.tracking import TABLE_MOTIONS, track

PRESETS = ("pf-diffusion-local", "pf-lie", "pf-lie-defensive", "pf-gpdm")
PACES = (0.6, 1.0, 1.4)
SCENARIOS = ("noise", "blackout:sigma_px=5")
FPS = 30.0


def at_pace(motion: Motion, pace: float, fps: float = FPS) -> Motion:
    """``motion`` at ``fps``, played at ``pace`` × its speed (:meth:`Motion.played_at`)."""
    return motion.resample(fps).played_at(pace)


def eval_pace(presets: Sequence[str] = PRESETS, motions: Sequence[str] = TABLE_MOTIONS,
              paces: Sequence[float] = PACES, scenarios: Sequence[str] = SCENARIOS, seeds: int = 2) -> dict:
    """{"table": {preset: {motion@pace: {scenario: mean MPJPE (mm) over the seeds}}}, "runs": [rows]}."""
    if seeds < 1:
        raise PriortrackError(f"seeds must be at least 1, got {seeds}")
    walks = {name: load_motion(name) for name in motions}
    runs, table = [], {p: {} for p in presets}
    for name, walk in walks.items():
        for pace in paces:
            paced = at_pace(walk, pace)
            for preset in presets:
                for scenario in scenarios:
                    rows = [track(paced, preset, scenario, seed).result for seed in range(seeds)]
                    runs += rows
                    table[preset].setdefault(paced.name, {})[scenario] = float(np.mean([r["mpjpe_mm"] for r in rows]))
    return {"table": table, "runs": runs, "paces": list(paces), "scenarios": list(scenarios), "seeds": seeds}

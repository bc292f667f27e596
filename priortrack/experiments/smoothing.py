"""``priortrack eval smoothing``: smoothed against filtered, from the same runs, through a blackout.

Each preset tracks each held-out walk (:data:`~priortrack.experiments.tracking.TABLE_MOTIONS`: none
is in any preset's training data) under the one-gait-cycle blackout at 5 px (every joint missing for
1.1 s from a third of the clip), is smoothed over the whole run, and both estimates are scored
against the mocap: world MPJPE over the blacked-out frames, over the frames with observations
("clean"), and over the run.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from priortrack.body.fk import joint_positions
from priortrack.errors import PriortrackError
from priortrack.experiments.metrics import mpjpe
from priortrack.experiments.tracking import TABLE_MOTIONS, track
from priortrack.filters.snapshot import KNOWN_FRAMES

PRESETS = ("pf-diffusion-local", "pf-gpdm", "pf-lie", "ukf-diffusion-local", "ukf-gpdm")
SCENARIO = "blackout:sigma_px=5"


def smoothing_run(preset: str, motion: str, seed: int = 0, scenario: str = SCENARIO, cache=None) -> dict:
    """One run: MPJPE (mm) of the filtered and smoothed estimates over the blacked-out frames, the
    frames with observations and all tracked frames, and the forward and smoothing seconds."""
    run = track(motion, preset, scenario, seed, cache=cache, smooth=True)
    truth = joint_positions(run.motion, "eval15")[KNOWN_FRAMES:]
    dark = ~np.isfinite(run.observations.uv[KNOWN_FRAMES:]).any(axis=(1, 2))
    row = {"preset": preset, "motion": motion, "seed": seed, "scenario": scenario,
           "forward_seconds": run.track.seconds, "smoothing_seconds": run.smoothed.seconds}
    for name, estimates in (("filtered", run.track.estimates), ("smoothed", run.smoothed.estimates)):
        error = mpjpe(estimates[KNOWN_FRAMES:], truth)
        row.update({f"{name}_mm": float(error.mean()), f"{name}_blackout_mm": float(error[dark].mean()),
                    f"{name}_clean_mm": float(error[~dark].mean())})
    return row


def eval_smoothing(presets: Sequence[str] = PRESETS, motions: Sequence[str] = TABLE_MOTIONS, seeds: int = 1,
                   scenario: str = SCENARIO, cache=None) -> dict:
    """Every preset × motion × seed of :func:`smoothing_run`: {"table": {preset: means of each figure
    over the runs, with "blackout_ratio", "clean_ratio" and "ratio" (smoothed / filtered)}, "runs": [...]}."""
    if seeds < 1:
        raise PriortrackError(f"seeds must be at least 1, got {seeds}")
    runs = [smoothing_run(p, m, s, scenario, cache) for p in presets for m in motions for s in range(seeds)]
    table = {}
    for p in presets:
        rows = [r for r in runs if r["preset"] == p]
        means = {key: float(np.mean([r[key] for r in rows])) for key in rows[0]
                 if key.endswith("_mm") or key.endswith("_seconds")}
        means.update({f"{part}ratio": means[f"smoothed_{part}mm"] / means[f"filtered_{part}mm"]
                      for part in ("", "blackout_", "clean_")})
        means["worst_blackout_ratio"] = max(r["smoothed_blackout_mm"] / r["filtered_blackout_mm"] for r in rows)
        table[p] = means
    return {"table": table, "runs": runs, "scenario": scenario, "motions": list(motions), "seeds": seeds}

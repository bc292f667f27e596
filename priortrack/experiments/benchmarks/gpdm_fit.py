"""Benchmark: fitting a balanced GPDM to convergence on about 300 frames of walking.

The problem: the first training walks of the subject-35 walk/jog set (30 fps), each its own
sequence, as many as it takes to reach ``frames`` (the last one cut), ~50 angle channels, d = 3.
Convergence is the fit's own criterion (:mod:`priortrack.priors.gpdm`: L-BFGS-B's relative
decrease and projected-gradient tolerances within its iteration cap).
"""

from __future__ import annotations

import time


from priortrack.data.bundled import load_walkjog
from priortrack.errors import PriortrackError
from priortrack.priors.gpdm import GPDM
from priortrack.threads import torch_threads


def bench_walks(frames: int = 300) -> list:
    """The first subject-35 training walks, cut to ``frames`` frames in all (each ≥ 3 frames)."""
    walks, total = [], 0
    for motion in load_walkjog().walks("train"):
        take = min(len(motion), frames - total)
        if take < 3:
            break
        walks.append(motion[:take])
        total += take
    return walks


def bench_gpdm_fit(frames: int = 300, seed: int = 0, threads: int = 2) -> dict:
    """Fit a B-GPDM (d = 3) on ``frames`` frames of walking with ``threads`` torch threads.

    Returns ``{"frames", "dims", "sequences", "seconds", "iterations", "evaluations", "objective",
    "converged", "threads"}``: N, D, the number of walks, wall time of the whole fit, L-BFGS-B
    iterations and objective evaluations, the final objective L and whether the fit met its
    tolerance.
    """
    if frames < 10 or threads < 1:
        raise PriortrackError(f"bench gpdm: frames must be ≥ 10 and threads ≥ 1 (got {frames}, {threads})")
    walks = bench_walks(frames)
    with torch_threads(threads):
        start = time.perf_counter()
        model = GPDM.fit(walks, balanced=True, d=3, seed=seed)
        seconds = time.perf_counter() - start
    summary = model.fit_summary
    return {"frames": len(model.Y), "dims": model.D, "sequences": len(walks), "seconds": seconds,
            "iterations": summary["iterations"], "evaluations": summary["evaluations"],
            "objective": summary["objective"], "converged": summary["converged"], "threads": threads}

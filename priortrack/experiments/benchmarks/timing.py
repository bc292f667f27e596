"""What every benchmark shares: interleaved timings and the machine's load.

Timings are medians over interleaved repeats (reference, ours, reference, ours, …) so that
machine noise hits both alike; compare the ratio, not the absolute figures.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable

import numpy as np


def load_average() -> tuple[float, float, float] | None:
    """The machine's 1, 5 and 15 minute load averages (``os.getloadavg``), None where the system
    has none: whether a timing had the cores to itself."""
    return os.getloadavg() if hasattr(os, "getloadavg") else None


def interleaved_median_ms(functions: dict[str, Callable[[], object]], repeats: int) -> dict[str, float]:
    """Median wall time (ms) of each function, run in turn ``repeats`` times after one warm-up."""
    times: dict[str, list[float]] = {name: [] for name in functions}
    for name, f in functions.items():
        f()
    for _ in range(repeats):
        for name, f in functions.items():
            start = time.perf_counter()
            f()
            times[name].append(time.perf_counter() - start)
    return {name: 1000.0 * float(np.median(t)) for name, t in times.items()}

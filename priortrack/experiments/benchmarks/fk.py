"""``priortrack bench fk``: our forward kinematics against pytorch-kinematics on the same poses."""

from __future__ import annotations

import numpy as np
import torch

from priortrack.body.chain import KinematicChain
from priortrack.body.fk import ForwardKinematics
from priortrack.data.bundled import load_bundled
from priortrack.errors import PriortrackError
from priortrack.experiments.benchmarks.timing import interleaved_median_ms
from priortrack.threads import torch_threads


def bench_fk(batch: int = 10_000, repeats: int = 9, threads: int = 2, seed: int = 0,
             motion: str = "cmu:07_01") -> dict:
    """Our FK against pytorch-kinematics' ``forward_kinematics_tensor`` in float32.

    Poses are the frames of a bundled walk, tiled to ``batch`` and perturbed by N(0, 0.1²)
    radians. The error is measured in float64 on the same poses.

    Returns ``{"batch", "priortrack_ms", "pytorch_kinematics_ms", "ratio", "max_abs_err_m", "threads"}``
    where ratio = pytorch_kinematics_ms / priortrack_ms.
    """
    if batch < 1 or repeats < 1 or threads < 1:
        raise PriortrackError(f"bench fk: batch, repeats and threads must be positive (got {batch}, {repeats}, {threads})")
    m = load_bundled(motion)
    rng = np.random.default_rng(seed)
    frames = m.channels[rng.integers(0, len(m), size=batch)]
    channels = frames + rng.normal(0.0, 0.1, size=frames.shape) * (np.arange(m.skeleton.num_channels) >= 3)

    results = {}
    with torch_threads(threads):
        for dtype in (torch.float64, torch.float32):
            ours = ForwardKinematics(m.skeleton, dtype=dtype)
            reference = KinematicChain(m.skeleton, dtype=dtype)
            x = torch.as_tensor(channels, dtype=dtype)
            th = reference.joint_values(x)
            if dtype == torch.float64:
                results["max_abs_err_m"] = float((ours(x) - reference.positions_from_values(th)).abs().max())
                continue
            with torch.inference_mode():
                ms = interleaved_median_ms({"pytorch_kinematics": lambda: reference.positions_from_values(th),
                                            "priortrack": lambda: ours(x)}, repeats)
    return {
        "batch": batch,
        "priortrack_ms": ms["priortrack"],
        "pytorch_kinematics_ms": ms["pytorch_kinematics"],
        "ratio": ms["pytorch_kinematics"] / ms["priortrack"],
        "max_abs_err_m": results["max_abs_err_m"],
        "threads": threads,
    }

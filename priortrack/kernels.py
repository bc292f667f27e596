"""When the fused numba kernels apply: the package's kernels (FK, placement, global motion, the Lie
draw, the Kalman update) compute on CPU numpy views of their inputs, without autograd, so each
runs only where every input is a CPU tensor that needs no gradient (and, for the float32-only
ones, float32). Everything else takes the torch path, which each kernel is tested against."""

from __future__ import annotations

import torch


def cpu_kernel_applies(*tensors: torch.Tensor, dtype: torch.dtype | None = None) -> bool:
    """True if every tensor is on the CPU, needs no gradient, and (if ``dtype`` is given) has that dtype."""
    return all(t.device.type == "cpu" and not t.requires_grad and (dtype is None or t.dtype == dtype)
               for t in tensors)

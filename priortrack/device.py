"""Where the particle filters compute: a device name checked once, at the boundary (the filter's
constructor, the command line), so that a missing GPU is one clear error and not a CUDA traceback
from deep inside a step. Everything below a filter follows its particles' device (each prior,
global motion and likelihood moves its own constants to the tensors it is given)."""

from __future__ import annotations

import torch

from priortrack.errors import PriortrackError

#: The names ``--device`` takes; "cuda:N" picks the N-th GPU.
DEVICES = ("cpu", "cuda")


def resolve_device(name: str | torch.device) -> torch.device:
    """"cpu", "cuda" or "cuda:N" → a torch.device that this machine has; a PriortrackError naming the
    problem otherwise (an unknown name, no CUDA build or no GPU, a GPU index past the count)."""
    try:
        device = torch.device(name)
    except (RuntimeError, TypeError) as error:
        raise PriortrackError(f"device {name!r} is not one of {', '.join(DEVICES)} (or cuda:N)") from error
    if device.type not in DEVICES:
        raise PriortrackError(f"device {name!r} is not one of {', '.join(DEVICES)} (or cuda:N)")
    if device.type == "cuda":
        if not torch.cuda.is_available():
            raise PriortrackError(f"device {name!r}: this torch ({torch.__version__}) sees no CUDA GPU on this machine; "
                                  f"run with --device cpu")
        if device.index is not None and device.index >= torch.cuda.device_count():
            raise PriortrackError(f"device {name!r}: this machine has {torch.cuda.device_count()} CUDA GPU(s)")
    return device


def synchronize(device: torch.device) -> None:
    """Wait for the device's queued work (a no-op on the CPU): what a wall-clock timing of GPU work needs."""
    if device.type == "cuda":
        torch.cuda.synchronize(device)

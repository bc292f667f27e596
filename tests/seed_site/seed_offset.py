"""Every seed offset by k, to find the tests whose outcome rests on one draw of random numbers.

``make test SEED_OFFSET=k`` (or ``PRIORTRACK_TEST_SEED_OFFSET=k``, or ``pytest --seed-offset k``) adds k
to every integer seed given to ``numpy.random.default_rng``, ``torch.manual_seed`` and
``torch.Generator().manual_seed``, in the tests and in the package they call alike. A seed sequence
``(s, i)`` has its first entry offset, so streams kept apart stay apart. The suite's own processes
are patched by ``conftest.py``; the processes they start (the CLI run as a program, spawned workers,
notebook kernels) by this folder's ``sitecustomize.py``, which ``conftest.py`` puts on their
``PYTHONPATH``. Hypothesis keeps its own seeds. With k = 0 nothing is patched.
"""

from __future__ import annotations

import os

ENV = "PRIORTRACK_TEST_SEED_OFFSET"


def offset_from_env() -> int:
    """k from the environment (0 where unset)."""
    text = os.environ.get(ENV, "").strip()
    try:
        return int(text) if text else 0
    except ValueError:
        raise SystemExit(f"{ENV} must be a whole number, got {text!r}") from None


def _shifted(seed, k: int):
    """An integer seed plus k; a sequence of integers with its first entry plus k; anything else as given
    (None, a SeedSequence, a Generator)."""
    import numpy as np

    if isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
        return int(seed) + k
    if isinstance(seed, (tuple, list)) and seed and isinstance(seed[0], (int, np.integer)):
        return type(seed)([int(seed[0]) + k, *seed[1:]])
    return seed


def apply(k: int) -> None:
    """Patch numpy's and torch's seeding entry points to add k (no-op for k = 0 or when already applied)."""
    import numpy as np
    import torch

    if k == 0 or getattr(np.random.default_rng, "seed_offset", None) is not None:
        return
    default_rng, manual_seed = np.random.default_rng, torch.manual_seed

    def offset_default_rng(seed=None):
        return default_rng(_shifted(seed, k))

    def offset_manual_seed(seed):
        return manual_seed(_shifted(seed, k))

    class OffsetGenerator(torch.Generator):
        def manual_seed(self, seed):
            return super().manual_seed(_shifted(seed, k))

    offset_default_rng.seed_offset = k
    np.random.default_rng = offset_default_rng
    torch.manual_seed = offset_manual_seed
    torch.Generator = OffsetGenerator

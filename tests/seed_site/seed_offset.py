"""Every seed offset by k, to find the tests whose outcome rests on one draw of random numbers.

``PRIORTRACK_TEST_SEED_OFFSET=k make test`` (or ``pytest --seed-offset k``) adds k to every integer seed
given to ``numpy.random.default_rng``, ``torch.manual_seed`` and ``torch.Generator().manual_seed``, in
the tests and in the package they call alike. A seed sequence ``(s, i)`` has its first entry offset, so
streams kept apart stay apart. The suite's own processes are patched by ``conftest.py``; the processes
they start (the CLI run as a program, spawned workers, notebook kernels) by this folder's
``sitecustomize.py``, which ``conftest.py`` puts on their ``PYTHONPATH`` and which patches numpy and
torch only when the process imports them (a process that never does, as the packaging tests' check
of what a command imports, is left as it was). Hypothesis keeps its own seeds. With k = 0 nothing is
patched.
"""

from __future__ import annotations

import importlib.util
import os
import sys

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


def patch_numpy(k: int) -> None:
    import numpy as np

    if getattr(np.random.default_rng, "seed_offset", None) is not None:
        return
    default_rng = np.random.default_rng

    def offset_default_rng(seed=None):
        return default_rng(_shifted(seed, k))

    offset_default_rng.seed_offset = k
    np.random.default_rng = offset_default_rng


def patch_torch(k: int) -> None:
    import torch

    if getattr(torch.manual_seed, "seed_offset", None) is not None:
        return
    manual_seed = torch.manual_seed

    def offset_manual_seed(seed):
        return manual_seed(_shifted(seed, k))

    class OffsetGenerator(torch.Generator):
        def manual_seed(self, seed):
            return super().manual_seed(_shifted(seed, k))

    offset_manual_seed.seed_offset = k
    torch.manual_seed = offset_manual_seed
    torch.Generator = OffsetGenerator


def apply(k: int) -> None:
    """Patch numpy's and torch's seeding now (both imported; no-op for k = 0 or when already applied)."""
    if k:
        patch_numpy(k)
        patch_torch(k)


class _AfterImport:
    """A meta-path finder that patches numpy or torch right after the process first imports it."""

    def __init__(self, k: int):
        self.k, self.busy = k, set()

    def find_spec(self, name, path=None, target=None):
        patch = {"numpy": patch_numpy, "torch": patch_torch}.get(name)
        if patch is None or name in self.busy:
            return None
        self.busy.add(name)
        try:
            spec = importlib.util.find_spec(name)
        finally:
            self.busy.discard(name)
        if spec is None or spec.loader is None:
            return spec
        run = spec.loader.exec_module

        def exec_module(module):
            run(module)
            patch(self.k)

        spec.loader.exec_module = exec_module
        return spec


def apply_on_import(k: int) -> None:
    """Patch numpy and torch when they are imported (the sitecustomize's way: nothing imported early)."""
    if k:
        sys.meta_path.insert(0, _AfterImport(k))

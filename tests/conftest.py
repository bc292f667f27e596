"""Suite-wide settings: fitted priors of presets are cached in the repository's (git-ignored)
.pytest_cache, never in the user's home; concurrent workers write the cache atomically."""

from pathlib import Path

import pytest

CACHE = Path(__file__).resolve().parents[1] / ".pytest_cache" / "priortrack-priors"


@pytest.fixture(autouse=True)
def _prior_cache(monkeypatch):
    monkeypatch.setenv("PRIORTRACK_CACHE", str(CACHE))


def pytest_configure(config):
    """One torch thread per test process: `make test` runs two xdist workers on two cores, and
    two-thread BLAS calls in each would oversubscribe them (a GPDM fit ran several times slower)."""
    import torch

    torch.set_num_threads(1)

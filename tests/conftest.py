"""Suite-wide settings: fitted priors of presets are cached in the repository's (git-ignored)
.pytest_cache (one cache per seed offset: priors fitted from other seeds are other priors), never in
the user's home; concurrent workers write the cache atomically. Every seed
can be offset (``--seed-offset k`` or ``PRIORTRACK_TEST_SEED_OFFSET=k``: ``seed_site/seed_offset.py``)."""

import os
import sys
from pathlib import Path


SEED_SITE = Path(__file__).resolve().parent / "seed_site"
sys.path.insert(0, str(SEED_SITE))
import seed_offset  # noqa: E402  (the folder above is put on the path first)

CACHE = Path(__file__).resolve().parents[1] / ".pytest_cache" / "priortrack-priors"


def pytest_addoption(parser):
    parser.addoption("--seed-offset", type=int, default=None,
                     help="add this to every integer seed numpy and torch are given (default: "
                          f"${seed_offset.ENV} or 0)")


def pytest_configure(config):
    """One torch thread per test process: `make test` runs two xdist workers on two cores, and
    two-thread BLAS calls in each would oversubscribe them (a GPDM fit ran several times slower).
    The seed offset is applied here and handed to every process the tests start."""
    import torch

    torch.set_num_threads(1)
    k = config.getoption("--seed-offset")
    k = seed_offset.offset_from_env() if k is None else k
    # the suite's prior cache for every test and fixture of any scope (a module fixture built before a
    # function-scoped one would read the user's cache, whose priors another seed offset may have fitted)
    os.environ["PRIORTRACK_CACHE"] = str(CACHE if k == 0 else CACHE.with_name(f"{CACHE.name}-seed-offset-{k}"))
    if k:
        os.environ[seed_offset.ENV] = str(k)
        os.environ["PYTHONPATH"] = os.pathsep.join(filter(None, [str(SEED_SITE), os.environ.get("PYTHONPATH")]))
    seed_offset.apply(k)


def pytest_report_header(config):
    k = seed_offset.offset_from_env()
    return f"seeds offset by {k}" if k else None

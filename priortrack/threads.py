"""Threads for torch work: scoped thread counts (torch's, and BLAS's for numpy and scipy), and a pool
of single-threaded workers that run blocks of a batch side by side (the Lie prior's sampler, the
row-wise kernels)."""

from __future__ import annotations

import contextlib
import os
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor

import torch
from threadpoolctl import ThreadpoolController

_POOL_LOCK = threading.Lock()
_pool: tuple[int, int, ThreadPoolExecutor] | None = None                               # (pid, threads, pool)


_blas: ThreadpoolController | None = None


def blas_threads(n: int):
    """A context in which numpy's and scipy's BLAS (OpenBLAS) run on ``n`` threads, restored after; the
    libraries are found once, on first use (after those that the package imports are loaded)."""
    global _blas
    if _blas is None:
        _blas = ThreadpoolController()
    return _blas.limit(limits=n, user_api="blas")


@contextlib.contextmanager
def torch_threads(n: int) -> Iterator[None]:
    """Run torch's intra-op work on ``n`` threads inside the block, restoring the count after."""
    previous = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


def _single_threaded_worker() -> None:
    """Initialiser of :func:`block_pool`'s threads: torch set to one thread in this thread. torch
    initialises a thread's count on its first use there (to the default), so that comes first."""
    torch.get_num_threads()
    torch.set_num_threads(1)


def block_pool(workers: int) -> ThreadPoolExecutor:
    """The process's pool of block workers, with at least ``workers`` threads (rebuilt after a fork).

    It lives for the life of the process. Each worker sets torch to one thread for itself:
    OpenMP's and MKL's thread counts are per-thread settings, so T blocks run side by side keep
    T threads busy instead of starting T teams (in builds with MKL, its vector math behind acos,
    exp, sin and cos would otherwise thread each call). Since ``torch.set_num_threads`` also sets
    the default that threads take on their first use of torch, that default is put back once
    every worker has started.
    """
    global _pool
    with _POOL_LOCK:
        if _pool is None or _pool[0] != os.getpid() or _pool[1] < workers:
            threads = torch.get_num_threads()
            pool = ThreadPoolExecutor(workers, thread_name_prefix="priortrack-blocks",
                                      initializer=_single_threaded_worker)
            started = threading.Barrier(workers + 1)
            for _ in range(workers):
                pool.submit(started.wait)
            started.wait()
            torch.set_num_threads(threads)
            _pool = (os.getpid(), workers, pool)
        return _pool[2]


def split_rows(n: int, run: Callable[[slice], None], min_rows: int = 2048) -> None:
    """Call ``run(rows)`` on contiguous slices covering range(n): side by side on
    min(torch's thread count, n // min_rows) workers of :func:`block_pool` (for kernels that
    release the GIL and treat rows independently), or once, in this thread."""
    workers = min(torch.get_num_threads(), n // min_rows)
    if workers <= 1:
        run(slice(0, n))
        return
    bounds = [n * k // workers for k in range(workers + 1)]
    pool = block_pool(workers)
    for future in [pool.submit(run, slice(a, b)) for a, b in zip(bounds[:-1], bounds[1:])]:
        future.result()

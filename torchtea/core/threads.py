"""How many threads the engines use: chosen for the problem and the machine's load, set for a block of work.

A check's torch work is small (a few thousand spectrum terms, matrices of tens of rows): torch's threads only wait
for each other, and OpenMP's waiting threads spin — beside another job a one-channel check burnt 4.7× the CPU of its
one-thread run. Its compiled likelihood kernels run parameter sets in parallel (numba's ``prange``), one set
per thread, so their results do not depend on the number of threads; they get the cores the machine has free."""
from __future__ import annotations

import contextlib
import os

__all__ = ["free_cores", "engine_threads"]


def free_cores() -> int:
    """The cores not busy with other work: the machine's cores less its load over the last minute (rounded), at
    least 1. Read when a command starts, the load is the other jobs'."""
    cores = os.cpu_count() or 1
    try:
        load = os.getloadavg()[0]
    except (OSError, AttributeError):  # (not on every platform)
        return cores
    return max(1, min(cores, cores - int(round(load))))


@contextlib.contextmanager
def engine_threads(threads: int | None = None):
    """Within the block, torch and the BLAS libraries (NumPy's, SciPy's: ``threadpoolctl``) on one thread and numba's
    kernels on ``threads`` (default :func:`free_cores`, at most numba's pool); all restored after. The process's
    allocator keeps large blocks in its heap from then on (:func:`~torchtea.core.alloc.tune_allocator`). One BLAS thread
    also makes a long dot product's rounding the same in every process (OpenBLAS splits it among its threads)."""
    import numba
    import torch
    from threadpoolctl import threadpool_limits

    from .alloc import tune_allocator

    tune_allocator()  # (a Dask worker's allocator settings made every large temporary a fresh mapping)
    n = free_cores() if threads is None else max(1, int(threads))
    n = min(n, numba.config.NUMBA_NUM_THREADS)
    before = torch.get_num_threads(), numba.get_num_threads()
    torch.set_num_threads(1)
    numba.set_num_threads(n)
    try:
        with threadpool_limits(limits=1, user_api="blas"):
            yield n
    finally:
        torch.set_num_threads(before[0])
        numba.set_num_threads(before[1])

"""Process-level performance settings.

A batched filter step allocates and frees the same few-megabyte temporaries thousands of times per
second. With glibc's defaults, blocks that large are mapped and unmapped (or trimmed back to the system)
each time, and every fresh page costs a page fault on first touch: in isolation, the exponential-sum
evaluation of 1000 realisations ran 3–4× faster with :func:`tune_allocator`, which keeps such blocks in
the heap. In whole TEA runs the benchmark (``experiments/bench/README.md``) measures the effect side by
side; it was not large enough to turn on by default there.

A Dask nanny starts its workers with ``MALLOC_TRIM_THRESHOLD_=65536``, which also switches off glibc's dynamic
mmap threshold: a check on a worker then took 47 million page faults and 90 s of system time where the same
check in one process took 0.3 million and 2.5 s (the bundled recording, two workers), and each channel
2–2.5× as long. The channels' tasks (:func:`torchtea.checking.channels.check_channel`,
:func:`torchtea.fitting.recording.fit_channel`) therefore call :func:`tune_allocator` wherever they run.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import sys

__all__ = ["tune_allocator"]

_M_TRIM_THRESHOLD = -1  # glibc mallopt parameters (malloc.h)
_M_MMAP_THRESHOLD = -3


def tune_allocator(mmap_threshold: int = 1 << 28, trim_threshold: int = 1 << 30) -> bool:
    """Serve allocations below ``mmap_threshold`` bytes from the heap and keep up to ``trim_threshold``
    bytes of freed heap instead of returning it to the system (glibc ``mallopt``).

    Returns True if applied; False on platforms without glibc (nothing changes there).
    """
    if not sys.platform.startswith("linux"):
        return False
    name = ctypes.util.find_library("c")
    if not name:
        return False
    try:
        libc = ctypes.CDLL(name)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    ok = mallopt(_M_MMAP_THRESHOLD, int(mmap_threshold)) == 1
    ok = mallopt(_M_TRIM_THRESHOLD, int(trim_threshold)) == 1 and ok
    return ok

"""Process-level performance settings (moved to :mod:`torchtea.core.alloc`, which the check's and the fits' tasks on
a Dask worker call; kept here for the benchmarks and users that import it from here)."""
from ..core.alloc import tune_allocator

__all__ = ["tune_allocator"]

"""Test-wide settings.

* hypothesis runs derandomised, so every run (and CI) checks the same examples;
* torch (here and in the torchtea processes the tests start) uses one thread: the tests' tensors are small,
  and two processes that each spin two OpenMP threads on a 2-core machine slow each other down many times
  over — the suite must also pass, in reasonable time, beside another CPU-heavy job. Speed is measured in
  experiments/bench, not here.
"""
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")  # before torch is imported; inherited by child processes

import pytest  # noqa: E402
import torch  # noqa: E402
from hypothesis import settings  # noqa: E402

torch.set_num_threads(int(os.environ["OMP_NUM_THREADS"]))

settings.register_profile("torchtea", derandomize=True, print_blob=True)
settings.load_profile("torchtea")


@pytest.fixture(scope="module")
def cluster():
    """A real local Dask cluster — two worker processes with one thread each — and a client to it, shared by the tests
    of one module that do not break it."""
    pytest.importorskip("distributed")
    from torchtea.studies.cluster import local_cluster

    cl, client = local_cluster(2, threads_per_worker=1)
    try:
        yield client
    finally:
        client.close()
        cl.close()

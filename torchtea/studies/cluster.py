"""Monte Carlo studies sharded on a Dask distributed cluster.

A study's realisations are split into shards of consecutive realisations; each shard is one Dask task that runs
:func:`~torchtea.studies.montecarlo.run_range` on a worker and sends back only what the summary and the TensorBoard
run need (a :class:`~torchtea.studies.montecarlo.StudyResult` without full trajectories: ~100 bytes per realisation
plus α̂ and ŵ at the logged steps). Realisation ``i`` draws from its own seed wherever it runs, so the merged result
is the single-process result: per-realisation values are identical, per-step NEES/NIS sums differ by the order of
summation only.

Faults are Dask's: a worker that dies loses its running and held shards, which the scheduler recomputes elsewhere
(up to ``distributed.scheduler.allowed-failures`` times per shard); a shard is fetched once and then released, so
no realisation is counted twice. Ctrl-C cancels the shards not yet finished and keeps the finished ones.

Start a cluster with :func:`local_cluster` (processes on this machine) or connect to a running scheduler with
``distributed.Client(address)``; see the README ("Monte Carlo on a cluster").
"""
from __future__ import annotations

import math
import os

from .montecarlo import Study, StudyResult, auto_chunk, run_range

__all__ = ["run_studies", "plan_shards", "local_cluster", "StudyFailed", "shard_task"]


class StudyFailed(RuntimeError):
    """A shard failed for a reason other than a lost worker (an exception in the task, or a shard that killed
    ``allowed-failures`` workers). ``partial`` holds, per study, the result of the shards that finished (marked
    interrupted), so nothing computed is lost."""

    def __init__(self, message: str, partial: list[StudyResult]):
        super().__init__(message)
        self.partial = partial


def plan_shards(study: Study, shard: int | None, workers_threads: int) -> list[range]:
    """Consecutive ranges of realisations, one per task: ``shard`` realisations each, or by default about four
    shards per worker thread (so that a slow or lost worker delays the end by a fraction of its share) and no more
    than one memory chunk each (:func:`~torchtea.studies.montecarlo.auto_chunk`)."""
    R = study.realisations
    if shard is None:
        shard = min(study.chunk or auto_chunk(study.truth.n_steps), math.ceil(R / (4 * max(1, workers_threads))))
    if shard < 1:
        raise ValueError(f"shard must be at least 1 realisation, got {shard}")
    return [range(s, min(R, s + shard)) for s in range(0, R, shard)]


def shard_task(study: Study, start: int, stop: int, device: str | None, threads: int | None) -> StudyResult:
    """The Dask task of one shard (module level, so that workers import it rather than unpickle code)."""
    if threads is None:
        # a Dask nanny starts each worker process with OMP_NUM_THREADS set (1 by default), which torch follows;
        # numba's pool does not read it, so the compiled engine is held to the same count here
        threads = int(os.environ.get("OMP_NUM_THREADS", "0")) or None
    return run_range(study, start, stop, device=device, threads=threads)


def run_studies(studies: list[Study], client, *, shard: int | None = None, device=None, progress=None,
                threads: int | None = None) -> list[StudyResult]:
    """Run studies as shards on a Dask cluster, all shards scheduled together; one result per study.

    ``client``: a ``distributed.Client``. ``shard``: realisations per task (default :func:`plan_shards`).
    ``device``: the device name each worker runs its shards on (``"cuda"`` is each worker's own first GPU: give
    workers different GPUs with ``CUDA_VISIBLE_DEVICES``). ``progress(done, total)`` counts shards.
    ``threads``: torch and numba threads per shard (default: the worker's ``OMP_NUM_THREADS``).
    Ctrl-C returns what finished, each result marked ``interrupted``; a failing shard raises
    :class:`StudyFailed` holding the same.
    """
    from dask.base import tokenize
    from distributed import as_completed

    dev = None if device is None else str(device)
    nthreads = sum(client.nthreads().values()) or 1
    plans = [plan_shards(st, shard, nthreads) for st in studies]
    futures = {}
    for i, (st, ranges) in enumerate(zip(studies, plans)):
        token = tokenize(st, dev, threads)
        for rows in ranges:
            fut = client.submit(shard_task, st, rows.start, rows.stop, dev, threads,
                                key=f"torchtea-shard-{token[:12]}-{rows.start}-{rows.stop}")
            futures[fut.key] = (i, fut)
    parts = [[] for _ in studies]
    total, done = len(futures), 0
    interrupted = False
    failure = None
    ac = as_completed([f for _, f in futures.values()], with_results=False)
    try:
        for fut in ac:
            i, _ = futures.pop(fut.key)
            if fut.status == "error":
                failure = (fut.key, fut.exception())
                break
            if fut.status == "cancelled":
                failure = (fut.key, RuntimeError("cancelled by the cluster"))
                break
            part = fut.result()
            fut.release()  # the worker may drop it: a worker lost later does not recompute a fetched shard
            parts[i].append(part)
            done += 1
            if progress is not None:
                progress(done, total)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        ac.clear()
        pending = [f for _, f in futures.values()]
        if pending:
            client.cancel(pending)
    stopped = interrupted or failure is not None
    results = [_merge(st, p, stopped) for st, p in zip(studies, parts)]
    if failure is not None:
        key, exc = failure
        raise StudyFailed(f"shard {key} failed on the cluster: {type(exc).__name__}: {exc}", results)
    return results


def _merge(study: Study, parts: list[StudyResult], interrupted: bool) -> StudyResult:
    if parts:
        return StudyResult.concat(parts, interrupted=interrupted)
    return StudyResult.empty(study, interrupted=interrupted)


def local_cluster(workers: int, *, threads_per_worker: int | None = None, quiet: bool = True):
    """A ``distributed.LocalCluster`` of ``workers`` processes on this machine and a client to it.

    Each process runs one shard at a time with ``threads_per_worker`` torch/numba threads (default: this
    machine's cores shared out, at least 1). Returns ``(cluster, client)``; close both (``client.close();
    cluster.close()``) or use them as context managers. No dashboard is started (pass one with Dask's own
    ``LocalCluster`` if you want it).
    """
    import logging

    import dask
    from distributed import Client, LocalCluster

    if workers < 1:
        raise ValueError(f"workers must be at least 1, got {workers}")
    threads = threads_per_worker or max(1, (os.cpu_count() or 1) // workers)
    if quiet:
        for name in ("distributed", "distributed.nanny", "distributed.scheduler", "distributed.worker"):
            logging.getLogger(name).setLevel(logging.ERROR)
    env = dict(dask.config.get("distributed.nanny.pre-spawn-environ", default={}))
    env.update(OMP_NUM_THREADS=threads, MKL_NUM_THREADS=threads, OPENBLAS_NUM_THREADS=threads)
    with dask.config.set({"distributed.nanny.pre-spawn-environ": env}):
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0")
    return cluster, Client(cluster)

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

__all__ = ["run_study", "run_studies", "plan_studies", "plan_shards", "local_cluster", "StudyFailed", "shard_task"]


class StudyFailed(RuntimeError):
    """A shard failed for a reason other than a lost worker (an exception in the task, or a shard that killed
    ``allowed-failures`` workers). ``partial`` holds, per study, the result of the shards that finished (marked
    interrupted), so nothing computed is lost."""

    def __init__(self, message: str, partial: list[StudyResult]):
        super().__init__(message)
        self.partial = partial


def plan_shards(study: Study, shard: int | None, workers_threads: int, device=None) -> list[range]:
    """Consecutive ranges of realisations, one per task: ``shard`` realisations each, or by default about four
    shards per worker thread (so that a slow or lost worker delays the end by a fraction of its share), on the CPU
    no more than one memory chunk each (:func:`~torchtea.studies.montecarlo.auto_chunk`). On a GPU the shards are
    not capped: there a batch costs hardly more than a single realisation, and the worker chunks a large shard to
    its own memory anyway."""
    R = study.realisations
    if shard is None:
        shard = math.ceil(R / (4 * max(1, workers_threads)))
        if device is None or str(device).startswith("cpu"):
            shard = min(shard, study.chunk or auto_chunk(study.truth.n_steps))
    if shard < 1:
        raise ValueError(f"shard must be at least 1 realisation, got {shard}")
    return [range(s, min(R, s + shard)) for s in range(0, R, shard)]


def plan_studies(studies: list[Study], client, shard: int | None = None, device=None) -> list[list[range]]:
    """:func:`plan_shards` of each study for the worker threads ``client``'s cluster has now."""
    nthreads = sum(client.nthreads().values()) or 1
    return [plan_shards(st, shard, nthreads, device) for st in studies]


def shard_task(study: Study, start: int, stop: int, device: str | None, threads: int | None) -> StudyResult:
    """The Dask task of one shard (module level, so that workers import it rather than unpickle code)."""
    if threads is None:
        # a Dask nanny starts each worker process with OMP_NUM_THREADS set (1 by default), which torch follows;
        # numba's pool does not read it, so the compiled engine is held to the same count here
        threads = int(os.environ.get("OMP_NUM_THREADS", "0")) or None
    return run_range(study, start, stop, device=device, threads=threads)


def run_studies(studies: list[Study], client, *, shard: int | None = None, device=None, progress=None,
                threads: int | None = None, names: list[str] | None = None,
                plans: list[list[range]] | None = None) -> list[StudyResult]:
    """Run studies as shards on a Dask cluster, all shards scheduled together; one result per study.

    ``client``: a ``distributed.Client``. ``shard``: realisations per task (default :func:`plan_shards`).
    ``device``: the device name each worker runs its shards on (``"cuda"`` is each worker's own first GPU: give
    workers different GPUs with ``CUDA_VISIBLE_DEVICES``). ``progress(done, total)`` counts shards.
    ``threads``: torch and numba threads per shard (default: the worker's ``OMP_NUM_THREADS``). ``names``: the
    studies' names in error messages (default their positions). ``plans``: the shards of each study, as
    :func:`plan_studies` gives them for these ``shard`` and ``device`` (computed here when not given).
    Ctrl-C returns what finished, a study marked ``interrupted`` where shards are missing; a failing shard raises
    :class:`StudyFailed` holding the same.
    """
    import uuid

    from distributed import as_completed

    dev = None if device is None else str(device)
    plans = plans or plan_studies(studies, client, shard, dev)
    names = names or [f"study {i}" for i in range(len(studies))]
    run_id = uuid.uuid4().hex[:10]  # keys unique to this call: equal studies, or a rerun, never share a task
    futures = {}
    for i, (st, ranges) in enumerate(zip(studies, plans)):
        for rows in ranges:
            fut = client.submit(shard_task, st, rows.start, rows.stop, dev, threads,
                                key=f"torchtea-shard-{run_id}-{i}-{rows.start}-{rows.stop}")
            futures[fut.key] = (i, rows, fut)
    parts = [[] for _ in studies]
    total, done = len(futures), 0
    failure = None
    ac = as_completed([f for *_, f in futures.values()], with_results=False)
    try:
        for fut in ac:
            i, rows, _ = futures[fut.key]
            try:
                if fut.status == "cancelled":
                    raise RuntimeError("cancelled by the cluster")
                part = fut.result()  # raises the task's exception, or KilledWorker after allowed-failures deaths
            except Exception as exc:  # noqa: BLE001 -- every failure of a shard ends the study the same way
                failure = (names[i], rows, exc, _remote_traceback(fut))
                del futures[fut.key]
                break
            del futures[fut.key]  # only now: a Ctrl-C during the fetch leaves it pending, and cancelled below
            fut.release()  # the worker may drop it: a worker lost later does not recompute a fetched shard
            parts[i].append(part)
            done += 1
            if progress is not None:
                progress(done, total)
    except KeyboardInterrupt:
        pass
    finally:
        ac.clear()
        pending = [f for *_, f in futures.values()]
        if pending:
            client.cancel(pending)
    results = [_merge(st, p) for st, p in zip(studies, parts)]
    if failure is not None:
        name, rows, exc, tb = failure
        where = f"{name}, realisations {rows.start}–{rows.stop - 1}"
        raise StudyFailed(f"a shard failed on the cluster ({where}): {type(exc).__name__}: {exc}{tb}", results)
    return results


def _remote_traceback(fut) -> str:
    """The last lines of a failed task's traceback, as the worker raised it ('' where there is none)."""
    import traceback

    try:
        tb = fut.traceback()
    except Exception:  # noqa: BLE001 -- a cancelled or lost task has none
        return ""
    if tb is None:
        return ""
    lines = "".join(traceback.format_tb(tb)).rstrip().splitlines()
    return "\n  worker traceback (last lines):\n" + "\n".join(lines[-6:]) if lines else ""


def _merge(study: Study, parts: list[StudyResult]) -> StudyResult:
    """One study's finished shards; ``interrupted`` when any of its realisations is missing."""
    if not parts:
        return StudyResult.empty(study, interrupted=True)
    result = StudyResult.concat(parts)
    result.interrupted = result.finished < study.realisations
    return result


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
        # quiet: the worker processes log errors only (Ctrl-C's cancelled tasks are no news to the user)
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0",
                               silence_logs=logging.ERROR if quiet else logging.WARNING)
    return cluster, Client(cluster)


def run_study(study: Study, *, progress=None, device=None, client=None, shard: int | None = None,
              trajectories: bool = False) -> StudyResult:
    """Run a study; Ctrl-C keeps the finished chunks (or shards).

    Without ``client``, in this process chunk by chunk (:func:`run_range`); ``progress(done, total)`` counts
    realisations. With a Dask ``client`` (``distributed.Client``), as shards of ``shard`` realisations on its
    workers (:func:`run_studies`); ``progress(done, total)`` counts shards. ``device``:
    where the truths are simulated and the TEA runs (default the CPU, where the TEA is the compiled engine; on a
    cluster, each worker's device of that name); each realisation's draws come from its own CPU generator
    whatever the device, and the results come back to the CPU. ``trajectories``: also keep every realisation's
    full trajectories (``R × N`` × 7 float64 values; not with a client).
    """
    if client is not None:
        if trajectories:
            raise ValueError("run_study: full trajectories are not sent back from a cluster; run without client")
        return run_studies([study], client, shard=shard, device=device, progress=progress)[0]
    return run_range(study, 0, study.realisations, device=device, progress=progress, trajectories=trajectories)

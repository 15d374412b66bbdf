"""Independent tasks (a recording's channels): one after another here, or on a Dask cluster — submitted together,
gathered in their own order — each handed on as it is made (:func:`run_parts`, :func:`run_on_cluster`)."""
from __future__ import annotations

from collections.abc import Callable

import numpy as np

__all__ = ["run_parts", "run_on_cluster", "WorkerLines", "TaskFailed"]

#: Arguments larger than this (bytes of their arrays) are scattered to the workers before the tasks are submitted.
SCATTER_BYTES = 1 << 20


def _nbytes(x) -> int:
    if isinstance(x, np.ndarray):
        return x.nbytes
    if isinstance(x, dict):
        return sum(_nbytes(v) for v in x.values())
    if isinstance(x, (list, tuple)):
        return sum(_nbytes(v) for v in x)
    return 0


def _scattered(client, x):
    """``x`` itself, or a future of it on the workers when its arrays are large."""
    return client.scatter([x], hash=False)[0] if _nbytes(x) > SCATTER_BYTES else x


def run_parts(labels: list, here: Callable, *, done: dict | None = None, keep: Callable | None = None,
              progress: Callable | None = None, cluster: Callable | None = None) -> dict:
    """label → result for each of ``labels``, in their order: those in ``done`` (an interrupted run's, kept) as they
    are, the others made by ``here(label)`` one after another — or, given ``cluster``, by ``cluster(todo, made)``,
    all at once (:func:`run_on_cluster` with ``on_result=made``). ``keep(label, result)`` as each is made (to keep it
    at once), ``progress(done, total)`` after each, the parts taken from ``done`` counted first."""
    results = {label: done[label] for label in labels if done and label in done}
    todo = [label for label in labels if label not in results]

    def made(label, result) -> None:
        results[label] = result
        if keep is not None:
            keep(label, result)
        if progress is not None:
            progress(len(results), len(labels))

    if progress is not None and results:
        progress(len(results), len(labels))
    if cluster is not None and todo:
        cluster(todo, made)
    for label in todo if cluster is None else ():
        made(label, here(label))
    return {label: results[label] for label in labels}


class WorkerLines:
    """A task's ``progress(line)`` on a worker: each line goes back to the client as an event of ``topic``, with
    ``prefix`` (the channel's label) before it — how a channel's stages and steps reach the terminal as a run in this
    process prints them. Outside a worker (the same function run here) the lines go nowhere."""

    def __init__(self, topic: str, prefix: str):
        self.topic, self.prefix = topic, prefix

    def __call__(self, line: str) -> None:
        from distributed import get_worker

        try:
            worker = get_worker()
        except ValueError:
            return
        worker.log_event(self.topic, self.prefix + line)


class TaskFailed(RuntimeError):
    """A task that failed on the cluster for a reason of its own or killed its workers; ``done`` holds the results
    of the tasks that finished (label → result)."""

    def __init__(self, message: str, done: dict):
        super().__init__(message)
        self.done = done


def run_on_cluster(client, fn: Callable, calls: list, *, name: str = "task", progress: Callable | None = None,
                   on_result: Callable | None = None, lines: Callable | None = None,
                   lines_kw: str = "progress") -> dict:
    """``fn(*args, **kw)`` for each ``(label, args, kw)`` of ``calls`` as tasks of ``client``'s cluster (a
    ``distributed.Client``); ``progress(done, total)`` and ``on_result(label, result)`` as each finishes (so that a
    caller keeps each result at once). ``lines(text)``: each task gets a :class:`WorkerLines` as its ``lines_kw``
    argument, and what it says arrives here, prefixed with its label. Returns label → result in the order of
    ``calls``.

    A worker that dies (killed, out of memory) loses its running task, which the scheduler runs again on another
    worker (up to Dask's ``distributed.scheduler.allowed-failures`` times); the results are the same. A task that
    killed that many workers is a :class:`TaskFailed` naming it (the finished ones in ``done``); a task's own
    exception is raised here; either way the others are cancelled. Ctrl-C (or SIGTERM raised as ``KeyboardInterrupt``) cancels the tasks not finished, quietly,
    and is raised again: what finished went to ``on_result``."""
    import logging
    import uuid

    from distributed import KilledWorker, as_completed

    run = uuid.uuid4().hex[:10]
    topic = f"torchtea-{name}-{run}-lines"
    if lines is not None:
        client.subscribe_topic(topic, lambda event: lines(event[1]))
    futures = {}
    results = {}
    try:
        for label, args, kw in calls:
            # a channel's samples go to the workers as data, not inside the task graph (Dask warns above 10 MB)
            args = [_scattered(client, a) for a in args]
            kw = {k: _scattered(client, v) for k, v in kw.items()}
            if lines is not None:
                kw[lines_kw] = WorkerLines(topic, f"  {label}: ")
            fut = client.submit(fn, *args, key=f"torchtea-{name}-{run}-{label}", **kw)
            futures[fut.key] = (label, fut)
        for fut in as_completed([f for _, f in futures.values()]):
            label, _ = futures.pop(fut.key)
            try:
                results[label] = fut.result()
            except KilledWorker as exc:  # (the scheduler's count: a remote one's setting need not be this process's)
                raise TaskFailed(f"{name} of {label}: its task killed {exc.allowed_failures + 1} worker(s) in turn "
                                 "(out of memory?); the other tasks were cancelled", results) from None
            if on_result is not None:
                on_result(label, results[label])
            if progress is not None:
                progress(len(results), len(calls))
    except KeyboardInterrupt:
        for logger in ("distributed", "distributed.client", "distributed.scheduler", "distributed.worker"):
            logging.getLogger(logger).setLevel(logging.CRITICAL)  # (the cancelled tasks are not news to the user)
        raise
    finally:
        pending = [f for _, f in futures.values()]
        if pending:
            client.cancel(pending)
        if lines is not None:
            client.unsubscribe_topic(topic)
    return {label: results[label] for label, _, _ in calls}


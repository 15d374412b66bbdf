"""Independent tasks (a recording's channels) on a Dask cluster: submitted together, gathered in their own order."""
from __future__ import annotations

from collections.abc import Callable

import numpy as np

__all__ = ["run_on_cluster"]

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


def run_on_cluster(client, fn: Callable, calls: list, *, name: str = "task", progress: Callable | None = None) -> dict:
    """``fn(*args, **kw)`` for each ``(label, args, kw)`` of ``calls`` as tasks of ``client``'s cluster (a
    ``distributed.Client``); ``progress(done, total)`` as each finishes. Returns label → result in the order of
    ``calls``. A task's exception is raised here (the others cancelled); Ctrl-C cancels the tasks not finished and
    returns the finished ones."""
    import uuid

    from distributed import as_completed

    run = uuid.uuid4().hex[:10]
    futures = {}
    for label, args, kw in calls:
        # a channel's samples go to the workers as data, not inside the task graph (which Dask warns of above 10 MB)
        args = [_scattered(client, a) for a in args]
        kw = {k: _scattered(client, v) for k, v in kw.items()}
        fut = client.submit(fn, *args, key=f"torchtea-{name}-{run}-{label}", **kw)
        futures[fut.key] = (label, fut)
    results = {}
    try:
        for fut in as_completed([f for _, f in futures.values()]):
            label, _ = futures.pop(fut.key)
            results[label] = fut.result()
            if progress is not None:
                progress(len(results), len(calls))
    except KeyboardInterrupt:
        pass
    finally:
        pending = [f for _, f in futures.values()]
        if pending:
            client.cancel(pending)
    return {label: results[label] for label, _, _ in calls if label in results}

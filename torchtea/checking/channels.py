"""``check`` on every channel of a recording: the workflow ``torchtea check`` and ``torchtea export`` run (the
check, the effects added by hand, then the loop) — channel after channel in this process, or the channels as tasks
of a Dask cluster —, and its summary as text lines."""
from __future__ import annotations

from collections.abc import Callable, Iterable

import numpy as np

from ..core.tasks import run_parts
from ..core.threads import engine_threads
from ..noise.model import PAPER_MODEL
from .check import CheckResult, change_words, check
from .report import _fmt

__all__ = ["check_measurements", "check_channel", "summary_lines"]


def check_channel(values, h: float, model, *, inputs: dict | None = None, add: Iterable[str] = (), auto: bool = False,
                  max_steps: int = 6, strong: float | None = None, intervals: bool = True, levels: dict | None = None,
                  progress: Callable | None = None, threads: int | None = None, effects: tuple = (),
                  simplify: bool = True, fits: str = "auto", exclude_start: bool = False) -> CheckResult:
    """One channel's workflow: :func:`check` of ``model``, the ``add`` effects in order, then (``auto``) the loop
    (:meth:`CheckResult.auto`, taking away and swapping unless ``simplify`` is False). ``progress(line)``: each stage as it starts. ``threads``: numba's threads
    (:func:`~torchtea.core.threads.engine_threads`; torch runs on one). ``effects``: users' modules of effects to
    import first (:func:`torchtea.effects.import_effects`: a Dask worker has not imported them). ``fits``: how the loop
    fits (:func:`check`'s). ``exclude_start``: where the loop ends naming a stretch that differs at the record's start
    (:attr:`~.results.CheckRecord.stretch`: a sensor settling), that stretch is left out — its samples missing, as
    ``--exclude`` leaves one out — and the workflow runs again; the result's ``stretch`` says so (``left_out``)."""
    from ..effects import import_effects

    for name in effects:
        import_effects(name)

    def workflow(y):
        r = check(y, h, model=model, inputs=inputs, intervals=intervals, progress=progress, fits=fits,
                  **(levels or {}))
        for effect in add:
            r = r.add(effect, intervals=intervals, progress=progress)
        if auto:
            r = r.auto(max_steps=max_steps, strong=strong, intervals=intervals, progress=progress, simplify=simplify)
        return r

    with engine_threads(threads):
        r = workflow(values)
        st = r.stretch
        if exclude_start and auto and st is not None and st["from_s"] <= START_SLACK * len(values) * h:
            y = np.array(values, dtype=np.float64, copy=True)
            y[:int(np.ceil(st["to_s"] / h)) + 1] = np.nan
            if progress is not None:
                progress(f"leaving out the start-up stretch 0–{st['to_s']:.4g} s and checking again")
            first = r
            r = workflow(y)
            left = {**st, "from_s": 0.0, "left_out": True,
                    "words": (f"the start-up stretch 0–{st['to_s']:.4g} s was left out (--exclude-start): the check "
                              f"of the whole record ended {first.model.spec} with {st['spikes']} of its outliers "
                              "there, a stretch that differs; its samples are missing here")}
            r.notes.append(left["words"])
            r.stretch = left if r.stretch is None else r.stretch
            r.loop_end = f"{r.loop_end}; {left['words']}"
    return r


#: ``exclude_start`` leaves a stretch out only where it starts within this share of the record from its first sample.
START_SLACK = 0.02


def check_measurements(m, model=None, *, inputs: dict | None = None, add: Iterable[str] = (), auto: bool = False,
                       max_steps: int = 6, strong: float | None = None, intervals: bool = True, simplify: bool = True,
                       levels: dict | None = None, progress: Callable | None = None,
                       log: Callable | None = None, client=None, threads: int | None = None,
                       effects: tuple = (), stages: Callable | None = None, fits: str = "auto",
                       exclude_start: bool = False, done: dict | None = None, keep: Callable | None = None) -> dict:
    """Check each channel of ``m`` (:class:`~torchtea.sensors.measurements.Measurements`) with ``model`` (default
    :data:`PAPER_MODEL`): :func:`check_channel` with ``add``, ``auto``, ``max_steps``, ``strong``, ``simplify``; ``levels``: check's
    ``level``/``screen_level`` where given; ``exclude_start``: :func:`check_channel`'s. ``progress(done, total)`` after each channel; ``log(line)`` before each
    channel; ``stages(line)`` at each stage within one (in this process).

    ``client``: a ``distributed.Client``: each channel is one task on its workers (``threads`` numba threads each,
    default 1), the results in channel order and the same as in this process (every number a channel's check computes
    is its own: the kernels' parallel loops run whole parameter sets per thread, and torch runs on one thread either
    way); ``stages`` hears each channel's stages from the workers too. ``effects``: users' modules of effects each
    task imports first. ``done``: channels checked before (label → result: an interrupted run's, kept), not checked
    again; ``keep(label, result)`` as each channel finishes (to keep it at once). Returns label → result in channel
    order."""
    model = model or PAPER_MODEL
    kw = dict(inputs=inputs, add=tuple(add), auto=auto, max_steps=max_steps, strong=strong, intervals=intervals,
              simplify=simplify, levels=levels, effects=tuple(effects), fits=fits, exclude_start=exclude_start)
    channels = {c.label: c for c in m.channels}

    def here(label):
        c = channels[label]
        if log is not None:
            log(f"checking {c.label}, {c.title} ({m.samples} samples, model {model}) …")
        say = None if stages is None else (lambda line: stages(f"  {label}: {line}"))
        return check_channel(c.values, m.h, model, progress=say, threads=threads, **kw)

    def cluster(todo, made):
        from ..core.tasks import run_on_cluster

        if log is not None:
            log(f"checking {len(todo)} channels on the cluster ({sum(client.nthreads().values())} worker threads, "
                f"{m.samples} samples each, model {model}) …")
        calls = [(a, (channels[a].values, m.h, model), dict(threads=1 if threads is None else threads, **kw))
                 for a in todo]
        run_on_cluster(client, check_channel, calls, name="check", on_result=made, lines=stages)

    return run_parts(list(channels), here, done=done, keep=keep, progress=progress,
                     cluster=None if client is None else cluster)


def summary_lines(results: dict, titles: dict) -> list[str]:
    """The text summary of a recording's check (``results``: label → :class:`CheckResult`; ``titles``: label → the
    channel's title): per channel the model and its verdict, the loop's steps, each diagnostic, the suggestions and
    what is left unexplained."""
    lines = []
    for a, r in results.items():
        lines += _channel_lines(a, titles.get(a, a), r)
    return lines
def _channel_lines(a: str, title: str, r: CheckResult) -> list[str]:
    out = []
    head = f"{a} ({title}): {r.model.spec}: {'adequate' if r.adequate else 'NOT adequate'}"
    if len(r.steps) > 2 or r.loop_end:
        out.append(head)
        for k, st in enumerate(r.step_rows()):
            what = ("start" if k == 0 else
                    f"{change_words(st)} (gain {st['gain']:.1f}, repaired {', '.join(st['repaired']) or '—'})")
            out.append(f"  step {k}: {what}: nll/sample {st['nll_per_sample']:.5f}, psd misfit "
                       f"{_fmt(st['psd_misfit'], '.4f')}, adev misfit {_fmt(st['adev_misfit'], '.4f')}, failed "
                       f"{', '.join(st['failed']) or 'none'}")
        if r.loop_end:
            out.append(f"  loop end: {r.loop_end}")
        for t in r.ties:
            out.append(f"  tie: {t['words']}")
    else:
        if r.before is not None:
            b = r.before
            head += (f" (before, {b.model.spec}: nll/sample {b.metrics['nll_per_sample']:.5f}, failed "
                     f"{', '.join(b.failed) or 'none'}; now {r.metrics['nll_per_sample']:.5f})")
        out.append(head)
    for d in r.diagnostics:
        mark = "   " if d.passed is None else (" ok" if d.passed else "BAD")
        out.append(f"  {mark} {d.name:12s} {d.summary}")
    for s in r.suggestions:
        pars = ", ".join(f"{k} {v:.4g}" for k, v in s.parameters.items())
        out.append(f"  suggest {s.effect}: gain {s.gain:.1f} (ΔBIC), {pars}; repairs {', '.join(s.repairs) or '—'}"
                   + (f" — {s.note}" if s.note else ""))
    if not r.suggestions and r.failed_refits:
        out.append(f"  no suggestion: the screens of {', '.join(r.failed_refits)} passed, but their refits failed to "
                   "find what the screens saw (an optimiser's failure, not evidence against them)")
    if not r.suggestions and r.unconfirmed:
        out.append(f"  no suggestion: the Whittle screens of {', '.join(r.unconfirmed)} passed, but the exact "
                   "likelihood does not confirm them (below the model at the screens' own points; no gain refitted)")
    if not (r.suggestions or r.failed_refits or r.unconfirmed):
        out.append("  no suggestion: no effect of the library passes its screen")
    for u in r.unexplained:
        more = ([f"--add {', '.join(u['add_by_hand'])} by hand"] if u["add_by_hand"] else []) + (
            [f"not in the library: {', '.join(u['not_in_library'])}"] if u["not_in_library"] else [])
        if u.get("exclude"):
            more.append(f"a disturbance of the recording there? leave it out with {' '.join(u['exclude'][:3])}")
        out.append(f"  unexplained {u['diagnostic']}: {u['would_fit']}" + (f" ({'; '.join(more)})" if more else ""))
    return out

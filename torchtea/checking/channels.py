"""``check`` on every channel of a recording: the workflow ``torchtea check`` and ``torchtea export`` run (the
check, the effects added by hand, then the loop), and its summary as text lines."""
from __future__ import annotations

from typing import Callable, Iterable

from ..noise.model import PAPER_MODEL
from .check import CheckResult, check

__all__ = ["check_measurements", "summary_lines"]


def check_measurements(m, model=None, *, inputs: dict | None = None, add: Iterable[str] = (), auto: bool = False,
                       max_steps: int = 6, strong: float | None = None, intervals: bool = True,
                       levels: dict | None = None, progress: Callable | None = None,
                       log: Callable | None = None) -> dict:
    """Check each channel of ``m`` (:class:`~torchtea.sensors.measurements.Measurements`) with ``model`` (default
    :data:`PAPER_MODEL`), then add the ``add`` effects in order, then (``auto``) run the loop
    (:meth:`CheckResult.auto` with ``max_steps``, ``strong``). ``levels``: check's ``level``/``screen_level`` where
    given. ``progress(done, total)`` after each channel, ``log(line)`` before it. Returns label → result."""
    model = model or PAPER_MODEL
    results = {}
    for i, c in enumerate(m.channels):
        if log is not None:
            log(f"checking {c.label}, {c.title} ({m.samples} samples, model {model}) …")
        r = check(c.values, m.h, model=model, inputs=inputs, intervals=intervals, **(levels or {}))
        for effect in add:
            r = r.add(effect, intervals=intervals)
        if auto:
            r = r.auto(max_steps=max_steps, strong=strong, intervals=intervals)
        results[c.label] = r
        if progress is not None:
            progress(i + 1, len(m.channels))
    return results


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
                    f"+ {st['added']} (gain {st['gain']:.1f}, repaired {', '.join(st['repaired']) or '—'})")
            out.append(f"  step {k}: {what}: nll/sample {st['nll_per_sample']:.5f}, psd misfit {st['psd_misfit']:.4f}, "
                       f"adev misfit {st['adev_misfit']:.4f}, failed {', '.join(st['failed']) or 'none'}")
        if r.loop_end:
            out.append(f"  loop end: {r.loop_end}")
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
    if not r.suggestions:
        out.append("  no suggestion: no effect of the library passes its screen")
    for u in r.unexplained:
        more = ([f"--add {', '.join(u['add_by_hand'])} by hand"] if u["add_by_hand"] else []) + (
            [f"not in the library: {', '.join(u['not_in_library'])}"] if u["not_in_library"] else [])
        out.append(f"  unexplained {u['diagnostic']}: {u['would_fit']}" + (f" ({'; '.join(more)})" if more else ""))
    return out

"""The loop's policy (:meth:`~.check.CheckResult.auto`): add the best suggestion while it is strong enough, then take
away and swap while BIC falls and the model stays adequate (:mod:`.simplify`), and say why the loop ended."""
from __future__ import annotations

import copy
import time

from . import simplify as simplifying
from .ranking import CLOSE_BIC, STRONG_BIC
from .refits import near_fits

__all__ = ["run_loop", "loop_end"]


def run_loop(start, max_steps: int = 6, strong: float | None = None, simplify: bool = True, **kw):
    """The loop from the check ``start`` (:meth:`~.check.CheckResult.auto`, which documents it; ``kw`` passed on to
    each :meth:`~.check.CheckResult.add`): the last result, its :attr:`loop_end` and :attr:`ties` set."""
    strong = STRONG_BIC if strong is None else float(strong)
    # (a loop that adds and changes nothing still ends in a result of its own: this one, when it is not a step of
    # the loop's path, gets back what the search wrote on it)
    saved = (start.seconds, dict(start.timings), list(start.alternatives), start.loop_end, list(start.ties),
             start.stretch)
    res = start
    added = changes = 0
    stretch = None
    while True:
        while added < max_steps:
            sug, stretch = next_suggestion(res, stretch)
            if sug is None or (res.adequate and sug.gain < strong):
                break
            res = res.add(sug.effect, **kw)
            added += 1
        if not simplify or changes >= simplifying.MAX_CHANGES:
            break
        res.stretch = stretch  # (the simplification swaps in nothing that only papers over it)
        simpler = simplifying.simplify(res, **kw)
        if simpler is res:
            break
        res, changes = simpler, changes + 1
    if res is start:
        res = copy.copy(start)
        res.timings, res.alternatives = dict(start.timings), list(start.alternatives)
        start.seconds, start.timings, start.alternatives, start.loop_end, start.ties, start.stretch = saved
    if simplify:  # (the near candidates' refits counted in this step's seconds, as the simplification's are)
        t0 = time.perf_counter()
        res.near = near_fits(res, kw.get("progress"))
        dt = time.perf_counter() - t0
        res.seconds += dt
        res.timings["ties"] = res.timings.get("ties", 0.0) + dt
    res.ties = simplifying.ties(res, CLOSE_BIC) if simplify else []
    res.stretch = stretch
    res.loop_end = loop_end(res, added, changes, max_steps, strong)
    return res


def loop_end(res, added: int, changes: int, max_steps: int, strong: float) -> str:
    """Why the loop ended at ``res`` after ``added`` additions and ``changes`` changes, in words (check.json's
    ``loop_end``): adequate, stopped by ``max_steps``, or not adequate with what failed — a screen that passed and a
    refit that failed is said to be the optimiser's failure, a Whittle screen the exact likelihood does not confirm
    a disagreement of the two likelihoods — and the ties."""
    done = f"{added} effect(s) added" + (f", {changes} change(s) taking away or swapping" if changes else "")
    first, _ = next_suggestion(res, res.stretch)  # (what the loop would add next: no patch of a stretch)
    if res.adequate and first is not None and first.gain >= strong:
        end = (f"stopped after {max_steps} effects added (max_steps), adequate; "
               f"{first.effect} still gains {first.gain:.1f}")
    elif res.adequate:
        end = f"adequate after {done}"
        if first is not None:
            end += (f" ({first.effect} would still gain {first.gain:.1f} BIC, under the {strong:g} an adequate "
                    f"model's loop asks for)")
    elif first is None and (res.failed_refits or res.unconfirmed):
        end = f"not adequate after {done}: failing {', '.join(res.failed)}"
        if res.failed_refits:
            end += (f"; the screens of {', '.join(res.failed_refits)} passed, but their refits failed to "
                    "find what the screens saw — an optimiser's failure, not evidence that nothing "
                    "explains it")
        if res.unconfirmed:
            end += (f"; the Whittle screens of {', '.join(res.unconfirmed)} passed, but the exact "
                    "likelihood does not confirm them (below the model at the screens' own points, no "
                    "gain when refitted): the record is not what the cheap likelihood takes it for — "
                    "not stationary?")
    elif first is None:
        end = (f"not adequate after {done}, and no effect of the library passes its "
               f"screen and lowers BIC{' but patches of the stretch below' if res.stretch else ''}: failing "
               f"{', '.join(res.failed)}")
    else:
        end = (f"stopped after {max_steps} effects added (max_steps), not adequate: failing "
               f"{', '.join(res.failed)}")
    if res.stretch:
        st = res.stretch
        end += (f"; {st['spikes']} of the {st['of']} outliers the spikes screen found lie in {st['from_s']:.4g}–"
                f"{st['to_s']:.4g} s, where the innovations are larger than the model allows over the whole stretch "
                f"(the NIS window): a stretch that differs — a disturbance of the recording, a sensor settling? — "
                f"not spikes, and nothing located in it was added; leave it out with {st['exclude']}")
    if res.ties:
        end += "; cannot tell apart: " + "; ".join(t["words"] for t in res.ties)
    return end


#: Spikes are a stretch that differs, not outliers, when at least this many of those a suggestion found lie in one
#: stretch where the windowed NIS fails ...
STRETCH_SPIKES = 3
#: ... that stretch no longer than this share of the record.
STRETCH_SHARE = 0.5


def stretch_of(res, sug, known: dict | None = None) -> dict | None:
    """The stretch that differs that the suggestion ``sug`` of ``res`` would only paper over, or None: where it is
    spikes of which at least :data:`STRETCH_SPIKES` lie in one range where the windowed NIS fails
    (``res.failing_ranges_s``) no longer than :data:`STRETCH_SHARE` of the record, and fails there still with the
    spikes in the model (spikes that bring the window's NIS back into its band are spikes) — ``{"from_s", "to_s", "spikes"
    (inside), "of" (found), "exclude" (the flag that leaves it out)}` — or where a stretch is ``known`` and every time
    the suggestion's effect is located at (a spike's, a step's) lies in it (that stretch). The innovations there are
    larger than the model allows as a whole, not at a few samples: a disturbance of the recording (a sensor settling,
    a knock that rings), which spikes one by one, or steps at its edges, would only paper over."""
    times = simplifying.located_times(sug.fit, {sug.label})
    if known is not None and times and all(known["from_s"] <= t <= known["to_s"] for t in times):
        return known
    if sug.effect != "spikes":
        return None
    span = len(res.y) * res.h
    after = [r for d in sug.diagnostics if d.name == "nis" for r in d.ranges]  # (with the spikes in the model)
    for a, b in res.failing_ranges_s:
        a, b = float(a), float(b)
        inside = [t for t in times if a <= t <= b]
        still = any(lo < b and hi > a for lo, hi in after)  # (spikes that explain the window are spikes)
        if b - a <= STRETCH_SHARE * span and len(inside) >= STRETCH_SPIKES and still:
            return {"from_s": a, "to_s": b, "spikes": len(inside), "of": len(times),
                    "exclude": f"--exclude {a:.4g}:{b:.4g}"}
    return None


def next_suggestion(res, known: dict | None = None):
    """The suggestion the loop adds next from ``res`` and the stretch that differs, if one is ``known`` or stood in its
    way: the best suggestion, unless it would paper over such a stretch (:func:`stretch_of`) — then the best other
    one, or none."""
    stretch = known
    for sug in res.suggestions:  # (spikes in a stretch, wherever they rank, make it known first)
        if stretch is None and sug.effect == "spikes":
            stretch = stretch_of(res, sug)
    for sug in res.suggestions:
        if stretch_of(res, sug, stretch) is None:
            return sug, stretch
    return None, stretch

"""The loop's policy (:meth:`~.check.CheckResult.auto`): add the best suggestion while it is strong enough, then take
away and swap while BIC falls and the model stays adequate (:mod:`.simplify`), and say why the loop ended."""
from __future__ import annotations

import copy
import time

from . import simplify as simplifying
from .ranking import CLOSE_BIC, STRONG_BIC

__all__ = ["run_loop", "loop_end"]


def run_loop(start, max_steps: int = 6, strong: float | None = None, simplify: bool = True, **kw):
    """The loop from the check ``start`` (:meth:`~.check.CheckResult.auto`, which documents it; ``kw`` passed on to
    each :meth:`~.check.CheckResult.add`): the last result, its :attr:`loop_end` and :attr:`ties` set."""
    strong = STRONG_BIC if strong is None else float(strong)
    # (a loop that adds and changes nothing still ends in a result of its own: this one, when it is not a step of
    # the loop's path, gets back what the search wrote on it)
    saved = (start.seconds, dict(start.timings), list(start.alternatives), start.loop_end, list(start.ties))
    res = start
    added = changes = 0
    while True:
        while added < max_steps and res.suggestions and not (res.adequate and res.suggestions[0].gain < strong):
            res = res.add(res.suggestions[0].effect, **kw)
            added += 1
        if not simplify or changes >= simplifying.MAX_CHANGES:
            break
        simpler = simplifying.simplify(res, **kw)
        if simpler is res:
            break
        res, changes = simpler, changes + 1
    if res is start:
        res = copy.copy(start)
        res.timings, res.alternatives = dict(start.timings), list(start.alternatives)
        start.seconds, start.timings, start.alternatives, start.loop_end, start.ties = saved
    if simplify:  # (the near candidates' refits counted in this step's seconds, as the simplification's are)
        from .check import near_fits

        t0 = time.perf_counter()
        res.near = near_fits(res, kw.get("progress"))
        dt = time.perf_counter() - t0
        res.seconds += dt
        res.timings["ties"] = res.timings.get("ties", 0.0) + dt
    res.ties = simplifying.ties(res, CLOSE_BIC) if simplify else []
    res.loop_end = loop_end(res, added, changes, max_steps, strong)
    return res


def loop_end(res, added: int, changes: int, max_steps: int, strong: float) -> str:
    """Why the loop ended at ``res`` after ``added`` additions and ``changes`` changes, in words (check.json's
    ``loop_end``): adequate, stopped by ``max_steps``, or not adequate with what failed — a screen that passed and a
    refit that failed is said to be the optimiser's failure, a Whittle screen the exact likelihood does not confirm
    a disagreement of the two likelihoods — and the ties."""
    done = f"{added} effect(s) added" + (f", {changes} change(s) taking away or swapping" if changes else "")
    if res.adequate and res.suggestions and res.suggestions[0].gain >= strong:
        end = (f"stopped after {max_steps} effects added (max_steps), adequate; "
               f"{res.suggestions[0].effect} still gains {res.suggestions[0].gain:.1f}")
    elif res.adequate:
        end = f"adequate after {done}"
        if res.suggestions:
            s = res.suggestions[0]
            end += (f" ({s.effect} would still gain {s.gain:.1f} BIC, under the {strong:g} an adequate "
                    f"model's loop asks for)")
    elif not res.suggestions and (res.failed_refits or res.unconfirmed):
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
    elif not res.suggestions:
        end = (f"not adequate after {done}, and no effect of the library passes its "
               f"screen and lowers BIC: failing {', '.join(res.failed)}")
    else:
        end = (f"stopped after {max_steps} effects added (max_steps), not adequate: failing "
               f"{', '.join(res.failed)}")
    if res.ties:
        end += "; cannot tell apart: " + "; ".join(t["words"] for t in res.ties)
    return end

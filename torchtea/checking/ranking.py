"""How ``check`` orders its suggestions (:func:`rank`): by the fall of BIC, except that an effect repairing a failed
diagnostic it explains comes first within :data:`EXPLAIN_WINDOW`; and the thresholds of evidence the loop reads
(:data:`STRONG_BIC`, :data:`CLOSE_BIC`)."""
from __future__ import annotations

from ..noise.components import COMPONENTS
from .screens import screening_of

__all__ = ["rank", "EXPLAIN_WINDOW", "STRONG_BIC", "CLOSE_BIC"]


#: A suggestion that repairs a failed diagnostic its effect explains (its screening's ``explains``, :class:`~.screens.Screening`: a temperature effect
#: the temperature diagnostic, a line the lines test) is ranked before the others unless one
#: of them gains more than this much BIC (2 nats of likelihood ≈ a factor 150 of evidence at 10): where the data
#: cannot tell a lagged temperature from a drift, the effect that names the failure comes first. Chosen by replaying
#: the rule on the studies' saved cases (experiments/check/ranking.py).
EXPLAIN_WINDOW = 10.0


#: :meth:`~.check.CheckResult.auto` goes on past an adequate model while its best suggestion gains at least this much BIC
#: (a difference above 10 is "very strong" evidence: Kass & Raftery 1995).
STRONG_BIC = 10.0


#: Suggestions whose BIC gains differ by less than this are told apart by the record only weakly (a difference of
#: 2–6 is "positive", not "strong", evidence: Kass & Raftery 1995): the first one's note names the others.
CLOSE_BIC = 6.0


def rank(suggestions: list, failed: set, window: float = EXPLAIN_WINDOW) -> list:
    """The suggestions in the order check gives them: by BIC gain, except that one repairing a failed diagnostic its
    effect explains comes first where no other gains more than ``window`` above it (:data:`EXPLAIN_WINDOW`); such a
    one gets a note saying so. The first one's note also names the suggestions within :data:`CLOSE_BIC` of it
    (:attr:`~.results.Suggestion.close`)."""
    if not suggestions:
        return []
    best = max(s.gain for s in suggestions)

    def explained(s):
        return sorted(set(screening_of(COMPONENTS[s.effect]).explains) & set(failed) & set(s.repairs))

    def key(s):
        return bool(explained(s)) and s.gain >= best - window, s.gain

    out = sorted(suggestions, key=key, reverse=True)
    by_gain = max(suggestions, key=lambda s: s.gain)
    first = out[0]
    notes = []
    if first is not by_gain:
        notes.append(f"ranked first: it repairs the failed {', '.join(explained(first))} diagnostic its effect "
                     f"explains; {by_gain.effect} gains {by_gain.gain - first.gain:.1f} more BIC (within {window:g}: "
                     "the data do not tell them apart clearly)")
    first.close = [s.effect for s in out[1:] if s.gain >= first.gain - CLOSE_BIC]
    others = [s for s in out[1:] if s.gain >= first.gain - CLOSE_BIC and s is not by_gain]
    if others:
        notes.append("about as good on this record (BIC within " f"{CLOSE_BIC:g}): " +
                     ", ".join(f"{s.effect} (gain {s.gain:.1f})" for s in others) +
                     " — a longer record or another temperature history tells them apart")
    first.note = "; ".join(notes)
    return out

"""The loop's other half: after adding, take away and swap.

A loop that only adds keeps whatever it took first: a fractional part at order 1 with its pole at 0 standing in for
a random walk, a random walk added before the temperature effect the data hold. :func:`simplify` tries, from the
model a loop ended with, each **alternative** (:func:`alternatives`):

- each component **dropped**;
- each component replaced by the **simpler effects it contains** (:attr:`~torchtea.noise.components.Component.
  special_cases`: the fractional part by a random walk or a first-order Gauss–Markov bias);
- each **added** effect **swapped** for the other candidates that passed their screens at the step that added it.

Each alternative is fitted (its Whittle likelihood first: those whose Whittle BIC is more than
:data:`WHITTLE_WINDOW` above the model's are not refitted; then the exact likelihood from its Whittle modes and from
the model's own fit — on the long-record path every alternative, its exact likelihood evaluated at its Whittle modes
and the model's starts), and those with a BIC below the model's are checked in order of BIC (:func:`~.check.check`: the
diagnostics, the screens); the first that keeps the model adequate (or, for a model that was not, fails nothing
more) is kept, and the search goes on from there. Each kept change is a step of the loop like an addition.

Where an alternative's BIC is within :data:`~.check.CLOSE_BIC` of the final model's, the record cannot tell them
apart: a **tie** (:func:`ties`), named in the verdict."""
from __future__ import annotations

import copy
import math
import time
from dataclasses import dataclass

import numpy as np

from ..fitting.mle import Fit, bic, refine_best, whittle_fit
from ..fitting.plan import duration, tie_length
from ..fitting.starts import starts_of
from ..fitting.whittle_path import fits_exactly, polished, uses_exact, whittle_refine
from ..noise.components import COMPONENTS
from ..noise.grammar import token
from ..noise.model import NoiseModel, parse_model
from .models import REFIT_TOLERANCE, assess, extend, model_fit, with_intervals
from .screens import screening_of

__all__ = ["Alternative", "alternatives", "evaluate", "simplify", "ties", "WHITTLE_WINDOW", "MAX_CHANGES"]

#: An alternative whose Whittle BIC is more than this above the model's is not refitted by exact likelihood (the
#: two BICs agree to a few units on a stationary record; a tie is within 6).
WHITTLE_WINDOW = 20.0
#: At most this many changes (drops, swaps, special cases) in one loop (:meth:`~.check.CheckResult.auto`).
MAX_CHANGES = 4


@dataclass
class Alternative:
    """One model the simplification tries in place of the loop's: ``kind`` ``"drop"`` (the component ``removed``
    taken away), ``"simpler"`` (replaced by its special case ``added``) or ``"swap"`` (an added effect replaced by
    ``added``, another candidate that passed its screen at that step)."""

    kind: str
    removed: str
    added: str | None
    model: NoiseModel
    #: filled in by :func:`simplify`: the exact fit, its BIC, the Whittle BIC difference to the model's
    fit: Fit | None = None
    bic: float = math.inf
    whittle_delta: float = math.inf
    #: the diagnostics it failed where the model passed them, when its BIC was lower but it was not kept
    fails: list | None = None
    #: its Whittle fit (what :func:`~.check.check` of it would make first)
    whittle: object = None
    #: why it was not kept though its BIC is lower (the diagnostics it fails)
    rejected: str = ""

    @property
    def words(self) -> str:
        if self.kind == "drop":
            return f"without {self.removed}"
        how = "its special case " if self.kind == "simpler" else ""
        return f"{self.removed} → {how}{self.added}"

    def as_dict(self) -> dict:
        return {"kind": self.kind, "removed": self.removed, "added": self.added, "model": self.model.spec,
                "bic": None if not math.isfinite(self.bic) else self.bic,
                "whittle_bic_difference": None if not math.isfinite(self.whittle_delta) else self.whittle_delta,
                "rejected": self.rejected}


def _swaps(res) -> dict:
    """label → the other effects that passed their screens at the step of the loop that added the component
    ``label`` (still in the model under that label and name)."""
    out = {}
    steps = res.steps
    now = dict(res.model.components)
    for prev, cur in zip(steps, steps[1:]):
        old = {lb for lb, _ in prev.model.components}
        for lb, comp in cur.model.components:
            if lb in old or lb not in now or now[lb].name != comp.name:
                continue
            passed = [r.effect for r in prev.screens if r.passed and r.effect != comp.name]
            out.setdefault(lb, [])
            out[lb] += [e for e in passed if e not in out[lb]]
    return out


def alternatives(res) -> list[Alternative]:
    """The models :func:`simplify` tries in place of ``res.model`` (a :class:`~.check.CheckResult`), each once."""
    model = res.model
    tokens = [token(c) for _, c in model.components]
    names = [c.name for _, c in model.components]
    swaps = _swaps(res)
    out, seen = [], {model.spec}

    def push(kind, label, effect, build):
        try:
            m = build()
        except ValueError:  # (no stochastic component left; a filter with nothing before it; …)
            return
        if m.spec not in seen:
            seen.add(m.spec)
            out.append(Alternative(kind, label, effect, m))

    for i, (label, comp) in enumerate(model.components):
        rest = tokens[:i] + tokens[i + 1:]
        push("drop", label, None, lambda rest=rest: parse_model("+".join(rest)))
        for kind, effects in (("simpler", screening_of(comp).special_cases), ("swap", swaps.get(label, ()))):
            for e in effects:
                if e not in COMPONENTS or (e in names and not screening_of(COMPONENTS[e]).add_again):
                    continue
                # a special case in the component's place where a filter after it filtered it; else (and a swapped
                # effect) where it goes by itself (a low-pass after the stochastic parts), failing that in its place
                filtered = kind == "simpler" and any(c.kind == "filter" for _, c in model.components[i + 1:])
                push(kind, label, e, lambda e=e, f=filtered, rest=rest, i=i: _replaced(rest, tokens, i, e, f))
    return out


def _replaced(rest: list, tokens: list, i: int, effect: str, in_place: bool) -> NoiseModel:
    if not in_place:
        try:
            return extend(parse_model("+".join(rest)), effect)
        except ValueError:
            pass
    return parse_model("+".join(tokens[:i] + [effect] + tokens[i + 1:]))


def carried_labels(model: NoiseModel, alt: NoiseModel, removed: str) -> dict:
    """Which component of ``model`` each component of the alternative ``alt`` is (its label in ``alt`` → its label
    in ``model``), ``removed`` taken out: the k-th of a name in ``alt`` is the k-th of that name left in ``model``
    (labels are numbered anew: without the first of two lines, the second is ``sinusoid``). A component ``alt``
    adds is not in it."""
    left = {}
    for lb, c in model.components:
        if lb != removed:
            left.setdefault(c.name, []).append(lb)
    return {lb: left[c.name].pop(0) for lb, c in alt.components if left.get(c.name)}


def _whittle_bic(model, wf, n) -> float:
    """The model's BIC on its Whittle likelihood (its Whittle fit ``wf``; its references not counted)."""
    return bic(len([p for p in model.names if p not in model.references()]), n, float(wf.loglik[0]))


def _model_starts(alt: Alternative, res) -> list:
    """Starts of the alternative from the model's fit: its values for the parameters both have, each component the
    alternative adds at its starting strengths against the model's spectrum (``(name, values)`` each; none where a
    component it adds gives no strength)."""
    m, current, h = alt.model, res.fit.values, res.h
    carried = carried_labels(res.model, m, alt.removed)
    shared = {f"{lb}.{p.name}": current[f"{carried[lb]}.{p.name}"] for lb, c in m.components if lb in carried
              for p in c.params if f"{carried[lb]}.{p.name}" in current}
    if len(shared) == len(m.names):
        return [("the model's fit", shared)]
    starts = []
    new = [(lb, c) for lb, c in m.components if any(f"{lb}.{p.name}" not in shared for p in c.params)]
    for lb, comp in new:  # (its strengths against the model's spectrum at its fit)
        for k, st in enumerate(starts_of(comp).strengths(comp, lb, res.model, current, h, len(res.y))):
            v = {**shared, **st}
            if set(v) >= set(m.names):
                starts.append((f"the model's fit with {comp.name} at strength {k + 1}", v))
    return starts


def _fit(alt: Alternative, res, wf, polish: bool = True) -> Fit:
    """The alternative's exact fit: from its Whittle modes (:func:`~torchtea.fitting.mle.fit_series`) and from the
    model's fit (:func:`_model_starts`), the best kept; held estimates counted in BIC as the loop counts them.
    ``polish=False``: on the long-record path, the best point unrefined."""
    y, h, inputs = res.y, res.h, res.inputs
    m = alt.model
    starts = _model_starts(alt, res)
    refs = m.references() | set(m.located())
    fixed = [n for n in m.names if n in refs]
    if not fits_exactly(m, y, res.fits):  # (the long-record path: its Whittle
        # modes and the model's starts, by the exact ℓ there; without a spectrum, the starts evaluated)
        points = starts or [("its Whittle fit", _mode_values(m, wf, h))]
        if uses_exact(m, y, res.fits):
            best, _ = refine_best(m, y, h, points, inputs=inputs, fixed=fixed, must=[n for n, _ in points],
                                  refine=False)
        else:
            best, _ = whittle_refine(m, y, h, points, inputs=inputs, fixed=fixed, must=[n for n, _ in starts],
                                     whittle=wf, polish=polish, fits=res.fits)
        best = copy.deepcopy(best)
        best.count(m.held_estimates())
        return best
    best = model_fit(m, y, h, inputs=inputs, whittle=wf, intervals=False, fits="exact")
    if starts:
        try:
            other, _ = refine_best(m, y, h, starts, inputs=inputs, fixed=fixed, tolerance=REFIT_TOLERANCE)
        except (ValueError, RuntimeError):
            other = None
        if other is not None and other.loglik_exact > best.loglik_exact:
            best = other
    best = copy.deepcopy(best)
    best.count(m.held_estimates())
    return best


def _mode_values(model, wf, h) -> dict:
    """The values of the best mode of the Whittle fit ``wf`` (its means included)."""
    return {**{n: float(x) for n, x in zip(model.names, wf.values[0].tolist())}, **wf.means[0]}


def _as_counted(fit: Fit) -> Fit:
    """A shallow copy of ``fit`` with every held estimate of its model counted (its ``k`` as BIC counts it here,
    however the fit was made)."""
    f = copy.copy(fit)
    f.free = list(fit.free)
    f.ci95_method = dict(fit.ci95_method)
    f.count(fit.model.held_estimates())
    return f


def _bic_of(fit: Fit) -> float:
    return _as_counted(fit).bic_exact


def evaluate(res, progress=None) -> list[Alternative]:
    """Every alternative to ``res.model`` (:func:`alternatives`), fitted where its Whittle BIC is within
    :data:`WHITTLE_WINDOW` of the model's or the check is on the long-record path (``fit``, ``bic``); sorted by BIC,
    the lowest first."""
    y, h = res.y, res.h
    filled = np.where(np.isnan(y), np.nanmean(y), y)  # (as check fits the Whittle likelihood: CheckResult.whittle)
    inp_list = None if res.inputs is None else [res.inputs]
    n = res.fit.n
    alts = alternatives(res)
    if not alts:
        return []
    here = _whittle_bic(res.model, res.whittle or whittle_fit(res.model, [filled], h, inputs=inp_list), n)
    here_exact = _bic_of(res.fit)
    for a in alts:
        if progress is not None:
            progress(f"simplifying: {a.words} ({a.model.spec})")
        try:  # (the grid, and the model's own values: a resonance stays where the model has it)
            starts = [v for _, v in _model_starts(a, res)] if a.model.stationary else []
            a.whittle = whittle_fit(a.model, [filled], h, inputs=inp_list, starts=[starts] if starts else None)
        except (ValueError, RuntimeError) as exc:
            a.rejected = f"not fitted: {exc}"
            continue
        a.whittle_delta = _whittle_bic(a.model, a.whittle, n) - here
        if fits_exactly(a.model, y, res.fits):
            if a.whittle_delta > WHITTLE_WINDOW:
                continue  # (the window spares exact refits)
            a.fit = _fit(a, res, a.whittle)
        else:  # (the long-record path: every alternative evaluated at its best Whittle point, one exact pass — the
            # Whittle BICs of a ramp and a random walk disagree with the exact ones by more than the window — and
            # refined only where that comes within the window by the exact BIC)
            a.fit = _fit(a, res, a.whittle, polish=False)
            if _bic_of(a.fit) <= here_exact + WHITTLE_WINDOW and not uses_exact(a.model, y, res.fits):
                a.fit = polished(a.model, y, a.fit, h, inputs=res.inputs, fits=res.fits)
        a.bic = _bic_of(a.fit)
    return sorted(alts, key=lambda a: a.bic)


def located_times(fit: Fit, labels) -> list:
    """The times (s from the first sample) at which the components ``labels`` of ``fit``'s model are located (a
    spike's, a step's)."""
    m = fit.model
    return [v for n, v in fit.values.items()
            if n.split(".", 1)[0] in labels and "from the first sample" in m.param_spec(n).unit]


def patches(stretch: dict | None, model: NoiseModel, fit: Fit) -> bool:
    """Whether ``fit`` (of a model grown from ``model``) only papers over the ``stretch`` that differs (the loop's,
    :func:`~.loop.stretch_of`): every time its new components are located at lies in the stretch."""
    if stretch is None:
        return False
    new = {label for label, _ in fit.model.components} - {label for label, _ in model.components}
    times = located_times(fit, new)
    return bool(times) and all(stretch["from_s"] <= t <= stretch["to_s"] for t in times)


def simplify(res, **kw):
    """One change from the loop's result ``res`` (:class:`~.check.CheckResult`): the alternative with the lowest BIC
    below the model's that stays adequate (or, for a model that was not, fails nothing more), checked
    (:func:`~.check.check`, ``kw`` passed on) — its result, :attr:`~.check.CheckResult.change` saying what changed;
    or ``res`` itself when none is kept. Either way the result's ``alternatives`` are those tried from it."""
    progress = kw.get("progress")
    t0 = time.perf_counter()

    def spent(kept=None):  # (the search counted in this step's seconds: check.json's seconds cover the whole loop)
        dt = time.perf_counter() - t0 - (kept.seconds if kept is not None else 0.0)
        res.seconds += dt
        res.timings["simplify"] = res.timings.get("simplify", 0.0) + dt

    alts = evaluate(res, progress)
    res.alternatives = alts
    current = _bic_of(res.fit)
    for a in alts:
        if not a.bic < current:
            break
        if patches(res.stretch, res.model, a.fit):
            a.rejected = "only papers over the stretch that differs (everything it adds is located there)"
            continue
        if progress is not None:
            progress(f"checking {a.model.spec} ({a.words}: BIC {current - a.bic:.1f} lower)")
        fit = with_intervals(a.fit, res.y, res.h, res.inputs, res.fits) if kw.get("intervals", True) else a.fit
        new = res.recheck(a.model, fit, a.whittle, **kw)
        if new.adequate or (not res.adequate and set(new.failed) <= set(res.failed)):
            new.before = res
            new.change = {"kind": a.kind, "removed": a.removed, "added": a.added}
            spent(new)
            return new
        a.fails = sorted(set(new.failed) - set(res.failed))
        a.rejected = f"BIC {current - a.bic:.1f} lower, but fails {', '.join(a.fails)}"
    spent()
    return res


def ties(res, close: float) -> list[dict]:
    """What the record cannot tell apart from the final model ``res``: every model the loop fitted on its way — the
    alternatives tried at each step (:attr:`~.check.CheckResult.alternatives`), each step's suggestions, the steps
    themselves — whose BIC is within ``close`` above the final one's and that is adequate where it is; the final
    step's suggestions that gain less than ``close`` (the loop stopped short of them); the final model with an effect
    whose screen did not pass but whose refit is within ``close`` either side (:attr:`~.check.CheckResult.near`: a
    weak effect the loop never fitted on its way); and the final model's alternatives whose BIC is up to ``close``
    *lower* but that fail a diagnostic the model passes (``fails``: the record cannot tell whether the part they lack
    is there, or only what the diagnostic sees), and the final model without one of its effects up to ``close``
    *higher* that fails a diagnostic (``fails``: by BIC the record cannot tell; the diagnostic points to the effect).
    Each: ``kind`` (swap: one component for another; add: one more; drop:
    one fewer; other), ``effects``, ``model``, ``bic_difference`` (its BIC − the final model's; below 0 for a suggestion,
    a near effect or an alternative that fails a diagnostic), ``fails`` (those diagnostics, or none), the record length
    expected to tell them apart (``resolve_samples``, ``resolve_seconds``) and the sentence to show."""
    out = []
    here = _as_counted(res.fit)
    current = here.bic_exact
    n0 = res.fit.n
    pool = {}
    for step in res.steps:
        fits = [step.fit] + [s.fit for s in step.suggestions] + [a.fit for a in step.alternatives if a.fit is not None]
        for f in map(_as_counted, fits):
            b = f.bic_exact
            if f.model.spec != res.model.spec and (f.model.spec not in pool or b < pool[f.model.spec][0]):
                pool[f.model.spec] = (b, f)
    near = {f.model.spec for f in res.near.values()}
    for f in map(_as_counted, res.near.values()):
        if f.model.spec not in pool or f.bic_exact < pool[f.model.spec][0]:
            pool[f.model.spec] = (f.bic_exact, f)
    failing = {a.fit.model.spec: a.fails for a in res.alternatives if a.fails and a.fit is not None}
    final = [c.name for _, c in res.model.components]
    suggested = {s.fit.model.spec for s in res.suggestions}  # (the loop stopped short of them: gain under strong)
    for spec, (b, f) in sorted(pool.items(), key=lambda kv: kv[1][0]):
        d = b - current
        fails = failing.get(spec) if -close < d < 0.0 else None
        if not (math.isfinite(d) and (0.0 <= d < close or fails
                                      or ((spec in suggested or spec in near) and -close < d < 0.0))):
            continue
        other = [c.name for _, c in f.model.components]
        gone = [c for c in final if c not in other or final.count(c) > other.count(c)]
        new = [c for c in other if c not in final or other.count(c) > final.count(c)]
        worse_fails = []  # (the final model without one effect, higher by BIC within close, failing a diagnostic)
        if res.adequate and not fails:
            _, diags, _ = assess(f.model, f.values, res.y, res.h, res.inputs, res.level)
            worse_fails = [x.name for x in diags if x.passed is False]
            if worse_fails and not (len(gone) == 1 and not new and d >= 0.0):
                continue
        kind, effects, words = _tie_words(spec, gone, new, d, fails, worse_fails)
        tie = _with_length({"kind": kind, "effects": effects, "model": spec, "bic_difference": d, "words": words},
                           d, f.k - here.k, n0, res.h, close)
        tie["fails"] = list(fails or worse_fails)
        out.append(tie)
    return out


def _tie_words(spec: str, gone: list, new: list, d: float, fails, worse_fails: list) -> tuple[str, list, str]:
    """A tie's ``(kind, effects, words)`` from what the other model ``spec`` lacks (``gone``) and has more (``new``)
    than the final one, its BIC difference ``d``, the diagnostics it fails where it is lower by BIC (``fails``) or,
    the final model without one effect, higher (``worse_fails``)."""
    if len(gone) == 1 and len(new) == 1:
        kind, effects = "swap", [gone[0], new[0]]
        words = f"{gone[0]} or {new[0]}: this record cannot tell them apart (BIC within {abs(d):.1f})"
    elif not gone and len(new) == 1:
        kind, effects = "add", new
        words = (f"with or without {new[0]}: this record cannot tell (BIC {abs(d):.1f} "
                 f"{'higher' if d >= 0 else 'lower'} with it)")
    elif len(gone) == 1 and not new and worse_fails:
        kind, effects = "drop", gone
        words = (f"{gone[0]} or without it: by BIC this record cannot tell (BIC {d:.1f} higher without it); "
                 f"without it the model fails {', '.join(worse_fails)}, which points to {gone[0]}")
    elif len(gone) == 1 and not new:
        kind, effects = "drop", gone
        words = (f"{gone[0]} or without it: this record cannot tell (BIC {abs(d):.1f} "
                 f"{'higher' if d >= 0 else 'lower'} without it)")
    else:
        kind, effects = "other", sorted(set(gone) | set(new))
        words = f"{spec} fits about as well (BIC within {abs(d):.1f})"
    if fails:  # (lower by BIC, not kept: it fails what the model passes)
        if kind == "drop":
            what, whether = f"without {effects[0]} ({spec})", f"whether {effects[0]} is there"
        elif kind == "add":
            what, whether = f"with {effects[0]} ({spec})", f"whether {effects[0]} is there"
        elif kind == "swap":
            what, whether = f"{effects[1]} in place of {effects[0]} ({spec})", "which of the two it holds"
        else:
            what, whether = spec, "which of the two models it holds"
        words = (f"{what}: BIC {-d:.1f} lower, but it fails {', '.join(fails)}, which the model passes (kept for "
                 f"that); by BIC this record cannot tell {whether}")
    return kind, effects, words


#: A tie is told apart in most records once the expected BIC difference is this many times the strong-evidence level
#: (the difference's own spread is a few units: for a Gauss–Markov bias with τ at a tenth of a 60 s record, named a
#: tie with the random walk, 6 of 6 records simulated from the truth at the length this gives, 6.8 min, were told
#: apart, ΔBIC 11–27 in its favour: tests/test_plan.py).
RESOLVE_FACTOR = 2.0


def _with_length(tie: dict, d0: float, dk: int, n0: int, h: float, close: float) -> dict:
    """The tie with the record length at which it is expected to be told apart in most records
    (:func:`~torchtea.fitting.plan.tie_length` at :data:`RESOLVE_FACTOR` × ``close``: ``resolve_samples``,
    ``resolve_seconds``; None: the likelihoods do not part) and its words."""
    n = tie_length(d0, dk, n0, RESOLVE_FACTOR * close)
    tie["resolve_samples"] = n
    tie["resolve_seconds"] = None if n is None else n * h
    # (one model inside the other: the length assumes the larger one's extra effect is real — if it is not, only
    # the penalty grows, as ln n, and it takes far longer)
    nested = tie["kind"] in ("add", "drop")
    tie["words"] += (f"; about {duration(n * h)} of recording would tell them apart ({n / n0:.1f}× this one; "
                     f"expected BIC difference {RESOLVE_FACTOR * close:g}"
                     + (f", if {tie['effects'][0]} is there — if not, far longer)" if nested else ")") if n
                     else "; a longer record is not expected to tell (their likelihoods do not part)")
    return tie

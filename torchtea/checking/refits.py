"""How ``check`` refits: a model extended by an effect that passed its screen, by exact likelihood from several starts
(:func:`refit`), the model itself from a better point a refit showed (:func:`refined_model`,
:func:`better_model_fit`), a degenerate fit from the other modes of its likelihood (:func:`degenerate`,
:func:`refit_degenerate`); and what one check keeps between its passes (:class:`CheckRun`)."""
from __future__ import annotations

import copy
import math
import time

import numpy as np
import torch

from ..fitting.exact import gradient_supported
from ..fitting.mle import Fit, centred, exact_loglik, whittle_fit
from ..fitting.starts import starts_of
from ..fitting.whittle_path import fits_exactly
from . import models
from .models import REFIT_TOLERANCE
from .ranking import CLOSE_BIC
from .screening import ScreenRow, new_label

__all__ = ["CheckRun", "Clock", "refit", "refit_from", "held_fixed", "loglik_at", "refined_model", "better_model_fit",
           "degenerate", "refit_degenerate", "judge_no_gain", "BASE_RESTARTS", "BASE_SLACK", "NESTED_SLACK", "LONG_RECORD",
           "NULL_EFFECT", "FIT_FAILED_SLACK", "near", "near_fits", "NEAR_SLACK"]


#: How many times :func:`check` refines the model from a candidate's better point and starts again.
BASE_RESTARTS = 2


#: A logit beyond this puts a parameter at its bound (an order within 3·10⁻⁴ of 0 or 1, a pole at its stability
#: limit or at 0); a stochastic component whose spectrum is below this fraction of the model's at every frequency
#: has collapsed (:func:`degenerate`).
DEGENERATE_LOGIT, DEGENERATE_SHARE = 8.0, 1e-4


#: The denser grid of starts a degenerate fit is refitted from (orders × pole fractions).
DEGENERATE_ORDERS, DEGENERATE_FRACTIONS = (0.05, 0.3, 0.6, 0.95), (0.2, 0.95)


def degenerate(model, fit: Fit, h: float, n: int) -> list[str]:
    """Why the fit of ``model`` is degenerate (empty when it is not): a free bounded parameter at its bound (an order
    at 0 or 1; a pole at its stability limit — a pole at 0 is a model without one: logits beyond
    :data:`DEGENERATE_LOGIT`), a stochastic component collapsed (its
    spectrum below :data:`DEGENERATE_SHARE` of the model's at every Fourier frequency of ``n`` samples) — one
    component standing in for another, as the fractional part at order 1 with a collapsed white noise stands in for
    a band and the white noise at once."""
    out = []
    u = fit.u
    for i, name in enumerate(model.names):
        spec = model.param_spec(name)
        if name not in fit.free or u is None:
            continue
        if spec.kind == "bounded" and abs(float(u[i])) > DEGENERATE_LOGIT:
            out.append(f"{name} {fit.values[name]:.6g} at its bound")
        elif spec.kind == "fraction" and float(u[i]) > DEGENERATE_LOGIT:  # (a pole at 0 is no pole: not degenerate)
            out.append(f"{name} {fit.values[name]:.6g} at its stability limit")
    omega = torch.linspace(2 * math.pi / n, math.pi, 512, dtype=torch.float64)
    values = {k: [v] for k, v in fit.values.items()}
    parts = model.component_spectra(values, omega, h)
    total = sum(parts.values())
    for label, S in parts.items():
        if len(parts) > 1 and bool((S < DEGENERATE_SHARE * total).all()):
            out.append(f"{label} collapsed")
    return out


def refit_degenerate(run: CheckRun, model, fit: Fit, wf, intervals: bool) -> Fit | None:
    """The model refitted from its degenerate fit and from the modes of its Whittle likelihood, those of the first
    fit and those of a grid of other starts (:data:`DEGENERATE_ORDERS` × :data:`DEGENERATE_FRACTIONS`), the best kept (:func:`refine_best`); None when
    none is higher than ``fit`` by :data:`BASE_SLACK`."""
    y, h = run.y, run.h
    starts = [("the degenerate fit", dict(fit.values))]
    dense = whittle_fit(model, [run.filled], h, inputs=run.inp_list, orders=DEGENERATE_ORDERS,
                        fractions=DEGENERATE_FRACTIONS) if model.order_name is not None else wf
    for w, name in ((wf, "Whittle mode"), (dense, "dense-grid Whittle mode")):
        for k, (u, _, _) in enumerate(w.modes[0] if w.modes else []):
            v = {n: float(x) for n, x in zip(model.names, model.as_matrix(model.from_unconstrained(u, h))[0])}
            starts.append((f"{name} {k + 1}", {**v, **w.means[0]}))
    located = model.located()
    fixed = [n for n in model.names if n not in fit.free or n in located or n in model.references()]
    # every distinct mode refined, however far below the degenerate fit it starts: a converged fit's ℓ against
    # unrefined starts' says nothing of where they climb
    new, _ = models.refine(model, y, h, starts, fits=run.fits, inputs=run.inputs, fixed=fixed, must=["the degenerate fit"],
                    intervals=intervals, margin=math.inf, others=len(starts))
    if not new.loglik_exact > fit.loglik_exact + BASE_SLACK:
        return None
    new.count({n: w for n, w in located.items()})
    return new


class CheckRun:
    """What one :func:`check` keeps between its passes: the series, the filled series the Whittle likelihood reads,
    the cache of fits that do not depend on the model's exact fit (the Whittle fits, screens and refits from the same
    starts), the clock and the progress callback."""

    def __init__(self, y, h, inputs, level, progress, fits: str = "auto"):
        self.y, self.h, self.inputs, self.level, self.fits = y, h, inputs, level, fits
        self.inp_list = None if inputs is None else [inputs]
        self.filled = np.where(np.isnan(y), np.nanmean(y), y)
        self.cache = {}
        self.clock = Clock()
        self.progress = progress
        self.carry = {}

    def exact(self, model) -> bool:
        """Whether this check fits ``model`` by maximising the exact likelihood, else on the long-record path
        (:func:`~torchtea.fitting.whittle_path.fits_exactly`)."""
        return fits_exactly(model, self.y, self.fits)

    def say(self, line: str) -> None:
        if self.progress is not None:
            self.progress(line)


#: A refit of the extended model whose ℓ is more than this many nats below the model's fit has failed (the
#: extended model contains the model, so its maximum is at least the model's).
NESTED_SLACK = 0.5


#: Above this many samples a check ranks the passing candidates by the exact likelihood at the best of their starts
#: (a lower bound of each refit's gain: the screen's Whittle fit, the model's fit with the effect at the screen's
#: values, …) and refits only the best: on 2.16·10⁶ samples one exact refit takes minutes.
LONG_RECORD = 500_000


#: A point of the model's own likelihood better than its fit by more than this many nats shows that the fit was not
#: the model's maximum.
BASE_SLACK = 0.5


#: A refit whose new component adds less than this many nats to the likelihood at its other values has put the
#: effect at its null value (half the χ²₁ 95 % point): what it gained over the model is the model's own.
NULL_EFFECT = 1.92


#: A refit whose likelihood-ratio falls more than this short of half its screen's statistic, and that lowers no BIC,
#: has failed to find what the screen saw (the screen's statistic is a likelihood-ratio too, of a cheaper likelihood
#: or with the model held).
FIT_FAILED_SLACK = 5.0


def refit(run: CheckRun, model, alt, label, fit: Fit, wf, row: ScreenRow, fixed: list, refine: bool = True) -> Fit:
    """The extended model ``alt`` (the model with the component ``label``) fitted by exact likelihood from several
    starts (:func:`~torchtea.fitting.mle.refine_best`), the best kept:

    - the screen's start: the component's values from its screen, the model's from the screen's Whittle fit (a
      stochastic effect) or from the extended model's Whittle fit (a mean or modifier: what the effect distorted in
      the model's fit is undone there); and, for a stochastic effect, the model's exact fit with the component at
      the screen's values;
    - the nested start: the model at its fit with the effect where it vanishes (a stochastic one,
      :meth:`~torchtea.fitting.starts.Starts.vanishing`) or at the screen's estimate given the model (a mean),
      whose ℓ is the model's — a refit can only gain from it — and the same with the effect at its starting
      strengths;
    - for a stochastic effect, the extended model's own Whittle fit from its multi-start grid, each of its modes:
      where the model's fit is degenerate (its order at a bound, a variance collapsing, the fractional part standing
      in for the missing effect), the extended model's optimum lies elsewhere, and starting from the model's fit
      stays on the model's mode.

    The row's note says which start won when it was not the screen's. ``refine=False`` (a long record's candidates,
    :data:`LONG_RECORD`): the best start as it is, its exact ℓ evaluated, not maximised — a lower bound of the
    refit's, so its gain is too."""
    y, h, inputs, cache = run.y, run.h, run.inputs, run.cache
    comp = dict(alt.components)[label]
    new = [n for n in alt.names if n not in model.names]
    base = dict(fit.values)
    start = dict(row.start)
    if comp.kind in ("mean", "modifier"):
        starts = _mean_starts(run, model, alt, wf, base, start, new)
    else:
        starts = _stochastic_starts(run, model, alt, label, comp, row, base, start, new)
    earlier = run.carry.get(row.effect)
    if earlier is not None:  # the last step's refit of this effect: its values there, the model's here
        kept = {n: earlier.values[n] for n in new if n in earlier.values}
        if len(kept) == len(new):
            starts.append(("the effect at its last step's refit", {**base, **kept}))
    starts = [(name, v) for name, v in starts if set(v) >= set(alt.names)]
    key = ("refit" if refine else "evaluated", alt.spec,
           tuple((name, tuple(sorted((k, float(x)) for k, x in v.items()))) for name, v in starts))
    if key not in cache:
        # always refined: the starts anchored at the model's exact fit (the effect at the screen's values; where it
        # vanishes: the guarantee that the refit's ℓ is at least the model's); the others compete for one more place
        must = ["the model's fit with the effect at the screen's estimate", "the model's fit with the effect at the "
                "screen's values", "the model's fit with the effect vanishing"]
        if comp.kind in ("mean", "modifier"):
            must.append("the screen's start")
        cache[key] = models.refine(alt, y, h, starts, fits=run.fits, inputs=inputs, fixed=fixed, must=must,
                                   others=1, tolerance=REFIT_TOLERANCE, refine=refine)
    f2, tried = cache[key]
    if refine and comp.kind not in ("mean", "modifier") and not fixed and _short_of_screen(f2, fit, row):
        # what the screen saw not found from these starts (the Whittle likelihood's modes can lie where the exact
        # one has none): the extended model's own fit, from its own Whittle grid and exact multi-start
        own = ("own fit", alt.spec)
        if own not in cache:
            cache[own] = models.model_fit(alt, y, h, inputs=inputs, intervals=False, fits=run.fits)
        if cache[own].loglik > f2.loglik:
            f2 = cache[own]
            tried = [*tried, ("the extended model's own fit", float("nan"), f2.loglik)]
    f2 = copy.deepcopy(f2)
    winner = max(tried, key=lambda t: t[2])
    if winner[0] != starts[0][0]:
        there = next((t[2] for t in tried if t[0] == starts[0][0]), None)
        there = "not refined (its ℓ far below the others')" if there is None else (
            f"{there:.2f}" if math.isfinite(there) else "−∞: no finite likelihood")
        row.add_note(f"refitted from {len(tried)} starts; the best from {winner[0]} (ℓ {winner[2]:.2f}; from the "
                       f"screen's start {there})")
    if refine and run.exact(alt) and not f2.loglik >= fit.loglik - NESTED_SLACK:
        row.add_note(f"every refit ended below the model's ℓ {fit.loglik:.2f} (best {f2.loglik:.2f}): an optimiser "
                       "failure (the models are nested)")
    return f2


def _short_of_screen(f2: Fit, fit: Fit, row: ScreenRow) -> bool:
    """Whether the refit ``f2``'s likelihood-ratio over the model's ``fit`` falls :data:`FIT_FAILED_SLACK` short of half
    its screen's statistic (a likelihood-ratio of a cheaper likelihood or with the model held)."""
    stat = row.statistic
    return stat is not None and 2.0 * (f2.loglik - fit.loglik) < 0.5 * stat - FIT_FAILED_SLACK


def _mean_starts(run: CheckRun, model, alt, wf, base: dict, start: dict, new: list) -> list:
    """:func:`refit`'s starts for a mean or a modifier: the screen's values with the noise of the extended model's
    Whittle fit, the model's fit with the effect at the screen's estimate, the extended model's other Whittle
    modes."""
    h, cache = run.h, run.cache
    starts = []
    key = ("whittle", alt.spec)
    if key not in cache:  # (a mean's own values are its least squares there; its noise starts at the grid —
        # a mean the model lacked can have bent its order to the other mode of the order–pole ridge, and the
        # extended model's optimum is then on the first — and at the model's Whittle fit)
        cache[key] = whittle_fit(alt, [run.filled], h, inputs=run.inp_list, fractions=(0.5,),
                                 starts=[[{**{n: start[n] for n in new},
                                           **dict(zip(model.names, wf.values[0].tolist()))}]])
    wfa = cache[key]
    held = model.located()  # (a step's time, spikes: held where the model's fit has them)
    noise = {n: x for n, x in zip(alt.names, wfa.values[0].tolist()) if n in model.names and n not in held}
    starts.append(("the screen's start", {**start, **noise}))
    starts.append(("the model's fit with the effect at the screen's estimate",
                   {**base, **{n: start[n] for n in new if n in start}}))
    for k, (u, _, _) in enumerate(wfa.modes[0][1:] if wfa.modes else []):  # (its best is the screen's start's)
        other = {n: float(x) for n, x in zip(alt.names, alt.as_matrix(alt.from_unconstrained(u, h))[0])
                 if n in model.names and n not in held}
        starts.append((f"the extended model's Whittle mode {k + 2}", {**start, **other}))
    return starts


def _stochastic_starts(run: CheckRun, model, alt, label: str, comp, row: ScreenRow, base: dict, start: dict,
                       new: list) -> list:
    """:func:`refit`'s starts for a stochastic effect: the screen's, the model's fit with the effect at the screen's
    values, vanishing (:meth:`~torchtea.fitting.starts.Starts.vanishing`) and at its starting strengths, each mode of
    the extended model's Whittle fit (the screen's, else its own)."""
    y, h, cache = run.y, run.h, run.cache
    starts = []
    starts.append(("the screen's start", start))
    # the model's exact fit with the new component at the screen's values: the screen's Whittle fit moves the
    # model's own components too, which the exact likelihood need not follow (a resonance narrowed onto one
    # periodogram ordinate)
    starts.append(("the model's fit with the effect at the screen's values",
                   {**base, **{n: start[n] for n in new if n in start}}))
    vanish = starts_of(comp).vanishing(comp, label, model, base, h, len(y))
    if vanish:
        starts.append(("the model's fit with the effect vanishing", {**base, **vanish}))
    for k, s_ in enumerate(starts_of(comp).strengths(comp, label, model, base, h, len(y))):
        starts.append((f"the model's fit with the effect at strength {k + 1}", {**base, **s_}))
    modes, row.modes = row.modes, None  # (the Whittle screen's fits of the extended model)
    if modes is None and alt.stationary and not np.isnan(y).any():
        key = ("whittle", alt.spec)
        if key not in cache:
            cache[key] = whittle_fit(alt, [centred(model, y)], h, inputs=run.inp_list)
        wfa = cache[key]
        modes = [{**{n: float(x) for n, x in zip(alt.names, alt.as_matrix(alt.from_unconstrained(u, h))[0])},
                  **wfa.means[0]} for u, _, _ in (wfa.modes[0] if wfa.modes else [])]
    for k, v in enumerate(modes or []):
        starts.append((f"the extended model's Whittle mode {k + 1}", v))
    return starts


def refit_from(run: CheckRun, alt, evaluated: Fit, fixed: list) -> Fit:
    """A long record's best suggestion: its exact maximum from the start that ranked it."""
    fit, _ = models.refine(alt, run.y, run.h, [("the start that ranked it", dict(evaluated.values))], fits=run.fits,
                    inputs=run.inputs, fixed=fixed, must=["the start that ranked it"], tolerance=REFIT_TOLERANCE)
    return fit


def held_fixed(alt, label) -> tuple[dict, list]:
    """What the extended model's components hold (a temperature reference; a new line's frequency at the refined
    periodogram peak, which still counts as an estimated parameter in BIC) and the names its refit keeps fixed."""
    estimates = {**alt.held_estimates(label), **alt.located()}
    return estimates, [n for n in alt.names if n in alt.references() or n in estimates]


def loglik_at(model, values: dict, y, h, inputs) -> float:
    """The model's exact ℓ at ``values`` (−∞ where it is not finite)."""
    ll = exact_loglik(model, {n: [values[n]] for n in model.names}, centred(model, y), h, inputs=inputs)
    return float(ll[0]) if np.isfinite(ll[0]) else -math.inf


def refined_model(model, fit: Fit, f2: Fit, y, h, inputs, intervals: bool, fits: str = "auto") -> Fit | None:
    """The model refined from the values a refit gives its parameters (:func:`~.models.refine_one`), if that beats
    ``fit`` by more than :data:`BASE_SLACK` in the exact likelihood (else None)."""
    located = model.located()
    fixed = [n for n in model.names if n not in fit.free or n in located]
    new = models.refine_one(model, y, h, {n: f2.values[n] for n in model.names}, inputs=inputs, fixed=fixed,
                            metric=fit.hessian, intervals=intervals, fits=fits)
    new.count(located)
    return new if new.loglik_exact > fit.loglik_exact + BASE_SLACK else None


def better_model_fit(model, fit: Fit, refits: list, y, h, inputs, intervals: bool,
                     fits: str = "auto") -> Fit | None:
    """The model refined from the best of the refits' values of its own parameters, if that beats ``fit`` by
    more than :data:`BASE_SLACK` (else None)."""
    points = [{n: f.values[n] for n in model.names} for f in refits]
    vals = {n: [p[n] for p in points] for n in model.names}
    ll = exact_loglik(model, vals, centred(model, y), h, inputs=inputs)
    ll = np.where(np.isfinite(ll), ll, -np.inf)
    best = int(np.argmax(ll))
    if not ll[best] > fit.loglik_exact + BASE_SLACK:
        return None
    return refined_model(model, fit, refits[best], y, h, inputs, intervals, fits)


class Clock:
    def __init__(self):
        self.t = time.perf_counter()
        self.laps = {}

    def __call__(self, name):
        now = time.perf_counter()
        self.laps[name] = self.laps.get(name, 0.0) + now - self.t
        self.t = now


def judge_no_gain(run: CheckRun, row: ScreenRow, fit: Fit, alt, gain: float, lr: float) -> None:
    """Say in the screen's ``row`` why a passed screen's refit (of ``alt``; its likelihood-ratio ``lr`` over the model's
    ``fit``) lowered no BIC (``gain`` ≤ 0): where the screen's statistic was far larger, either the Whittle screen's
    own point lies below the model in the exact likelihood — the two likelihoods disagree on the record,
    ``not_confirmed`` — or the refit failed to find what the screen saw — an optimiser's failure, ``refit_failed``;
    otherwise the effect simply lowers no BIC."""
    failed = row.statistic is not None and lr < 0.5 * row.statistic - FIT_FAILED_SLACK
    at_screen = (loglik_at(alt, row.start, run.y, run.h, run.inputs)
                 if failed and row.test.startswith("Whittle") and set(row.start or ()) >= set(alt.names)
                 else math.inf)
    if at_screen < fit.loglik_exact - BASE_SLACK:
        # the screen's own point is below the model in the exact likelihood: the cheap likelihood's gain does
        # not hold in the exact one (the optimiser is not what failed)
        row.add_note(f"passed its screen (LR {row.statistic:.1f}) on the Whittle likelihood, but the "
                       "exact likelihood does not confirm it: at the screen's own point it is "
                       f"{fit.loglik_exact - at_screen:.1f} nats below the model's, and the exact refit gains only "
                       f"{lr:.1f} in 2ℓ (BIC gain {gain:.1f}) — the two likelihoods disagree on this record "
                       "(the Whittle likelihood takes it as stationary), which is no evidence for the effect; "
                       "not suggested")
        row.not_confirmed = True
    elif failed:
        row.add_note(f"passed its screen (LR {row.statistic:.1f}), but the exact refit gains only "
                       f"{lr:.1f} in 2ℓ (BIC gain {gain:.1f}): the refit failed to find what the screen "
                       "saw — an optimiser's failure, not evidence against the effect; not suggested")
        row.refit_failed = True
    else:
        row.add_note(f"passed the screen but the exact refit does not lower BIC (gain {gain:.1f}): "
                       "not suggested")


#: A candidate whose screen did not pass is refitted for the ties when its likelihood-ratio statistic puts the model
#: with it within the tie margin (:data:`~.ranking.CLOSE_BIC`) plus this much of BIC (the screen's statistic is the
#: Whittle likelihood's, or the exact one's at the model's noise values: the refit's can be a few units higher).
NEAR_SLACK = 3.0


def near(row: ScreenRow, model, n: int) -> bool:
    """Whether a screen that did not pass puts the model with its effect within the tie margin of BIC by its
    likelihood-ratio statistic ``LR``: k·ln n − LR below :data:`~.ranking.CLOSE_BIC` + :data:`NEAR_SLACK`, k the
    parameters the effect adds (its references not counted)."""
    if row.passed or row.statistic is None or "LR" not in row.test or not row.start:
        return False
    alt = models.extend(model, row.token)
    k = len([n_ for n_ in alt.names if n_ not in model.names and n_ not in alt.references()])
    return k * np.log(max(n, 2)) - float(row.statistic) < CLOSE_BIC + NEAR_SLACK


def near_fits(res, progress=None) -> dict:
    """The loop's last result's near candidates (:attr:`~.results.CheckRecord.near_rows`: screens that did not pass,
    whose statistic says the model with the effect would be within the tie margin) refitted as a passing one is
    (:func:`~.refits.refit`; evaluated at the best of its starts, not maximised, where the exact likelihood has no
    gradient to score with or on the long-record path): effect → its fit, kept where its exact BIC is within
    :data:`~.ranking.CLOSE_BIC` of the model's, either side. A weak effect the loop never fits still has its tie
    named (:func:`~.simplify.ties`)."""
    run = CheckRun(res.y, res.h, res.inputs, res.level, progress, res.fits)
    run.carry = dict(res.refits)
    model, fit, out = res.model, res.fit, {}
    for row in res.near_rows:
        alt = models.extend(model, row.token)
        label = new_label(model, alt)
        estimates, fixed = held_fixed(alt, label)
        cheap = run.exact(alt) and gradient_supported(alt, centred(alt, res.y)) is None
        run.say(f"fitting {alt.spec} for the ties")
        try:
            f2 = refit(run, model, alt, label, fit, res.whittle, copy.copy(row), fixed, refine=cheap)
        except (ValueError, RuntimeError):
            continue
        f2.count(estimates)
        if abs(f2.bic_exact - fit.bic_exact) < CLOSE_BIC:
            out[row.effect] = f2
    return out

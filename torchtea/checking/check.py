r"""``check``: fit a noise model, test it against the measurements, and rank the effects it is missing.

1. **Fit** the model by exact maximum likelihood (:func:`~torchtea.fitting.fit_series`) — on a long record by the
   Whittle likelihood, the exact one evaluated at each point the loop compares (``fits``,
   :mod:`torchtea.fitting.whittle_path`).
2. **Diagnose** it (:mod:`.diagnostics`): the standardised innovations in time, lag and frequency, the Allan
   deviation against the model's band, the innovations against the temperature. ``adequate`` when every
   diagnostic that ran passed at its level.
3. **Screen** every registered effect (:mod:`torchtea.effects`) that the model lacks, each with a test whose
   null distribution is known, so its p-value is calibrated — each effect's screen (:mod:`.screens`; what each
   built-in one computes in :data:`SCREENS`):

   - linear mean terms (``ramp``, ``temperature-bias``): the exact likelihood-ratio at the fitted noise
     parameters, by least squares of the innovations on the *whitened* regressor (χ²₁; mean and noise
     parameters are orthogonal in a Gaussian model, so holding the latter is asymptotically exact);
   - ``sinusoid``: the ``lines`` diagnostic — the largest innovation periodogram ordinate against its
     neighbours, over all frequencies;
   - ``drifting-line``: the same after dechirping the innovations at each rate of a grid
     (:func:`.diagnostics.chirp_search`), Bonferroni over frequencies and rates;
   - ``thermal-lag``: the largest exact likelihood-ratio over a grid of lags (whitened lagged temperatures), its
     p-value that of the maximum of the grid's correlated statistics (simulated; :func:`.diagnostics.scan_lr`);
   - ``step``: the exact likelihood-ratio at the best of a few candidate times (least-squares splits, the largest
     innovations), Bonferroni over the N − 1 splits;
   - ``resonance``: the band of the innovations' periodogram with the most power against the model (sums of 4–256
     ordinates, Gamma under the model; Bonferroni over positions and widths: :func:`.diagnostics.band_search`);
   - ``spikes``: the ``extremes`` diagnostic's exact law of the largest |z|; the spikes are every innovation beyond
     its bound, set aside and the filter rerun until none is new, and the statistic their joint exact LR (GLS sizes)
     — the count decides the component's spec token ``spikes:K`` (:func:`.screens.configure`);
   - stochastic components (``random-walk``, ``gauss-markov``, ``low-pass``, ``digital-filter``, ``quantisation``): the Whittle
     likelihood-ratio of the model with and without the component (the null value is on the boundary: ½χ²₀ + ½χ²₁,
     ½χ²₁ + ½χ²₂ for the two parameters of a Gauss–Markov bias);
   - ``temperature-order``: the exact likelihood-ratio over its slope alone, the other parameters held
     at the fit (χ²₁; holding them makes the test conservative);
   - a user's mean effect without a screen of its own: the exact likelihood-ratio at its least-squares values
     with the model held (χ²ₖ, conservative).

   An effect passes when its p-value is below ``screen_level`` / (number screened) — Bonferroni, so on data
   from the model the chance of any suggestion is at most ``screen_level``.
4. **Refit** each passing effect by exact maximum likelihood, started from the model's estimate, and score it
   by the fall of BIC (``gain`` = BIC before − BIC after, in units of −2 log-likelihood); re-run the
   diagnostics, and say which ones it repairs. Suggestions are sorted by gain, except that one repairing a failed
   diagnostic its effect explains comes first unless another gains more than :data:`EXPLAIN_WINDOW` (:func:`rank`).
"""
from __future__ import annotations

import copy
import time

import numpy as np
import torch

from ..fitting.mle import Fit, whittle_fit
from ..noise.components import COMPONENTS
from ..noise.model import PAPER_MODEL, parse_model
from . import screens
from .diagnostics import LEVEL
from .models import assess as _assess
from .models import extend, model_fit, with_intervals
from .ranking import CLOSE_BIC, EXPLAIN_WINDOW, STRONG_BIC, rank
from .refits import (
    BASE_RESTARTS,
    BASE_SLACK,
    LONG_RECORD,
    NULL_EFFECT,
    CheckRun,
    better_model_fit,
    degenerate,
    held_fixed,
    judge_no_gain,
    loglik_at,
    refined_model,
    refit,
    refit_degenerate,
    refit_from,
)
from .refits import near as near_candidate
from .results import CheckRecord, Suggestion, change_words, effect_parameters, read_check
from .screening import ScreenContext, new_label, screen_all
from .screens import NotScreened, screening_of
from .screens import candidates as candidates_all

__all__ = ["check", "CheckResult", "Suggestion", "read_check", "CANDIDATES", "extend", "SCREENS", "effect_parameters",
           "rank", "change_words", "degenerate", "EXPLAIN_WINDOW", "STRONG_BIC", "CLOSE_BIC"]

#: The built-in effects check screens, in the order of its table; :func:`~torchtea.checking.screens.candidates` gives
#: every registered one (a user's too) at call time.
CANDIDATES = candidates_all()
#: What each built-in effect's screen computes (:func:`.screens.screen_test`).
SCREENS = {name: screens.screen_test(COMPONENTS[name]) for name in CANDIDATES}


class CheckResult(CheckRecord):
    """What :func:`check` found (:class:`~.results.CheckRecord`) and the loop's verbs: :meth:`add` an effect and check
    again, :meth:`recheck` another model on the same series, :meth:`auto` the whole loop."""

    def add(self, effect: str, **kw) -> CheckResult:
        """Check the model with ``effect`` added (reusing the suggestion's fit when there is one): a name, the
        suggestion's model when it suggested that effect, else the component configured on these data
        (:func:`.screens.configure`: how many spikes); or a token ``name:argument``."""
        sug = next((s for s in self.suggestions if s.effect == effect), None)
        if sug is not None:
            alt = sug.fit.model
        elif ":" in effect or effect not in COMPONENTS:
            alt = extend(self.model, effect)
        else:
            ctx = ScreenContext(self.model, None, "", self.fit, self.innovations, self.diagnostics, self.y,
                                np.arange(len(self.y)) * self.h, self.h, self.inputs)
            try:
                alt = extend(self.model, screens.configure(COMPONENTS[effect], ctx))
            except NotScreened as exc:
                raise ValueError(f"cannot add {effect}: {exc}") from None
        start = next((s.fit for s in self.suggestions if s.fit.model.spec == alt.spec), None)
        carry = {e: f for e, f in self.refits.items() if e != effect}
        res = check(self.y, self.h, model=alt, inputs=self.inputs, level=self.level,
                    screen_level=self.screen_level, fit=start, carry=carry, fits=self.fits, **kw)
        res.before = self
        return res

    def recheck(self, model, fit: Fit | None = None, whittle=None, **kw) -> CheckResult:
        """:func:`check` of another ``model`` on the same series, inputs and levels, from its exact ``fit`` and Whittle
        fit when given and with this result's refits carried as starts (the loop's simplification, :mod:`.simplify`)."""
        return check(self.y, self.h, model=model, inputs=self.inputs, level=self.level,
                     screen_level=self.screen_level, fit=fit, carry=self.refits, whittle=whittle, fits=self.fits, **kw)

    def auto(self, max_steps: int = 6, strong: float | None = None, simplify: bool = True, **kw) -> CheckResult:
        """Run the loop to its end: add the best suggestion and check again (:meth:`add`, ``kw`` passed on), until
        no effect passes its screen and lowers BIC, the model is adequate and no suggestion gains ``strong`` BIC
        or more (default :data:`STRONG_BIC`), or ``max_steps`` effects were added; then (``simplify``) take away and
        swap (:func:`~.simplify.simplify`: each component dropped, replaced by its special cases, each added effect
        swapped for the others that passed their screens), one change at a time while BIC falls and the model stays
        adequate, adding again after each change — at most :data:`~.simplify.MAX_CHANGES` changes. Returns the last
        result (a new one, also where nothing was added or changed: this result is left as it is): its
        :attr:`steps` are the path, its :attr:`loop_end` says why it stopped, its :attr:`ties` what the record cannot
        tell apart from it.

        An adequate model still gets a very strong suggestion added: the eight diagnostics are omnibus tests, and
        one effect can hide another from them (a random walk takes up a step's level, a bias per °C the slow part
        of a walk) while the screen of the hidden one, a likelihood-ratio test against that one alternative, still
        sees it. Of 300 series drawn from models fitted to the bundled recording none that passed the diagnostics
        got any suggestion (experiments/check/false_alarm.md)."""
        from .loop import run_loop

        return run_loop(self, max_steps, strong, simplify, **kw)


def check(y, h: float, model=PAPER_MODEL, inputs: dict | None = None, *, level: float = LEVEL,
          screen_level: float = 0.05, candidates=None, fit: Fit | None = None, intervals: bool = True,
          progress=None, carry: dict | None = None, whittle=None, fits: str = "auto") -> CheckResult:
    """Fit ``model`` to the series ``y`` (NaN = missing, sample time ``h``), run the diagnostics and rank the
    missing effects (module docstring). ``inputs``: ``{"temperature": (N,)}`` (°C) when there is a temperature
    channel. ``candidates``: the effects to screen (default: every registered candidate,
    :func:`~torchtea.checking.screens.candidates`). ``fit``: an existing exact fit of ``model`` to ``y`` to use.
    ``intervals``: compute the intervals of
    the model's parameters and of the best suggestion's (the observed information, from exact gradients where the
    sensitivity filter applies); the other suggestions' parameters come without. ``progress(line)``: called with a
    short line as each stage starts (the CLI shows them). ``carry``: effect → an earlier step's refit of a model
    with that effect (:attr:`CheckResult.refits`): one more start for its refit here, the effect at the values it
    had there (what the loop knows carries to its next step). ``whittle``: the model's Whittle fit on this series
    (:func:`~torchtea.fitting.mle.whittle_fit` of the model on the mean-filled series, the default grid), already
    made (:attr:`CheckResult.whittle`; the loop's simplification fits each alternative so). ``fits``: how the loop
    fits (:data:`~torchtea.fitting.whittle_path.FITS`): ``"auto"`` by the exact likelihood up to
    :data:`~torchtea.fitting.whittle_path.WHITTLE_PATH_SAMPLES` samples and on the long-record path above (the Whittle
    likelihood, the exact one evaluated at the points compared, :mod:`torchtea.fitting.whittle_path`), ``"exact"``
    or ``"whittle"`` whatever the length (a model without a spectrum, or a series with gaps, is fitted exactly).

    The model's exact likelihood can have several maxima (a fractional order bent to ≈ 1 mimics a random walk
    or a low-pass). Every candidate's refit starts from several places (:func:`refit`); when a refit, with its new
    component taken away, is a better point of the model's own likelihood, the model's fit was not its maximum: the
    model is refined from there and checked again (at most :data:`BASE_RESTARTS` times), so that no gain is a mere
    escape from the model's local maximum; the notes say so."""
    t0 = time.perf_counter()
    model = parse_model(model)
    y = np.asarray(y, dtype=np.float64)
    if inputs is not None:  # numpy float64 whatever came in (lists, tensors)
        inputs = {k: np.asarray(torch.as_tensor(v, dtype=torch.float64).cpu(), dtype=np.float64).reshape(-1)
                  for k, v in inputs.items()}
        for k, v in inputs.items():
            if len(v) != len(y):
                raise ValueError(f"input channel {k!r} has {len(v)} values, the series {len(y)}")
    run = CheckRun(y, h, inputs, level, progress, fits)
    run.carry = dict(carry or {})
    say = run.say
    if whittle is not None:
        run.cache[("whittle", model.spec)] = whittle
    if ("whittle", model.spec) not in run.cache:
        say(f"fitting {model.spec} (Whittle)")
        run.cache[("whittle", model.spec)] = whittle_fit(model, [run.filled], h, inputs=run.inp_list)
    wf = run.cache[("whittle", model.spec)]
    how = "exact" if run.exact(model) else "Whittle"
    if fit is None or fit.model.spec != model.spec:
        if run.exact(model):
            say(f"fitting {model.spec} (exact likelihood)")
        fit = model_fit(model, y, h, inputs=inputs, whittle=wf, intervals=intervals, fits=fits)
    notes = []
    why = degenerate(model, fit, h, len(y))
    if why:
        say(f"refitting {model.spec} from other modes ({'; '.join(why)})")
        better = refit_degenerate(run, model, fit, wf, intervals)
        if better is not None:
            notes.append(f"the {how} fit of {model.spec} was degenerate ({'; '.join(why)}; ℓ {fit.loglik_exact:.2f}): "
                         f"refitted from the other modes of its likelihood before anything was screened, the best "
                         f"({better.notes[0] if better.notes else 'ℓ ' + format(better.loglik_exact, '.2f')}) kept")
            fit = better
        else:
            notes.append(f"the {how} fit of {model.spec} is degenerate ({'; '.join(why)}): refitted from the other "
                         "modes of its likelihood, none higher — the data put it there")
    run.clock("fit")
    for attempt in range(BASE_RESTARTS + 1):
        res, better = _check_once(run, model, fit, wf, screen_level, candidates, intervals,
                                  restart=attempt < BASE_RESTARTS)
        if better is None:
            break
        notes.append(f"the {how} fit of {model.spec} was not its maximum (ℓ {fit.loglik_exact:.2f}): {better[1]} (ℓ "
                     f"{better[0].loglik_exact:.2f} after refining), and the check was run from there")
        fit = better[0]
    res.notes[:0] = notes
    if not res.fit.converged:
        res.notes.append(f"the {how} fit did not report convergence: diagnostics are at the last iterate")
    res.seconds = time.perf_counter() - t0
    res.timings = run.clock.laps
    res.whittle = wf
    res.fits = fits
    return res


def _check_once(run: CheckRun, model, fit: Fit, wf, screen_level, candidates, intervals, restart: bool):
    """One pass of :func:`check` from the model's exact fit ``fit``: the diagnostics, the screens, the refits, the
    ranking and the best suggestion's intervals. Returns ``(result, None)``, or ``(None, (better fit, how))`` when
    ``restart`` and a refit shows that ``fit`` is not the model's maximum."""
    y, h, inputs, cache, clock = run.y, run.h, run.inputs, run.cache, run.clock
    run.say(f"diagnostics of {model.spec}")
    inn, diags, mets = _assess(model, fit.values, y, h, inputs, run.level)
    clock("diagnostics")
    effects = [c for c in (candidates_all() if candidates is None else candidates)
               if c in COMPONENTS and screening_of(COMPONENTS[c]).candidate]
    run.say(f"screening {len(effects)} effects")
    rows = screen_all(model, fit, wf, inn, diags, y, h, inputs, effects, cache)
    clock("screen")
    screened = [r for r in rows if r.p_value is not None]
    threshold = screen_level / max(1, len(screened))
    suggestions = []
    refits = []
    refitted = {}
    failed_before = {d.name for d in diags if d.passed is False}
    for row in screened:
        row.passed = bool(row.p_value < threshold)
        row.threshold = threshold
    passed = [r for r in screened if r.passed]
    long = run.exact(model) and len(y) > LONG_RECORD and len(passed) > 1
    for k, row in enumerate(passed):
        run.say(f"{'evaluating' if long else 'refitting'} {model.spec}+{row.effect} ({k + 1}/{len(passed)})")
        alt = extend(model, row.token)
        label = new_label(model, alt)
        estimates, fixed = held_fixed(alt, label)
        f2 = refit(run, model, alt, label, fit, wf, row, fixed, refine=not long)
        if long:
            row.add_note("a long record: its gain is the exact likelihood's at the best of its starts, not maximised "
                           "(a lower bound); the best suggestion alone is refitted")
        refits.append(f2)
        refitted[row.effect] = f2
        f2.count(estimates)
        gain = fit.bic_exact - f2.bic_exact
        lr = 2.0 * (f2.loglik_exact - fit.loglik_exact)
        if restart:  # the effect at its null value: what the refit gained is the model's own
            base_there = loglik_at(model, f2.values, y, h, inputs)  # the model's part of the refit
            if base_there > fit.loglik_exact + BASE_SLACK and f2.loglik_exact - base_there < NULL_EFFECT:
                better = refined_model(model, fit, f2, y, h, inputs, intervals, run.fits)
                if better is not None:
                    return None, (better, f"{row.effect}'s refit put {row.effect} at its null value (its "
                                          f"share of ℓ {f2.loglik_exact - base_there:.2f} nats), the rest at a better "
                                          "point of the model's own likelihood")
        if gain <= 0 and long:
            row.add_note(f"at the best of its starts the exact likelihood lowers no BIC (gain {gain:.1f}, a lower "
                           "bound: not maximised on a long record); not suggested")
            continue
        if gain <= 0:
            judge_no_gain(run, row, fit, alt, gain, lr)
            continue
        _, d2, m2 = _assess(alt, f2.values, y, h, inputs, run.level)
        repairs = sorted(failed_before & {d.name for d in d2 if d.passed})
        suggestions.append(Suggestion(row.effect, float(gain), row.p_value, row.test, f2, d2, m2, repairs,
                                      label))
    near = [copy.copy(r) for r in screened if near_candidate(r, model, fit.n)]
    for row in rows:
        row.start = row.modes = None
    clock("refits")
    if refits and restart:
        better = better_model_fit(model, fit, refits, y, h, inputs, intervals, run.fits)
        if better is not None:
            return None, (better, "a candidate's refit without its new component was a better point")
    suggestions = rank(suggestions, failed_before)
    if long and suggestions:  # the best suggestion refitted, from the start that ranked it
        suggestions = _refit_best(run, fit, suggestions, rows, failed_before)
    if intervals and suggestions:  # the best suggestion's intervals (the observed information)
        run.say(f"intervals of {suggestions[0].fit.model.spec}")
        suggestions[0].fit = with_intervals(suggestions[0].fit, y, h, inputs, run.fits)
    clock("intervals")
    return CheckResult(y, h, inputs, fit, inn, diags, mets, rows, suggestions, run.level, screen_level, 0.0, [],
                       refits=refitted, near_rows=near), None


def _refit_best(run: CheckRun, fit: Fit, suggestions: list, rows: list, failed_before: set) -> list:
    """On a long record (:data:`~.refits.LONG_RECORD`), the best suggestion — ranked by the exact likelihood at the
    best of its starts — refitted from the start that ranked it, its gain, diagnostics and repairs anew, its screen's
    row saying so; the suggestions ranked again."""
    top = suggestions[0]
    row = next(r for r in rows if r.effect == top.effect)
    run.say(f"refitting {top.fit.model.spec}")
    alt = top.fit.model
    estimates, fixed = held_fixed(alt, top.label)
    f2 = refit_from(run, alt, top.fit, fixed)
    f2.count(estimates)
    top.fit, top.gain = f2, float(fit.bic_exact - f2.bic_exact)
    _, top.diagnostics, top.metrics = _assess(alt, f2.values, run.y, run.h, run.inputs, run.level)
    top.repairs = sorted(failed_before & {d.name for d in top.diagnostics if d.passed})
    row.note = row.note.replace("; the best suggestion alone is refitted", "; refitted as the best suggestion")
    return rank(suggestions, failed_before)

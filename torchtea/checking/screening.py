"""The screening step of ``check``: every candidate effect screened against the model at its fit — each by its own
screen (:mod:`.screens`), the stochastic ones without one by the Whittle likelihood-ratio on one periodogram — and the
context a screen reads (:class:`ScreenContext`)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..fitting.mle import Fit, centred, exact_loglik, whittle_fit
from ..fitting.starts import starts_of
from ..noise.components import COMPONENTS
from ..noise.model import NoiseModel
from . import screens
from .diagnostics import LEVEL, Diagnostic, Innovations
from .models import extend
from .screens import NotScreened, boundary_logsf

__all__ = ["ScreenRow", "ScreenContext", "screen_all", "whittle_screens", "new_label", "SCREEN_TOLERANCE"]

#: A Whittle screen's fit has converged when it can gain less than this many nats (its starts that crawl below the
#: best at less than ten times this an iteration are left in the race): half the time of the fit to 10⁻⁶, the
#: likelihood-ratio within 0.25 of it on the bundled recording's gyroscopes (a screen passes at 10 and more); the
#: refit that follows starts from its modes and goes on.
SCREEN_TOLERANCE = 1e-3


def new_label(base: NoiseModel, alt: NoiseModel) -> str:
    old = {label for label, _ in base.components}
    return next(label for label, _ in alt.components if label not in old)


@dataclass
class ScreenRow:
    """One candidate effect's screen against the model: its test, likelihood-ratio statistic and p-value (None where
    it was not screened, and ``note`` says why), whether it passed at the Bonferroni ``threshold``, and what its refit
    found. ``start`` (the values the screen found, the model's with them) and ``modes`` (the Whittle screen's fits
    of the extended model) are the refit's starts, not written out."""

    effect: str
    test: str
    statistic: float | None = None
    p_value: float | None = None
    log10_p: float | None = None
    note: str = ""
    #: the spec token of the component screened (:func:`.screens.configure`: how many spikes); None where it could
    #: not be configured
    token: str | None = None
    passed: bool | None = None
    threshold: float | None = None
    #: the exact likelihood does not confirm what the Whittle screen saw (the two likelihoods disagree on the record)
    not_confirmed: bool = False
    #: the exact refit did not find what the screen saw (an optimiser's failure)
    refit_failed: bool = False
    start: dict | None = None
    modes: list | None = None

    def add_note(self, text: str) -> None:
        self.note = f"{self.note}; {text}" if self.note else text

    def as_dict(self) -> dict:
        """As ``check.json`` has it: the token where the effect was configured, whether it passed and the threshold
        where it was screened, ``not_confirmed`` and ``refit_failed`` where true."""
        out = {"effect": self.effect, "test": self.test, "statistic": self.statistic, "p_value": self.p_value,
               "log10_p": self.log10_p, "note": self.note}
        if self.token is not None:
            out["token"] = self.token
        if self.passed is not None:
            out.update(passed=self.passed, threshold=self.threshold)
        if self.not_confirmed:
            out["not_confirmed"] = True
        if self.refit_failed:
            out["refit_failed"] = True
        return out


@dataclass
class ScreenContext:
    """What an effect's screen (:mod:`.screens`) may use: the model and its fit, the
    model extended by the component (``alt``, the component labelled ``label``), the model's innovations and
    diagnostics at the fit, the series ``y`` (NaN = missing) with its times ``t`` (s) and sample time ``h``, and the
    input channels (``{"temperature": (N,)}`` or None)."""

    model: NoiseModel
    alt: NoiseModel
    label: str
    fit: Fit
    inn: Innovations
    diags: list
    y: np.ndarray
    t: np.ndarray
    h: float
    inputs: dict | None
    #: what a screen's ``configure`` found (:func:`.screens.configure`), for the screen to reuse
    memo: dict = field(default_factory=dict)
    #: the level of the extremes diagnostic, whose bound decides what an isolated outlier is (spikes)
    extremes_level: float = LEVEL

    def diagnostic(self, name: str) -> Diagnostic:
        return next(d for d in self.diags if d.name == name)

    def exact_loglik(self, model, values, inputs: dict | None = None):
        """The exact log-likelihood ``(B,)`` of ``model`` at ``values`` (a batch) on this series as the likelihood sees
        it (:func:`~torchtea.fitting.exact.centred`), with this check's inputs unless ``inputs`` are given: what a
        component's screen evaluates, so that it needs nothing of the fitting layer."""
        return exact_loglik(model, values, centred(model, self.y), self.h,
                            inputs=self.inputs if inputs is None else inputs)


def screen_all(model: NoiseModel, fit: Fit, wf, inn: Innovations, diags, y, h, inputs, effects,
               cache: dict | None = None) -> list[ScreenRow]:
    """Screening statistic, p-value and a starting point for each candidate effect: each component's own
    screen (:func:`.screens.run_screen`), the stochastic ones without one by the Whittle
    likelihood-ratio (all of them on one periodogram)."""
    t = np.arange(len(y)) * h
    out = []
    stochastic = []
    for effect in effects:
        comp = COMPONENTS[effect]
        row = ScreenRow(effect, screens.screen_test(comp))
        out.append(row)
        ctx = ScreenContext(model, None, "", fit, inn, diags, y, t, h, inputs)
        try:
            row.token = screens.configure(comp, ctx)
            alt = extend(model, row.token)
        except (ValueError, NotScreened) as exc:
            row.note = f"not screened: {exc}"
            continue
        label = new_label(model, alt)
        ctx.alt, ctx.label = alt, label
        missing = [k for k in comp.inputs if inputs is None or inputs.get(k) is None]
        reason = f"needs the {' and '.join(missing)} channel" if missing else screens.screening_of(comp).why_not(comp, model)
        if reason:
            row.note = f"not screened: {reason}"
            continue
        if screens.whittle_screened(comp):
            stochastic.append((row, alt))
            continue
        try:
            lr, logp, values, note = screens.run_screen(comp, ctx)
        except NotScreened as exc:
            row.note = f"not screened: {exc}"
            continue
        row.statistic, row.start, row.note = lr, {**dict(fit.values), **values}, note
        row.p_value, row.log10_p = float(math.exp(logp)), float(logp / math.log(10))
    if stochastic and np.isnan(y).any():
        for row, _ in stochastic:
            row.note = "not screened: the Whittle likelihood-ratio needs a complete series (missing samples)"
    elif stochastic:
        whittle_screens(model, wf, stochastic, y, h, inputs, {} if cache is None else cache)
    return out


def whittle_screens(model, base, rows_alts, y, h, inputs, cache: dict):
    """Whittle LR of each stochastic candidate against the model (its Whittle fit ``base``), on the same
    periodogram. They do not depend on the model's exact fit, so a check run again from a better exact fit takes
    them from ``cache`` (keyed by the candidate's spec)."""
    yy = centred(model, y)
    inp = None if inputs is None else [inputs]
    base_values = dict(zip(model.names, base.values[0].tolist()))
    for row, alt in rows_alts:
        key = ("whittle screen", alt.spec)
        if key in cache:
            _found(row, cache[key])
            continue
        label = new_label(model, alt)
        # the grid as well as the effect's strengths from the model's fit: a model that lacks a random walk (or a
        # low-pass) may have bent its fractional order to ≈ 1 to mimic it, and the extended model's optimum is then
        # far from the model's. Both kinds of start run to convergence in one batch and the best is kept (a user's
        # component may give no strength: the grid alone then)
        comp = dict(alt.components)[label]
        strengths = starts_of(comp).strengths(comp, label, model, base_values, h, len(y))
        wf = whittle_fit(alt, [yy], h, inputs=inp, fractions=(0.5,), tolerance=SCREEN_TOLERANCE, hessian=False,
                         starts=[[{**base_values, **o} for o in strengths]] if strengths else None)
        lr = max(0.0, 2.0 * float(wf.loglik[0] - base.loglik[0]))
        logp = boundary_logsf(lr, screens.screen_df(dict(alt.components)[label]))
        vals = dict(zip(alt.names, wf.values[0].tolist()))
        vals.update(wf.means[0])
        modes = [{**{n: float(x) for n, x in zip(alt.names, alt.as_matrix(alt.from_unconstrained(u, h))[0])},
                  **wf.means[0]} for u, _, _ in (wf.modes[0] if wf.modes else [])]
        found = dict(statistic=lr, p_value=float(math.exp(logp)), log10_p=float(logp / math.log(10)),
                     start=vals, modes=modes)
        cache[key] = found
        _found(row, found)


def _found(row: ScreenRow, found: dict) -> None:
    row.statistic, row.p_value, row.log10_p = found["statistic"], found["p_value"], found["log10_p"]
    row.start, row.modes = found["start"], found["modes"]

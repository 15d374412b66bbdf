r"""``check``: fit a noise model, test it against the measurements, and rank the effects it is missing.

1. **Fit** the model by exact maximum likelihood (:func:`~torchtea.fitting.fit_series`).
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
import math
import time
from dataclasses import dataclass, field

import numpy as np
import torch

from ..fitting.mle import Fit, centred, exact_loglik, fit_series, refine_best, refine_exact, whittle_fit
from ..fitting.starts import starts_of
from ..noise.components import COMPONENTS
from . import screens
from .screens import NotScreened
from ..noise.components import candidates as candidates_all
from ..noise.model import PAPER_MODEL, NoiseModel, parse_model
from .diagnostics import LEVEL, Diagnostic, Innovations
from .models import REFIT_TOLERANCE, extend, with_intervals
from .models import assess as _assess
from .screening import ScreenContext, new_label, screen_all

__all__ = ["check", "CheckResult", "Suggestion", "read_check", "CANDIDATES", "extend", "SCREENS", "effect_parameters", "rank",
           "change_words", "EXPLAIN_WINDOW", "CLOSE_BIC"]

#: The built-in effects check screens, in the order of its table; :func:`~torchtea.noise.components.candidates` gives
#: every registered one (a user's too) at call time.
CANDIDATES = candidates_all()
#: What each built-in effect's screen computes (:func:`.screens.screen_test`).
SCREENS = {name: screens.screen_test(COMPONENTS[name]) for name in CANDIDATES}


def effect_parameters(fit: Fit, label: str) -> dict:
    """The values of one component's parameters, named without the label (``frequency_hz``, ``sigma`` …)."""
    return {n.split(".", 1)[1]: fit.values[n] for n in fit.model.names if n.split(".", 1)[0] == label}


@dataclass
class Suggestion:
    effect: str
    gain: float
    p_value: float
    screen: str
    fit: Fit
    diagnostics: list
    metrics: dict
    repairs: list
    label: str
    #: why it is ranked where it is when that is not by its gain alone, and the effects that fit about as well
    note: str = ""
    #: (the first suggestion) the other suggestions whose gain is within :data:`CLOSE_BIC` of its own or above it:
    #: the record does not tell them apart clearly
    close: list = field(default_factory=list)

    @property
    def parameters(self) -> dict:
        return effect_parameters(self.fit, self.label)

    def as_dict(self) -> dict:
        ci = {n.split(".", 1)[1]: self.fit.ci95[n] for n in self.fit.model.names
              if n.split(".", 1)[0] == self.label}
        return {"effect": self.effect, "gain": self.gain, "p_value": self.p_value, "screen": self.screen,
                "model": self.fit.model.spec, "parameters": self.parameters, "ci95": ci,
                "after": dict(self.metrics, failed=[d.name for d in self.diagnostics if d.passed is False]),
                "repairs": self.repairs, "note": self.note, "close": self.close}


@dataclass
class CheckResult:
    """What :func:`check` found. ``diagnostics``: list of :class:`~.diagnostics.Diagnostic`; ``screens``: one dict
    per effect screened (its statistic, p-value, whether it passed); ``suggestions``: :class:`Suggestion` s, best
    first; ``before``: the result this one was built from by :meth:`add`."""

    y: np.ndarray
    h: float
    inputs: dict | None
    fit: Fit
    innovations: Innovations
    diagnostics: list
    metrics: dict
    screens: list
    suggestions: list
    level: float
    screen_level: float
    seconds: float
    notes: list = field(default_factory=list)
    before: "CheckResult | None" = None
    #: Seconds per stage (fit, diagnostics, screen, refits, intervals) and exact-likelihood evaluations.
    timings: dict = field(default_factory=dict)
    #: Why :meth:`auto` stopped here ("" when this result is not the end of a loop).
    loop_end: str = ""
    #: Every passing candidate's exact refit, effect → :class:`~torchtea.fitting.mle.Fit` (the suggestions' and those
    #: that lowered no BIC): the next step of the loop starts its refits of the same effects from them.
    refits: dict = field(default_factory=dict)
    #: What this step of the loop changed when it took something away or swapped it (:mod:`.simplify`):
    #: ``{"kind": "drop" | "simpler" | "swap", "removed": label, "added": effect or None}``; None for an addition.
    change: dict | None = None
    #: The alternatives the simplification tried from this model (:class:`~.simplify.Alternative`, lowest BIC first).
    alternatives: list = field(default_factory=list)
    #: (the end of a loop) what the record cannot tell apart from this model (:func:`~.simplify.ties`).
    ties: list = field(default_factory=list)
    #: The model's Whittle fit on this series (:func:`~torchtea.fitting.mle.whittle_fit`), which the loop's
    #: simplification compares its alternatives with.
    whittle: object = None

    @property
    def model(self) -> NoiseModel:
        return self.fit.model

    @property
    def failed(self) -> list[str]:
        """The diagnostics that ran and failed (their p-value below the level), by name."""
        return [d.name for d in self.diagnostics if d.passed is False]

    @property
    def adequate(self) -> bool:
        """Every diagnostic that ran passed: the data are consistent with the fitted model by each test."""
        return not self.failed

    @property
    def failed_refits(self) -> list[str]:
        """The effects whose screen passed but whose refit failed to find what the screen saw (an optimiser's
        failure, not evidence against the effect)."""
        return [r["effect"] for r in self.screens if r.get("refit_failed")]

    @property
    def unconfirmed(self) -> list[str]:
        """The effects whose Whittle screen passed but which the exact likelihood does not confirm: below the model
        at the screen's own point and no gain when refitted (the two likelihoods disagree on this record)."""
        return [r["effect"] for r in self.screens if r.get("not_confirmed")]

    @property
    def failing_ranges_s(self) -> list:
        out = []
        for d in self.diagnostics:
            if d.name == "nis":
                out += d.ranges
        return out

    def diagnostic(self, name: str) -> Diagnostic:
        return next(d for d in self.diagnostics if d.name == name)

    @property
    def unexplained(self) -> list[dict]:
        """The failed diagnostics that no suggestion repairs: where each fails, and which kind of effect would fit
        that signature (:meth:`~.diagnostics.Diagnostic.signature`): ``in_library`` the screened candidates among
        them (screened here, so they did not pass or did not lower BIC), ``add_by_hand`` those registered but not
        screened (``--add`` them), ``not_in_library`` the others; effects the model has already are left out."""
        repaired = set().union(*(s.repairs for s in self.suggestions)) if self.suggestions else set()
        out = []
        for d in self.diagnostics:
            if d.passed is not False or d.name in repaired:
                continue
            words, names = d.signature()
            have = {c.name for _, c in self.model.components}
            out.append({"diagnostic": d.name, "where": d.summary, "ranges": d.ranges, "unit": d.unit,
                        "would_fit": words,
                        # a failure located in time may be a disturbance of the recording: how to leave it out
                        "exclude": [f"--exclude {a:.4g}:{b:.4g}" for a, b in d.ranges if b > a]
                        if d.domain == "time" else [],  # (a change at one instant is no stretch to leave out)
                        "in_library": [n for n in names if n in COMPONENTS and COMPONENTS[n].candidate and (
                            n not in have or COMPONENTS[n].add_again)],
                        "add_by_hand": [n for n in names if n in COMPONENTS and not COMPONENTS[n].candidate
                                        and n not in have],
                        "not_in_library": [n for n in names if n not in COMPONENTS]})
        return out

    def add(self, effect: str, **kw) -> "CheckResult":
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
                    screen_level=self.screen_level, fit=start, carry=carry, **kw)
        res.before = self
        return res

    def recheck(self, model, fit: Fit | None = None, whittle=None, **kw) -> "CheckResult":
        """:func:`check` of another ``model`` on the same series, inputs and levels, from its exact ``fit`` and Whittle
        fit when given and with this result's refits carried as starts (the loop's simplification, :mod:`.simplify`)."""
        return check(self.y, self.h, model=model, inputs=self.inputs, level=self.level,
                     screen_level=self.screen_level, fit=fit, carry=self.refits, whittle=whittle, **kw)

    def auto(self, max_steps: int = 6, strong: float | None = None, simplify: bool = True, **kw) -> "CheckResult":
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
        from . import simplify as simplifying

        strong = STRONG_BIC if strong is None else float(strong)
        # (a loop that adds and changes nothing still ends in a result of its own: this one, when it is not a step of
        # the loop's path, gets back what the search wrote on it)
        saved = (self.seconds, dict(self.timings), list(self.alternatives), self.loop_end, list(self.ties))
        res = self
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
        if res is self:
            res = copy.copy(self)
            res.timings, res.alternatives = dict(self.timings), list(self.alternatives)
            self.seconds, self.timings, self.alternatives, self.loop_end, self.ties = saved
        res.ties = simplifying.ties(res, CLOSE_BIC) if simplify else []
        done = f"{added} effect(s) added" + (f", {changes} change(s) taking away or swapping" if changes else "")
        if res.adequate and res.suggestions and res.suggestions[0].gain >= strong:
            res.loop_end = (f"stopped after {max_steps} effects added (max_steps), adequate; "
                            f"{res.suggestions[0].effect} still gains {res.suggestions[0].gain:.1f}")
        elif res.adequate:
            res.loop_end = f"adequate after {done}"
            if res.suggestions:
                s = res.suggestions[0]
                res.loop_end += (f" ({s.effect} would still gain {s.gain:.1f} BIC, under the {strong:g} an adequate "
                                 f"model's loop asks for)")
        elif not res.suggestions and (res.failed_refits or res.unconfirmed):
            res.loop_end = f"not adequate after {done}: failing {', '.join(res.failed)}"
            if res.failed_refits:
                res.loop_end += (f"; the screens of {', '.join(res.failed_refits)} passed, but their refits failed to "
                                 "find what the screens saw — an optimiser's failure, not evidence that nothing "
                                 "explains it")
            if res.unconfirmed:
                res.loop_end += (f"; the Whittle screens of {', '.join(res.unconfirmed)} passed, but the exact "
                                 "likelihood does not confirm them (below the model at the screens' own points, no "
                                 "gain when refitted): the record is not what the cheap likelihood takes it for — "
                                 "not stationary?")
        elif not res.suggestions:
            res.loop_end = (f"not adequate after {done}, and no effect of the library passes its "
                            f"screen and lowers BIC: failing {', '.join(res.failed)}")
        else:
            res.loop_end = (f"stopped after {max_steps} effects added (max_steps), not adequate: failing "
                            f"{', '.join(res.failed)}")
        if res.ties:
            res.loop_end += "; cannot tell apart: " + "; ".join(t["words"] for t in res.ties)
        return res

    @property
    def steps(self) -> list:
        """The checks that led here by :meth:`add` or :meth:`auto`, the first one first and this one last."""
        chain, r = [], self
        while r is not None:
            chain.append(r)
            r = r.before
        return chain[::-1]

    def step_rows(self) -> list[dict]:
        """One dict per step of :attr:`steps`: the model, −ℓ per sample, the PSD and Allan misfits, the failed
        diagnostics and, from the second on, the effect added, the BIC it gained and the diagnostics it repaired
        (failed before, pass now) or broke."""
        rows, prev = [], None
        for r in self.steps:
            row = {"model": r.model.spec, "adequate": r.adequate, "nll_per_sample": r.metrics["nll_per_sample"],
                   "psd_misfit": r.metrics["psd_misfit"], "adev_misfit": r.metrics["adev_misfit"],
                   "failed": r.failed, "bic": r.fit.bic_exact, "seconds": r.seconds, "timings": r.timings}
            if prev is not None:
                row.update(added=_added(prev.model, r.model), removed=_removed(prev.model, r.model),
                           change=(r.change or {}).get("kind", "add"), gain=prev.fit.bic_exact - r.fit.bic_exact,
                           repaired=sorted(set(prev.failed) - set(r.failed)),
                           broke=sorted(set(r.failed) - set(prev.failed)))
            rows.append(row)
            prev = r
        return rows

    def as_dict(self) -> dict:
        return {"model": self.model.spec, "adequate": self.adequate,
                "base": dict(self.metrics, failed=self.failed, failing_ranges_s=self.failing_ranges_s,
                             parameters=self.fit.values, se=self.fit.se, ci95=self.fit.ci95,
                             ci95_method=self.fit.ci95_method, loglik=self.fit.loglik_exact, bic=self.fit.bic_exact,
                             observed=self.fit.n),
                "diagnostics": [d.as_dict() for d in self.diagnostics],
                "screens": self.screens,
                "suggestions": [s.as_dict() for s in self.suggestions],
                "level": self.level, "screen_level": self.screen_level,
                "seconds": sum(r.seconds for r in self.steps), "seconds_this_step": self.seconds,
                "notes": self.notes, "steps": self.step_rows(), "loop_end": self.loop_end,
                "unexplained": self.unexplained, "ties": self.ties,
                "alternatives": [a.as_dict() for a in self.alternatives]}


def _removed(before: NoiseModel, after: NoiseModel) -> str:
    """The component ``before`` has and ``after`` has not (by label), as its effect's name; "" when none."""
    new = {label for label, _ in after.components}
    return next((c.name for label, c in before.components if label not in new), "")


def change_words(row: dict) -> str:
    """A step of the loop in a few characters: ``+ resonance``, ``− fractional``, ``fractional → random-walk``."""
    added, removed = row.get("added") or "", row.get("removed") or ""
    if added and removed:
        return f"{removed} → {added}"
    return f"− {removed}" if removed else f"+ {added}"


def _added(before: NoiseModel, after: NoiseModel) -> str:
    """The component ``after`` has and ``before`` has not (by label: a second line is ``sinusoid2``), as its
    effect's name."""
    old = {label for label, _ in before.components}
    return next((c.name for label, c in after.components if label not in old), "")


def read_check(path) -> tuple[dict, dict]:
    """A ``check.json`` read back: the document and, per channel, the :class:`~torchtea.fitting.mle.Fit` of the model
    its loop ended with (``axes[label]["base"]``, as :meth:`CheckResult.as_dict` writes it: values, standard errors,
    intervals and how each was made, the exact log-likelihood, the samples it saw — missing ones not counted; a
    check.json from before that field: the recording's rows), for ``identify --from-check``, ``export`` and
    ``plan --from-check``. Raises ``ValueError`` naming the file when it is not a check document."""
    import json
    from pathlib import Path

    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
        n = int(doc["samples"])
        fits = {}
        for label, axis in doc["axes"].items():
            base = axis["base"]
            model = parse_model(axis["model"])
            se = {k: None if v is None else float(v) for k, v in base["se"].items()}
            ci = {k: None if v is None else (float(v[0]), float(v[1])) for k, v in base["ci95"].items()}
            loglik = float(base["loglik"])
            fits[label] = Fit(model, "exact", {k: float(v) for k, v in base["parameters"].items()}, se, ci,
                              dict(base["ci95_method"]), loglik, loglik, int(base.get("observed", n)),
                              [f"{lb}.{p.name}" for lb, c in model.components for p in c.params
                               if p.name not in c.held], True,
                              notes=[f"read from {path.name} (check's fit of the model its loop ended with)"])
    except FileNotFoundError:
        raise ValueError(f"{path}: no such file") from None
    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{path}: not a check.json ({type(exc).__name__}: {exc})") from None
    return doc, fits


def check(y, h: float, model=PAPER_MODEL, inputs: dict | None = None, *, level: float = LEVEL,
          screen_level: float = 0.05, candidates=None, fit: Fit | None = None, intervals: bool = True,
          progress=None, carry: dict | None = None, whittle=None) -> CheckResult:
    """Fit ``model`` to the series ``y`` (NaN = missing, sample time ``h``), run the diagnostics and rank the
    missing effects (module docstring). ``inputs``: ``{"temperature": (N,)}`` (°C) when there is a temperature
    channel. ``candidates``: the effects to screen (default: every registered candidate,
    :func:`~torchtea.noise.components.candidates`). ``fit``: an existing exact fit of ``model`` to ``y`` to use.
    ``intervals``: compute the intervals of
    the model's parameters and of the best suggestion's (the observed information, from exact gradients where the
    sensitivity filter applies); the other suggestions' parameters come without. ``progress(line)``: called with a
    short line as each stage starts (the CLI shows them). ``carry``: effect → an earlier step's refit of a model
    with that effect (:attr:`CheckResult.refits`): one more start for its refit here, the effect at the values it
    had there (what the loop knows carries to its next step). ``whittle``: the model's Whittle fit on this series
    (:func:`~torchtea.fitting.mle.whittle_fit` of the model on the mean-filled series, the default grid), already
    made (:attr:`CheckResult.whittle`; the loop's simplification fits each alternative so).

    The model's exact likelihood can have several maxima (a fractional order bent to ≈ 1 mimics a random walk
    or a low-pass). Every candidate's refit starts from several places (:func:`_refit`); when a refit, with its new
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
    run = _Run(y, h, inputs, level, progress)
    run.carry = dict(carry or {})
    say = run.say
    if whittle is not None:
        run.cache[("whittle", model.spec)] = whittle
    if ("whittle", model.spec) not in run.cache:
        say(f"fitting {model.spec} (Whittle)")
        run.cache[("whittle", model.spec)] = whittle_fit(model, [run.filled], h, inputs=run.inp_list)
    wf = run.cache[("whittle", model.spec)]
    if fit is None or fit.model.spec != model.spec:
        say(f"fitting {model.spec} (exact likelihood)")
        fit = fit_series(model, [y], h, method="exact", inputs=run.inp_list, profile=False, whittle=wf,
                         intervals=intervals)[0]
    notes = []
    why = degenerate(model, fit, h, len(y))
    if why:
        say(f"refitting {model.spec} from other modes ({'; '.join(why)})")
        better = _refit_degenerate(run, model, fit, wf, intervals)
        if better is not None:
            notes.append(f"the exact fit of {model.spec} was degenerate ({'; '.join(why)}; ℓ {fit.loglik:.2f}): "
                         f"refitted from the other modes of its likelihood before anything was screened, the best "
                         f"({better.notes[0] if better.notes else 'ℓ ' + format(better.loglik, '.2f')}) kept")
            fit = better
        else:
            notes.append(f"the exact fit of {model.spec} is degenerate ({'; '.join(why)}): refitted from the other "
                         "modes of its likelihood, none higher — the data put it there")
    run.clock("fit")
    for attempt in range(BASE_RESTARTS + 1):
        res, better = _check_once(run, model, fit, wf, screen_level, candidates, intervals,
                                  restart=attempt < BASE_RESTARTS)
        if better is None:
            break
        notes.append(f"the exact fit of {model.spec} was not its maximum (ℓ {fit.loglik:.2f}): {better[1]} (ℓ "
                     f"{better[0].loglik:.2f} after refining), and the check was run from there")
        fit = better[0]
    res.notes[:0] = notes
    if not res.fit.converged:
        res.notes.append("the exact fit did not report convergence: diagnostics are at the last iterate")
    res.seconds = time.perf_counter() - t0
    res.timings = run.clock.laps
    res.whittle = wf
    return res


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
    a band and the white noise at once (issue 44)."""
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


def _refit_degenerate(run: _Run, model, fit: Fit, wf, intervals: bool) -> Fit | None:
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
    new, _ = refine_best(model, y, h, starts, inputs=run.inputs, fixed=fixed, must=["the degenerate fit"],
                         intervals=intervals, margin=math.inf)
    if not new.loglik > fit.loglik + BASE_SLACK:
        return None
    new.count({n: w for n, w in located.items()})
    return new


class _Run:
    """What one :func:`check` keeps between its passes: the series, the filled series the Whittle likelihood reads,
    the cache of fits that do not depend on the model's exact fit (the Whittle fits, screens and refits from the same
    starts), the clock and the progress callback."""

    def __init__(self, y, h, inputs, level, progress):
        self.y, self.h, self.inputs, self.level = y, h, inputs, level
        self.inp_list = None if inputs is None else [inputs]
        self.filled = np.where(np.isnan(y), np.nanmean(y), y)
        self.cache = {}
        self.clock = _Clock()
        self.progress = progress
        self.carry = {}

    def say(self, line: str) -> None:
        if self.progress is not None:
            self.progress(line)


def _check_once(run: _Run, model, fit: Fit, wf, screen_level, candidates, intervals, restart: bool):
    """One pass of :func:`check` from the model's exact fit ``fit``: the diagnostics, the screens, the refits, the
    ranking and the best suggestion's intervals. Returns ``(result, None)``, or ``(None, (better fit, how))`` when
    ``restart`` and a refit shows that ``fit`` is not the model's maximum."""
    y, h, inputs, cache, clock = run.y, run.h, run.inputs, run.cache, run.clock
    run.say(f"diagnostics of {model.spec}")
    inn, diags, mets = _assess(model, fit.values, y, h, inputs, run.level)
    clock("diagnostics")
    effects = [c for c in (candidates_all() if candidates is None else candidates)
               if c in COMPONENTS and COMPONENTS[c].candidate]
    run.say(f"screening {len(effects)} effects")
    rows = screen_all(model, fit, wf, inn, diags, y, h, inputs, effects, cache)
    clock("screen")
    screened = [r for r in rows if r["p_value"] is not None]
    threshold = screen_level / max(1, len(screened))
    suggestions = []
    refits = []
    refitted = {}
    failed_before = {d.name for d in diags if d.passed is False}
    for row in screened:
        row["passed"] = bool(row["p_value"] < threshold)
        row["threshold"] = threshold
    passed = [r for r in screened if r["passed"]]
    long = len(y) > LONG_RECORD and len(passed) > 1
    for k, row in enumerate(passed):
        run.say(f"{'evaluating' if long else 'refitting'} {model.spec}+{row['effect']} ({k + 1}/{len(passed)})")
        alt = extend(model, row["token"])
        label = new_label(model, alt)
        estimates, fixed = _held_fixed(alt, label)
        f2 = _refit(run, model, alt, label, fit, wf, row, fixed, refine=not long)
        if long:
            _add_note(row, "a long record: its gain is the exact likelihood's at the best of its starts, not maximised "
                           "(a lower bound); the best suggestion alone is refitted")
        refits.append(f2)
        refitted[row["effect"]] = f2
        f2.count(estimates)
        gain = fit.bic_exact - f2.bic_exact
        lr = 2.0 * (f2.loglik_exact - fit.loglik_exact)
        if restart:  # the effect at its null value: what the refit gained is the model's own
            base_there = _loglik_at(model, f2.values, y, h, inputs)  # the model's part of the refit
            if base_there > fit.loglik + BASE_SLACK and f2.loglik - base_there < NULL_EFFECT:
                better = _refined_model(model, fit, f2, y, h, inputs, intervals)
                if better is not None:
                    return None, (better, f"{row['effect']}'s refit put {row['effect']} at its null value (its "
                                          f"share of ℓ {f2.loglik - base_there:.2f} nats), the rest at a better "
                                          "point of the model's own likelihood")
        if gain <= 0 and long:
            _add_note(row, f"at the best of its starts the exact likelihood lowers no BIC (gain {gain:.1f}, a lower "
                           "bound: not maximised on a long record); not suggested")
            continue
        if gain <= 0:
            failed = row["statistic"] is not None and lr < 0.5 * row["statistic"] - FIT_FAILED_SLACK
            at_screen = (_loglik_at(alt, row["start"], y, h, inputs)
                         if failed and row["test"].startswith("Whittle") and set(row.get("start") or ()) >= set(alt.names)
                         else math.inf)
            if at_screen < fit.loglik - BASE_SLACK:
                # the screen's own point is below the model in the exact likelihood: the cheap likelihood's gain does
                # not hold in the exact one (the optimiser is not what failed)
                _add_note(row, f"passed its screen (LR {row['statistic']:.1f}) on the Whittle likelihood, but the "
                               "exact likelihood does not confirm it: at the screen's own point it is "
                               f"{fit.loglik - at_screen:.1f} nats below the model's, and the exact refit gains only "
                               f"{lr:.1f} in 2ℓ (BIC gain {gain:.1f}) — the two likelihoods disagree on this record "
                               "(the Whittle likelihood takes it as stationary), which is no evidence for the effect; "
                               "not suggested")
                row["not_confirmed"] = True
            elif failed:
                _add_note(row, f"passed its screen (LR {row['statistic']:.1f}), but the exact refit gains only "
                               f"{lr:.1f} in 2ℓ (BIC gain {gain:.1f}): the refit failed to find what the screen "
                               "saw — an optimiser's failure, not evidence against the effect; not suggested")
                row["refit_failed"] = True
            else:
                _add_note(row, f"passed the screen but the exact refit does not lower BIC (gain {gain:.1f}): "
                               "not suggested")
            continue
        _, d2, m2 = _assess(alt, f2.values, y, h, inputs, run.level)
        repairs = sorted(failed_before & {d.name for d in d2 if d.passed})
        suggestions.append(Suggestion(row["effect"], float(gain), row["p_value"], row["test"], f2, d2, m2, repairs,
                                      label))
    for row in rows:
        for k in ("metric", "start", "modes"):
            row.pop(k, None)
    clock("refits")
    if refits and restart:
        better = _better_model_fit(model, fit, refits, y, h, inputs, intervals)
        if better is not None:
            return None, (better, "a candidate's refit without its new component was a better point")
    suggestions = rank(suggestions, failed_before)
    if long and suggestions:  # the best suggestion refitted, from the start that ranked it
        top = suggestions[0]
        row = next(r for r in rows if r["effect"] == top.effect)
        run.say(f"refitting {top.fit.model.spec}")
        alt = top.fit.model
        estimates, fixed = _held_fixed(alt, top.label)
        f2 = _refit_from(run, alt, top.fit, fixed)
        f2.count(estimates)
        top.fit, top.gain = f2, float(fit.bic_exact - f2.bic_exact)
        _, top.diagnostics, top.metrics = _assess(alt, f2.values, y, h, inputs, run.level)
        top.repairs = sorted(failed_before & {d.name for d in top.diagnostics if d.passed})
        row["note"] = row["note"].replace("; the best suggestion alone is refitted", "; refitted as the best suggestion")
        suggestions = rank(suggestions, failed_before)
    if intervals and suggestions:  # the best suggestion's intervals (the observed information)
        run.say(f"intervals of {suggestions[0].fit.model.spec}")
        suggestions[0].fit = with_intervals(suggestions[0].fit, y, h, inputs)
    clock("intervals")
    return CheckResult(y, h, inputs, fit, inn, diags, mets, rows, suggestions, run.level, screen_level, 0.0, [],
                       refits=refitted), None


#: A suggestion that repairs a failed diagnostic its effect explains (``Component.explains``: a temperature effect
#: the temperature diagnostic, a line the lines test) is ranked before the others unless one
#: of them gains more than this much BIC (2 nats of likelihood ≈ a factor 150 of evidence at 10): where the data
#: cannot tell a lagged temperature from a drift, the effect that names the failure comes first. Chosen by replaying
#: the rule on the studies' saved cases (experiments/check/ranking.py).
EXPLAIN_WINDOW = 10.0


#: :meth:`CheckResult.auto` goes on past an adequate model while its best suggestion gains at least this much BIC
#: (a difference above 10 is "very strong" evidence: Kass & Raftery 1995).
STRONG_BIC = 10.0


#: Suggestions whose BIC gains differ by less than this are told apart by the record only weakly (a difference of
#: 2–6 is "positive", not "strong", evidence: Kass & Raftery 1995): the first one's note names the others.
CLOSE_BIC = 6.0


def rank(suggestions: list, failed: set, window: float = EXPLAIN_WINDOW) -> list:
    """The suggestions in the order check gives them: by BIC gain, except that one repairing a failed diagnostic its
    effect explains comes first where no other gains more than ``window`` above it (:data:`EXPLAIN_WINDOW`); such a
    one gets a note saying so. The first one's note also names the suggestions within :data:`CLOSE_BIC` of it
    (:attr:`Suggestion.close`)."""
    if not suggestions:
        return []
    best = max(s.gain for s in suggestions)

    def explained(s):
        return sorted(set(COMPONENTS[s.effect].explains) & set(failed) & set(s.repairs))

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


def _add_note(row: dict, text: str) -> None:
    row["note"] = f"{row['note']}; {text}" if row.get("note") else text


#: A refit of the extended model whose ℓ is more than this many nats below the model's fit has failed (the
#: extended model contains the model, so its maximum is at least the model's).
NESTED_SLACK = 0.5
#: Above this many samples a check ranks the passing candidates by the exact likelihood at the best of their starts
#: (a lower bound of each refit's gain: the screen's Whittle fit, the model's fit with the effect at the screen's
#: values, …) and refits only the best: on 2.16·10⁶ samples one exact refit takes minutes (issue 44).
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


def _refit(run: _Run, model, alt, label, fit: Fit, wf, row: dict, fixed: list, refine: bool = True) -> Fit:
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
    start = dict(row["start"])
    row.pop("metric", None)
    starts = []
    if comp.kind in ("mean", "modifier"):
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
    else:
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
        modes = row.pop("modes", None)  # (the Whittle screen's fits of the extended model)
        if modes is None and alt.stationary and not np.isnan(y).any():
            key = ("whittle", alt.spec)
            if key not in cache:
                cache[key] = whittle_fit(alt, [centred(model, y)], h, inputs=run.inp_list)
            wfa = cache[key]
            modes = [{**{n: float(x) for n, x in zip(alt.names, alt.as_matrix(alt.from_unconstrained(u, h))[0])},
                      **wfa.means[0]} for u, _, _ in (wfa.modes[0] if wfa.modes else [])]
        for k, v in enumerate(modes or []):
            starts.append((f"the extended model's Whittle mode {k + 1}", v))
    earlier = run.carry.get(row["effect"])
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
        cache[key] = refine_best(alt, y, h, starts, inputs=inputs, fixed=fixed, must=must, others=1,
                                 tolerance=REFIT_TOLERANCE, refine=refine)
    f2, tried = cache[key]
    f2 = copy.deepcopy(f2)
    winner = max(tried, key=lambda t: t[2])
    if winner[0] != starts[0][0]:
        there = next((t[2] for t in tried if t[0] == starts[0][0]), None)
        there = "not refined (its ℓ far below the others')" if there is None else (
            f"{there:.2f}" if math.isfinite(there) else "−∞: no finite likelihood")
        _add_note(row, f"refitted from {len(tried)} starts; the best from {winner[0]} (ℓ {winner[2]:.2f}; from the "
                       f"screen's start {there})")
    if refine and not f2.loglik >= fit.loglik - NESTED_SLACK:
        _add_note(row, f"every refit ended below the model's ℓ {fit.loglik:.2f} (best {f2.loglik:.2f}): an optimiser "
                       "failure (the models are nested)")
    return f2


def _refit_from(run: _Run, alt, evaluated: Fit, fixed: list) -> Fit:
    """A long record's best suggestion: its exact maximum from the start that ranked it."""
    fit, _ = refine_best(alt, run.y, run.h, [("the start that ranked it", dict(evaluated.values))],
                         inputs=run.inputs, fixed=fixed, tolerance=REFIT_TOLERANCE)
    return fit


def _held_fixed(alt, label) -> tuple[dict, list]:
    """What the extended model's components hold (a temperature reference; a new line's frequency at the refined
    periodogram peak, which still counts as an estimated parameter in BIC) and the names its refit keeps fixed."""
    estimates = {**alt.held_estimates(label), **alt.located()}
    return estimates, [n for n in alt.names if n in alt.references() or n in estimates]


def _loglik_at(model, values: dict, y, h, inputs) -> float:
    """The model's exact ℓ at ``values`` (−∞ where it is not finite)."""
    ll = exact_loglik(model, {n: [values[n]] for n in model.names}, centred(model, y), h, inputs=inputs)
    return float(ll[0]) if np.isfinite(ll[0]) else -math.inf


def _refined_model(model, fit: Fit, f2: Fit, y, h, inputs, intervals: bool) -> Fit | None:
    """The model refined from the values a refit gives its parameters, if that beats ``fit`` by more than
    :data:`BASE_SLACK` (else None)."""
    located = model.located()
    fixed = [n for n in model.names if n not in fit.free or n in located]
    new = refine_exact(model, y, h, {n: f2.values[n] for n in model.names}, inputs=inputs, fixed=fixed,
                       metric=fit.hessian, intervals=intervals)
    new.count(located)
    return new if new.loglik > fit.loglik + BASE_SLACK else None


def _better_model_fit(model, fit: Fit, refits: list, y, h, inputs, intervals: bool) -> Fit | None:
    """The model refined from the best of the refits' values of its own parameters, if that beats ``fit`` by
    more than :data:`BASE_SLACK` (else None)."""
    points = [{n: f.values[n] for n in model.names} for f in refits]
    vals = {n: [p[n] for p in points] for n in model.names}
    ll = exact_loglik(model, vals, centred(model, y), h, inputs=inputs)
    ll = np.where(np.isfinite(ll), ll, -np.inf)
    best = int(np.argmax(ll))
    if not ll[best] > fit.loglik + BASE_SLACK:
        return None
    return _refined_model(model, fit, refits[best], y, h, inputs, intervals)


class _Clock:
    def __init__(self):
        self.t = time.perf_counter()
        self.laps = {}

    def __call__(self, name):
        now = time.perf_counter()
        self.laps[name] = self.laps.get(name, 0.0) + now - self.t
        self.t = now

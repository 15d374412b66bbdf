"""What ``check`` finds, as data: a suggestion (:class:`Suggestion`), one check's findings (:class:`CheckRecord`, which
:class:`~.check.CheckResult` extends with the loop's verbs), the loop's steps in words, and a ``check.json`` read
back (:func:`read_check`)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..fitting.mle import Fit
from ..noise.components import COMPONENTS
from ..noise.model import NoiseModel, parse_model
from .diagnostics import Diagnostic, Innovations
from .screens import screening_of

__all__ = ["Suggestion", "CheckRecord", "effect_parameters", "change_words", "read_check"]


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
class CheckRecord:
    """What :func:`~.check.check` found (the data and their reading; :class:`~.check.CheckResult` adds the loop's
    verbs). ``diagnostics``: list of :class:`~.diagnostics.Diagnostic`; ``screens``: one
    :class:`~.screening.ScreenRow` per effect screened (its statistic, p-value, whether it passed); ``suggestions``: :class:`Suggestion` s, best
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
    before: CheckRecord | None = None
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
    #: How the loop fits (:data:`~torchtea.fitting.whittle_path.FITS`; :func:`~.check.check`'s ``fits``).
    fits: str = "auto"
    #: Candidates whose screen did not pass but whose likelihood-ratio statistic puts the model with them within the
    #: tie margin of BIC: their screens' rows with their starts (:func:`~.refits.near_fits` refits them at the loop's
    #: end), and those refits that stayed within it (effect → :class:`~torchtea.fitting.mle.Fit`; the ties read them,
    #: :func:`~.simplify.ties`).
    near_rows: list = field(default_factory=list)
    near: dict = field(default_factory=dict)
    #: (the end of a loop) the stretch that differs which the loop did not fill with spikes
    #: (:func:`~.loop.stretch_of`), or None.
    stretch: dict | None = None

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
        return [r.effect for r in self.screens if r.refit_failed]

    @property
    def unconfirmed(self) -> list[str]:
        """The effects whose Whittle screen passed but which the exact likelihood does not confirm: below the model
        at the screen's own point and no gain when refitted (the two likelihoods disagree on this record)."""
        return [r.effect for r in self.screens if r.not_confirmed]

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
                        "in_library": [n for n in names if n in COMPONENTS and screening_of(COMPONENTS[n]).candidate
                                       and (n not in have or screening_of(COMPONENTS[n]).add_again)],
                        "add_by_hand": [n for n in names if n in COMPONENTS
                                        and not screening_of(COMPONENTS[n]).candidate and n not in have],
                        "not_in_library": [n for n in names if n not in COMPONENTS]})
        return out

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
                             observed=self.fit.n, method=self.fit.method),
                "diagnostics": [d.as_dict() for d in self.diagnostics],
                "screens": [r.as_dict() for r in self.screens],
                "suggestions": [s.as_dict() for s in self.suggestions],
                "level": self.level, "screen_level": self.screen_level,
                "seconds": sum(r.seconds for r in self.steps), "seconds_this_step": self.seconds,
                "notes": self.notes, "steps": self.step_rows(), "loop_end": self.loop_end,
                "unexplained": self.unexplained, "ties": self.ties, "stretch": self.stretch,
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
        rate = doc["rate_hz"]
        if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not 0 < rate < math.inf:
            raise ValueError(f"rate_hz {rate!r} is not a sample rate")
        fits = {}
        for label, axis in doc["axes"].items():
            if "channels" in doc and not isinstance(doc["channels"][label]["column"], str) or not all(
                    isinstance(t, dict) and isinstance(t.get("words"), str) for t in axis.get("ties", [])):
                raise ValueError(f"axis {label!r}: its channel's column or ties are not as check writes them")
            base = axis["base"]
            model = parse_model(axis["model"])
            se = {k: None if v is None else float(v) for k, v in base["se"].items()}
            ci = {k: None if v is None else (float(v[0]), float(v[1])) for k, v in base["ci95"].items()}
            loglik = float(base["loglik"])
            fits[label] = Fit(model, base.get("method", "exact"), {k: float(v) for k, v in base["parameters"].items()},
                              se, ci,
                              dict(base["ci95_method"]), loglik, loglik, int(base.get("observed", n)),
                              [f"{lb}.{p.name}" for lb, c in model.components for p in c.params
                               if p.name not in c.held], True,
                              notes=[f"read from {path.name} (check's fit of the model its loop ended with)"])
    except FileNotFoundError:
        raise ValueError(f"{path}: no such file") from None
    except (json.JSONDecodeError, KeyError, TypeError, ValueError, AttributeError, IndexError) as exc:
        raise ValueError(f"{path}: not a check.json ({type(exc).__name__}: {exc})") from None
    return doc, fits

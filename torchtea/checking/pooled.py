"""The loop on several recordings of one sensor (:func:`check_together`): one model for all — its noise parameters
shared, each recording its own mean terms (:func:`~torchtea.fitting.together.fit_together`) — grown and pruned by
the pooled likelihood.

Each step checks every recording on its own with the current model (:func:`~.check.check`); an effect that passes a
screen and gains in any recording is a candidate, and so is one whose screens pass combined over the recordings
(Fisher's method: a little of it in each). Half the screens' family level goes to the recordings' own screens (split
over the recordings), half to the combined ones (split over the effects), so on recordings of the model the chance
of any candidate stays at the level. Each is refitted to all of them together: its gain is the fall of
the pooled BIC (the shared parameters counted once, each recording's own terms once per recording). The loop adds the
best candidate while it gains — past a model adequate in every recording only while it gains :data:`~.ranking.
STRONG_BIC` or more —, then tries each component taken away or replaced by its special case (the fractional part by a
random walk: :func:`~.simplify.alternatives`), kept where the pooled BIC falls and no recording's diagnostics fail
that passed. Adequacy is every recording's diagnostics at the pooled values, each at the level over the recordings. An effect that is located in a
recording (spikes, a step) is that recording's own fault, not the sensor's: it is named with the recording and not
added. At the end the recordings are tested against the final model, parameter by parameter
(:attr:`~torchtea.fitting.together.Together.parameters`), and their turn-on bias spread estimated."""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from ..fitting.together import Together, fit_together
from ..fitting.whittle_path import fits_exactly
from ..noise.components import COMPONENTS
from ..noise.model import parse_model
from . import simplify as simplifying
from .check import check
from .diagnostics import LEVEL
from .models import assess, extend, model_fit
from .ranking import STRONG_BIC

__all__ = ["check_together", "PooledCheck", "PooledStep", "POOLED_MEANING", "FINAL_SLACK"]

#: The final fit (each recording's exact fit with its intervals, the loop's pooled maximum among the starts) is said to
#: have found another maximum where its pooled ℓ is this much above the loop's last step.
FINAL_SLACK = 0.5

#: What a pooled check's entries in check.json mean (:meth:`PooledCheck.as_dict`).
POOLED_MEANING = {
    "steps": "the pooled loop's path: per step the model, the pooled exact log-likelihood, its estimates k (shared "
             "once, each recording's own terms once per recording), the pooled BIC, the change that led there and "
             "its gain (the fall of the pooled BIC), the diagnostics each recording fails at the pooled values, the "
             "candidates (effects that passed a screen in a recording, which recordings, their pooled gain) and "
             "the effects a recording's check suggests that are located in it (faults: not added; at the last step "
             "that recording's own fault, before it perhaps what the model still lacked — a random walk looks like a "
             "step)",
    "combined_screens": "per step, each effect screened in every recording: its screens' p-values combined by "
                        "Fisher's method, the threshold (the screens' family level over the effects) and whether it "
                        "passed — an effect no recording shows enough of alone is then a candidate too",
    "loop_end": "why the pooled loop ended, in words",
    "adequate": "every recording's diagnostics pass at the final model's pooled values, each at the level over the "
                "recordings (failing: those that do not)",
}


@dataclass
class PooledStep:
    """One step of the pooled loop: the model's pooled fit (``together``, no tests), each recording's own check of it
    (``checks``), the diagnostics each recording fails at the pooled values (``failing``), the candidates and their
    pooled gains, the recordings' own faults, and the change that led here."""

    together: Together
    checks: list
    failing: list
    change: str = "start"
    gain: float | None = None
    candidates: list = field(default_factory=list)
    faults: list = field(default_factory=list)
    tried: list = field(default_factory=list)
    #: each effect's screens combined over the recordings (:meth:`_Loop.combined`)
    combined: list = field(default_factory=list)
    #: the candidates refitted together, best first (:meth:`_Loop.candidates`), once made
    evaluated: list | None = field(default=None, repr=False)

    @property
    def model(self):
        return self.together.model

    @property
    def adequate(self) -> bool:
        return not any(self.failing)

    def as_dict(self) -> dict:
        tg = self.together
        return {"model": tg.model.spec, "change": self.change, "gain": self.gain, "loglik": tg.loglik, "k": tg.k,
                "n": tg.n, "bic": tg.bic, "adequate": self.adequate,
                "failing": {name: list(f) for name, f in zip(tg.recordings, self.failing)},
                "candidates": list(self.candidates), "faults": list(self.faults), "tried": list(self.tried),
                "combined_screens": list(self.combined)}


@dataclass
class PooledCheck:
    """:func:`check_together`'s result: the path (``steps``, the last the final model), the final model's pooled fit
    with its per-parameter tests and bias spread (``together``), and why the loop ended."""

    steps: list
    together: Together
    loop_end: str
    seconds: float = 0.0

    @property
    def model(self):
        return self.together.model

    @property
    def final(self) -> PooledStep:
        return self.steps[-1]

    @property
    def adequate(self) -> bool:
        return self.final.adequate

    def as_dict(self) -> dict:
        return {"model": self.model.spec, "adequate": self.adequate, "loop_end": self.loop_end,
                "steps": [s.as_dict() for s in self.steps], "replicates": self.together.as_dict(),
                "seconds": self.seconds}


def _own_fault(effect: str, token: str | None) -> bool:
    """An effect a recording's check configures on its own record (``spikes:K``) or locates in it (a step's time):
    that recording's, not the sensor's — also where the model has one already."""
    return ":" in (token or "") or (effect in COMPONENTS and bool(COMPONENTS[effect].located))


def _row_token(check_result, effect: str) -> str | None:
    """The spec token a recording's screen of ``effect`` configured."""
    return next((r.token for r in check_result.screens if r.effect == effect), None)


class _Loop:
    def __init__(self, series, h, inputs, names, level, screen_level, fits, say):
        self.series, self.h, self.inputs, self.names = series, h, inputs, names
        self.level, self.screen_level, self.fits, self.say = level, screen_level, fits, say
        self.R = len(series)

    def failing(self, tg: Together) -> list:
        """Per recording, the diagnostics it fails at the pooled values, each at the level over the recordings
        (Bonferroni: a model of the recordings is called inadequate in any of them no more often than one check of
        one recording calls it so)."""
        out = []
        for y, v, inp in zip(self.series, tg.values, self.inputs):
            _, diags, _ = assess(tg.model, v, y, self.h, inp, self.level / self.R)
            out.append(sorted(d.name for d in diags if d.passed is False))
        return out

    def step(self, model, fits: list | None = None, change: str = "start", gain: float | None = None,
             pooled: Together | None = None) -> PooledStep:
        """Each recording checked on its own with ``model`` (from its ``fits`` where given), then the pooled fit from
        those fits — ``pooled``, already made from them, where every check kept its fit —, and each recording's
        diagnostics at the pooled values."""
        checks = []
        for r, (y, inp) in enumerate(zip(self.series, self.inputs)):
            self.say(f"{self.names[r]}: checking {model.spec}")
            checks.append(check(y, self.h, model=model, inputs=inp, level=self.level,
                                screen_level=self.screen_level / (2 * self.R), intervals=False, fits=self.fits,
                                fit=None if fits is None else fits[r]))
        kept = pooled is not None and all(c.fit is f for c, f in zip(checks, fits))
        tg = pooled if kept else self.together(model, [c.fit for c in checks])
        return PooledStep(tg, checks, self.failing(tg), change, gain)

    def together(self, model, separate: list) -> Together:
        self.say(f"fitting {model.spec} to the {self.R} recordings together")
        return fit_together(model, self.series, self.h, inputs=self.inputs, recordings=self.names, separate=separate,
                            tests=False, repeatability=False)

    def versus(self, node: PooledStep, alt) -> tuple[list, Together, float | None]:
        """``alt`` against the step's model: each recording's own fit of it (:meth:`fits_of`), their pooled fit, and
        the fall of the pooled BIC — None where either pooled likelihood is not finite."""
        fits = self.fits_of(alt, node)
        tg = self.together(alt, fits)
        gain = float(node.together.bic - tg.bic) if tg.finite and node.together.finite else None
        return fits, tg, gain

    def fits_of(self, alt, node: PooledStep) -> list:
        """Each recording's own fit of ``alt``: its check's refit where it made one, else fitted."""
        out = []
        for r, c in enumerate(node.checks):
            have = [s.fit for s in c.suggestions if s.fit.model.spec == alt.spec]
            have += [f for f in c.refits.values() if f.model.spec == alt.spec]
            if have:
                out.append(max(have, key=lambda f: f.loglik_exact))
            else:
                self.say(f"{self.names[r]}: fitting {alt.spec}")
                out.append(model_fit(alt, self.series[r], self.h, inputs=self.inputs[r], intervals=False,
                                     fits=self.fits))
        return out

    def candidates(self, node: PooledStep) -> list:
        """The effects that passed a screen in some recording and gain there, each refitted to all together:
        ``(gain, alt model, own fits, effect, pooled fit)``, best first; the recordings' own faults noted on ``node``."""
        if node.evaluated is not None:
            return node.evaluated
        found: dict = {}
        for name, c in zip(self.names, node.checks):
            for s in c.suggestions:
                if _own_fault(s.effect, _row_token(c, s.effect)):
                    node.faults.append({"recording": name, "effect": s.effect, "gain": s.gain,
                                        "model": s.fit.model.spec})
                    continue
                best = found.get(s.effect)
                if best is None or s.gain > best[1]:  # (the model of the recording where it gains most)
                    found[s.effect] = (s.fit.model, s.gain, (best[2] if best else []) + [name])
                else:
                    best[2].append(name)
        for effect, tok in self.combined(node, set(found)):
            found[effect] = (extend(node.model, tok), 0.0, ["the recordings' screens combined"])
        out = []
        for effect, (alt, _, by) in found.items():
            fits, tg, gain = self.versus(node, alt)
            node.candidates.append({"effect": effect, "model": alt.spec, "suggested_by": by, "gain": gain})
            if gain is None:
                node.candidates[-1]["rejected"] = "no finite pooled likelihood"
                continue
            out.append((gain, alt, fits, effect, tg))
        node.candidates.sort(key=lambda c: -math.inf if c["gain"] is None else -c["gain"])
        node.evaluated = sorted(out, key=lambda t: -t[0])
        return node.evaluated

    def combined(self, node: PooledStep, found: set) -> list:
        """The effects that no recording's screen passes alone but all of them together do: each recording's screen
        p-value combined by Fisher's method (−2 Σ ln p, χ² with 2R degrees of freedom under the model: the
        recordings are independent), at the screens' family level over the effects screened — an effect every
        recording shows a little of. ``(effect, token)`` for those not in ``found``, not located in a recording."""
        rows = {}
        for c in node.checks:
            for r in c.screens:
                if r.p_value is not None and r.token is not None:
                    rows.setdefault(r.effect, []).append(r)
        full = {e: rs for e, rs in rows.items() if len(rs) == self.R}
        threshold = 0.5 * self.screen_level / max(1, len(full))
        out = []
        for effect, rs in full.items():
            if effect in found or _own_fault(effect, rs[0].token) or any(r.token != rs[0].token for r in rs):
                continue
            x = -2.0 * sum(math.log(max(r.p_value, 1e-300)) for r in rs)
            p = float(stats.chi2.sf(x, 2 * self.R))
            node.combined.append({"effect": effect, "p_value": p, "threshold": threshold,
                                  "passed": p < threshold, "p_values": [r.p_value for r in rs]})
            if p < threshold:
                out.append((effect, rs[0].token))
        return out

    def simpler(self, node: PooledStep) -> tuple | None:
        """The best of the model's components taken away or replaced by its special case where it lowers the pooled
        BIC and no recording fails a diagnostic it passed: ``(gain, step)``, or None."""
        best = None
        before = {(r, d) for r, f in enumerate(node.failing) for d in f}
        for alt in simplifying.alternatives(node.checks[0]):
            if alt.kind == "swap":
                continue
            fits, tg, gain = self.versus(node, alt.model)
            entry = {"change": alt.words, "model": alt.model.spec, "gain": gain}
            node.tried.append(entry)
            if gain is None:
                entry["rejected"] = "no finite pooled likelihood"
                continue
            if gain <= 0 or (best is not None and gain <= best[0]):
                continue
            failing = self.failing(tg)
            worse = {(r, d) for r, f in enumerate(failing) for d in f} - before
            if worse:
                entry["rejected"] = "fails " + ", ".join(f"{d} in {self.names[r]}" for r, d in sorted(worse))
                continue
            best = (gain, alt, fits, tg)
        if best is None:
            return None
        gain, alt, fits, tg = best
        return gain, self.step(alt.model, fits, alt.words, gain, pooled=tg)


def check_together(model, series: list, h: float, *, inputs: list | None = None, recordings: list | None = None,
                   max_steps: int = 6, strong: float | None = None, simplify: bool = True, level: float = LEVEL,
                   screen_level: float = 0.05, fits: str = "auto", progress=None) -> PooledCheck:
    """The loop on the pooled likelihood of several recordings of one sensor (module docstring): ``series`` 1-D arrays
    of one channel (NaN = missing), ``inputs`` one dict or None per recording, ``recordings`` their names. Adds at
    most ``max_steps`` effects; ``strong`` (default :data:`~.ranking.STRONG_BIC`) is the gain an adequate model's loop
    asks for; ``simplify`` tries each component taken away or replaced by its special case, at most
    :data:`~.simplify.MAX_CHANGES` changes. Returns the path and the final model's pooled fit with its tests."""
    t0 = time.perf_counter()
    model = parse_model(model)
    R = len(series)
    if R < 2:
        raise ValueError("checking together needs two or more recordings")
    series = [np.asarray(y, dtype=np.float64) for y in series]
    inputs = [None] * R if inputs is None else list(inputs)
    names = list(recordings) if recordings is not None else [f"recording {r + 1}" for r in range(R)]
    strong = STRONG_BIC if strong is None else float(strong)
    say = progress or (lambda line: None)
    loop = _Loop(series, h, inputs, names, level, screen_level, fits, say)
    node = loop.step(model)
    steps = [node]
    added = changes = 0
    while True:
        while added < max_steps:
            cands = loop.candidates(node)
            if not cands or cands[0][0] <= 0 or (node.adequate and cands[0][0] < strong):
                break
            gain, alt, alt_fits, effect, pooled = cands[0]
            node = loop.step(alt, alt_fits, f"added {effect}", gain, pooled=pooled)
            steps.append(node)
            added += 1
        if not simplify or changes >= simplifying.MAX_CHANGES:
            break
        found = loop.simpler(node)
        if found is None:
            break
        node = found[1]
        steps.append(node)
        changes += 1
    loop.candidates(node)  # (what the last model would still gain, for the words)
    say(f"testing the recordings against {node.model.spec}, parameter by parameter")
    joint, x = node.together.pooled
    exact = all(fits_exactly(node.model, y, fits) for y in series)  # (else each recording's fit as its check made it)
    final = fit_together(node.model, series, h, inputs=inputs, recordings=names, progress=say,
                         separate=None if exact else [c.fit for c in node.checks],
                         starts=[[joint.unpack(x, r)[0] for r in range(R)]])
    end = _loop_end(steps, added, changes, max_steps, strong)
    if final.loglik > node.together.loglik + FINAL_SLACK:  # (the tests' fit climbed from more places)
        failing = loop.failing(final)
        end += (f"; the final fit found a higher maximum of the pooled likelihood than the loop's last step (ℓ "
                f"{final.loglik - node.together.loglik:+.1f}), the replicates' values and tests are at it, and there "
                + ("every recording is adequate" if not any(failing) else
                   "; ".join(f"{n} fails {', '.join(f)}" for n, f in zip(names, failing) if f)))
    return PooledCheck(steps, final, end, time.perf_counter() - t0)


def _loop_end(steps: list, added: int, changes: int, max_steps: int, strong: float) -> str:
    """Why the pooled loop ended, in words."""
    node = steps[-1]
    done = f"{added} effect(s) added" + (f", {changes} change(s) taking away or replacing" if changes else "")
    best = next((c for c in node.candidates if c["gain"] is not None and c["gain"] > 0), None)
    wanted = best is not None and best["gain"] >= (strong if node.adequate else 0.0)  # (what the loop would add)
    state = "adequate in every recording" if node.adequate else "not adequate"
    if max_steps == 0 and not changes:
        end = f"the model checked, not the loop: {state}"
        if best is not None:
            end += f"; {best['effect']} would gain {best['gain']:.1f} pooled BIC"
    elif added >= max_steps and wanted:
        end = (f"stopped after {max_steps} effects added (max_steps), {state}; {best['effect']} would still gain "
               f"{best['gain']:.1f} pooled BIC")
    elif node.adequate:
        end = f"adequate in every recording after {done}"
        if best is not None:
            end += (f" ({best['effect']} would still gain {best['gain']:.1f} pooled BIC, under the {strong:g} an "
                    "adequate model's loop asks for)")
    else:
        end = f"not adequate after {done}, and no candidate lowers the pooled BIC"
    if not node.adequate:
        end += ": " + "; ".join(f"{n} fails {', '.join(f)}" for n, f in zip(node.together.recordings, node.failing)
                                 if f)
    faults = {}
    for f in node.faults:
        faults.setdefault(f["recording"], []).append(f["effect"])
    if faults:
        end += ("; found in one recording only, its own fault and not the sensor's (check it alone, or leave the "
                "stretch out): " + "; ".join(f"{n}: {', '.join(e)}" for n, e in faults.items()))
    for name, c in zip(node.together.recordings, node.checks):  # (as one recording's loop says them)
        if c.failed_refits:
            end += (f"; in {name} the screens of {', '.join(c.failed_refits)} passed, but their refits failed to find "
                    "what the screens saw — an optimiser's failure, not evidence that nothing explains it")
        if c.unconfirmed:
            end += (f"; in {name} the Whittle screens of {', '.join(c.unconfirmed)} passed, but the exact likelihood "
                    "does not confirm them: not stationary?")
    if not node.together.finite:
        end += "; the pooled likelihood of the model is not finite: no gain could be measured against it"
    return end

r"""How long to record: the expected 95 % interval of a model's numbers as a function of the
record's length, the length a target asks for, and the length at which two models the record cannot tell apart
would be told apart.

**The information.** For a stationary Gaussian series of ``n`` samples with two-sided spectral density
:math:`S_\theta(\omega)`, the Whittle likelihood's expected information is

.. math:: \mathcal I_n(\theta) = \sum_{j=1}^{\lfloor (n-1)/2 \rfloor}
          \nabla_\theta \log S_\theta(\omega_j)\,\nabla_\theta \log S_\theta(\omega_j)^\top,
          \qquad \omega_j = 2\pi j/n,

asymptotically the exact likelihood's (Whittle 1953; Dzhaparidze 1986). It grows with ``n`` through the number of
Fourier frequencies *and* through how low they reach: a random walk or a long correlation time is told by the
lowest ones, so its interval narrows differently from the white noise's. The gradients are taken on the fits'
unconstrained coordinates (a log for a positive parameter, a logit for a bounded one) and the 95 % interval is
mapped back from there, as the fits' intervals are (:func:`~.mle.fit_series`). Above :data:`EXACT_ORDINATES`
ordinates the sum runs over geometric bins of them (each bin's count times its centre's term).

The mean effects (a ramp, a temperature bias, a line) are not in the spectrum: their information depends on the
temperature history and the line, and the plan leaves them out (it says so). The white-noise density is
:math:`N = \sqrt{r\,h}` and the bias random walk :math:`K = \sigma` of a random walk (IEEE Std 952's terms, as
:mod:`torchtea.export` writes them).

**Ties.** Two models whose BIC differs by :math:`d_0` on ``n₀`` samples, the other with :math:`\Delta k` more
parameters: this one's likelihood-ratio statistic over the other, :math:`L_0 = d_0 - \Delta k \ln n_0`, grows in
proportion to the record while the models stay what they are (the Kullback–Leibler rate per sample is fixed), so
:math:`d(n) = L_0\,n/n_0 + \Delta k \ln n`, and the record tells them apart once :math:`|d(n)|` reaches the
strong-evidence level (:func:`tie_length`) — in the favour of the one ahead in likelihood, or by the penalty alone
when neither is. That is an expectation from this record's own statistic, itself noisy: the tests check it against
simulation.

**Datasheets.** :func:`~.datasheet.datasheet_model` turns a datasheet's N, B and K into white noise, a flicker (fractional order
½, pole at 0) and a random walk. IEEE Std 952's rate PSDs are two-sided — white noise :math:`N^2`, whose Allan
variance is :math:`N^2/\tau`, and flicker :math:`B^2/(2\pi f)`, whose Allan deviation is flat at
:math:`\sqrt{2\ln 2/\pi}\,B = 0.664\,B` — and the fractional part at order ½ has the two-sided PSD
:math:`q h/(2\pi f)` at low frequencies, so ``q = B²/h`` (its model Allan deviation is flat at 0.664 B: tested)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from ..core import forward
from ..noise.components import STOCHASTIC_KINDS
from ..noise.model import NoiseModel, parse_model
from ..noise.navigation import nav_term_of, nav_value

__all__ = ["PlanRow", "plan", "length_for", "tie_length", "EXACT_ORDINATES", "nav_numbers", "plan_document",
           "plan_lines", "plan_table", "parse_target", "duration"]

Z95 = 1.959963984540054
#: Up to this many Fourier ordinates (records of 2·10⁶ samples) the information is summed over each: 0.6 s for the
#: bundled gz's seven-parameter model at 2.16·10⁶ samples. Geometric bins under-resolve a narrow band (with 50 000 bins
#: the bundled gz's 3 mHz-wide resonance came out with a wider bandwidth interval at 1.25 h than at 1 h); above, the
#: first 1000 ordinates and as many geometric bins of the rest as this.
EXACT_ORDINATES = 1_000_000


def _stochastic(model: NoiseModel) -> list[str]:
    """The parameters of the model's noise (state, measurement and filter components), not its references."""
    refs = model.references()
    return [f"{lb}.{p.name}" for lb, c in model.components if c.kind in STOCHASTIC_KINDS
            for p in c.params if f"{lb}.{p.name}" not in refs]


def _ordinates(n: int) -> tuple[np.ndarray, np.ndarray]:
    """The Fourier indices j (as floats, a bin's centre) and their weights (a bin's count) for ``n`` samples."""
    m = (n - 1) // 2
    if m <= EXACT_ORDINATES:
        j = np.arange(1, m + 1, dtype=np.float64)
        return j, np.ones_like(j)
    head = np.arange(1, 1001, dtype=np.float64)
    edges = np.unique(np.round(np.geomspace(1001, m + 1, EXACT_ORDINATES)).astype(np.int64))
    counts = np.diff(edges).astype(np.float64)
    centres = 0.5 * (edges[:-1] + edges[1:] - 1)
    keep = counts > 0
    return np.concatenate([head, centres[keep]]), np.concatenate([np.ones(1000), counts[keep]])


#: A bounded parameter whose logit is beyond this sits at its bound (an order at 0 or 1, a pole at 0): the plan holds
#: it there (its information is all but zero, and it would make the others' singular) and says so.
AT_BOUND_LOGIT = 8.0


def _point(model, values: dict, h: float) -> torch.Tensor:
    """The values (name → float) as the fits' unconstrained coordinates ``(P,)``."""
    return model.to_unconstrained({k: torch.as_tensor([float(values[k])], dtype=torch.float64)
                                   for k in model.names}, h)[0].detach()


def _held(model, values: dict, h: float, fixed=()) -> list[str]:
    """The noise parameters the plan holds: those ``fixed`` and those at a bound (:data:`AT_BOUND_LOGIT`)."""
    u = _point(model, values, h)
    return [p for p in _stochastic(model) if p in fixed or (
        model.param_spec(p).scale == "logit"
        and abs(float(u[model.names.index(p)])) > AT_BOUND_LOGIT)]


def information(model, values: dict, h: float, n: int, fixed=()) -> tuple[list[str], np.ndarray]:
    """The expected (Whittle) information of ``n`` samples about the model's noise parameters at ``values``, on the
    unconstrained coordinates, those held (``fixed``, or at a bound: :func:`_held`) left out: ``(names, I (F, F))``."""
    model = parse_model(model)
    held = _held(model, values, h, fixed)
    names = [p for p in _stochastic(model) if p not in held]
    idx = [model.names.index(p) for p in names]
    u0 = _point(model, values, h)
    j, w = _ordinates(n)
    omega = torch.as_tensor(2.0 * math.pi * j / n)

    def log_s(us):
        u = u0.clone()
        u[idx] = us
        return torch.log(model.spectrum(model.from_unconstrained(u.unsqueeze(0), h), omega, h)[0])

    J = forward.jacfwd(log_s)(u0[idx]).numpy()  # (W, F)
    wt = torch.as_tensor(w).numpy()
    return names, (J * wt[:, None]).T @ J


@dataclass
class PlanRow:
    """The expected 95 % intervals at one record length: ``samples``, ``seconds``; ``intervals`` name → (lo, hi)
    (the noise parameters, and ``N``, ``K`` where the model has them); ``relative`` name → half the interval's width
    over the value; ``singular``: the information is singular (a parameter at its bound, or not identified beside
    the others): no intervals."""

    samples: int
    seconds: float
    intervals: dict
    relative: dict
    singular: bool = False
    #: the noise parameters held where they are (given as fixed, or at a bound)
    held: tuple = ()
    #: the parameters (and N, K) of components the fit put almost nothing of in the record (:data:`COLLAPSED`)
    collapsed: tuple = ()

    def as_dict(self) -> dict:
        return {"samples": self.samples, "seconds": self.seconds, "ci95": self.intervals,
                "relative_half_width": self.relative, "singular": self.singular, "held": list(self.held),
                "collapsed": list(self.collapsed)}


def nav_numbers(model, values: dict, h: float) -> dict:
    """The IEEE 952 numbers the model has directly, each from one parameter (its components'
    :func:`~torchtea.noise.navigation.nav_value`: ``N`` √(r h) of its white noise, ``K`` σ of its random
    walk): term → (value, the parameter, the power it enters with). With two components of one term (white and
    quantisation noise both N) the term is not one parameter's, and is left out."""
    model = parse_model(model)
    out, seen = {}, {}
    for lb, c in model.components:
        term = nav_term_of(c).term
        if term in ("N", "K"):
            seen[term] = seen.get(term, 0) + 1
            got = nav_value(c, lb, values, h)
            if got is not None:
                out[term] = got
    return {t: x for t, x in out.items() if seen[t] == 1}


def plan(model, values: dict, h: float, lengths, fixed=(), terms: dict | None = None) -> list[PlanRow]:
    """The expected 95 % intervals of the model's noise parameters (and N, K: :func:`nav_numbers`, or ``terms`` in
    that form) at each record length of ``lengths`` (samples), the model at ``values`` taken as the truth (module
    docstring), the parameters ``fixed`` and those at a bound held."""
    model = parse_model(model)
    nav = nav_numbers(model, values, h) if terms is None else terms
    held = tuple(_held(model, values, h, fixed))
    rows = []
    for n in lengths:
        n = int(n)
        names, info = information(model, values, h, n, fixed)
        intervals, relative = {}, {}
        cov, names, collapsed = _covariance(names, info)
        if cov is not None:
            se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
            for p, s in zip(names, se):
                lo, hi = _mapped(model, values, h, p, s)
                intervals[p] = (lo, hi)
                relative[p] = (hi - lo) / (2.0 * abs(float(values[p]))) if float(values[p]) else math.inf
            for term, (v, p, power) in nav.items():
                if p in intervals:
                    lo, hi = intervals[p]
                    intervals[term] = (v * (lo / float(values[p])) ** power, v * (hi / float(values[p])) ** power)
                    relative[term] = (intervals[term][1] - intervals[term][0]) / (2.0 * v)
        gone = [t for t, (_, p, _) in nav.items() if p in collapsed]
        rows.append(PlanRow(n, n * h, intervals, relative, cov is None, held, tuple(collapsed) + tuple(gone)))
    return rows


#: A parameter whose expected information is below this fraction of the largest one's is of a component the fit put
#: (almost) nothing of in the record — a random walk at σ ≈ 0: the plan leaves it out (``collapsed``) rather than
#: call every interval undetermined.
COLLAPSED = 1e-8


def _covariance(names: list, info: np.ndarray) -> tuple:
    """The inverse information, the names it is over and those left out as collapsed (:data:`COLLAPSED`); the
    covariance None where what is left is still singular."""
    d = np.diag(info)
    keep = [i for i in range(len(names)) if d[i] > COLLAPSED * max(d.max(initial=0.0), 1e-300)]
    collapsed = [names[i] for i in range(len(names)) if i not in keep] if len(keep) < len(names) else []
    sub = info[np.ix_(keep, keep)]
    names = [names[i] for i in keep]
    if not keep:
        return None, names, collapsed
    try:
        evals = np.linalg.eigvalsh(sub)
        cov = np.linalg.inv(sub) if evals.min() > 1e-12 * max(evals.max(), 1e-300) else None
    except np.linalg.LinAlgError:
        cov = None
    return cov, names, collapsed


def _mapped(model, values, h, name, se_u) -> tuple[float, float]:
    """The 95 % interval of ``name`` from its unconstrained coordinate's standard error, mapped back."""
    u = _point(model, values, h)
    i = model.names.index(name)
    ends = []
    for sign in (-1.0, 1.0):
        uu = u.clone()
        uu[i] = uu[i] + sign * Z95 * se_u
        ends.append(float(model.from_unconstrained(uu.unsqueeze(0), h)[name][0]))
    return min(ends), max(ends)


def length_for(model, values: dict, h: float, name: str, relative: float, start: int = 16,
               limit: int = 10 ** 10, fixed=(), terms: dict | None = None) -> int | None:
    """The fewest samples at which ``name``'s expected 95 % interval is within ±``relative`` of its value (half its
    width over the value), found on a doubling grid and refined by bisection on log n; None when not even ``limit``
    samples reach it."""
    def width(n):
        r = plan(model, values, h, [n], fixed, terms)[0]
        return r.relative.get(name, math.inf)

    lo, hi = None, max(int(start), 8)
    while width(hi) > relative:
        lo, hi = hi, hi * 2
        if hi > limit:
            return None
    if lo is None:
        return hi
    for _ in range(12):
        mid = int(round(math.sqrt(lo * hi)))
        if mid in (lo, hi):
            break
        if width(mid) > relative:
            lo = mid
        else:
            hi = mid
    return hi


def tie_length(d0: float, dk: int, n0: int, close: float = 6.0, limit: float = 1e4) -> int | None:
    r"""The record length (samples) at which two models whose BIC differs by ``d0`` on ``n0`` samples (BIC of the
    other − BIC of this one), the other with ``dk`` more parameters, are expected to differ by ``close``: the
    smallest ``n > n0`` with :math:`|L_0 n/n_0 + \Delta k \ln n| \ge` ``close``, :math:`L_0 = d_0 - \Delta k \ln n_0`
    the likelihood-ratio statistic of this model over the other (module docstring); None when not within ``limit`` ×
    ``n0`` (their likelihoods do not part: only the penalty grows)."""
    L0 = d0 - dk * math.log(n0)

    def d(n):
        return L0 * n / n0 + dk * math.log(n)

    grid = np.geomspace(n0, n0 * limit, 400)
    hit = next((n for n in grid[1:] if abs(d(n)) >= close), None)
    if hit is None:
        return None
    lo, hi = float(n0), float(hit)
    for _ in range(60):
        mid = math.sqrt(lo * hi)
        if abs(d(mid)) >= close:
            hi = mid
        else:
            lo = mid
    return int(math.ceil(hi))


def parse_target(text: str) -> tuple[str, float]:
    """``"K=10%"`` → ``("K", 0.10)``: a number (N, B, K or a parameter's name) within ± that much of its value."""
    name, sep, value = text.partition("=")
    value = value.strip()
    try:
        if not sep or not name.strip():
            raise ValueError
        rel = float(value[:-1]) / 100.0 if value.endswith("%") else float(value)
    except ValueError:
        raise ValueError(f"--target {text!r}: expected NAME=PERCENT, e.g. K=10%") from None
    if not 0 < rel < 10:
        raise ValueError(f"--target {text!r}: the half-width must be a positive share of the value (e.g. 10%)")
    return name.strip(), rel


def plan_document(model, values: dict, h: float, lengths, *, recorded: int | None = None, targets=(), fixed=(),
                  terms: dict | None = None) -> dict:
    """One axis's plan as the command writes it: the model and values taken as the truth, the rows at ``lengths``
    (samples; :func:`plan`), each target's length (:func:`length_for`) and what the plan leaves out."""
    model = parse_model(model)
    rows = plan(model, values, h, lengths, fixed, terms)
    names = set(rows[0].intervals) if rows else set()
    out_targets = []
    known = set(_stochastic(model)) | set(nav_numbers(model, values, h) if terms is None else terms)
    held = _held(model, values, h, fixed)
    for name, rel in targets:
        if name in held:
            out_targets.append({"name": name, "relative_half_width": rel, "samples": None, "seconds": None,
                                "absent": f"{name} is held (given, or at a bound): not estimated"})
            continue
        if name not in known:  # (another axis's model may have it)
            out_targets.append({"name": name, "relative_half_width": rel, "samples": None, "seconds": None,
                                "absent": f"{model.spec} has no {name} (its numbers: {', '.join(sorted(known))})"})
            continue
        if rows and all(name in r.collapsed for r in rows):  # (a length from a σ at ≈ 0 would be the optimiser's)
            out_targets.append({"name": name, "relative_half_width": rel, "samples": None, "seconds": None,
                                "absent": f"none seen: the fit puts almost no {name} in the record, so no length "
                                          "pins it down from here (a longer record may show one)"})
            continue
        n = length_for(model, values, h, name, rel, fixed=fixed, terms=terms)
        out_targets.append({"name": name, "relative_half_width": rel, "samples": n,
                            "seconds": None if n is None else n * h})
    means = [lb for lb, c in model.components if c.kind in ("mean", "modifier")]
    notes = []
    if means:
        notes.append(f"not planned: {', '.join(means)} (a mean's information depends on the temperature history or "
                     "the line, not on the noise alone)")
    if held:
        notes.append(f"held where they are: {', '.join(held)} (given, or at a bound)")
    gone = sorted({n for r in rows for n in r.collapsed})
    if gone:
        notes.append(f"none seen: {', '.join(gone)} — almost no information on it in a record of that length (a "
                     "component the fit puts almost nothing of in the record, as a random walk at σ ≈ 0): no interval, "
                     "an upper bound is all such a record gives; the other numbers' intervals without it")
    if rows and not names:
        notes.append("the information is singular: no intervals")
    return {"model": model.spec, "values": {k: float(v) for k, v in values.items()}, "sample_time_s": h,
            "recorded_samples": recorded, "rows": [r.as_dict() for r in rows], "targets": out_targets,
            "notes": notes,
            "meaning": "expected 95 % intervals if the model at these values is the truth (the Whittle likelihood's "
                       "expected information); relative_half_width = half the interval's width over the value"}


def duration(seconds: float) -> str:
    """``seconds`` in the largest unit that keeps it above 1: s, min, h, days."""
    for unit, size in (("days", 86400.0), ("h", 3600.0), ("min", 60.0)):
        if seconds >= size:
            return f"{seconds / size:.3g} {unit}"
    return f"{seconds:.3g} s"


def _share(rel: float | None) -> str:
    if rel is None or not math.isfinite(rel):
        return "—"
    return "not determined" if rel >= 1.0 else f"±{100 * rel:.2g} %"


def plan_table(doc: dict) -> tuple[list[str], list[list[str]]]:
    """One axis's plan (:func:`plan_document`) as a table: the header (length, then N, B, K where the model has
    them, then its noise parameters) and a row of strings per length."""
    rows = doc["rows"]
    names = [t for t in ("N", "B", "K") if rows and (t in rows[0]["relative_half_width"]
                                                    or t in rows[0].get("collapsed", ()))]
    names += sorted({n for r in rows for n in [*r["relative_half_width"], *r.get("collapsed", ())]} - set(names))
    return ["length"] + names, [[duration(r["seconds"])] + [
        "none seen" if n in r.get("collapsed", ()) else _share(r["relative_half_width"].get(n)) for n in names]
        for r in rows]


def plan_lines(label: str, doc: dict, markdown: bool = False) -> list[str]:
    """The text of one axis's plan (:func:`plan_document`): a row per length, a column per number (N, B, K first),
    then the targets and the notes; ``markdown``: the table as a markdown table, without the heading lines."""
    head, table = plan_table(doc)
    rec = doc.get("recorded_samples")
    if markdown:
        out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)] + ["| " + " | ".join(r) + " |" for r in table]
    else:
        out = [f"{label}: {doc['model']}" + (f" (recorded {duration(rec * doc['sample_time_s'])})" if rec else ""),
               "  expected 95 % interval, ± its half-width over the value, by record length:",
               "  " + " | ".join(head)] + ["  " + " | ".join(r) for r in table]
    pad = "" if markdown else "  "
    for t in doc["targets"]:
        out.append(f"{pad}{t['name']} within ±{100 * t['relative_half_width']:g} %: " + (
                   t["absent"] if t.get("absent") else "not within 10¹⁰ samples" if t["samples"] is None else
                      f"{duration(t['seconds'])} ({t['samples']} samples)"))
    out += [f"{pad}note: {x}" for x in doc["notes"]]
    return out

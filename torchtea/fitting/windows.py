"""A sensor over time: a model's noise parameters estimated in windows of a record, a test that they are constant,
and where one changes (:func:`noise_over_time`).

The record's fitted mean (its level, ramp, lines, temperature terms) is removed first; the model's noise part is then
fitted in windows of the given length, half-overlapping (the rows a picture draws, each with its 95 % interval). The
test cuts the whole record into W pieces of at least that length that do not overlap and fits them as recordings of
one sensor together (:func:`~.together.fit_together`: noise parameters shared, each piece its own level): per noise
parameter the likelihood ratio of its own value in each piece against one value in all, χ² with W − 1 degrees of
freedom, at the family level over the parameters (Bonferroni). The pieces are taken as independent, each with its own
level: exact for white noise and a random walk, a composite likelihood where the noise has a longer memory (a
fractional part, a slow Gauss–Markov bias), whose χ² is then approximate. Where a parameter is not constant, the
change is located: the pooled likelihood with the parameter one value before a boundary between pieces and another
after, the boundary that maximises it, then refined within the pieces either side on the record itself (the two values
held, the split moved in 40 steps over the two pieces, each side its own level). A change near an end names the
stretch to leave out."""
from __future__ import annotations

import numpy as np
import torch

from ..noise.components import STOCHASTIC_KINDS
from ..noise.model import assemble, parse_model
from .exact import centred, exact_loglik
from .mle import Fit, fit_series
from .together import TOGETHER_LEVEL, _values, fit_together, regrouped

__all__ = ["noise_over_time", "noise_part", "window_samples", "WINDOWS_MEANING", "EDGE_SHARE"]

#: A change within this share of the record from either end is a stretch at that end to leave out.
EDGE_SHARE = 0.25

#: What ``windows`` in a JSON document means.
WINDOWS_MEANING = {
    "windows": "the final model's noise parameters over time: its fitted mean removed, its noise part fitted in "
               "windows of length_s seconds, half-overlapping; a test that each is constant; where one changes",
    "length_s": "the windows' length (s); they start every length_s / 2",
    "rows": "per window: from_s, to_s, each noise parameter's value and 95 % interval (ci95)",
    "constancy": "per noise parameter, over the whole record cut into pieces of at least a window's length that do "
                 "not overlap: the likelihood-ratio statistic of its own value in each piece against one in all, its "
                 "degrees of freedom, p_value and whether it changes (p below the family level over the parameters)",
    "changes": "where a parameter changes: at_s (the split that maximises the likelihood with the parameter one value "
               "before and another after), the parameters, the constancy test's p_value, the values before and after, "
               "and what to do (the stretch to leave out where it is near an end)",
}


def noise_part(model):
    """The model's noise: its state, measurement and filter components (its means and modifiers left out)."""
    model = parse_model(model)
    kept = [c for _, c in model.components if c.kind in STOCHASTIC_KINDS]
    return assemble(kept)


def window_samples(length_s: float, h: float, n_samples: int) -> int:
    """The samples of a window of ``length_s`` seconds; ``ValueError`` where a record of ``n_samples`` cannot hold two
    of them, or a window is under 200 samples."""
    n = int(round(length_s / h))
    if n < 200 or 2 * n > n_samples:
        raise ValueError(f"windows of {length_s:g} s are {n} samples: the record ({n_samples} samples) must hold two "
                         "windows, each of at least 200 samples")
    return n


def noise_over_time(model, y, h: float, length_s: float, *, fit: Fit | None = None, inputs: dict | None = None,
                    level: float = TOGETHER_LEVEL, progress=None) -> dict:
    """The noise parameters of ``model`` over time in ``y`` (NaN = missing), windows of ``length_s`` seconds;
    ``fit`` the model's fit to the whole of ``y`` (its mean is removed; fitted here when None). Returns the document
    :data:`WINDOWS_MEANING` describes."""
    model = parse_model(model)
    say = progress or (lambda line: None)
    y = np.asarray(y, dtype=np.float64)
    N = len(y)
    n = window_samples(length_s, h, N)
    if fit is None:
        fit = fit_series(model, [y], h, inputs=None if inputs is None else [inputs], intervals=False)[0]
    t = torch.arange(N, dtype=torch.float64) * h
    residual = y - model.mean(fit.values, t, inputs).numpy()[0]
    noise = noise_part(model)
    notes = []
    if any(c.kind == "modifier" for _, c in model.components):
        notes.append("the temperature-driven order is left out of the windows' model (its order constant in each)")
    step = n // 2
    starts = list(range(0, N - n + 1, step))
    fits = []
    for k, a in enumerate(starts):
        say(f"window {k + 1}/{len(starts)}")
        fits.append(fit_series(noise, [residual[a:a + n]], h)[0])
    names = [nm for nm in noise.names if nm in fits[0].free]
    rows = [{"from_s": a * h, "to_s": (a + n) * h, "parameters": {nm: f.values[nm] for nm in names},
             "ci95": {nm: f.ci95.get(nm) for nm in names}} for a, f in zip(starts, fits)]
    W = N // n  # the pieces of the test: the whole record, none shorter than a window
    cuts = [round(k * N / W) for k in range(W + 1)]
    pieces = [(cuts[k], cuts[k + 1]) for k in range(W)]
    say(f"testing the noise parameters' constancy over {W} pieces of the record")
    own = [fit_series(noise, [residual[a:b]], h, intervals=False)[0] for a, b in pieces]
    tg = fit_together(noise, [residual[a:b] for a, b in pieces], h, separate=own, level=level, repeatability=False,
                      recordings=[f"{a * h:g}–{b * h:g} s" for a, b in pieces])
    constancy = [{"name": p["name"], "statistic": p["statistic"], "df": p["df"], "p_value": p["p_value"],
                  "changes": p["differs"]} for p in tg.parameters]
    changes = []
    changing = [p for p in tg.parameters if p["differs"]]
    if changing:
        joint, x = tg.pooled
        for p in changing:
            say(f"locating the change of {p['name']}")
            changes.append(_locate(noise, joint, x, tg, p, residual, pieces, h))
        changes = _merge(changes, n * h)
    return {"length_s": n * h, "rows": rows, "constancy": constancy, "changes": changes,
            "threshold": tg.threshold, "level": level, "model": noise.spec, "notes": notes}


def _locate(noise, joint, x, tg, p: dict, residual, pieces: list, h: float) -> dict:
    """The change of parameter ``p``: the boundary between pieces that maximises the pooled likelihood with the
    parameter one value before and another after, refined on the record over the pieces either side."""
    i = noise.names.index(p["name"])
    W = len(pieces)
    N = pieces[-1][1]
    own = [f.u.detach().clone() for f in tg.separate]
    best = None
    for k in range(1, W):
        groups = (np.arange(W) >= k).astype(np.int64)
        new, x2, ll2 = regrouped(joint, x, i, groups, [own], each=False)
        if best is None or ll2 > best[0]:
            best = (ll2, k, new, x2)
    _, k, new, x2 = best
    before, after = _values(noise, new.unpack(x2, 0), h), _values(noise, new.unpack(x2, W - 1), h)
    span = (pieces[k - 1][0], pieces[k][1])  # the pieces either side of the boundary
    grid = np.unique(np.linspace(span[0] + 20, span[1] - 20, 41).astype(int))
    y = np.asarray(residual)
    lls = []
    for s in grid:  # the span split at s, the values before and after held
        a, b = y[span[0]:s], y[s:span[1]]
        lls.append(float(exact_loglik(noise, before, centred(noise, a), h)[0])
                   + float(exact_loglik(noise, after, centred(noise, b), h)[0]))
    at = int(grid[int(np.argmax(lls))])
    at_s, T = at * h, N * h
    if at_s < EDGE_SHARE * T:
        advice = f"the first {at_s:.1f} s differ: leave them out (--exclude 0:{at_s:.1f})"
    elif at_s > (1 - EDGE_SHARE) * T:
        advice = f"the last {T - at_s:.1f} s differ: leave them out (--exclude {at_s:.1f}:{T:.1f})"
    else:
        advice = (f"the noise changes at {at_s:.1f} s, within the record: check the two parts apart "
                  f"(--exclude 0:{at_s:.1f}, --exclude {at_s:.1f}:{T:.1f})")
    return {"at_s": at_s, "parameters": [p["name"]], "p_value": p["p_value"],
            "before": {p["name"]: before[p["name"]]}, "after": {p["name"]: after[p["name"]]}, "advice": advice}


def _merge(changes: list, length_s: float) -> list:
    """Changes of several parameters within half a window of each other as one."""
    changes = sorted(changes, key=lambda c: c["at_s"])
    out = []
    for c in changes:
        if out and abs(c["at_s"] - out[-1]["at_s"]) <= 0.5 * length_s:
            last = out[-1]
            last["parameters"] += c["parameters"]
            last["before"].update(c["before"])
            last["after"].update(c["after"])
            last["p_value"] = min(last["p_value"], c["p_value"])
        else:
            out.append(dict(c))
    return out

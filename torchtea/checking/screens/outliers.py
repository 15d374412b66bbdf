"""The screen of spikes: every innovation beyond the extremes law's bound, set aside and the filter run again until
no new one appears; the data decide how many (``spikes:K``)."""
from __future__ import annotations

import numpy as np

from ...core.search import max_abs_bound, max_abs_logp
from ...noise.components.outliers import Spikes
from .registry import NotScreened, register_screen


def find(comp, model, values, y, h, inputs, inn, level: float) -> tuple[list, float]:
    """The samples of the spikes (sorted) and the log p-value of the largest |z| of ``inn`` under the model: every
    standardised innovation beyond the bound c with P(max |z| > c) = ``level`` over the n observed samples, the
    samples found set aside (missing) and the filter run again, ``comp.ROUNDS`` times at most, until no new one is
    beyond the bound. Raises :class:`NotScreened` for more than ``comp.MAX_SPIKES``."""
    from scipy.ndimage import maximum_filter1d

    z = inn.z
    ok = np.isfinite(z)
    n = int(ok.sum())
    logp = max_abs_logp(float(np.max(np.abs(z[ok]))) if n else 0.0, n)
    found: list = []
    y = np.asarray(y, dtype=np.float64)
    for _ in range(comp.ROUNDS):
        ok = np.isfinite(z)
        bound = max_abs_bound(int(ok.sum()), level)
        a = np.abs(np.where(ok, z, 0.0))
        # only the largest within ±NEAR samples: the innovation after a spike carries −gain × spike and can be
        # beyond the bound too; the filter rerun without the spike tells whether it is one
        peak = a >= maximum_filter1d(a, 2 * comp.NEAR + 1, mode="constant")
        new = [int(k) for k in np.nonzero((a > bound) & peak)[0] if k not in found]
        if not new:
            break
        found += new
        if len(found) > comp.MAX_SPIKES:
            raise NotScreened(f"{len(found)} or more innovations beyond the extremes bound: heavy-tailed noise, "
                              f"not isolated spikes (at most {comp.MAX_SPIKES})")
        y2 = y.copy()
        y2[found] = np.nan
        z = inn.again(y2).z
    if not found:  # nothing beyond the bound: the largest, so that the screen has a statistic (and fails)
        found = [int(np.nanargmax(np.abs(inn.z)))]
    return sorted(found), logp


def found_in(comp, ctx) -> tuple[list, float]:
    """:func:`find` on the check's model and innovations, once per check (kept in ``ctx.memo``)."""
    key = ("spikes", ctx.model.spec)
    if key not in ctx.memo:
        ctx.memo[key] = find(comp, ctx.model, dict(ctx.fit.values), ctx.y, ctx.h, ctx.inputs, ctx.inn,
                             ctx.extremes_level)
    return ctx.memo[key]


def configure(comp, ctx) -> str:
    """``spikes:K``, K the spikes found."""
    return f"{comp.name}:{len(found_in(comp, ctx)[0])}"


@register_screen(Spikes, "largest |z| against its exact law, P(max > m) = 1 − (1 − 2Φ(−m))ⁿ; the outliers set aside "
                         "until none is left", configure=configure)
def spikes(comp, ctx):
    """The spikes :func:`find` gives, their sizes by GLS (the whitened impulses, jointly, the model held): the
    statistic is their exact likelihood-ratio, the p-value that of the largest |z| under the model (the
    extremes diagnostic's exact law: it is what decides whether there is any spike)."""

    ks, logp = found_in(comp, ctx)
    added = dict(ctx.alt.components)[ctx.label]
    if added.count != len(ks):
        raise NotScreened(f"the model was extended by {added.count} spikes, {len(ks)} were found")
    X = np.zeros((len(ks), len(ctx.y)))
    X[np.arange(len(ks)), ks] = 1.0
    lr, beta = ctx.inn.linear_lr(X)
    values = {}
    for j, (k, b) in enumerate(zip(ks, np.atleast_1d(beta)), start=1):
        values[f"{ctx.label}.size{j}"] = float(b)
        values[f"{ctx.label}.t{j}"] = float(ctx.t[k])
    times = ", ".join(f"{ctx.t[k]:.2f} s" for k in ks[:8]) + (f" and {len(ks) - 8} more" if len(ks) > 8 else "")
    return float(lr), float(logp), values, f"{len(ks)} spike(s) at {times}"

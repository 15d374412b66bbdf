"""Screens of the levels: a ramp (the exact likelihood-ratio of the whitened time) and a step (the best of a few
candidate times, Bonferroni over every split)."""
from __future__ import annotations

import math

import numpy as np

from ...noise.components.levels import Ramp, Step
from .registry import register_screen


@register_screen(Ramp, "exact LR (whitened regressor), χ²₁")
def ramp(comp, ctx):
    """The exact likelihood-ratio at the fitted noise parameters, by least squares of the innovations on the
    whitened time (mean and noise parameters are orthogonal in a Gaussian model: holding the latter is
    asymptotically exact)."""
    from scipy import stats

    lr, beta = ctx.inn.linear_lr(ctx.t - ctx.t.mean())
    return lr, stats.chi2.logsf(lr, 1), {f"{ctx.label}.slope": float(beta[0])}, ""


def _tops(score, k: int, gap: int) -> list:
    """The indices of the ``k`` largest finite scores at least ``gap`` apart."""
    score = np.array(score, dtype=np.float64)
    out = []
    for _ in range(k):
        i = int(np.argmax(score))
        if not np.isfinite(score[i]):
            break
        out.append(i)
        score[max(0, i - gap):i + gap + 1] = -np.inf
    return out


@register_screen(Step, "exact LR at the best candidate time, Bonferroni over the N−1 splits")
def step(comp, ctx):
    """A step's time is searched among a few candidates — the least-squares splits of the model's residual
    (where a step shows in a model without a slow part) and the largest innovations (where it shows in a model
    with a random walk, which absorbs it after one sample) — and its exact likelihood-ratio (the model held,
    the whitened step) taken at the best. The p-value pays for a search over every split: Bonferroni over the
    N−1 of them (a bound, whatever the model's correlation)."""
    from scipy import stats

    y, N = ctx.y, len(ctx.y)
    ok = ~np.isnan(y)
    resid = np.where(ok, ctx.inn.y - ctx.inn.mean, 0.0)
    ks = [k + 1 for k in _tops(comp.split_scores(resid, ok), 4, max(1, N // 50))]  # starts at sample k
    z = np.where(np.isfinite(ctx.inn.z), np.abs(ctx.inn.z), -np.inf)
    z[0] = -np.inf  # a step at the first sample is the level
    ks = sorted(set(ks) | set(_tops(z, 4, 10)))
    X = (np.arange(N)[None, :] >= np.asarray(ks)[:, None]).astype(np.float64)
    lr, beta, _ = ctx.inn.scan_lr(X)
    g = int(np.argmax(lr))
    logp = min(0.0, math.log(N - 1) + float(stats.chi2.logsf(lr[g], 1)))
    return float(lr[g]), logp, {f"{ctx.label}.size": float(beta[g]), f"{ctx.label}.t_step": float(ctx.t[ks[g]])}, ""

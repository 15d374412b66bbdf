"""Outliers: spikes at located samples, each with its own size."""
from __future__ import annotations

import numpy as np
import torch

from ...core.search import max_abs_bound, max_abs_logp
from .base import Component, NotScreened, ParamSpec


class Spikes(Component):
    r"""Isolated spikes (shocks, a knock on the bench, a corrupted sample): ``count`` additive outliers, spike j of
    size :math:`s_j` at sample :math:`k_j` (time :math:`t_j`), :math:`\mu_k = \sum_j s_j [k = k_j]` — the additive
    outlier of time-series analysis (Box & Tiao 1975; Chen & Liu 1993). Written ``spikes:K`` in a spec (K its count).
    A handful of 6–10 σ spikes moves no averaged diagnostic (NIS windows, Allan deviation, spectrum) but wrecks a
    fit: the white level absorbs them, and an Allan line fit breaks on them. ``check`` finds them with the
    ``extremes`` diagnostic's law: every standardised innovation beyond the bound that n samples allow at the
    diagnostic's level, the samples found set aside (missing) and the model's filter run again until no new one
    appears (a spike's neighbours are disturbed through the filter's gains; so is the bound, by the spike's own
    weight). Sizes are GLS at the model's noise parameters (whitened impulses), times the samples found; both are
    held in every fit (a time is not a smooth parameter, and a size with its time fixed is a linear mean term,
    orthogonal to the noise parameters) and both count as estimated in BIC (2K parameters)."""

    name = "spikes"
    kind = "mean"
    add_again = True
    screen_test = "largest |z| against its exact law, P(max > m) = 1 − (1 − 2Φ(−m))ⁿ; the outliers set aside until none is left"
    screen_order = 60
    explains = ("extremes",)
    needs_argument = "spikes need their count: spikes:K (check finds the spikes and their count itself)"
    #: more outliers than this are not isolated spikes but heavy-tailed noise, which no mean term describes
    MAX_SPIKES = 50
    #: how many times the filter is rerun with the spikes found set aside
    ROUNDS = 10
    #: in one round, an exceedance counts only where it is the largest within this many samples either side
    NEAR = 3
    WORDS = "the sample of an outlier beyond the extremes bound (held): no interval"
    SIZE_WORDS = ("GLS at the noise parameters of the check that found it, or by hand the excess over its neighbours' "
                  "median (held in the fits): no interval")

    def __init__(self, count: int = 0):
        self.count = int(count)
        self.params = tuple(p for j in range(1, self.count + 1)
                            for p in (ParamSpec(f"size{j}", "free", "units"),
                                      ParamSpec(f"t{j}", "free", "t (s from the first sample)")))
        self.held = {p.name: self.WORDS if p.name.startswith("t") else self.SIZE_WORDS for p in self.params}
        self.located = tuple(p.name for p in self.params)

    @property
    def token(self):
        return f"{self.name}:{self.count}"

    def configured(self, argument):
        try:
            count = int(argument)
        except ValueError:
            count = 0
        if not 1 <= count <= self.MAX_SPIKES:
            raise ValueError(f"spikes:{argument}: the count must be a whole number from 1 to {self.MAX_SPIKES}")
        return Spikes(count)

    def token_for(self, label, values):
        return f"{self.name}:{sum(1 for n in values if n.startswith(f'{label}.t'))}"

    def mean(self, v, t, inputs):
        h = float(t[1] - t[0]) if t.shape[-1] > 1 else 1.0
        B = v["size1"].shape[0]
        out = t.new_zeros(B, t.shape[-1])
        for j in range(1, self.count + 1):
            at = (torch.abs(t - v[f"t{j}"].unsqueeze(-1)) < 0.5 * h).to(t.dtype)  # (B, N): the spike's sample
            out = out + v[f"size{j}"].unsqueeze(-1) * at
        return out

    def typical(self, param, h, t_ref):
        j = int(param[4:] if param.startswith("size") else param[1:])
        return 0.05 * (-1) ** j if param.startswith("size") else round((5.0 + 10.0 * (j - 1)) / h) * h

    @classmethod
    def find(cls, model, values, y, h, inputs, inn, level: float) -> tuple[list, float]:
        """The samples of the spikes (sorted) and the log p-value of the largest |z| of ``inn`` under the model: every
        standardised innovation beyond the bound c with P(max |z| > c) = ``level`` over the n observed samples, the
        samples found set aside (missing) and the filter run again, :attr:`ROUNDS` times at most, until no new one is
        beyond the bound. Raises :class:`NotScreened` for more than :attr:`MAX_SPIKES`."""
        from scipy.ndimage import maximum_filter1d


        z = inn.z
        ok = np.isfinite(z)
        n = int(ok.sum())
        logp = max_abs_logp(float(np.max(np.abs(z[ok]))) if n else 0.0, n)
        found: list = []
        y = np.asarray(y, dtype=np.float64)
        for _ in range(cls.ROUNDS):
            ok = np.isfinite(z)
            bound = max_abs_bound(int(ok.sum()), level)
            a = np.abs(np.where(ok, z, 0.0))
            # only the largest within ±NEAR samples: the innovation after a spike carries −gain × spike and can be
            # beyond the bound too; the filter rerun without the spike tells whether it is one
            peak = a >= maximum_filter1d(a, 2 * cls.NEAR + 1, mode="constant")
            new = [int(k) for k in np.nonzero((a > bound) & peak)[0] if k not in found]
            if not new:
                break
            found += new
            if len(found) > cls.MAX_SPIKES:
                raise NotScreened(f"{len(found)} or more innovations beyond the extremes bound: heavy-tailed noise, "
                                  f"not isolated spikes (at most {cls.MAX_SPIKES})")
            y2 = y.copy()
            y2[found] = np.nan
            z = inn.again(y2).z
        if not found:  # nothing beyond the bound: the largest, so that the screen has a statistic (and fails)
            found = [int(np.nanargmax(np.abs(inn.z)))]
        return sorted(found), logp

    def _found(self, ctx) -> tuple[list, float]:
        """:meth:`find` on the check's model and innovations, once per check (kept in ``ctx.memo``)."""
        key = ("spikes", ctx.model.spec)
        if key not in ctx.memo:
            ctx.memo[key] = self.find(ctx.model, dict(ctx.fit.values), ctx.y, ctx.h, ctx.inputs, ctx.inn,
                                      ctx.extremes_level)
        return ctx.memo[key]

    def configure(self, ctx):
        return f"{self.name}:{len(self._found(ctx)[0])}"

    def screen(self, ctx):
        """The spikes :meth:`find` gives, their sizes by GLS (the whitened impulses, jointly, the model held): the
        statistic is their exact likelihood-ratio, the p-value that of the largest |z| under the model (the
        extremes diagnostic's exact law: it is what decides whether there is any spike)."""

        ks, logp = self._found(ctx)
        comp = dict(ctx.alt.components)[ctx.label]
        if comp.count != len(ks):
            raise NotScreened(f"the model was extended by {comp.count} spikes, {len(ks)} were found")
        X = np.zeros((len(ks), len(ctx.y)))
        X[np.arange(len(ks)), ks] = 1.0
        lr, beta = ctx.inn.linear_lr(X)
        values = {}
        for j, (k, b) in enumerate(zip(ks, np.atleast_1d(beta)), start=1):
            values[f"{ctx.label}.size{j}"] = float(b)
            values[f"{ctx.label}.t{j}"] = float(ctx.t[k])
        times = ", ".join(f"{ctx.t[k]:.2f} s" for k in ks[:8]) + (f" and {len(ks) - 8} more" if len(ks) > 8 else "")
        return float(lr), float(logp), values, f"{len(ks)} spike(s) at {times}"

    def fit_residual(self, label, resid, t, ok, h, start, inputs):
        """The ``count`` samples farthest from the median of their ±5 neighbours (a local level: a wander or a step
        does not count), in units of the median absolute deviation of those excesses (a scale the spikes do not
        inflate); each spike's size its excess. A start for a model written by hand: ``check`` finds the spikes by
        the extremes law and their sizes by GLS (:meth:`screen`)."""
        from scipy.ndimage import generic_filter

        r = np.where(ok, resid, np.nan)
        fill = np.where(ok, resid, np.nanmedian(r))
        local = generic_filter(fill, lambda w: np.median(np.r_[w[:5], w[6:]]), size=11, mode="nearest")
        ex = np.where(ok, fill - local, 0.0)
        mad = float(np.median(np.abs(ex[ok]))) or 1.0
        score = np.where(ok, np.abs(ex) / mad, -np.inf)
        ks = sorted(int(k) for k in np.argsort(-score)[:self.count])
        out = {}
        for j, k in enumerate(ks, start=1):
            size = float(ex[k])
            resid[k] -= size
            out[f"{label}.size{j}"] = size
            out[f"{label}.t{j}"] = float(t[k])
        return out

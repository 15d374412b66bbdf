"""The levels' starts: the offset at the mean, the ramp by regression, a step at its least-squares location, and the
profile-likelihood interval of a step's time."""
from __future__ import annotations

import math

import numpy as np

from ...noise.components import Offset, Ramp, Step
from .registry import Starts, register_start


@register_start(Offset)
class OffsetStarts(Starts):
    """The series' mean (then the mean of what the other means leave)."""

    def start(self, comp, param, data):
        return float(data.y.mean())


@register_start(Ramp)
class RampStarts(Starts):
    """By linear regression on t − t̄."""

    def regressors(self, comp, label, t, inputs, ok):
        return {}, [(f"{label}.slope", t - t[ok].mean())]


@register_start(Step)
class StepStarts(Starts):
    """The least-squares location of one step in the residual and the size there; its time's interval by profile
    likelihood."""

    #: 2Δℓ bound of the time's 95 % set. The location of a step is not a regular parameter: 2(ℓ̂ − ℓ(t₀)) at the
    #: true time is not χ²₁ but, in the Brownian limit, twice the larger of two independent Exp(1) (the supremum of
    #: W(s) − |s|/2 on either side; Hinkley 1970, Siegmund 1988), whose 95 % point is −2 ln(1 − √0.95) = 7.35 —
    #: χ²₁'s 3.84 covered 16 of 24 step cases of the random study
    INTERVAL_BOUND = -2.0 * math.log(1.0 - math.sqrt(0.95))
    #: the widest window (samples either side of the fitted time) the interval's search reaches
    INTERVAL_HALF = 800
    #: how its time's interval is made (:meth:`located_intervals`)
    INTERVAL = ("profile likelihood over the step's time, the other parameters held (2Δℓ ≤ 7.35, the change-point "
                "limit's 95 % point; hull)")

    def fit_residual(self, comp, label, resid, t, ok, h, start, inputs):
        # least squares for one step in white noise (the raw |c_k| would be pulled towards the middle)
        k = int(np.argmax(comp.split_scores(resid, ok))) + 1  # the step is between samples k−1 and k
        before, after = ok[:k], ok[k:]
        size = float(resid[k:][after].mean() - resid[:k][before].mean()) if before.any() and after.any() else 0.0
        resid[ok & (np.arange(len(resid)) >= k)] -= size
        return {f"{label}.size": size, f"{label}.t_step": float(t[k])}

    def located_intervals(self, comp, label, model, values, y, h, inputs, innovations=None):
        """The time's 95 % set by profile likelihood: the exact likelihood-ratio of a step at each sample near the
        fitted time, its size at its GLS value and every other parameter held (the model's innovations without this
        step, the whitened step columns: :meth:`~torchtea.fitting.innovations.Innovations.scan_lr`), and the samples
        within :attr:`INTERVAL_BOUND` of the best; the window doubles (±50 samples to ±:attr:`INTERVAL_HALF`) until
        the set ends inside it. The hull is reported (the set can have holes). Its coverage is measured in
        experiments/check (random study)."""
        name = f"{label}.t_step"
        t = np.arange(len(y)) * h
        k0 = int(round(values[name] / h))
        without = {**values, f"{label}.size": 0.0}
        inn = innovations(without)
        crit = self.INTERVAL_BOUND
        half = 50
        lrs = {}
        while True:
            ks = np.arange(max(1, k0 - half), min(len(y) - 1, k0 + half) + 1)
            todo = np.array([k for k in ks if k not in lrs])
            for i in range(0, len(todo), 200):  # 200 whitened columns at a time (memory)
                part = todo[i:i + 200]
                X = (np.arange(len(y))[None, :] >= part[:, None]).astype(np.float64)
                lrs.update(zip(part.tolist(), inn.scan_lr(X, draws=0)[0].tolist()))
            lr = np.array([lrs[k] for k in ks])
            inside = ks[lr >= lr.max() - crit]
            edge = inside.min() == ks[0] and ks[0] > 1 or inside.max() == ks[-1] and ks[-1] < len(y) - 1
            if not edge or half >= self.INTERVAL_HALF:
                break
            half *= 2
        words = self.INTERVAL + (f" — reaches the ±{self.INTERVAL_HALF}-sample window searched: wider than shown"
                                 if edge else "")
        return {name: ((float(t[inside.min()]), float(t[inside.max()])), words)}

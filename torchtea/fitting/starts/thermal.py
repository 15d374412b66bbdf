"""The temperature effects' starts: the bias per °C by regression, a lag's β by least squares over a grid of lags,
the temperature-driven order's slope at 0."""
from __future__ import annotations

import numpy as np
import torch

from ...noise.components import TemperatureBias, TemperatureOrder, ThermalLag
from .registry import Starts, register_start


@register_start(TemperatureBias)
class TemperatureBiasStarts(Starts):
    """By linear regression on the temperature about its mean."""

    def regressors(self, comp, label, t, inputs, ok):
        T = np.asarray(inputs["temperature"], dtype=np.float64)
        tref = float(np.nanmean(T))
        return {f"{label}.t_ref": tref}, [(f"{label}.bias_per_degC", T - tref)]


@register_start(ThermalLag)
class ThermalLagStarts(Starts):
    """β by least squares at each lag of a log-spaced grid (one sample to the record), the best lag kept."""

    def fit_residual(self, comp, label, resid, t, ok, h, start, inputs):
        """β by least squares for each τ of the lag grid (:meth:`~torchtea.noise.components.ThermalLag.lags`), the
        τ of the smallest residual kept."""
        T = np.asarray(inputs["temperature"], dtype=np.float64)
        t_ref = float(np.nanmean(T))
        best = None
        for tau in comp.lags(h, len(resid)):
            x = comp.lagged(T, torch.tensor([tau]), h)[0].numpy()[ok]
            x = x - x.mean()
            beta = float(x @ resid[ok] / (x @ x)) if x @ x > 0 else 0.0
            rss = float(np.sum((resid[ok] - beta * x) ** 2))
            if best is None or rss < best[0]:
                best = (rss, tau, beta)
        _, tau, beta = best
        x = comp.lagged(T, torch.tensor([tau]), h)[0].numpy()
        resid[ok] -= beta * (x[ok] - x[ok].mean())
        return {f"{label}.bias_per_degC": beta, f"{label}.tau_s": float(tau), f"{label}.t_ref": t_ref}


@register_start(TemperatureOrder)
class TemperatureOrderStarts(Starts):
    """The slope per °C at 0, the reference at the mean temperature."""

    def regressors(self, comp, label, t, inputs, ok):
        """Not a mean: only its reference (the mean temperature), and γ = 0 to start from."""
        return {f"{label}.t_ref": float(np.nanmean(np.asarray(inputs["temperature"], dtype=np.float64))),
                f"{label}.order_per_degC": 0.0}, []

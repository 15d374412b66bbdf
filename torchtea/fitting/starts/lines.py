"""The lines' starts: the residual periodogram's highest peak (a sinusoid), the chirp search (a drifting line), each
refined, amplitude and phase by least squares."""
from __future__ import annotations

import math

import numpy as np

from ...core.search import chirp_search, refine_chirp, refine_frequency
from ...noise.components import DriftingLine, Sinusoid
from .registry import Starts, register_start


@register_start(Sinusoid)
class SinusoidStarts(Starts):
    """The residual periodogram's highest peak, refined; amplitude and phase by least squares."""

    def start(self, comp, param, data):
        return {"frequency_hz": 0.1 / data.h, "amplitude": math.sqrt(data.var) / 10.0, "phase": 0.0}[param]

    def fit_residual(self, comp, label, resid, t, ok, h, start, inputs):
        """The residual periodogram's highest peak (not the trend's three lowest bins), its frequency refined,
        amplitude and phase by least squares."""
        N = len(resid)
        r = np.where(ok, resid, 0.0)
        spec = np.abs(np.fft.rfft(r)) ** 2
        spec[:3] = 0.0  # not the trend
        j = int(np.argmax(spec))
        f0 = refine_frequency(r, j / (N * h), h)
        w = 2 * np.pi * f0 * t
        X = np.stack([np.sin(w), np.cos(w)], 1)
        coef, *_ = np.linalg.lstsq(X[ok], resid[ok], rcond=None)
        resid[ok] -= X[ok] @ coef
        return {f"{label}.frequency_hz": f0, f"{label}.amplitude": float(math.hypot(*coef)),
                f"{label}.phase": float(math.atan2(coef[1], coef[0]))}


@register_start(DriftingLine)
class DriftingLineStarts(Starts):
    """The chirp search on the residual, refined; amplitude and phase by least squares."""

    def start(self, comp, param, data):
        return {"frequency_hz": 0.1 / data.h, "rate_hz_per_s": 0.0, "amplitude": math.sqrt(data.var) / 10.0,
                "phase": 0.0}[param]

    def fit_residual(self, comp, label, resid, t, ok, h, start, inputs):
        """The chirp search on the residual, refined; amplitude and phase by least squares."""
        r = np.where(ok, resid, np.nan)
        found = chirp_search(r, h)
        f0, f1 = refine_chirp(r, found["f0_hz"], found["rate_hz_per_s"], h)
        X = comp.columns(f0, f1, t).T
        coef, *_ = np.linalg.lstsq(X[ok], resid[ok], rcond=None)
        resid[ok] -= X[ok] @ coef
        return {f"{label}.frequency_hz": f0, f"{label}.rate_hz_per_s": f1,
                f"{label}.amplitude": float(math.hypot(*coef)), f"{label}.phase": float(math.atan2(coef[1], coef[0]))}

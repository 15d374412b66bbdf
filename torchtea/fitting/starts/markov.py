"""The integer-order states' starts: strengths set against the model's spectrum at the lowest Fourier frequency, a
resonance's frequency where the data's spectrum stands highest above its trend."""
from __future__ import annotations

import math

import numpy as np
import torch

from ...noise.components import GaussMarkov, RandomWalk, Resonance
from .registry import Starts, register_start


def level_at_lowest(model, values, h, n) -> tuple[float, float]:
    """``(ω₁, S(ω₁))``: the lowest Fourier frequency of ``n`` samples and ``model``'s spectrum there at ``values``."""
    omega1 = torch.tensor([2 * math.pi / n], dtype=torch.float64)
    return float(omega1), float(model.spectrum(values, omega1, h)[0, 0])


@register_start(RandomWalk)
class RandomWalkStarts(Starts):
    """σ from the series' variance over its length; refits from σ at 10 % and 100 % of the model's spectrum at
    the lowest Fourier frequency."""

    def start(self, comp, param, data):
        return math.sqrt(max(data.var, 1e-12) / (len(data.y) * data.h)) / 10.0

    def scale_drive(self, comp, label, v, s, fixed):
        if f"{label}.sigma" not in fixed:
            v[f"{label}.sigma"] = v[f"{label}.sigma"] * math.sqrt(s) * 0.1

    @staticmethod
    def sigma(share, model, values, h, n):
        """The σ whose spectrum at ω₁ is ``share`` × the model's there: S_rw(ω₁) = σ²h/(2π·4 sin²(ω₁/2))."""
        omega1, level = level_at_lowest(model, values, h, n)
        return math.sqrt(share * level * 2 * math.pi * 4 * math.sin(omega1 / 2) ** 2 / h)

    def strengths(self, comp, label, model, values, h, n):
        return [{f"{label}.sigma": self.sigma(share, model, values, h, n)} for share in (0.1, 1.0)]

    def vanishing(self, comp, label, model, values, h, n):
        return {f"{label}.sigma": self.sigma(1e-8, model, values, h, n)}


@register_start(GaussMarkov)
class GaussMarkovStarts(Starts):
    """σ a tenth of the series' deviation, τ a tenth of the record; refits from τ at 5 % and 30 % of the record,
    σ meeting the model's spectrum at the lowest Fourier frequency."""

    def start(self, comp, param, data):
        n = len(data.y)
        return {"sigma": math.sqrt(max(data.var, 1e-12)) / 10.0, "tau_s": n * data.h / 10.0}[param]

    @staticmethod
    def sigma(share, model, values, h, n, tau):
        """The σ whose spectrum at ω₁ is ``share`` × the model's there (correlation time ``tau``)."""
        omega1, level = level_at_lowest(model, values, h, n)
        a = math.exp(-h / tau)
        return math.sqrt(share * level * 2 * math.pi * (1 - 2 * a * math.cos(omega1) + a * a) / (1 - a * a))

    def strengths(self, comp, label, model, values, h, n):
        out = []
        for frac in (0.05, 0.3):  # correlation times of 5 % and 30 % of the record
            tau = frac * n * h
            out.append({f"{label}.sigma": self.sigma(1.0, model, values, h, n, tau), f"{label}.tau_s": tau})
        return out

    def vanishing(self, comp, label, model, values, h, n):
        tau = 0.1 * n * h
        return {f"{label}.sigma": self.sigma(1e-8, model, values, h, n, tau), f"{label}.tau_s": tau}


def band(y, h) -> tuple[float, float]:
    """The frequency (Hz) where the data's Welch spectrum stands highest above its own smooth trend (a running median
    over ±1/16 of the band, in log), above 2 % of the Nyquist frequency, and that excess (ratio): a resonance's start
    by hand (``check`` screens it by the band search of the innovations instead)."""
    from scipy.ndimage import median_filter
    from scipy.signal import welch

    x = np.asarray(y, dtype=np.float64)
    x = x[np.isfinite(x)]
    f, p = welch(x - x.mean(), fs=1.0 / h, nperseg=min(512, len(x)))
    lp = np.log(np.maximum(p, 1e-300))
    trend = median_filter(lp, size=max(5, len(lp) // 8) | 1, mode="nearest")
    ok = (f > 0.02 * f[-1]) & (f < f[-1])  # (not the Nyquist bin itself: the frequency is below it)
    k = int(np.argmax(np.where(ok, lp - trend, -np.inf)))
    return float(f[k]), float(np.exp(lp[k] - trend[k]))


@register_start(Resonance)
class ResonanceStarts(Starts):
    """The frequency where the data's Welch spectrum stands highest above its own trend, a band of 2 % of the
    sampling rate, σ a third of the series' deviation."""

    def start(self, comp, param, data):
        if param == "frequency_hz":
            return band(data.y.numpy(), data.h)[0]
        if param == "bandwidth_hz":
            return 0.02 / data.h
        return math.sqrt(max(data.var, 1e-12)) / 3.0

    def scale_drive(self, comp, label, v, s, fixed):
        if f"{label}.sigma" not in fixed:
            v[f"{label}.sigma"] = v[f"{label}.sigma"] * math.sqrt(s) * 0.3

    def vanishing(self, comp, label, model, values, h, n):
        return {f"{label}.frequency_hz": 0.1 / h, f"{label}.bandwidth_hz": 0.02 / h, f"{label}.sigma": 1e-12}

"""Lines: a sinusoid and a line whose frequency drifts linearly."""
from __future__ import annotations

import math

import numpy as np
import torch

from .base import MeanEffect, ParamSpec


class Sinusoid(MeanEffect):
    """A sin(2π f₀ t + φ): a vibration line. Not a spectral density — removed before the Whittle sum."""

    name = "sinusoid"
    params = (ParamSpec("frequency_hz", "positive", "f₀ (Hz)"), ParamSpec("amplitude", "positive", "A (units)"),
              ParamSpec("phase", "free", "φ (rad)"))


    def mean(self, v, t, inputs):
        return v["amplitude"].unsqueeze(-1) * torch.sin(2.0 * math.pi * v["frequency_hz"].unsqueeze(-1) * t
                                                        + v["phase"].unsqueeze(-1))

    def typical(self, param, h, t_ref):
        return {"frequency_hz": 3.37, "amplitude": 0.01, "phase": 0.0}[param]


    # the frequency at the refined periodogram peak (asymptotically efficient in coloured noise, Hannan 1973)
    held = {"frequency_hz": "refined periodogram peak (held in the exact refit): no interval"}


class DriftingLine(MeanEffect):
    r"""A vibration line whose frequency moves linearly in time (a fan or a motor speeding up or slowing down):
    :math:`A \sin(2\pi (f_0 \tau + \tfrac12 f_1 \tau^2) + \varphi)`, τ = t − t̄ the time from the record's
    middle, so f₀ is the frequency there and f₁ its rate (Hz/s). Its power is spread over |f₁| T Hz, so the line
    test, which looks for one frequency, misses it once that is more than a few bins. Found by a chirp search
    (:func:`~torchtea.checking.diagnostics.chirp_search`: dechirp at each rate of a grid, then the line test), f₀ and
    f₁ refined and held (counted in BIC), the amplitude and phase by least squares."""

    name = "drifting-line"
    params = (ParamSpec("frequency_hz", "positive", "f₀ (Hz), at the record's middle"),
              ParamSpec("rate_hz_per_s", "free", "f₁ (Hz/s)"),
              ParamSpec("amplitude", "positive", "A (units)"), ParamSpec("phase", "free", "φ (rad)"))
    held = {"frequency_hz": "chirp search, refined (held in the exact refit): no interval",
            "rate_hz_per_s": "chirp search, refined (held in the exact refit): no interval"}

    def mean(self, v, t, inputs):
        tau = t - t.mean()
        f0, f1 = v["frequency_hz"].unsqueeze(-1), v["rate_hz_per_s"].unsqueeze(-1)
        return v["amplitude"].unsqueeze(-1) * torch.sin(2.0 * math.pi * (f0 * tau + 0.5 * f1 * tau * tau)
                                                        + v["phase"].unsqueeze(-1))

    def typical(self, param, h, t_ref):
        return {"frequency_hz": 12.45, "rate_hz_per_s": -4e-3, "amplitude": 0.01, "phase": 0.0}[param]


    @staticmethod
    def columns(f0: float, f1: float, t) -> np.ndarray:
        tau = np.asarray(t) - np.mean(t)
        w = 2 * np.pi * (f0 * tau + 0.5 * f1 * tau * tau)
        return np.stack([np.sin(w), np.cos(w)])


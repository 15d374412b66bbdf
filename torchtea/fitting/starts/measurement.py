"""The measurement noises' starts: from the white level (half the variance of the first differences, or the
periodogram's level at high frequencies)."""
from __future__ import annotations

import math

import torch

from ...noise.components import Quantisation, White
from .registry import Starts, register_start


@register_start(White)
class WhiteStarts(Starts):
    """Half the white level (half the variance of the first differences; in the grid, the periodogram's level at
    high frequencies)."""

    def start(self, comp, param, data):
        return data.white / 2.0

    def grid_start(self, comp, label, v, white, order, fraction, h):
        v[f"{label}.r"] = white * 0.5


def white_level(model, values, h, n) -> float:
    """The white level of ``model`` at ``values``: its measurement variance, else its spectrum's at ω₁ × 2π (ω₁ the
    lowest Fourier frequency of ``n`` samples)."""
    r = float(model.measurement_variance(values)[0])
    if not r:
        omega1 = torch.tensor([2 * math.pi / n], dtype=torch.float64)
        r = float(model.spectrum(values, omega1, h)[0, 0]) * 2 * math.pi
    return r


@register_start(Quantisation)
class QuantisationStarts(Starts):
    """The step whose Δ²/12 is half the white level; refits from the model's white level."""

    def start(self, comp, param, data):
        return math.sqrt(12.0 * data.white / 2.0)

    def grid_start(self, comp, label, v, white, order, fraction, h):
        v[f"{label}.step"] = math.sqrt(12 * white * 0.5)

    def strengths(self, comp, label, model, values, h, n):
        return [{f"{label}.step": math.sqrt(12 * white_level(model, values, h, n))}]

    def vanishing(self, comp, label, model, values, h, n):
        return {f"{label}.step": math.sqrt(12 * 1e-8 * white_level(model, values, h, n))}

"""Measurement noise: white noise and quantisation."""
from __future__ import annotations

import math

import torch

from .base import MeasurementEffect, ParamSpec


class White(MeasurementEffect):
    """Measurement (ADC) noise ν_k ~ N(0, r): spectrum r/2π."""

    name = "white"
    params = (ParamSpec("r", "positive", "variance (units²)"),)

    def measurement_variance(self, v):
        return v["r"]

    def variance_derivatives(self, v):
        return v["r"], torch.ones_like(v["r"]).unsqueeze(-1)

    def typical(self, param, h, t_ref):
        return 1e-3


    def spectrum(self, v, omega, h):
        return (v["r"] / (2.0 * math.pi)).unsqueeze(-1).expand(-1, omega.shape[-1])

    def spectrum_derivatives(self, v, omega, h):
        S = self.spectrum(v, omega, h)
        return S, torch.full_like(S, 1.0 / (2.0 * math.pi)).unsqueeze(1)


class Quantisation(MeasurementEffect):
    """Quantisation of step Δ, modelled as white noise of variance Δ²/12."""

    name = "quantisation"
    params = (ParamSpec("step", "positive", "Δ (units)"),)

    def measurement_variance(self, v):
        return v["step"] ** 2 / 12.0

    def variance_derivatives(self, v):
        return self.measurement_variance(v), (v["step"] / 6.0).unsqueeze(-1)

    def typical(self, param, h, t_ref):
        return 0.01


    def spectrum(self, v, omega, h):
        return (self.measurement_variance(v) / (2.0 * math.pi)).unsqueeze(-1).expand(-1, omega.shape[-1])

    def spectrum_derivatives(self, v, omega, h):
        S = self.spectrum(v, omega, h)
        return S, (2.0 * S / v["step"].unsqueeze(-1)).unsqueeze(1)

"""The screen of a resonance: the band of the innovations' periodogram with the most power against the model."""
from __future__ import annotations

import math

import torch

from ...core.search import band_search
from ...noise.components.markov import Resonance
from .registry import register_screen


@register_screen(Resonance, "largest band of the innovation periodogram (Gamma sums of 4–256 ordinates, Bonferroni "
                            "over positions and widths)")
def resonance(comp, ctx):
    """The band search on the model's standardised innovations; the start: f_r at the band's centre, B its width,
    σ² the band's excess power over the model there, (ratio − 1) S(ω) × 2 × the band's width in rad/sample."""

    found = band_search(ctx.inn.z, ctx.h)
    w = torch.tensor([2.0 * math.pi * found["centre_hz"] * ctx.h], dtype=torch.float64)
    level = float(ctx.model.spectrum(dict(ctx.fit.values), w, ctx.h)[0, 0])
    dw = 2.0 * math.pi * found["width_hz"] * ctx.h
    sigma = math.sqrt(max(found["ratio"] - 1.0, 0.1) * level * 2.0 * dw)
    lab = ctx.label
    return found["ratio"], found["log_p"], {
        f"{lab}.frequency_hz": found["centre_hz"], f"{lab}.bandwidth_hz": max(found["width_hz"], 2.0 / (len(ctx.y) * ctx.h)),
        f"{lab}.sigma": sigma}, (f"band {found['centre_hz'] - found['width_hz'] / 2:.3g}–"
                                 f"{found['centre_hz'] + found['width_hz'] / 2:.3g} Hz at {found['ratio']:.2f}× "
                                 "the model")

"""Screens of the lines: a sinusoid (the lines diagnostic's test) and a drifting line (the chirp search)."""
from __future__ import annotations

import math

import numpy as np

from ...core.search import chirp_search, refine_chirp, refine_frequency
from ...noise.components.lines import DriftingLine, Sinusoid
from .registry import register_screen


@register_screen(Sinusoid, "largest innovation periodogram line (F(2,200), max over frequencies)")
def sinusoid(comp, ctx):
    """The ``lines`` diagnostic's p-value (the largest innovation periodogram ordinate against its neighbours,
    over all frequencies); the statistic and the start: the whitened sine and cosine at the refined peak."""

    ln = ctx.diagnostic("lines")
    inn, t = ctx.inn, ctx.t
    r = inn.y - inn.mean
    f0 = refine_frequency(np.where(inn.observed, r, 0.0), ln.detail["peak_hz"], ctx.h)
    lr, beta = inn.linear_lr(np.stack([np.sin(2 * np.pi * f0 * t), np.cos(2 * np.pi * f0 * t)]))
    return lr, ln.detail["log_p"], {f"{ctx.label}.frequency_hz": f0,
                                    f"{ctx.label}.amplitude": float(math.hypot(*beta)),
                                    f"{ctx.label}.phase": float(math.atan2(beta[1], beta[0]))}, ""


@register_screen(DriftingLine, "largest dechirped innovation periodogram line (F(2,200), Bonferroni over "
                               "frequencies and rates)")
def drifting_line(comp, ctx):
    """The chirp search on the model's standardised innovations (its p-value, Bonferroni over every frequency
    and rate tested); the statistic and the start: the whitened chirp's sine and cosine at the refined
    (f₀, f₁)."""

    inn, t = ctx.inn, ctx.t
    found = chirp_search(inn.z, ctx.h)
    r = np.where(inn.observed, inn.y - inn.mean, np.nan)
    f0, f1 = refine_chirp(r, found["f0_hz"], found["rate_hz_per_s"], ctx.h)
    lr, beta = inn.linear_lr(comp.columns(f0, f1, t))
    return lr, found["log_p"], {f"{ctx.label}.frequency_hz": f0, f"{ctx.label}.rate_hz_per_s": f1,
                                f"{ctx.label}.amplitude": float(math.hypot(*beta)),
                                f"{ctx.label}.phase": float(math.atan2(beta[1], beta[0]))}, ""

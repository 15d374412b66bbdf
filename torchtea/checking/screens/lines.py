"""Screens of the lines: a sinusoid (the lines diagnostic's test) and a drifting line (the chirp search)."""
from __future__ import annotations

import math

import numpy as np

from ...core.search import chirp_search, refine_chirp, refine_frequency, slow_line
from ...noise.components.lines import DriftingLine, Sinusoid
from .registry import register_screen


@register_screen(Sinusoid, "largest innovation periodogram line: against its neighbours (F(2,200), max over the "
                           "frequencies the lines diagnostic tests) or, below them, against the model (Exp(1), max "
                           "over 3–52 cycles per record); Bonferroni over the two")
def sinusoid(comp, ctx):
    """The ``lines`` diagnostic's p-value (the largest innovation periodogram ordinate against its neighbours, from
    53 cycles per record up) or, where it is smaller, the slow range's (:func:`~torchtea.core.search.slow_line`:
    3–52 cycles, where a line has too few neighbours to be weighed against), doubled for the two; the statistic and
    the start: the whitened sine and cosine at the refined peak."""

    ln = ctx.diagnostic("lines")
    inn, t = ctx.inn, ctx.t
    slow = slow_line(inn.z, ctx.h)
    log_p, peak, note = ln.detail["log_p"], ln.detail["peak_hz"], ""
    if slow["log_p"] < log_p:
        log_p, peak = slow["log_p"], slow["peak_hz"]
        note = (f"a slow line: {slow['cycles']} cycles in the record, {slow['ordinate']:.1f}× the model's level "
                "(a drift the model lacks raises it too)")
    log_p = min(0.0, log_p + math.log(2.0))
    r = inn.y - inn.mean
    f0 = refine_frequency(np.where(inn.observed, r, 0.0), peak, ctx.h)
    lr, beta = inn.linear_lr(np.stack([np.sin(2 * np.pi * f0 * t), np.cos(2 * np.pi * f0 * t)]))
    return lr, log_p, {f"{ctx.label}.frequency_hz": f0,
                       f"{ctx.label}.amplitude": float(math.hypot(*beta)),
                       f"{ctx.label}.phase": float(math.atan2(beta[1], beta[0]))}, note


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

"""Screens of the temperature effects: a bias per °C (the temperature diagnostic's score test), the same through a
first-order lag (the largest likelihood-ratio over a grid of lags) and an order driven by the temperature (an exact
likelihood-ratio over the slope, :func:`scan`)."""
from __future__ import annotations

import math

import numpy as np
import torch

from ...noise.components.thermal import TemperatureBias, TemperatureOrder, ThermalLag
from .registry import NotScreened, register_screen


@register_screen(TemperatureBias, "exact LR (whitened regressor), χ²₁")
def temperature_bias(comp, ctx):
    """The temperature diagnostic's score test, which is this likelihood-ratio (the whitened temperature)."""
    from scipy import stats

    dt = ctx.diagnostic("temperature").detail
    lr = dt["score_bias"]
    return lr, stats.chi2.logsf(lr, 1), {f"{ctx.label}.bias_per_degC": float(dt["bias_per_degC_gls"]),
                                         f"{ctx.label}.t_ref": float(np.mean(ctx.inputs["temperature"]))}, ""


@register_screen(ThermalLag, "exact LR, largest over a grid of lags (whitened; its maximum's null by simulation)")
def thermal_lag(comp, ctx):
    """The exact likelihood-ratio of β at each lag of the component's ``lags`` (the model held; the whitened lagged
    temperature), the largest kept; its p-value is that of the maximum of the grid's correlated statistics
    under the model (:func:`~torchtea.checking.diagnostics.scan_lr`), so the search over τ is paid for."""

    T = np.asarray(ctx.inputs["temperature"], dtype=np.float64)
    taus = comp.lags(ctx.h, len(ctx.y))
    X = comp.lagged(T, torch.as_tensor(taus), ctx.h).numpy()
    lr, beta, logp = ctx.inn.scan_lr(X - X.mean(1, keepdims=True))
    g = int(np.argmax(lr))
    return float(lr[g]), logp, {f"{ctx.label}.bias_per_degC": float(beta[g]), f"{ctx.label}.tau_s": float(taus[g]),
                                f"{ctx.label}.t_ref": float(np.mean(T))}, ""


#: The temperature-order scan stops after its first stage when the parabola through γ = 0, ±δ peaks less than this
#: many nats above the model's ℓ (its LR below 1; passing the screen at 0.05 / 6 effects needs an LR of about 7).
SCAN_QUIET = 0.5


@register_screen(TemperatureOrder, "exact LR over the slope, others held (χ²₁, conservative)")
def temperature_order(comp, ctx):
    """The exact likelihood-ratio over the slope alone, the other parameters held at the fit (:func:`scan`)."""
    from scipy import stats

    lr, g, quiet = scan(ctx)
    if lr is None:
        frac = ctx.model.order_labels[0]
        raise NotScreened(f"the fitted order {ctx.fit.values[f'{frac}.order']:.3g} is at its bound, and no "
                          "slope per °C keeps it inside (0, 1)")
    note = (f"the scan stopped after γ = 0, ±δ: their parabola peaks less than {SCAN_QUIET:g} nat above the "
            "model (a lower bound of the statistic)") if quiet else ""
    return lr, stats.chi2.logsf(lr, 1), {f"{ctx.label}.order_per_degC": g,
                                         f"{ctx.label}.t_ref": float(np.mean(ctx.inputs["temperature"]))}, note


def scan(ctx) -> tuple[float | None, float | None, bool]:
    """2·max Δℓ over the temperature-order slope γ with the other parameters at the fit, the best γ, and whether
    the scan stopped after its first stage (None, None, False when the fitted order is within 10⁻⁶ of its bound 0
    or 1, where no slope keeps it inside).

    ℓ(γ) is sharply peaked (its width is the slope's standard error, often 1 % of the range of slopes that keep
    the order inside (0, 1)), so a coarse grid misses it. Two Newton-like stages, three points each in one
    batched evaluation: a parabola through γ = 0, ±δ (δ = γ_max / 40, γ_max = 0.9 × the largest |γ| that keeps
    the order inside (0, 1) at the recording's temperatures) gives the first step; a parabola
    through the step's ½×, 1×, 2× refines it — unless the first parabola peaks below :data:`SCAN_QUIET` (no
    signal to refine). The best γ evaluated is kept — the statistic is a lower bound of the full maximisation,
    which only makes the test conservative."""
    model, alt, label, fit, inn = ctx.model, ctx.alt, ctx.label, ctx.fit, ctx.inn
    T = np.asarray(ctx.inputs["temperature"], dtype=np.float64)
    frac = model.order_labels[0]
    a0 = fit.values[f"{frac}.order"]
    span = max(float(np.max(np.abs(T - T.mean()))), 1e-9)
    if min(a0, 1 - a0) < 1e-6:  # the order at its bound: no slope keeps it inside (0, 1)
        return None, None, False
    g_max = 0.9 * min(a0, 1 - a0) / span

    def ll(gs):
        gs = np.clip(np.asarray(gs, dtype=np.float64), -g_max, g_max)
        vals = {n: [fit.values[n]] * len(gs) for n in model.names}
        vals[f"{label}.order_per_degC"] = list(gs)
        vals[f"{label}.t_ref"] = [float(T.mean())] * len(gs)
        return gs, ctx.exact_loglik(alt, vals, inputs={"temperature": T})

    def parabola(g3, l3):
        """The maximiser of the parabola through three points and its value (None, None when it is not concave)."""
        if len(set(np.asarray(g3).tolist())) < 3:  # points that coincide (clipped at ±g_max): no parabola
            return None, None
        c2, c1, c0 = np.linalg.solve(np.vander(g3, 3), l3)
        return (None, None) if c2 >= 0 else (-c1 / (2 * c2), c0 - c1 * c1 / (4 * c2))

    d = g_max / 40
    g2_, l2_ = ll([-d, d])  # γ = 0 is the model itself: its ℓ is the fit's, no need to filter again
    g3, l3 = np.array([g2_[0], 0.0, g2_[1]]), np.array([l2_[0], inn.loglik, l2_[1]])
    g1, top = parabola(g3, l3)
    if g1 is None:  # not concave at 0: head up the slope
        g1 = math.copysign(g_max / 4, l3[2] - l3[0])
    gs, ls = [*g3], [*l3]
    # a concave parabola whose peak is less than ½ nat above the fit (an LR below 1, a seventh of what the screen
    # needs) sees no signal, and the refinement, which starts at that peak, would not find one: it is skipped
    quiet = top is not None and top - inn.loglik < SCAN_QUIET
    if abs(g1) > 1e-12 and not quiet:
        g3b, l3b = ll([0.5 * g1, g1, 2.0 * g1])
        gs += [*g3b]
        ls += [*l3b]
        g2, _ = parabola(g3b, l3b)
        if g2 is not None and abs(g2) > 1e-12:
            gc, lc = ll([g2])
            gs += [*gc]
            ls += [*lc]
    k = int(np.argmax(ls))
    return max(0.0, 2.0 * float(ls[k] - inn.loglik)), float(gs[k]), quiet

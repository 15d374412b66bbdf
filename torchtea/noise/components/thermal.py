"""Temperature effects: a bias per °C, the same through a first-order lag, and an order driven by the
temperature."""
from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

from .base import Component, NotScreened, ParamSpec


class TemperatureBias(Component):
    """β (T_k − T_ref) added to the output; T the measured ``temperature`` input (°C), T_ref its mean
    unless fixed."""

    name = "temperature-bias"
    kind = "mean"
    inputs = ("temperature",)
    held = {"t_ref": None}
    params = (ParamSpec("bias_per_degC", "free", "units/°C"), ParamSpec("t_ref", "free", "T_ref (°C)"))

    def mean(self, v, t, inputs):
        T = inputs["temperature"]
        return v["bias_per_degC"].unsqueeze(-1) * (T - v["t_ref"].unsqueeze(-1))

    def typical(self, param, h, t_ref):
        return {"bias_per_degC": 0.02, "t_ref": t_ref}[param]

    def regressors(self, label, t, inputs, ok):
        T = np.asarray(inputs["temperature"], dtype=np.float64)
        tref = float(np.nanmean(T))
        return {f"{label}.t_ref": tref}, [(f"{label}.bias_per_degC", T - tref)]

    screen_test = "exact LR (whitened regressor), χ²₁"
    screen_order = 30
    explains = ("temperature",)

    def screen(self, ctx):
        """The temperature diagnostic's score test, which is this likelihood-ratio (the whitened temperature)."""
        from scipy import stats

        dt = ctx.diagnostic("temperature").detail
        lr = dt["score_bias"]
        return lr, stats.chi2.logsf(lr, 1), {f"{ctx.label}.bias_per_degC": float(dt["bias_per_degC_gls"]),
                                             f"{ctx.label}.t_ref": float(np.mean(ctx.inputs["temperature"]))}, ""


class _FirstOrderLag(torch.autograd.Function):
    r""":math:`y_k = a y_{k-1} + (1-a) T_k`, :math:`y_0 = T_0`, for each coefficient of ``a`` ``(B,)`` (``scipy.signal.
    lfilter``), with its derivative in ``a`` for both modes of automatic differentiation: :math:`z_k = \partial y_k /
    \partial a` obeys :math:`z_k = a z_{k-1} + y_{k-1} - T_k`, :math:`z_0 = 0` (differentiate the recursion), filtered
    alongside. ``T`` is data (no derivative). Returns ``(y, z)``, each ``(B, N)``."""

    @staticmethod
    def forward(a, T):
        from scipy.signal import lfilter

        Tn = T.detach().cpu().numpy()
        ys, zs = [], []
        for x in a.detach().numpy():
            y, _ = lfilter([1.0 - x], [1.0, -x], Tn, zi=[x * Tn[0]])
            ys.append(y)
            zs.append(lfilter([1.0], [1.0, -x], np.concatenate([[0.0], y[:-1] - Tn[1:]])))
        return torch.as_tensor(np.stack(ys)), torch.as_tensor(np.stack(zs))

    @staticmethod
    def setup_context(ctx, inputs, output):
        ctx.mark_non_differentiable(output[1])
        ctx.save_for_backward(output[1])
        ctx.save_for_forward(output[1])

    @staticmethod
    def jvp(ctx, da, dT):
        z, = ctx.saved_tensors
        return z * da.unsqueeze(-1), None

    @staticmethod
    def backward(ctx, gy, gz):
        z, = ctx.saved_tensors
        return (gy * z).sum(-1), None


class ThermalLag(Component):
    r"""A bias that follows the temperature through a first-order lag: :math:`\beta\,(T^{\tau}_k - T_\mathrm{ref})`
    with :math:`T^{\tau}_k = a\,T^{\tau}_{k-1} + (1-a)\,T_k`, :math:`a = e^{-h/\tau}`, :math:`T^{\tau}_0 = T_0` —
    the die is not where the temperature sensor is, and heat takes τ to cross (a lag of 140 s is seen on MEMS
    boards). ``t_ref`` is the mean temperature (held). As τ → 0 it is ``temperature-bias``. Its start: β by least
    squares for each τ of a log-spaced grid (1 s to the record's length), the best τ kept."""

    name = "thermal-lag"
    kind = "mean"
    inputs = ("temperature",)
    params = (ParamSpec("bias_per_degC", "free", "units/°C"), ParamSpec("tau_s", "positive", "τ (s), thermal lag"),
              ParamSpec("t_ref", "free", "T_ref (°C)"))
    held = {"t_ref": None}
    screen_test = "exact LR, largest over a grid of lags (whitened; its maximum's null by simulation)"
    screen_order = 35
    explains = ("temperature",)

    @staticmethod
    def lags(h: float, n: int) -> np.ndarray:
        """The grid of lags (s) its start and screen search: one sample (≈ ``temperature-bias``) to the record."""
        return np.geomspace(h, max(n * h, 2 * h), 20)

    def screen(self, ctx):
        """The exact likelihood-ratio of β at each lag of :meth:`lags` (the model held; the whitened lagged
        temperature), the largest kept; its p-value is that of the maximum of the grid's correlated statistics
        under the model (:func:`~torchtea.checking.diagnostics.scan_lr`), so the search over τ is paid for."""

        T = np.asarray(ctx.inputs["temperature"], dtype=np.float64)
        taus = self.lags(ctx.h, len(ctx.y))
        X = self.lagged(T, torch.as_tensor(taus), ctx.h).numpy()
        lr, beta, logp = ctx.inn.scan_lr(X - X.mean(1, keepdims=True))
        g = int(np.argmax(lr))
        return float(lr[g]), logp, {f"{ctx.label}.bias_per_degC": float(beta[g]), f"{ctx.label}.tau_s": float(taus[g]),
                                    f"{ctx.label}.t_ref": float(np.mean(T))}, ""

    @staticmethod
    def lagged(T: Tensor, tau: Tensor, h: float) -> Tensor:
        """``(B, N)`` the temperature ``(N,)`` through the first-order lags of time constants ``tau`` ``(B,)``;
        differentiable in ``tau`` (:class:`_FirstOrderLag`)."""
        T = torch.as_tensor(T, dtype=torch.float64).reshape(-1)
        a = torch.exp(-h / torch.as_tensor(tau, dtype=torch.float64).reshape(-1))
        return _FirstOrderLag.apply(a, T)[0]

    def mean(self, v, t, inputs):
        h = float(t[1] - t[0]) if t.shape[-1] > 1 else 1.0
        lag = self.lagged(inputs["temperature"], v["tau_s"], h)
        return v["bias_per_degC"].unsqueeze(-1) * (lag - v["t_ref"].unsqueeze(-1))

    def typical(self, param, h, t_ref):
        return {"bias_per_degC": 0.02, "tau_s": 60.0, "t_ref": t_ref}[param]

    def fit_residual(self, label, resid, t, ok, h, start, inputs):
        T = np.asarray(inputs["temperature"], dtype=np.float64)
        t_ref = float(np.nanmean(T))
        best = None
        for tau in self.lags(h, len(resid)):
            x = self.lagged(T, torch.tensor([tau]), h)[0].numpy()[ok]
            x = x - x.mean()
            beta = float(x @ resid[ok] / (x @ x)) if x @ x > 0 else 0.0
            rss = float(np.sum((resid[ok] - beta * x) ** 2))
            if best is None or rss < best[0]:
                best = (rss, tau, beta)
        _, tau, beta = best
        x = self.lagged(T, torch.tensor([tau]), h)[0].numpy()
        resid[ok] -= beta * (x[ok] - x[ok].mean())
        return {f"{label}.bias_per_degC": beta, f"{label}.tau_s": float(tau), f"{label}.t_ref": t_ref}


class TemperatureOrder(Component):
    r"""The fractional component's order driven by temperature: :math:`\alpha_k = \alpha_0 + \gamma (T_k - T_\mathrm{ref})`,
    α₀ the fractional component's ``order`` (its value at T_ref, the mean temperature unless fixed), T the
    measured ``temperature`` input (°C). The GL difference is the paper's A-type (10): step k+1 uses
    :math:`h^{\alpha_{k+1}}` and :math:`c_j(\alpha_{k+1})` for the whole history; α_k is clipped to
    [10⁻⁶, 0.999] (the exponential-sum kernel's range). The pole is fitted as a fraction of its stability
    limit at α₀, so the model is stable at α₀ but need not be at every α_k. The model is not stationary: its spectrum (for the Whittle start) is that at
    T_ref (γ = 0), and γ is fitted by the exact likelihood only."""

    name = "temperature-order"
    kind = "modifier"
    stationary = False
    varies_order = True
    tea_note = ("not a state: KFo estimates the order's variation in time itself (its estimate can be read against "
                "the temperature); the fitted slope per °C is not used")

    def tea_part(self, label, v, h):
        return None
    inputs = ("temperature",)
    held = {"t_ref": None}
    params = (ParamSpec("order_per_degC", "free", "1/°C"), ParamSpec("t_ref", "free", "T_ref (°C)"))

    def validate(self, components, spec):
        names = [c.name for _, c in components]
        if names.count(self.name) > 1 or sum(c.order_param is not None for _, c in components) != 1:
            raise ValueError(f"model {spec!r}: temperature-order drives the order of exactly one fractional "
                             "component, and a model holds one temperature-order")
        if any(c.kind == "filter" for _, c in components):
            raise ValueError(f"model {spec!r}: temperature-order drives the order of one fractional component and "
                             "cannot be combined with a sensor filter (low-pass, digital-filter)")

    def position(self, model):
        if model.order_name is None:
            raise ValueError(f"temperature-order drives a fractional component's order; {model.spec!r} has none")
        return len(model.components)

    def typical(self, param, h, t_ref):
        return {"order_per_degC": 0.03, "t_ref": t_ref}[param]

    def regressors(self, label, t, inputs, ok):
        """Not a mean: only its reference (the mean temperature), and γ = 0 to start from."""
        return {f"{label}.t_ref": float(np.nanmean(np.asarray(inputs["temperature"], dtype=np.float64))),
                f"{label}.order_per_degC": 0.0}, []

    screen_test = "exact LR over the slope, others held (χ²₁, conservative)"
    screen_order = 40
    explains = ("temperature",)

    def screen(self, ctx):
        """The exact likelihood-ratio over the slope alone, the other parameters held at the fit (:meth:`scan`)."""
        from scipy import stats

        lr, g, quiet = self.scan(ctx)
        if lr is None:
            frac = ctx.model.order_labels[0]
            raise NotScreened(f"the fitted order {ctx.fit.values[f'{frac}.order']:.3g} is at its bound, and no "
                              "slope per °C keeps it inside (0, 1)")
        note = (f"the scan stopped after γ = 0, ±δ: their parabola peaks less than {self.SCAN_QUIET:g} nat above the "
                "model (a lower bound of the statistic)") if quiet else ""
        return lr, stats.chi2.logsf(lr, 1), {f"{ctx.label}.order_per_degC": g,
                                             f"{ctx.label}.t_ref": float(np.mean(ctx.inputs["temperature"]))}, note

    #: The temperature-order scan stops after its first stage when the parabola through γ = 0, ±δ peaks less than this
    #: many nats above the model's ℓ (its LR below 1; passing the screen at 0.05 / 6 effects needs an LR of about 7).
    SCAN_QUIET = 0.5

    def scan(self, ctx) -> tuple[float | None, float | None, bool]:
        """2·max Δℓ over the temperature-order slope γ with the other parameters at the fit, the best γ, and whether
        the scan stopped after its first stage (None, None, False when the fitted order is within 10⁻⁶ of its bound 0
        or 1, where no slope keeps it inside).

        ℓ(γ) is sharply peaked (its width is the slope's standard error, often 1 % of the range of slopes that keep
        the order inside (0, 1)), so a coarse grid misses it. Two Newton-like stages, three points each in one
        batched evaluation: a parabola through γ = 0, ±δ (δ = γ_max / 40, γ_max = 0.9 × the largest |γ| that keeps
        the order inside (0, 1) at the recording's temperatures) gives the first step; a parabola
        through the step's ½×, 1×, 2× refines it — unless the first parabola peaks below :attr:`SCAN_QUIET` (no
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
        quiet = top is not None and top - inn.loglik < self.SCAN_QUIET
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

    def orders(self, v: dict, alpha0: Tensor, T: Tensor) -> Tensor:
        """``(B, N)`` orders α_k for ``(B,)`` α₀ and the temperature ``(N,)``."""
        a = alpha0.unsqueeze(-1) + v["order_per_degC"].unsqueeze(-1) * (T - v["t_ref"].unsqueeze(-1))
        return a.clamp(1e-6, 0.999)  # the exponential-sum kernel's range: the lags and the tail see one order

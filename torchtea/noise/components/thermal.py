"""Temperature effects: a bias per °C, the same through a first-order lag, and an order driven by the
temperature."""
from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from .base import MeanEffect, Modifier, ParamSpec


class TemperatureBias(MeanEffect):
    """β (T_k − T_ref) added to the output; T the measured ``temperature`` input (°C), T_ref its mean
    unless fixed."""

    name = "temperature-bias"
    inputs = ("temperature",)
    held = {"t_ref": None}
    params = (ParamSpec("bias_per_degC", "free", "units/°C"), ParamSpec("t_ref", "free", "T_ref (°C)"))

    def mean(self, v, t, inputs):
        T = inputs["temperature"]
        return v["bias_per_degC"].unsqueeze(-1) * (T - v["t_ref"].unsqueeze(-1))

    def typical(self, param, h, t_ref):
        return {"bias_per_degC": 0.02, "t_ref": t_ref}[param]


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


class ThermalLag(MeanEffect):
    r"""A bias that follows the temperature through a first-order lag: :math:`\beta\,(T^{\tau}_k - T_\mathrm{ref})`
    with :math:`T^{\tau}_k = a\,T^{\tau}_{k-1} + (1-a)\,T_k`, :math:`a = e^{-h/\tau}`, :math:`T^{\tau}_0 = T_0` —
    the die is not where the temperature sensor is, and heat takes τ to cross (a lag of 140 s is seen on MEMS
    boards). ``t_ref`` is the mean temperature (held). As τ → 0 it is ``temperature-bias``. Its start: β by least
    squares for each τ of a log-spaced grid (1 s to the record's length), the best τ kept."""

    name = "thermal-lag"
    inputs = ("temperature",)
    params = (ParamSpec("bias_per_degC", "free", "units/°C"), ParamSpec("tau_s", "positive", "τ (s), thermal lag"),
              ParamSpec("t_ref", "free", "T_ref (°C)"))
    held = {"t_ref": None}

    @staticmethod
    def lags(h: float, n: int) -> np.ndarray:
        """The grid of lags (s) its start and screen search: one sample (≈ ``temperature-bias``) to the record."""
        return np.geomspace(h, max(n * h, 2 * h), 20)

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


class TemperatureOrder(Modifier):
    r"""The fractional component's order driven by temperature: :math:`\alpha_k = \alpha_0 + \gamma (T_k - T_\mathrm{ref})`,
    α₀ the fractional component's ``order`` (its value at T_ref, the mean temperature unless fixed), T the
    measured ``temperature`` input (°C). The GL difference is the paper's A-type (10): step k+1 uses
    :math:`h^{\alpha_{k+1}}` and :math:`c_j(\alpha_{k+1})` for the whole history; α_k is clipped to
    [10⁻⁶, 0.999] (the exponential-sum kernel's range). The pole is fitted as a fraction of its stability
    limit at α₀, so the model is stable at α₀ but need not be at every α_k. The model is not stationary: its spectrum (for the Whittle start) is that at
    T_ref (γ = 0), and γ is fitted by the exact likelihood only."""

    name = "temperature-order"
    inputs = ("temperature",)
    held = {"t_ref": None}
    params = (ParamSpec("order_per_degC", "free", "1/°C"), ParamSpec("t_ref", "free", "T_ref (°C)"))

    def typical(self, param, h, t_ref):
        return {"order_per_degC": 0.03, "t_ref": t_ref}[param]

    def orders(self, v: dict, alpha0: Tensor, T: Tensor) -> Tensor:
        """``(B, N)`` orders α_k for ``(B,)`` α₀ and the temperature ``(N,)``."""
        a = alpha0.unsqueeze(-1) + v["order_per_degC"].unsqueeze(-1) * (T - v["t_ref"].unsqueeze(-1))
        return a.clamp(1e-6, 0.999)  # the exponential-sum kernel's range: the lags and the tail see one order

r"""The physical parts of a sensor's noise model, each with named parameters, a spectrum and a state block.

Conventions (ALGORITHMS.md §7): sample time ``h``, ω in rad/sample, two-sided spectra with
``var = ∫_{−π}^{π} S(ω) dω``. The measurement is the sum of the components; a ``low-pass`` filters the
sum of the stochastic components listed before it — state and white alike, as a sensor's digital filter
filters its whole signal — and white / quantisation noise listed after it enters unfiltered (e.g. the
output's rounding): ``fractional+white+low-pass`` filters everything, ``fractional+low-pass+white`` only the
fractional part.

Three kinds of component:

* **state** components (``fractional``, ``random-walk``, ``low-pass``) are linear Gaussian state-space
  blocks — the exact Kalman filter and the simulator stack them (:mod:`torchtea.noise.model`);
* **measurement** components (``white``, ``quantisation``) add independent white noise of variance ``r``;
* **mean** components (``offset``, ``ramp``, ``sinusoid``, ``temperature-bias``) are deterministic functions
  of time and the input channels. The Whittle likelihood removes them by regression first (lines are not
  spectral densities); the exact filter subtracts them.

Parameters are given in natural units (``fractional.order``, ``white.r`` …) and every parameter has a
transform to an unconstrained real number for the optimisers (log for a positive value, logit for a bounded
one). The fractional pole's admissible range depends on the order (stability: ``−2^α < f h^α < 0``), so it
is stored as the fraction ``ρ = −f h^α / 2^α ∈ (0, 1)`` internally and reported as ``f``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor

from ..core.gl import gl_tail_coefficients

__all__ = ["ParamSpec", "Component", "StartData", "COMPONENTS", "ORDER_BOUNDS", "logit"]

#: Orders the ``fractional`` component may take: open interval, the kernel is designed on it.
ORDER_BOUNDS = (0.0, 1.0)


@dataclass(frozen=True)
class ParamSpec:
    """One parameter of a component.

    ``kind``: ``"positive"`` (log transform), ``"bounded"`` (logit on ``bounds``), ``"free"`` (identity),
    ``"fraction"`` (logit on (0, 1): the fractional pole's stability fraction, see the module docstring).
    ``unit`` is what the value means, written next to it in reports.
    """

    name: str
    kind: str
    unit: str
    bounds: tuple = (-math.inf, math.inf)

    def bounded_to_unconstrained(self, x: Tensor) -> Tensor:
        """``logit((x − low)/(high − low))``: a ``bounded`` value on the optimisers' scale."""
        lo, hi = self.bounds
        return logit((x - lo) / (hi - lo))


class StartData(NamedTuple):
    """What a component's :meth:`Component.start` may use: the series ``y`` (tensor), its variance, half the
    variance of its first differences (the white level), the number of state components, the sample time and the
    fractional order to start from."""

    y: Tensor
    var: float
    white: float
    n_state: int
    h: float
    order: float


def logit(p: Tensor) -> Tensor:
    return torch.log(p) - torch.log1p(-p)


class Component:
    """Base class: a named part of the model. Subclasses set ``name``, ``kind`` and ``params``."""

    name: str = ""
    kind: str = ""  # "state", "measurement", "filter", "mean", "modifier" (changes another component)
    params: tuple = ()
    inputs: tuple = ()  # input channels the component reads (e.g. "temperature")

    # ---- spectra (stationary parts) -------------------------------------------------------------
    def spectrum(self, v: dict, omega: Tensor, h: float) -> Tensor:
        """Two-sided spectral density at ω (rad/sample) for parameter values ``v`` (each ``(B,)``) → ``(B, W)``."""
        raise NotImplementedError

    # ---- state blocks ---------------------------------------------------------------------------
    def n_states(self, memory) -> int:
        return 0

    def block(self, v: dict, h: float, memory) -> tuple[Tensor, Tensor]:
        """Transition ``F`` ``(B, n, n)`` and noise loading ``G`` ``(B, n, m)`` of the block (process noise
        ``G ξ_k``, ξ standard normal, so ``Q = G Gᵀ``); the block's output is its state 0."""
        raise NotImplementedError

    # ---- means ------------------------------------------------------------------------------------
    def mean(self, v: dict, t: Tensor, inputs: dict) -> Tensor:
        """Deterministic contribution ``(B, N)`` at times ``t`` (s, from the first sample)."""
        raise NotImplementedError

    def measurement_variance(self, v: dict) -> Tensor:
        raise NotImplementedError

    # ---- how a model holds it ---------------------------------------------------------------------------
    #: at most one in a model (``parse_model`` refuses a second)
    single: bool = False
    #: ``check`` may add it to a model that has it already (a second line)
    add_again: bool = False
    #: it carries the series' constant level: the fits do not centre the series (``offset``)
    level: bool = False

    def position(self, model) -> int:
        """Where :func:`~torchtea.checking.check.extend` inserts it among ``model``'s components (default: at the
        end); raises ``ValueError`` naming what the model lacks when it cannot be added."""
        return len(model.components)

    # ---- values -----------------------------------------------------------------------------------------
    def typical(self, param: str, h: float, t_ref: float) -> float:
        """A MEMS-like value of ``param`` (accelerometer units, m/s²; sample time ``h``; ``t_ref`` the mean
        temperature): what ``torchtea simulate --model`` uses unless ``--set`` gives another."""
        raise NotImplementedError(f"component {self.name!r} has no typical value of {param!r}")

    def start(self, param: str, data: "StartData") -> float:
        """A rough data-based value of ``param`` to start a fit from (not an estimate). Default: 0 for a free
        parameter, 1 for a positive one, the middle of a bounded one's range."""
        spec = next(p for p in self.params if p.name == param)
        if spec.kind == "positive":
            return 1.0
        if spec.kind == "fraction":
            return 0.5
        if spec.kind == "bounded":
            lo, hi = spec.bounds
            return 0.5 * (lo + hi) if math.isfinite(lo) and math.isfinite(hi) else 0.0
        return 0.0

    def grid_start(self, label: str, v: dict, white: float, order, fraction, h: float) -> None:
        """Set this component's values (in place) in one start of the Whittle fit's grid: ``white`` the
        periodogram's level at high frequencies (variance), ``order``/``fraction`` the grid's fractional order
        and pole fraction (None without a fractional part)."""

    def scale_drive(self, label: str, v: dict, s: float, fixed) -> None:
        """Scale this component's drive (in place) when a grid start's spectrum is scaled by ``s`` to meet the
        periodogram on the lower half of the band (names in ``fixed`` are kept)."""

    def regressors(self, label: str, t, inputs: dict | None, ok) -> tuple[dict, list]:
        """The mean's linear part for the least-squares start (:func:`~torchtea.fitting.mle.regress_mean`):
        ``(values fixed by the data, [(parameter name, regressor column (N,)), …])``."""
        return {}, []

    def fit_residual(self, label: str, resid, t, ok, h: float, start: dict, inputs: dict | None) -> dict:
        """Values estimated from the residual after the linear regression (a line's frequency, amplitude and
        phase); removes what it explains from ``resid`` in place. ``start``: this component's start values
        (:meth:`start`). Default: nothing for a component that is not a mean, carries the level or whose mean the
        regression took (:meth:`regressors`); a mean that the regression did not take (a user's effect) by nonlinear least
        squares over its parameters from ``start`` (:func:`scipy.optimize.least_squares`)."""
        if self.kind != "mean" or self.level or self.regressors(label, t, inputs, ok)[1]:
            return {}
        from scipy.optimize import least_squares

        names = [p.name for p in self.params]
        tt = torch.as_tensor(t, dtype=torch.float64)
        inp = None if inputs is None else {k: torch.as_tensor(x, dtype=torch.float64) for k, x in inputs.items()}

        def natural(u):
            out = {}
            for p, x in zip(self.params, u):
                if p.kind == "positive":
                    out[p.name] = math.exp(x)
                elif p.kind in ("bounded", "fraction"):
                    lo, hi = p.bounds if p.kind == "bounded" else (0.0, 1.0)
                    out[p.name] = lo + (hi - lo) / (1.0 + math.exp(-x))
                else:
                    out[p.name] = x
            return out

        def unconstrained(p, x):
            if p.kind == "positive":
                return math.log(x)
            if p.kind in ("bounded", "fraction"):
                lo, hi = p.bounds if p.kind == "bounded" else (0.0, 1.0)
                q = (x - lo) / (hi - lo)
                return math.log(q / (1 - q))
            return x

        def residual(u):
            v = {n: torch.tensor([x], dtype=torch.float64) for n, x in natural(u).items()}
            m = self.mean(v, tt, inp)[0].numpy()
            r = resid - m
            return (r - r[ok].mean())[ok]

        u0 = [unconstrained(p, start[f"{label}.{p.name}"]) for p in self.params]
        sol = least_squares(residual, u0, method="lm")
        best = natural(sol.x)
        v = {n: torch.tensor([best[n]], dtype=torch.float64) for n in names}
        resid[ok] -= self.mean(v, tt, inp)[0].numpy()[ok]
        return {f"{label}.{n}": float(best[n]) for n in names}


class Fractional(Component):
    r"""The paper's (43)–(45): :math:`x_{k+1} = h^{\alpha}(f x_k + \omega_k) - \sum_{j\ge1} c_j(\alpha) x_{k+1-j}`,
    ω ~ N(0, q), zero history before ``x_0 = 0``. Spectrum (ALGORITHMS.md §5)
    :math:`S(\omega) = q h^{2\alpha} / (2\pi |(1-e^{-i\omega})^\alpha - f h^\alpha e^{-i\omega}|^2)`."""

    name = "fractional"
    kind = "state"
    params = (ParamSpec("order", "bounded", "α (dimensionless)", ORDER_BOUNDS),
              ParamSpec("pole", "fraction", "f (1/s^α), stable for −2^α < f h^α < 0"),
              ParamSpec("q", "positive", "drive variance (units²)"))

    def spectrum(self, v, omega, h):
        alpha, f, q = v["order"].unsqueeze(-1), v["pole"].unsqueeze(-1), v["q"].unsqueeze(-1)
        a = f * h ** alpha
        # |(1 − e^{−iω})^α − a e^{−iω}|²: 1 − e^{−iω} = 2 sin(ω/2) e^{i(π−ω)/2}
        mag = (2.0 * torch.sin(omega / 2.0)) ** alpha
        phase = alpha * (math.pi - omega) / 2.0
        re = mag * torch.cos(phase) - a * torch.cos(omega)
        im = mag * torch.sin(phase) + a * torch.sin(omega)
        return q * h ** (2.0 * alpha) / (2.0 * math.pi * (re * re + im * im))

    def n_states(self, memory) -> int:
        return memory.lags + memory.n_modes

    def first_row(self, alpha: Tensor, f: Tensor, q: Tensor, h: float, memory) -> tuple[Tensor, Tensor]:
        """The block's first row of F, ``(*S, J + M)``, and its noise loading ``h^α √q`` ``(*S,)`` for orders
        ``alpha`` ``(*S,)`` (the only part of the block that depends on the order, so a time-varying order
        changes this row alone); ``f``, ``q`` broadcast against ``alpha``."""
        J, M = memory.lags, memory.n_modes
        hp = h ** alpha
        c = gl_tail_coefficients(alpha.reshape(-1), J).reshape(*alpha.shape, J)  # c_1 … c_J
        row = torch.cat([-c, -memory.kernel.weights(alpha)], dim=-1) if M else -c
        row[..., 0] = row[..., 0] + hp * f
        return row, hp * torch.sqrt(q)

    def typical(self, param, h, t_ref):
        a = 0.3  # the Monte Carlo studies' part: order 0.3, pole at 40 % of its stability limit, q = r / h^{2α}
        return {"order": a, "pole": -0.4 * 2 ** a / h ** a, "q": 1e-3 / h ** (2 * a)}[param]

    def start(self, param, data):
        a = data.order
        return {"order": a, "pole": -0.5 * 2.0 ** a / data.h ** a,
                "q": max(data.var - data.white, 0.1 * data.var) / data.n_state}[param]

    def grid_start(self, label, v, white, order, fraction, h):
        v[f"{label}.order"] = order
        v[f"{label}.pole"] = -fraction * 2.0 ** order / h ** order

    def scale_drive(self, label, v, s, fixed):
        if f"{label}.q" not in fixed:
            v[f"{label}.q"] = v[f"{label}.q"] * s

    def block(self, v, h, memory):
        alpha, f, q = v["order"], v["pole"], v["q"]
        B = alpha.shape[0]
        J, M = memory.lags, memory.n_modes
        n = J + M
        F = alpha.new_zeros(B, n, n)
        F[:, 0], g = self.first_row(alpha, f, q, h, memory)
        idx = torch.arange(1, J)
        F[:, idx, idx - 1] = 1.0
        if M:
            _, _, decay, inject = memory.kernel.tensors(alpha.dtype, alpha.device)
            modes = torch.arange(J, n)
            F[:, modes, modes] = decay
            F[:, modes, J - 1] = inject
        G = alpha.new_zeros(B, n, 1)
        G[:, 0, 0] = g
        return F, G


class RandomWalk(Component):
    r"""Bias random walk :math:`b_{k+1} = b_k + \sigma\sqrt{h}\,\xi_k`, ``b_0 = 0`` (σ: rate random walk K, units/√s).
    Spectrum of its increments' integral: :math:`\sigma^2 h / (2\pi \cdot 4\sin^2(\omega/2))`."""

    name = "random-walk"
    kind = "state"
    params = (ParamSpec("sigma", "positive", "K (units/√s)"),)

    def spectrum(self, v, omega, h):
        s = v["sigma"].unsqueeze(-1)
        return s * s * h / (2.0 * math.pi * 4.0 * torch.sin(omega / 2.0) ** 2)

    def n_states(self, memory) -> int:
        return 1

    def typical(self, param, h, t_ref):
        return 2e-3

    def start(self, param, data):
        return math.sqrt(max(data.var, 1e-12) / (len(data.y) * data.h)) / 10.0

    def scale_drive(self, label, v, s, fixed):
        if f"{label}.sigma" not in fixed:
            v[f"{label}.sigma"] = v[f"{label}.sigma"] * math.sqrt(s) * 0.1

    def block(self, v, h, memory):
        s = v["sigma"]
        F = s.new_ones(s.shape[0], 1, 1)
        G = (s * math.sqrt(h)).reshape(-1, 1, 1)
        return F, G


class LowPass(Component):
    r"""First-order low-pass :math:`l_k = a l_{k-1} + (1-a) s_k`, :math:`a = e^{-2\pi f_c h}`, of the stochastic
    components before it, :math:`s_k` their sum (the sensor's digital filter), started from rest before the first
    sample. Multiplies their spectra by :math:`(1-a)^2/(1 - 2a\cos\omega + a^2)`."""

    name = "low-pass"
    kind = "filter"
    params = (ParamSpec("cutoff_hz", "positive", "f_c (Hz)"),)

    def gain(self, v, omega, h):
        a = self.coefficient(v, h).unsqueeze(-1)
        return (1.0 - a) ** 2 / (1.0 - 2.0 * a * torch.cos(omega) + a * a)

    def coefficient(self, v, h):
        return torch.exp(-2.0 * math.pi * v["cutoff_hz"] * h)

    single = True

    def position(self, model):
        """Right after the last stochastic component: a sensor's digital filter filters its whole signal, white
        noise included."""
        last = max((i for i, (_, c) in enumerate(model.components) if c.kind in ("state", "measurement")),
                   default=None)
        if last is None:
            raise ValueError(f"a low-pass filters stochastic components; {model.spec!r} has none")
        return last + 1

    def typical(self, param, h, t_ref):
        return 5.0

    def start(self, param, data):
        return 0.25 / data.h


class White(Component):
    """Measurement (ADC) noise ν_k ~ N(0, r): spectrum r/2π."""

    name = "white"
    kind = "measurement"
    params = (ParamSpec("r", "positive", "variance (units²)"),)

    def measurement_variance(self, v):
        return v["r"]

    def typical(self, param, h, t_ref):
        return 1e-3

    def start(self, param, data):
        return data.white / 2.0

    def grid_start(self, label, v, white, order, fraction, h):
        v[f"{label}.r"] = white * 0.5

    def spectrum(self, v, omega, h):
        return (v["r"] / (2.0 * math.pi)).unsqueeze(-1).expand(-1, omega.shape[-1])


class Quantisation(Component):
    """Quantisation of step Δ, modelled as white noise of variance Δ²/12."""

    name = "quantisation"
    kind = "measurement"
    params = (ParamSpec("step", "positive", "Δ (units)"),)

    def measurement_variance(self, v):
        return v["step"] ** 2 / 12.0

    def typical(self, param, h, t_ref):
        return 0.01

    def start(self, param, data):
        return math.sqrt(12.0 * data.white / 2.0)

    def grid_start(self, label, v, white, order, fraction, h):
        v[f"{label}.step"] = math.sqrt(12 * white * 0.5)

    def spectrum(self, v, omega, h):
        return (self.measurement_variance(v) / (2.0 * math.pi)).unsqueeze(-1).expand(-1, omega.shape[-1])


class Offset(Component):
    name = "offset"
    kind = "mean"
    params = (ParamSpec("value", "free", "units"),)
    level = True

    def mean(self, v, t, inputs):
        return v["value"].unsqueeze(-1).expand(-1, t.shape[-1])

    def typical(self, param, h, t_ref):
        return 0.0

    def start(self, param, data):
        return float(data.y.mean())


class Ramp(Component):
    """slope · (t − t̄): a linear drift through zero at the middle of the record (t̄ the mean time), so that it
    does not move the series' mean (which ``offset``, or the centring of a model without one, carries)."""

    name = "ramp"
    kind = "mean"
    params = (ParamSpec("slope", "free", "units/s"),)

    def mean(self, v, t, inputs):
        return v["slope"].unsqueeze(-1) * (t - t.mean())

    def typical(self, param, h, t_ref):
        return 1e-4

    def regressors(self, label, t, inputs, ok):
        return {}, [(f"{label}.slope", t - t[ok].mean())]


class Sinusoid(Component):
    """A sin(2π f₀ t + φ): a vibration line. Not a spectral density — removed before the Whittle sum."""

    name = "sinusoid"
    kind = "mean"
    params = (ParamSpec("frequency_hz", "positive", "f₀ (Hz)"), ParamSpec("amplitude", "positive", "A (units)"),
              ParamSpec("phase", "free", "φ (rad)"))

    add_again = True  # a second line

    def mean(self, v, t, inputs):
        return v["amplitude"].unsqueeze(-1) * torch.sin(2.0 * math.pi * v["frequency_hz"].unsqueeze(-1) * t
                                                        + v["phase"].unsqueeze(-1))

    def typical(self, param, h, t_ref):
        return {"frequency_hz": 3.37, "amplitude": 0.01, "phase": 0.0}[param]

    def start(self, param, data):
        return {"frequency_hz": 0.1 / data.h, "amplitude": math.sqrt(data.var) / 10.0, "phase": 0.0}[param]

    def fit_residual(self, label, resid, t, ok, h, start, inputs):
        """The residual periodogram's highest peak (not the trend's three lowest bins), its frequency refined,
        amplitude and phase by least squares."""
        from ..fitting.mle import refine_frequency

        N = len(resid)
        r = np.where(ok, resid, 0.0)
        spec = np.abs(np.fft.rfft(r)) ** 2
        spec[:3] = 0.0  # not the trend
        j = int(np.argmax(spec))
        f0 = refine_frequency(r, j / (N * h), h)
        w = 2 * np.pi * f0 * t
        X = np.stack([np.sin(w), np.cos(w)], 1)
        coef, *_ = np.linalg.lstsq(X[ok], resid[ok], rcond=None)
        resid[ok] -= X[ok] @ coef
        return {f"{label}.frequency_hz": f0, f"{label}.amplitude": float(math.hypot(*coef)),
                f"{label}.phase": float(math.atan2(coef[1], coef[0]))}


class TemperatureBias(Component):
    """β (T_k − T_ref) added to the output; T the measured ``temperature`` input (°C), T_ref its mean
    unless fixed."""

    name = "temperature-bias"
    kind = "mean"
    inputs = ("temperature",)
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
    inputs = ("temperature",)
    params = (ParamSpec("order_per_degC", "free", "1/°C"), ParamSpec("t_ref", "free", "T_ref (°C)"))

    def position(self, model):
        if not model.has("fractional"):
            raise ValueError(f"temperature-order drives a fractional component's order; {model.spec!r} has none")
        return len(model.components)

    def typical(self, param, h, t_ref):
        return {"order_per_degC": 0.03, "t_ref": t_ref}[param]

    def regressors(self, label, t, inputs, ok):
        """Not a mean: only its reference (the mean temperature), and γ = 0 to start from."""
        return {f"{label}.t_ref": float(np.nanmean(np.asarray(inputs["temperature"], dtype=np.float64))),
                f"{label}.order_per_degC": 0.0}, []

    def orders(self, v: dict, alpha0: Tensor, T: Tensor) -> Tensor:
        """``(B, N)`` orders α_k for ``(B,)`` α₀ and the temperature ``(N,)``."""
        a = alpha0.unsqueeze(-1) + v["order_per_degC"].unsqueeze(-1) * (T - v["t_ref"].unsqueeze(-1))
        return a.clamp(1e-6, 0.999)  # the exponential-sum kernel's range: the lags and the tail see one order


COMPONENTS = {c.name: c for c in (Fractional(), White(), Quantisation(), RandomWalk(), LowPass(), Offset(), Ramp(),
                                  Sinusoid(), TemperatureBias(), TemperatureOrder())}

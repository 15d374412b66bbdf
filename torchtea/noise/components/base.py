"""The base of every effect: :class:`Component` (what the model, the fits, the screens, the TEA and the exports ask
of an effect), its parameters (:class:`ParamSpec`). Its place in the TEA is :mod:`torchtea.noise.tea`'s. How ``check``
screens an effect is not here (:mod:`torchtea.checking.screens`), nor how the fits start it
(:mod:`torchtea.fitting.starts`)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from ...core import forward

#: Orders the ``fractional`` component may take: open interval, the kernel is designed on it.
ORDER_BOUNDS = (0.0, 1.0)


@dataclass(frozen=True)
class ParamSpec:
    """One parameter of a component.

    ``kind``: ``"positive"`` (log transform), ``"bounded"`` (logit on ``bounds``), ``"free"`` (identity),
    ``"fraction"`` (logit on (0, 1): the fractional pole's stability fraction, see the module docstring),
    ``"nyquist"`` (a frequency in Hz below the Nyquist frequency 1/(2h): logit of f·2h — above it a resonance aliases
    to the same model, so the fit must not go there). ``unit`` is what the value means, written next to it in reports.
    """

    name: str
    kind: str
    unit: str
    bounds: tuple = (-math.inf, math.inf)

    @property
    def scale(self) -> str:
        """The scale its kind puts it on for the optimisers and the intervals: ``"log"``, ``"logit"`` or
        ``"identity"``."""
        return SCALES[self.kind]

    def to_unconstrained(self, x: Tensor, h: float, order: Tensor | None = None, where: str = "") -> Tensor:
        """The value ``x`` on the optimisers' unconstrained scale — the one transform of its kind (every fit, start
        and interval uses it): log of a positive value, logit of a bounded one's share of its range, of a
        frequency's share of the Nyquist frequency 1/(2h), of a pole's fraction ``−f h^α/2^α`` of its stability
        limit (``order`` α, the fractional order the pole belongs to). Raises ``ValueError`` (naming ``where``) for
        a frequency outside (0, Nyquist)."""
        if self.kind == "positive":
            return torch.log(x)
        if self.kind == "bounded":
            lo, hi = self.bounds
            return logit((x - lo) / (hi - lo))
        if self.kind == "nyquist":
            if not bool(((x > 0) & (x * 2.0 * h < 1)).all()):
                raise ValueError(f"{where or self.name} must lie between 0 and the Nyquist frequency {0.5 / h:g} Hz, "
                                 f"got {x.tolist()}")
            return logit(x * 2.0 * h)
        if self.kind == "fraction":
            return logit(-x * h ** order / 2.0 ** order)
        return x

    def from_unconstrained(self, u: Tensor, h: float, order: Tensor | None = None) -> Tensor:
        """Inverse of :meth:`to_unconstrained` (differentiable)."""
        if self.kind == "positive":
            return torch.exp(u)
        if self.kind == "bounded":
            lo, hi = self.bounds
            return lo + (hi - lo) * torch.sigmoid(u)
        if self.kind == "nyquist":
            return torch.sigmoid(u) / (2.0 * h)
        if self.kind == "fraction":
            return -torch.sigmoid(u) * 2.0 ** order / h ** order
        return u

    def derivative(self, u: Tensor, value: Tensor, h: float) -> Tensor:
        """``∂value/∂u`` of :meth:`from_unconstrained` at ``u``, where it gave ``value`` (a pole fraction's at its order
        held): ``value`` for a log, ``(hi − lo) s (1 − s)`` for a logit with ``s = sigmoid(u)``, ``s (1 − s)/(2h)`` for
        a frequency, ``value (1 − s)`` for a pole's fraction, 1 for the identity."""
        if self.kind == "positive":
            return value
        if self.kind in ("bounded", "nyquist", "fraction"):
            s = torch.sigmoid(u)
            if self.kind == "fraction":
                return value * (1.0 - s)
            scale = (self.bounds[1] - self.bounds[0]) if self.kind == "bounded" else 1.0 / (2.0 * h)
            return scale * s * (1.0 - s)
        return torch.ones_like(u)

    def order_derivative(self, value: Tensor, h: float) -> Tensor:
        """A pole fraction's ``∂value/∂order`` at its unconstrained coordinate held: the pole is ``−ρ 2^α/h^α``, so
        ``value (ln 2 − ln h)``; zero for every other kind (no parameter but a pole moves with the order)."""
        if self.kind != "fraction":
            return torch.zeros_like(value)
        return value * (math.log(2.0) - math.log(h))


#: Each parameter kind's scale (:attr:`ParamSpec.scale`).
SCALES = {"positive": "log", "bounded": "logit", "fraction": "logit", "nyquist": "logit", "free": "identity"}


def logit(p: Tensor) -> Tensor:
    return torch.log(p) - torch.log1p(-p)


def forward_derivatives(function, params: tuple, v: dict, *args):
    """``function(v, *args)`` — a tensor ``(B, …)`` or a tuple of them — and its derivatives with respect to each of
    ``params`` (the values ``v[name]`` ``(B,)``), each ``(B, p, …)`` (a tuple of them for a tuple), by forward-mode
    automatic differentiation (:func:`torch.func.jvp`, one pass per parameter): the default of the components'
    derivative methods (:meth:`Component.spectrum_derivatives`, :meth:`Component.block_derivatives`, …)."""
    names = [p.name for p in params]
    primals = tuple(v[n] for n in names)

    def of(*values):
        return function({**v, **dict(zip(names, values))}, *args)

    value, columns = None, []
    for k in range(len(names)):
        tangents = tuple(torch.ones_like(x) if j == k else torch.zeros_like(x) for j, x in enumerate(primals))
        value, d = forward.jvp(of, primals, tangents)
        columns.append(d)
    if value is None:
        value = of(*primals)
    single = isinstance(value, Tensor)
    values = (value,) if single else tuple(value)
    if columns:
        out = tuple(torch.stack([c if single else c[i] for c in columns], dim=1) for i in range(len(values)))
    else:
        out = tuple(x.new_zeros(x.shape[0], 0, *x.shape[1:]) for x in values)
    return (value, out[0]) if single else (value, out)


#: The kinds of component that are noise — a state, a measurement's white part, a sensor filter — as against a mean
#: (a deterministic function of time and inputs) and a modifier (it changes another component): what the Whittle
#: likelihood sees, what screens by its likelihood ratio, what the plan's intervals are about.
STOCHASTIC_KINDS = ("state", "measurement", "filter")


class Component:
    """Base class of every effect: a named part of the model with its parameters. An effect derives from the base of
    its kind — :class:`StateEffect`, :class:`MeasurementEffect`, :class:`MeanEffect` (a user's effect is one of these
    three), :class:`FilterEffect` or :class:`Modifier` — which sets ``kind`` and declares the hooks the engines call
    for that kind; a subclass sets ``name`` and ``params`` and writes them."""

    name: str = ""
    kind: str = ""  # "state", "measurement", "filter", "mean", "modifier": set by the base of the kind
    params: tuple = ()
    inputs: tuple = ()  # input channels the component reads (e.g. "temperature")
    #: the parameter that is a fractional order — the memory the TEA's KFo estimates, over which the Whittle profile
    #: and the fractional-presence test run (:attr:`NoiseModel.order_name`); None: it has none
    order_param: str | None = None
    #: False for a component that makes the model's dynamics change in time: the model then has no spectrum that
    #: defines its likelihood, and only the exact likelihood fits it
    stationary: bool = True
    #: Parameters the exact fits hold where the data put them, name → None for a reference (not an estimate:
    #: the temperature's ``t_ref``) or the words the report gives for its interval (an estimate made elsewhere —
    #: a line's frequency at the refined periodogram peak — which counts as estimated in BIC).
    held: dict = {}
    #: Of the held estimates, those every fit holds (their likelihood is not smooth — a time — so no optimiser can
    #: move them): at the value the least-squares start found (:meth:`~torchtea.fitting.starts.Starts.fit_residual`), counted as estimated in BIC.
    located: tuple = ()

    def check_fixed(self, label: str, fixed) -> None:
        """Raise ``ValueError`` when the parameter names ``fixed`` hold some of this component's parameters in a way
        its fit cannot (default: any is fine)."""

    def spectrum(self, v: dict, omega: Tensor, h: float) -> Tensor:
        """Two-sided spectral density at ω (rad/sample) for parameter values ``v`` (each ``(B,)``) → ``(B, W)``:
        what the Whittle likelihood and the spectra of ``check`` read of a state or measurement effect."""
        raise NotImplementedError(f"component {self.name!r} ({self.kind}) has no spectrum of its own")

    def spectrum_derivatives(self, v: dict, omega: Tensor, h: float) -> tuple[Tensor, Tensor]:
        """The spectrum ``S`` ``(B, W)`` and its derivatives with respect to the component's parameters, in the order
        of :attr:`params` and on their natural scale, ``(B, p, W)`` — what the Whittle fits' scoring reads at every
        iteration. The built-in effects write them in closed form; this default differentiates :meth:`spectrum` by
        forward-mode automatic differentiation (one pass per parameter), so that a user's effect needs none."""
        return forward_derivatives(self.spectrum, self.params, v, omega, h)

    def typical(self, param: str, h: float, t_ref: float) -> float:
        """A MEMS-like value of ``param`` (accelerometer units, m/s²; sample time ``h``; ``t_ref`` the mean
        temperature): what ``torchtea simulate --model`` uses unless ``--set`` gives another."""
        raise NotImplementedError(f"component {self.name!r} has no typical value of {param!r}")


class StateEffect(Component):
    """A linear Gaussian state block driven by white noise (a random walk, a Gauss–Markov bias, the fractional
    noise): the exact Kalman filter and the simulator stack its :meth:`block`; its output is its state 0."""

    kind = "state"
    #: True for a block that does not return to a mean (a random walk): the transform of a series holding it
    #: carries the whole excursion over the record at every Fourier frequency, as a trend's would — its periodogram
    #: twice the spectrum there —, so the Whittle fits profile a trend out of its models (generalised least squares
    #: under each spectrum, :class:`~torchtea.likelihood.whittle.Regressors`)
    diffuse: bool = False

    def block(self, v: dict, h: float, memory) -> tuple[Tensor, Tensor]:
        """Transition ``F`` ``(B, n, n)`` and noise loading ``G`` ``(B, n, m)`` of the block (process noise
        ``G ξ_k``, ξ standard normal, so ``Q = G Gᵀ``); the block's output is its state 0."""
        raise NotImplementedError

    def block_derivatives(self, v: dict, h: float, memory) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """:meth:`block`'s ``F`` ``(B, n, n)`` and ``G`` ``(B, n, m)`` and their derivatives with respect to the
        component's parameters (natural scale, :attr:`params` order), ``(B, p, n, n)`` and ``(B, p, n, m)``: the
        exact likelihood's gradient (the sensitivity filter) reads them. Default: forward-mode automatic
        differentiation of :meth:`block`; the built-in effects write them in closed form."""
        (F, G), (dF, dG) = forward_derivatives(lambda values: self.block(values, h, memory), self.params, v)
        return F, G, dF, dG

    def spectrum(self, v: dict, omega: Tensor, h: float) -> Tensor:
        r"""Default: the stationary spectrum of the block's output (state 0),
        :math:`S(\omega) = \frac{1}{2\pi}\,\lVert e_0^\top (I - F e^{-i\omega})^{-1} G \rVert^2` — right for a
        stable block (every eigenvalue of F inside the unit circle); a block that does not return to a mean (a random
        walk) writes its own."""
        F, G = self.block(v, h, None)  # (B, n, n), (B, n, m)
        z = torch.exp(-1j * omega.to(device=F.device, dtype=torch.float64))
        z = z.unsqueeze(0) if z.ndim == 1 else z  # (1 or B, W): one frequency grid, or one per parameter set
        eye = torch.eye(F.shape[-1], dtype=torch.complex128, device=F.device)
        M = eye - F.to(torch.complex128).unsqueeze(1) * z[..., None, None]  # (B, W, n, n)
        X = torch.linalg.solve(M, G.to(torch.complex128).unsqueeze(1))  # (B, W, n, m)
        return ((X[..., 0, :].abs() ** 2).sum(-1) / (2.0 * math.pi)).to(F.dtype)


class FractionalState(StateEffect):
    """A state of fractional order (:attr:`order_param`) whose block is a Grünwald–Letnikov memory of its own past:
    the order moves only the block's first row, so an order that changes in time (a :class:`Modifier`, a known
    trajectory) changes that row per step, and the TEA's order filter reads it."""

    def first_row(self, v: dict, alpha: Tensor, h: float, memory) -> tuple[Tensor, Tensor]:
        """The block's first row of F, ``(*S, n)``, and its noise loading ``(*S,)`` for orders ``alpha`` ``(*S,)``;
        the effect's other parameters ``v`` broadcast against ``alpha``."""
        raise NotImplementedError

    def run_exact(self, v: dict, alpha: Tensor, h: float, xi: Tensor, forcing: Tensor | None = None,
                  x0: Tensor | None = None) -> Tensor:
        """The state ``(S, N)`` by its recursion over the whole past (the simulator's exact memory): ``alpha``
        ``(S, N)`` the order of each step, ``xi`` ``(S, N)`` the standard-normal drive, ``forcing`` a known input."""
        raise NotImplementedError


class MeasurementEffect(Component):
    """Independent white noise added to the measurement (white noise, the output's rounding)."""

    kind = "measurement"

    def measurement_variance(self, v: dict) -> Tensor:
        """The variance ``(B,)`` it adds to every sample."""
        raise NotImplementedError

    def variance_derivatives(self, v: dict) -> tuple[Tensor, Tensor]:
        """:meth:`measurement_variance` ``(B,)`` and its derivatives ``(B, p)``. Default: forward-mode automatic
        differentiation."""
        return forward_derivatives(self.measurement_variance, self.params, v)


class MeanEffect(Component):
    """A deterministic function of time and the input channels (a level, a ramp, a line, a temperature's bias): the
    Whittle likelihood removes it by regression first, the exact filter subtracts it."""

    kind = "mean"
    #: it carries the series' constant level: the fits do not centre the series (``offset``)
    level: bool = False

    def mean(self, v: dict, t: Tensor, inputs: dict) -> Tensor:
        """Deterministic contribution ``(B, N)`` at times ``t`` (s, from the first sample)."""
        raise NotImplementedError


class FilterEffect(Component):
    """The sensor's low-pass filter of the stochastic effects listed before it: it multiplies their spectra by its
    :meth:`gain`, and the state-space assembly stacks its :meth:`filter_block` after them."""

    kind = "filter"
    #: first-order stages in cascade
    stages: int = 1

    def gain(self, v: dict, omega: Tensor, h: float) -> Tensor:
        """The filter's power gain ``(B, W)`` at ω (rad/sample)."""
        raise NotImplementedError

    def gain_derivatives(self, v: dict, omega: Tensor, h: float) -> tuple[Tensor, Tensor]:
        """:meth:`gain` ``(B, W)`` and its derivatives with respect to the parameters ``(B, p, W)``."""
        return forward_derivatives(self.gain, self.params, v, omega, h)

    def filter_block(self, v: dict, h: float) -> tuple[Tensor, Tensor]:
        """The filter as a state space fed by its input: ``A`` ``(B, m, m)``, ``b`` ``(B, m)``, output the last
        state."""
        raise NotImplementedError


class Modifier(Component):
    """Changes the order of the model's :class:`FractionalState` in time: the model is then not stationary
    (only the exact likelihood fits it)."""

    kind = "modifier"
    stationary = False

    def orders(self, v: dict, alpha0: Tensor, T: Tensor) -> Tensor:
        """``(B, N)`` orders α_k for ``(B,)`` α₀ and the input channel ``(N,)``."""
        raise NotImplementedError


#: The base of each kind: an effect of a kind derives from it.
KIND_BASES = {"state": StateEffect, "measurement": MeasurementEffect, "mean": MeanEffect, "filter": FilterEffect,
              "modifier": Modifier}

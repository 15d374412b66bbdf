r"""How the GL sums see the past: ``exact`` full history, ``soe`` exponential sums, or a finite ``window``.

The memory term of the A-type model, :math:`S_k(\alpha) = \sum_{j\ge1} c_j(\alpha)\,x_{k+1-j}`, costs
O(k) per step when summed directly. ALGORITHMS.md §4 gives an exact integral for the coefficients,

.. math::  c_j(\alpha) = -\frac{\sin\pi\alpha}{\pi}\int_0^\infty e^{-js}(e^s-1)^\alpha\,ds
           \qquad (\alpha > -1,\ j > \alpha),

whose trapezoidal discretisation in :math:`u = \ln s` has nodes :math:`s_n = e^{n\eta}` that do **not**
depend on the order. Keeping the first :math:`J_0` lags exact and every later lag in one state per node,

.. math::  S_k(\alpha) \approx \sum_{j=1}^{J_0} c_j(\alpha)\,x_{k+1-j} + \sum_n W_n(\alpha) H_n + W_\star(\alpha) R,
           \qquad H_n \leftarrow e^{-s_n}H_n + e^{-(J_0+1)s_n}\,x_{\text{dropped}},\quad R \leftarrow R + x_{\text{dropped}},

one set of states serves every order — every sigma point, every step — at O(J₀ + L) cost per step.
Nodes below a cut are lumped into the zero-rate running sum ``R`` (the last *mode* here, with decay 1).
:func:`design_kernel` chooses the nodes so that **every** coefficient of a lag :math:`J_0 < j \le N` and
every order of the kernel's range is reproduced to relative error ``tol`` — checked numerically against
the recursion, not assumed — which gives the bound

.. math::  |S_{\text{soe}} - S_{\text{exact}}| \le \text{tol}\cdot\sum_{j>J_0}|c_j(\alpha)|\,|x_{k+1-j}|.

The fractional Kalman filter also needs :math:`\sum_{j\ge2} c_j(a_s)c_j(a_t)P_{k-j}` (paper (31)). Its
weights decay like :math:`j^{-2-a_s-a_t}`, so ``soe`` keeps :math:`J_P` lags exact and multiplies the
remaining *coefficient mass* (:func:`cov_tail_mass`, closed form from the Gauss sum
:math:`\sum_{j\ge0} c_j(a)c_j(b) = \Gamma(1+a+b)/(\Gamma(1+a)\Gamma(1+b))`) by the oldest covariance kept.

``window`` truncates both sums at ``L`` lags (the short-memory principle of the literature) — biased for
small orders, there for comparison.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import NamedTuple

import torch
from torch import Tensor

from .gl import gl_tail_coefficients

__all__ = ["MemoryConfig", "SOEKernel", "design_kernel", "kernel_for", "BoundedHistory", "cov_tail_mass", "gl_coefficients_at",
           "MEMORY_KINDS", "parse_memory", "MemoryPlan", "memory_plan"]

MEMORY_KINDS = ("exact", "soe", "window")


@dataclass(frozen=True)
class MemoryConfig:
    """How the GL history sums are evaluated.

    Attributes
    ----------
    kind : ``"exact"`` (full sums, O(k) per step), ``"soe"`` (exponential sums, O(1) per step) or
        ``"window"`` (the last ``window`` lags only).
    tol : ``soe``: worst relative error of any coefficient ``c_j``, ``exact_lags < j ≤ N``.
    exact_lags : ``soe``: ``J₀``, lags summed exactly before the exponential sum takes over.
    cov_lags : ``soe``: ``J_P``, lags of the covariance sum (31) kept exactly; the rest is the
        closed-form coefficient mass times the oldest covariance kept, except the first
        ``cov_head`` covariances of the run (the start-up transient, e.g. the prior ``P₀``), which keep
        their exact terms at every step.
    cov_head : ``soe``: number of initial covariances kept exactly (see ``cov_lags``).
    window : ``window``: ``L``, lags kept (mean and covariance sums).
    order_range : ``soe``: orders the kernel must serve, ``(low, high)``; ``None`` picks it from the
        estimator's order bounds (or the simulated orders). Orders outside are clamped **for the
        exponential-sum part only** (lags > ``exact_lags``).
    """

    kind: str = "exact"
    tol: float = 1e-8
    exact_lags: int = 8
    cov_lags: int = 64
    cov_head: int = 16
    window: int = 1000
    order_range: tuple | None = None

    def __post_init__(self):
        if self.kind not in MEMORY_KINDS:
            raise ValueError(f"memory kind must be one of {MEMORY_KINDS}, got {self.kind!r}")
        if not 0 < self.tol < 1e-2:
            raise ValueError(f"memory tol must lie in (0, 1e-2), got {self.tol}")
        if self.exact_lags < 4:
            raise ValueError("memory exact_lags must be >= 4 (the exponential sum needs j > order)")
        if self.cov_lags < 2 or self.window < 1 or self.cov_head < 0:
            raise ValueError("memory cov_lags must be >= 2, cov_head >= 0 and window >= 1")
        if self.order_range is not None:
            lo, hi = self.order_range
            if not -1.0 < lo < hi < self.exact_lags:
                raise ValueError(f"memory order_range must satisfy -1 < low < high < exact_lags, got {self.order_range}")

    @property
    def bounded(self) -> bool:
        """Constant work and state per step (``soe``, ``window``); ``exact`` keeps the whole past."""
        return self.kind != "exact"

    def spec(self) -> str:
        if self.kind == "soe":
            return f"soe:{self.tol:g}"
        if self.kind == "window":
            return f"window:{self.window}"
        return "exact"

    def to_dict(self) -> dict:
        d = {"kind": self.kind, "tol": self.tol, "exact_lags": self.exact_lags, "cov_lags": self.cov_lags,
             "cov_head": self.cov_head, "window": self.window}
        if self.order_range is not None:
            d["order_range"] = list(self.order_range)
        return d

    @classmethod
    def from_dict(cls, data: dict) -> MemoryConfig:
        data = dict(data)
        if "order_range" in data and data["order_range"] is not None:
            data["order_range"] = tuple(data["order_range"])
        bad = set(data) - {"kind", "tol", "exact_lags", "cov_lags", "cov_head", "window", "order_range"}
        if bad:
            raise ValueError(f"unknown settings in [memory]: {sorted(bad)}")
        return cls(**data)


def parse_memory(spec) -> MemoryConfig:
    """``"exact"``, ``"soe"``, ``"soe:1e-10"``, ``"window:500"`` (or a MemoryConfig / dict) → MemoryConfig."""
    if isinstance(spec, MemoryConfig):
        return spec
    if isinstance(spec, dict):
        return MemoryConfig.from_dict(spec)
    text = str(spec).strip()
    kind, _, arg = text.partition(":")
    kind = kind.strip().lower()
    try:
        if kind == "soe":
            return MemoryConfig("soe", tol=float(arg)) if arg else MemoryConfig("soe")
        if kind == "window":
            if not arg:
                raise ValueError
            return MemoryConfig("window", window=int(arg))
        if kind == "exact" and not arg:
            return MemoryConfig("exact")
    except ValueError:
        pass
    raise ValueError(f"bad memory spec {text!r}: use exact, soe, soe:TOL or window:L")


# --------------------------------------------------------------------------- the exponential-sum kernel


@dataclass(frozen=True, eq=False)
class SOEKernel:
    """Order-independent nodes of the exponential sum (ALGORITHMS.md §4).

    Attributes
    ----------
    eta : trapezoidal step in ``u = ln s``.
    n0 : index of the first explicit node; nodes ``n < n0`` form the running-sum mode.
    u : ``(L,)`` float64, ``u_n = n η`` for the explicit nodes.
    exact_lags : ``J₀``.
    order_range : orders served, ``(low, high)``.
    tol : the requested bound; ``error`` the worst relative coefficient error found by the check.
    horizon : largest lag checked (the recording length it was designed for).
    """

    eta: float
    n0: int
    u: Tensor
    exact_lags: int
    order_range: tuple
    tol: float
    error: float
    horizon: int

    @property
    def n_modes(self) -> int:
        """Explicit nodes plus the running-sum mode."""
        return self.u.shape[0] + 1

    @functools.lru_cache(maxsize=8)  # noqa: B019 — kernels are few and long-lived
    def tensors(self, dtype, device):
        """``(a, b, decay, inject)`` in ``dtype`` on ``device``: weights are ``exp(a + α b)`` times the
        order's factor, ``decay = e^{−s}``, ``inject = e^{−(J₀+1)s}`` (1 and 1 for the running sum)."""
        u = self.u.to(torch.float64)
        s = u.exp()
        a = torch.cat([math.log(self.eta) + u, torch.tensor([math.log(self.eta) + self.n0 * self.eta], dtype=torch.float64)])
        b = torch.cat([torch.log(torch.expm1(s)), torch.tensor([self.n0 * self.eta], dtype=torch.float64)])
        one = torch.ones(1, dtype=torch.float64)
        decay = torch.cat([torch.exp(-s), one])
        inject = torch.cat([torch.exp(-(self.exact_lags + 1) * s), one])
        return tuple(t.to(dtype=dtype, device=device) for t in (a, b, decay, inject))

    def weights(self, order: Tensor) -> Tensor:
        r"""The mode weights :math:`W_1(\alpha) … W_L(\alpha), W_\star(\alpha)`, shape ``(*order.shape, L+1)``:
        :math:`W_n = -(\sin\pi\alpha/\pi)\,e^{a_n+\alpha b_n}`, and ``W_⋆`` carries ``q/(1−q) = 1/expm1((1+α)η)``.
        Orders are clamped to the kernel's range (the exponential sum is only checked there)."""
        a, b, _, _ = self.tensors(order.dtype, order.device)
        alpha = order.clamp(*self.order_range).unsqueeze(-1)
        w = torch.exp(a + alpha * b)
        lump = torch.ones_like(w)
        lump = torch.cat([lump[..., :-1], 1.0 / torch.expm1((1.0 + alpha) * self.eta)], dim=-1)
        return w * lump * (torch.sin(math.pi * alpha) * (-1.0 / math.pi))

    def tail_sums(self, order: Tensor, modes: Tensor) -> Tensor:
        r""":math:`\sum_n W_n(\alpha) H_n + W_\star(\alpha) R` for ``S`` orders against one set of modes.

        order ``(*B, S, n)``, modes ``(*B, n, L+1)`` → ``(*B, S, n)``, with the weights of :meth:`weights`.
        """
        return (self.weights(order) * modes.unsqueeze(-3)).sum(-1)

    def coefficients(self, order: Tensor, lags: Tensor) -> Tensor:
        """The kernel's approximation of ``c_j(order)`` at the given lags (> J₀), shape ``(*order.shape, len(lags))``."""
        s = torch.cat([self.u.exp(), torch.zeros(1, dtype=torch.float64)]).to(order)
        E = torch.exp(-lags.to(order).unsqueeze(-1) * s)  # (J, L+1): the modes of a unit impulse J lags back
        return self.tail_sums(order.unsqueeze(-1).expand(order.shape + lags.shape), E)


def _check_grid(order_range, exact_lags: int, horizon: int):
    lo, hi = order_range
    alphas = torch.linspace(lo, hi, 25, dtype=torch.float64)
    # an integer order has c_j = 0 for j > order, where a relative error means nothing: nudge it
    near = (alphas - alphas.round()).abs() < 1e-3
    nudged = torch.where(alphas + 2e-3 <= hi, alphas + 2e-3, alphas - 2e-3)
    alphas = torch.where(near, nudged, alphas)
    dense = torch.arange(exact_lags + 1, min(horizon, 600) + 1, dtype=torch.float64)
    lags = dense
    if horizon > 600:
        sparse = torch.logspace(math.log10(601), math.log10(horizon), 300, dtype=torch.float64).round()
        lags = torch.unique(torch.cat([dense, sparse, torch.tensor([float(horizon)], dtype=torch.float64)]))
    return alphas, lags


#: The check computes reference coefficients by the recursion up to this lag; beyond it the node
#: range still follows the design rule but the error is not checked.
CHECK_HORIZON = 2_000_000


def _max_rel_error(kernel: SOEKernel, alphas: Tensor, lags: Tensor) -> float:
    worst = 0.0
    n = int(lags.max())
    idx = lags.long() - 1
    for chunk in alphas.split(4):
        exact = gl_tail_coefficients(chunk, n)[:, idx]
        approx = kernel.coefficients(chunk, lags)
        ok = exact.abs() > 1e-290
        rel = ((approx - exact).abs() / exact.abs().clamp(min=1e-300))[ok]
        if rel.numel():
            worst = max(worst, float(rel.max()))
    return worst


@functools.lru_cache(maxsize=32)
def design_kernel(tol: float, horizon: int, order_range: tuple, exact_lags: int = 8) -> SOEKernel:
    """Nodes for relative coefficient error ≤ ``tol`` at every lag ``exact_lags < j ≤ horizon`` and order
    in ``order_range`` (ALGORITHMS.md §4's rule, then checked and refined).

    Start from η = 9.2 / ln(57/tol) and the node range ``s* = tol^{1/(2+α_min)}/N`` …
    ``s_max = ln(1/tol)/(J₀+1−α_max)``; the trapezoid's error grows with the order, so η shrinks by 10 %
    until the worst relative error over 25 orders × ~900 lags (all lags to 600, log-spaced beyond,
    reference by the float64 recursion) is below ``tol``.
    """
    lo, hi = (float(v) for v in order_range)
    if not -1.0 < lo < hi < exact_lags:
        raise ValueError(f"order_range must satisfy -1 < low < high < exact_lags, got {order_range}")
    horizon = max(int(horizon), exact_lags + 2)
    s_lo = tol ** (1.0 / (2.0 + lo)) / horizon
    s_hi = math.log(1.0 / tol) / (exact_lags + 1 - max(hi, 0.0))
    alphas, lags = _check_grid((lo, hi), exact_lags, min(horizon, CHECK_HORIZON))
    eta = 9.2 / math.log(57.0 / tol)
    for _ in range(30):
        n0 = math.floor(math.log(s_lo) / eta)
        n1 = math.ceil(math.log(s_hi) / eta)
        u = torch.arange(n0, n1 + 1, dtype=torch.float64) * eta
        kernel = SOEKernel(eta, n0, u, exact_lags, (lo, hi), tol, 0.0, horizon)
        err = _max_rel_error(kernel, alphas, lags)
        if err <= tol:
            return SOEKernel(eta, n0, u, exact_lags, (lo, hi), tol, err, horizon)
        eta *= 0.9
    raise RuntimeError(f"could not design an exponential-sum kernel for tol={tol}, orders {order_range}")


def kernel_for(cfg: MemoryConfig, horizon: int, low: float, high: float) -> SOEKernel:
    """The kernel of a ``soe`` config for orders in ``[low, high]`` (``cfg.order_range`` wins if set),
    the range kept inside ``(−0.95, exact_lags − 1)`` where (★) and the check hold."""
    lo, hi = cfg.order_range or (max(low, -0.95), min(high, cfg.exact_lags - 1.0))
    return design_kernel(cfg.tol, int(horizon), (float(lo), float(hi)), cfg.exact_lags)


# --------------------------------------------------------------------------- the one dispatch


@dataclass(frozen=True)
class MemoryPlan:
    """What a memory setting is for a run of ``horizon`` samples: the one place where the kinds become lags, modes
    and a kernel. Every engine — the TEA (torch and compiled), the paper-model simulator, the noise model's state
    space, the live estimator — reads this, none reads ``kind``.

    ``bounded``: constant work per step (``soe``, ``window``); ``x_lags`` / ``p_lags``: lags of the mean and of the
    covariance sums kept exactly (the horizon for ``exact``); ``head``: start-up covariances kept exactly (``soe``);
    ``kernel``: the exponential sum of the older lags (``soe``), else None."""

    config: MemoryConfig
    bounded: bool
    x_lags: int
    p_lags: int
    head: int
    kernel: SOEKernel | None

    @property
    def n_modes(self) -> int:
        return 0 if self.kernel is None else self.kernel.n_modes

    @property
    def code(self) -> int:
        """The compiled kernels' switch: 0 the whole past, 1 exponential sums, 2 a window."""
        return 0 if not self.bounded else 1 if self.kernel is not None else 2


def memory_plan(memory, horizon: int, order_range: tuple | None = None) -> MemoryPlan:
    """The :class:`MemoryPlan` of ``memory`` (a spec, dict or :class:`MemoryConfig`) for ``horizon`` samples;
    ``order_range`` ``(low, high)``: the orders a ``soe`` kernel must serve (:func:`kernel_for`; the config's own
    ``order_range`` wins), needed only for ``soe``."""
    cfg = parse_memory(memory)
    if cfg.kind == "exact":
        return MemoryPlan(cfg, False, int(horizon), int(horizon), 0, None)
    if cfg.kind == "window":
        return MemoryPlan(cfg, True, cfg.window, cfg.window, 0, None)
    if order_range is None and cfg.order_range is None:
        raise ValueError("a soe memory plan needs the orders its kernel serves")
    lo, hi = order_range if order_range is not None else cfg.order_range
    kernel = kernel_for(cfg, horizon, lo, hi)
    return MemoryPlan(cfg, True, cfg.exact_lags, max(cfg.cov_lags, cfg.exact_lags), cfg.cov_head, kernel)


# --------------------------------------------------------------------------- bounded histories


class BoundedHistory(NamedTuple):
    """Constant-size history of a batch of states (``soe`` or ``window``), newest first.

    ``window`` ``(*B, n, J)`` holds ``x_{k}, …, x_{k+1−J}`` (zeros before the start); ``modes``
    ``(*B, n, L+1)`` the exponential-sum states of everything older (``L+1 = 0`` for a plain window).
    """

    window: Tensor
    modes: Tensor

    @classmethod
    def zeros(cls, batch, n: int, lags: int, n_modes: int, *, dtype, device) -> BoundedHistory:
        return cls(torch.zeros(tuple(batch) + (n, lags), dtype=dtype, device=device),
                   torch.zeros(tuple(batch) + (n, n_modes), dtype=dtype, device=device))

    def push(self, x: Tensor, decay: Tensor | None, inject: Tensor | None) -> BoundedHistory:
        """Append ``x`` ``(*B, n)`` as the newest state; the oldest windowed state moves into the modes."""
        window = torch.cat([x.unsqueeze(-1), self.window[..., :-1]], dim=-1)
        if self.modes.shape[-1] == 0:
            return BoundedHistory(window, self.modes)
        dropped = self.window[..., -1:]
        return BoundedHistory(window, torch.addcmul(self.modes * decay, inject, dropped))

    def sum(self, coeffs: Tensor, orders: Tensor | None = None, kernel: SOEKernel | None = None,
            weights: Tensor | None = None) -> Tensor:
        r""":math:`\sum_j c_j x_{k+1-j}` for ``S`` orders: coeffs ``(*B, S, n, J)`` (lags 1…J) and, with a
        kernel, the exponential-sum part for ``orders`` ``(*B, S, n)`` → ``(*B, S, n)``; or with the mode
        weights ``kernel.weights(orders)`` given (``(*B, S, n, L+1)``, e.g. computed once for a constant order)."""
        out = (coeffs * self.window.unsqueeze(-3)).sum(-1)
        if weights is not None:
            out = out + (weights * self.modes.unsqueeze(-3)).sum(-1)
        elif kernel is not None:
            out = out + kernel.tail_sums(orders, self.modes)
        return out


def _recip_gamma_neg(a: Tensor) -> Tensor:
    """``1/Γ(−a)`` by reflection, ``−sin(πa) Γ(1+a)/π``: finite and zero at non-negative integers."""
    return -torch.sin(math.pi * a) * torch.exp(torch.lgamma(1.0 + a)) / math.pi


def gl_coefficients_at(order: Tensor, lags: Tensor) -> Tensor:
    r""":math:`c_j(\alpha) = \Gamma(j-\alpha)/(\Gamma(-\alpha)\Gamma(j+1))` at lags ``j > order`` by log-gamma,
    broadcasting ``order`` against ``lags``. Relative error grows like ``1e-16 · j ln j`` (2e-9 at j = 10⁶):
    for covariance terms, not for the mean sums."""
    lags = lags.to(order.dtype)
    return _recip_gamma_neg(order) * torch.exp(torch.lgamma(lags - order) - torch.lgamma(lags + 1.0))


def cov_tail_mass(a: Tensor, b: Tensor, coeff_a: Tensor, coeff_b: Tensor, k) -> Tensor:
    r"""Coefficient mass :math:`\sum_{j=J+1}^{k} c_j(a)\,c_j(b)` of the covariance sum beyond ``J`` lags.

    ``coeff_a``, ``coeff_b``: ``c_1 … c_J`` of ``a`` and ``b`` (same leading shape as ``a``, ``b`` plus
    the lag dimension); ``k`` the number of lags that exist (the step index). Uses
    :math:`\sum_{j\ge0} c_j(a)c_j(b) = \Gamma(1+a+b)/(\Gamma(1+a)\Gamma(1+b))` (Gauss's sum,
    ``a + b > −1``) minus the first ``J`` terms minus the asymptotic sum over ``j > k``:
    :math:`c_j(a) = j^{-1-a}/\Gamma(-a)\,(1 + a(1+a)/(2j) + O(j^{-2}))`, summed by the midpoint rule
    from ``k + ½``; the relative error of that last piece is O(k⁻²). Zero when ``k ≤ J``.
    """
    J = coeff_a.shape[-1]
    total = torch.exp(torch.lgamma(1.0 + a + b) - torch.lgamma(1.0 + a) - torch.lgamma(1.0 + b))
    head = 1.0 + (coeff_a * coeff_b).sum(-1)
    p1 = 1.0 + a + b
    # a Python k stays a Python number: no tensor made from it per step (off the CPU, a host-device copy)
    K = k + 0.5 if isinstance(k, int) else torch.as_tensor(k, dtype=a.dtype, device=a.device) + 0.5
    g = 0.5 * (a * (1.0 + a) + b * (1.0 + b))
    beyond = _recip_gamma_neg(a) * _recip_gamma_neg(b) * (K ** (-p1) / p1 + g * K ** (-p1 - 1.0) / (p1 + 1.0))
    mass = total - head - beyond
    if isinstance(k, int):
        return mass if k > J else torch.zeros_like(mass)
    return torch.where(torch.as_tensor(k, device=a.device) > J, mass, torch.zeros_like(mass))

r"""One noise model for every engine: a sum of named components, assembled once into what the engines read.

A model is written as a spec string, ``fractional+white``, ``fractional+white+random-walk+sinusoid`` …
(:func:`parse_model`). Its parameters are named ``component.parameter`` (``fractional.order``,
``white.r``); a batch of parameter sets is a dict of ``(B,)`` tensors, or a ``(B, P)`` matrix in
:attr:`NoiseModel.names` order.

What the engines read:

* :meth:`NoiseModel.spectrum` — the sum of the stationary components' spectra (the Whittle likelihood);
* :meth:`NoiseModel.mean` — the deterministic part (offset, ramp, sinusoids, temperature terms);
* :meth:`NoiseModel.state_space` — ``F, Q, C, R`` of the stacked linear Gaussian state (the exact
  Kalman filter and the simulator); the fractional component's history is its GL window plus the
  exponential-sum modes of :mod:`torchtea.core.memory` (``soe``), or the whole past (``exact``, small N only).

Every state starts at zero with zero variance: the GL model's ``x_0 = 0`` and zero history, the random
walk's ``b_0 = 0`` (an ``offset`` component, or the exact likelihood's integrated level, carries an unknown
constant); a low-pass that filters white noise starts at its first filtered sample (``StateSpace.g0``).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch
from torch import Tensor

from ..core.gl import broadcast_shapes
from ..core.memory import MemoryConfig, SOEKernel, memory_plan, parse_memory
from . import grammar
from .components import COMPONENTS, ORDER_BOUNDS, Component, FractionalState, MeanEffect, Modifier, StateEffect

__all__ = ["NoiseModel", "PAPER_MODEL", "parse_model", "StateSpace", "VaryingRow", "StateMemory", "state_memory",
           "EXACT_MEMORY_LIMIT", "ROW_TABLE"]

#: ``exact`` memory puts the whole past in the state (O(N²) per step): only for short series (tests).
EXACT_MEMORY_LIMIT = 4000


@dataclass(frozen=True)
class StateMemory:
    """How a fractional state's past is carried: ``lags`` exact lags and, for ``soe``, the kernel's modes."""

    lags: int
    kernel: SOEKernel | None = None

    @property
    def n_modes(self) -> int:
        return 0 if self.kernel is None else self.kernel.n_modes


def state_memory(memory, n_steps: int, orders: tuple | None = None) -> StateMemory:
    """The state-space form of a memory setting (``"soe"``, ``"soe:1e-8"``, ``"exact"``, ``"window:L"``)
    for series of ``n_steps`` samples. The single place where memory kinds become states. A ``soe`` kernel serves
    the model's orders (:data:`ORDER_BOUNDS`); ``orders`` ``(low, high)``, the orders a simulation runs, widens it
    when they leave them (the paper's Example 3 reaches order 2) — inside them it is the filter's kernel."""
    cfg = parse_memory(memory)
    if not cfg.bounded:
        if n_steps > EXACT_MEMORY_LIMIT:
            raise ValueError(f"exact memory keeps all {n_steps} past samples in the state; use soe for more than "
                             f"{EXACT_MEMORY_LIMIT} samples")
        return StateMemory(max(n_steps - 1, 1))
    lo, hi = ORDER_BOUNDS[0], ORDER_BOUNDS[1] - 1e-3
    if orders is not None:
        lo, hi = min(lo, float(orders[0]) - 0.01), max(hi, float(orders[1]) + 0.01)
    plan = memory_plan(cfg, max(n_steps, cfg.exact_lags + 2), (lo, hi))
    return StateMemory(plan.x_lags, plan.kernel)


#: A time-varying order's first rows are tabulated: exactly at each distinct order when there are at most this many,
#: else on this many equally spaced orders between the lowest and highest with linear interpolation between them.
ROW_TABLE = 4096
#: A known order trajectory (``state_space(..., orders=)``: the paper's schedules) is tabulated exactly at every
#: distinct order while the tables of all parameter sets hold at most this many entries (64 MB), and like a
#: temperature-driven order beyond (a wide batch of parameter sets under a long schedule: rows interpolated).
ROW_ENTRIES = 1 << 23


@dataclass(frozen=True)
class VaryingRow:
    """Row ``i`` of F and the noise loading of its noise ``column`` per step, for a time-varying order: step k → k+1
    uses ``row(k)`` ``(B, n)`` and ``loading(k)`` ``(B,)`` (so ``Q_k[i, i] = loading²``); every other entry of F and
    Q is constant. Stored as a table over orders — ``table`` ``(B, G, n)``, ``loading_table`` ``(B, G)`` — and per
    step the table position ``index`` ``(B, N)`` and the weight ``frac`` ``(B, N)`` of the next entry: memory O(N),
    not O(N n) (a three-hour recording's rows would take gigabytes). The entries are exact at the table's orders;
    between them (more than :data:`ROW_TABLE` distinct orders) the interpolation's error is that of a line through
    a smooth function over a step of (range of orders)/4095 — about 10⁻¹⁰ relative for a range of 0.1, far below
    the exponential-sum kernel's own tolerance."""

    i: int
    table: Tensor
    loading_table: Tensor
    index: Tensor
    frac: Tensor
    column: int

    def _at(self, tab: Tensor, k: int) -> Tensor:
        """Step k's entry of ``tab`` (``(B, G, …)``): its table entry and the next mixed by the weight (the compiled
        kernels do the same in :func:`torchtea.noise.simulate_kernel.varying_row`)."""
        b = torch.arange(tab.shape[0])
        j = self.index[:, k]
        w = self.frac[:, k].reshape(-1, *([1] * (tab.dim() - 2)))
        nxt = (j + 1).clamp(max=tab.shape[1] - 1)
        return tab[b, j] * (1.0 - w) + tab[b, nxt] * w

    def row(self, k: int) -> Tensor:
        return self._at(self.table, k)

    def loading(self, k: int) -> Tensor:
        return self._at(self.loading_table, k)

    def rows(self) -> Tensor:
        """Every step's row ``(B, N, n)`` (O(N n) memory: for short series and tests)."""
        return torch.stack([self.row(k) for k in range(self.index.shape[1])], dim=1)

    def expand(self, m: int) -> VaryingRow:
        return VaryingRow(self.i, self.table.expand(m, -1, -1), self.loading_table.expand(m, -1),
                          self.index.expand(m, -1), self.frac.expand(m, -1), self.column)


def varying_kernel_args(v: VaryingRow | None, B: int, n: int) -> tuple:
    """``(i, table, loading_table, index, frac, column)`` as NumPy arrays in the form the compiled kernels take them
    (the simulator's loop, the Riccati filter); without a time-varying order (``v`` None) ``i = -1`` and
    placeholders of the same types, so each kernel is compiled once."""
    if v is None:
        return -1, np.zeros((B, 1, n)), np.zeros((B, 1)), np.zeros((B, 1), dtype=np.int64), np.zeros((B, 1)), 0

    def arr(t: Tensor, dtype) -> np.ndarray:
        return np.ascontiguousarray(t.detach().cpu().numpy(), dtype=dtype)

    return (int(v.i), arr(v.table, np.float64), arr(v.loading_table, np.float64), arr(v.index, np.int64),
            arr(v.frac, np.float64), int(v.column))


@dataclass(frozen=True)
class StateSpace:
    r"""``z_{k+1} = F z_k + ε_k``, ε ~ N(0, Q); ``y_k = μ_k + C z_k + ν_k``, ν ~ N(0, R); ``z_0 = 0``.

    F ``(B, n, n)``; ``ε_k = G ξ_k`` with G ``(B, n, m)`` and ξ standard normal, so ``Q = G Gᵀ``;
    C ``(B, n)``; R ``(B,)``; ``blocks`` maps each state component to its slice of z (its output is the slice's first
    state; a filter's is its last)."""

    F: Tensor
    G: Tensor
    C: Tensor
    R: Tensor
    blocks: dict = field(default_factory=dict)
    #: A time-varying order (``temperature-order``, :class:`VaryingRow`): row ``i`` of F and G's entry in row ``i``
    #: and noise ``column`` (which no other row shares) per step; every other entry of F and Q is constant.
    varying: VaryingRow | None = None
    #: The initial state's loading ``(B, n)``: ``z_0 = g0 ξ`` with ξ standard normal (``P_0 = g0 g0ᵀ``); None is
    #: zero (every state starts at zero). A low-pass that filters white noise starts at its first input sample.
    g0: Tensor | None = None

    @property
    def initial(self) -> Tensor:
        """``g0`` ``(B, n)`` (zeros when every state starts at zero)."""
        return self.F.new_zeros(self.F.shape[0], self.F.shape[-1]) if self.g0 is None else self.g0

    def expand(self, m: int) -> StateSpace:
        """The one parameter set of a batch of one repeated ``m`` times (views, no copies): to filter ``m``
        series, e.g. regressors, with the same gains."""
        if self.F.shape[0] != 1:
            raise ValueError(f"expand needs a state space of one parameter set, got {self.F.shape[0]}")
        v = self.varying
        return StateSpace(self.F.expand(m, -1, -1), self.G.expand(m, -1, -1), self.C.expand(m, -1), self.R.expand(m),
                          self.blocks, None if v is None else v.expand(m),
                          None if self.g0 is None else self.g0.expand(m, -1))

    @property
    def Q(self) -> Tensor:
        return self.G @ self.G.mT

    @property
    def n(self) -> int:
        return self.F.shape[-1]


class NoiseModel:
    """A sum of components (see :func:`parse_model`). ``h`` is the sample time (s)."""

    def __init__(self, components: list[tuple[str, Component]], spec: str):
        self.components = components
        self.spec = spec
        self.names = [f"{label}.{p.name}" for label, comp in components for p in comp.params]
        self._specs = {f"{label}.{p.name}": p for label, comp in components for p in comp.params}
        #: a pole fraction's name → the name of the order it is a fraction of the stability limit at
        self._order_of = {f"{label}.{p.name}": f"{label}.{comp.order_param}" for label, comp in components
                          for p in comp.params if p.kind == "fraction"}

    def __repr__(self):
        return f"NoiseModel({self.spec!r})"

    # ------------------------------------------------------------------ structure
    def has(self, name: str) -> bool:
        return any(comp.name == name for _, comp in self.components)

    @property
    def order_labels(self) -> list[str]:
        """The labels of the components with a fractional order (:attr:`Component.order_param`)."""
        return [label for label, c in self.components if c.order_param is not None]

    @property
    def order_name(self) -> str | None:
        """The parameter name of the model's fractional order (``fractional.order``), None without one."""
        labels = self.order_labels
        return None if not labels else f"{labels[0]}.{dict(self.components)[labels[0]].order_param}"

    @property
    def stationary(self) -> bool:
        """Whether the model's dynamics are the same at every time (its spectrum defines its likelihood)."""
        return all(c.stationary for _, c in self.components)

    @property
    def diffuse(self) -> bool:
        """A component does not return to a mean (a random walk): the Whittle fits profile a trend out
        (:attr:`~torchtea.noise.components.Component.diffuse`)."""
        return any(isinstance(c, StateEffect) and c.diffuse for _, c in self.components)

    @property
    def has_level(self) -> bool:
        """A component carries the series' constant level (an ``offset``): the fits do not centre the series."""
        return any(isinstance(c, MeanEffect) and c.level for _, c in self.components)

    @property
    def modifiers(self) -> list:
        """The labels of the components that change the fractional state's order in time
        (:class:`~torchtea.noise.components.Modifier`)."""
        return [label for label, c in self.components if isinstance(c, Modifier)]

    def references(self) -> set:
        """The parameters the components hold as references, not estimates (a temperature's ``t_ref``)."""
        return {f"{lb}.{p}" for lb, c in self.components for p, words in c.held.items() if words is None}

    def held_estimates(self, label: str = "*") -> dict:
        """The estimates the components hold in a fit (:attr:`~torchtea.noise.components.Component.held` entries with
        words, not the references): those of the component ``label``, or of every component with ``"*"``. Name →
        the words for its interval. They count in BIC (:meth:`~torchtea.fitting.mle.Fit.count`)."""
        return {f"{lb}.{p}": words for lb, comp in self.components for p, words in comp.held.items()
                if words is not None and label in ("*", lb)}

    def located(self) -> dict:
        """The parameters every fit holds where the data put them (a step's time: the likelihood is not smooth in
        it), name → the words for its interval (:attr:`~torchtea.noise.components.Component.located`)."""
        return {f"{lb}.{p}": c.held[p] for lb, c in self.components for p in c.located}

    def labels(self, kind: str | None = None) -> list[str]:
        return [label for label, comp in self.components if kind is None or comp.kind == kind]

    def param_spec(self, name: str):
        return self._specs[name]

    def without(self, name: str) -> NoiseModel:
        """The same model without every component called ``name`` (the null of a presence test)."""
        name = name.partition(":")[0]  # (a token, spikes:3, names its component)
        kept = [c for _, c in self.components if c.name != name]
        if not kept:
            raise ValueError(f"the model {self.spec!r} has nothing left without {name!r}")
        return assemble(kept)

    # ------------------------------------------------------------------ parameter sets
    def as_dict(self, values) -> dict:
        """A ``(B, P)`` matrix / ``(P,)`` vector / dict of values → dict of ``(B,)`` float64 tensors."""
        if isinstance(values, dict):
            missing = [n for n in self.names if n not in values]
            if missing:
                raise ValueError(f"model {self.spec!r} needs values for {missing}")
            out = {n: torch.as_tensor(values[n], dtype=torch.float64) for n in self.names}
            shape = broadcast_shapes(*(v.shape for v in out.values()))
            shape = shape if len(shape) else (1,)
            return {n: v.expand(shape).reshape(-1) for n, v in out.items()}
        m = torch.as_tensor(values, dtype=torch.float64)
        m = m.reshape(-1, len(self.names)) if m.ndim < 2 else m
        return {n: m[:, i] for i, n in enumerate(self.names)}

    def as_matrix(self, values) -> Tensor:
        v = self.as_dict(values)
        return torch.stack([v[n] for n in self.names], dim=-1)

    def _by_component(self, v: dict) -> dict:
        out = {}
        for label, comp in self.components:
            out[label] = {p.name: v[f"{label}.{p.name}"] for p in comp.params}
        return out

    def to_unconstrained(self, values, h: float) -> Tensor:
        """Values → unconstrained ``(B, P)`` (log for positive, logit for bounded, for a frequency's share of the Nyquist
        frequency and for the pole's fraction)."""
        v = self.as_dict(values)
        return torch.stack([self._specs[n].to_unconstrained(v[n], h, v.get(self._order_of.get(n)), where=n)
                            for n in self.names], dim=-1)

    def from_unconstrained(self, u: Tensor, h: float) -> dict:
        """Inverse of :meth:`to_unconstrained` (differentiable)."""
        u = u.reshape(-1, len(self.names))
        v = {n: self._specs[n].from_unconstrained(u[:, i], h) for i, n in enumerate(self.names)
             if n not in self._order_of}
        for i, n in enumerate(self.names):  # (a pole fraction after the order it is a fraction at)
            if n in self._order_of:
                v[n] = self._specs[n].from_unconstrained(u[:, i], h, v[self._order_of[n]])
        return v

    # ------------------------------------------------------------------ what the engines read
    def spectrum(self, values, omega: Tensor, h: float) -> Tensor:
        """Two-sided spectral density of the stochastic part at ω (rad/sample), ``(B, W)``."""
        byc = self._by_component(self.as_dict(values))
        total = None
        for label, comp in self.components:
            if comp.kind == "filter":
                if total is not None:
                    total = total * comp.gain(byc[label], omega, h)
                continue
            if comp.kind in ("state", "measurement"):
                s = comp.spectrum(byc[label], omega, h)
                total = s if total is None else total + s
        if total is None:
            raise ValueError(f"model {self.spec!r} has no stochastic component")
        return total

    def component_spectra(self, values, omega: Tensor, h: float) -> dict:
        """Each stochastic component's share of :meth:`spectrum` (label → ``(B, W)``, through the sensor filter
        after it; they sum to it: the components are independent)."""
        byc = self._by_component(self.as_dict(values))
        out = {}
        for label, comp in self.components:
            if comp.kind == "filter":
                g = comp.gain(byc[label], omega, h)
                out = {k: s * g for k, s in out.items()}
            elif comp.kind in ("state", "measurement"):
                out[label] = comp.spectrum(byc[label], omega, h)
        return out

    def check_inputs(self, inputs: dict | None, kinds=("mean", "modifier")) -> None:
        """Raise ``ValueError`` naming the first component of ``kinds`` whose input channel (e.g. the
        temperature) is not in ``inputs``."""
        for label, comp in self.components:
            if comp.kind in kinds:
                for name in comp.inputs:
                    if inputs is None or name not in inputs:
                        raise ValueError(f"component {label!r} needs the input channel {name!r} "
                                         f"(e.g. --temperature COLUMN)")

    def mean(self, values, t: Tensor, inputs: dict | None = None) -> Tensor:
        """Deterministic part ``(B, N)`` at times ``t`` (s from the first sample)."""
        self.check_inputs(inputs, ("mean",))
        v = self.as_dict(values)
        byc = self._by_component(v)
        B = next(iter(v.values())).shape[0]
        t = torch.as_tensor(t, dtype=torch.float64)
        out = torch.zeros(B, t.shape[-1], dtype=torch.float64)
        for label, comp in self.components:
            if comp.kind != "mean":
                continue
            out = out + comp.mean(byc[label], t, {k: torch.as_tensor(x, dtype=torch.float64)
                                                  for k, x in (inputs or {}).items()})
        return out

    def measurement_variance(self, values) -> Tensor:
        """Total white measurement variance ``(B,)`` (white r plus quantisation Δ²/12; zero without them)."""
        v = self.as_dict(values)
        byc = self._by_component(v)
        r = torch.zeros(next(iter(v.values())).shape[0], dtype=torch.float64)
        for label, comp in self.components:
            if comp.kind == "measurement":
                r = r + comp.measurement_variance(byc[label])
        return r

    def state_space(self, values, h: float, n_steps: int, memory="soe", inputs: dict | None = None,
                    orders: Tensor | None = None) -> StateSpace:
        """Assemble the stacked state: blocks of the state components on the diagonal, the sensor filter (if
        any: a low-pass, one state; a digital filter, one state per stage) fed by the sum of the stochastic components
        before it (:meth:`~torchtea.noise.components.LowPass.filter_block`), white noise after it in R; with a
        ``temperature-order`` component the fractional block's first row per step (``StateSpace.varying``,
        from ``inputs["temperature"]``). ``orders`` ``(B, N)`` or ``(N,)``: a known order trajectory of the fractional
        component instead (the paper's variable-order examples, (9) with ``α_k`` given), its row per step alike."""
        v = self.as_dict(values)
        byc = self._by_component(v)
        B = next(iter(v.values())).shape[0]
        mem = state_memory(memory, n_steps) if isinstance(memory, (str, dict, MemoryConfig)) else memory
        Fs, Gs, blocks, outs_before, outs_after = [], [], {}, [], []
        lowpass = None
        start = 0
        r_before = torch.zeros(B, dtype=torch.float64)  # white noise the low-pass filters
        r_after = torch.zeros(B, dtype=torch.float64)  # white noise in R
        for label, comp in self.components:
            if comp.kind == "filter":
                lowpass = label
                continue
            if comp.kind == "measurement":
                r = comp.measurement_variance(byc[label]).expand(B)
                if lowpass is None:
                    r_before = r_before + r
                else:
                    r_after = r_after + r
                continue
            if comp.kind != "state":
                continue
            F, G = comp.block(byc[label], h, mem)
            F, G = F.expand(B, -1, -1), G.expand(B, -1, -1)
            blocks[label] = slice(start, start + F.shape[-1])
            (outs_after if lowpass else outs_before).append(start)
            start += F.shape[-1]
            Fs.append(F)
            Gs.append(G)
        n = start
        m = sum(G.shape[-1] for G in Gs)
        F = torch.zeros(B, n, n, dtype=torch.float64)
        G = torch.zeros(B, n, m, dtype=torch.float64)
        col = 0
        noise_cols = {}
        for (label, sl), Fb, Gb in zip(blocks.items(), Fs, Gs):
            F[:, sl, sl] = Fb
            G[:, sl, col:col + Gb.shape[-1]] = Gb
            noise_cols[label] = col
            col += Gb.shape[-1]
        C = torch.zeros(B, n, dtype=torch.float64)
        g0 = None
        if lowpass is not None:
            F, G, C, g0 = self._with_filter(byc, lowpass, h, B, F, G, blocks, outs_before, outs_after, r_before)
        else:
            C[:, outs_before] = 1.0
        varying = self._varying_order(byc, blocks, noise_cols, lowpass, h, n_steps, mem, inputs, B, F.shape[-1],
                                      orders)
        return StateSpace(F, G, C, (r_before + r_after if lowpass is None else r_after).clone(), blocks, varying, g0)

    def _with_filter(self, byc, lowpass: str, h: float, B: int, F: Tensor, G: Tensor, blocks: dict,
                     outs_before: list, outs_after: list, r_before: Tensor):
        """The stacked ``(F, G, C, g0)`` with the sensor filter ``lowpass``'s states appended (``blocks`` updated)."""
        n = F.shape[-1]
        g0 = None
        if not outs_before and not bool((r_before > 0).any()):
            raise ValueError(f"model {self.spec!r}: a {lowpass} needs components before it to filter")
        # the filter's own states x_{k+1} = A x_k + b u_{k+1} (its output the last), driven by the sum of the
        # components before it, u_{k+1} = s·(F z_k + ε_k) + ν_{k+1}: m more states, their noise correlated with
        # the others' and, with white noise before the filter, one more noise column ν of variance r_before
        A, b = dict(self.components)[lowpass].filter_block(byc[lowpass], h)  # (B, m, m), (B, m)
        A, b = A.expand(B, -1, -1), b.expand(B, -1)
        m_f = A.shape[-1]
        s = torch.zeros(B, n, dtype=torch.float64)  # selects the sum of the components before it
        s[:, outs_before] = 1.0
        T = torch.cat([torch.eye(n, dtype=torch.float64).expand(B, n, n),
                       b.unsqueeze(-1) * s.unsqueeze(1)], dim=1)  # (B, n+m, n)
        F2 = torch.zeros(B, n + m_f, n + m_f, dtype=torch.float64)
        F2[:, :, :n] = T @ F
        F2[:, n:, n:] = A
        F, G = F2, T @ G
        if bool((r_before > 0).any()):
            nu = torch.zeros(B, n + m_f, 1, dtype=torch.float64)
            nu[:, n:, 0] = b * torch.sqrt(r_before).unsqueeze(-1)
            G = torch.cat([G, nu], dim=-1)
            # the filter starts from rest before the first sample: x_0 = b ν_0 (the states start at 0)
            g0 = nu[..., 0].clone()
        blocks[lowpass] = slice(n, n + m_f)
        C = torch.zeros(B, n + m_f, dtype=torch.float64)
        C[:, n + m_f - 1] = 1.0
        C[:, outs_after] = 1.0
        return F, G, C, g0

    def _varying_order(self, byc, blocks, noise_cols, lowpass, h, n_steps, mem, inputs, B, n, orders=None):
        mods = self.modifiers
        if not mods and orders is None:
            return None
        fracs = self.order_labels
        if (len(mods) + (orders is not None) > 1 or len(fracs) != 1 or lowpass is not None
                or not isinstance(dict(self.components)[fracs[0]], FractionalState)):
            raise ValueError(f"model {self.spec!r}: a time-varying order (temperature-order, or a known order "
                             "trajectory) drives the order of one fractional component, once, and cannot be combined "
                             "with a sensor filter (low-pass, digital-filter)")
        frac = byc[fracs[0]]
        comps = dict(self.components)
        alpha = self._orders_in_time(byc, n_steps, inputs, orders, B)  # (B, N): α_k
        exact_rows = max(ROW_TABLE, ROW_ENTRIES // (n * B)) if orders is not None else ROW_TABLE
        a_next = torch.cat([alpha[:, 1:], alpha[:, -1:]], dim=1)  # step k → k+1 uses α_{k+1}
        grids, index, weight = [], [], []
        for b in range(B):
            values, inverse = torch.unique(a_next[b], return_inverse=True)
            if len(values) <= exact_rows:  # exact: a row per distinct order
                grids.append(values)
                index.append(inverse)
                weight.append(torch.zeros(n_steps, dtype=torch.float64))
            else:
                lo, hi = float(values[0]), float(values[-1])
                grid = torch.linspace(lo, hi, ROW_TABLE, dtype=torch.float64)
                pos = (a_next[b] - lo) / (hi - lo) * (ROW_TABLE - 1)
                j = pos.floor().clamp(0, ROW_TABLE - 2)
                grids.append(grid)
                index.append(j.to(torch.int64))
                weight.append(pos - j)
        G_ = max(len(g_) for g_ in grids)
        tabulated = torch.stack([torch.cat([g_, g_[-1:].expand(G_ - len(g_))]) for g_ in grids])  # (B, G)
        row, g = comps[fracs[0]].first_row({k: x.unsqueeze(-1) for k, x in frac.items()}, tabulated, h, mem)
        sl = blocks[fracs[0]]
        table = row.new_zeros(B, G_, n)
        table[..., sl] = row
        return VaryingRow(sl.start, table, g, torch.stack(index), torch.stack(weight), noise_cols[fracs[0]])

    def orders_in_time(self, values, n_steps: int, inputs: dict | None = None, orders=None) -> Tensor | None:
        """The fractional component's order at every step ``(B, N)``: the known trajectory ``orders`` (``(N,)`` or
        ``(B, N)``), else the one a ``temperature-order`` modifier gives (from ``inputs["temperature"]``), else its
        constant ``order``; None for a model without a fractional component."""
        if not self.order_labels:
            return None
        v = self.as_dict(values)
        return self._orders_in_time(self._by_component(v), n_steps, inputs, orders, next(iter(v.values())).shape[0])

    def _orders_in_time(self, byc: dict, n_steps: int, inputs, orders, B: int) -> Tensor:
        comps = dict(self.components)
        label = self.order_labels[0]
        alpha0 = byc[label][comps[label].order_param]
        if orders is not None:
            a = torch.as_tensor(orders, dtype=torch.float64)
            if (a.shape[-1] != n_steps or a.ndim > 2 or a.ndim == 2 and a.shape[0] not in (1, B)
                    or not bool(torch.isfinite(a).all())):
                raise ValueError(f"orders must have shape ({n_steps},) or (B, {n_steps}) with B = {B}, finite; got "
                                 f"shape {tuple(a.shape)}")
            return a.reshape(-1, n_steps).expand(B, n_steps)
        mods = self.modifiers
        if not mods:
            return alpha0.reshape(B, 1).expand(B, n_steps)
        self.check_inputs(inputs, ("modifier",))
        T = torch.as_tensor(inputs["temperature"], dtype=torch.float64).reshape(-1)
        if T.shape[0] < n_steps or not bool(torch.isfinite(T[:n_steps]).all()):
            raise ValueError(f"the temperature input must have {n_steps} finite values, got {T.shape[0]} "
                             f"({int((~torch.isfinite(T)).sum())} not finite)")
        return comps[mods[0]].orders(byc[mods[0]], alpha0, T[:n_steps])


#: The paper's noise model (43)–(45): a fractional state and white measurement noise — every command's starting model.
PAPER_MODEL = "fractional+white"


def parse_model(spec) -> NoiseModel:
    """``"fractional+white"`` → :class:`NoiseModel`. Components are joined by ``+``; a component named twice
    gets labels ``name``, ``name2`` … ; ``name:argument`` configures one that takes an argument (``spikes:13``,
    :meth:`~torchtea.noise.components.Component.configured`). Raises ``ValueError`` naming the spec and the
    choices."""
    if isinstance(spec, NoiseModel):
        return spec
    text = str(spec).strip().lower().replace(" ", "")
    parts = [p for p in text.split("+")]
    if not text or any(not p for p in parts):
        raise ValueError(f"bad model spec {spec!r}: components joined by '+', e.g. fractional+white")
    comps = []
    for token in parts:
        p, _, argument = token.partition(":")
        if p not in COMPONENTS:  # an installed package's effect, registered on first use
            from ..effects import load_entry_points

            load_entry_points()
        if p not in COMPONENTS:
            raise ValueError(f"unknown component {p!r} in model {spec!r}; choose from: {', '.join(COMPONENTS)}")
        comps.append(component_of(COMPONENTS[p], argument, spec))
    return assemble(comps, spec)


def component_of(comp: Component, argument: str, spec) -> Component:
    """The registered ``comp`` as the spec ``spec`` writes it: configured by ``argument`` (``spikes:13``), or refused
    where it needs one and has none."""
    if argument:
        return grammar.configured(comp, argument)
    if grammar.grammar_of(comp).needs_argument:
        raise ValueError(f"model {spec!r}: {grammar.grammar_of(comp).needs_argument}")
    return comp


def assemble(components: list, spec=None) -> NoiseModel:
    """The model of these components in this order (each labelled by its name, a second one ``name2`` …), as
    :func:`parse_model` builds it from a spec: refused (naming ``spec``, default the components' own spec) where a
    model cannot hold them."""
    spec = "+".join(grammar.token(c) for c in components) if spec is None else spec
    comps, by_name = [], {}
    for comp in components:
        same = by_name.setdefault(comp.name, [])
        same.append(comp)
        comps.append((comp.name if len(same) == 1 else f"{comp.name}{len(same)}", comp))
    for name, same in by_name.items():
        if len(same) > 1 and grammar.grammar_of(same[0]).single:
            raise ValueError(f"model {spec!r}: at most one {name}")
    if not any(c.kind in ("state", "measurement") for _, c in comps):
        raise ValueError(f"model {spec!r} has no stochastic component (fractional, white, random-walk …)")
    for _, comp in comps:
        grammar.validate(comp, comps, spec)
    return NoiseModel(comps, "+".join(grammar.token(c) for _, c in comps))

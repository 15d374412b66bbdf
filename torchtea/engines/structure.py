"""Linear A-type discrete fractional variable-order state-space (DFVOSS) model.

Paper (9)–(11)::

    x_{k+1} = h^{α_{k+1}} (A(w) x_k + B u_k + ω_k) − Σ_{j=1}^{k+1} c_j(α_{k+1}) x_{k+1−j}
    y_k     = C x_k + ν_k

with one order per state (``h^{α}`` and ``c_j(α)`` act as diagonal matrices),
parameters ``w`` entering ``A`` affinely, known inputs ``u``. An integer-order
state (bias random walk) is a state with a fixed order 1.

Shapes: ``n`` states, ``m`` parameters, ``d`` inputs, ``p`` outputs.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import torch
from torch import Tensor

__all__ = [
    "ParametricMatrix",
    "Structure",
    "OrderSchedule",
    "ConstantOrder",
    "LinearOrder",
    "ParabolicOrder",
    "FunctionOrder",
    "InputOrder",
    "parse_order_spec",
]


def _as_matrix(value, rows: int | None = None, cols: int | None = None) -> Tensor:
    t = torch.as_tensor(value, dtype=torch.float64)
    if t.ndim == 0:
        t = t.reshape(1, 1)
    if t.ndim != 2:
        raise ValueError(f"expected a matrix, got shape {tuple(t.shape)}")
    if rows is not None and t.shape[0] != rows or cols is not None and t.shape[1] != cols:
        raise ValueError(f"expected a {rows}x{cols} matrix, got {tuple(t.shape)}")
    return t


@dataclass(frozen=True)
class ParametricMatrix:
    """An affine matrix function ``M(w) = M₀ + Σ_i w_i M_i``.

    Attributes
    ----------
    base : Tensor, shape ``(r, c)``
        ``M₀``.
    basis : Tensor, shape ``(m, r, c)``
        ``M_i``, one per parameter.
    """

    base: Tensor
    basis: Tensor

    def __post_init__(self):
        if self.basis.ndim != 3 or self.basis.shape[1:] != self.base.shape:
            raise ValueError("basis must have shape (m, *base.shape)")

    @property
    def n_params(self) -> int:
        return self.basis.shape[0]

    @classmethod
    def scalar(cls) -> ParametricMatrix:
        """``A(w) = w`` for one state and one parameter (the paper's ``f``)."""
        return cls(torch.zeros(1, 1, dtype=torch.float64), torch.ones(1, 1, 1, dtype=torch.float64))

    def __call__(self, w: Tensor) -> Tensor:
        """Evaluate for parameters ``w`` of shape ``(*B, m)``; returns ``(*B, r, c)``."""
        base = self.base.to(w)
        basis = self.basis.to(w)
        if w.shape[-1] != self.n_params:
            raise ValueError(f"expected {self.n_params} parameters, got {w.shape[-1]}")
        return base + torch.einsum("...m,mrc->...rc", w, basis)


@dataclass(frozen=True)
class Structure:
    """The known structure of an A-type DFVOSS model (what the estimator assumes).

    Attributes
    ----------
    A : ParametricMatrix
        State matrix ``A(w)``, ``n × n``, with ``m`` parameters.
    B : Tensor, shape ``(n, d)``
        Input matrix.
    C : Tensor, shape ``(p, n)``
        Output matrix.
    estimated : tuple of bool, length ``n``
        Which states have an estimated order (KFo); the others use ``fixed_orders``.
    fixed_orders : Tensor, shape ``(n,)``
        Orders of the states that are not estimated (e.g. 1 for a random walk).
    """

    A: ParametricMatrix = field(default_factory=ParametricMatrix.scalar)
    B: Tensor = field(default_factory=lambda: torch.ones(1, 1, dtype=torch.float64))
    C: Tensor = field(default_factory=lambda: torch.ones(1, 1, dtype=torch.float64))
    estimated: tuple = (True,)
    fixed_orders: Tensor = field(default_factory=lambda: torch.ones(1, dtype=torch.float64))

    def __post_init__(self):
        n = self.A.base.shape[0]
        if self.A.base.shape != (n, n):
            raise ValueError("A must be square")
        object.__setattr__(self, "B", _as_matrix(self.B, rows=n))
        object.__setattr__(self, "C", _as_matrix(self.C, cols=n))
        fixed = torch.as_tensor(self.fixed_orders, dtype=torch.float64).reshape(-1)
        if fixed.numel() == 1:
            fixed = fixed.expand(n).clone()
        object.__setattr__(self, "fixed_orders", fixed)
        if len(self.estimated) != n or fixed.shape != (n,):
            raise ValueError("estimated and fixed_orders need one entry per state")
        if not any(self.estimated):
            raise ValueError("at least one order must be estimated")

    @property
    def n_states(self) -> int:
        return self.A.base.shape[0]

    @property
    def n_params(self) -> int:
        return self.A.n_params

    @property
    def n_inputs(self) -> int:
        return self.B.shape[1]

    @property
    def n_outputs(self) -> int:
        return self.C.shape[0]

    @property
    def n_estimated_orders(self) -> int:
        return sum(bool(e) for e in self.estimated)

    def full_orders(self, estimated: Tensor) -> Tensor:
        """Insert estimated orders ``(*B, L)`` among the fixed ones → ``(*B, n)``."""
        idx = [i for i, e in enumerate(self.estimated) if e]
        fixed = self.fixed_orders.to(estimated)
        if len(idx) == self.n_states:
            return estimated
        out = fixed.expand(estimated.shape[:-1] + (self.n_states,)).clone()
        out[..., idx] = estimated
        return out

    @classmethod
    def scalar_noise(cls) -> Structure:
        """The paper's noise model (43)–(45): ``A = f`` (estimated), ``B = C = 1``."""
        return cls()


# --------------------------------------------------------------------------- orders


class OrderSchedule:
    """A known order trajectory ``α_k``, one value per state.

    Subclasses implement :meth:`values`.
    """

    def values(self, n_steps: int, h: float, n_states: int, inputs: Tensor | None = None) -> Tensor:
        """Orders ``α_k`` for ``k = 0 … n_steps−1``.

        Returns a tensor of shape ``(N, n)``, or ``(*B, N, n)`` when it depends
        on batched inputs ``(*B, N, d)``.
        """
        raise NotImplementedError

    def _time(self, n_steps: int, h: float) -> Tensor:
        return torch.arange(n_steps, dtype=torch.float64) * h

    def spec(self) -> str:
        """The command-line SPEC of this schedule (inverse of :func:`parse_order_spec`)."""
        raise ValueError(f"{type(self).__name__} has no command-line SPEC")

    @staticmethod
    def _per_state(v: Tensor, n_states: int) -> Tensor:
        """The same order ``(N,)`` for every state → ``(N, n)``."""
        return v.unsqueeze(-1).expand(v.shape[0], n_states).clone()


@dataclass(frozen=True)
class ConstantOrder(OrderSchedule):
    """``α_k = value`` (Example 1)."""

    value: float

    def spec(self) -> str:
        return repr(float(self.value))

    def values(self, n_steps, h, n_states, inputs=None):
        return torch.full((n_steps, n_states), float(self.value), dtype=torch.float64)


@dataclass(frozen=True)
class LinearOrder(OrderSchedule):
    """``α_k = start + slope · k h`` — paper (47) with start 0.2, slope 0.1."""

    start: float
    slope: float

    def spec(self) -> str:
        return f"linear:{float(self.start)!r},{float(self.slope)!r}"

    def values(self, n_steps, h, n_states, inputs=None):
        return self._per_state(self.start + self.slope * self._time(n_steps, h), n_states)


@dataclass(frozen=True)
class ParabolicOrder(OrderSchedule):
    """``α_k = start + curvature · (k h)²`` — paper (48) with start 0.2, curvature 0.05."""

    start: float
    curvature: float

    def spec(self) -> str:
        return f"parabolic:{float(self.start)!r},{float(self.curvature)!r}"

    def values(self, n_steps, h, n_states, inputs=None):
        return self._per_state(self.start + self.curvature * self._time(n_steps, h) ** 2, n_states)


@dataclass(frozen=True)
class FunctionOrder(OrderSchedule):
    """``α_k = fn(t_k)`` for a user function of the time tensor ``(N,)``, returning ``(N,)`` or ``(N, n)``."""

    fn: Callable[[Tensor], Tensor]

    def values(self, n_steps, h, n_states, inputs=None):
        v = torch.as_tensor(self.fn(self._time(n_steps, h)), dtype=torch.float64)
        if v.shape == (n_steps,):
            v = self._per_state(v, n_states)
        if v.shape != (n_steps, n_states):
            raise ValueError(f"order function returned shape {tuple(v.shape)}, expected ({n_steps},) or ({n_steps}, {n_states})")
        return v.clone()


@dataclass(frozen=True)
class InputOrder(OrderSchedule):
    """``α_k = start + gain · u_k[channel]``: an order driven by a known input (e.g. temperature)."""

    start: float
    gain: float
    channel: int = 0

    def values(self, n_steps, h, n_states, inputs=None):
        if inputs is None:
            raise ValueError("InputOrder needs inputs")
        v = self.start + self.gain * inputs[..., self.channel].to(torch.float64)
        return v.unsqueeze(-1).expand(v.shape + (n_states,)).clone()


def parse_order_spec(spec: str | float) -> OrderSchedule:
    """Parse the command-line order SPEC (or a study table's ``order``, where TOML makes ``0.35`` a number).

    ``"0.35"`` or ``0.35`` → constant; ``"linear:A0,SLOPE"`` → ``α_k = A0 + SLOPE·k·h``;
    ``"parabolic:A0,C"`` → ``α_k = A0 + C·(k·h)²``.
    """
    if isinstance(spec, (int, float)) and not isinstance(spec, bool):
        spec = repr(float(spec))
    if not isinstance(spec, str):
        raise ValueError(f"bad order SPEC {spec!r}: expected a number, 'linear:A0,SLOPE' or 'parabolic:A0,C'")
    text = spec.strip()
    kind, _, rest = text.partition(":")
    try:
        if not rest:
            value = float(text)
            if not math.isfinite(value):
                raise ValueError
            return ConstantOrder(value)
        numbers = [float(v) for v in rest.split(",")]
        if len(numbers) != 2 or not all(math.isfinite(v) for v in numbers):
            raise ValueError
    except ValueError:
        raise ValueError(
            f"bad order SPEC {spec!r}: expected a number, 'linear:A0,SLOPE' or 'parabolic:A0,C'"
        ) from None
    if kind == "linear":
        return LinearOrder(*numbers)
    if kind == "parabolic":
        return ParabolicOrder(*numbers)
    raise ValueError(f"bad order SPEC {spec!r}: unknown kind {kind!r} (use linear or parabolic)")

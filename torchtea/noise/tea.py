r"""The TEA's view of a :class:`~torchtea.noise.model.NoiseModel`: its :class:`~torchtea.engines.structure.Structure`
and :class:`~torchtea.engines.settings.TEAConfig` at one parameter set — the model is described once, here it is
only read.

The TEA (:mod:`torchtea.engines.tea`) runs an A-type model (paper (9)–(10)): every state follows
:math:`x_{k+1} = h^{\alpha}(A x_k + \omega_k) - \sum_j c_j(\alpha) x_{k+1-j}` and ``y_k = C x_k + ν_k``. Each
component says what it is there (:meth:`~torchtea.noise.components.Component.tea_part`):

* a ``fractional`` component is a state whose order KFo estimates and whose pole KFw estimates (both starting at
  the values given), with KFx's drive ``Q0 = q`` — the TEA's ``noise_scaling = "scaled"`` adds
  :math:`h^\alpha Q_0 h^\alpha`, the same :math:`G = h^\alpha\sqrt q` as :meth:`NoiseModel.state_space`;
* any other state (random walk, Gauss–Markov bias, vibration band …) is a block of order 1, exactly its
  transition and drive, ``A = (F − I)/h``, ``Q0 = G Gᵀ/h²``;
* the measurement noises (white, quantisation) are KFx's R (and KFo's and KFw's);
* the mean components (offset, ramp, sinusoid, temperature terms, steps, spikes …) are removed from the series at
  their values (:meth:`TEAView.residual`);
* a ``temperature-order`` modifier is not used: KFo estimates the order's variation itself;
* a sensor filter (low-pass, digital filter) is refused, saying why.

A model of one fractional state and measurement noise gives the paper's scalar structure and the settings the
TEA ran with before this view existed, number for number (tests/test_tea_view.py).
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import torch
from torch import Tensor

from ..engines.presets import get_preset
from ..engines.settings import TEAConfig
from ..engines.structure import ParametricMatrix, Structure
from .components import TEAPart
from .model import NoiseModel, parse_model

__all__ = ["TEAView", "tea_view", "same_structure"]


@dataclass(frozen=True)
class TEAView:
    """What the TEA runs for one model and parameter set.

    ``states``: each KFx state's component label (a component of several states is named once per state);
    ``orders``: the labels whose order KFo estimates, in KFo's order; ``params``: the parameter names KFw
    estimates (``fractional.pole`` …), in KFw's order; ``notes``: component label → what the TEA does with it."""

    model: NoiseModel
    values: dict
    structure: Structure
    config: TEAConfig
    states: tuple
    orders: tuple
    params: tuple
    notes: dict

    def residual(self, y, t, inputs: dict | None = None) -> Tensor:
        """``y − μ(t)``: the series without the model's mean at its values (``y`` ``(N,)``, NaN kept; ``t`` the
        times in s from the first sample). A model without a level (no ``offset``) also loses the series' own mean,
        as the TEA's plain run always did."""
        y = torch.as_tensor(y, dtype=torch.float64)
        inp = None if inputs is None else {k: torch.as_tensor(v, dtype=torch.float64) for k, v in inputs.items()}
        r = y - self.model.mean(self.values, torch.as_tensor(t, dtype=torch.float64), inp)[0]
        if not self.model.has_level:
            r = r - torch.nanmean(r)
        return r


def _block_diag(blocks: list[Tensor]) -> Tensor:
    return torch.block_diag(*blocks) if blocks else torch.zeros(0, 0, dtype=torch.float64)


def tea_view(model, values, h: float, base: TEAConfig | None = None) -> TEAView:
    """The TEA's structure and settings for ``model`` at one parameter set ``values`` (a dict of numbers or
    ``(1,)`` tensors, as in ``Fit.values``), on top of ``base`` (default: the paper's MEMS x-axis preset): KFx's
    ``Q0`` and ``R`` from the model, KFo and KFw starting at its orders and poles (their ``R`` the model's
    measurement variance too, unless ``base`` sets it to ``"innovation"``), ``noise_scaling = "scaled"``. Raises
    ``ValueError`` naming the component the TEA cannot run, or a model without a fractional state or without
    measurement noise."""
    model = parse_model(model)
    v = model.as_dict(values)
    if next(iter(v.values())).shape[0] != 1:
        raise ValueError("tea_view takes one parameter set; call it once per set")
    byc = model._by_component(v)
    parts: list[tuple[str, TEAPart]] = []
    notes = {}
    for label, comp in model.components:
        part = comp.tea_part(label, byc[label], h)
        notes[label] = comp.tea_note
        if part is not None:
            parts.append((label, part))
    fractional = sum(p.estimated for _, p in parts)
    if not fractional:
        raise ValueError(f"model {model.spec!r} has no fractional state: the TEA estimates a fractional order")
    if fractional > 1:
        raise ValueError(f"model {model.spec!r} has {fractional} fractional states: the TEA's view runs one (its "
                         "summaries and studies read one order and one pole)")
    r = float(model.measurement_variance(v)[0])
    if not r > 0:
        raise ValueError(f"model {model.spec!r} has no measurement noise (white or quantisation): the TEA's "
                         "filters need R > 0")
    n = sum(p.n for _, p in parts)
    A0 = _block_diag([p.A.to(torch.float64) for _, p in parts])
    Q0 = _block_diag([p.Q0.to(torch.float64) for _, p in parts])
    C = torch.zeros(1, n, dtype=torch.float64)
    Bm = torch.zeros(n, 1, dtype=torch.float64)
    states, estimated, fixed, orders, poles, params, starts = [], [], [], [], [], [], []
    basis = []
    i = 0
    for label, p in parts:
        C[0, i] = 1.0  # a block's output is its state 0
        if p.estimated:
            Bm[i, 0] = 1.0  # a known input drives the fractional state (the paper's B), no other
        if p.pole is not None:
            b = torch.zeros(n, n, dtype=torch.float64)
            b[i, i] = 1.0
            basis.append(b)
            poles.append(p.pole)
            params.append(f"{label}.pole")
        for _ in range(p.n):
            states.append(label)
            estimated.append(p.estimated)
            fixed.append(1.0 if p.estimated else p.order)
        if p.estimated:
            orders.append(label)
            starts.append(p.order)
        i += p.n
    base = base or get_preset("paper-mems-x")
    if n == 1:  # the paper's scalar model: its default structure and scalar settings (the compiled engine takes it)
        structure = Structure()
        kfx = replace(base.kfx, R=r, Q0=float(Q0[0, 0]))
    else:
        A = ParametricMatrix(A0, torch.stack(basis) if basis else torch.zeros(0, n, n, dtype=torch.float64))
        structure = Structure(A=A, B=Bm, C=C, estimated=tuple(estimated), fixed_orders=torch.tensor(fixed))
        # the prior: the paper's for the fractional state, the model's own start (z_0 = 0, no variance) for the others
        p0 = torch.as_tensor(base.kfx.P0, dtype=torch.float64)
        if p0.ndim > 0:
            raise ValueError("the TEA's view of a model of several states takes a scalar kfx.P0 (the fractional "
                             f"state's prior variance), got {base.kfx.P0!r}")
        P0 = torch.diag(torch.tensor([float(p0) if e else 0.0 for e in estimated], dtype=torch.float64))
        kfx = replace(base.kfx, R=r, Q0=Q0.tolist(), x0=[0.0] * n, P0=P0.tolist())
    one = lambda xs: xs[0] if len(xs) == 1 else list(xs)  # noqa: E731
    own_r = lambda f: f.R if f.uses_innovation else r  # noqa: E731 — "innovation" stays: it is KFx's S, not a number
    config = replace(base, noise_scaling="scaled", kfx=kfx,
                     kfo=replace(base.kfo, R=own_r(base.kfo), x0=one(starts)),
                     kfw=replace(base.kfw, R=own_r(base.kfw), x0=one(poles)))
    return TEAView(model, {k: t.clone() for k, t in v.items()}, structure, config, tuple(states), tuple(orders),
                   tuple(params), notes)


def same_structure(a: Structure, b: Structure) -> bool:
    """Whether two structures are the same model (one TEA batch can run both)."""
    eq = lambda x, y: x.shape == y.shape and bool(torch.equal(x, y))  # noqa: E731
    return (eq(a.A.base, b.A.base) and eq(a.A.basis, b.A.basis) and eq(a.B, b.B) and eq(a.C, b.C)
            and a.estimated == b.estimated and eq(a.fixed_orders, b.fixed_orders))

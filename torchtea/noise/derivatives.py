"""The model's derivatives with respect to its unconstrained coordinates, assembled from each component's own: the
spectrum's (:func:`spectrum_jacobian`, what the Whittle fits' scoring reads) and the state space's
(:func:`state_space_derivatives`, what the exact likelihood's sensitivity filter reads). A component gives its
derivatives in closed form (:meth:`~torchtea.noise.components.Component.spectrum_derivatives`,
:meth:`~torchtea.noise.components.Component.block_derivatives`, …) or, a user's effect that gives none, by
forward-mode automatic differentiation of its own method; the chain rule through the transforms (a pole's fraction
moves with its order) and through the sum, the sensor filter and the stacking is here, once. Both are tested against
automatic differentiation of the whole assembly (``tests/test_derivatives.py``)."""
from __future__ import annotations

import torch
from torch import Tensor

from ..core.memory import MemoryConfig
from .components import Component
from .components.base import forward_derivatives
from .model import NoiseModel, state_memory

__all__ = ["spectrum_jacobian", "state_space_derivatives"]


def spectrum_jacobian(model: NoiseModel, u: Tensor, omega: Tensor, h: float, columns=None) -> tuple[Tensor, Tensor]:
    """The spectrum of the stochastic part ``(B, W)`` at unconstrained points ``u`` ``(B, P)`` and its derivatives
    with respect to the coordinates ``columns`` (indices into ``model.names``; default all) ``(B, len(columns), W)``,
    from each component's own derivatives (:meth:`~torchtea.noise.components.Component.spectrum_derivatives`, a
    filter's ``gain_derivatives``) by the chain rule through the transforms (a pole's fraction moves with its
    order): the scoring of the Whittle fits reads it, with no automatic differentiation of the sum. The same
    sum as :meth:`~torchtea.noise.model.NoiseModel.spectrum`, in the same order."""
    u = torch.as_tensor(u, dtype=torch.float64).reshape(-1, len(model.names))
    v = model.from_unconstrained(u, h)
    cols = list(range(len(model.names))) if columns is None else [int(c) for c in columns]
    where = {model.names[c]: k for k, c in enumerate(cols)}
    B = u.shape[0]
    byc = model._by_component(v)
    total, dtotal = None, None
    for label, comp in model.components:
        if comp.kind not in ("filter", "state", "measurement") or (comp.kind == "filter" and total is None):
            continue
        if comp.kind == "filter":
            G, dG = _own(comp, "gain", "gain_derivatives", byc[label], omega, h)
            dtotal = dtotal * G.unsqueeze(1)
            before, total = total, total * G
            dtotal = _chain(model, label, comp, dG * before.unsqueeze(1), u, v, h, where, dtotal)
            continue
        S, dS = _own(comp, "spectrum", "spectrum_derivatives", byc[label], omega, h)
        S = S.expand(B, -1) if S.shape[0] != B else S
        if total is None:
            total = S
            dtotal = S.new_zeros(B, len(cols), S.shape[-1])
        else:
            total = total + S
        dtotal = _chain(model, label, comp, dS, u, v, h, where, dtotal)
    if total is None:
        raise ValueError(f"model {model.spec!r} has no stochastic component")
    return total, dtotal


def state_space_derivatives(model: NoiseModel, u: Tensor, h: float, n_steps: int, memory="soe", columns=None):
    """The state space at unconstrained points ``u`` ``(B, P)`` (the same numbers as
    :meth:`~torchtea.noise.model.NoiseModel.state_space`) and its derivatives with respect to the coordinates
    ``columns`` (indices into ``model.names``; default all), from each component's own
    (:meth:`~torchtea.noise.components.Component.block_derivatives`, a measurement's ``variance_derivatives``, a
    filter's ``filter_block`` differentiated forward) by the chain rule through the transforms and the assembly —
    what the sensitivity filter reads, without differentiating the assembly. Returns ``(ss, dF (B, C, n, n),
    dG (B, C, n, m), dR (B, C), dg0 (B, C, n))``. Not for a time-varying order (its transition varies: the exact
    gradient is taken by differences there)."""
    u = torch.as_tensor(u, dtype=torch.float64).reshape(-1, len(model.names))
    v = model.from_unconstrained(u, h)
    byc = model._by_component(v)
    B = u.shape[0]
    mem = state_memory(memory, n_steps) if isinstance(memory, (str, dict, MemoryConfig)) else memory
    ss = model.state_space(v, h, n_steps, mem)
    if ss.varying is not None:
        raise ValueError(f"model {model.spec!r}: a time-varying order has no constant transition to differentiate")
    cols = list(range(len(model.names))) if columns is None else [int(c) for c in columns]
    where = {model.names[c]: k for k, c in enumerate(cols)}
    C = len(cols)
    blocks, lowpass, dr_before, dr_after = [], None, u.new_zeros(B, C), u.new_zeros(B, C)
    for label, comp in model.components:
        if comp.kind == "filter":
            lowpass = label
        elif comp.kind == "measurement":
            _, dvar = _own(comp, "measurement_variance", "variance_derivatives", byc[label])
            d = dr_before if lowpass is None else dr_after
            _chain(model, label, comp, dvar, u, v, h, where, d)
        elif comp.kind == "state":
            _, _, dF, dG = _own(comp, "block", "block_derivatives", byc[label], h, mem)
            blocks.append((label, _chain(model, label, comp, dF, u, v, h, where, dF.new_zeros(B, C, *dF.shape[2:])),
                           _chain(model, label, comp, dG, u, v, h, where, dG.new_zeros(B, C, *dG.shape[2:]))))
    n0 = sum(dF.shape[-1] for _, dF, _ in blocks)
    m0 = sum(dG.shape[-1] for _, _, dG in blocks)
    dF0, dG0 = u.new_zeros(B, C, n0, n0), u.new_zeros(B, C, n0, m0)
    start = col = 0
    for _, dF, dG in blocks:
        n_c, m_c = dF.shape[-1], dG.shape[-1]
        dF0[:, :, start:start + n_c, start:start + n_c] = dF
        dG0[:, :, start:start + n_c, col:col + m_c] = dG
        start, col = start + n_c, col + m_c
    n, m = ss.F.shape[-1], ss.G.shape[-1]
    if lowpass is None:
        return ss, dF0, dG0, dr_before + dr_after, u.new_zeros(B, C, n)
    # the filter's states after the others (NoiseModel._with_filter): F = [T F₀, 0; 0, A] with T = [I; b sᵀ],
    # G = [T G₀, ν], ν = b √r the white noise it filters, g0 = ν
    comp = dict(model.components)[lowpass]
    (A, b), (dA, db) = forward_derivatives(lambda values: comp.filter_block(values, h), comp.params, byc[lowpass])
    dA = _chain(model, lowpass, comp, dA, u, v, h, where, dA.new_zeros(B, C, *A.shape[1:]))
    db = _chain(model, lowpass, comp, db, u, v, h, where, db.new_zeros(B, C, b.shape[-1]))
    s = torch.zeros(B, n0, dtype=torch.float64)
    for label, sl in ss.blocks.items():
        if label != lowpass and _filtered(model, label, lowpass):
            s[:, sl.start] = 1.0
    F0 = ss.F[:, :n0, :n0]
    G0 = ss.G[:, :n0, :m0]
    T = torch.cat([torch.eye(n0, dtype=torch.float64).expand(B, n0, n0), b.unsqueeze(-1) * s.unsqueeze(1)], dim=1)
    dT = torch.cat([u.new_zeros(B, C, n0, n0), db.unsqueeze(-1) * s[:, None, None, :]], dim=2)
    dF = u.new_zeros(B, C, n, n)
    dF[:, :, :, :n0] = dT @ F0.unsqueeze(1) + T.unsqueeze(1) @ dF0
    dF[:, :, n0:, n0:] = dA
    dG = u.new_zeros(B, C, n, m)
    dG[:, :, :, :m0] = dT @ G0.unsqueeze(1) + T.unsqueeze(1) @ dG0
    dg0 = u.new_zeros(B, C, n)
    if m > m0:  # white noise before the filter: ν = b √r_before, also the filter's first state
        r = _white_before(model, byc, lowpass)
        root = torch.sqrt(r)
        dnu = db * root[:, None, None] + b.unsqueeze(1) * (dr_before / (2.0 * root.unsqueeze(-1))).unsqueeze(-1)
        dG[:, :, n0:, m - 1] = dnu
        dg0[:, :, n0:] = dnu
    return ss, dF, dG, dr_after, dg0


def _filtered(model: NoiseModel, label: str, lowpass: str) -> bool:
    """Whether the state component ``label`` comes before the filter ``lowpass`` (the filter filters it)."""
    order = [lb for lb, _ in model.components]
    return order.index(label) < order.index(lowpass)


def _white_before(model: NoiseModel, byc: dict, lowpass: str) -> Tensor:
    """The white measurement variance the filter ``lowpass`` filters ``(B,)`` (the components before it)."""
    r = None
    for label, comp in model.components:
        if label == lowpass:
            break
        if comp.kind == "measurement":
            x = comp.measurement_variance(byc[label])
            r = x if r is None else r + x
    return r


def _own(comp: Component, value: str, derivative: str, v: dict, *args):
    """A component's ``value`` method's result and its derivatives, by its own ``derivative`` method where the class
    that defines it also defines ``value`` or derives from the class that does (a user's effect that overrides the
    block of a built-in one but not its derivatives gets them automatically), else by forward-mode automatic
    differentiation of ``value``: ``derivative``'s own return."""
    mro = type(comp).__mro__
    owner = next((c for c in mro if value in vars(c)), None)
    deriver = next((c for c in mro if derivative in vars(c)), None)
    if deriver is not None and owner is not None and issubclass(deriver, owner) and deriver is not Component:
        return getattr(comp, derivative)(v, *args)
    out = forward_derivatives(lambda values: getattr(comp, value)(values, *args), comp.params, v)
    if isinstance(out[0], tuple):  # (values, derivatives) of a tuple → the derivative method's flat form
        return (*out[0], *out[1])
    return out


def _chain(model: NoiseModel, label: str, comp: Component, d: Tensor, u: Tensor, v: dict, h: float, where: dict,
           out: Tensor) -> Tensor:
    """``out`` ``(B, C, …)`` plus the component's derivatives ``d`` ``(B, p, …)`` (natural parameters) carried to the
    unconstrained coordinates ``where`` (name → column): times each parameter's ``∂value/∂u``, and a pole's fraction's
    share through its order (:meth:`~torchtea.noise.components.ParamSpec.order_derivative`)."""
    d = d.expand(out.shape[0], *d.shape[1:]) if d.shape[0] != out.shape[0] else d
    tail = (1,) * (d.dim() - 2)
    for k, name, i, spec, order in _parameters(model, label):
        if name in where:
            out[:, where[name]] += d[:, k] * spec.derivative(u[:, i], v[name], h).reshape(-1, *tail)
        if order is not None and order[0] in where:
            name_o, j, spec_o = order
            dorder = spec_o.derivative(u[:, j], v[name_o], h)
            out[:, where[name_o]] += d[:, k] * (spec.order_derivative(v[name], h) * dorder).reshape(-1, *tail)
    return out


def _parameters(model: NoiseModel, label: str) -> list:
    """The component ``label``'s parameters as :func:`_chain` reads them: ``(k, name, index, spec, order)`` with
    ``order`` the ``(name, index, spec)`` of the order a pole's fraction moves with, else None (remembered per model
    and label)."""
    comp = dict(model.components)[label]
    key = (tuple(model.names), label, type(comp), comp.params)
    if key not in _PARAMETERS:
        names = model.names
        out = []
        for k, p in enumerate(comp.params):
            name = f"{label}.{p.name}"
            o = model._order_of.get(name)
            out.append((k, name, names.index(name), model.param_spec(name),
                        None if o is None else (o, names.index(o), model.param_spec(o))))
        _PARAMETERS[key] = out
    return _PARAMETERS[key]


#: :func:`_parameters`' memory (a model's parameter names and a component's class and parameters fix them).
_PARAMETERS: dict = {}

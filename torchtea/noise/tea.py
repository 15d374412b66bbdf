r"""The TEA's view of a :class:`~torchtea.noise.model.NoiseModel`: its :class:`~torchtea.engines.structure.Structure`
and :class:`~torchtea.engines.settings.TEAConfig` at one parameter set — the model is described once, here it is
only read.

The TEA (:mod:`torchtea.engines.tea`) runs an A-type model (paper (9)–(10)): every state follows
:math:`x_{k+1} = h^{\alpha}(A x_k + \omega_k) - \sum_j c_j(\alpha) x_{k+1-j}` and ``y_k = C x_k + ν_k``. Each
component's place there is :func:`tea_part`'s, by its kind, or registered for its class (:func:`register_tea_role`):

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

from collections.abc import Callable
from dataclasses import dataclass, replace

import torch
from torch import Tensor

from ..core.registry import Registry
from ..engines.presets import get_preset
from ..engines.settings import TEAConfig
from ..engines.structure import ParametricMatrix, Structure
from .components import Fractional, LowPass, TemperatureOrder
from .model import NoiseModel, parse_model

__all__ = ["TEAView", "tea_view", "same_structure", "TEAPart", "TEAUnsupported", "TEARole", "TEA_ROLES",
           "register_tea_role", "unregister_tea_role", "tea_part", "tea_note"]


@dataclass(frozen=True)
class TEAPart:
    r"""A state component's place in the TEA's A-type model (paper (9)–(10)): its ``n`` states follow
    :math:`x_{k+1} = h^{\alpha}(A x_k + \omega_k) - \sum_{j\ge1} c_j(\alpha) x_{k+1-j}` with
    :math:`\omega_k \sim N(0, Q_0)` — KFx's ``Q0`` in the TEA's ``"scaled"`` convention, where the drive enters
    as :math:`h^\alpha Q_0 h^\alpha` — and its output is its state 0.

    ``order``: the states' order (a number; every state of the part has it). ``estimated``: KFo estimates it (from
    ``order``). ``pole``: the value KFw estimates as ``A[0, 0]``'s parameter (``A`` then holds 0 there), or None.
    An integer-order part (``order`` 1) is exact whatever the memory: ``c_1(1) = −1`` and ``c_j(1) = 0`` for j ≥ 2."""

    A: Tensor  # (n, n)
    Q0: Tensor  # (n, n)
    order: float = 1.0
    estimated: bool = False
    pole: float | None = None

    @property
    def n(self) -> int:
        return self.A.shape[0]


class TEAUnsupported(ValueError):
    """Raised by :func:`tea_part` when the TEA's A-type model has no place for the component."""


@dataclass(frozen=True)
class TEARole:
    """A component's place in the TEA where its kind's default is not it. ``part(comp, label, v, h)`` → its
    :class:`TEAPart` for one parameter set ``v`` (each ``(1,)``), None where it is not a state (None here: the
    kind's default); ``note``: what the TEA does with it, in the identification's report (None: the kind's);
    ``refusal``: why the TEA has no place for it (a filter's or a modifier's default refusal says this)."""

    part: Callable | None = None
    note: str | None = None
    refusal: str | None = None


#: The components' places in the TEA by class, where the kind's default is not it (a subclass has its parent's).
TEA_ROLES = Registry("TEA role", by_class=True)
_DEFAULT = TEARole()
#: What the TEA does with a component of each kind by default, in the identification's report.
KIND_NOTES = {"measurement": "in KFx's R (and KFo's, KFw's)", "mean": "removed from the series at its fitted values",
              "state": "a KFx state of order 1 (its transition and drive as the exact filter has them)"}


def register_tea_role(effect, part: Callable | None = None, note: str | None = None, refusal: str | None = None,
                      *, replace: bool = False) -> None:
    """The effect class ``effect`` (or an instance's class) has the place in the TEA that :class:`TEARole` says."""
    TEA_ROLES.add(effect, TEARole(part, note, refusal), replace=replace)


def unregister_tea_role(effect) -> None:
    """Remove what a user registered for the effect class ``effect`` (a built-in entry it replaced is back)."""
    TEA_ROLES.remove(effect)


def tea_part(comp, label: str, v: dict, h: float) -> TEAPart | None:
    """``comp``'s place in the TEA's model for one parameter set ``v`` (each ``(1,)``): its registered part, else by
    its kind. A state of integer order: its block ``z_{k+1} = F z_k + G ξ_k`` is the A-type model's order-1 form
    ``x_{k+1} = h(A x_k + ω_k) + x_k`` with ``A = (F − I)/h`` and ``Q0 = G Gᵀ/h²`` — exactly (the same transition and
    drive). A measurement noise is KFx's R, a mean is taken from the series before the TEA runs (None for both). A
    filter or a modifier has no general place: :class:`TEAUnsupported`, saying why."""
    role = TEA_ROLES.find(comp, _DEFAULT)
    if role.part is not None:
        return role.part(comp, label, v, h)
    if comp.kind in ("measurement", "mean"):
        return None
    if comp.kind == "state":
        F, G = comp.block(v, h, None)
        F, G = F[0], G[0]
        eye = torch.eye(F.shape[-1], dtype=F.dtype)
        return TEAPart((F - eye) / h, G @ G.mT / h ** 2)
    raise TEAUnsupported(f"{comp.name} ({comp.kind}) has no place in the TEA's A-type model "
                         f"x_(k+1) = h^a (A x_k + w_k) - sum c_j x_(k+1-j): "
                         f"{role.refusal or 'no state-space form of this kind'}")


def tea_note(comp) -> str:
    """What the TEA does with ``comp``, in the identification's report."""
    role = TEA_ROLES.find(comp, _DEFAULT)
    return role.note if role.note is not None else KIND_NOTES.get(comp.kind, "")


def _fractional_part(comp, label, v, h):
    """The paper's (43)–(45) itself: order and pole estimated (KFo, KFw, starting at the fitted values), its drive
    ``Q0 = q``."""
    return TEAPart(torch.zeros(1, 1, dtype=torch.float64), v["q"].reshape(1, 1).to(torch.float64),
                   order=float(v["order"][0]), estimated=True, pole=float(v["pole"][0]))


register_tea_role(Fractional, _fractional_part,
                  note="KFx's fractional state: KFo estimates its order, KFw its pole, from the fitted values")
register_tea_role(TemperatureOrder, lambda comp, label, v, h: None,
                  note="not a state: KFo estimates the order's variation in time itself (its estimate can be read "
                       "against the temperature); the fitted slope per °C is not used")
register_tea_role(LowPass, refusal="its state is driven by the next value of the states before it, whose row "
                                   "depends on the estimated order: no fixed A holds it")
TEA_ROLES.seal()


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
        part = tea_part(comp, label, byc[label], h)
        notes[label] = tea_note(comp)
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

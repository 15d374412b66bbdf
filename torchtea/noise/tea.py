r"""The TEA's settings read from a :class:`~torchtea.noise.model.NoiseModel` and its parameter values.

The TEA (:mod:`torchtea.engines.tea`) runs the paper's scalar model, which in noise-model terms is
``fractional`` (+ measurement noise): KFx's state is the fractional component's state with
:math:`x_{k+1} = h^{\alpha}(f x_k + \omega_k) - \sum c_j x_{k+1-j}`, ω ~ N(0, q) — the TEA's
``noise_scaling = "scaled"`` adds :math:`h^\alpha Q_0 h^\alpha`, the same :math:`G = h^\alpha\sqrt q` as
:meth:`NoiseModel.state_space` — and its R is the model's total white measurement variance (``white.r``
plus ``quantisation`` Δ²/12). KFo starts at the model's order, KFw at its pole.

Mean components (offset, ramp, sinusoid, temperature-bias) are not states of the TEA: remove them from the
series first (:func:`torchtea.fitting.mle.regress_mean`). Models with other state components (random walk,
low-pass, a second fractional part) or a temperature-driven order (the TEA estimates a time-varying order
itself) have no TEA counterpart here and are refused by name.
"""
from __future__ import annotations

from dataclasses import replace

from ..engines.presets import get_preset
from ..engines.settings import TEAConfig
from .model import NoiseModel, parse_model

__all__ = ["tea_config"]


def tea_config(model, values, base: TEAConfig | None = None) -> TEAConfig:
    """KFx's ``Q0`` = q and ``R`` = the measurement variance, KFo's ``x0`` = order and KFw's ``x0`` = pole
    (KFo's and KFw's ``R`` too) on top of ``base`` (default: the paper's MEMS x-axis preset). ``values``
    holds one parameter set (a dict of numbers, as in ``Fit.values``)."""
    model: NoiseModel = parse_model(model)
    frac = [label for label, c in model.components if c.name == "fractional"]
    other = [label for label, c in model.components
             if c.kind in ("state", "filter", "modifier") and c.name != "fractional"]
    if len(frac) != 1 or other:
        raise ValueError(f"the TEA runs one fractional state plus measurement noise; model {model.spec!r} has "
                         f"{len(frac)} fractional component(s)" + (f" and {other}" if other else ""))
    v = model.as_dict(values)
    if v[model.names[0]].shape[0] != 1:
        raise ValueError("tea_config takes one parameter set; call it once per set")
    label = frac[0]
    r = float(model.measurement_variance(v)[0])
    if not r > 0:
        raise ValueError(f"model {model.spec!r} has no measurement noise (white or quantisation): the TEA's "
                         "filters need R > 0")
    order, pole, q = (float(v[f"{label}.{p}"][0]) for p in ("order", "pole", "q"))
    base = base or get_preset("paper-mems-x")
    return replace(base, noise_scaling="scaled",
                   kfx=replace(base.kfx, R=r, Q0=q),
                   kfo=replace(base.kfo, R=r, x0=order),
                   kfw=replace(base.kfw, R=r, x0=pole))

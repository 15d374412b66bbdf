"""The starts' registry and the default start of every effect (:class:`Starts`)."""
from __future__ import annotations

import math
from typing import NamedTuple

import torch
from torch import Tensor

from ...core.registry import Registry
from ...noise.grammar import token
from ...noise.model import NoiseModel

__all__ = ["Starts", "StartData", "REGISTRY", "register_start", "unregister_start", "starts_of", "initial_values"]


class StartData(NamedTuple):
    """What :meth:`Starts.start` may use: the series ``y`` (tensor), its variance, half the variance of its first
    differences (the white level), the number of state components, the sample time and the fractional order to start
    from."""

    y: Tensor
    var: float
    white: float
    n_state: int
    h: float
    order: float


class Starts:
    """How the fits start an effect ``comp`` (every method's first argument) and hold its located parameters: the
    defaults, which an effect's own starts override (subclass, override what you know better, and register the
    subclass for the effect's class with :func:`register_start`). Values are keyed ``label.parameter``."""

    def start(self, comp, param: str, data: StartData) -> float:
        """A rough data-based value of ``param`` to start a fit from (not an estimate). Default: 0 for a free
        parameter, 1 for a positive one, the middle of a bounded one's range, a pole at half its stability limit at
        the order started from (``−½·2^α/h^α``, α ``data.order``), a quarter of the sampling rate for a frequency
        below Nyquist."""
        spec = next(p for p in comp.params if p.name == param)
        if spec.kind == "positive":
            return 1.0
        if spec.kind == "fraction":  # (the value is the pole: its fraction of the limit is what the fits move)
            return -0.5 * 2.0 ** data.order / data.h ** data.order
        if spec.kind == "nyquist":
            return 0.25 / data.h
        if spec.kind == "bounded":
            lo, hi = spec.bounds
            return 0.5 * (lo + hi) if math.isfinite(lo) and math.isfinite(hi) else 0.0
        return 0.0

    def grid_start(self, comp, label: str, v: dict, white: float, order, fraction, h: float) -> None:
        """Set the effect's values (in place) in one start of the Whittle fit's grid: ``white`` the periodogram's
        level at high frequencies (variance), ``order``/``fraction`` the grid's fractional order and pole fraction
        (None without a fractional part). Default: its :meth:`start` values stand."""

    def scale_drive(self, comp, label: str, v: dict, s: float, fixed) -> None:
        """Scale the effect's drive (in place) when a grid start's spectrum is scaled by ``s`` to meet the
        periodogram on the lower half of the band (names in ``fixed`` are kept). Default: unscaled."""

    def strengths(self, comp, label: str, model, values: dict, h: float, n: int) -> list[dict]:
        """The effect's parameters at a few strengths, to start the Whittle fit of ``model`` extended by it from the
        fit ``values`` of ``model`` (``n`` samples); default none (the grid's starts only)."""
        return []

    def vanishing(self, comp, label: str, model, values: dict, h: float, n: int) -> dict:
        """The effect's parameters where it (all but) vanishes, so that ``model`` extended by it at these values is
        ``model`` at ``values``: the start from which an extended model's likelihood is at least the model's (the
        models are nested). Default: empty (not known)."""
        return {}

    def regressors(self, comp, label: str, t, inputs: dict | None, ok) -> tuple[dict, list]:
        """The mean's linear part for the least-squares start (:func:`~torchtea.fitting.mle.regress_mean`):
        ``(values fixed by the data, [(parameter name, regressor column (N,)), …])``; default none."""
        return {}, []

    def fit_residual(self, comp, label: str, resid, t, ok, h: float, start: dict, inputs: dict | None) -> dict:
        """Values estimated from the residual after the linear regression (a line's frequency, amplitude and
        phase); removes what it explains from ``resid`` in place. ``start``: the model's start values
        (:func:`initial_values`). Default: nothing for an effect that is not a mean, carries the level or whose mean
        the regression took (:meth:`regressors`); a mean that the regression did not take (a user's effect) by
        nonlinear least squares over its parameters from ``start`` (:func:`scipy.optimize.least_squares`), each on its
        kind's unconstrained scale (:meth:`~torchtea.noise.components.ParamSpec.to_unconstrained`, as every fit)."""
        if comp.kind != "mean" or comp.level or self.regressors(comp, label, t, inputs, ok)[1]:
            return {}
        from scipy.optimize import least_squares

        names = [p.name for p in comp.params]
        tt = torch.as_tensor(t, dtype=torch.float64)
        inp = None if inputs is None else {k: torch.as_tensor(x, dtype=torch.float64) for k, x in inputs.items()}

        alone = NoiseModel([(label, comp)], token(comp))  # (its parameters' transforms, as a model has them)

        def natural(u):
            v = alone.from_unconstrained(torch.as_tensor(u, dtype=torch.float64), h)
            return {p.name: float(v[f"{label}.{p.name}"][0]) for p in comp.params}

        def residual(u):
            v = {n: torch.tensor([x], dtype=torch.float64) for n, x in natural(u).items()}
            m = comp.mean(v, tt, inp)[0].numpy()
            r = resid - m
            return (r - r[ok].mean())[ok]

        u0 = alone.to_unconstrained({n: start[n] for n in alone.names}, h)[0].tolist()
        sol = least_squares(residual, u0, method="lm")
        best = natural(sol.x)
        v = {n: torch.tensor([best[n]], dtype=torch.float64) for n in names}
        resid[ok] -= comp.mean(v, tt, inp)[0].numpy()[ok]
        return {f"{label}.{n}": float(best[n]) for n in names}

    def located_intervals(self, comp, label: str, model, values: dict, y, h: float, inputs: dict | None,
                          innovations=None) -> dict:
        """95 % intervals of the effect's :attr:`~torchtea.noise.components.Component.located` parameters at the fit
        ``values`` of ``model`` to ``y``: name → ``((lo, hi), words)``; default none (they are reported without).
        ``innovations(values)``: the model's :class:`~torchtea.fitting.innovations.Innovations` on ``y`` at other
        values."""
        return {}


#: The starts by the effect's class (a subclass inherits its parent's unless it registers its own; the rule of
#: :class:`~torchtea.core.registry.Registry` for registering again and unregistering).
REGISTRY = Registry("starts", by_class=True)
#: The defaults, for an effect without starts of its own.
DEFAULT = Starts()


def register_start(effect, *, replace: bool = False):
    """Class decorator: the :class:`Starts` subclass becomes the starts of the effect class ``effect`` (or of an
    effect instance's class). Register it in the module that defines the effect, so that whatever loads the effect
    loads its starts too. A class that has starts already (a built-in effect's) keeps them unless ``replace``."""
    cls = REGISTRY.key(effect)

    def attach(starts: type) -> type:
        if not (isinstance(starts, type) and issubclass(starts, Starts)):
            raise TypeError(f"register_start({cls.__name__}) takes a Starts subclass, got {starts!r}")
        REGISTRY.add(cls, starts(), replace=replace)
        return starts
    return attach


def unregister_start(effect) -> None:
    """Remove the starts a user registered for the effect class ``effect`` (or an instance's class): a built-in
    effect's own starts are back where a user replaced them, the defaults elsewhere; a built-in effect's own starts
    are not removed (``ValueError``)."""
    REGISTRY.remove(effect)


def starts_of(comp) -> Starts:
    """The starts registered for ``comp``'s class or its nearest parent; the defaults (:class:`Starts`) otherwise."""
    return REGISTRY.find(comp, DEFAULT)


def initial_values(model, y: Tensor, h: float, order: float = 0.3) -> dict:
    """Rough data-based starting values of every parameter of ``model`` for one series ``y`` (a fit's start, not an
    estimate): each effect's :meth:`Starts.start`."""
    y = torch.as_tensor(y, dtype=torch.float64)
    var = float(y.var()) if y.numel() > 1 else 1.0
    var = var if var > 0 else 1.0
    d = torch.diff(y)
    white = max(float(d.var()) / 2.0, 1e-6 * var) if d.numel() > 1 else var / 2
    data = StartData(y, var, white, len(model.labels("state")), h, order)
    return {f"{label}.{p.name}": starts_of(comp).start(comp, p.name, data)
            for label, comp in model.components for p in comp.params}

"""The screens' registry and what every screen shares: how a screen is attached to an effect
(:func:`register_screen`), the default screens (the Whittle likelihood-ratio of a stochastic effect, run in
``check``; :func:`mean_screen` for a mean), their null laws and their names in check's table."""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from ...core.registry import Registry
from ...core.search import remove_regressors
from ...fitting.starts import initial_values, starts_of
from ...noise.components import COMPONENTS, STOCHASTIC_KINDS

__all__ = ["Screening", "SCREENING", "register_screening", "unregister_screening", "screening_of", "candidates",
           "Screen", "REGISTRY", "register_screen", "unregister_screen", "screen_of", "screen_df", "screen_test", "whittle_screened",
           "run_screen", "configure", "mean_screen", "boundary_logsf", "NotScreened", "WHITTLE_SCREEN",
           "WHITTLE_SCREEN_2", "MEAN_SCREEN"]


class NotScreened(Exception):
    """Raised by a screen when this model or these data cannot screen its effect; the message says why (``check``
    writes it in the screen's row)."""


#: The screen of a stochastic component (a state, measurement or filter): the Whittle likelihood-ratio of the model
#: with and without it; the null value is on the boundary of the parameter space, hence the mixture.
WHITTLE_SCREEN = "Whittle LR, ½χ²₀+½χ²₁"
#: The same for a stochastic component of two parameters (a Gauss–Markov bias's σ and τ: τ is not identified where σ
#: vanishes, so the mixture is an approximation; its false-alarm rate is measured in experiments/check)
WHITTLE_SCREEN_2 = "Whittle LR, ½χ²₁+½χ²₂"
#: The default screen of a user's mean effect: the exact likelihood-ratio at the effect's least-squares values (on
#: the model's residual) with the model's parameters held — a lower bound of the refit's, so conservative.
MEAN_SCREEN = "exact LR at the effect's least-squares values, the model's held (χ²ₖ, conservative)"


def boundary_logsf(lr: float, k: int) -> float:
    """log P(LR > ``lr``) for a likelihood-ratio whose null puts one parameter of ``k`` on its boundary (a variance
    at 0): the mixture ½χ²_{k−1} + ½χ²_k (Self & Liang 1987), χ²₀ a point mass at 0."""
    from scipy import stats

    if lr <= 0:
        return 0.0
    hi = stats.chi2.logsf(lr, k)
    if k == 1:
        return math.log(0.5) + hi
    return math.log(0.5) + float(np.logaddexp(stats.chi2.logsf(lr, k - 1), hi))


@dataclass(frozen=True)
class Screen:
    """An effect's own screen: ``run(component, ctx)`` → ``(statistic, log p-value, the effect's start values,
    note)`` (raising :class:`NotScreened` with the reason when it cannot), ``test`` what it computes (check's table
    names it), and ``configure(component, ctx)`` → the token with which ``check`` adds the effect when the data decide
    its argument (how many spikes; None: its name). ``ctx``: :class:`~torchtea.checking.screening.ScreenContext`."""

    run: Callable
    test: str
    configure: Callable | None = None



#: The screens by the effect's class (a subclass inherits its parent's unless it registers its own; the rule of
#: :class:`~torchtea.core.registry.Registry` for registering again and unregistering).
REGISTRY = Registry("screen", by_class=True)


def register_screen(effect, test: str, configure: Callable | None = None, *, replace: bool = False):
    """Decorator: the function becomes the screen of the effect class ``effect`` (a user's, or the class of an effect
    instance given; a class that has a screen already — a built-in effect's — needs ``replace=True``), as
    ``torch.distributions.register_kl`` attaches a divergence to a pair of classes. Register it in the module that
    defines the effect, so that whatever loads the effect — ``--effects``, a Dask worker, an entry point — loads its
    screen too."""
    def attach(run: Callable) -> Callable:
        REGISTRY.add(effect, Screen(run, test, configure), replace=replace)
        return run
    return attach


def unregister_screen(effect) -> None:
    """Remove the screen a user registered for the effect class ``effect`` (or an instance's class): its kind's
    default is back, or the built-in screen it had replaced."""
    REGISTRY.remove(effect)


def screen_of(comp) -> Screen | None:
    """The screen registered for ``comp``'s class or its nearest parent; None: the default one."""
    return REGISTRY.find(comp)


@dataclass(frozen=True)
class Screening:
    """How ``check`` treats an effect as a candidate (its screen apart, :class:`Screen`). ``candidate``: ``check``
    screens it where the model lacks it (the base parts — fractional, white, offset — are not); ``order``: its row in
    check's table (the built-in ones 10 … 70, a user's effect 100: after them); ``explains``: the diagnostics whose
    failure it explains physically (a temperature effect the ``temperature`` diagnostic): where it repairs such a
    failed diagnostic, ``check`` ranks it before a suggestion that only soaks up slow variance, unless that one gains
    clearly more (``EXPLAIN_WINDOW``); ``special_cases``: the simpler effects it contains, which the loop's
    simplification tries in its place (dropping it is always tried); ``add_again``: ``check`` may add it to a model
    that has it already (a second line); ``not_screened(comp, model)``: why ``model`` cannot be screened for it
    (None: it can)."""

    candidate: bool = True
    order: int = 100
    explains: tuple = ()
    special_cases: tuple = ()
    add_again: bool = False
    not_screened: Callable | None = None

    def why_not(self, comp, model) -> str | None:
        """Why ``model`` cannot be screened for ``comp`` (None: it can); ``check`` skips it with this note."""
        return None if self.not_screened is None else self.not_screened(comp, model)


#: How check treats each effect as a candidate, by class (a subclass has its parent's unless it registers its own).
SCREENING = Registry("screening", by_class=True)
DEFAULT_SCREENING = Screening()


def register_screening(effect, *, candidate: bool = True, order: int = 100, explains: tuple = (),
                       special_cases: tuple = (), add_again: bool = False, not_screened: Callable | None = None,
                       replace: bool = False) -> None:
    """How ``check`` treats the effect class ``effect`` (or an instance's class) as a candidate: see
    :class:`Screening`. An effect without it is screened with the defaults (a candidate, after the built-in ones,
    explaining no diagnostic in particular)."""
    SCREENING.add(effect, Screening(candidate, order, tuple(explains), tuple(special_cases), add_again, not_screened),
                  replace=replace)


def unregister_screening(effect) -> None:
    """Remove what a user registered for the effect class ``effect`` (a built-in entry it replaced is back)."""
    SCREENING.remove(effect)


def screening_of(comp) -> Screening:
    """How ``check`` treats ``comp`` as a candidate: its class's entry or its nearest parent's, else the defaults."""
    return SCREENING.find(comp, DEFAULT_SCREENING)


def candidates() -> tuple:
    """The effects ``check`` screens, in the order of its table: every registered component that is a candidate, by
    its screening's ``order`` (a user's effects after the built-in ones)."""
    names = list(COMPONENTS)
    return tuple(sorted((n for n, c in COMPONENTS.items() if screening_of(c).candidate),
                        key=lambda n: (screening_of(COMPONENTS[n]).order, names.index(n))))


def screen_df(comp) -> int:
    """The Whittle screen's degrees of freedom: the parameters the fits estimate (not those held)."""
    return max(1, len([p for p in comp.params if p.name not in comp.held]))


def whittle_screened(comp) -> bool:
    """A stochastic effect (a state, measurement or filter) without a screen of its own: ``check`` screens it by the
    Whittle likelihood-ratio, all of them on one periodogram."""
    return comp.kind in STOCHASTIC_KINDS and screen_of(comp) is None


def screen_test(comp) -> str | None:
    """What ``comp``'s screen computes, named in check's table: its own screen's, a stochastic component's Whittle LR,
    a mean's exact LR at its least-squares values (:func:`mean_screen`); None: not screened."""
    own = screen_of(comp)
    if own is not None:
        return own.test
    if comp.kind in STOCHASTIC_KINDS:
        df = screen_df(comp)
        return WHITTLE_SCREEN if df == 1 else WHITTLE_SCREEN_2 if df == 2 else f"Whittle LR, ½χ²{df - 1}+½χ²{df}"
    return MEAN_SCREEN if comp.kind == "mean" else None


def configure(comp, ctx) -> str:
    """The token with which ``check`` adds ``comp`` to ``ctx.model`` (a context whose ``alt`` and ``label`` are not
    set yet): its name, or ``name:argument`` where its screen lets the data decide (how many spikes). May raise
    :class:`NotScreened`."""
    own = screen_of(comp)
    return comp.name if own is None or own.configure is None else own.configure(comp, ctx)


def run_screen(comp, ctx) -> tuple[float, float, dict, str]:
    """The screen of ``ctx.alt`` (the model extended by ``comp``, labelled ``ctx.label``) against the model at its
    fit: its own screen, else the default for a mean (:func:`mean_screen`); a stochastic component without one is
    screened by the Whittle likelihood-ratio in ``check`` (this function is not called for it)."""
    own = screen_of(comp)
    if own is not None:
        return own.run(comp, ctx)
    if comp.kind == "mean":
        return mean_screen(comp, ctx)
    raise NotScreened(f"{comp.name} has no screen")


def mean_screen(comp, ctx) -> tuple[float, float, dict, str]:
    """The default screen of a mean (a user's effect): its values by least squares on the model's residual — its
    ``regressors`` and ``fit_residual``, from its ``start`` — and the exact likelihood-ratio there with the model's
    parameters held (:data:`MEAN_SCREEN`, χ² with as many degrees of freedom as it has parameters)."""
    from scipy import stats

    y, t, ok = ctx.y, ctx.t, ~np.isnan(ctx.y)
    inp = None if ctx.inputs is None else {k: torch.as_tensor(v, dtype=torch.float64)
                                            for k, v in ctx.inputs.items()}
    fitted = ctx.model.mean(dict(ctx.fit.values), torch.as_tensor(t), inp).numpy()[0]
    resid = np.where(ok, y - fitted, np.nan)
    resid[ok] -= resid[ok].mean()
    start = initial_values(ctx.alt, torch.as_tensor(np.where(ok, y, np.nanmean(y))), ctx.h)
    values, columns = starts_of(comp).regressors(comp, ctx.label, t, ctx.inputs, ok)
    values.update(remove_regressors(resid, ok, columns))
    values.update(starts_of(comp).fit_residual(comp, ctx.label, resid, t, ok, ctx.h, start, ctx.inputs))
    values = {n: values.get(n, start[n]) for n in ctx.alt.names if n not in ctx.model.names}
    ll = float(ctx.exact_loglik(ctx.alt, {**ctx.fit.values, **values})[0])
    lr = max(0.0, 2.0 * (ll - ctx.inn.loglik)) if math.isfinite(ll) else 0.0
    return lr, float(stats.chi2.logsf(lr, len(values))), values, ""

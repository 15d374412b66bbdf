"""The models check's loop moves between and how it compares them: a model extended by an effect, the estimates a
model's components hold and how they count in BIC, an exact fit with its intervals, a model's diagnostics at a fit.
Used by :mod:`.check` (adding) and :mod:`.simplify` (taking away and swapping)."""
from __future__ import annotations

from ..fitting.mle import Fit, located_intervals, refine_exact
from ..noise.components import COMPONENTS
from ..noise.components import candidates as candidates_all
from ..noise.model import NoiseModel, parse_model
from .diagnostics import innovations, metrics, run_diagnostics

__all__ = ["extend", "assess", "with_intervals", "REFIT_TOLERANCE"]

#: A candidate's refit has converged when it can gain less than this many nats: its BIC gain is then known to 10⁻³
#: (the ranking needs 0.1; the suggestion the loop adds is refined to :func:`~torchtea.fitting.mle.decrement_tolerance`
#: with its intervals).
REFIT_TOLERANCE = 1e-3


def extend(model: NoiseModel, effect: str) -> NoiseModel:
    """``model`` with one more component, where the component's :meth:`~torchtea.noise.components.Component.position`
    puts it (a ``low-pass`` right after the last stochastic component, anything else at the end). ``effect``: a name,
    or a spec token ``name:argument`` (``spikes:3``)."""
    model = parse_model(model)
    name = effect.partition(":")[0]
    if name not in COMPONENTS:
        raise ValueError(f"unknown effect {effect!r}; choose from: {', '.join(candidates_all())}")
    comp = COMPONENTS[name]
    names = [c.name for _, c in model.components]
    if name in names and not comp.add_again:
        raise ValueError(f"model {model.spec!r} already has {name!r}")
    tokens = [c.token for _, c in model.components]
    tokens.insert(comp.position(model), effect)
    return parse_model("+".join(tokens))


def assess(model, values, y, h, inputs, level):
    """The model's innovations at ``values``, its diagnostics at ``level`` and their metrics."""
    inn = innovations(model, values, y, h, inputs)
    T = None if inputs is None else inputs.get("temperature")
    diags = run_diagnostics(model, values, inn, h, temperature=T, level=level)
    return inn, diags, metrics(inn, diags)


def with_intervals(f: Fit, y, h, inputs) -> Fit:
    """The exact fit ``f`` refined with its intervals (the observed information), what it holds fixed kept fixed and
    its held estimates counted; a located parameter's interval from its own profile."""
    kept = f.model.held_estimates()
    fixed = [n for n in f.model.names if n not in f.free or n in kept]
    out = refine_exact(f.model, y, h, f.values, inputs=inputs, fixed=fixed, metric=f.hessian, intervals=True)
    out.notes[:0] = f.notes
    out.count({n: f.ci95_method[n] for n in kept if n in f.free})
    for n, (c, words) in located_intervals(f.model, out.values, y, h, inputs).items():
        if n in out.free:
            out.ci95[n], out.ci95_method[n] = c, words
    return out

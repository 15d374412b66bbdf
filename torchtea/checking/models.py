"""The models check's loop moves between and how it compares them: a model extended by an effect, the estimates a
model's components hold and how they count in BIC, a model's diagnostics at a fit, and how the loop fits — by the
exact likelihood, or on a long record by the Whittle likelihood with the exact one evaluated at the points it
compares (:mod:`torchtea.fitting.whittle_path`): the model's fit (:func:`model_fit`), its fit from several starts
(:func:`refine`, :func:`refine_one`) and its intervals (:func:`with_intervals`). Used by :mod:`.check` (adding) and
:mod:`.simplify` (taking away and swapping)."""
from __future__ import annotations

from ..fitting.mle import Fit, fit_series, located_intervals, refine_best, refine_exact
from ..fitting.whittle_path import (
    exact_information,
    exact_optimised,
    fits_exactly,
    uses_exact,
    whittle_estimate,
    whittle_refine,
)
from ..noise.components import COMPONENTS
from ..noise.grammar import position, token
from ..noise.model import NoiseModel, assemble, component_of, parse_model
from .diagnostics import innovations, metrics, run_diagnostics
from .screens import candidates as candidates_all
from .screens import screening_of

__all__ = ["extend", "assess", "with_intervals", "model_fit", "refine", "refine_one", "REFIT_TOLERANCE"]

#: A candidate's refit has converged when it can gain less than this many nats: its BIC gain is then known to 10⁻³
#: (the ranking needs 0.1; the suggestion the loop adds is refined to :func:`~torchtea.fitting.mle.decrement_tolerance`
#: with its intervals).
REFIT_TOLERANCE = 1e-3


def extend(model: NoiseModel, effect: str) -> NoiseModel:
    """``model`` with one more component, where the component's :func:`~torchtea.noise.grammar.position`
    puts it (a ``low-pass`` right after the last stochastic component, anything else at the end). ``effect``: a name,
    or a spec token ``name:argument`` (``spikes:3``)."""
    model = parse_model(model)
    name = effect.partition(":")[0]
    if name not in COMPONENTS:
        raise ValueError(f"unknown effect {effect!r}; choose from: {', '.join(candidates_all())}")
    comp = COMPONENTS[name]
    names = [c.name for _, c in model.components]
    if name in names and not screening_of(comp).add_again:
        raise ValueError(f"model {model.spec!r} already has {name!r}")
    at = position(comp, model)
    comps, tokens = [c for _, c in model.components], [token(c) for _, c in model.components]
    tokens.insert(at, effect)
    spec = "+".join(tokens)  # (what a refusal names)
    comps.insert(at, component_of(comp, effect.partition(":")[2], spec))
    return assemble(comps, spec)


def assess(model, values, y, h, inputs, level):
    """The model's innovations at ``values``, its diagnostics at ``level`` and their metrics."""
    inn = innovations(model, values, y, h, inputs)
    T = None if inputs is None else inputs.get("temperature")
    diags = run_diagnostics(model, values, inn, h, temperature=T, level=level)
    return inn, diags, metrics(inn, diags)


def model_fit(model, y, h, *, inputs: dict | None = None, whittle=None, intervals: bool = True,
              fits: str = "auto") -> Fit:
    """The model's fit to ``y``: by the exact likelihood from its Whittle fit's modes
    (:func:`~torchtea.fitting.mle.fit_series`), or on the long-record path its Whittle estimate
    (:func:`~torchtea.fitting.whittle_path.whittle_estimate`) — ``fits`` decides (:func:`~torchtea.fitting.
    whittle_path.uses_exact`)."""
    if fits_exactly(model, y, fits):
        return fit_series(model, [y], h, method="exact", inputs=None if inputs is None else [inputs], profile=False,
                          whittle=whittle, intervals=intervals)[0]
    return whittle_estimate(model, y, h, inputs=inputs, whittle=whittle, intervals=intervals, fits=fits)


def refine(model, y, h, starts: list, *, fits: str = "auto", **kw) -> tuple[Fit, list]:
    """The model's fit from several starts: :func:`~torchtea.fitting.mle.refine_best`, or on the long-record path
    :func:`~torchtea.fitting.whittle_path.whittle_refine` (the same arguments and return)."""
    if uses_exact(model, y, fits):
        if not exact_optimised(y, fits, model):  # (a longer record, no spectrum: the starts evaluated)
            kw["refine"] = False
        return refine_best(model, y, h, starts, **kw)
    return whittle_refine(model, y, h, starts, fits=fits, **kw)


def refine_one(model, y, h, start: dict, *, inputs: dict | None = None, fixed=(), metric=None, intervals: bool = True,
               fits: str = "auto") -> Fit:
    """The model's fit from one start (:func:`~torchtea.fitting.mle.refine_exact`, or on the long-record path its
    Whittle fit from there, the start kept where its exact likelihood is higher)."""
    if fits_exactly(model, y, fits):
        return refine_exact(model, y, h, start, inputs=inputs, fixed=fixed, metric=metric, intervals=intervals)
    if uses_exact(model, y, fits):  # (a long record, a model without a spectrum: the start evaluated)
        fit, _ = refine_best(model, y, h, [("the start", start)], inputs=inputs, fixed=fixed, must=["the start"],
                             refine=False, intervals=False)
        return with_intervals(fit, y, h, inputs, fits) if intervals else fit
    fit, _ = whittle_refine(model, y, h, [("the start", start)], inputs=inputs, fixed=fixed, must=["the start"],
                            intervals=intervals, fits=fits)
    return fit


def with_intervals(f: Fit, y, h, inputs, fits: str = "auto") -> Fit:
    """The fit ``f`` with its intervals: refined by the exact likelihood with the observed information, what it holds
    fixed kept fixed and its held estimates counted, a located parameter's interval from its own profile; on the
    long-record path at its point, from the exact likelihood's information there
    (:func:`~torchtea.fitting.whittle_path.exact_information`)."""
    if not fits_exactly(f.model, y, fits):
        return exact_information(f, y, h, inputs)
    kept = f.model.held_estimates()
    fixed = [n for n in f.model.names if n not in f.free or n in kept]
    out = refine_exact(f.model, y, h, f.values, inputs=inputs, fixed=fixed, metric=f.hessian, intervals=True)
    out.notes[:0] = f.notes
    out.count({n: f.ci95_method[n] for n in kept if n in f.free})
    for n, (c, words) in located_intervals(f.model, out.values, y, h, inputs).items():
        if n in out.free:
            out.ci95[n], out.ci95_method[n] = c, words
    return out

"""The long-record path: where a record is long enough that optimising the exact likelihood is what a check costs
(:data:`WHITTLE_PATH_SAMPLES`, measured), every fit of the loop is a Whittle fit — the log-binned periodogram, the
means by least squares — and the exact filter runs once per point the loop compares: for the exact log-likelihood
its BIC reads (:attr:`~.results.Fit.bic_exact`), the innovations its diagnostics read, and, for the model it ends
with, the exact likelihood's scoring information its intervals come from (one pass of the sensitivity filter).

:func:`uses_exact` decides, per model and series; :func:`whittle_estimate` is the model's fit there,
:func:`whittle_refine` the counterpart of :func:`~.mle.refine_best` (a model's fit from several starts: its Whittle
fit from them, the exact likelihood evaluated at its modes and at the starts that must be kept, the highest kept)
and :func:`exact_information` the intervals of a fit at its point. Up to :data:`POLISH_SAMPLES` the point a fit
ends at is :func:`polished`: scoring on the exact likelihood from there, one start instead of the exact path's
several (a Whittle mode can lie tens of nats below the exact maximum beside it where a narrow resonance is fitted).
A model whose dynamics vary in time (no spectrum) is fitted exactly up to :data:`POLISH_SAMPLES` (with ``fits="whittle"``
up to :data:`WHITTLE_PATH_SAMPLES`), and above evaluated at its best start; a series with missing samples is fitted by the Whittle likelihood of the series with its
gaps filled by its mean, the exact likelihood evaluated with the gaps."""
from __future__ import annotations

import math

import numpy as np
import torch

from ..noise.model import NoiseModel, parse_model
from .exact import FIT_MEMORY, centred, exact_loglik, exact_loglik_grad, gradient_supported
from .results import Fit, estimates_from_hessian

__all__ = ["FITS", "WHITTLE_PATH_SAMPLES", "POLISH_SAMPLES", "uses_exact", "exact_optimised", "fits_exactly", "polished",
           "whittle_estimate", "whittle_refine", "exact_information"]

#: How ``check`` fits: ``"auto"`` (the Whittle path above :data:`WHITTLE_PATH_SAMPLES`), ``"exact"``, ``"whittle"``.
FITS = ("auto", "exact", "whittle")

#: Above this many samples ``check --fits auto`` runs the loop on the Whittle likelihood.
WHITTLE_PATH_SAMPLES = 10_000
#: Up to this many samples the long-record path's fits end at the exact likelihood's maximum nearest their best
#: point (:func:`polished`): a Whittle mode there can lie tens of nats below it (a narrow resonance).
POLISH_SAMPLES = 100_000
#: A polish takes at most this many scoring iterations (from a Whittle mode the maximum is a few away; a flat ridge —
#: a fractional part that is white — is not followed further for the fraction of a nat it gains).
POLISH_ITERATIONS = 12
#: ... and stops where the next would gain less than this many nats (a Newton decrement δ: the estimates then
#: within √(2δ) = 0.2 of their standard errors of the maximum).
POLISH_TOLERANCE = 0.02


def uses_exact(model, y, fits: str = "auto") -> bool:
    """Whether ``check`` fits ``model`` to ``y`` by the exact likelihood: always with ``fits="exact"``, and for a model
    without a spectrum (its dynamics vary in time); with ``"auto"``, also up to :data:`WHITTLE_PATH_SAMPLES` samples.
    (Above, a series with missing samples is fitted by the Whittle likelihood of the series with its gaps filled by
    its mean, the exact likelihood evaluated with the gaps.)"""
    if fits not in FITS:
        raise ValueError(f"fits must be one of {FITS}, got {fits!r}")
    if fits == "exact" or not parse_model(model).stationary:
        return True
    return fits == "auto" and len(y) <= WHITTLE_PATH_SAMPLES


def exact_optimised(y, fits: str = "auto", model=None) -> bool:
    """Whether the exact likelihood may be optimised on ``y``: with ``fits="exact"``, or up to
    :data:`WHITTLE_PATH_SAMPLES` samples; for a ``model`` whose dynamics vary in time (no spectrum, no Whittle fit to
    stand in), up to :data:`POLISH_SAMPLES` unless ``fits="whittle"``. Above, a model :func:`uses_exact` fits
    exactly is evaluated at its best start, not optimised: its gain is a lower bound."""
    if fits == "exact" or len(y) <= WHITTLE_PATH_SAMPLES:
        return True
    return (model is not None and fits == "auto" and not parse_model(model).stationary
            and len(y) <= POLISH_SAMPLES)


def fits_exactly(model, y, fits: str = "auto") -> bool:
    """Whether ``check`` optimises the exact likelihood of ``model`` on ``y`` — the exact path: :func:`uses_exact` and
    :func:`exact_optimised` both (else the long-record path: a Whittle fit, or a model without a spectrum evaluated at
    its best start)."""
    return uses_exact(model, y, fits) and exact_optimised(y, fits, model)


def polished(model, y, fit: Fit, h: float, *, inputs: dict | None = None, fixed=(), tolerance: float | None = None,
             fits: str = "auto", memory=FIT_MEMORY) -> Fit:
    """``fit`` (a point of the long-record path), on a record of at most :data:`POLISH_SAMPLES` samples and a model
    the sensitivity filter serves, unless ``fits="whittle"`` (the Whittle estimates as they are, to compare),
    taken to the exact likelihood's maximum from there by scoring
    (:func:`~.mle.refine_best` from that one start): its method ``"exact"``, its notes saying where it started. Else
    ``fit`` itself. ``fixed``: names held at ``fit``'s values, with those no fit moves (:func:`_held`)."""
    from .mle import refine_best

    model = parse_model(model)
    if fits == "whittle" or len(y) > POLISH_SAMPLES or gradient_supported(model, centred(model, y)) is not None:
        return fit
    out, _ = refine_best(model, y, h, [("the Whittle path's point", fit.values)], inputs=inputs,
                         fixed=_held(model, fixed),
                         must=["the Whittle path's point"], others=0, memory=memory,
                         tolerance=POLISH_TOLERANCE if tolerance is None else max(tolerance, POLISH_TOLERANCE),
                         max_iter=POLISH_ITERATIONS)
    if not out.loglik_exact >= fit.loglik_exact:  # (scoring never ends below its start; a failed run kept out)
        return fit
    out.notes = list(fit.notes) + [f"refined by the exact likelihood from there (ℓ {fit.loglik_exact:.2f} → "
                                   f"{out.loglik_exact:.2f})"]
    out.count({**model.held_estimates(), **model.located()})
    return out


def _held(model: NoiseModel, fixed=()) -> list:
    """The parameters no fit moves: ``fixed``, the references (a temperature's ``t_ref``) and the estimates the
    components hold where the data put them (a step's time, a line's frequency)."""
    held = set(fixed) | model.references() | set(model.located()) | set(model.held_estimates())
    return [n for n in model.names if n in held]


def whittle_estimate(model, y, h: float, *, inputs: dict | None = None, whittle=None, intervals: bool = False,
                     fits: str = "auto", memory=FIT_MEMORY) -> Fit:
    """The model's fit on the Whittle path: its Whittle MLE (``whittle``: a :func:`~.mle.whittle_fit` of it already
    made), the means by least squares, the exact log-likelihood there, :func:`polished`, and with ``intervals``
    those of :func:`exact_information`. ``loglik`` is the Whittle one where not polished; the estimated parameters
    (the means' too) count in k."""
    from .mle import whittle_fit

    model = parse_model(model)
    y = np.asarray(y, dtype=np.float64)
    filled = np.where(np.isnan(y), np.nanmean(y), y)
    wf = whittle if whittle is not None else whittle_fit(model, [filled], h, inputs=None if inputs is None else [inputs])
    values = {**{n: float(x) for n, x in zip(model.names, wf.values[0].tolist())}, **wf.means[0]}
    fit = _fit_at(model, y, h, values, float(wf.loglik[0]), inputs, bool(wf.converged[0]), False, memory,
                  ["fitted by the Whittle likelihood (the long-record path): the exact likelihood evaluated at "
                   "the estimate"])
    fit = polished(model, y, fit, h, inputs=inputs, fits=fits, memory=memory)
    return exact_information(fit, y, h, inputs, memory) if intervals else fit


def _fit_at(model, y, h, values: dict, ll_whittle: float, inputs, converged: bool, intervals: bool, memory,
            notes: list, ll_exact: float | None = None) -> Fit:
    held = _held(model)
    free = [n for n in model.names if n not in held]
    if ll_exact is None:
        ll_exact = float(exact_loglik(model, {n: [values[n]] for n in model.names}, centred(model, y), h,
                                      inputs=inputs, memory=memory)[0])
    u = model.to_unconstrained(values, h)[0]
    how = {n: "not computed (intervals=False)" if n in free else "fixed" for n in model.names}
    fit = Fit(model, "whittle", dict(values), {n: None for n in model.names}, {n: None for n in model.names}, how,
              ll_whittle, ll_exact, int(np.sum(~np.isnan(y))), free, converged, None, list(notes), u, None)
    fit.count({**model.held_estimates(), **model.located()})
    return exact_information(fit, y, h, inputs, memory) if intervals else fit


def exact_information(fit: Fit, y, h: float, inputs: dict | None = None, memory=FIT_MEMORY) -> Fit:
    """``fit`` with standard errors and 95 % intervals from the exact likelihood's scoring information at its point
    (one pass of the sensitivity filter, :func:`~.exact.exact_loglik_grad`: the expected information of the
    innovations, Harvey 1989, §3.4.6) over its estimated parameters, by the delta method as
    :func:`~.results.intervals_from_hessian`; where the sensitivity filter does not apply, the observed information
    by central differences (:func:`~.scoring.exact_hessian`). The intervals' words say which."""
    from . import scoring

    model = fit.model
    yc = centred(model, y)
    held = _held(model)
    mask = torch.tensor([n in fit.free and n not in held for n in model.names])
    idx = mask.nonzero().squeeze(-1)
    P = len(model.names)
    if gradient_supported(model, yc) is not None and not exact_optimised(y, model=model):  # (1 + 2k² passes of hours: none)
        out = Fit(model, fit.method, fit.values, fit.se, fit.ci95, dict(fit.ci95_method), fit.loglik,
                  fit.loglik_exact, fit.n, list(fit.free), fit.converged, fit.profile, list(fit.notes), fit.u, None)
        for n in model.names:
            if mask[model.names.index(n)]:
                out.ci95_method[n] = (f"not computed: {gradient_supported(model, yc)}, so the observed information "
                                      "takes central differences of the exact likelihood, too long a record for them")
        return out
    if gradient_supported(model, yc) is None:
        _, _, info = exact_loglik_grad(model, fit.u.unsqueeze(0), yc, h, idx.numpy(), inputs=inputs, memory=memory)
        H = torch.zeros(P, P, dtype=torch.float64)
        H[idx.unsqueeze(-1), idx] = torch.as_tensor(info[0])
        words = "the exact likelihood's scoring information"
    else:
        H = scoring.exact_hessian(model, yc, h, fit.u, mask, inputs, memory)
        words = "the exact likelihood's observed information"
    values, se, ci, how = estimates_from_hessian(model, fit.u, H, mask, h)
    out = Fit(model, fit.method, values, se, ci, dict(fit.ci95_method), fit.loglik, fit.loglik_exact, fit.n,
              list(fit.free), fit.converged, fit.profile, list(fit.notes), fit.u, H)
    for n in model.names:
        if mask[model.names.index(n)]:
            out.ci95_method[n] = f"{how[n]}, from {words} at the {fit.method} estimate"
    return out


def whittle_refine(model, y, h: float, starts: list, *, inputs: dict | None = None, fixed=(), must=(),
                   intervals: bool = False, others: int | None = None, tolerance: float | None = None,
                   refine: bool = True, margin: float = math.inf, whittle=None, polish: bool = True,
                   fits: str = "auto", memory=FIT_MEMORY) -> tuple[Fit, list]:
    """The long-record counterpart of :func:`~.mle.refine_best`, with its arguments and return: the model's Whittle
    fit from ``starts`` (``(name, values)`` each; the names in ``fixed`` held at the first start's values) and from
    its grid, then the exact log-likelihood at each distinct Whittle mode and at the starts ``must`` names (one
    batch), the highest kept and :func:`polished` (up to :data:`POLISH_SAMPLES`: the exact maximum from there, to
    ``tolerance``; above, the point itself, its ℓ a lower bound of the exact maximum's — ``others`` and ``margin``
    are the exact refinement's and unused here). ``refine=False``: the starts alone, evaluated. ``whittle``: the
    model's Whittle fit from these starts, already made (its modes are used). ``polish=False``: the best point as it
    is; ``fits``: as :func:`polished` reads it. Returns the :class:`~.results.Fit`
    (method ``"whittle"``, or ``"exact"`` where polished; its notes say which point won) and per point ``(name, ℓ
    there, ℓ at the end)``."""
    from .mle import whittle_fit, whittle_value

    model = parse_model(model)
    y = np.asarray(y, dtype=np.float64)
    fixed = [n for n in model.names if n in set(fixed)]
    first = starts[0][1]
    points = [(name, {**v, **{n: first[n] for n in fixed}}) for name, v in starts]
    wf = None
    candidates = [(name, v) for name, v in points if name in must or not refine]
    if refine:
        inp = None if inputs is None else [inputs]
        wf = whittle if whittle is not None else whittle_fit(
            model, [np.where(np.isnan(y), np.nanmean(y), y)], h, inputs=inp, fixed={n: first[n] for n in fixed},
            starts=[[v for _, v in points]])
        for k, (u, _, _) in enumerate(wf.modes[0] if wf.modes else [(wf.u[0], None, None)]):
            vals = {n: float(x) for n, x in zip(model.names, model.as_matrix(model.from_unconstrained(u, h))[0])}
            candidates.append((f"the Whittle fit's mode {k + 1}", {**vals, **wf.means[0],
                                                                    **{n: first[n] for n in fixed}}))
    if not candidates:
        candidates = points[:1]
    yc = centred(model, y)
    ll = exact_loglik(model, {n: [v[n] for _, v in candidates] for n in model.names}, yc, h, inputs=inputs,
                      memory=memory)
    ll = np.where(np.isfinite(ll), ll, -np.inf)
    b = int(np.argmax(ll))
    name, values = candidates[b]
    ll_w = whittle_value(model, wf.data, values, h) if wf is not None else math.nan
    notes = [f"fitted by the Whittle likelihood (the long-record path); the best of {len(candidates)} points by the "
             f"exact likelihood: {name} (ℓ {ll[b]:.2f})"]
    fit = _fit_at(model, y, h, values, ll_w, inputs, True, False, memory, notes, float(ll[b]))
    if refine and polish:
        fit = polished(model, y, fit, h, inputs=inputs, fixed=fixed, tolerance=tolerance, fits=fits, memory=memory)
    fit = exact_information(fit, y, h, inputs, memory) if intervals else fit
    return fit, [(n, float(x), fit.loglik_exact if k == b else float(x))
                 for k, ((n, _), x) in enumerate(zip(candidates, ll))]

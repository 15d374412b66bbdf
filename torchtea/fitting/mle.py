r"""Maximum-likelihood fits of a :class:`~torchtea.noise.model.NoiseModel`, with uncertainty.

The procedure, per series (axes and candidate models are batched):

1. **Deterministic part** (offset, ramp, temperature bias, sinusoids) by least squares — a sinusoid's
   frequency from the periodogram's peak, refined — and removed (:func:`regress_mean`).
2. **Whittle MLE** of the stochastic part from several starting orders and poles in one batch (the
   likelihood has a second mode where order and pole trade, ALGORITHMS.md §7), by the method of scoring
   (:func:`~.scoring.score`) on the components' closed-form spectral derivatives
   (:func:`~torchtea.noise.derivatives.spectrum_jacobian`): the gradient and the expected information of the
   binned Whittle sum (:func:`~torchtea.likelihood.whittle.whittle_scores`), no automatic differentiation in the
   loop; the starts race, and each distinct maximum is a mode.
3. ``method="exact"``: from there, the **exact** likelihood (Kalman filter on the stacked state,
   :func:`~torchtea.likelihood.kalman.loglik_fast`) is maximised over all free parameters, the mean
   parameters included, by the method of scoring on the sensitivity filter's exact gradients
   (:func:`~.scoring.score_batch`) — where the series has gaps or the order varies in time, quasi-Newton steps on
   the Whittle fit's Hessian with central-difference gradients, and L-BFGS-B where those stall.
4. **Uncertainty**: standard errors from the observed information (the Hessian of −ℓ: for Whittle by central
   differences of its closed-form gradient, for exact of the exact gradients) by the delta method from the unconstrained coordinates;
   95 % intervals on those coordinates (log for positive values, logit for the order) so they respect
   the constraints; for the order also the **profile-likelihood** interval of the Whittle likelihood,
   which sees both modes. AIC = 2k − 2ℓ, BIC = k ln N − 2ℓ with k the free parameters.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor

from ..core.search import refine_frequency, remove_regressors
from ..likelihood.settings import current as likelihood_settings
from ..likelihood.whittle import RESOLUTION, WhittleData, periodogram, whittle_data
from ..noise.components import STOCHASTIC_KINDS, MeanEffect
from ..noise.model import NoiseModel, parse_model
from . import scoring
from .exact import FIT_MEMORY, ExactPass, centred, exact_loglik, exact_pass, gradient_supported, unknown_level
from .innovations import located_intervals
from .multistart import exact_multistart
from .results import Z95, Fit, bic, estimates_from_hessian, intervals_from_hessian
from .scoring import decrement_tolerance
from .starts import initial_values, starts_of
from .whittle_objective import WhittleObjective, whittle_value

__all__ = ["Fit", "WhittleFit", "WhittleObjective", "whittle_value", "linear_mean", "fit_series", "located_intervals", "refine_exact", "refine_best", "regress_mean", "whittle_fit", "exact_loglik", "profile_order", "METHODS",
           "Z95", "CHI2_95", "bic", "decrement_tolerance",
           # defined in .exact, .innovations and core.search, imported from here too
           "FIT_MEMORY", "ExactPass", "exact_pass", "centred", "unknown_level", "refine_frequency", "remove_regressors"]

METHODS = ("whittle", "exact")
CHI2_95 = 3.841458820694124
#: Starting orders and pole fractions ρ = −f h^α / 2^α of the multi-start.
START_ORDERS = (0.1, 0.3, 0.5, 0.7, 0.9)
START_FRACTIONS = (0.05, 0.5)


# --------------------------------------------------------------------------- deterministic part


def regress_mean(model: NoiseModel, y, h: float, inputs: dict | None = None) -> tuple[dict, np.ndarray]:
    """Least-squares values of the mean components of one series and the residual series.

    Without an ``offset`` component the series' mean is removed all the same (and reported by the caller):
    a stochastic model of zero mean cannot explain gravity."""
    y = np.asarray(y, dtype=np.float64)
    N = len(y)
    t = np.arange(N) * h
    vals: dict = {}
    ok = ~np.isnan(y)
    resid = y.copy()
    resid[ok] -= resid[ok].mean()
    columns = []
    model.check_inputs(inputs)
    for label, comp in model.components:
        fixed, cols = starts_of(comp).regressors(comp, label, t, inputs, ok)
        vals.update(fixed)
        columns += cols
    vals.update(remove_regressors(resid, ok, columns))
    start = None
    for label, comp in model.components:  # what the residual shows (a line), one component after the other
        if comp.kind == "mean" and start is None:
            start = initial_values(model, torch.as_tensor(np.where(ok, y, np.nanmean(y))), h)
        vals.update(starts_of(comp).fit_residual(comp, label, resid, t, ok, h, start or {}, inputs))
    _level(model, y, vals, t, ok, inputs)
    return vals, resid


def _level(model: NoiseModel, y: np.ndarray, vals: dict, t: np.ndarray, ok: np.ndarray,
           inputs: dict | None = None) -> None:
    """The level (an ``offset``'s) in ``vals``, in place: the mean of what is left plus what was removed (the other
    mean terms at their values, with the input channels they read)."""
    for label, comp in model.components:
        if isinstance(comp, MeanEffect) and comp.level:
            m = model.mean({**{n: 0.0 for n in model.names}, **vals}, torch.as_tensor(t), inputs).numpy()[0]
            vals[f"{label}.{comp.params[0].name}"] = float(np.mean((y - m)[ok]))


def linear_mean(model: NoiseModel, y, h: float, inputs: dict | None = None) -> tuple[list, np.ndarray]:
    """The linear part of the model's mean (:meth:`~.starts.Starts.regressors`: a ramp's slope, a bias per °C):
    its coefficients' names and their regressors ``(p, N)``, centred over the observed samples as the least squares
    of :func:`regress_mean` centres them."""
    y = np.asarray(y, dtype=np.float64)
    t = np.arange(len(y)) * h
    ok = ~np.isnan(y)
    names, cols = [], []
    for label, comp in model.components:
        for name, col in starts_of(comp).regressors(comp, label, t, inputs, ok)[1]:
            names.append(name)
            cols.append(np.asarray(col, dtype=np.float64))
    X = np.stack(cols) if cols else np.zeros((0, len(y)))
    return names, X - (X[:, ok].mean(1, keepdims=True) if cols else 0.0)


# --------------------------------------------------------------------------- Whittle

def _stochastic(model: NoiseModel, name: str) -> bool:
    label = name.rsplit(".", 1)[0]
    return dict(model.components)[label].kind in STOCHASTIC_KINDS


def _starts(model: NoiseModel, y: np.ndarray, h: float, omega: Tensor, I: Tensor, mean_vals: dict,
            fixed: dict, orders=START_ORDERS, fractions=START_FRACTIONS) -> list[dict]:
    """Starting values: a grid of orders × pole fractions (one start without a fractional part), the
    drive variances scaled so that the model's mean spectrum meets the periodogram's."""
    has_frac = model.order_name is not None
    orders = orders if has_frac else (None,)
    fracs = fractions if has_frac else (None,)
    base = initial_values(model, torch.as_tensor(y), h)
    hi = I[omega > omega.max() * 0.75].mean()
    white = float(hi) * 2 * math.pi
    low = omega < omega.max() * 0.5
    starts = []
    for a in orders:
        for rho in fracs:
            v = dict(base)
            v.update(mean_vals)
            for label, comp in model.components:
                starts_of(comp).grid_start(comp, label, v, white, a, rho, h)
            v.update(fixed)
            # scale the state drives so that the mean spectrum matches on the lower half
            S = model.spectrum(v, omega, h)[0]
            target = float(I[low].mean())
            now = float(S[low].mean())
            if now > 0 and target > 0:
                s = target / now
                for label, comp in model.components:
                    starts_of(comp).scale_drive(comp, label, v, s, fixed)
            if all(v != w for w in starts):
                starts.append(v)
    return starts


def _free_mask(model: NoiseModel, fixed, stochastic_only: bool) -> Tensor:
    """``(P,)`` bool: not among the ``fixed`` names (and, with ``stochastic_only``, of a stochastic component)."""
    return torch.tensor([(n not in fixed) and (not stochastic_only or _stochastic(model, n)) for n in model.names])


class WhittleFit(NamedTuple):
    """Whittle MLEs of ``S`` series: ``values`` ``(S, P)``, ``loglik`` ``(S,)``, unconstrained ``u`` ``(S, P)`` and
    the Hessian of −ℓ_W there ``(S, P, P)``, the least-squares mean values per series, ``converged`` ``(S,)``,
    the ``free`` mask ``(P,)``, the terms of the Whittle sums of the residual series ``data``
    (:class:`~torchtea.likelihood.whittle.WhittleData`, binned as the likelihood settings say), and per series
    its distinct local maxima ``modes`` (a list of ``(u (P,), loglik, hessian (P, P))``, best first; the first is
    the estimate) — the starts of the exact fit's multi-start —, and per series the grid's ``starts`` ``(k, P)`` (unconstrained;
    the exact fit's multi-start also runs from them where the model has a fractional order: the Whittle sum and the
    exact likelihood need not share their modes on the order–pole ridge)."""

    values: Tensor
    loglik: Tensor
    u: Tensor
    hessian: Tensor
    means: list
    converged: Tensor
    free: Tensor
    data: WhittleData
    modes: list | None = None
    starts: list | None = None


#: The Whittle fits' starts race (:func:`~.scoring.score`): a start that cannot end higher than a finished one is
#: left where it is, and is no mode.
RACE = True

#: The Whittle fits' absolute damping floor (:func:`~.scoring.score`'s ``floor``): a direction whose information is
#: below this fraction of the largest is damped — a variance collapsing along a flat direction stays near where it
#: stopped mattering (measured: a fit's collapsed white noise ran to e⁻²² without it, and the exact fit started
#: there could not come back, 12 nats below the one started at e⁻¹¹; 10⁻⁴ moved the optima by 0.002 nats).
FLOOR = 1e-6

#: At most this many modes per series are kept (:attr:`WhittleFit.modes`).
MAX_MODES = 4


def whittle_resolution() -> float | None:
    """The binned Whittle sum's resolution under the likelihood settings in force (None: every ordinate)."""
    how = likelihood_settings().whittle
    if how not in ("binned", "full"):
        raise ValueError(f"likelihood setting whittle must be 'binned' or 'full', got {how!r}")
    return None if how == "full" else RESOLUTION


def whittle_fit(model, series: list, h: float, *, inputs: list | None = None, fixed: dict | None = None,
                orders=START_ORDERS, fractions=START_FRACTIONS, starts: list | None = None,
                grid: bool = True, tolerance: float | None = None, hessian: bool = True) -> WhittleFit:
    """Whittle MLEs of several series at once (:class:`WhittleFit`): the mean components by least squares — the
    linear ones (:func:`linear_mean`) then profiled out of the Whittle sum under each spectrum, so that their values
    are its generalised least squares at the fit —, then the stochastic part from every start of the multi-start grid (``grid``) and of ``starts`` (per
    series a list of dicts of values of the stochastic parameters). ``tolerance``: the decrement (nats) at which a start has
    converged (default :func:`~.scoring.decrement_tolerance`'s; a screen, which reads the likelihood-ratio to a tenth,
    asks for less). ``hessian=False``: the observed information is not computed (zeros: a screen reads the
    likelihood and the modes alone)."""
    model = parse_model(model)
    fixed = dict(fixed or {})
    rows_u, owner, mean_list, Is, before, regs, grids = [], [], [], [], [], [], []
    omega = None
    resolution = whittle_resolution()
    for s, y in enumerate(series):
        mean_vals, resid = regress_mean(model, y, h, None if inputs is None else inputs[s])
        names, X = linear_mean(model, y, h, None if inputs is None else inputs[s])
        left = resid + np.array([mean_vals[n] for n in names]) @ X  # (the linear mean left in)
        if model.diffuse and not any(_is_trend(x) for x in X):
            X = np.vstack([X, _trend(y, h)])
        before.append(left)
        regs.append(X)
        mean_list.append(mean_vals)
        omega, I = periodogram(torch.as_tensor(resid))
        Is.append(I)
        points = _starts(model, resid, h, omega, I, mean_vals, fixed, orders, fractions) if grid else []
        grids.append(len(points))
        points += [{**v, **mean_vals, **fixed} for v in (starts[s] if starts is not None else [])]
        if not points:
            raise ValueError("whittle_fit: no starting values (grid=False and no starts)")
        for v in points:
            rows_u.append(model.to_unconstrained(v, h)[0])
            owner.append(s)
    # the linear mean's coefficients profiled out under each spectrum (generalised least squares in the frequency
    # domain), the least squares above only placing the terms' frequencies and starting the means; a model with a
    # random walk has a trend profiled out too, a parameter of no model (a walk's periodogram holds its whole
    # increment over the record as a trend's, twice its spectrum at every Fourier frequency: profiled, none of it)
    data = whittle_data(omega, torch.stack(Is), resolution, residual=torch.as_tensor(np.stack(before)),
                        columns=torch.as_tensor(np.stack(regs)))
    owner = torch.tensor(owner)
    free = _free_mask(model, fixed, True)
    U0 = torch.stack(rows_u)
    idx = free.nonzero().squeeze(-1).numpy()
    # every start to convergence: after a few iterations a start on the order–pole ridge can look better than one that
    # converges to the higher mode, and each distinct mode is a start of the exact fit; a start that has reached
    # another's mode stops there
    objective = WhittleObjective(model, data, h, U0, owner, idx)
    U, loss, converged = _scored(model, data, h, U0, owner, idx, RACE, objective, tolerance)
    modes = _distinct(U, loss, converged, owner, free, len(series))
    best = [kept[0] for kept in modes]
    flat = [i for kept in modes for i in kept]
    if names:  # each mode at its own coefficients, each series' means at its best mode's
        beta = objective.beta(U[flat], flat)[:, :len(names)]
        for k, i in enumerate(flat):
            U[i, [model.names.index(n) for n in names]] = beta[k]
        for s, kept in enumerate(modes):
            mean_list[s].update(zip(names, beta[flat.index(kept[0])].tolist()))
            _level(model, np.asarray(series[s], dtype=np.float64), mean_list[s], np.arange(len(series[s])) * h,
                   ~np.isnan(np.asarray(series[s], dtype=np.float64)), None if inputs is None else inputs[s])
    P = U.shape[-1]
    H = dict(zip(flat, objective.hessian(U[flat], flat) if hessian else torch.zeros(len(flat), P, P,
                                                                                   dtype=torch.float64)))
    modes = [[(U[i].clone(), -float(loss[i]), H[i]) for i in kept] for kept in modes]
    best = torch.tensor(best)
    first = [int((owner == s).nonzero()[0]) for s in range(len(series))]
    return WhittleFit(model.as_matrix(model.from_unconstrained(U[best], h)).detach(), -loss[best],
                      U[best], torch.stack([H[int(i)] for i in best]), mean_list, torch.as_tensor(converged)[best],
                      free, data, modes, [U0[i:i + k] for i, k in zip(first, grids)])


def _trend(y: np.ndarray, h: float) -> np.ndarray:
    """``(1, N)``: time, centred over the observed samples (a trend's regressor)."""
    t = np.arange(len(y)) * h
    return (t - t[~np.isnan(np.asarray(y, dtype=np.float64))].mean())[None]


def _is_trend(x: np.ndarray) -> bool:
    """A regressor that is a trend (a ramp's: its differences all but constant)."""
    d = np.diff(x)
    return bool(np.ptp(d) <= 1e-9 * max(float(np.abs(d).max()), 1e-300))


def _scored(model, data: WhittleData, h: float, U0: Tensor, owner: Tensor, idx, race: bool, objective=None,
            tolerance: float | None = None):
    """The starts ``U0`` (series ``owner``) scored to their maxima of ``data``'s Whittle sum: ``(U, −ℓ_W (inf where
    not finite), converged)``."""
    objective = objective or WhittleObjective(model, data, h, U0, owner, idx)
    X, loss, converged, _ = scoring.score(objective.vgi, objective.values, U0[:, idx].numpy(),
                                         scoring.logit_limits(model, idx), groups=owner.numpy(), race=race, pin=True,
                                         floor=FLOOR, tolerance=tolerance)
    U = U0.clone()
    U[:, idx] = torch.as_tensor(X)
    return U, torch.as_tensor(np.where(loss < 1e300, loss, np.inf)), converged


def _distinct(U: Tensor, loss: Tensor, converged, owner: Tensor, free: Tensor, series: int) -> list:
    """Per series, its distinct maxima among the scored starts (indices, the best first, at most
    :data:`MAX_MODES`): a start left in the race is none, and two within :data:`~.scoring.MODE_DISTANCE` of each other
    are one."""
    modes = []
    for s in range(series):
        mine = (owner == s).nonzero().squeeze(-1)
        order = mine[torch.argsort(loss[mine])]
        kept = []
        for i in order.tolist():
            if not math.isfinite(float(loss[i])) or (kept and not converged[i]):  # (a start left in the race)
                continue
            # distances on coordinates clipped to ±8: an order at its bound has a logit of 12 or 14 by rounding
            if all(float((U[i].clamp(-8, 8) - U[j].clamp(-8, 8))[free].abs().max()) > scoring.MODE_DISTANCE
                   for j in kept):
                kept.append(i)
            if len(kept) == MAX_MODES:
                break
        modes.append(kept or [int(order[0])])
    return modes


# --------------------------------------------------------------------------- exact


# --------------------------------------------------------------------------- uncertainty


def profile_order(model, wf: WhittleFit, h: float, *, grid: int = 21, fixed: dict | None = None) -> list[dict]:
    """The Whittle profile log-likelihood of the fractional order on a grid over (0, 1) for each series of
    the Whittle fit ``wf`` (its periodograms and MLEs), and the 95 % interval {α : 2 (ℓ̂ − ℓ_p(α)) ≤ χ²₁,₀.₉₅}
    read off by linear interpolation — a union of pieces when the profile has two modes, reported as its
    hull with ``pieces``."""
    model = parse_model(model)
    name = model.order_name
    if name is None:
        raise ValueError(f"model {model.spec!r} has no fractional order to profile")
    io = model.names.index(name)
    alphas = torch.linspace(0.0125, 0.9875, grid, dtype=torch.float64)
    ua = model.param_spec(name).to_unconstrained(alphas, h)
    free = _free_mask(model, set(fixed or {}) | {name}, True)
    S = wf.u.shape[0]
    loss_grid = torch.full((S, grid), math.inf, dtype=torch.float64)
    idx = free.nonzero().squeeze(-1).numpy()
    # continuation: from the grid point next to each series' MLE outwards, each point started from the last;
    # the upward and the downward chains advance together as one batch
    k0 = torch.argmin((alphas.unsqueeze(0) - wf.values[:, io].unsqueeze(-1)).abs(), dim=-1)
    u_up, u_down = wf.u.clone(), wf.u.clone()
    for step in range(grid):
        k_up, k_down = k0 + step, k0 - step - 1
        up = (k_up < grid).nonzero().squeeze(-1)
        down = (k_down >= 0).nonzero().squeeze(-1)
        if up.numel() + down.numel() == 0:
            break
        rows = torch.cat([up, down])
        kk = torch.cat([k_up[up], k_down[down]])
        u0 = torch.cat([u_up[up], u_down[down]])
        u0[:, io] = ua[kk]
        objective = WhittleObjective(model, wf.data, h, u0, rows, idx)
        X, loss, _, _ = scoring.score(objective.vgi, objective.values, u0[:, idx].numpy(),
                                      scoring.logit_limits(model, idx), max_iter=30, tolerance=1e-3,
                                      groups=np.arange(len(rows)), race=False, pin=True)
        u0[:, idx] = torch.as_tensor(X)
        u_up[up], u_down[down] = u0[:len(up)], u0[len(up):]
        loss_grid[rows, kk] = torch.as_tensor(np.where(loss < 1e300, loss, np.inf))
    out = []
    a = alphas.numpy()
    for s in range(S):
        ll = -loss_grid[s]
        top = max(float(ll.max()), float(wf.loglik[s]))
        d = (2.0 * (top - ll)).numpy()
        inside = d <= CHI2_95
        pieces = []
        i = 0
        while i < grid:
            if inside[i]:
                j = i
                while j + 1 < grid and inside[j + 1]:
                    j += 1
                lo_ = a[i] if i == 0 else a[i - 1] + (a[i] - a[i - 1]) * (d[i - 1] - CHI2_95) / (d[i - 1] - d[i])
                hi_ = a[j] if j == grid - 1 else a[j] + (a[j + 1] - a[j]) * (CHI2_95 - d[j]) / (d[j + 1] - d[j])
                pieces.append([float(lo_), float(hi_)])
                i = j + 1
            else:
                i += 1
        if not pieces:  # the grid is coarser than the interval: the grid points next to the optimum
            k = int(np.argmin(d))
            pieces = [[float(a[max(k - 1, 0)]), float(a[min(k + 1, grid - 1)])]]
        out.append({"orders": a.tolist(), "loglik": ll.numpy().tolist(), "ci95": [pieces[0][0], pieces[-1][1]],
                    "pieces": pieces, "at_edge": bool(inside[0] or inside[-1])})
    return out


# --------------------------------------------------------------------------- the whole fit


def _fit_arguments(model: NoiseModel, method: str, fixed: dict | None, series: list) -> tuple[dict, list]:
    """:func:`fit_series`'s ``fixed`` and ``series`` checked against the model and the method (float64 arrays);
    ``ValueError`` naming what is wrong: an unknown method, a fixed name the model lacks or its components cannot
    hold, the Whittle method on a non-stationary model or on series with gaps."""
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    fixed = dict(fixed or {})
    unknown = set(fixed) - set(model.names)
    if unknown:
        raise ValueError(f"fixed parameters {sorted(unknown)} are not in model {model.spec!r} ({model.names})")
    for label, comp in model.components:
        comp.check_fixed(label, fixed)
    series = [np.asarray(y, dtype=np.float64) for y in series]
    if method == "whittle" and not model.stationary:
        moving = ", ".join(c.name for _, c in model.components if not c.stationary)
        raise ValueError(f"{moving} makes the model non-stationary: it is fitted by the exact likelihood only "
                         "(--method exact)")
    if method == "whittle" and any(bool(np.isnan(y).any()) for y in series):
        raise ValueError("the Whittle method needs complete series; use --method exact for recordings with "
                         "missing samples")
    return fixed, series


def fit_series(model, series: list, h: float, *, method: str = "exact", inputs: list | None = None,
               fixed: dict | None = None, memory=FIT_MEMORY, profile: bool | None = None,
               whittle: WhittleFit | None = None, intervals: bool = True) -> list[Fit]:
    """Fit ``model`` to each series of ``series`` (1-D arrays, NaN = missing; sample time ``h``).

    ``whittle``: a :func:`whittle_fit` of the same model, series and ``fixed`` to start from (instead of
    fitting it here). ``intervals=False``: the exact method skips its finite-difference Hessian (1 + 2k²
    likelihood evaluations) and reports no standard errors or intervals.

    ``profile``: compute the order's Whittle profile likelihood (``Fit.profile``; it is the order's reported
    interval for ``method="whittle"``, beside the Wald one otherwise). Default: for the Whittle method only —
    it costs about as much as the Whittle fit itself."""
    if profile is None:
        profile = method == "whittle"
    model = parse_model(model)
    fixed, series = _fit_arguments(model, method, fixed, series)
    filled = [np.where(np.isnan(y), np.nanmean(y), y) for y in series]
    wf = whittle_fit(model, filled, h, inputs=inputs, fixed=fixed) if whittle is None else whittle
    name = model.order_name
    profiles = [None] * len(series)
    if profile and name is not None and name not in fixed:
        profiles = profile_order(model, wf, h, fixed=fixed)
    fits = []
    for s, y in enumerate(series):
        inp = None if inputs is None else inputs[s]
        notes = []
        # the references the components hold (a temperature's t_ref) join `fixed` for the exact stage
        fx = dict(fixed)
        refs = model.references()
        located = {n: words for n, words in model.located().items() if n not in fx}
        for n, x in wf.means[s].items():
            if n in refs or n in located:
                fx.setdefault(n, x)
        y_exact = centred(model, y)
        if method == "whittle":
            free = wf.free & torch.tensor([n not in fx for n in model.names])
            u, ll, H, ok = wf.u[s], float(wf.loglik[s]), wf.hessian[s], bool(wf.converged[s])
            vals, se, ci, how = intervals_from_hessian(model, u, H, free, h)
            for n in model.names:
                if not _stochastic(model, n) and n not in fx:
                    how[n] = "least squares before the Whittle sum: no interval"
            ll_exact = float(exact_loglik(model, vals, y_exact, h, inputs=inp, memory=memory)[0])
        else:
            free = torch.tensor([n not in fx for n in model.names])
            modes = wf.modes[s] if wf.modes else [(wf.u[s], float(wf.loglik[s]), wf.hessian[s])]
            u, ll, H, ok, more = exact_multistart(model, y_exact, h, modes, free, inp, memory, intervals,
                                                  wf.starts[s] if wf.starts else None)
            notes += more
            vals, se, ci, how = estimates_from_hessian(model, u, H, free, h)
            ll_exact = ll
        kfree = [n for n, f in zip(model.names, free.tolist()) if f]
        if not model.has_level:
            notes.append(f"mean {float(np.nanmean(y)):.6g} removed before fitting; the model has no offset, so the "
                         "exact likelihood integrates the unknown level out")
        prof = profiles[s]
        if prof is not None and method == "whittle":
            ci[name] = prof["ci95"]
            how[name] = "Whittle profile likelihood" + (" (two pieces, hull)" if len(prof["pieces"]) > 1 else "")
        fit = Fit(model, method, vals, se, ci, how, ll, ll_exact, int(np.sum(~np.isnan(y))), kfree, ok, prof, notes,
                  u, H)
        fit.count(located)  # (held where the data put them, but estimated)
        if intervals and method == "exact":  # their own intervals, where the component makes one
            for n, (c, words) in located_intervals(model, vals, y, h, inp).items():
                if n in located:
                    ci[n], how[n] = c, words
        fits.append(fit)
    return fits


def refine_exact(model, y, h: float, start: dict, *, inputs: dict | None = None, fixed=(), metric: Tensor | None = None,
                 memory=FIT_MEMORY, intervals: bool = True) -> Fit:
    """The exact stage of :func:`fit_series` on its own: the exact MLE of one series from ``start`` (values of
    every parameter of ``model``; the names in ``fixed`` stay there), quasi-Newton steps on ``metric`` (a Hessian
    of −ℓ on the unconstrained scale, e.g. a smaller model's; uncovered coordinates get their own curvature).
    Used to fit a model extended by one component from the smaller model's estimate. With ``intervals=False``
    the finite-difference Hessian (1 + 2k² likelihood evaluations) and the intervals are skipped."""
    model = parse_model(model)
    y = np.asarray(y, dtype=np.float64)
    u0 = model.to_unconstrained(start, h)[0]
    free = torch.tensor([n not in fixed for n in model.names])
    u, ll, H, ok, _ = scoring.exact_refine(model, centred(model, y), h, u0, free, inputs, memory, metric,
                                    hessian=intervals)
    vals, se, ci, how = estimates_from_hessian(model, u, H, free, h)
    kfree = [n for n, f in zip(model.names, free.tolist()) if f]
    return Fit(model, "exact", vals, se, ci, how, ll, ll, int(np.sum(~np.isnan(y))), kfree, ok, None, [], u, H)


#: :func:`refine_best` refines the starts whose exact ℓ is within this many nats of the best start's (besides the
#: starts it must refine), at most :data:`MAX_MODES` of them.
START_MARGIN = 10.0


def refine_best(model, y, h: float, starts: list, *, inputs: dict | None = None, fixed=(), must=(),
                memory=FIT_MEMORY, intervals: bool = False, others: int = MAX_MODES,
                tolerance: float | None = None, refine: bool = True,
                margin: float = START_MARGIN, max_iter: int = 60) -> tuple[Fit, list]:
    """The exact MLE of one series from several starts, the best kept: ``starts`` a list of ``(name, values)``
    (values of every parameter of ``model``; the names in ``fixed`` stay at the first start's values). The exact ℓ is
    evaluated at every start in one batch; those whose names are in ``must`` and the best ``others`` of the rest
    within ``margin`` nats (:data:`START_MARGIN`) of the best (distinct) are refined — as one batch of scoring iterations
    where the sensitivity filter applies (:func:`~.scoring.score_batch`), else one after another — and the highest maximum
    kept (``tolerance``: the decrement at which a start has converged, ``max_iter`` the most scoring iterations,
    :func:`~.scoring.score_batch`). ``refine=False``:
    the best start as it is, no iteration (its ℓ a lower bound of the maximum's). Returns the
    :class:`Fit` (its notes say which start won) and per refined start ``(name, ℓ at the start, ℓ at its
    maximum)``."""
    model = parse_model(model)
    y = np.asarray(y, dtype=np.float64)
    yc = centred(model, y)
    fixed = [n for n in model.names if n in set(fixed)]
    first = starts[0][1]
    points = [(name, {**v, **{n: first[n] for n in fixed}}) for name, v in starts]
    U = torch.cat([model.to_unconstrained(v, h) for _, v in points])
    free = torch.tensor([n not in fixed for n in model.names])
    ll0 = exact_loglik(model, model.from_unconstrained(U, h), yc, h, inputs=inputs, memory=memory)
    ll0 = np.where(np.isfinite(ll0), ll0, -np.inf)
    chosen = [i for i in range(len(points)) if points[i][0] in must]
    extra = 0
    for i in np.argsort(-ll0):
        i = int(i)
        if i in chosen or extra >= others or not ll0[i] >= ll0.max() - margin:
            continue
        if any(float((U[i].clamp(-8, 8) - U[j].clamp(-8, 8))[free].abs().max()) <= scoring.MODE_DISTANCE for j in chosen):
            continue
        chosen.append(i)
        extra += 1
    if not refine:
        runs = [(U[i].clone(), float(ll0[i]), False) for i in chosen]
    elif gradient_supported(model, yc) is None:
        X, f, ok, _ = scoring.score_batch(model, yc, h, U[chosen], free, inputs, memory, max_iter=max_iter,
                                          tolerance=tolerance)
        runs = []
        for k, i in enumerate(chosen):
            u = U[i].clone()
            u[free] = torch.as_tensor(X[k])
            runs.append((u, -float(f[k]) if f[k] < 1e300 else -math.inf, bool(ok[k])))
    else:
        runs = [(lambda r: (r[0], r[1], r[3]))(scoring.exact_refine(model, yc, h, U[i].clone(), free, inputs, memory,
                                                                hessian=False)) for i in chosen]
    lls = [r[1] if math.isfinite(r[1]) else -math.inf for r in runs]
    b = int(np.argmax(lls))
    u, ll, ok = runs[b]
    H = scoring.exact_hessian(model, yc, h, u, free, inputs, memory) if intervals else None
    vals, se, ci, how = estimates_from_hessian(model, u, H, free, h)
    kfree = [n for n, fr in zip(model.names, free.tolist()) if fr]
    notes = []
    if len(runs) > 1:
        notes.append(f"the best of {len(runs)} starts: {points[chosen[b]][0]} (ℓ {ll:.2f}; the others "
                     + ", ".join(f"{points[i][0]} {lls[k]:.2f}" for k, i in enumerate(chosen) if k != b) + ")")
    fit = Fit(model, "exact", vals, se, ci, how, ll, ll, int(np.sum(~np.isnan(y))), kfree, ok, None, notes, u, H)
    return fit, [(points[i][0], float(ll0[i]), lls[k]) for k, i in enumerate(chosen)]

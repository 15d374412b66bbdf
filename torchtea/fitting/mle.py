r"""Maximum-likelihood fits of a :class:`~torchtea.noise.model.NoiseModel`, with uncertainty.

The procedure, per series (axes and candidate models are batched):

1. **Deterministic part** (offset, ramp, temperature bias, sinusoids) by least squares — a sinusoid's
   frequency from the periodogram's peak, refined — and removed (:func:`regress_mean`).
2. **Whittle MLE** of the stochastic part from several starting orders and poles in one batch (the
   likelihood has a second mode where order and pole trade, ALGORITHMS.md §7), by a batched damped
   Newton with autograd derivatives (:mod:`.optimize`).
3. ``method="exact"``: from there, the **exact** likelihood (Kalman filter on the stacked state,
   :func:`~torchtea.likelihood.kalman.loglik_fast`) is maximised over all free parameters, the mean
   parameters included: quasi-Newton steps on the Whittle fit's Hessian with central-difference gradients
   (the difference points evaluated as one batch) — where that Hessian covers every free parameter, i.e.
   the model has no mean or modifier parameters — else, or when those steps stall, L-BFGS-B.
4. **Uncertainty**: standard errors from the observed information (the Hessian of −ℓ: autograd for
   Whittle, central differences for exact) by the delta method from the unconstrained coordinates;
   95 % intervals on those coordinates (log for positive values, logit for the order) so they respect
   the constraints; for the order also the **profile-likelihood** interval of the Whittle likelihood,
   which sees both modes. AIC = 2k − 2ℓ, BIC = k ln N − 2ℓ with k the free parameters.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor

from ..core.search import refine_frequency, remove_regressors
from .exact import (FIT_MEMORY, ExactPass, centred, exact_loglik, exact_loglik_grad, exact_pass, gradient_supported,
                    unknown_level)
from .innovations import located_intervals
from ..likelihood.settings import current as likelihood_settings
from ..likelihood.whittle import RESOLUTION, WhittleData, periodogram, whittle_data
from ..noise.model import NoiseModel, parse_model
from .optimize import newton
from .starts import initial_values, starts_of

__all__ = ["Fit", "WhittleFit", "fit_series", "located_intervals", "refine_exact", "refine_best", "regress_mean", "whittle_fit", "exact_loglik", "profile_order", "METHODS",
           "Z95", "CHI2_95",
           # defined in .exact, .innovations and core.search, imported from here too
           "FIT_MEMORY", "ExactPass", "exact_pass", "centred", "unknown_level", "refine_frequency", "remove_regressors"]

METHODS = ("whittle", "exact")
Z95 = 1.959963984540054
CHI2_95 = 3.841458820694124
#: Starting orders and pole fractions ρ = −f h^α / 2^α of the multi-start.
START_ORDERS = (0.1, 0.3, 0.5, 0.7, 0.9)
START_FRACTIONS = (0.05, 0.5)
#: Central-difference step of the exact gradient in the unconstrained coordinates. 10⁻³: on 2.16·10⁶ samples the
#: step 10⁻⁴ left gradients dominated by ℓ's rounding noise, and the refinement stopped 0.0015 nats (5 % of a
#: standard error) short of the maximum that 10⁻³ reached in six iterations; on 30 000 samples (five hidden-effect
#: cases) the two steps give the same estimates within 0.4 % of a standard error.
FD_STEP = 1e-3


@dataclass
class Fit:
    """One series' fit. ``values``/``se``/``ci95`` keyed by ``component.parameter`` (``se`` None for a
    fixed parameter); ``ci95_method`` says how each interval was made; ``loglik`` of ``method``;
    ``loglik_exact`` the exact log-likelihood at the estimate (also for a Whittle fit);
    ``free`` the names estimated; ``n`` samples; ``notes`` what a reader must know."""

    model: NoiseModel
    method: str
    values: dict
    se: dict
    ci95: dict
    ci95_method: dict
    loglik: float
    loglik_exact: float | None
    n: int
    free: list
    converged: bool
    profile: dict | None = None
    notes: list = field(default_factory=list)
    #: The estimate on the optimisers' unconstrained scale ``(P,)`` and the Hessian of −ℓ there ``(P, P)``
    #: (zero rows for fixed parameters; None when not computed).
    u: Tensor | None = None
    hessian: Tensor | None = None

    @property
    def k(self) -> int:
        return len(self.free)

    @property
    def aic(self) -> float:
        return 2.0 * self.k - 2.0 * self.loglik

    @property
    def bic(self) -> float:
        """BIC on the likelihood of its ``method`` (``fit``'s number)."""
        return bic(self.k, self.n, self.loglik)

    @property
    def bic_exact(self) -> float:
        """BIC on the exact likelihood (what ``check`` compares models by, whatever the fit's method)."""
        return bic(self.k, self.n, self.loglik_exact)

    def count(self, estimates: dict) -> None:
        """The one rule of what BIC counts: a parameter a fit holds where the data put it (a step's time, a line's
        frequency at the refined periodogram peak — :meth:`~torchtea.noise.model.NoiseModel.held_estimates`) is an
        estimate all the same, so ``estimates`` (name → the words for its interval) join the fit's estimated
        parameters ``free`` (its ``k``); a reference (a temperature's ``t_ref``) never does."""
        for n, words in estimates.items():
            if n not in self.free:
                self.free.append(n)
            self.ci95_method[n] = words


def bic(k: int, n: int, loglik: float) -> float:
    """The Bayesian information criterion k ln n − 2ℓ of a fit of ``k`` estimated parameters to ``n`` samples with
    log-likelihood ``loglik`` (which likelihood: the caller's, and said where the number is written)."""
    return k * math.log(n) - 2.0 * loglik


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
    # the level: the mean of what is left plus what was removed
    for label, comp in model.components:
        if comp.level:
            m = model.mean({**{n: 0.0 for n in model.names}, **vals}, torch.as_tensor(t)).numpy()[0]
            vals[f"{label}.{comp.params[0].name}"] = float(np.mean((y - m)[ok]))
    return vals, resid


# --------------------------------------------------------------------------- Whittle

def _stochastic(model: NoiseModel, name: str) -> bool:
    label = name.rsplit(".", 1)[0]
    return dict(model.components)[label].kind in ("state", "measurement", "filter")


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
    the estimate) — the starts of the exact fit's multi-start."""

    values: Tensor
    loglik: Tensor
    u: Tensor
    hessian: Tensor
    means: list
    converged: Tensor
    free: Tensor
    data: WhittleData
    modes: list | None = None


#: Two Whittle optima are distinct modes when their free unconstrained coordinates differ by more than this.
MODE_DISTANCE = 0.1
#: At most this many modes per series are kept (:attr:`WhittleFit.modes`).
MAX_MODES = 4


def whittle_resolution() -> float | None:
    """The binned Whittle sum's resolution under the likelihood settings in force (None: every ordinate)."""
    how = likelihood_settings().whittle
    if how not in ("binned", "full"):
        raise ValueError(f"likelihood setting whittle must be 'binned' or 'full', got {how!r}")
    return None if how == "full" else RESOLUTION


def _whittle_loss(model: NoiseModel, data: WhittleData, h: float):
    """−ℓ_W of problems ``rows`` (series of ``data``) at parameters ``u`` (one row each), for :func:`newton`."""
    def loss(u, rows):
        d = data.rows(rows)
        return -d.loglik(model.spectrum(model.from_unconstrained(u, h), d.frequencies(), h))
    return loss


def whittle_fit(model, series: list, h: float, *, inputs: list | None = None, fixed: dict | None = None,
                orders=START_ORDERS, fractions=START_FRACTIONS, starts: list | None = None,
                grid: bool = True) -> WhittleFit:
    """Whittle MLEs of several series at once (:class:`WhittleFit`): the mean components by least squares,
    then the stochastic part from every start of the multi-start grid (``grid``) and of ``starts`` (per
    series a list of dicts of values of the stochastic parameters)."""
    model = parse_model(model)
    fixed = dict(fixed or {})
    rows_u, owner, mean_list, Is = [], [], [], []
    omega = None
    resolution = whittle_resolution()
    for s, y in enumerate(series):
        mean_vals, resid = regress_mean(model, y, h, None if inputs is None else inputs[s])
        mean_list.append(mean_vals)
        omega, I = periodogram(torch.as_tensor(resid))
        Is.append(I)
        points = _starts(model, resid, h, omega, I, mean_vals, fixed, orders, fractions) if grid else []
        points += [{**v, **mean_vals, **fixed} for v in (starts[s] if starts is not None else [])]
        if not points:
            raise ValueError("whittle_fit: no starting values (grid=False and no starts)")
        for v in points:
            rows_u.append(model.to_unconstrained(v, h)[0])
            owner.append(s)
    data = whittle_data(omega, torch.stack(Is), resolution)
    owner = torch.tensor(owner)
    free = _free_mask(model, fixed, True)
    # every start to convergence (the binned sum makes it cheap): after a few iterations a start on the order–pole
    # ridge can look better than one that converges to the higher mode
    res = newton(_whittle_loss(model, data.rows(owner), h), torch.stack(rows_u), free)
    finite = torch.where(torch.isfinite(res.loss), res.loss, torch.full_like(res.loss, math.inf))
    modes, best = [], []
    for s in range(len(series)):
        mine = (owner == s).nonzero().squeeze(-1)
        order = mine[torch.argsort(finite[mine])]
        kept = []
        for i in order.tolist():
            if not math.isfinite(float(finite[i])):
                continue
            # distances on coordinates clipped to ±8: an order at its bound has a logit of 12 or 14 by rounding
            if all(float((res.u[i].clamp(-8, 8) - res.u[j].clamp(-8, 8))[free].abs().max()) > MODE_DISTANCE
                   for j in kept):
                kept.append(i)
            if len(kept) == MAX_MODES:
                break
        kept = kept or [int(order[0])]
        best.append(kept[0])
        modes.append([(res.u[i].clone(), -float(res.loss[i]), res.hessian[i].clone()) for i in kept])
    best = torch.tensor(best)
    return WhittleFit(model.as_matrix(model.from_unconstrained(res.u[best], h)).detach(), -res.loss[best],
                      res.u[best], res.hessian[best], mean_list, res.converged[best], free, data, modes)


# --------------------------------------------------------------------------- exact


def _scoring_objective(model, y, h, base: Tensor, idx: np.ndarray, inputs, memory):
    """−ℓ ``(K,)``, its gradient ``(K, F)`` and the scoring information ``(K, F, F)`` at K points at once, each point the
    free coordinates ``idx`` of ``base`` (unconstrained), by the sensitivity filter
    (:func:`~.exact.exact_loglik_grad`); +1e300 (zero gradient and information) where ℓ is not finite."""
    def vgi(points: np.ndarray):
        U = base.repeat(points.shape[0], 1)
        U[:, idx] = torch.as_tensor(points)
        ll, gr, info = exact_loglik_grad(model, U, y, h, idx, inputs=inputs, memory=memory)
        bad = ~(np.isfinite(ll) & np.isfinite(gr).all(-1) & np.isfinite(info).all((-1, -2)))
        f = np.where(bad, 1e300, -ll)
        g = np.where(bad[:, None], 0.0, -gr)
        info = np.where(bad[:, None, None], 0.0, info)
        return f, g, info
    return vgi


#: The scoring iterations' Levenberg–Marquardt damping (relative to the information's diagonal): its start, and the
#: bound beyond which the iteration has stalled.
SCORING_DAMPING = (1e-3, 1e8)
#: Central-difference step (unconstrained coordinates) of the observed information from the sensitivity filter's
#: gradients. The gradients carry no differencing error, so the step only trades truncation (O(d²)) against the
#: gradients' rounding; standard errors agree to 0.1 % for steps 10⁻⁴–10⁻³ (tests/test_gradient.py).
INFORMATION_STEP = 3e-4


def _exact_score(model, y, h, u0: Tensor, free: Tensor, inputs, memory, max_iter: int = 60, hessian: bool = True):
    """Maximise the exact likelihood over the ``free`` unconstrained coordinates from ``u0`` by the method of scoring
    with exact gradients (:func:`_score_batch` from one start). Returns what :func:`_exact_refine` returns; the
    Hessian is the observed information, by central differences of the exact gradients
    (:func:`_information_from_gradients`)."""
    X, f, ok, iterations = _score_batch(model, y, h, u0.unsqueeze(0), free, inputs, memory, max_iter)
    u = u0.clone()
    u[free] = torch.as_tensor(X[0])
    H = _exact_hessian(model, y, h, u, free, inputs, memory) if hessian else None
    return u, -float(f[0]), H, bool(ok[0]), int(iterations[0])


#: The scoring iterations stop once this many accepted steps in a row each gained less than the decrement tolerance:
#: the likelihood no longer moves by what its rounding can tell (a parameter running to its bound — a variance to
#: zero, an order to 1 — keeps a constant predicted decrement along its log or logit while its real gains vanish).
STALL_STEPS = 2


#: Step lengths the scoring iterations try along each direction, as one batch of likelihood values (the longest that
#: lowers −ℓ enough is taken).
SCORING_STEPS = (1.0, 0.25, 0.0625, 0.015625)
#: A start still running is left where it is once, at its pace over the last RACE_WINDOW iterations, it cannot come
#: within RACE_MARGIN nats of a finished start's ℓ in its iterations left (:func:`_score_batch`).
RACE_WINDOW, RACE_MARGIN = 5, 2.0
#: The scoring iterations keep every logit (a bounded parameter's, the pole's fraction, a frequency's share of
#: Nyquist) within ±this (:func:`_score_batch`): an order within 6·10⁻⁶ of 0 or 1 is at its bound. Measured: on a
#: ramp's data, fractional+white's order bent to its bound gains 0.3 nats more at a logit of 18 (the fit before issue
#: 44 went there) and costs 42 scoring iterations at a bound of 16 against 9 at 12 (bundled gy).
LOGIT_BOUND = 12.0
#: A start has converged when its last FLAT_WINDOW accepted steps together gained less than FLAT_GAIN nats and its
#: decrement is below FLAT_GAIN too: a crawl along a flat direction (a variance collapsed to 10⁻¹² of the data's, whose
#: log still drifts; measured on a 60 000-sample gyroscope: 30 more iterations for 0.003 nats) is at its maximum for
#: every use of ℓ (BIC, likelihood ratios read to 0.1 nats).
FLAT_WINDOW, FLAT_GAIN = 5, 1e-3
#: A start less than RACE_MARGIN below a finished one is left where it is once the gap is more than CATCH_SAFETY
#: times what it can still gain by two estimates, the larger taken: its decrement, and the sum of its gains if they go
#: on shrinking at the rate of its last RACE_WINDOW iterations (a geometric series; none while they do not shrink).
#: (Not further below: there the local estimates say nothing of how far a start climbs.) Measured on the bundled gx
#: (fractional+white, 44 930 samples): a second mode of the order–pole ridge 0.04 nats below the best, taking quarter
#: steps along the curved ridge and gaining 2–3·10⁻³ nats each, ran 36 iterations more (7 s) to end 0.006 nats below
#: it; from 0.03 nats below, its gains to the end were 0.023, the estimate times two 0.029.
CATCH_SAFETY = 2.0
#: Two full scoring steps in a row whose decrement is above this fraction of the one before: linear convergence, and
#: the metric starts learning from the gradients (:func:`_score_batch`).
SLOW_RATIO = 0.5


def _score_batch(model, y, h, U0: Tensor, free: Tensor, inputs, memory, max_iter: int = 60,
                 tolerance: float | None = None):
    r"""The method of scoring from K starts ``U0`` ``(K, P)`` at once (their likelihoods evaluated as one batch, the
    finished ones left out): directions :math:`-(\mathcal I + \mu\,\mathrm{diag}\,\mathcal I)^{-1} g` on the
    scoring information of the sensitivity filter (:func:`~.exact.exact_loglik_grad`), capped at 3 in the
    unconstrained coordinates, and along each the longest of :data:`SCORING_STEPS` that lowers −ℓ by a tenth of what
    the information predicts (Armijo: the full steps of all starts in one batch of likelihood values, the shorter
    ones, in a second, only where the full one fails); each start's damping μ shrunk
    after a full step and grown after none (Levenberg–Marquardt). A start has converged when its decrement
    ½ gᵀ𝓘⁻¹g (the −ℓ still to gain on the information) is below :func:`decrement_tolerance`, or after
    :data:`STALL_STEPS` steps in a row that each gained less, or once its last :data:`FLAT_WINDOW` steps together
    gained less than :data:`FLAT_GAIN` with its decrement below that too (a crawl along a flat direction). A start still running is left where it is once it is
    within :data:`MODE_DISTANCE` of a finished one, below it, or once at its recent pace it cannot reach a finished
    one's ℓ in the iterations it has left (:data:`RACE_WINDOW`, :data:`RACE_MARGIN`), or it is below a finished one
    and gains less per iteration than the tolerance's ten times: the batch does not wait for a start that cannot end
    higher.
    ``tolerance``: the decrement (nats) at which a start has converged, instead of :func:`decrement_tolerance`'s.
    Returns the free coordinates ``(K, F)``, −ℓ ``(K,)``, converged ``(K,)`` and iterations ``(K,)``."""
    idx = free.nonzero().squeeze(-1).numpy()
    U0 = U0.detach().to(torch.float64)
    if not bool((U0[:, ~free] == U0[0, ~free]).all()):
        raise ValueError("the starts of one scoring batch share their fixed coordinates")
    vgi = _scoring_objective(model, y, h, U0[0].clone(), idx, inputs, memory)
    values = _objective(model, y, h, U0[0].clone(), idx, inputs, memory)
    X = U0[:, idx].numpy().copy()
    K = len(X)
    # a logit past ±LOGIT_BOUND is a parameter at its bound (an order within 6·10⁻⁶ of 0 or 1, a pole at its
    # stability limit or at 0): the steps stop there instead of wandering along a flat boundary
    bounded = np.array([model.param_spec(model.names[i]).scale == "logit" for i in idx])
    lim = np.where(bounded, LOGIT_BOUND, np.inf)
    X = np.clip(X, -lim, lim)
    f, g, info = vgi(X)
    if not len(idx):  # nothing free: the likelihood where it is
        return X, f, np.ones(K, dtype=bool), np.zeros(K, dtype=int)
    # the metric of each start's steps: the scoring information, until the steps converge only linearly (each full
    # step gains what the information predicts, but the prediction shrinks slowly: the information overstates the
    # curvature along some direction — the misspecified part of a model, a mean's second derivatives), then
    # BFGS-updated from the exact gradients' changes, which learn that curvature (back to the information when a
    # learnt direction fails)
    metric = info.copy()
    history = [[x] for x in f]
    learning = np.zeros(K, dtype=bool)
    slow = np.zeros(K, dtype=int)
    last_dec = np.full(K, np.inf)
    mu = np.full(K, SCORING_DAMPING[0])
    ok = np.zeros(K, dtype=bool)
    done = f >= 1e300
    stalls = np.zeros(K, dtype=int)
    iterations = np.zeros(K, dtype=int)
    tol = np.array([decrement_tolerance(x) if tolerance is None else tolerance for x in f])
    ts = np.array(SCORING_STEPS)
    for _ in range(max_iter):
        active = np.nonzero(~done)[0]
        if not len(active):
            break
        steps, decs = [], []
        for k in active:
            # a logit held at its bound while the gradient pushes it further out stays there: the step is the
            # Newton step of the others (projected Newton; a step clipped at the bound afterwards points elsewhere)
            held = (np.abs(X[k]) >= lim) & (np.sign(X[k]) == -np.sign(g[k]))
            move = ~held
            step = np.zeros_like(g[k])
            d = np.diag(metric[k])[move]
            floor = 1e-12 * max(float(d.max()), 1e-300) if len(d) else 1.0
            A = metric[k][np.ix_(move, move)] + np.diag(mu[k] * np.maximum(d, floor) + floor)
            try:
                step[move] = -np.linalg.solve(A, g[k][move])
            except np.linalg.LinAlgError:
                step[move] = -g[k][move] / (np.maximum(d, floor) * (1 + mu[k]))
            decs.append(-0.5 * float(g[k] @ step))
            big = float(np.max(np.abs(step))) if len(step) else 0.0
            steps.append(step * (3.0 / big) if big > 3.0 else step)
        decs = np.array(decs)
        conv = (decs < tol[active]) & (mu[active] <= SCORING_DAMPING[0])
        ok[active[conv]] = done[active[conv]] = True
        keep = ~conv
        active, decs = active[keep], decs[keep]
        steps = np.stack([st for st, c in zip(steps, keep) if c]) if len(active) else None
        if not len(active):
            break
        iterations[active] += 1
        trials = np.clip(X[active][:, None, :] + ts[None, :, None] * steps[:, None, :], -lim, lim)  # (A, T, F)
        slope = np.einsum("af,af->a", g[active], steps)  # the directional derivative of −ℓ (negative)
        # the full step of every start first, the shorter ones only for the starts where it fails
        fv = np.full((len(active), len(ts)), np.inf)
        fv[:, 0] = values(trials[:, 0])
        retry = ~(fv[:, 0] <= f[active] + 0.1 * slope)
        if retry.any():
            fv[retry, 1:] = values(trials[retry, 1:].reshape(-1, X.shape[1])).reshape(int(retry.sum()), len(ts) - 1)
        good = fv <= f[active][:, None] + 0.1 * ts[None, :] * slope[:, None]
        moved = good.any(axis=1)
        pick = np.argmax(good, axis=1)  # the longest step that is good enough
        rows = active[moved]
        if len(rows):
            chosen = trials[moved, pick[moved]]
            fn, gn, In = vgi(chosen)
            for j, k in enumerate(rows):
                if not fn[j] <= f[k]:  # (the two kernels' values differ by rounding: a tie at the noise)
                    mu[k] *= 8.0
                    continue
                gained = f[k] - fn[j]
                full = pick[moved][j] == 0
                s_, y_ = chosen[j] - X[k], gn[j] - g[k]
                if learning[k]:
                    sy = float(s_ @ y_)
                    if sy > 1e-12 * float(np.linalg.norm(s_) * np.linalg.norm(y_)):
                        Ms = metric[k] @ s_
                        metric[k] = metric[k] - np.outer(Ms, Ms) / float(s_ @ Ms) + np.outer(y_, y_) / sy
                else:
                    metric[k] = In[j]
                    slow[k] = slow[k] + 1 if full and decs[j] > SLOW_RATIO * last_dec[k] else 0
                    if slow[k] >= 2:
                        learning[k] = True
                last_dec[k] = decs[j]
                X[k], f[k], g[k], info[k] = chosen[j], fn[j], gn[j], In[j]
                mu[k] = max(mu[k] / 4.0, 1e-9) if full else mu[k]
                stalls[k] = stalls[k] + 1 if gained < tol[k] else 0
                if stalls[k] >= STALL_STEPS:
                    ok[k] = done[k] = True
        for j, k in enumerate(active[~moved]):
            if decs[~moved][j] < NOISE_DECREMENTS * tol[k]:  # nothing to gain that ℓ's rounding can tell
                ok[k] = done[k] = True
                continue
            if learning[k]:  # the learnt metric failed: back to the scoring information
                learning[k], slow[k], metric[k] = False, 0, info[k]
                continue
            mu[k] *= 8.0
            if mu[k] >= SCORING_DAMPING[1]:  # no step lowers −ℓ: at the rounding noise of ℓ that is convergence
                ok[k] = decs[~moved][j] < NOISE_DECREMENTS * tol[k]
                done[k] = True
        # a start heading for the maximum a finished start has reached is left there: it cannot end higher. (A start
        # far below a finished one is not: its decrement, the −ℓ it can gain where ℓ is near quadratic, says nothing
        # of how far it climbs from far away — one 184 nats below a finished start ended 2.6 nats above it.)
        # Nor is one that, at the pace of its last RACE_WINDOW iterations, cannot reach a finished start's ℓ within its
        # iterations left: a start that wanders along a flat ridge far below.
        for j, k in enumerate(active):
            history[k].append(f[k])
            if (not done[k] and len(history[k]) > FLAT_WINDOW and decs[j] < FLAT_GAIN
                    and history[k][-FLAT_WINDOW - 1] - f[k] < FLAT_GAIN):
                ok[k] = done[k] = True
        finished = np.nonzero(done & ok)[0]
        for j, k in enumerate(active):
            if done[k] or not len(finished):
                continue
            top = finished[np.argmin(f[finished])]
            near = any(f[k] >= f[j] and float(np.max(np.abs(np.clip(X[k], -8, 8) - np.clip(X[j], -8, 8))))
                       <= MODE_DISTANCE for j in finished)
            pace = (history[k][-RACE_WINDOW - 1] - f[k]) / RACE_WINDOW if len(history[k]) > RACE_WINDOW else np.inf
            gap = f[k] - f[top]
            behind = gap > RACE_MARGIN + pace * (max_iter - iterations[k])
            crawling = gap > 0 and pace < NOISE_DECREMENTS * tol[k]  # below it and all but still
            caught = RACE_MARGIN >= gap > CATCH_SAFETY * max(decs[j], _remaining(history[k]))
            if near or behind or crawling or caught:
                done[k] = True
    return X, f, ok, iterations


def _remaining(history: list) -> float:
    """What a start whose −ℓ went through ``history`` gains in all if its gains of the last :data:`RACE_WINDOW`
    iterations go on shrinking at their rate (a geometric series); ∞ while they do not shrink."""
    if len(history) <= RACE_WINDOW:
        return math.inf
    gains = -np.diff(history[-RACE_WINDOW - 1:])
    if not (gains > 0).all() or gains[-1] >= gains[0]:
        return math.inf
    r = (gains[-1] / gains[0]) ** (1.0 / (len(gains) - 1))
    return float(gains[-1] * r / (1.0 - r))


def _information_from_gradients(model, y, h, u: Tensor, free: Tensor, inputs, memory) -> Tensor:
    """The observed information (the Hessian of −ℓ) at ``u`` over the ``free`` coordinates by central differences of
    the exact gradients: 2F sensitivity passes in one batch instead of the 1 + 2F² likelihood passes of
    :func:`_exact_hessian`; zero rows and columns for the others ``(P, P)``."""
    idx = free.nonzero().squeeze(-1).numpy()
    vgi = _scoring_objective(model, y, h, u.clone(), idx, inputs, memory)
    x = u[idx].numpy()
    p = len(idx)
    E = np.eye(p) * INFORMATION_STEP
    _, g, _ = vgi(np.concatenate([x + E, x - E]))
    H = ((g[:p] - g[p:]) / (2 * INFORMATION_STEP)).T
    H = 0.5 * (H + H.T)
    Hfull = torch.zeros(len(u), len(u), dtype=torch.float64)
    Hfull[np.ix_(idx, idx)] = torch.as_tensor(H)
    return Hfull


def _exact_refine(model, y, h, u0: Tensor, free: Tensor, inputs, memory, metric: Tensor | None = None,
                  max_iter: int = 30, hessian: bool = True):
    """Maximise the exact likelihood over the ``free`` unconstrained coordinates from ``u0``: by scoring with exact
    gradients (:func:`_exact_score`) where the sensitivity filter applies (:func:`~.exact.gradient_supported`), else
    as follows.

    With a positive-definite ``metric`` (the Whittle fit's Hessian of −ℓ, which approximates the exact one
    on a long series) the steps are quasi-Newton steps on it, with central-difference gradients of the
    exact −ℓ, a backtracking line search and BFGS updates of the metric: from the Whittle optimum two or
    three steps reach the exact one when the model fits, a few more when it does not (steps are capped at 1
    in the unconstrained coordinates). Free coordinates the metric does not cover (a zero or non-finite
    diagonal: mean and modifier parameters — offset, ramp, sinusoid, temperature terms — which the Whittle
    fit does not see) get their own block of the Hessian by central differences (:func:`_fd_hessian`), with
    no cross terms to the others (mean and noise parameters are orthogonal in a Gaussian model). When the steps stall,
    L-BFGS-B does the work. ``converged``: the quasi-Newton decrement on the metric fell below
    :func:`decrement_tolerance` (10⁻⁶ nats up to ~50 000 samples), else L-BFGS-B's success. Returns ``(u, ℓ, Hessian of −ℓ, converged, iterations)``; the Hessian by
    central differences (:func:`_fd_hessian`), or None with ``hessian=False``."""
    if gradient_supported(model, y) is None:
        return _exact_score(model, y, h, u0, free, inputs, memory, hessian=hessian)
    idx = free.nonzero().squeeze(-1).numpy()
    p = len(idx)
    base = u0.clone()
    batch = _objective(model, y, h, base, idx, inputs, memory)

    def fun(x):
        pts = [x] + [x + FD_STEP * e for e in np.eye(p)] + [x - FD_STEP * e for e in np.eye(p)]
        f = batch(np.stack(pts))
        g = (f[1:p + 1] - f[p + 1:]) / (2 * FD_STEP)
        return f[0], g

    x = u0[idx].numpy().copy()
    ok, iterations = False, 0
    M = None
    if metric is not None:
        M = metric[np.ix_(idx, idx)].numpy().copy()
        missing = np.nonzero(~np.isfinite(np.diag(M)) | (np.diag(M) <= 0))[0]
        if len(missing):  # the Hessian block of the uncovered coordinates by differences; no cross terms
            M[missing, :] = 0.0
            M[:, missing] = 0.0

            def sub(points):
                full = np.repeat(x[None], len(points), 0)
                full[:, missing] = points
                return batch(full)

            Hm = _fd_hessian(sub, x[missing])
            if np.all(np.isfinite(Hm)) and np.all(np.linalg.eigvalsh(Hm) > 0):
                M[np.ix_(missing, missing)] = Hm
            else:
                M[missing, missing] = np.where(np.isfinite(np.diag(Hm)) & (np.diag(Hm) > 0), np.diag(Hm), 1.0)
        if not (np.all(np.isfinite(M)) and np.all(np.linalg.eigvalsh(M) > 0)):
            M = None
    if M is not None:
        f, g = fun(x)
        tol = decrement_tolerance(f)
        for iterations in range(1, max_iter + 1):
            step = -np.linalg.solve(M, g)
            decrement = -0.5 * float(g @ step)
            if decrement < tol:  # the exact −ℓ still to gain (on this metric) is below what ℓ's rounding can tell
                ok = True
                break
            # a step longer than 1 in the unconstrained coordinates (a factor e in a variance) means the metric
            # is far off along some direction (a misspecified model's Whittle optimum far from the exact one):
            # shorten it and let the BFGS updates learn the curvature
            t = min(1.0, 1.0 / float(np.max(np.abs(step))))
            while t >= 1.0 / 256:
                fn, gn = fun(x + t * step)
                if fn <= f + 1e-4 * t * float(g @ step):
                    break
                t /= 4.0
            else:
                # no decrease along the quasi-Newton direction: at the rounding noise of ℓ this is convergence,
                # else hand over to L-BFGS-B
                ok = decrement < NOISE_DECREMENTS * tol
                break
            # BFGS update of the metric with the step taken and the change of gradient: the Whittle Hessian
            # is only a start (on a misspecified model it can be far from the exact one along the ridge)
            s_, y_ = t * step, gn - g
            sy = float(s_ @ y_)
            if sy > 1e-12 * float(np.linalg.norm(s_) * np.linalg.norm(y_)):
                Ms = M @ s_
                M = M - np.outer(Ms, Ms) / float(s_ @ Ms) + np.outer(y_, y_) / sy
            gained = f - fn
            x, f, g = x + t * step, fn, gn
            if gained < tol and decrement < NOISE_DECREMENTS * tol:  # the step gained nothing ℓ's rounding can tell
                ok = True
                break
    if not ok:
        from scipy.optimize import minimize
        res = minimize(fun, x, jac=True, method="L-BFGS-B", options={"maxiter": max_iter, "gtol": 1e-4})
        x, f, ok, iterations = res.x, float(res.fun), bool(res.success), iterations + int(res.nit)
    u = base.clone()
    u[idx] = torch.as_tensor(x)
    if not hessian:
        return u, -float(f), None, ok, iterations
    return u, -float(f), _exact_hessian(model, y, h, u, free, inputs, memory), ok, iterations


#: The exact refinement stops when its Newton decrement (the −ℓ still to gain on its metric) is below
#: ``max(1e-6, DECREMENT_RELATIVE · |ℓ|)`` nats. ℓ is a sum over the samples and its float64 rounding grows with it:
#: measured on 540 000 samples (ℓ ≈ 9·10⁵) the same point's ℓ moves by about 2·10⁻⁵ nats under steps of 10⁻⁴,
#: so a micro-nat is below what the differences can tell there. A decrement δ leaves the parameters within √(2δ)
#: of their standard errors from the maximum: 1.2 % at 2·10⁶ samples; below 50 000 samples the tolerance is the
#: micro-nat of before.
DECREMENT_RELATIVE = 2e-11
#: No decrease along the quasi-Newton direction with a decrement under this many tolerances is convergence at the
#: rounding noise (not a reason to hand over to L-BFGS-B).
NOISE_DECREMENTS = 10.0


def decrement_tolerance(neg_loglik: float) -> float:
    """The Newton decrement (nats) below which the exact refinement has converged at −ℓ = ``neg_loglik``."""
    return max(1e-6, DECREMENT_RELATIVE * abs(neg_loglik)) if math.isfinite(neg_loglik) else 1e-6


def _objective(model, y, h, base: Tensor, idx: np.ndarray, inputs, memory):
    """The exact −ℓ of many points at once, each point the free coordinates ``idx`` of ``base`` (unconstrained);
    +1e300 where ℓ is not finite."""
    def batch(points: np.ndarray) -> np.ndarray:
        U = base.repeat(points.shape[0], 1)
        U[:, idx] = torch.as_tensor(points)
        vals = model.from_unconstrained(U, h)
        ll = exact_loglik(model, vals, y, h, inputs=inputs, memory=memory)
        return np.where(np.isfinite(ll), -ll, 1e300)
    return batch


def _exact_hessian(model, y, h, u: Tensor, free: Tensor, inputs, memory) -> Tensor:
    """The Hessian of the exact −ℓ at ``u`` over the ``free`` coordinates: central differences of the exact gradients
    (:func:`_information_from_gradients`) where the sensitivity filter applies, else of ℓ itself
    (:func:`_fd_hessian`); zero rows and columns for the others ``(P, P)``."""
    if gradient_supported(model, y) is None:
        return _information_from_gradients(model, y, h, u, free, inputs, memory)
    idx = free.nonzero().squeeze(-1).numpy()
    H = _fd_hessian(_objective(model, y, h, u.clone(), idx, inputs, memory), u[idx].numpy().copy())
    Hfull = torch.zeros(len(u), len(u), dtype=torch.float64)
    Hfull[np.ix_(idx, idx)] = torch.as_tensor(H)
    return Hfull


#: The exact fit's multi-start refines every Whittle mode whose exact ℓ at the Whittle optimum is within this many
#: nats of the best one's (at most :data:`MAX_MODES`), and keeps the highest exact maximum.
EXACT_MODE_MARGIN = 10.0


def _exact_multistart(model, y, h, modes: list, free: Tensor, inputs, memory, hessian: bool):
    """:func:`_exact_refine` from the Whittle ``modes`` (``(u, ℓ_W, H_W)`` each) whose exact ℓ is within
    :data:`EXACT_MODE_MARGIN` of the best; the best exact maximum, with its Hessian when ``hessian``. Returns
    ``(u, ℓ, H or None, converged, notes)``."""
    notes = []
    if len(modes) > 1:
        U = torch.stack([m[0] for m in modes])
        ll0 = exact_loglik(model, model.from_unconstrained(U, h), y, h, inputs=inputs, memory=memory)
        ll0 = np.where(np.isfinite(ll0), ll0, -np.inf)
        order = [int(i) for i in np.argsort(-ll0) if ll0[i] >= ll0.max() - EXACT_MODE_MARGIN]
        modes = [modes[i] for i in order]
    if len(modes) == 1 or gradient_supported(model, y) is not None:
        runs = [_exact_refine(model, y, h, m[0].clone(), free, inputs, memory, m[2], hessian=False) for m in modes]
    else:  # every mode's scoring iterations as one batch
        U0 = torch.stack([m[0] for m in modes])
        X, f, ok, its = _score_batch(model, y, h, U0, free, inputs, memory)
        runs = []
        for k in range(len(modes)):
            u = U0[k].clone()
            u[free] = torch.as_tensor(X[k])
            runs.append((u, -float(f[k]), None, bool(ok[k]), int(its[k])))
    best = max(range(len(runs)), key=lambda i: runs[i][1] if math.isfinite(runs[i][1]) else -math.inf)
    u, ll, _, ok, _ = runs[best]
    if best != 0:
        notes.append(f"the exact likelihood's best maximum (ℓ {ll:.2f}) came from the Whittle fit's mode number "
                     f"{best + 1} of {len(runs)}, not from its best one (exact ℓ there {runs[0][1]:.2f})")
    H = _exact_hessian(model, y, h, u, free, inputs, memory) if hessian else None
    return u, ll, H, ok, notes


#: Central-difference step of the observed information (the exact Hessian) in the unconstrained coordinates:
#: between the rounding noise of ℓ, which grows with the series (about 10⁻⁴ nats at 2.16·10⁶ samples, from the
#: integrated level's regression) and the curvature's change along the order–pole ridge. Measured standard errors of
#: fractional+white+random-walk agree within 1.5 % (2.16·10⁶ samples) and 3 % (540 000) for steps 2–5·10⁻³; 10⁻³ is
#: noise-dominated there (+14 %), 10⁻² truncation-dominated (+14 %). On 30 000 samples 10⁻³ and 3·10⁻³ agree to 1 %.
HESSIAN_STEP = 3e-3


def _fd_hessian(batch, x: np.ndarray, d: float = HESSIAN_STEP) -> np.ndarray:
    """Central-difference Hessian of ``batch`` (a function of many points at once) at ``x``, all 1 + 2p²
    points in one batch: :math:`H_{ii} = [f(x+2d e_i) - 2f(x) + f(x-2d e_i)]/4d^2`,
    :math:`H_{ij} = [f(x+d e_i+d e_j) - f(x+d e_i-d e_j) - f(x-d e_i+d e_j) + f(x-d e_i-d e_j)]/4d^2`; error
    O(d²). (The order and the pole trade along a ridge, so H is ill-conditioned — condition numbers 10³–10⁴ —
    and an O(d) forward formula, whose entries are good to 0.3 %, moved standard errors by up to 14 %.)"""
    p = len(x)
    E = np.eye(p) * d
    pairs = [(i, j) for i in range(p) for j in range(i, p)]
    pts = [x]
    for i, j in pairs:
        pts += ([x + 2 * E[i], x - 2 * E[i]] if i == j else
                [x + E[i] + E[j], x + E[i] - E[j], x - E[i] + E[j], x - E[i] - E[j]])
    f = batch(np.stack(pts))
    H = np.zeros((p, p))
    pos = 1
    for i, j in pairs:
        if i == j:
            H[i, i] = (f[pos] - 2 * f[0] + f[pos + 1]) / (4 * d * d)
            pos += 2
        else:
            H[i, j] = H[j, i] = (f[pos] - f[pos + 1] - f[pos + 2] + f[pos + 3]) / (4 * d * d)
            pos += 4
    return H


# --------------------------------------------------------------------------- uncertainty

def _intervals(model: NoiseModel, u: Tensor, H: Tensor, free: Tensor, h: float):
    """Delta-method standard errors and 95 % intervals on the unconstrained scale, mapped back."""
    idx = free.nonzero().squeeze(-1)
    se, ci, how = {}, {}, {}
    values = {n: float(x) for n, x in zip(model.names, model.as_matrix(model.from_unconstrained(u, h))[0])}
    Hf = H[idx][:, idx]
    try:
        evals = torch.linalg.eigvalsh(Hf)
        cov_u = torch.linalg.inv(Hf) if bool((evals > 0).all()) else None
    except RuntimeError:
        cov_u = None
    for n in model.names:
        se[n], ci[n], how[n] = None, None, "fixed"
    if cov_u is None:
        for n in (model.names[i] for i in idx.tolist()):
            how[n] = "observed information not positive definite: no interval"
        return values, se, ci, how

    def natural(uu):
        return model.as_matrix(model.from_unconstrained(uu.unsqueeze(0), h))[0]

    J = torch.autograd.functional.jacobian(natural, u.detach())[:, idx]  # (P, F)
    cov = J @ cov_u @ J.mT
    for k, i in enumerate(idx.tolist()):
        n = model.names[i]
        sd_u = float(torch.sqrt(cov_u[k, k]))
        se[n] = float(torch.sqrt(cov[i, i].clamp(min=0)))
        spec = model.param_spec(n)
        if spec.scale != "identity" and spec.kind != "fraction":  # (a pole: Wald on its own scale, below)
            lo_u, hi_u = u.clone(), u.clone()
            lo_u[i] -= Z95 * sd_u
            hi_u[i] += Z95 * sd_u
            a, b = float(natural(lo_u)[i]), float(natural(hi_u)[i])
            ci[n] = [min(a, b), max(a, b)]
            # (a frequency below the Nyquist frequency: the logit of its share of it)
            how[n] = f"Wald on the {spec.scale} scale"
        else:
            ci[n] = [values[n] - Z95 * se[n], values[n] + Z95 * se[n]]
            how[n] = "Wald"
        if not (math.isfinite(se[n]) and all(math.isfinite(c) for c in ci[n])):
            se[n], ci[n] = None, None
            how[n] = ("no interval: the likelihood is all but flat along it (an estimate at its bound — a variance "
                      "at zero, an order at 0 or 1 — or not identified beside the others)")
    return values, se, ci, how


def _estimates(model: NoiseModel, u: Tensor, H: Tensor | None, free: Tensor, h: float):
    """:func:`_intervals`, or, without a Hessian (``H`` None), the values alone."""
    if H is not None:
        return _intervals(model, u, H, free, h)
    vals = {n: float(x) for n, x in zip(model.names, model.as_matrix(model.from_unconstrained(u, h))[0])}
    how = {n: "not computed (intervals=False)" if f else "fixed" for n, f in zip(model.names, free.tolist())}
    return vals, {n: None for n in model.names}, {n: None for n in model.names}, how


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
        res = newton(_whittle_loss(model, wf.data.rows(rows), h), u0, free, max_iter=30, ftol=1e-9, dtol=1e-3)
        u_up[up], u_down[down] = res.u[:len(up)], res.u[len(up):]
        loss_grid[rows, kk] = res.loss
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
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    fixed = dict(fixed or {})
    unknown = set(fixed) - set(model.names)
    if unknown:
        raise ValueError(f"fixed parameters {sorted(unknown)} are not in model {model.spec!r} ({model.names})")
    for label, comp in model.components:
        comp.check_fixed(label, fixed)
    series = [np.asarray(y, dtype=np.float64) for y in series]
    gaps = [bool(np.isnan(y).any()) for y in series]
    if method == "whittle" and not model.stationary:
        moving = ", ".join(c.name for _, c in model.components if not c.stationary)
        raise ValueError(f"{moving} makes the model non-stationary: it is fitted by the exact likelihood only "
                         "(--method exact)")
    if method == "whittle" and any(gaps):
        raise ValueError("the Whittle method needs complete series; use --method exact for recordings with "
                         "missing samples")
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
            vals, se, ci, how = _intervals(model, u, H, free, h)
            for n in model.names:
                if not _stochastic(model, n) and n not in fx:
                    how[n] = "least squares before the Whittle sum: no interval"
            ll_exact = float(exact_loglik(model, vals, y_exact, h, inputs=inp, memory=memory)[0])
        else:
            free = torch.tensor([n not in fx for n in model.names])
            modes = wf.modes[s] if wf.modes else [(wf.u[s], float(wf.loglik[s]), wf.hessian[s])]
            u, ll, H, ok, more = _exact_multistart(model, y_exact, h, modes, free, inp, memory, intervals)
            notes += more
            vals, se, ci, how = _estimates(model, u, H, free, h)
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
    u, ll, H, ok, _ = _exact_refine(model, centred(model, y), h, u0, free, inputs, memory, metric,
                                    hessian=intervals)
    vals, se, ci, how = _estimates(model, u, H, free, h)
    kfree = [n for n, f in zip(model.names, free.tolist()) if f]
    return Fit(model, "exact", vals, se, ci, how, ll, ll, int(np.sum(~np.isnan(y))), kfree, ok, None, [], u, H)


#: :func:`refine_best` refines the starts whose exact ℓ is within this many nats of the best start's (besides the
#: starts it must refine), at most :data:`MAX_MODES` of them.
START_MARGIN = 10.0


def refine_best(model, y, h: float, starts: list, *, inputs: dict | None = None, fixed=(), must=(),
                memory=FIT_MEMORY, intervals: bool = False, others: int = MAX_MODES,
                tolerance: float | None = None, refine: bool = True,
                margin: float = START_MARGIN) -> tuple[Fit, list]:
    """The exact MLE of one series from several starts, the best kept: ``starts`` a list of ``(name, values)``
    (values of every parameter of ``model``; the names in ``fixed`` stay at the first start's values). The exact ℓ is
    evaluated at every start in one batch; those whose names are in ``must`` and the best ``others`` of the rest
    within ``margin`` nats (:data:`START_MARGIN`) of the best (distinct) are refined — as one batch of scoring iterations
    where the sensitivity filter applies (:func:`_score_batch`), else one after another — and the highest maximum
    kept (``tolerance``: the decrement at which a start has converged, :func:`_score_batch`). ``refine=False``:
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
        if any(float((U[i].clamp(-8, 8) - U[j].clamp(-8, 8))[free].abs().max()) <= MODE_DISTANCE for j in chosen):
            continue
        chosen.append(i)
        extra += 1
    if not refine:
        runs = [(U[i].clone(), float(ll0[i]), False) for i in chosen]
    elif gradient_supported(model, yc) is None:
        X, f, ok, _ = _score_batch(model, yc, h, U[chosen], free, inputs, memory, tolerance=tolerance)
        runs = []
        for k, i in enumerate(chosen):
            u = U[i].clone()
            u[free] = torch.as_tensor(X[k])
            runs.append((u, -float(f[k]) if f[k] < 1e300 else -math.inf, bool(ok[k])))
    else:
        runs = [(lambda r: (r[0], r[1], r[3]))(_exact_refine(model, yc, h, U[i].clone(), free, inputs, memory,
                                                                hessian=False)) for i in chosen]
    lls = [r[1] if math.isfinite(r[1]) else -math.inf for r in runs]
    b = int(np.argmax(lls))
    u, ll, ok = runs[b]
    H = _exact_hessian(model, yc, h, u, free, inputs, memory) if intervals else None
    vals, se, ci, how = _estimates(model, u, H, free, h)
    kfree = [n for n, fr in zip(model.names, free.tolist()) if fr]
    notes = []
    if len(runs) > 1:
        notes.append(f"the best of {len(runs)} starts: {points[chosen[b]][0]} (ℓ {ll:.2f}; the others "
                     + ", ".join(f"{points[i][0]} {lls[k]:.2f}" for k, i in enumerate(chosen) if k != b) + ")")
    fit = Fit(model, "exact", vals, se, ci, how, ll, ll, int(np.sum(~np.isnan(y))), kfree, ok, None, notes, u, H)
    return fit, [(points[i][0], float(ll0[i]), lls[k]) for k, i in enumerate(chosen)]

"""The exact likelihood's optimiser: the method of scoring from a batch of starts with exact gradients (the sensitivity
filter: :func:`score_batch`, the races between starts, the bounds of the logits), L-BFGS-B where the gradients do not
apply (:func:`exact_refine`), and the observed information at the maximum (:func:`exact_hessian`: from the gradients,
or by central differences of ℓ, :func:`fd_hessian`). :mod:`.mle` starts it from the Whittle fit's modes."""
from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

from .exact import exact_loglik, exact_loglik_grad, gradient_supported

__all__ = ["score_batch", "exact_refine", "exact_score", "exact_hessian", "fd_hessian", "objective", "scoring_objective",
           "information_from_gradients", "remaining", "decrement_tolerance", "MODE_DISTANCE", "HESSIAN_STEP",
           "CATCH_SAFETY", "RACE_WINDOW", "LOGIT_BOUND"]


#: Central-difference step of the exact gradient in the unconstrained coordinates. 10⁻³: on 2.16·10⁶ samples the
#: step 10⁻⁴ left gradients dominated by ℓ's rounding noise, and the refinement stopped 0.0015 nats (5 % of a
#: standard error) short of the maximum that 10⁻³ reached in six iterations; on 30 000 samples (five hidden-effect
#: cases) the two steps give the same estimates within 0.4 % of a standard error.
FD_STEP = 1e-3


#: Two Whittle optima are distinct modes when their free unconstrained coordinates differ by more than this.
MODE_DISTANCE = 0.1


def scoring_objective(model, y, h, base: Tensor, idx: np.ndarray, inputs, memory):
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


def exact_score(model, y, h, u0: Tensor, free: Tensor, inputs, memory, max_iter: int = 60, hessian: bool = True):
    """Maximise the exact likelihood over the ``free`` unconstrained coordinates from ``u0`` by the method of scoring
    with exact gradients (:func:`score_batch` from one start). Returns what :func:`exact_refine` returns; the
    Hessian is the observed information, by central differences of the exact gradients
    (:func:`information_from_gradients`)."""
    X, f, ok, iterations = score_batch(model, y, h, u0.unsqueeze(0), free, inputs, memory, max_iter)
    u = u0.clone()
    u[free] = torch.as_tensor(X[0])
    H = exact_hessian(model, y, h, u, free, inputs, memory) if hessian else None
    return u, -float(f[0]), H, bool(ok[0]), int(iterations[0])


#: The scoring iterations stop once this many accepted steps in a row each gained less than the decrement tolerance:
#: the likelihood no longer moves by what its rounding can tell (a parameter running to its bound — a variance to
#: zero, an order to 1 — keeps a constant predicted decrement along its log or logit while its real gains vanish).
STALL_STEPS = 2


#: Step lengths the scoring iterations try along each direction, as one batch of likelihood values (the longest that
#: lowers −ℓ enough is taken).
SCORING_STEPS = (1.0, 0.25, 0.0625, 0.015625)


#: A start still running is left where it is once, at its pace over the last RACE_WINDOW iterations, it cannot come
#: within RACE_MARGIN nats of a finished start's ℓ in its iterations left (:func:`score_batch`).
RACE_WINDOW, RACE_MARGIN = 5, 2.0


#: The scoring iterations keep every logit (a bounded parameter's, the pole's fraction, a frequency's share of
#: Nyquist) within ±this (:func:`score_batch`): an order within 6·10⁻⁶ of 0 or 1 is at its bound. Measured: on a
#: ramp's data, fractional+white's order bent to its bound gains 0.3 nats more at a logit of 18 and costs 42 scoring
#: iterations at a bound of 16 against 9 at 12 (bundled gy).
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
#: the metric starts learning from the gradients (:func:`score_batch`).
SLOW_RATIO = 0.5


def score_batch(model, y, h, U0: Tensor, free: Tensor, inputs, memory, max_iter: int = 60,
                 tolerance: float | None = None):
    r"""The method of scoring on the exact likelihood from K starts ``U0`` ``(K, P)`` at once: :func:`score` with the
    sensitivity filter's −ℓ, gradient and information (:func:`~.exact.exact_loglik_grad`) over the ``free``
    coordinates, the starts' likelihoods evaluated as one batch.
    ``tolerance``: the decrement (nats) at which a start has converged, instead of :func:`decrement_tolerance`'s.
    Returns the free coordinates ``(K, F)``, −ℓ ``(K,)``, converged ``(K,)`` and iterations ``(K,)``."""
    idx = free.nonzero().squeeze(-1).numpy()
    U0 = U0.detach().to(torch.float64)
    if not bool((U0[:, ~free] == U0[0, ~free]).all()):
        raise ValueError("the starts of one scoring batch share their fixed coordinates")
    exact = scoring_objective(model, y, h, U0[0].clone(), idx, inputs, memory)
    batch = objective(model, y, h, U0[0].clone(), idx, inputs, memory)
    return score(lambda points, rows: exact(points), lambda points, rows: batch(points), U0[:, idx].numpy().copy(),
                 logit_limits(model, idx), max_iter=max_iter, tolerance=tolerance)


def logit_limits(model, idx) -> np.ndarray:
    """The bound of each free coordinate ``idx`` in the scoring iterations: :data:`LOGIT_BOUND` for a logit (a
    bounded parameter's, a pole's fraction, a frequency's share of Nyquist), none for the others."""
    bounded = np.array([model.param_spec(model.names[i]).scale == "logit" for i in idx], dtype=bool)
    return np.where(bounded, LOGIT_BOUND, np.inf)


def score(vgi, values, X0: np.ndarray, lim: np.ndarray, *, max_iter: int = 60, tolerance: float | None = None,
          groups: np.ndarray | None = None, race: bool = True, margin: float | None = None, pin: bool = False,
          floor: float | None = None):
    r"""The method of scoring from K starts ``X0`` ``(K, F)`` at once. ``vgi(points, rows)`` gives −ℓ ``(k,)``, its
    gradient ``(k, F)`` and the scoring information ``(k, F, F)`` of the starts ``rows`` at ``points`` ``(k, F)``
    (+1e300, zero gradient and information where ℓ is not finite), ``values(points, rows)`` −ℓ alone; ``lim`` ``(F,)``
    the bound of each coordinate (:func:`logit_limits`).

    Directions :math:`-(\mathcal I + \mu\,\mathrm{diag}\,\mathcal I)^{-1} g`, capped at 3 in the unconstrained
    coordinates, and along each the longest of :data:`SCORING_STEPS` that lowers −ℓ by a tenth of what the
    information predicts (Armijo: the full steps of all starts in one batch of values, the shorter ones, in a second,
    only where the full one fails); each start's damping μ shrunk after a full step and grown after none
    (Levenberg–Marquardt). A start has converged when its decrement ½ gᵀ𝓘⁻¹g (the −ℓ still to gain on the
    information) is below :func:`decrement_tolerance`, or after :data:`STALL_STEPS` steps in a row that each gained
    less, or once its last :data:`FLAT_WINDOW` steps together gained less than :data:`FLAT_GAIN` with its decrement
    below that too (a crawl along a flat direction). With ``race``, a start still running is left where it is once
    it is within :data:`MODE_DISTANCE` of a finished one, below it, or once at its recent pace it cannot come within
    ``margin`` nats (default :data:`RACE_MARGIN`) of a finished one's ℓ in the iterations it has left
    (:data:`RACE_WINDOW`), or it is below a finished one and gains less per iteration than the tolerance's ten times,
    or it is less than ``margin`` below and cannot gain the gap (:data:`CATCH_SAFETY`): the batch does not wait for a
    start that cannot end higher (or within ``margin``). Without it, only the first of those: a start that has
    reached a finished one's mode.
    ``groups`` ``(K,)``: starts race only within their group (each series of a batch of several is its own).
    ``pin``: a step longer than 3 pins its long coordinates at ±3 and takes the quadratic model's step in the others
    (:func:`_pinned`) instead of shrinking every coordinate by its length.
    ``tolerance``: the decrement (nats) at which a start has converged, instead of :func:`decrement_tolerance`'s.
    Returns the coordinates ``(K, F)``, −ℓ ``(K,)``, converged ``(K,)`` and iterations ``(K,)``."""
    X = np.clip(np.asarray(X0, dtype=np.float64), -lim, lim)
    K = len(X)
    f, g, info = vgi(X, np.arange(K))
    if not X.shape[1]:  # nothing free: the likelihood where it is
        return X, f, np.ones(K, dtype=bool), np.zeros(K, dtype=int)
    b = _Batch(X, f, g, info, lim, tolerance, np.zeros(K, dtype=int) if groups is None else np.asarray(groups), race,
               RACE_MARGIN if margin is None else margin)
    b.pinning = pin
    b.floor = 1e-12 if floor is None else floor
    ts = np.array(SCORING_STEPS)
    for _ in range(max_iter):
        active = np.nonzero(~b.done)[0]
        if not len(active):
            break
        steps, decs = b.directions(active)
        conv = (decs < b.tol[active]) & (b.mu[active] <= SCORING_DAMPING[0])
        b.ok[active[conv]] = b.done[active[conv]] = True
        keep = ~conv
        active, decs = active[keep], decs[keep]
        steps = np.stack([st for st, c in zip(steps, keep) if c]) if len(active) else None
        if not len(active):
            break
        b.iterations[active] += 1
        trials, moved, pick = b.line_search(active, steps, ts, values)
        rows = active[moved]
        if len(rows):
            chosen = trials[moved, pick[moved]]
            b.accept(rows, chosen, vgi(chosen, rows), pick[moved] == 0, decs[moved])
        b.refuse(active[~moved], decs[~moved])
        b.race(active, decs, max_iter)
    return b.X, b.f, b.ok, b.iterations


class _Batch:
    """The state of :func:`score_batch`'s starts: their free coordinates ``X``, −ℓ ``f``, gradients ``g``, scoring
    information ``info``, the metric of their steps (the information, or BFGS-learnt), damping ``mu``, histories of
    −ℓ, and which have finished (``done``) and converged (``ok``)."""

    def __init__(self, X, f, g, info, lim, tolerance, groups, race, margin):
        K = len(X)
        self.X, self.f, self.g, self.info, self.lim = X, f, g, info, lim
        self.groups, self.racing, self.margin = groups, race, margin
        # the metric of each start's steps: the scoring information, until the steps converge only linearly (each
        # full step gains what the information predicts, but the prediction shrinks slowly: the information
        # overstates the curvature along some direction — the misspecified part of a model, a mean's second
        # derivatives), then BFGS-updated from the exact gradients' changes, which learn that curvature (back to the
        # information when a learnt direction fails)
        self.metric = info.copy()
        self.history = [[x] for x in f]
        self.learning = np.zeros(K, dtype=bool)
        self.slow = np.zeros(K, dtype=int)
        self.last_dec = np.full(K, np.inf)
        self.mu = np.full(K, SCORING_DAMPING[0])
        self.ok = np.zeros(K, dtype=bool)
        self.done = f >= 1e300
        self.stalls = np.zeros(K, dtype=int)
        self.iterations = np.zeros(K, dtype=int)
        self.tol = np.array([decrement_tolerance(x) if tolerance is None else tolerance for x in f])

    def directions(self, active):
        """Each active start's damped scoring step (capped at 3) and its decrement ½ gᵀ𝓘⁻¹g."""
        X, g, metric, mu, lim = self.X, self.g, self.metric, self.mu, self.lim
        steps, decs = [], []
        for k in active:
            # a logit held at its bound while the gradient pushes it further out stays there: the step is the
            # Newton step of the others (projected Newton; a step clipped at the bound afterwards points elsewhere)
            held = (np.abs(X[k]) >= lim) & (np.sign(X[k]) == -np.sign(g[k]))
            move = ~held
            step = np.zeros_like(g[k])
            d = np.diag(metric[k])[move]
            floor = self.floor * max(float(d.max()), 1e-300) if len(d) else 1.0
            A = metric[k][np.ix_(move, move)] + np.diag(mu[k] * np.maximum(d, floor) + floor)
            try:
                step[move] = -np.linalg.solve(A, g[k][move])
            except np.linalg.LinAlgError:
                step[move] = -g[k][move] / (np.maximum(d, floor) * (1 + mu[k]))
            decs.append(-0.5 * float(g[k] @ step))
            big = float(np.max(np.abs(step))) if len(step) else 0.0
            if big > 3.0 and self.pinning:
                step = _pinned(A, g[k], step, move)
            elif big > 3.0:
                step = step * (3.0 / big)
            steps.append(step)
        return steps, np.array(decs)

    def line_search(self, active, steps, ts, values):
        """The trial points along each step (lengths ``ts``), the full steps of all starts in one batch of
        likelihood values, the shorter ones only where the full one fails (Armijo); which starts moved and the
        longest good step of each."""
        X, f, g, lim = self.X, self.f, self.g, self.lim
        trials = np.clip(X[active][:, None, :] + ts[None, :, None] * steps[:, None, :], -lim, lim)  # (A, T, F)
        slope = np.einsum("af,af->a", g[active], steps)  # the directional derivative of −ℓ (negative)
        fv = np.full((len(active), len(ts)), np.inf)
        fv[:, 0] = values(trials[:, 0], active)
        retry = ~(fv[:, 0] <= f[active] + 0.1 * slope)
        if retry.any():
            fv[retry, 1:] = values(trials[retry, 1:].reshape(-1, X.shape[1]),
                                   np.repeat(active[retry], len(ts) - 1)).reshape(int(retry.sum()), len(ts) - 1)
        good = fv <= f[active][:, None] + 0.1 * ts[None, :] * slope[:, None]
        return trials, good.any(axis=1), np.argmax(good, axis=1)  # (the longest step that is good enough)

    def accept(self, rows, chosen, evaluated, full, decs):
        """The starts ``rows`` at their ``chosen`` points (``evaluated``: −ℓ, gradient and information there):
        the metric updated (the information, or a BFGS step once learning), the damping shrunk after a full step,
        a stall counted where the gain is below the tolerance. ``decs`` are the moved starts' decrements, ``decs[j]``
        that of ``rows[j]``."""
        fn, gn, In = evaluated
        X, f, g, metric, mu = self.X, self.f, self.g, self.metric, self.mu
        for j, k in enumerate(rows):
            if not fn[j] <= f[k]:  # (the two kernels' values differ by rounding: a tie at the noise)
                mu[k] *= 8.0
                continue
            gained = f[k] - fn[j]
            s_, y_ = chosen[j] - X[k], gn[j] - g[k]
            if self.learning[k]:
                sy = float(s_ @ y_)
                if sy > 1e-12 * float(np.linalg.norm(s_) * np.linalg.norm(y_)):
                    Ms = metric[k] @ s_
                    metric[k] = metric[k] - np.outer(Ms, Ms) / float(s_ @ Ms) + np.outer(y_, y_) / sy
            else:
                metric[k] = In[j]
                self.slow[k] = self.slow[k] + 1 if full[j] and decs[j] > SLOW_RATIO * self.last_dec[k] else 0
                if self.slow[k] >= 2:
                    self.learning[k] = True
            self.last_dec[k] = decs[j]
            X[k], f[k], g[k], self.info[k] = chosen[j], fn[j], gn[j], In[j]
            mu[k] = max(mu[k] / 4.0, 1e-9) if full[j] else mu[k]
            self.stalls[k] = self.stalls[k] + 1 if gained < self.tol[k] else 0
            if self.stalls[k] >= STALL_STEPS:
                self.ok[k] = self.done[k] = True

    def refuse(self, rows, decs):
        """The starts ``rows`` that found no step lowering −ℓ: converged when their decrement is at ℓ's rounding,
        back to the information when a learnt metric failed, else damped more (finished once fully damped)."""
        for j, k in enumerate(rows):
            if decs[j] < NOISE_DECREMENTS * self.tol[k]:  # nothing to gain that ℓ's rounding can tell
                self.ok[k] = self.done[k] = True
                continue
            if self.learning[k]:  # the learnt metric failed: back to the scoring information
                self.learning[k], self.slow[k], self.metric[k] = False, 0, self.info[k]
                continue
            self.mu[k] *= 8.0
            if self.mu[k] >= SCORING_DAMPING[1]:  # no step lowers −ℓ: at the rounding noise of ℓ that is convergence
                self.ok[k] = decs[j] < NOISE_DECREMENTS * self.tol[k]
                self.done[k] = True

    def race(self, active, decs, max_iter):
        """A start crawling along a flat direction is converged; one that cannot end higher than a finished start
        is left where it is (module docstring of :func:`score_batch`)."""
        X, f, done, ok, history, tol = self.X, self.f, self.done, self.ok, self.history, self.tol
        # a start heading for the maximum a finished start has reached is left there: it cannot end higher. (A start
        # far below a finished one is not: its decrement, the −ℓ it can gain where ℓ is near quadratic, says nothing
        # of how far it climbs from far away — one 184 nats below a finished start ended 2.6 nats above it.)
        # Nor is one that, at the pace of its last RACE_WINDOW iterations, cannot reach a finished start's ℓ within
        # its iterations left: a start that wanders along a flat ridge far below.
        for j, k in enumerate(active):
            history[k].append(f[k])
            if (not done[k] and len(history[k]) > FLAT_WINDOW and decs[j] < FLAT_GAIN
                    and history[k][-FLAT_WINDOW - 1] - f[k] < FLAT_GAIN):
                ok[k] = done[k] = True
        finished = np.nonzero(done & ok)[0]
        for j, k in enumerate(active):
            mine = finished[self.groups[finished] == self.groups[k]]
            if done[k] or not len(mine):
                continue
            near = any(f[k] >= f[i] and float(np.max(np.abs(np.clip(X[k], -8, 8) - np.clip(X[i], -8, 8))))
                       <= MODE_DISTANCE for i in mine)
            if not self.racing:
                done[k] = near
                continue
            top = mine[np.argmin(f[mine])]
            pace = (history[k][-RACE_WINDOW - 1] - f[k]) / RACE_WINDOW if len(history[k]) > RACE_WINDOW else np.inf
            gap = f[k] - f[top]
            behind = gap > self.margin + pace * (max_iter - self.iterations[k])
            crawling = gap > 0 and pace < NOISE_DECREMENTS * tol[k]  # below it and all but still
            caught = self.margin >= gap > CATCH_SAFETY * max(decs[j], remaining(history[k]))
            if near or behind or crawling or caught:
                done[k] = True


def _pinned(A: np.ndarray, g: np.ndarray, step: np.ndarray, move: np.ndarray) -> np.ndarray:
    """The scoring step with each coordinate beyond ±3 pinned there and the others the minimiser of the quadratic
    model ``gᵀd + ½ dᵀA d`` given the pinned ones (``A`` over the coordinates ``move``): a coordinate running off
    (a variance collapsing, whose information vanishes with it) moves by 3 while the others take their own step,
    instead of all of them shrunk by its length."""
    out = step.copy()
    where = np.nonzero(move)[0]
    pinned = np.zeros(len(where), dtype=bool)
    d = step[where]
    for _ in range(len(where)):
        over = ~pinned & (np.abs(d) > 3.0)
        if not over.any():
            break
        pinned |= over
        d = np.where(pinned, np.clip(d, -3.0, 3.0), d)
        free = ~pinned
        if free.any():
            rhs = g[where][free] + A[np.ix_(free, pinned)] @ d[pinned]
            try:
                d[free] = -np.linalg.solve(A[np.ix_(free, free)], rhs)
            except np.linalg.LinAlgError:
                return step * (3.0 / float(np.max(np.abs(step))))
    out[where] = d
    return out


def remaining(history: list) -> float:
    """What a start whose −ℓ went through ``history`` gains in all if its gains of the last :data:`RACE_WINDOW`
    iterations go on shrinking at their rate (a geometric series); ∞ while they do not shrink."""
    if len(history) <= RACE_WINDOW:
        return math.inf
    gains = -np.diff(history[-RACE_WINDOW - 1:])
    if not (gains > 0).all() or gains[-1] >= gains[0]:
        return math.inf
    r = (gains[-1] / gains[0]) ** (1.0 / (len(gains) - 1))
    return float(gains[-1] * r / (1.0 - r))


def information_from_gradients(model, y, h, u: Tensor, free: Tensor, inputs, memory) -> Tensor:
    """The observed information (the Hessian of −ℓ) at ``u`` over the ``free`` coordinates by central differences of
    the exact gradients: 2F sensitivity passes in one batch instead of the 1 + 2F² likelihood passes of
    :func:`exact_hessian`; zero rows and columns for the others ``(P, P)``."""
    idx = free.nonzero().squeeze(-1).numpy()
    vgi = scoring_objective(model, y, h, u.clone(), idx, inputs, memory)
    x = u[idx].numpy()
    p = len(idx)
    E = np.eye(p) * INFORMATION_STEP
    _, g, _ = vgi(np.concatenate([x + E, x - E]))
    H = ((g[:p] - g[p:]) / (2 * INFORMATION_STEP)).T
    H = 0.5 * (H + H.T)
    Hfull = torch.zeros(len(u), len(u), dtype=torch.float64)
    Hfull[np.ix_(idx, idx)] = torch.as_tensor(H)
    return Hfull


def _start_metric(metric: Tensor, idx, x, batch):
    """:func:`exact_refine`'s first metric: ``metric``'s block of the free coordinates ``idx``, the uncovered ones (a
    zero or non-finite diagonal) by central differences of −ℓ (``batch``) at ``x``, without cross terms; None where
    the result is not positive definite."""
    M = metric[np.ix_(idx, idx)].numpy().copy()
    missing = np.nonzero(~np.isfinite(np.diag(M)) | (np.diag(M) <= 0))[0]
    if len(missing):  # the Hessian block of the uncovered coordinates by differences; no cross terms
        M[missing, :] = 0.0
        M[:, missing] = 0.0

        def sub(points):
            full = np.repeat(x[None], len(points), 0)
            full[:, missing] = points
            return batch(full)

        Hm = fd_hessian(sub, x[missing])
        if np.all(np.isfinite(Hm)) and np.all(np.linalg.eigvalsh(Hm) > 0):
            M[np.ix_(missing, missing)] = Hm
        else:
            M[missing, missing] = np.where(np.isfinite(np.diag(Hm)) & (np.diag(Hm) > 0), np.diag(Hm), 1.0)
    if not (np.all(np.isfinite(M)) and np.all(np.linalg.eigvalsh(M) > 0)):
        return None
    return M


def exact_refine(model, y, h, u0: Tensor, free: Tensor, inputs, memory, metric: Tensor | None = None,
                  max_iter: int = 30, hessian: bool = True):
    """Maximise the exact likelihood over the ``free`` unconstrained coordinates from ``u0``: by scoring with exact
    gradients (:func:`exact_score`) where the sensitivity filter applies (:func:`~.exact.gradient_supported`), else
    as follows.

    With a positive-definite ``metric`` (the Whittle fit's Hessian of −ℓ, which approximates the exact one
    on a long series) the steps are quasi-Newton steps on it, with central-difference gradients of the
    exact −ℓ, a backtracking line search and BFGS updates of the metric: from the Whittle optimum two or
    three steps reach the exact one when the model fits, a few more when it does not (steps are capped at 1
    in the unconstrained coordinates). Free coordinates the metric does not cover (a zero or non-finite
    diagonal: mean and modifier parameters — offset, ramp, sinusoid, temperature terms — which the Whittle
    fit does not see) get their own block of the Hessian by central differences (:func:`fd_hessian`), with
    no cross terms to the others (mean and noise parameters are orthogonal in a Gaussian model). When the steps stall,
    L-BFGS-B does the work. ``converged``: the quasi-Newton decrement on the metric fell below
    :func:`decrement_tolerance` (10⁻⁶ nats up to ~50 000 samples), else L-BFGS-B's success. Returns ``(u, ℓ, Hessian of −ℓ, converged, iterations)``; the Hessian by
    central differences (:func:`fd_hessian`), or None with ``hessian=False``."""
    if gradient_supported(model, y) is None:
        return exact_score(model, y, h, u0, free, inputs, memory, hessian=hessian)
    idx = free.nonzero().squeeze(-1).numpy()
    p = len(idx)
    base = u0.clone()
    batch = objective(model, y, h, base, idx, inputs, memory)

    def fun(x):
        pts = [x] + [x + FD_STEP * e for e in np.eye(p)] + [x - FD_STEP * e for e in np.eye(p)]
        f = batch(np.stack(pts))
        g = (f[1:p + 1] - f[p + 1:]) / (2 * FD_STEP)
        return f[0], g

    x = u0[idx].numpy().copy()
    ok, iterations = False, 0
    M = None if metric is None else _start_metric(metric, idx, x, batch)
    if M is not None:
        f, g = fun(x)
        tol = decrement_tolerance(f)
        for iterations in range(1, max_iter + 1):  # noqa: B007 (the count is read after the loop)
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
    return u, -float(f), exact_hessian(model, y, h, u, free, inputs, memory), ok, iterations


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


def objective(model, y, h, base: Tensor, idx: np.ndarray, inputs, memory):
    """The exact −ℓ of many points at once, each point the free coordinates ``idx`` of ``base`` (unconstrained);
    +1e300 where ℓ is not finite."""
    def batch(points: np.ndarray) -> np.ndarray:
        U = base.repeat(points.shape[0], 1)
        U[:, idx] = torch.as_tensor(points)
        vals = model.from_unconstrained(U, h)
        ll = exact_loglik(model, vals, y, h, inputs=inputs, memory=memory)
        return np.where(np.isfinite(ll), -ll, 1e300)
    return batch


def exact_hessian(model, y, h, u: Tensor, free: Tensor, inputs, memory) -> Tensor:
    """The Hessian of the exact −ℓ at ``u`` over the ``free`` coordinates: central differences of the exact gradients
    (:func:`information_from_gradients`) where the sensitivity filter applies, else of ℓ itself
    (:func:`fd_hessian`); zero rows and columns for the others ``(P, P)``."""
    if gradient_supported(model, y) is None:
        return information_from_gradients(model, y, h, u, free, inputs, memory)
    idx = free.nonzero().squeeze(-1).numpy()
    H = fd_hessian(objective(model, y, h, u.clone(), idx, inputs, memory), u[idx].numpy().copy())
    Hfull = torch.zeros(len(u), len(u), dtype=torch.float64)
    Hfull[np.ix_(idx, idx)] = torch.as_tensor(H)
    return Hfull


#: Central-difference step of the observed information (the exact Hessian) in the unconstrained coordinates:
#: between the rounding noise of ℓ, which grows with the series (about 10⁻⁴ nats at 2.16·10⁶ samples, from the
#: integrated level's regression) and the curvature's change along the order–pole ridge. Measured standard errors of
#: fractional+white+random-walk agree within 1.5 % (2.16·10⁶ samples) and 3 % (540 000) for steps 2–5·10⁻³; 10⁻³ is
#: noise-dominated there (+14 %), 10⁻² truncation-dominated (+14 %). On 30 000 samples 10⁻³ and 3·10⁻³ agree to 1 %.
HESSIAN_STEP = 3e-3


def fd_hessian(batch, x: np.ndarray, d: float = HESSIAN_STEP) -> np.ndarray:
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

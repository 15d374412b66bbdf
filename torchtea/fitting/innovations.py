"""The model's innovations at a fit and the exact tests on them: the standardised innovations of the exact filter
(:class:`Innovations`, :func:`innovations`), regressors whitened by the same filter (:func:`whiten`), the exact
likelihood-ratio of linear mean terms (:func:`linear_lr`) and of the best of many (:func:`scan_lr`), and the intervals
the components make for their located parameters (:func:`located_intervals`). ``check``'s diagnostics and the
components' screens read them — the screens through the :class:`Innovations` they are given (its methods), so that
:mod:`torchtea.noise` imports nothing of this layer."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from ..likelihood.kalman import filter_fast
from ..noise.model import StateSpace, parse_model
from .exact import FIT_MEMORY, centred, exact_pass
from .starts import starts_of

__all__ = ["Innovations", "innovations", "whiten", "gls_statistic", "linear_lr", "scan_lr", "located_intervals",
           "whiten_with_level"]


@dataclass
class Innovations:
    """The exact filter at the fitted values: standardised innovations ``z`` (NaN where missing), the state
    space (to whiten regressors with the same gains), the fitted mean, and the exact log-likelihood."""

    z: np.ndarray
    ss: StateSpace
    mean: np.ndarray
    loglik: float
    observed: np.ndarray
    y: np.ndarray  # the series the filter saw (centred unless the model has an offset)
    #: what made it (:meth:`again` reruns the filter on another series)
    model: object = None
    values: dict | None = None
    h: float | None = None
    inputs: dict | None = None
    memory: object = FIT_MEMORY
    #: the whitened constant, once a regressor has been whitened beside it (:func:`whiten_with_level`)
    level: np.ndarray | None = field(default=None, repr=False)

    def linear_lr(self, columns: np.ndarray) -> tuple[float, np.ndarray]:
        """:func:`linear_lr` of these innovations (a component's screen reads it as ``ctx.inn.linear_lr(X)``)."""
        return linear_lr(self, columns)

    def scan_lr(self, columns: np.ndarray, **kw) -> tuple[np.ndarray, np.ndarray, float]:
        """:func:`scan_lr` of these innovations."""
        return scan_lr(self, columns, **kw)

    def again(self, y) -> Innovations:
        """The same model and values filtered on the series ``y`` (e.g. with samples set missing)."""
        return innovations(self.model, self.values, y, self.h, self.inputs, self.memory)


def innovations(model, values: dict, y, h: float, inputs: dict | None = None, memory=FIT_MEMORY) -> Innovations:
    p = exact_pass(model, values, y, h, inputs=inputs, memory=memory)
    return Innovations(p.innovation / np.sqrt(p.variance), p.ss, p.mean.numpy()[0], p.loglik, ~np.isnan(p.y), p.y,
                       model, values, h, inputs, memory)


def whiten(inn: Innovations, columns: np.ndarray) -> np.ndarray:
    """Standardised innovations ``(m, N)`` of regressor columns ``(m, N)`` through the same filter (the gains do
    not depend on the data): ``z(y − Xβ) = z(y) − Σ β_i w_i``, so GLS of ``y`` on ``X`` is least squares of ``z``
    on ``w`` — an exact likelihood-ratio for linear mean terms at the fitted noise parameters."""
    X = np.atleast_2d(np.asarray(columns, dtype=np.float64)).copy()
    X[:, ~inn.observed] = np.nan
    _, e, S = filter_fast(inn.ss.expand(X.shape[0]), X)
    return e / np.sqrt(S)


def gls_statistic(z: np.ndarray, w: np.ndarray, nuisance: np.ndarray | None = None) -> tuple[float, np.ndarray]:
    """2Δℓ of adding the linear terms whose whitened regressors are ``w`` ``(m, N)`` (least squares of z on w),
    and their coefficients. With ``nuisance`` ``(k, N)`` (whitened regressors free under both hypotheses, e.g. the
    constant): the fall of the residual sum of squares from z on ``nuisance`` to z on both; the coefficients are
    ``w``'s in the joint fit."""
    nu = np.zeros((0, z.shape[-1])) if nuisance is None else np.atleast_2d(nuisance)
    ok = np.isfinite(z) & np.isfinite(w).all(0) & np.isfinite(nu).all(0)

    def explained(X):
        if X.shape[1] == 0:
            return 0.0, np.zeros(0)
        b, *_ = np.linalg.lstsq(X, z[ok], rcond=None)
        f = X @ b
        return float(2.0 * z[ok] @ f - f @ f), b

    full, b = explained(np.concatenate([w[:, ok], nu[:, ok]]).T)
    base, _ = explained(nu[:, ok].T)
    return full - base, b[:w.shape[0]]


def linear_lr(inn: Innovations, columns: np.ndarray) -> tuple[float, np.ndarray]:
    """Exact likelihood-ratio statistic (at the filter's noise parameters) of adding linear mean terms with
    regressors ``columns`` ``(m, N)``, the level free under both hypotheses (the whitened constant as nuisance),
    and their GLS coefficients. The level matters where the model's own mean, the sample mean, is not its GLS
    estimate — a random walk, an order near 1 — and a slow regressor (a warm-up) would otherwise pick up the
    filter's start-up from the wrong level."""
    w = whiten_with_level(inn, columns)
    return gls_statistic(inn.z, w[:-1], w[-1:])


def scan_lr(inn: Innovations, columns: np.ndarray, *, draws: int = 20_000, seed: int = 0
            ) -> tuple[np.ndarray, np.ndarray, float]:
    """Exact likelihood-ratio statistics of each linear mean term of ``columns`` ``(G, N)`` alone (at the filter's
    noise parameters, the level free), their GLS coefficients, and the log p-value of their maximum under the
    model. Under the model the innovations are independent standard normal, so the G statistics are the squares
    of jointly normal scores whose correlation is the (level-projected) whitened columns' — the maximum's tail by
    ``draws`` seeded draws of them, never above the Bonferroni bound G·P(χ²₁ > max) (which takes over where no
    draw exceeds it)."""
    w = whiten_with_level(inn, columns)
    ok = np.isfinite(inn.z) & np.isfinite(w).all(0)
    c, W, z = w[-1, ok], w[:-1, ok], inn.z[ok]
    cc = float(c @ c)
    Wp = W - np.outer(W @ c, c) / cc
    zp = z - (z @ c) / cc * c
    nn = np.einsum("ij,ij->i", Wp, Wp)
    good = nn > 1e-12 * max(float(nn.max()), 1e-300)
    score = np.where(good, Wp @ zp, 0.0)
    lr = np.where(good, score ** 2 / np.where(good, nn, 1.0), 0.0)
    beta = np.where(good, score / np.where(good, nn, 1.0), 0.0)
    top = float(lr.max())
    logp = math.log(max(1, int(good.sum()))) + float(stats.chi2.logsf(top, 1))
    if good.sum() > 1 and draws > 0:  # (draws = 0: the statistics alone, the p-value by Bonferroni)
        U = Wp[good] / np.sqrt(nn[good])[:, None]
        lam, V = np.linalg.eigh(U @ U.T)
        L = V * np.sqrt(np.clip(lam, 0.0, None))
        u = np.random.default_rng(seed).standard_normal((draws, L.shape[0])) @ L.T
        hits = int(np.sum((u * u).max(1) >= top))
        logp = min(logp, math.log((hits + 1) / (draws + 1)))
    return lr, beta, min(0.0, logp)


def whiten_with_level(inn: Innovations, columns: np.ndarray) -> np.ndarray:
    """The whitened regressors ``columns`` ``(m, N)`` and, as the last row, the whitened constant (one filter pass;
    the constant's is kept in ``inn`` and not filtered again)."""
    X = np.atleast_2d(np.asarray(columns, dtype=np.float64))
    if inn.level is not None:
        return np.concatenate([whiten(inn, X), inn.level[None]])
    w = whiten(inn, np.concatenate([X, np.ones((1, X.shape[1]))]))
    inn.level = w[-1].copy()
    return w


def located_intervals(model, values: dict, y, h: float, inputs: dict | None = None) -> dict:
    """The 95 % intervals the components make for their located parameters (a step's time) at the fit ``values``:
    name → ``((lo, hi), words)`` (:meth:`~torchtea.fitting.starts.Starts.located_intervals`, given the model's
    innovations at any values as ``innovations(values)``)."""
    model = parse_model(model)
    out = {}
    for label, comp in model.components:
        if comp.located:
            out.update(starts_of(comp).located_intervals(
                comp, label, model, dict(values), np.asarray(y, dtype=np.float64), h, inputs,
                innovations=lambda v: innovations(model, v, centred(model, y), h, inputs=inputs)))
    return out

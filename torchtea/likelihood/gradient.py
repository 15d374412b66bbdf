r"""The exact log-likelihood's gradient and scoring information without finite differences: forward sensitivities.

The filter is a chain of differentiable operations on ``F, G, C, R``, the initial loading ``g0`` and the mean μ, so
carrying, beside each quantity of the Chandrasekhar recursions (:mod:`.chandrasekhar`), its derivative along every
parameter direction gives :math:`\partial e_k/\partial\theta_i` and :math:`\partial S_k/\partial\theta_i` at every
step — the filter's *sensitivity equations* (Gupta & Mehra, "Computational aspects of maximum likelihood estimation
and reduction in sensitivity function calculations", *IEEE TAC* 19(6), 1974). From them, in the same pass:

.. math::

    \frac{\partial\ell}{\partial\theta_i} = -\sum_k \Big[\frac{e_k}{S_k}\frac{\partial e_k}{\partial\theta_i}
        + \frac12\Big(1 - \frac{e_k^2}{S_k}\Big)\frac{1}{S_k}\frac{\partial S_k}{\partial\theta_i}\Big],
    \qquad
    \mathcal I_{ij} = \sum_k \Big[\frac{1}{S_k}\frac{\partial e_k}{\partial\theta_i}\frac{\partial e_k}{\partial\theta_j}
        + \frac{1}{2 S_k^2}\frac{\partial S_k}{\partial\theta_i}\frac{\partial S_k}{\partial\theta_j}\Big],

the second the information of the method of scoring for Gaussian innovations (Harvey, *Forecasting, structural time
series models and the Kalman filter*, 1989, §3.4.6, eq. 3.4.69 without its expectation) — positive semi-definite,
no second derivatives. With the level integrated out (``level=True``, the diffuse likelihood of
:func:`.kalman.kalman_filter`) the generalised-least-squares residual sum is differentiated at its minimiser (the
envelope theorem), and the information is that of the innovations less the estimated level.

The cost is about 1 + P passes of the filter for P directions, against 2P + 1 for central differences, and the
derivatives carry no differencing error. Scope: a time-invariant model (no temperature-driven order) and a complete
series (no missing samples: the factor's compression at a gap's edge is not differentiated here); the callers keep
central differences for the others.
"""
from __future__ import annotations

import numpy as np

__all__ = ["loglik_grad", "initial_factor_grad"]


def _csr_with_derivatives(F: np.ndarray, dF: np.ndarray):
    """One CSR pattern for F ``(B, n, n)`` and its derivatives ``dF`` ``(B, P, n, n)`` (the union of their non-zeros),
    F's values ``(B, nnz)``, the derivatives' ``(B, P, nnz)``, and per direction the rows where any derivative is
    non-zero (``(P, n)`` padded, with their counts ``(P,)``)."""
    mask = (F != 0).any(axis=0) | (dF != 0).any(axis=(0, 1))
    n = mask.shape[0]
    rows, cols = np.nonzero(mask)
    indptr = np.zeros(n + 1, dtype=np.int64)
    np.add.at(indptr, rows + 1, 1)
    indptr = np.cumsum(indptr)
    fvals = np.ascontiguousarray(F[:, rows, cols])
    dvals = np.ascontiguousarray(dF[:, :, rows, cols])
    P = dF.shape[1]
    moving = (dF != 0).any(axis=(0, 3))  # (P, n): direction q moves row i
    drows = np.zeros((P, n), dtype=np.int64)
    ndrows = np.zeros(P, dtype=np.int64)
    for q in range(P):
        idx = np.nonzero(moving[q])[0]
        drows[q, :len(idx)] = idx
        ndrows[q] = len(idx)
    return indptr, cols.astype(np.int64), fvals, dvals, drows, ndrows


def initial_factor_grad(F, dF, G, dG, C, R, dR, g0, dg0):
    r"""The Chandrasekhar start :math:`\delta_0 = P_1 - P_0 = L_0 M_0 L_0^T`, :math:`b_0 = P_0 C^T`,
    :math:`S_0 = C P_0 C^T + R` and their derivatives, for a complete series. With ``g0 = 0`` (every state starts at
    zero) :math:`L_0 = G`, :math:`M_0 = I` as in :func:`.chandrasekhar.initial_factor`; otherwise, with
    :math:`P_0 = g_0 g_0^T` and the first sample observed, :math:`P_0^+ = \kappa g_0 g_0^T`,
    :math:`\kappa = R/S_0`, so :math:`\delta_0 = \kappa (F g_0)(F g_0)^T + G G^T - g_0 g_0^T`: the factor
    :math:`L_0 = [F g_0, G, g_0]`, :math:`M_0 = \mathrm{diag}(\kappa, I, -1)` — written out, without the eigen-
    decomposition the value kernel compresses it with, so that it has derivatives. Shapes: F ``(B, n, n)``, dF
    ``(B, P, n, n)``, G ``(B, n, m)``, dG ``(B, P, n, m)``, C ``(B, n)``, R ``(B,)``, dR ``(B, P)``, g0 ``(B, n)``,
    dg0 ``(B, P, n)``."""
    B, n, m = G.shape
    P = dF.shape[1]
    if not (np.any(g0) or np.any(dg0)):
        L0 = np.ascontiguousarray(G)
        M0 = np.broadcast_to(np.eye(m), (B, m, m)).copy()
        return (L0, M0, np.zeros((B, n)), np.asarray(R, dtype=np.float64).copy(),
                np.ascontiguousarray(dG), np.zeros((B, P, m, m)), np.zeros((B, P, n)),
                np.ascontiguousarray(dR, dtype=np.float64))
    cg = np.einsum("bi,bi->b", C, g0)
    dcg = np.einsum("bi,bqi->bq", C, dg0)
    S0 = cg * cg + R
    dS0 = 2.0 * cg[:, None] * dcg + dR
    b0 = g0 * cg[:, None]
    db0 = dg0 * cg[:, None, None] + g0[:, None, :] * dcg[:, :, None]
    kappa = R / S0
    dkappa = dR / S0[:, None] - (R / S0 ** 2)[:, None] * dS0
    Fg = np.einsum("bij,bj->bi", F, g0)
    dFg = np.einsum("bqij,bj->bqi", dF, g0) + np.einsum("bij,bqj->bqi", F, dg0)
    L0 = np.concatenate([Fg[:, :, None], G, g0[:, :, None]], axis=2)
    dL0 = np.concatenate([dFg[..., None], dG, dg0[..., None]], axis=3)
    r = m + 2
    M0 = np.zeros((B, r, r))
    M0[:, 0, 0] = kappa
    M0[:, 1:m + 1, 1:m + 1] = np.eye(m)
    M0[:, r - 1, r - 1] = -1.0
    dM0 = np.zeros((B, P, r, r))
    dM0[:, :, 0, 0] = dkappa
    return (np.ascontiguousarray(L0), M0, np.ascontiguousarray(b0), S0, np.ascontiguousarray(dL0), dM0,
            np.ascontiguousarray(db0), np.ascontiguousarray(dS0))


def _kernel():
    try:
        from ._sensitivity import sensitivity_batch
    except ImportError as exc:  # pragma: no cover - numba is a dependency
        raise ImportError("the exact likelihood's gradient needs numba (pip install numba)") from exc
    return sensitivity_batch


def loglik_grad(F, dF, G, dG, C, R, dR, g0, dg0, y, mean=None, dmean=None, dmean_row=None, *, level: bool = False):
    """The exact log-likelihood ``(B,)``, its gradient ``(B, P)`` and the scoring information ``(B, P, P)`` of the
    series ``y`` ``(N,)`` (complete) under B parameter sets of a time-invariant state space (module docstring), from
    the matrices and their derivatives along P directions: F ``(B, n, n)``, dF ``(B, P, n, n)``, G ``(B, n, m)``, dG
    ``(B, P, n, m)``, C ``(B, n)`` (no derivative: a selector), R ``(B,)``, dR ``(B, P)``, g0 ``(B, n)``, dg0
    ``(B, P, n)``; the mean ``(1 or B, N)`` and its derivatives ``dmean`` ``(1 or B, D, N)`` along the directions
    ``dmean_row`` names (``(P,)``, −1 for a direction that does not move the mean). ``level``: as in
    :func:`.kalman.loglik_fast`."""
    f64 = lambda a: np.ascontiguousarray(np.asarray(a, dtype=np.float64))  # noqa: E731
    F, dF, G, dG, C, R, dR, g0, dg0 = map(f64, (F, dF, G, dG, C, R, dR, g0, dg0))
    y = f64(y).reshape(1, -1)
    if np.isnan(y).any():
        raise ValueError("the sensitivity filter needs a complete series (missing samples: central differences)")
    B, P = dF.shape[:2]
    N = y.shape[-1]
    mu = np.zeros((1, N)) if mean is None else f64(mean).reshape(-1, N)
    if dmean is None:
        dmu, row = np.zeros((1, 1, 1)), np.full(P, -1, dtype=np.int64)
    else:
        dmu = f64(dmean)
        dmu = dmu.reshape(-1, dmu.shape[-2], N)
        row = np.asarray(dmean_row, dtype=np.int64)
    indptr, indices, fvals, dvals, drows, ndrows = _csr_with_derivatives(F, dF)
    L0, M0, b0, S0, dL0, dM0, db0, dS0 = initial_factor_grad(F, dF, G, dG, C, R, dR, g0, dg0)
    cidx = np.nonzero((C != 0).any(axis=0))[0].astype(np.int64)
    grads = np.zeros((B, P))
    infos = np.zeros((B, P, P))
    ll = _kernel()(indptr, indices, fvals, dvals, drows, ndrows, L0, M0, b0, S0, dL0, dM0, db0, dS0, C, cidx, y, mu,
                   dmu, row, bool(level), grads, infos)
    return ll, grads, infos

r"""The exact Kalman filter of a time-invariant model in O(state) per sample: Chandrasekhar recursions.

The model of :class:`~torchtea.noise.model.StateSpace` is time-invariant (F, Q, C, R constant) unless a
``temperature-order`` makes F vary. Then the one-step covariance ``P_k`` of the exact filter changes by a matrix
of low rank from one step to the next, :math:`\delta_k = P_{k+1} - P_k = L_k M_k L_k^T`, and the filter can carry
the factor ``L`` (n × r) and the small ``M`` (r × r) instead of P (n × n) — Morf, Sidhu & Kailath (1974), "Some new
algorithms for recursive estimation in constant, linear, discrete-time systems", IEEE TAC 19(4); Kailath, Sayed &
Hassibi, *Linear Estimation* (2000), §17.3. With :math:`b_k = P_k C^T`, :math:`S_k = C b_k + R` (the innovation's
variance), :math:`u_k = L_k^T C^T`, :math:`c_k = M_k u_k`:

.. math::

    b_{k+1} = b_k + L_k c_k, \qquad S_{k+1} = S_k + u_k^T c_k,

    L_{k+1} = F\,(L_k - b_k u_k^T / S_k), \qquad M_{k+1} = M_k - c_k c_k^T / S_{k+1}

(both samples observed; checked by expanding :math:`P^+_{k+1} - P^+_k` with :math:`P^+ = P - b b^T/S`). Each
step costs r + 1 products with the sparse F and O(n r) more, against the n × n covariance update of the
textbook filter (:mod:`.kalman`'s Riccati kernel): r is the number of noise inputs (1 for ``fractional+white``).
The recursion is exact — it is the same filter, not a steady-state approximation, which would be wrong here:
the fractional state's long memory makes ``S_k`` approach its limit only algebraically (about 1/k).

A missing sample (no update at step k) changes the identity: with ``o_k`` = 1 where y_k is observed,
:math:`\delta_{k+1} = F (\delta_k - o_{k+1} b_{k+1}b_{k+1}^T/S_{k+1} + o_k b_k b_k^T/S_k) F^T`, which equals
the formula above when both are observed, keeps ``F L_k`` when neither is, and adds one column to L (with weight
``1/S_k`` or ``−1/S_{k+1}``) at each edge of a gap. After such a step the factor is compressed again (QR of L and
the eigen-decomposition of the small ``R M Rᵀ``, dropping weights below 10⁻¹³ of the largest), so gaps raise the
rank only while their effect on P lasts.

The start: ``P_0 = g0 g0ᵀ`` (zero for every model but a low-pass that filters white noise) and
:math:`\delta_0 = F P_0^+ F^T + Q - P_0`, factored once per parameter set (:func:`initial_factor`); with
``g0 = 0`` it is ``Q = G Gᵀ`` and L = G, M = I exactly.
"""
from __future__ import annotations

import numpy as np

__all__ = ["initial_factor", "DROP"]

#: Weights of the factor below this fraction of the largest are dropped when it is compressed (after a gap).
DROP = 1e-13


def initial_factor(F: np.ndarray, G: np.ndarray, C: np.ndarray, R: np.ndarray, g0: np.ndarray | None,
                   first_observed: np.ndarray):
    """``(L0 (B, n, r), M0 (B, r, r), b0 (B, n), S0 (B,))``: the factor of :math:`\\delta_0 = P_1 - P_0`, and
    :math:`b_0 = P_0 C^T`, :math:`S_0 = C P_0 C^T + R` for F ``(B, n, n)``, G ``(B, n, m)``, C ``(B, n)``, R
    ``(B,)``, the initial loading ``g0`` ``(B, n)`` (None: zero) and whether sample 0 is observed (``(B,)`` bool)."""
    B, n, m = G.shape
    if g0 is None or not np.any(g0):
        return (np.ascontiguousarray(G), np.broadcast_to(np.eye(m), (B, m, m)).copy(), np.zeros((B, n)),
                np.asarray(R, dtype=np.float64).copy())
    P0 = g0[:, :, None] * g0[:, None, :]
    b0 = np.einsum("bij,bj->bi", P0, C)
    S0 = np.einsum("bi,bi->b", C, b0) + R
    Pp = P0 - np.where(first_observed, 1.0, 0.0)[:, None, None] * b0[:, :, None] * b0[:, None, :] / S0[:, None, None]
    D = F @ Pp @ F.transpose(0, 2, 1) + G @ G.transpose(0, 2, 1) - P0
    D = 0.5 * (D + D.transpose(0, 2, 1))
    lam, V = np.linalg.eigh(D)
    big = np.abs(lam).max(axis=-1, keepdims=True)
    keep = np.abs(lam) > DROP * np.where(big > 0, big, 1.0)
    r = max(int(keep.sum(axis=-1).max()), 1)
    L0 = np.zeros((B, n, r))
    M0 = np.zeros((B, r, r))
    for b in range(B):
        idx = np.argsort(-np.abs(lam[b]))[:r]  # the r largest weights (the rest are zero to rounding)
        L0[b] = V[b][:, idx]
        M0[b] = np.diag(np.where(keep[b, idx], lam[b, idx], 0.0))
    return L0, M0, b0, S0


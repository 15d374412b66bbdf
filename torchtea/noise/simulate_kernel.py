"""The compiled loop of :func:`torchtea.noise.simulate.simulate_model` (numba), imported on first use; at module level
so that numba's on-disk cache reloads it (see :mod:`torchtea.likelihood._kernels`)."""
import numpy as np
from numba import njit, prange


@njit(cache=True, inline="always", error_model="numpy")
def varying_row(tv_T, tv_g, tv_j, tv_w, k, row):
    """Step k's row of a time-varying order from its table (:class:`~torchtea.noise.model.VaryingRow`): ``row`` is
    filled with the rows ``tv_j[k]`` and the next one mixed by the weight ``tv_w[k]``; returns the noise gain, mixed
    alike. Shared by the simulator and the likelihood's Riccati kernel (numba's cache does not see a change here
    from those modules: clear their ``__pycache__`` after editing it)."""
    j = tv_j[k]
    j1 = min(j + 1, tv_T.shape[0] - 1)
    wk = tv_w[k]
    for r in range(row.shape[0]):
        row[r] = tv_T[j, r] * (1.0 - wk) + tv_T[j1, r] * wk
    return tv_g[j] * (1.0 - wk) + tv_g[j1] * wk


#: realisations advanced together (their states side by side, so each term of F z is one contiguous loop)
LANES = 16


@njit(parallel=True, cache=True, error_model="numpy")
def simulate_batch(indptr, indices, fvals, gptr, gcol, gvals, cidx, Cs, z0s, xis, outs, states, keep, fr_i, frs,
                   tv_i, tv_Ts, tv_gs, tv_js, tv_ws, tv_col):
    """``z_{k+1} = F z_k + G ξ_k (+ fr_k in row fr_i)`` from ``z_0``, ``out[k] = C z_k``, for every (parameter set,
    realisation) pair: F and G in CSR form (``indptr/indices``, ``fvals`` ``(B, nnz)``; ``gptr/gcol``, ``gvals``
    ``(B, nnz_G)``), C's non-zero columns ``cidx`` — the zeros skipped, so each sum is the dense product's, term for
    term in the same order; ``Cs`` ``(B, n)``, ``z0s`` ``(B, R, n)``, ``xis`` ``(B, R, N, m)``, ``outs`` ``(B, R, N)``,
    ``states`` ``(B, R, N, K)`` for the ``K`` state indices ``keep``; row ``tv_i`` of F and its noise loading from the
    table of a time-varying order (``tv_i < 0``: none); ``frs`` ``(B, R, N)`` a known forcing of row ``fr_i``
    (``fr_i < 0``: none, ``(1, 1, 1)``). Realisations run :data:`LANES` at a time (each lane's arithmetic is the one
    realisation's alone), the groups in parallel."""
    B, R, N = outs.shape
    n = z0s.shape[2]
    K = keep.shape[0]
    groups = (R + LANES - 1) // LANES
    for p in prange(B * groups):
        b = p // groups
        r0 = (p % groups) * LANES
        W = min(LANES, R - r0)
        fval, gval, C = fvals[b], gvals[b], Cs[b]
        z = np.zeros((n, LANES))  # lanes past W stay zero (the last group of a batch may be short)
        for i in range(n):
            for w in range(W):
                z[i, w] = z0s[b, r0 + w, i]
        zn = np.zeros((n, LANES))
        acc = np.zeros(LANES)
        xk = np.zeros((xis.shape[3], LANES))  # step k's draws, lane by lane
        rowk = np.zeros(n)
        for k in range(N):
            for w in range(W):
                acc[w] = 0.0
            for t in range(cidx.shape[0]):
                c = C[cidx[t]]
                for w in range(W):
                    acc[w] += c * z[cidx[t], w]
            for w in range(W):
                outs[b, r0 + w, k] = acc[w]
                for j in range(K):
                    states[b, r0 + w, k, j] = z[keep[j], w]
            if k + 1 == N:
                break
            for c in range(xk.shape[0]):
                for w in range(W):
                    xk[c, w] = xis[b, r0 + w, k, c]
            gk = 0.0
            if tv_i >= 0:
                gk = varying_row(tv_Ts[b], tv_gs[b], tv_js[b], tv_ws[b], k, rowk)
            for i in range(n):
                for w in range(LANES):
                    zn[i, w] = 0.0
                if i == tv_i:
                    for r in range(n):
                        f = rowk[r]
                        for w in range(LANES):
                            zn[i, w] += f * z[r, w]
                    for w in range(LANES):
                        zn[i, w] += gk * xk[tv_col, w]
                else:
                    for t in range(indptr[i], indptr[i + 1]):
                        f = fval[t]
                        col = indices[t]
                        for w in range(LANES):
                            zn[i, w] += f * z[col, w]
                    for t in range(gptr[i], gptr[i + 1]):
                        g = gval[t]
                        col = gcol[t]
                        for w in range(LANES):
                            zn[i, w] += g * xk[col, w]
                if i == fr_i:
                    for w in range(W):
                        zn[i, w] += frs[b, r0 + w, k]
            z, zn = zn, z


def csr(F: np.ndarray):
    """One sparsity pattern for the batch (the union of the non-zeros), values per parameter set."""
    mask = (F != 0).any(axis=0)
    n = mask.shape[0]
    rows, cols = np.nonzero(mask)
    indptr = np.zeros(n + 1, dtype=np.int64)
    np.add.at(indptr, rows + 1, 1)
    indptr = np.cumsum(indptr)
    return indptr, cols.astype(np.int64), np.ascontiguousarray(F[:, rows, cols])

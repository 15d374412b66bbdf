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


@njit(cache=True, error_model="numpy")
def simulate_one(indptr, indices, fval, G, C, z0, xi, out, states, keep, fr_i, fr, tv_i, tv_T, tv_g, tv_j, tv_w,
                 tv_col):
    """``z_{k+1} = F z_k + G ξ_k (+ fr_k in row fr_i)`` from ``z_0 = z0``, ``out[k] = C z_k``, F in CSR form; row
    ``tv_i`` of F and its noise loading from the table of a time-varying order (``tv_i < 0``: none); ``fr``: a known
    forcing of row ``fr_i`` (``fr_i < 0``: none); ``states[k]`` the states ``keep`` (indices) of step k."""
    n = z0.shape[0]
    N = out.shape[0]
    m = G.shape[1]
    K = keep.shape[0]
    z = z0.copy()
    zn = np.zeros(n)
    rowk = np.zeros(n)
    for k in range(N):
        acc = 0.0
        for i in range(n):
            acc += C[i] * z[i]
        out[k] = acc
        for j in range(K):
            states[k, j] = z[keep[j]]
        if k + 1 == N:
            break
        gk = 0.0
        if tv_i >= 0:
            gk = varying_row(tv_T, tv_g, tv_j, tv_w, k, rowk)
        for i in range(n):
            acc = 0.0
            if i == tv_i:
                for r in range(n):
                    acc += rowk[r] * z[r]
                acc += gk * xi[k, tv_col]
            else:
                for t in range(indptr[i], indptr[i + 1]):
                    acc += fval[t] * z[indices[t]]
                for c in range(m):
                    acc += G[i, c] * xi[k, c]
            if i == fr_i:
                acc += fr[k]
            zn[i] = acc
        for i in range(n):
            z[i] = zn[i]


@njit(parallel=True, cache=True, error_model="numpy")
def simulate_batch(indptr, indices, fvals, Gs, Cs, z0s, xis, outs, states, keep, fr_i, frs, tv_i, tv_Ts, tv_gs, tv_js,
                   tv_ws, tv_col):
    """Every (parameter set, realisation) pair in parallel: ``fvals`` ``(B, nnz)``, ``Gs`` ``(B, n, m)``, ``Cs``
    ``(B, n)``, ``z0s`` ``(B, R, n)``, ``xis`` ``(B, R, N, m)``, ``outs`` ``(B, R, N)``, ``states`` ``(B, R, N, K)``
    for the ``K`` state indices ``keep``, the forcing ``frs`` ``(B, R, N)`` (or ``(1, 1, 1)`` when ``fr_i < 0``)."""
    B, R = outs.shape[0], outs.shape[1]
    for p in prange(B * R):
        b = p // R
        r = p % R
        simulate_one(indptr, indices, fvals[b], Gs[b], Cs[b], z0s[b, r], xis[b, r], outs[b, r], states[b, r], keep,
                     fr_i, frs[b, r] if fr_i >= 0 else frs[0, 0], tv_i, tv_Ts[b], tv_gs[b], tv_js[b], tv_ws[b], tv_col)


def csr(F: np.ndarray):
    """One sparsity pattern for the batch (the union of the non-zeros), values per parameter set."""
    mask = (F != 0).any(axis=0)
    n = mask.shape[0]
    rows, cols = np.nonzero(mask)
    indptr = np.zeros(n + 1, dtype=np.int64)
    np.add.at(indptr, rows + 1, 1)
    indptr = np.cumsum(indptr)
    return indptr, cols.astype(np.int64), np.ascontiguousarray(F[:, rows, cols])

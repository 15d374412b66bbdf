"""The compiled kernels of the exact filter (numba), imported on first use: the textbook covariance update
(:mod:`.kalman`'s Riccati filter) and the Chandrasekhar recursions (:mod:`.chandrasekhar`). They live at module
level so that numba's on-disk cache reloads them in the next process: a closure's cache key pickles its cells,
and a compiled function in a cell pickles differently in every process, so a kernel built inside a function is
compiled again by every new process (about 3 s each)."""
import math

import numpy as np
from numba import njit, prange

from ..noise.simulate_kernel import varying_row
from .chandrasekhar import DROP


@njit(cache=True, inline="always")
def level_step(sww, beta, rss, e, ew, S):
    """One observed sample of the recursive weighted least squares of the innovations e on those of the constant
    level, ew (each of variance S): the running Σ ew²/S, the level β and the residual sum Σ (e − β ew)²/S at the
    current β, updated without forming the sums (no cancellation when some S is tiny). Every exact filter calls it
    (the Riccati and Chandrasekhar kernels, the sensitivity kernel)."""
    if sww > 0.0:
        d = e - beta * ew
        rss += d * d / (S + ew * ew / sww)
        sww += ew * ew / S
        beta += (ew / S) * d / sww
    elif ew != 0.0:
        sww = ew * ew / S
        beta = e / ew
    else:
        rss += e * e / S
    return sww, beta, rss


# error_model="numpy": a zero innovation variance (white noise → 0 with a zero-variance start) gives an
# infinite or NaN log-likelihood, which the optimisers reject, instead of raising ZeroDivisionError
@njit(cache=True, fastmath=False, error_model="numpy")
def riccati_one(indptr, indices, fval, Q, C, cidx, R, y, mu, e_out, s_out, w_out, keep, tv_i, tv_T, tv_g, tv_j, tv_w,
                g0, lvl):
    n = Q.shape[0]
    N = y.shape[0]
    rowk = np.zeros(n)  # row tv_i of F at this step (a time-varying order), interpolated in its table
    tvq = 0.0
    z = np.zeros(n)
    w = np.zeros(n)  # the filter's state for the constant regressor (level profiling)
    P = np.zeros((n, n))
    for i in range(n):
        for j in range(n):
            P[i, j] = g0[i] * g0[j]
    M = np.zeros((n, n))
    Pc = np.zeros(n)
    ll = 0.0
    sww = 0.0  # Σ w²/S
    beta = 0.0  # the GLS level so far
    rss = 0.0  # Σ (e − β w)²/S at the current β, updated recursively (no cancellation when some S is tiny)
    nc = cidx.shape[0]
    for k in range(N):
        # update with y_k (C has few non-zeros: cidx)
        for i in range(n):
            acc = 0.0
            for t in range(nc):
                acc += P[i, cidx[t]] * C[cidx[t]]
            Pc[i] = acc
        S = R
        pred = mu[k]
        for t in range(nc):
            S += C[cidx[t]] * Pc[cidx[t]]
            pred += C[cidx[t]] * z[cidx[t]]
        e = y[k] - pred
        ew = 0.0
        if lvl:
            ew = 1.0
            for t in range(nc):
                ew -= C[cidx[t]] * w[cidx[t]]
        if keep:
            e_out[k] = e
            s_out[k] = S
            if lvl:
                w_out[k] = ew
        if not np.isnan(e):
            if lvl:  # recursive weighted least squares of e on w (a constant's innovations)
                ll -= 0.5 * math.log(2.0 * math.pi * S)
                sww, beta, rss = level_step(sww, beta, rss, e, ew, S)
                g = ew / S
                for i in range(n):
                    w[i] += Pc[i] * g
            else:
                ll -= 0.5 * (math.log(2.0 * math.pi * S) + e * e / S)
            g = e / S
            for i in range(n):
                z[i] += Pc[i] * g
            for i in range(n):
                a = Pc[i] / S
                for j in range(i, n):
                    v = P[i, j] - a * Pc[j]
                    P[i, j] = v
                    P[j, i] = v
        if k + 1 == N:
            break
        # predict: z = F z, P = F P Fᵀ + Q, with F in CSR form
        # row tv_i (a time-varying order) is rowk (dense) instead of its CSR row, and Q[tv_i, tv_i] tvq
        if tv_i >= 0:
            gk = varying_row(tv_T, tv_g, tv_j, tv_w, k, rowk)
            tvq = gk * gk
        znew = np.zeros(n)
        wnew = np.zeros(n)
        for i in range(n):
            acc = 0.0
            accw = 0.0
            if i == tv_i:
                for r in range(n):
                    acc += rowk[r] * z[r]
                    accw += rowk[r] * w[r]
            else:
                for t in range(indptr[i], indptr[i + 1]):
                    acc += fval[t] * z[indices[t]]
                    accw += fval[t] * w[indices[t]]
            znew[i] = acc
            wnew[i] = accw
        z = znew
        w = wnew
        for i in range(n):  # M = F P
            for j in range(n):
                M[i, j] = 0.0
            if i == tv_i:
                for r in range(n):
                    f = rowk[r]
                    if f != 0.0:
                        for j in range(n):
                            M[i, j] += f * P[r, j]
                continue
            for t in range(indptr[i], indptr[i + 1]):
                f = fval[t]
                r = indices[t]
                for j in range(n):
                    M[i, j] += f * P[r, j]
        for i in range(n):  # P = M Fᵀ + Q (symmetric: upper triangle, mirrored)
            for j in range(i, n):
                acc = Q[i, j]
                if j == tv_i:
                    if i == tv_i:
                        acc = tvq
                    for r in range(n):
                        acc += M[i, r] * rowk[r]
                else:
                    for t in range(indptr[j], indptr[j + 1]):
                        acc += M[i, indices[t]] * fval[t]
                P[i, j] = acc
                P[j, i] = acc
    if lvl:
        ll -= 0.5 * rss
        if sww > 0.0:
            ll += 0.5 * math.log(2.0 * math.pi / sww)
        if keep:
            for k in range(N):
                e_out[k] -= beta * w_out[k]
    return ll

@njit(parallel=True, cache=True, error_model="numpy")
def riccati_batch(indptr, indices, fvals, Qs, Cs, cidx, Rs, ys, mus, e_out, s_out, w_out, keep, tv_i, tv_Ts, tv_gs,
                  tv_js, tv_ws, g0s, lvl):
    B = fvals.shape[0]
    out = np.zeros(B)
    for b in prange(B):
        jy = np.int64(b) if ys.shape[0] > 1 else np.int64(0)  # one series for every set, or one each
        jm = np.int64(b) if mus.shape[0] > 1 else np.int64(0)
        out[b] = riccati_one(indptr, indices, fvals[b], Qs[b], Cs[b], cidx, Rs[b], ys[jy], mus[jm], e_out[b], s_out[b],
                             w_out[b], keep, tv_i, tv_Ts[b], tv_gs[b], tv_js[b], tv_ws[b], g0s[b], lvl)
    return out



@njit(cache=True, error_model="numpy")
def _jacobi_eigh(T, V):
    """Eigenvalues of the small symmetric ``T`` (r × r, overwritten: its diagonal ends as the eigenvalues) and
    their vectors in the columns of ``V`` — cyclic Jacobi rotations (Golub & Van Loan, *Matrix Computations*, 4th
    ed., §8.5.3) until the off-diagonal mass is below 1e-30 of the total. In the kernel instead of LAPACK's eigh:
    no BLAS call inside the parallel loop (OpenBLAS warns that it may hang under an OpenMP loop)."""
    r = T.shape[0]
    for i in range(r):
        for j in range(r):
            V[i, j] = 1.0 if i == j else 0.0
    for _sweep in range(60):
        off = 0.0
        tot = 0.0
        for i in range(r):
            for j in range(r):
                tot += T[i, j] * T[i, j]
                if i != j:
                    off += T[i, j] * T[i, j]
        if off <= 1e-30 * tot or tot == 0.0:
            return
        for p in range(r - 1):
            for q in range(p + 1, r):
                if T[p, q] == 0.0:
                    continue
                theta = (T[q, q] - T[p, p]) / (2.0 * T[p, q])
                t = (1.0 if theta >= 0.0 else -1.0) / (abs(theta) + math.sqrt(theta * theta + 1.0))
                c = 1.0 / math.sqrt(t * t + 1.0)
                s = t * c
                for k in range(r):  # T = Jᵀ T J
                    tkp, tkq = T[k, p], T[k, q]
                    T[k, p] = c * tkp - s * tkq
                    T[k, q] = s * tkp + c * tkq
                for k in range(r):
                    tpk, tqk = T[p, k], T[q, k]
                    T[p, k] = c * tpk - s * tqk
                    T[q, k] = s * tpk + c * tqk
                for k in range(r):
                    vkp, vkq = V[k, p], V[k, q]
                    V[k, p] = c * vkp - s * vkq
                    V[k, q] = s * vkp + c * vkq


@njit(cache=True, error_model="numpy")
def chandrasekhar_compress(Y, M, r):
    """The factor L M Lᵀ (L = Y[:, 2:2+r], M[:r, :r]) re-expressed as Q (orthonormal columns) times a diagonal
    weight matrix, weights below DROP of the largest dropped; returns the new rank (written in place). L = Q R by
    modified Gram–Schmidt, each column orthogonalised twice ("twice is enough", Giraud et al. 2005); a column in the
    span of the others gets a zero row of R. Then R M Rᵀ = V Λ Vᵀ (:func:`_jacobi_eigh`) and L M Lᵀ = (QV) Λ (QV)ᵀ."""
    n = Y.shape[0]
    Q = np.zeros((n, r))
    Rm = np.zeros((r, r))
    for j in range(r):
        for i in range(n):
            Q[i, j] = Y[i, 2 + j]
        norm0 = 0.0
        for i in range(n):
            norm0 += Q[i, j] * Q[i, j]
        for _ in range(2):
            for k in range(j):
                d = 0.0
                for i in range(n):
                    d += Q[i, k] * Q[i, j]
                Rm[k, j] += d
                for i in range(n):
                    Q[i, j] -= d * Q[i, k]
        norm = 0.0
        for i in range(n):
            norm += Q[i, j] * Q[i, j]
        if norm <= 1e-28 * norm0 or norm == 0.0:  # dependent on the columns before it
            for i in range(n):
                Q[i, j] = 0.0
            continue
        norm = math.sqrt(norm)
        Rm[j, j] = norm
        for i in range(n):
            Q[i, j] /= norm
    T = np.zeros((r, r))
    for i in range(r):
        for j in range(r):
            acc = 0.0
            for a in range(r):
                for b in range(r):
                    acc += Rm[i, a] * M[a, b] * Rm[j, b]
            T[i, j] = acc
    for i in range(r):
        for j in range(i + 1, r):
            v = 0.5 * (T[i, j] + T[j, i])
            T[i, j] = v
            T[j, i] = v
    V = np.zeros((r, r))
    _jacobi_eigh(T, V)
    big = 0.0
    for i in range(r):
        big = max(big, abs(T[i, i]))
    for i in range(M.shape[0]):
        for j in range(M.shape[1]):
            M[i, j] = 0.0
    k = 0
    for j in range(r):
        lam = T[j, j]
        if big > 0.0 and abs(lam) > DROP * big:
            for i in range(n):
                acc = 0.0
                for a in range(r):
                    acc += Q[i, a] * V[a, j]
                Y[i, 2 + k] = acc
            M[k, k] = lam
            k += 1
    return k


@njit(cache=True, error_model="numpy")
def chandrasekhar_one(indptr, indices, fval, L0, M0, b0, S0, C, cidx, R, y, mu, e_out, s_out, w_out, keep, lvl):
    n = b0.shape[0]
    N = y.shape[0]
    r = L0.shape[1]
    cap = r + 2
    # X holds, per state, what F multiplies in one pass: the filtered x, the filtered level regressor w, and
    # the r (+1 at a gap's edge) columns of the inner factor; Y = F X. Row-major, so a row's entries are
    # adjacent for the CSR pass.
    X = np.zeros((n, 2 + cap))
    Y = np.zeros((n, 2 + cap))
    M = np.zeros((cap, cap))
    for i in range(n):
        for j in range(r):
            Y[i, 2 + j] = L0[i, j]  # Y's columns 2.. hold the current factor L
    M[:r, :r] = M0
    b = b0.copy()
    S = S0
    u = np.zeros(cap)
    c = np.zeros(cap)
    nc = cidx.shape[0]
    cv = np.zeros(nc)
    for t in range(nc):
        cv[t] = C[cidx[t]]
    ll = 0.0
    sww = 0.0
    beta = 0.0
    rss = 0.0
    for k in range(N):
        pred = mu[k]
        ew = 1.0
        for t in range(nc):
            pred += cv[t] * Y[cidx[t], 0]
            ew -= cv[t] * Y[cidx[t], 1]
        e = y[k] - pred
        if not lvl:
            ew = 0.0
        if keep:
            e_out[k] = e
            s_out[k] = S
            if lvl:
                w_out[k] = ew
        obs = not np.isnan(e)
        g = 0.0
        gw = 0.0
        if obs:
            if lvl:  # recursive weighted least squares of e on w, as the Riccati kernel
                ll -= 0.5 * np.log(2.0 * np.pi * S)
                sww, beta, rss = level_step(sww, beta, rss, e, ew, S)
                gw = ew / S
            else:
                ll -= 0.5 * (np.log(2.0 * np.pi * S) + e * e / S)
            g = e / S
        if k + 1 == N:
            break
        # the covariance's low-rank step: u = Lᵀ Cᵀ, c = M u, S_{k+1} = S_k + uᵀ c
        for j in range(r):
            acc = 0.0
            for t in range(nc):
                acc += cv[t] * Y[cidx[t], 2 + j]
            u[j] = acc
        S_next = S
        for i in range(r):
            acc = 0.0
            for j in range(r):
                acc += M[i, j] * u[j]
            c[i] = acc
            S_next += u[i] * acc
        obs_next = not np.isnan(y[k + 1])
        grow = obs != obs_next
        if grow and r + 1 > cap:
            cap2 = 2 * cap
            X2 = np.zeros((n, 2 + cap2))
            Y2 = np.zeros((n, 2 + cap2))
            M2 = np.zeros((cap2, cap2))
            Y2[:, :2 + cap] = Y
            M2[:cap, :cap] = M
            X, Y, M = X2, Y2, M2
            u2 = np.zeros(cap2)
            c2 = np.zeros(cap2)
            u2[:cap] = u
            c2[:cap] = c
            u, c = u2, c2
            cap = cap2
        both = obs and obs_next
        rr = r + 1 if grow else r
        for i in range(n):
            bi = b[i]
            X[i, 0] = Y[i, 0] + bi * g
            X[i, 1] = Y[i, 1] + bi * gw
            s = bi / S
            acc = 0.0
            for j in range(r):
                lij = Y[i, 2 + j]
                acc += lij * c[j]
                X[i, 2 + j] = lij - s * u[j] if both else lij
            if grow and obs:  # + b_k b_kᵀ / S_k
                X[i, 2 + r] = bi
            b[i] = bi + acc  # b_{k+1} = b_k + L c
            if grow and not obs:  # − b_{k+1} b_{k+1}ᵀ / S_{k+1}
                X[i, 2 + r] = b[i]
        if both:
            for i in range(r):
                for j in range(r):
                    M[i, j] -= c[i] * c[j] / S_next
        elif grow:
            for i in range(r):
                M[i, r] = 0.0
                M[r, i] = 0.0
            M[r, r] = 1.0 / S if obs else -1.0 / S_next
        # Y = F X, one pass over the sparse rows. Up to four columns (x, w and a factor of rank ≤ 2: every model
        # without a gap's edge but one with three noise inputs) in four scalar accumulators, which the compiler keeps
        # in registers: 2.4× faster than the loop over columns, and the same sums in the same order
        cols = 2 + rr
        if cols <= 4:
            for i in range(n):
                a0 = 0.0
                a1 = 0.0
                a2 = 0.0
                a3 = 0.0
                for t in range(indptr[i], indptr[i + 1]):
                    f = fval[t]
                    a = indices[t]
                    a0 += f * X[a, 0]
                    a1 += f * X[a, 1]
                    a2 += f * X[a, 2]  # X has at least five columns: a column past cols holds stale numbers,
                    a3 += f * X[a, 3]  # summed but not stored
                Y[i, 0] = a0
                Y[i, 1] = a1
                if cols > 2:
                    Y[i, 2] = a2
                if cols > 3:
                    Y[i, 3] = a3
        else:
            for i in range(n):
                for j in range(cols):
                    Y[i, j] = 0.0
                for t in range(indptr[i], indptr[i + 1]):
                    f = fval[t]
                    a = indices[t]
                    for j in range(cols):
                        Y[i, j] += f * X[a, j]
        S = S_next
        r = rr
        if grow:
            r = chandrasekhar_compress(Y, M, r)
            if r == 0:  # P stopped changing altogether: keep one zero column
                r = 1
    if lvl:
        ll -= 0.5 * rss
        if sww > 0.0:
            ll += 0.5 * np.log(2.0 * np.pi / sww)
        if keep:
            for k in range(N):
                e_out[k] -= beta * w_out[k]
    return ll

@njit(parallel=True, cache=True, error_model="numpy")
def chandrasekhar_batch(indptr, indices, fvals, L0s, M0s, b0s, S0s, Cs, cidx, Rs, ys, mus, e_out, s_out, w_out, keep, lvl):
    B = fvals.shape[0]
    out = np.zeros(B)
    for i in prange(B):
        jy = np.int64(i) if ys.shape[0] > 1 else np.int64(0)  # one series for every set, or one each
        jm = np.int64(i) if mus.shape[0] > 1 else np.int64(0)
        out[i] = chandrasekhar_one(indptr, indices, fvals[i], L0s[i], M0s[i], b0s[i], S0s[i], Cs[i], cidx, Rs[i],
                                   ys[jy], mus[jm],
                     e_out[i], s_out[i], w_out[i], keep, lvl)
    return out

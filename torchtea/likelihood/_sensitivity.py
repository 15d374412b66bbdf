"""The compiled forward-sensitivity kernel of the exact filter (numba), imported on first use: the Chandrasekhar
recursions of :mod:`.chandrasekhar` carried together with their derivatives along P directions, giving the exact
log-likelihood, its gradient and the scoring information in one pass (:mod:`.gradient` says what it computes and
where it comes from). At module level for numba's on-disk cache (see :mod:`._kernels`)."""
import math

import numpy as np
from numba import njit, prange

from ._kernels import level_step


@njit(cache=True, error_model="numpy")
def sensitivity_one(indptr, indices, fval, dval, drows, ndrows, L0, M0, b0, S0, dL0, dM0, db0, dS0, C, cidx,
                    y, mu, dmu, dmu_row, lvl, grad, info):
    """One parameter set: returns ℓ and writes ``grad`` ``(P,)`` and ``info`` ``(P, P)``. ``fval`` F's values on the
    CSR pattern ``indptr/indices``; ``dval`` ``(P, nnz)`` the derivatives of F's entries on the same pattern, non-zero
    only in the rows ``drows[q, :ndrows[q]]``; ``L0 (n, r), M0 (r, r), b0 (n,), S0`` the covariance factor's start and
    ``dL0 (P, n, r), dM0 (P, r, r), db0 (P, n), dS0 (P,)`` their derivatives (the measurement noise R enters through ``S0``); the series ``y``
    (complete), its mean ``mu`` and the mean's derivatives ``dmu`` (rows ``dmu_row[q]``, −1 where direction q does not
    move the mean); ``lvl``: the level integrated out (the diffuse likelihood of :func:`.kalman.kalman_filter`)."""
    n = b0.shape[0]
    N = y.shape[0]
    r = L0.shape[1]
    P = dS0.shape[0]
    W = 2 + r  # columns of one block: the predicted state z, the level regressor's w, the factor L
    K = (1 + P) * W  # block 0 the values, block q + 1 the derivatives along direction q
    X = np.zeros((n, K))
    Y = np.zeros((n, K))
    for i in range(n):
        for j in range(r):
            Y[i, 2 + j] = L0[i, j]
            for q in range(P):
                Y[i, (q + 1) * W + 2 + j] = dL0[q, i, j]
    M = M0.copy()
    dM = dM0.copy()
    b = b0.copy()
    db = db0.copy()
    S = S0
    dS = dS0.copy()
    dSn = np.zeros(P)
    u = np.zeros(r)
    c = np.zeros(r)
    du = np.zeros((P, r))
    dc = np.zeros((P, r))
    de = np.zeros(P)
    dew = np.zeros(P)
    dg = np.zeros(P)
    dgw = np.zeros(P)
    nc = cidx.shape[0]
    cv = np.zeros(nc)
    for t in range(nc):
        cv[t] = C[cidx[t]]
    ll = 0.0
    sww = 0.0
    beta = 0.0
    rss = 0.0
    # the level's sums (lvl): Σ e²/S, Σ e w/S, Σ w²/S differentiated, and the information's three parts
    dA = np.zeros(P)
    dB = np.zeros(P)
    dCw = np.zeros(P)
    Iee = np.zeros((P, P))
    Iew = np.zeros((P, P))
    Iww = np.zeros((P, P))
    for q in range(P):
        grad[q] = 0.0
        for s in range(P):
            info[q, s] = 0.0
    for k in range(N):
        pred = mu[k]
        ew = 1.0
        for t in range(nc):
            pred += cv[t] * Y[cidx[t], 0]
            ew -= cv[t] * Y[cidx[t], 1]
        e = y[k] - pred
        if not lvl:
            ew = 0.0
        for q in range(P):
            o = (q + 1) * W
            a0 = 0.0
            a1 = 0.0
            for t in range(nc):
                a0 -= cv[t] * Y[cidx[t], o]
                a1 -= cv[t] * Y[cidx[t], o + 1]
            if dmu_row[q] >= 0:
                a0 -= dmu[dmu_row[q], k]
            de[q] = a0
            dew[q] = a1 if lvl else 0.0
        # ℓ, its gradient and the scoring information (Harvey 1989, §3.4.6: Σ ∂e ∂eᵀ/S + ½ ∂S ∂Sᵀ/S²)
        iS = 1.0 / S
        iS2 = iS * iS
        for q in range(P):
            grad[q] -= 0.5 * dS[q] * iS
            for s in range(q, P):
                v = 0.5 * dS[q] * dS[s] * iS2
                info[q, s] += v
        if lvl:
            ll -= 0.5 * math.log(2.0 * math.pi * S)
            sww, beta, rss = level_step(sww, beta, rss, e, ew, S)
            for q in range(P):
                dA[q] += 2.0 * e * de[q] * iS - e * e * dS[q] * iS2
                dB[q] += (de[q] * ew + e * dew[q]) * iS - e * ew * dS[q] * iS2
                dCw[q] += 2.0 * ew * dew[q] * iS - ew * ew * dS[q] * iS2
                for s in range(P):
                    Iew[q, s] += de[q] * dew[s] * iS
                for s in range(q, P):
                    Iee[q, s] += de[q] * de[s] * iS
                    Iww[q, s] += dew[q] * dew[s] * iS
        else:
            ll -= 0.5 * (math.log(2.0 * math.pi * S) + e * e * iS)
            for q in range(P):
                grad[q] += 0.5 * e * e * dS[q] * iS2 - e * de[q] * iS
                for s in range(q, P):
                    info[q, s] += de[q] * de[s] * iS
        g = e * iS
        gw = ew * iS
        for q in range(P):
            dg[q] = de[q] * iS - e * dS[q] * iS2
            dgw[q] = dew[q] * iS - ew * dS[q] * iS2
        if k + 1 == N:
            break
        # the covariance's low-rank step (Morf, Sidhu & Kailath 1974), and its derivative along each direction
        for j in range(r):
            acc = 0.0
            for t in range(nc):
                acc += cv[t] * Y[cidx[t], 2 + j]
            u[j] = acc
            for q in range(P):
                o = (q + 1) * W
                acc = 0.0
                for t in range(nc):
                    acc += cv[t] * Y[cidx[t], o + 2 + j]
                du[q, j] = acc
        S_next = S
        for i in range(r):
            acc = 0.0
            for j in range(r):
                acc += M[i, j] * u[j]
            c[i] = acc
            S_next += u[i] * acc
        for q in range(P):
            acc_s = dS[q]
            for i in range(r):
                acc = 0.0
                for j in range(r):
                    acc += dM[q, i, j] * u[j] + M[i, j] * du[q, j]
                dc[q, i] = acc
                acc_s += du[q, i] * c[i] + u[i] * acc
            dSn[q] = acc_s
        for i in range(n):
            bi = b[i]
            s_ = bi * iS
            X[i, 0] = Y[i, 0] + bi * g
            X[i, 1] = Y[i, 1] + bi * gw
            acc = 0.0
            for j in range(r):
                lij = Y[i, 2 + j]
                acc += lij * c[j]
                X[i, 2 + j] = lij - s_ * u[j]
            for q in range(P):
                o = (q + 1) * W
                dbi = db[q, i]
                ds = dbi * iS - bi * dS[q] * iS2
                X[i, o] = Y[i, o] + dbi * g + bi * dg[q]
                X[i, o + 1] = Y[i, o + 1] + dbi * gw + bi * dgw[q]
                accd = 0.0
                for j in range(r):
                    accd += Y[i, o + 2 + j] * c[j] + Y[i, 2 + j] * dc[q, j]
                    X[i, o + 2 + j] = Y[i, o + 2 + j] - ds * u[j] - s_ * du[q, j]
                db[q, i] = dbi + accd
            b[i] = bi + acc
        iSn = 1.0 / S_next
        for q in range(P):
            for i in range(r):
                for j in range(r):
                    dM[q, i, j] -= (dc[q, i] * c[j] + c[i] * dc[q, j]) * iSn - c[i] * c[j] * dSn[q] * iSn * iSn
        for i in range(r):
            for j in range(r):
                M[i, j] -= c[i] * c[j] * iSn
        # Y = F X for every block, then + dF_q X₀ in block q + 1 (dF_q's few non-zero rows)
        for i in range(n):
            for j in range(K):
                Y[i, j] = 0.0
            for t in range(indptr[i], indptr[i + 1]):
                f = fval[t]
                a = indices[t]
                for j in range(K):
                    Y[i, j] += f * X[a, j]
        for q in range(P):
            o = (q + 1) * W
            for m in range(ndrows[q]):
                i = drows[q, m]
                for t in range(indptr[i], indptr[i + 1]):
                    f = dval[q, t]
                    if f != 0.0:
                        a = indices[t]
                        for j in range(W):
                            Y[i, o + j] += f * X[a, j]
        S = S_next
        for q in range(P):
            dS[q] = dSn[q]
    if lvl:
        ll -= 0.5 * rss
        if sww > 0.0:
            ll += 0.5 * math.log(2.0 * math.pi / sww)
            for q in range(P):
                # rss = min_c Σ (e − c w)²/S at ĉ = β (its derivative at fixed ĉ: the envelope theorem)
                grad[q] -= 0.5 * (dA[q] - 2.0 * beta * dB[q] + beta * beta * dCw[q]) + 0.5 * dCw[q] / sww
        for q in range(P):
            for s in range(q, P):
                info[q, s] += Iee[q, s] - beta * (Iew[q, s] + Iew[s, q]) + beta * beta * Iww[q, s]
    for q in range(P):
        for s in range(q + 1, P):
            info[s, q] = info[q, s]
    return ll


@njit(parallel=True, cache=True, error_model="numpy")
def sensitivity_batch(indptr, indices, fvals, dvals, drows, ndrows, L0s, M0s, b0s, S0s, dL0s, dM0s, db0s, dS0s, Cs,
                      cidx, ys, mus, dmus, dmu_row, lvl, grads, infos):
    """:func:`sensitivity_one` for B parameter sets in parallel (the series ``ys``/``mus``/``dmus``: one for every
    set, or one each)."""
    B = fvals.shape[0]
    out = np.zeros(B)
    for i in prange(B):
        jy = np.int64(i) if ys.shape[0] > 1 else np.int64(0)
        jm = np.int64(i) if mus.shape[0] > 1 else np.int64(0)
        jd = np.int64(i) if dmus.shape[0] > 1 else np.int64(0)
        out[i] = sensitivity_one(indptr, indices, fvals[i], dvals[i], drows, ndrows, L0s[i], M0s[i], b0s[i], S0s[i],
                                 dL0s[i], dM0s[i], db0s[i], dS0s[i], Cs[i], cidx, ys[jy], mus[jm],
                                 dmus[jd], dmu_row, lvl, grads[i], infos[i])
    return out

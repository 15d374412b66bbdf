"""The compiled kernel of :mod:`.fast` (numba), imported on first use: the torch step (:func:`.tea._tea_step`)
for the scalar structure, written as one scalar twin per function of that step (``sigma_points`` for
``unscented.sigma_points``, …, ``guard`` for ``tea._guard``; ``mean_sums``, ``kfx_sums`` and ``push`` for the
memory's methods), which :func:`advance` calls in the torch step's order. tests/test_fast_twins.py checks each twin against its torch
function on the same inputs and that order; the numerics inside the twins (``vexp``, ``tails3``, …) are checked
through them.

The functions live at module level so that numba's on-disk cache can reload them: a closure's cache key pickles
the closure's cells, which for other compiled functions differ from process to process."""
import math

import numpy as np
from numba import njit, prange

pi = math.pi


@njit(cache=True, fastmath={"contract"})
def lagf(la, order, lb):
    """The GL recursion factor ``la + order·lb`` fused into one multiply-add, as torch.addcmul computes it
    (gl.gl_tail_coefficients), so that both engines round alike."""
    return la + order * lb


@njit(cache=True, inline="always")
def rgn(a):  # 1/Γ(−a) by reflection (memory._recip_gamma_neg)
    return -math.sin(pi * a) * math.exp(math.lgamma(1.0 + a)) / pi


@njit(cache=True, fastmath={"contract"})
def vexp(x, out, ib, fb, M):
    """``out[:M] = exp(x[:M])`` in two loops that the compiler vectorises (libm's exp is a call per value):
    Cody–Waite reduction ``x = k ln2 + r``, |r| ≤ ln2/2, the Taylor polynomial of degree 13 (truncation
    < 5e−18), and 2^k built in the exponent bits of ``ib`` (``fb`` is ``ib`` viewed as float64). Within 2.3
    ulp of libm's exp over [−708, 709] (measured on 5·10⁵ points); below −708 it gives e^−708 (2.2e−308·1.5),
    which no sum here can tell from 0. fastmath only lets mul+add contract into fused multiply-adds."""
    for i in range(M):
        xi = min(max(x[i], -708.0), 709.0)
        kf = (xi * 1.4426950408889634 + 6755399441055744.0) - 6755399441055744.0  # round to nearest
        r = (xi - kf * 6.93147180369123816490e-01) - kf * 1.90821492927058770002e-10
        p = 1.0 / 6227020800.0
        p = p * r + 1.0 / 479001600.0
        p = p * r + 1.0 / 39916800.0
        p = p * r + 1.0 / 3628800.0
        p = p * r + 1.0 / 362880.0
        p = p * r + 1.0 / 40320.0
        p = p * r + 1.0 / 5040.0
        p = p * r + 1.0 / 720.0
        p = p * r + 1.0 / 120.0
        p = p * r + 1.0 / 24.0
        p = p * r + 1.0 / 6.0
        p = p * r + 0.5
        p = p * r + 1.0
        out[i] = p * r + 1.0
        ib[i] = (np.int64(kf) + 1023) << 52
    for i in range(M):
        out[i] *= fb[i]


@njit(cache=True, fastmath={"reassoc", "contract"})
def dot(a, b, M):
    """Σ_{n<M} a_n b_n, reassociated so that the compiler vectorises it (the order of the additions is not the
    sequential one: the result differs from a plain loop in the last bits)."""
    s = 0.0
    for n in range(M):
        s += a[n] * b[n]
    return s


@njit(cache=True, fastmath={"reassoc", "contract"})
def dot3(E, m, D, Di, M):
    """(Σ E·m, Σ E·m·D, Σ E·m·Di) over n < M, vectorised as :func:`dot`."""
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    for n in range(M):
        e0 = E[n] * m[n]
        s0 += e0
        s1 += e0 * D[n]
        s2 += e0 * Di[n]
    return s0, s1, s2


@njit(cache=True, inline="always")
def tail(order, modes, ka, kb, eta, klo, khi, arg, E, ib, fb):
    """Σ_n W_n(order) modes_n (SOEKernel.tail_sums) for one order; ``arg, E, ib, fb``: scratch of ``modes``' size."""
    al = min(max(order, klo), khi)
    M = modes.shape[0]
    for n in range(M):
        arg[n] = ka[n] + al * kb[n]
    vexp(arg, E, ib, fb, M)
    s = dot(E, modes, M - 1)
    s += E[M - 1] * (1.0 / math.expm1((1.0 + al) * eta)) * modes[M - 1]
    return s * (math.sin(pi * al) * (-1.0 / pi))


@njit(cache=True, inline="always")
def tails3(al, ro, modes, ka, kb, kbig, eta, klo, khi, out, arg, E, Ec, have, D, Di, ib, fb):
    """``tail`` at the three KFo sigma orders ``al, al + ro, al − ro`` into ``out``. When none is clamped,
    exp(a + (al ± ro) b) = exp(a + al b) · exp(±ro b) (``kbig``: max |b| of the explicit modes, which bounds
    the factor), in two vectorised passes of exponentials; ``have``: ``Ec`` already holds exp(a + al b) (the
    previous step's KFx evaluated its tail at this order), else it is computed into ``E``."""
    M = modes.shape[0]
    if al - ro < klo or al + ro > khi or ro * kbig > 300.0:
        out[0] = tail(al, modes, ka, kb, eta, klo, khi, arg, E, ib, fb)
        out[1] = tail(al + ro, modes, ka, kb, eta, klo, khi, arg, E, ib, fb)
        out[2] = tail(al - ro, modes, ka, kb, eta, klo, khi, arg, E, ib, fb)
        return
    if have:
        E = Ec
    else:
        for n in range(M - 1):
            arg[n] = ka[n] + al * kb[n]
        vexp(arg, E, ib, fb, M - 1)
    for n in range(M - 1):
        arg[n] = ro * kb[n]
    vexp(arg, D, ib, fb, M - 1)
    for n in range(M - 1):
        Di[n] = 1.0 / D[n]
    s0, s1, s2 = dot3(E, modes, D, Di, M - 1)
    for i in range(3):
        o = al if i == 0 else (al + ro if i == 1 else al - ro)
        last = math.exp(ka[M - 1] + o * kb[M - 1]) * (1.0 / math.expm1((1.0 + o) * eta)) * modes[M - 1]
        sm = s0 if i == 0 else (s1 if i == 1 else s2)
        out[i] = (sm + last) * (math.sin(pi * o) * (-1.0 / pi))


@njit(cache=True, inline="always")
def exact_sums3(so, xh, k, la, lb, out):
    """Σ_{j=1..k} c_j(σ) x_{k−j} for the three sigma orders in one pass over the history (chronological);
    the recursion factor (1 − 1/j) + σ(−1/j) from the tables ``la``, ``lb`` (gl.lag_constants)."""
    c0 = c1 = c2 = 1.0
    s0 = s1 = s2 = 0.0
    o0, o1, o2 = so[0], so[1], so[2]
    for j in range(1, k + 1):
        xv = xh[k - j]
        c0 *= lagf(la[j], o0, lb[j])
        c1 *= lagf(la[j], o1, lb[j])
        c2 *= lagf(la[j], o2, lb[j])
        s0 += c0 * xv
        s1 += c1 * xv
        s2 += c2 * xv
    out[0], out[1], out[2] = s0, s1, s2


@njit(cache=True, inline="always")
def window_sum(order, win, J, la, lb):
    """Σ_{j=1..J} c_j(order) win_{j−1} (window newest first); recursion factors from the lag tables."""
    c = 1.0
    s = 0.0
    for j in range(1, J + 1):
        c *= lagf(la[j], order, lb[j])
        s += c * win[j - 1]
    return s


@njit(cache=True, inline="always")
def push_front(row, n, v):
    """``row[:n]`` becomes ``v, row[0], …, row[n−2]`` (a window, newest first)."""
    for j in range(n - 1, 0, -1):
        row[j] = row[j - 1]
    row[0] = v


# --------------------------------------------------------------------------- the step's functions
# Each function below is the scalar twin of one function of the torch step (its docstring names it; the names
# are the torch ones without the underscore). tests/test_fast.py checks every twin against its torch function on
# the same inputs, and that `advance` calls them in the order `tea._tea_step` calls theirs.


@njit(cache=True, inline="always")
def psd(v):
    return 0.0 if v < 0.0 else v  # NaN stays NaN (as torch's clamp), so the guard sees it


@njit(cache=True, inline="always")
def sigma_points(mean, prior_cov, scale, out):
    """Sigma points (15)/(40) of a scalar filter (unscented.sigma_points): ``mean, mean + r, mean − r`` into ``out``
    with ``r = √(scale · prior_cov)``; returns ``r``."""
    r = math.sqrt(psd(scale * prior_cov))
    out[0], out[1], out[2] = mean, mean + r, mean - r
    return r


@njit(cache=True, inline="always")
def mean_sums(kind, so, ro, k, xh, la, lb, win, xl, modes, ka, kb, kbig, eta, klo, khi, have, Ex, arg, E, D, Di, ib, fb,
              out):
    """Σ_j c_j(σᵢ) x̂_{k−j} at KFo's three sigma orders ``so = (α, α + ro, α − ro)`` into ``out`` (the memory's
    ``mean_sums``, which tea._replica calls; here the loop calls it just before :func:`replica`): ``kind`` 0 the
    whole past ``xh`` (chronological), 1 the window ``win`` (newest first, ``xl`` lags) plus the exponential sums of
    ``modes``, 2 the window alone. ``have``: ``Ex`` holds exp(a + α b) already (:func:`tails3`); ``arg … fb``:
    scratch of the modes' size, one by one (passed as a tuple they cost the loop ~5 %, experiments/bench/README.md)."""
    if kind == 0:
        exact_sums3(so, xh, k, la, lb, out)
        return
    if kind == 1:
        tails3(so[0], ro, modes, ka, kb, kbig, eta, klo, khi, out, arg, E, Ex, have, D, Di, ib, fb)
    for i in range(3):
        s = window_sum(so[i], win, xl, la, lb)
        out[i] = s + out[i] if kind == 1 else s


@njit(cache=True, inline="always")
def replica(so, sw, w, x, up, h, ms, Y):
    """The model replica (16)–(18), (41)–(42) (tea._replica), scalar ``A(w) = w``, ``B = C = 1``: KFo's sigma orders
    ``so`` with ŵ_{k−1} into ``Y[0:3]``, KFw's sigma parameters ``sw`` at KFo's centre order into ``Y[3:6]``,
    from the history sums ``ms`` at ``so`` (:func:`mean_sums`)."""
    hp = h ** so[0]  # the centre order's, which KFw's points share
    Y[0] = hp * (w * x + up) - ms[0]
    for i in range(1, 3):
        Y[i] = h ** so[i] * (w * x + up) - ms[i]
    for j in range(3):
        Y[3 + j] = hp * (sw[j] * x + up) - ms[0]


@njit(cache=True, inline="always")
def ut_update(Y, off, pts, mean, Pt, wm, wc, start, R, obs, yv):
    """Unscented update (19)–(24) of one scalar filter (unscented.ut_update): sigma points ``pts``, their predicted
    outputs ``Y[off:off+3]``; returns (mean, covariance, gain, innovation, Pyy, Pxy)."""
    yp = wm[0] * Y[off] + wm[1] * Y[off + 1] + wm[2] * Y[off + 2]
    Pyy = 0.0
    Pxy = 0.0
    for i in range(start, 3):
        dy = Y[off + i] - yp
        wd = dy * wc[i]
        Pyy += wd * dy
        Pxy += (pts[i] - mean) * wd
    Pyy += R
    K = Pxy / Pyy if obs else 0.0
    e = yv - yp if obs else 0.0
    return mean + K * e, psd(Pt - K * Pyy * K), K, e, Pyy, Pxy


@njit(cache=True, inline="always")
def adapt_q(Q, K, e, delta, qmax, obs):
    """Robbins–Monro adaptation (25) with its cap (unscented.adapt_q), scalar."""
    if delta == 0.0:
        return Q
    Ke = K * e
    Qn = (1.0 - delta) * Q + delta * (Ke * Ke)
    Qn = Qn * min(qmax / max(Qn, 2.2250738585072014e-308), 1.0)
    return Qn if obs else Q


@njit(cache=True, inline="always")
def kfx_sums(kind, gain, a, k, xh, Ph, Pgh, la, lb, win, xl, pl, Pwin, Pwin_g, H, Phead, Phead_g, modes, ka, kb, eta,
             klo, khi, arg, Ex, ib, fb):
    """KFx's history sums at its order ``a`` (the memory's ``kfx_sums``): ``(Σ_j c_j x̂_{k−j}, Σ_{j≥2} c_j² P_{k−j},
    the same over the gain's covariances)``. ``kind`` as in :func:`mean_sums`; the bounded kinds keep ``pl``
    covariances newest first (``Pwin``), and ``soe`` the start-up covariances ``Phead`` (``H``) and the coefficient
    mass of the lags in between. ``Ex`` receives exp(a + a b), which the next step's KFo reuses."""
    mean = 0.0
    cov = 0.0
    covg = 0.0
    if kind == 0:
        c = 1.0
        for j in range(1, k + 1):
            c *= lagf(la[j], a, lb[j])
            mean += c * xh[k - j]
            if j >= 2:
                cov += c * c * Ph[k - j]
                if gain:
                    covg += c * c * Pgh[k - j]
        return mean, cov, covg
    c = 1.0
    sumsq = 0.0
    for j in range(1, pl + 1):
        c *= lagf(la[j], a, lb[j])
        if j <= xl:
            mean += c * win[j - 1]
        if j >= 2:
            cov += c * c * Pwin[j - 1]
            if gain:
                covg += c * c * Pwin_g[j - 1]
        sumsq += c * c
    if kind == 1:
        mean += tail(a, modes, ka, kb, eta, klo, khi, arg, Ex, ib, fb)
        ac = max(a, max(-0.49, klo))
        kk = k - H
        r = rgn(ac)  # 1/Γ(−ac), shared by the two terms below
        if kk > pl:
            total = math.exp(math.lgamma(1.0 + 2.0 * ac) - 2.0 * math.lgamma(1.0 + ac))
            p1 = 1.0 + 2.0 * ac
            KK = kk + 0.5
            g = 0.5 * (ac * (1.0 + ac) + ac * (1.0 + ac))
            beyond = r * r * (KK ** (-p1) / p1 + g * KK ** (-p1 - 1.0) / (p1 + 1.0))
            mass = total - (1.0 + sumsq) - beyond  # coefficient mass × the oldest windowed P
            cov += mass * Pwin[pl - 1]
            if gain:
                covg += mass * Pwin_g[pl - 1]
        j0 = max(k - H + 1, pl + 1)  # the head's lags k − i beyond the window: j0 … k
        if H > 0 and j0 <= k:
            # c_j(ac) at the smallest lag by log-gamma, then c_{j+1} = c_j (j − ac)/(j + 1)
            ch = r * math.exp(math.lgamma(j0 - ac) - math.lgamma(j0 + 1.0))
            for j in range(j0, k + 1):
                cov += ch * ch * Phead[k - j]
                if gain:
                    covg += ch * ch * Phead_g[k - j]
                ch *= (j - ac) / (j + 1.0)
    return mean, cov, covg


@njit(cache=True, inline="always")
def estimate_uncertainty(Y, off, r, wc, prior_cov, cov):
    """``J P Jᵀ`` (tea._estimate_uncertainty), scalar: ``J`` the statistical linearisation of the replica over a
    filter's sigma points, Σᵢ Wᵢᶜ Yᵢ (σᵢ − m) / P̃ = W₁ᶜ r (Y₊ − Y₋) / P̃ (zero where P̃ is zero); ``Y[off:off+3]``
    the replica at the points drawn with root ``r`` from ``prior_cov``; ``cov`` the estimate's covariance."""
    J = wc[1] * r * (Y[off + 1] - Y[off + 2]) / prior_cov if prior_cov > 0 else 0.0
    return J * J * cov


@njit(cache=True, inline="always")
def kfx_update(x_pred, P_pred, R, obs, yv):
    """KFx's measurement update (33)–(35) (tea._kfx_update), ``C = 1``: returns ``(x, P, e, S, K)``."""
    S = P_pred + R
    e = yv - x_pred if obs else 0.0
    K = P_pred / S if obs else 0.0
    return x_pred + K * e, psd(P_pred - K * S * K), e, S, K


@njit(cache=True, inline="always")
def joseph(P, K, H, R):
    """(1 − K H) P (1 − K H) + K R K, scalar (unscented._joseph)."""
    g = 1.0 - K * H
    return g * P * g + K * R * K


@njit(cache=True, inline="always")
def constant_truth_cov(Sig, Pt, K, Pyy, Pxy):
    """The error covariance of a scalar unscented filter for a constant truth (unscented._constant_truth_cov):
    (1 − K H)² Σ + K² (P_yy − H² P̃) with H = P_σy / P̃ (0 where P̃ is 0)."""
    Hh = Pxy / Pt if Pt > 0 else 0.0
    return psd(joseph(Sig, K, Hh, psd(Pyy - Hh * Pt * Hh)))


@njit(cache=True, inline="always")
def guard(values, limit):
    """Whether a carry diverged (tea._guard's test): a value non-finite or beyond ``±limit``."""
    for v in values:
        if not (abs(v) <= limit):
            return True
    return False


@njit(cache=True, inline="always")
def push(kind, gain, k, x, P, Pg, xh, Ph, Pgh, win, xl, modes, decay, inject, Pwin, pl, Pwin_g, H, Phead, Phead_g):
    """Append x̂_k, P_k (and the gain's P_k) to KFx's history (the memory's ``push``): the whole past in order
    (``kind`` 0); else the windows, newest first, the dropped state into the modes, P_k into the start-up head."""
    if kind == 0:
        xh[k] = x
        Ph[k] = P
        if gain:
            Pgh[k] = Pg
        return
    M = modes.shape[0]
    if M > 0:
        dropped = win[xl - 1]
        for n in range(M):
            modes[n] = modes[n] * decay[n] + inject[n] * dropped
    push_front(win, xl, x)
    push_front(Pwin, pl, P)
    if k < H:
        Phead[k] += P
    if gain:
        push_front(Pwin_g, pl, Pg)
        if k < H:
            Phead_g[k] += Pg


# --------------------------------------------------------------------------- the loop


@njit(cache=True, parallel=True, error_model="numpy")
def advance(k0, k1, yoff, ooff, every, y, u, has_u,
            h, Q, R, Ro, Rw, qmax_o, qmax_w, scaled, start, lo, hi, limit, delta_o, delta_w, mode, const,
            inn_o, inn_w, wm_o, wc_o, scale_o, wm_w, wc_w, scale_w,
            kind, xl, pl, H, ka, kb, kbig, decay, inject, eta, klo, khi, count_lo, count_hi, la, lb,
            X, P, AL, PO, QO, W, PW, QW, DIV, DAT, CLAMP, PG, POG, PWG, SS,
            xh, Ph, win, modes, Pwin, Phead, Pgh, Pwin_g, Phead_g,
            o_x, o_P, o_a, o_Po, o_Qo, o_w, o_Pw, o_Qw, o_e, o_S):
    """Steps ``k0 … k1−1`` of every realisation in place (FastTEA.advance): the torch step (tea._tea_step) as the
    calls of its twins above, in its order. ``mode``: ``kfx_uncertainty`` as
    0 (paper), 1 (propagated) or 2 (paper-gain: ``PG`` and the histories ``Pgh``/``Pwin_g``/``Phead_g`` hold the
    paper's covariance, which sets the gain, and ``P`` that filter's error covariance). ``const``
    (``estimate_uncertainty = "constant-truth"``): ``POG``/``PWG`` hold KFo's and KFw's own covariances, which set
    their gains, and ``PO``/``PW`` their error covariances for a constant truth; otherwise the two are equal.
    ``inn_o``/``inn_w`` (``kfo.R``/``kfw.R = "innovation"``): KFo/KFw take ``SS``, KFx's innovation covariance of the
    step before from the covariance that sets its gain, as their R (``Ro``/``Rw`` otherwise)."""
    nB = y.shape[0]
    M = modes.shape[1]
    gain = mode == 2
    for b in prange(nB):
        x, Pk, al, Po, Qo, w, Pw, Qw = X[b], P[b], AL[b], PO[b], QO[b], W[b], PW[b], QW[b]
        Pg = PG[b]
        Pog, Pwg = POG[b], PWG[b]
        Sp = SS[b]
        inn = inn_o or inn_w
        div = DIV[b]
        dat = DAT[b]
        clamp = CLAMP[b]
        # this realisation's history
        xh_b, Ph_b, Pgh_b, win_b, modes_b = xh[b], Ph[b], Pgh[b], win[b], modes[b]
        Pwin_b, Pwin_g_b, Phead_b, Phead_g_b = Pwin[b], Pwin_g[b], Phead[b], Phead_g[b]
        so = np.empty(3)
        sw = np.empty(3)
        Y = np.empty(6)
        ms = np.empty(3)
        arg = np.empty(M)  # scratch of the exponential sums (tails3, tail)
        E = np.empty(M)
        Ex = np.empty(M)  # exp(a + α b) at the order of the last KFx tail (ex_al), reused by the next KFo
        ex_al = math.nan
        D = np.empty(M)
        Di = np.empty(M)
        ib = np.empty(M, np.int64)
        fb = ib.view(np.float64)
        for k in range(k0, k1):
            yk = y[b, k - yoff]
            obs = not math.isnan(yk)
            yv = yk if obs else 0.0
            up = u[b, k - 1 - yoff] if has_u else 0.0
            # the soe clamp count (tea._loop_bounded): extreme KFo sigma orders, before the step
            spread = math.sqrt(psd(scale_o * (Pog + Qo)))
            if (al - spread) < count_lo or (al + spread) > count_hi:
                clamp += 1
            # KFo and KFw predictions (13)–(15), (38)–(40), from the covariances that set their gains
            Pot = Pog + Qo
            Pwt = Pwg + Qw
            ro = sigma_points(al, Pot, scale_o, so)
            rw = sigma_points(w, Pwt, scale_w, sw)
            mean_sums(kind, so, ro, k, xh_b, la, lb, win_b, xl, modes_b, ka, kb, kbig, eta, klo, khi, al == ex_al, Ex,
                      arg, E, D, Di, ib, fb, ms)
            replica(so, sw, w, x, up, h, ms, Y)
            # KFo's update (19)–(24) with the order projected, adaptation (25); then KFw's
            al_n, Pog_n, Ko, eo, Pyy_o, Pxy_o = ut_update(Y, 0, so, al, Pot, wm_o, wc_o, start,
                                                          Sp if inn_o else Ro[b], obs, yv)
            al_n = min(max(al_n, lo), hi)
            Qo_n = adapt_q(Qo, Ko, eo, delta_o, qmax_o[b], obs)
            w_n, Pwg_n, Kw, ew, Pyy_w, Pxy_w = ut_update(Y, 3, sw, w, Pwt, wm_w, wc_w, start,
                                                         Sp if inn_w else Rw[b], obs, yv)
            Qw_n = adapt_q(Qw, Kw, ew, delta_w, qmax_w[b], obs)
            # KFx (29)–(35) with α̂_k and ŵ_{k−1}
            a = al_n
            mean, cov, covg = kfx_sums(kind, gain, a, k, xh_b, Ph_b, Pgh_b, la, lb, win_b, xl, pl, Pwin_b, Pwin_g_b,
                                       H, Phead_b, Phead_g_b, modes_b, ka, kb, eta, klo, khi, arg, Ex, ib, fb)
            if kind == 1:
                ex_al = min(max(a, klo), khi)
            hp = h ** a
            x_pred = hp * (w * x + up) - mean
            F = hp * w + a
            Qx = Q[b] * (hp * hp) if scaled else Q[b]
            P_pred = F * Pk * F + Qx + cov
            if mode != 0:
                # with the filters' own covariances (tea._tea_step)
                P_pred += estimate_uncertainty(Y, 0, ro, wc_o, Pot, Pog_n) \
                    + estimate_uncertainty(Y, 3, rw, wc_w, Pwt, Pwg)
            Pg_n = 0.0
            if gain:
                # the paper's KFx sets the gain; P is the covariance of that filter's error (Joseph form)
                Pg_pred = F * Pg * F + Qx + covg
                x_n, Pg_n, e, S_n, Kx = kfx_update(x_pred, Pg_pred, R[b], obs, yv)
                S = P_pred + R[b]
                P_n = joseph(P_pred, Kx, 1.0, R[b])
            else:
                x_n, P_n, e, S, Kx = kfx_update(x_pred, P_pred, R[b], obs, yv)
                S_n = S  # the innovation covariance from the covariance that sets the gain (KFo's and KFw's next R)
            if const:
                # the filters' own covariances set the gains; Po and Pw: those of their errors for a constant truth
                Po_n = constant_truth_cov(Po, Pot, Ko, Pyy_o, Pxy_o)
                Pw_n = constant_truth_cov(Pw, Pwt, Kw, Pyy_w, Pxy_w)
            else:
                Po_n, Pw_n = Pog_n, Pwg_n
            # the guard: non-finite or beyond the limit → flagged and frozen
            bad = guard((x_n, P_n, al_n, Po_n, Qo_n, w_n, Pw_n, Qw_n, Pg_n, Pog_n, Pwg_n, S_n if inn else 0.0), limit)
            if div or bad:
                if not div:
                    dat = k
                div = True
            else:
                x, Pk, al, Po, Qo, w, Pw, Qw, Pg = x_n, P_n, al_n, Po_n, Qo_n, w_n, Pw_n, Qw_n, Pg_n
                Pog, Pwg = Pog_n, Pwg_n
                Sp = S_n
            # the history (tea._loop: memory.push)
            push(kind, gain, k, x, Pk, Pg, xh_b, Ph_b, Pgh_b, win_b, xl, modes_b, decay, inject, Pwin_b, pl, Pwin_g_b,
                 H, Phead_b, Phead_g_b)
            if k % every == 0:
                row = k // every - ooff
                o_x[b, row], o_P[b, row], o_a[b, row], o_Po[b, row] = x, Pk, al, Po
                o_Qo[b, row], o_w[b, row], o_Pw[b, row], o_Qw[b, row] = Qo, w, Pw, Qw
                o_e[b, row], o_S[b, row] = e, S
        X[b], P[b], AL[b], PO[b], QO[b], W[b], PW[b], QW[b] = x, Pk, al, Po, Qo, w, Pw, Qw
        PG[b] = Pg
        POG[b], PWG[b] = Pog, Pwg
        SS[b] = Sp
        DIV[b] = div
        DAT[b] = dat
        CLAMP[b] = clamp

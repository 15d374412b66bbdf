"""A scalar NumPy reference of the Triple Estimation Algorithm, written separately.

One realisation, one state, one order, one parameter (the paper's noise model
(43)–(45) with A = f = w, B = C = 1), plain Python floats and a loop over time.
It shares no code with ``torchtea``; the tests and the benchmark compare the
batched PyTorch implementation against it.
"""
from __future__ import annotations

import math

import numpy as np


def gl(a: float, n: int) -> np.ndarray:
    """c_0 … c_n of order a by the recursion c_j = c_{j−1}(1 − (1+a)/j)."""
    f = 1.0 - (1.0 + a) / np.arange(1, n + 1, dtype=np.float64)
    return np.concatenate([[1.0], np.cumprod(f)])


def tea_reference(y, u, h, s, *, honest: bool = False, r_from_kfx: bool = False):
    """Run the TEA on one scalar series.

    y : (N,) measurements (NaN = missing); u : (N,) inputs or None;
    s : dict with x0 P0 Q R a0 P0o Q0o Ro w0 P0w Q0w Rw ua ub kappa delta_o delta_w
        Qmax_o Qmax_w start scaled lo hi.
    Returns a dict of (N,) arrays.

    Two options of issue 15's studies (experiments/montecarlo/paper_gain_prototype.py), off by default:
    ``honest`` adds ``out["Ph"]``, the covariance of the error of this (the paper's) filter with the order's and
    parameter's uncertainty included: ``P̃ʰ = F² Pʰ + Q + Σ_{j≥2} c_j² Pʰ_{k−j} + J_α² Pᵒ_k + J_w² Pʷ_{k−1}``
    (J as ``kfx_uncertainty = "propagated"`` takes them) and ``Pʰ = (1 − K)² P̃ʰ + K² R`` with the paper's K,
    and ``out["Sh"] = P̃ʰ + R``, the innovation covariance that goes with it.
    ``r_from_kfx``: KFo and KFw take KFx's last innovation covariance S as their measurement covariance.
    """
    N = len(y)
    u = np.zeros(N) if u is None else np.asarray(u, dtype=float)
    lam = s["ua"] ** 2 * (1 + s["kappa"]) - 1
    Wm = [lam / (1 + lam), 1 / (2 * (1 + lam)), 1 / (2 * (1 + lam))]
    Wc = [Wm[0] + 1 - s["ua"] ** 2 + s["ub"], Wm[1], Wm[2]]
    st = s["start"]
    out = {k: np.zeros(N) for k in ("x", "P", "a", "Po", "Qo", "w", "Pw", "Qw", "e", "S") + (("Ph", "Sh") if honest else ())}
    xs, Ps, Phs = [], [], []  # history, oldest first

    # k = 0: KFx update from the prior
    x, P = s["x0"], s["P0"]
    S = P + s["R"]
    if math.isnan(y[0]):
        e = 0.0
    else:
        K = P / S
        e = y[0] - x
        x, P = x + K * e, max(P - K * S * K, 0.0)
    a, Po, Qo, w, Pw, Qw = s["a0"], s["P0o"], s["Q0o"], s["w0"], s["P0w"], s["Q0w"]
    xs.append(x)
    Ps.append(P)
    Phs.append(P)
    for key, v in zip(("x", "P", "a", "Po", "Qo", "w", "Pw", "Qw", "e", "S", "Ph", "Sh"), (x, P, a, Po, Qo, w, Pw, Qw, e, S, P, S)):
        if key in out:
            out[key][0] = v

    for k in range(1, N):
        past = np.array(xs[::-1])  # x_{k-1}, …, x_0
        pastP = np.array(Ps[::-1])
        x_prev, u_prev = xs[-1], u[k - 1]
        obs = not math.isnan(y[k])

        def model(order, param):
            c = gl(order, k)
            return h**order * (param * x_prev + u_prev) - float(np.dot(c[1:], past))

        def unscented(mean, Pt, points, Ys, R):
            yp = sum(Wm[i] * Ys[i] for i in range(3))
            Pyy = sum(Wc[i] * (Ys[i] - yp) ** 2 for i in range(st, 3)) + R
            Pxy = sum(Wc[i] * (points[i] - mean) * (Ys[i] - yp) for i in range(st, 3))
            if not obs:
                return mean, Pt, 0.0, 0.0
            K = Pxy / Pyy
            e = y[k] - yp
            return mean + K * e, max(Pt - K * Pyy * K, 0.0), K, e

        def adapt(Q, K, e, delta, qmax):
            if delta == 0.0 or not obs:
                return Q
            Qn = (1 - delta) * Q + delta * (K * e) ** 2
            return min(Qn, qmax) if qmax is not None else Qn

        # KFo
        Pot = Po + Qo
        r = math.sqrt((1 + lam) * Pot)
        pts = [a, a + r, a - r]
        Ys = [model(p, w) for p in pts]
        a_new, Po, K, e = unscented(a, Pot, pts, Ys, S if r_from_kfx else s["Ro"])
        Jo = Wc[1] * r * (Ys[1] - Ys[2]) / Pot if Pot > 0 else 0.0
        a_new = min(max(a_new, s["lo"]), s["hi"])
        Qo = adapt(Qo, K, e, s["delta_o"], s["Qmax_o"])
        # KFw (order α̂_{k−1})
        Pw_prev = Pw
        Pwt = Pw + Qw
        r = math.sqrt((1 + lam) * Pwt)
        ptw = [w, w + r, w - r]
        Ys = [model(a, p) for p in ptw]
        w_new, Pw, K, e = unscented(w, Pwt, ptw, Ys, S if r_from_kfx else s["Rw"])
        Jw = Wc[1] * r * (Ys[1] - Ys[2]) / Pwt if Pwt > 0 else 0.0
        Qw = adapt(Qw, K, e, s["delta_w"], s["Qmax_w"])
        # KFx with α̂_k and ŵ_{k−1}
        c = gl(a_new, k)
        hp = h**a_new
        xp = hp * (w * x_prev + u_prev) - float(np.dot(c[1:], past))
        Q = s["Q"] * hp * hp if s["scaled"] else s["Q"]
        Pp = (hp * w + a_new) ** 2 * pastP[0] + Q + float(np.dot(c[2:] ** 2, pastP[1:]))
        S = Pp + s["R"]
        if obs:
            K = Pp / S
            e = y[k] - xp
            x, P = xp + K * e, max(Pp - K * S * K, 0.0)
        else:
            K, e, x, P = 0.0, 0.0, xp, Pp
        Ph = Sh = 0.0
        if honest:
            pastPh = np.array(Phs[::-1])
            Pph = ((hp * w + a_new) ** 2 * pastPh[0] + Q + float(np.dot(c[2:] ** 2, pastPh[1:]))
                   + Jo * Jo * Po + Jw * Jw * Pw_prev)
            Ph = (1 - K) ** 2 * Pph + K * K * s["R"]
            Sh = Pph + s["R"]
        a, w = a_new, w_new
        xs.append(x)
        Ps.append(P)
        Phs.append(Ph)
        for key, v in zip(("x", "P", "a", "Po", "Qo", "w", "Pw", "Qw", "e", "S", "Ph", "Sh"),
                          (x, P, a, Po, Qo, w, Pw, Qw, e, S, Ph, Sh)):
            if key in out:
                out[key][k] = v
    return out


def settings_from_config(cfg) -> dict:
    """Flatten a scalar :class:`torchtea.engines.settings.TEAConfig` into the reference's dict."""
    f = lambda v: float(v)  # noqa: E731
    cap = lambda c: None if c.Q_max == "none" else (float(c.Q0) if c.Q_max == "Q0" else float(c.Q_max))  # noqa: E731
    return dict(
        x0=f(cfg.kfx.x0), P0=f(cfg.kfx.P0), Q=f(cfg.kfx.Q0), R=f(cfg.kfx.R),
        a0=f(cfg.kfo.x0), P0o=f(cfg.kfo.P0), Q0o=f(cfg.kfo.Q0), Ro=f(cfg.kfo.R),
        w0=f(cfg.kfw.x0), P0w=f(cfg.kfw.P0), Q0w=f(cfg.kfw.Q0), Rw=f(cfg.kfw.R),
        ua=cfg.kfo.ut_alpha, ub=cfg.kfo.ut_beta, kappa=2.0 if cfg.kfo.kappa is None else cfg.kfo.kappa,
        delta_o=cfg.kfo.delta, delta_w=cfg.kfw.delta, Qmax_o=cap(cfg.kfo), Qmax_w=cap(cfg.kfw),
        start=cfg.sigma_sum_start, scaled=cfg.noise_scaling == "scaled",
        lo=cfg.order_bounds[0], hi=cfg.order_bounds[1],
    )

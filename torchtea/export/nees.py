r"""The cover as a navigation filter feels it: a static IMU whose bias a Kalman filter estimates with the exported
white noise + random walk, then dead-reckons through an outage — run on series simulated from the *fitted* model.

The bias filter: :math:`b_k = b_{k-1} + w_k`, :math:`\operatorname{Var} w = K^2\Delta t`; :math:`y_k = b_k + v_k`,
:math:`\operatorname{Var} v = N^2/\Delta t` (Kalibr's discretisation). At a time k it stops (an outage of L
samples, τ = LΔt) and integrates the rate it believes, :math:`y_j - \hat b_k`: the static IMU's true angle (gyroscope)
or velocity (accelerometer) change is 0, so the error is :math:`e = \Delta t\sum_{j=k+1}^{k+L}(y_j - \hat b_k)`, and
the filter's own variance of it is :math:`\Delta t^2\,[L^2 P_k + L N^2/\Delta t + K^2\Delta t\,L(L+1)(2L+1)/6]`.
No decomposition of the simulated noise into "bias" and "noise" is needed: the truth is zero.
:math:`\mathrm{NEES} = e^2/\operatorname{Var}` is χ²₁ for a consistent filter; the outage ending at the record's end
in each of M realisations gives a mean whose 95 % band is :math:`[\chi^2_M(0.025)/M,\ \chi^2_M(0.975)/M]`
(Bar-Shalom, Li & Kirubarajan 2001, §5.4): above it the filter is overconfident (its variance smaller than its
errors), below it conservative. Also reported: the mean over every outage of the record's second half (outages
of one realisation share its bias estimate's error, so that mean has no exact band).
"""
from __future__ import annotations

import math

import numpy as np
import torch

__all__ = ["nees_study", "bias_filter", "outage_nees"]


def bias_filter(y: np.ndarray, h: float, N: float, K: float) -> tuple[np.ndarray, np.ndarray]:
    """The scalar bias filter on ``y`` ``(M, n)`` (one series per row): estimates ``(M, n)`` and variances
    ``(n,)`` (the same for every realisation). Started at the first sample with its noise variance."""
    y = np.atleast_2d(np.asarray(y, dtype=np.float64))
    M, n = y.shape
    R, Q = N * N / h, K * K * h
    P = np.empty(n)
    b = np.empty_like(y)
    b[:, 0], P[0] = y[:, 0], R
    p = R
    for k in range(1, n):  # the gain does not depend on the data: one scalar recursion, the estimates batched
        pp = p + Q
        g = pp / (pp + R)
        b[:, k] = b[:, k - 1] + g * (y[:, k] - b[:, k - 1])
        p = (1.0 - g) * pp
        P[k] = p
    return b, P


def outage_nees(y: np.ndarray, h: float, N: float, K: float, L: int, filtered=None) -> tuple[np.ndarray, np.ndarray]:
    """NEES of the outages of ``L`` samples: those starting at k = n/2, n/2 + L, … → ``(M, W)``; and the one ending
    at the last sample ``(M,)``. ``filtered``: :func:`bias_filter`'s output for these (N, K), when already run."""
    y = np.atleast_2d(np.asarray(y, dtype=np.float64))
    M, n = y.shape
    b, P = bias_filter(y, h, N, K) if filtered is None else filtered
    c = np.concatenate([np.zeros((M, 1)), np.cumsum(y, axis=1)], axis=1)  # c[:, j] = Σ_{i<j} y_i

    def nees(k):
        e = h * (c[:, k + 1 + L] - c[:, k + 1] - L * b[:, k])
        var = h * h * (L * L * P[k] + L * N * N / h + K * K * h * L * (L + 1) * (2 * L + 1) / 6.0)
        return e * e / var

    starts = range(n // 2, n - L, L)
    every = np.stack([nees(k) for k in starts], axis=1) if len(starts) else np.empty((M, 0))
    return every, nees(n - 1 - L)


def nees_study(model, values: dict, h: float, n: int, values_sets: dict, taus, realisations: int = 64,
               seed: int = 0, inputs: dict | None = None) -> dict:
    """Simulate ``realisations`` series of ``n`` samples from ``model`` at ``values`` and, for each ``(N, K)`` of
    ``values_sets`` (name → pair) and each outage ``τ`` of ``taus`` (s, at most a quarter of the record), the
    outage NEES → ``{"taus_s", "band", "realisations", "samples", "meaning", name: [{"tau_s", "nees_end",
    "nees_mean", "verdict"}, …]}``."""
    from scipy import stats

    from ..noise import simulate_model

    v = {k: float(x) for k, x in values.items()}
    inp = None if inputs is None else {k: torch.as_tensor(np.asarray(x)[:n], dtype=torch.float64)
                                       for k, x in inputs.items()}
    y = simulate_model(model, v, n_steps=n, h=h, realisations=realisations, inputs=inp,
                       generator=torch.Generator().manual_seed(seed))[0].numpy()
    lo, hi = (float(stats.chi2.ppf(q, realisations) / realisations) for q in (0.025, 0.975))
    Ls = sorted({int(round(t / h)) for t in taus if 1 <= round(t / h) <= n // 4})
    out = {"taus_s": [L * h for L in Ls], "band": [lo, hi], "realisations": realisations, "samples": n,
           "meaning": "NEES of a static IMU's dead reckoning through an outage of tau s, after a bias filter that "
                      "assumes the values (N, K), on series simulated from the fitted model: 1 when the filter's "
                      "variance is honest; 'nees_end': the outage ending at the last sample, mean over the "
                      "realisations, 95 % band 'band'; 'nees_mean': every outage of the second half"}
    for name, (N, K) in values_sets.items():
        rows = []
        ok = N > 0 and math.isfinite(N) and math.isfinite(K)
        filtered = bias_filter(y, h, N, K) if ok else None  # (the same filter for every outage)
        for L in Ls:
            if not ok:
                rows.append({"tau_s": L * h, "nees_end": None, "nees_mean": None,
                             "verdict": "not run: N is 0 (the filter needs a measurement noise)"})
                continue
            every, end = outage_nees(y, h, N, K, L, filtered)
            e = float(end.mean())
            verdict = ("not computed (a non-finite error: the simulated series or the filter diverged)"
                       if not math.isfinite(e) else
                       "overconfident" if e > hi else "conservative" if e < lo else "consistent")
            rows.append({"tau_s": L * h, "nees_end": e if math.isfinite(e) else None,
                         "nees_mean": float(every.mean()) if every.size else None, "verdict": verdict})
        out[name] = {"N": N, "K": K, "outages": rows}
    return out

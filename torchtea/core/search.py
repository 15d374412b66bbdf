"""Searches and exact laws on a series, used by ``check``'s diagnostics and by the components' own screens (which is
why they live in the lowest layer: a component in :mod:`torchtea.noise` reads them without reaching up to
:mod:`torchtea.checking`): the largest |z| of n standard normals (:func:`max_abs_p`, :func:`max_abs_bound`), the band
of a periodogram with the most power (:func:`band_search`), a line of drifting frequency (:func:`chirp_search`,
:func:`refine_chirp`), a tone's frequency (:func:`refine_frequency`) and least squares on regressors
(:func:`remove_regressors`). NumPy and SciPy only."""
from __future__ import annotations

import math

import numpy as np
from scipy import stats

__all__ = ["max_abs_p", "max_abs_logp", "smallest_of_logp", "max_abs_bound", "innovation_periodogram", "BAND_WIDTHS", "band_search",
           "against_neighbours", "chirp_search", "search_chirps", "refine_chirp", "refine_frequency", "remove_regressors"]


def max_abs_p(m: float, n: int) -> float:
    """P(max |z| > m) for n independent N(0, 1): 1 − (1 − 2Φ(−m))ⁿ, exactly."""
    return float(-np.expm1(n * np.log1p(-2.0 * stats.norm.sf(m))))


def max_abs_logp(m: float, n: int) -> float:
    """log :func:`max_abs_p`, by its first-order bound n·2Φ(−m) in logs where the probability is below 10⁻¹²."""
    p = max_abs_p(m, n)
    return math.log(p) if p > 1e-12 else math.log(n) + math.log(2.0) + float(stats.norm.logsf(m))


def smallest_of_logp(log_p: float, m: int) -> float:
    """log P(the smallest of ``m`` independent p-values ≤ exp(``log_p``)) = log(1 − (1 − p)^m), computed in logs; by
    its first-order bound log p + log m below p = e⁻³⁰."""
    if log_p < -30:
        return float(log_p + math.log(m))
    return math.log(max(float(-np.expm1(m * np.log1p(-math.exp(log_p)))), 1e-300))


def max_abs_bound(n: int, level: float) -> float:
    """The c with P(max |z| > c) = ``level`` for n independent N(0, 1)."""
    return float(stats.norm.isf(-np.expm1(np.log1p(-level) / n) / 2.0))


def innovation_periodogram(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    x = np.where(np.isfinite(z), z, 0.0)
    N = len(x)
    n_obs = int(np.isfinite(z).sum())
    d = np.fft.rfft(x)
    j = np.arange(1, (N - 1) // 2 + 1)
    return j, np.abs(d[j]) ** 2 / n_obs  # 2π·I: Exp(1) per ordinate under the model


#: the widths (in Fourier ordinates) :func:`band_search` tries
BAND_WIDTHS = (4, 16, 64, 256)


def band_search(z: np.ndarray, h: float, widths=BAND_WIDTHS) -> dict:
    """The band of the standardised innovations' periodogram with the most power against the model: for each width
    m of ``widths`` (up to an eighth of the ordinates) the sum of every m adjacent ordinates, each Exp(1) under the
    model, so the sum is Gamma(m, 1); the smallest upper-tail p-value, Bonferroni over the positions and the widths
    (a bound: the overlapping windows are correlated, so the test is conservative). Returns the band's centre and
    width (Hz), its power against the model (the mean ordinate) and the log p-value."""
    from scipy import stats

    j, u = innovation_periodogram(z)
    N = len(z)
    best = None
    widths = [m for m in widths if m <= len(u) // 8] or [max(1, len(u) // 8)]
    for m in widths:
        c = np.concatenate([[0.0], np.cumsum(u)])
        sums = c[m:] - c[:-m]
        k = int(np.argmax(sums))
        logp = float(stats.gamma.logsf(sums[k], m)) + math.log(len(sums)) + math.log(len(widths))
        if best is None or logp < best["log_p"]:
            lo, hi = j[k], j[k + m - 1]
            best = {"centre_hz": float((lo + hi) / 2 / (N * h)), "width_hz": float(m / (N * h)),
                    "ratio": float(sums[k] / m), "log_p": min(0.0, logp), "ordinates": m}
    return best


def against_neighbours(u: np.ndarray, neighbours: int = 50, guard: int = 2):
    """Each periodogram ordinate ``u`` (Exp(1) under the model) with its full ``neighbours`` on both sides (skipping
    ``guard`` next to it) against their mean: ``(indices, ratio, log p)``, ratio ~ F(2, 2K) for independent
    exponentials."""
    c = np.concatenate([[0.0], np.cumsum(u)])
    idx = np.arange(guard + neighbours, len(u) - guard - neighbours)
    Mu = len(u)

    def seg(lo, hi):  # sum and count of u[lo:hi], clipped to the array
        lo, hi = np.clip(lo, 0, Mu), np.clip(hi, 0, Mu)
        return c[hi] - c[lo], hi - lo

    s1, n1 = seg(idx - guard - neighbours, idx - guard)
    s2, n2 = seg(idx + guard + 1, idx + guard + 1 + neighbours)
    K = n1 + n2
    ratio = u[idx] / ((s1 + s2) / K)
    return idx, ratio, stats.f.logsf(ratio, 2, 2 * K)


#: the fewest cycles per record at which :func:`slow_line` looks for a line: at one or two cycles a line cannot be
#: told from a drift
SLOW_CYCLES = 3


def slow_line(z: np.ndarray, h: float, neighbours: int = 50, guard: int = 2) -> dict:
    """The largest periodogram ordinate of the standardised innovations ``z`` below the range
    :func:`against_neighbours` tests (from :data:`SLOW_CYCLES` up to ``guard + neighbours`` cycles per record), against
    the model itself: each ordinate is Exp(1) under the model, so the largest of M has
    P = 1 − (1 − e^{−u})^M. There a line has no neighbours on both sides to be weighed against; a drift the model
    lacks raises these ordinates too, so this is a screen's statistic (the likelihood then decides), not a
    diagnostic's. ``{"peak_hz", "cycles", "ordinate", "log_p"}``; ``log_p`` 0 when the record is too short."""
    j, u = innovation_periodogram(z)
    top = min(guard + neighbours, len(u))
    band = np.arange(SLOW_CYCLES - 1, top)
    if len(band) == 0:
        return {"peak_hz": float("nan"), "cycles": 0, "ordinate": 0.0, "log_p": 0.0}
    k = int(band[np.argmax(u[band])])
    log_p = smallest_of_logp(-float(u[k]), len(band))  # (log P(Exp(1) > u) = −u)
    return {"peak_hz": float(j[k] / (len(z) * h)), "cycles": int(j[k]), "ordinate": float(u[k]), "log_p": log_p}


#: :func:`chirp_search` remembers its last results by their input (the loop's fits of models with a drifting line
#: search the same residual again)
_CHIRP_MEMO: dict = {}
CHIRP_MEMO_SIZE = 8


#: The transform work (rates × samples) :func:`search_chirps` allows: 1201 rates on 30 000 samples
CHIRP_WORK = 3.6e7


def chirp_search(x: np.ndarray, h: float, *, max_rates: int = 1201, neighbours: int = 50, guard: int = 2,
                 batch: int = 32) -> dict:
    """:func:`search_chirps`, remembered: the same series and settings again give the result of the last search
    (one of the last :data:`CHIRP_MEMO_SIZE`) without searching."""
    import hashlib

    x = np.ascontiguousarray(x, dtype=np.float64)
    key = (hashlib.blake2b(x.tobytes(), digest_size=16).hexdigest(), len(x), float(h), max_rates, neighbours, guard)
    if key not in _CHIRP_MEMO:
        if len(_CHIRP_MEMO) >= CHIRP_MEMO_SIZE:
            _CHIRP_MEMO.pop(next(iter(_CHIRP_MEMO)))
        _CHIRP_MEMO[key] = search_chirps(x, h, max_rates=max_rates, neighbours=neighbours, guard=guard, batch=batch)
    return dict(_CHIRP_MEMO[key])


def search_chirps(x: np.ndarray, h: float, *, max_rates: int = 1201, neighbours: int = 50, guard: int = 2,
                  batch: int = 32) -> dict:
    """The strongest line of linearly drifting frequency in ``x`` (NaN = missing): for each drift rate f₁ of a grid
    (step 2/T², T the record's length — a phase error of at most π/2 at its ends —, ``max_rates`` rates centred on
    0, fewer where R·N would pass :data:`CHIRP_WORK`: R rates cover lines that sweep up to about R/T Hz over the
    record either way: 4 Hz over 30 000 samples at 100 Hz, 0.004 Hz over three hours), ``x`` is multiplied by
    exp(−iπ f₁ (t − t̄)²), which turns a line of frequency f₀ + f₁ (t − t̄) into a tone at
    f₀, and each positive-frequency ordinate is tested against its neighbours as :func:`lines` does (F(2, 2K)).
    Returns the best's ``f0_hz`` (at the record's middle t̄), ``rate_hz_per_s``, ``ratio``, its ``log_p`` with
    Bonferroni over every ordinate and rate tested, and ``tests`` (their number).

    Every tested ordinate has its full K = 2 ``neighbours``, so its p-value falls as its ratio grows and the best
    ordinate of a rate is the one of largest ratio; F(2, 2K)'s tail is :math:`(1 + r/K)^{-K}` in closed form. One
    transform serves two rates: ``x`` is real, so the dechirped series at −f₁ is the conjugate of the one at f₁ and
    its positive-frequency ordinates are the other's negative-frequency ones, mirrored. The transforms run ``batch``
    at a time, on the threads torch is given (:func:`against_neighbours` per rate is the obvious path; the tests hold
    the two to each other). Ties go to the lowest rate, then the lowest frequency. The search runs on the record's
    central N′ samples, N′ the longest length up to N whose transform has only small prime factors
    (:func:`scipy.fft.prev_fast_len`), where that drops at most 1 % of it: a length with a large prime factor costs three
    to four times as much (44 930 samples, the bundled recording's: 44 800 searched)."""
    import scipy.fft
    import torch

    x = np.asarray(x, dtype=np.float64)
    fast = scipy.fft.prev_fast_len(len(x), real=False)
    if fast >= 0.99 * len(x):
        x = x[(len(x) - fast) // 2:(len(x) - fast) // 2 + fast]
    ok = np.isfinite(x)
    N = len(x)
    xx = np.where(ok, x, 0.0)
    n_obs = int(ok.sum())
    t = (np.arange(N) - (N - 1) / 2.0) * h
    T = N * h
    R = max(41, min(max_rates, int(CHIRP_WORK / N))) // 2 * 2 + 1  # fewer rates on long records
    rates = (np.arange(R) - R // 2) * 2.0 / T ** 2
    W = (N - 1) // 2
    lo, hi = guard + neighbours, W - guard - neighbours  # the ordinates with their full neighbours
    K = 2 * neighbours
    tt = np.pi * t * t
    top = np.full(R, -np.inf)  # each rate's largest ratio and where
    where = np.zeros(R, dtype=np.int64)
    centre = R // 2
    workers = max(1, torch.get_num_threads())
    turn = np.exp(-1j * (rates[centre + 1] - rates[centre]) * tt)  # one rate step's chirp
    for start in range(centre, R, batch):
        idx = np.arange(start, min(start + batch, R))
        z = np.empty((len(idx), N), dtype=np.complex128)
        z[0] = xx * np.exp(-1j * rates[start] * tt)
        for k in range(1, len(idx)):  # each next rate's chirp one step on (a product: no exponential per sample)
            np.multiply(z[k - 1], turn, out=z[k])
        d = scipy.fft.fft(z, axis=-1, workers=workers, overwrite_x=True)
        power = d.real ** 2 + d.imag ** 2
        for sign, rows in ((1, idx), (-1, 2 * centre - idx)):
            # the rate's positive ordinates 1 … W; for −f₁ the mirrored ones N − 1 … N − W
            u = (power[:, 1:W + 1] if sign > 0 else power[:, N - 1:N - W - 1:-1]) / n_obs
            c = np.zeros((len(idx), W + 1))
            np.cumsum(u, axis=1, out=c[:, 1:])
            around = (c[:, lo - guard:hi - guard] - c[:, lo - guard - neighbours:hi - guard - neighbours]
                      + c[:, lo + guard + 1 + neighbours:hi + guard + 1 + neighbours] - c[:, lo + guard + 1:hi + guard + 1])
            ratio = u[:, lo:hi] / (around / K)
            best = np.argmax(ratio, axis=1)
            top[rows] = ratio[np.arange(len(idx)), best]
            where[rows] = best + lo
    b = int(np.argmax(top))
    tests = R * max(hi - lo, 0)
    ratio, j = float(top[b]), int(where[b]) + 1
    logp = -K * math.log1p(ratio / K)  # log P(F(2, 2K) > ratio)
    return {"f0_hz": j / T, "rate_hz_per_s": float(rates[b]), "ratio": ratio,
            "log_p": min(0.0, logp + math.log(tests)), "tests": tests}


def refine_chirp(x: np.ndarray, f0: float, f1: float, h: float) -> tuple[float, float]:
    """``(f₀, f₁)`` maximising |Σ x_k exp(−i(2π f₀ τ_k + π f₁ τ_k²))|² (τ the time from the record's middle) near
    the grid's ``(f0, f1)`` — within one frequency bin and one rate step: L-BFGS-B on the offsets in bins and steps,
    with the power's gradient from the same sums (two weighted sums beside the transform's, no differences)."""
    from scipy.optimize import minimize

    N = len(x)
    xx = np.where(np.isfinite(x), x, 0.0)
    tau = (np.arange(N) - (N - 1) / 2.0) * h
    T = N * h
    sf, sr = 1.0 / T, 2.0 / T ** 2
    z = xx * np.exp(-1j * (2 * np.pi * f0 * tau + np.pi * f1 * tau * tau))
    lin, quad = -2j * np.pi * sf * tau, -1j * np.pi * sr * tau * tau

    def neg(p):
        e = z * np.exp(lin * p[0] + quad * p[1])
        a = e.sum()
        da, db = (e * lin).sum(), (e * quad).sum()
        return -abs(a) ** 2, np.array([-2.0 * (a.conjugate() * da).real, -2.0 * (a.conjugate() * db).real])

    res = minimize(neg, [0.0, 0.0], jac=True, method="L-BFGS-B", bounds=[(-1.0, 1.0), (-1.0, 1.0)],
                   options={"ftol": 1e-14, "gtol": 1e-10})
    p = np.clip(res.x, -1, 1)
    return float(f0 + p[0] * sf), float(f1 + p[1] * sr)


def refine_frequency(y: np.ndarray, f0: float, h: float) -> float:
    from scipy.optimize import minimize_scalar
    k = np.arange(len(y))
    df = 1.0 / (len(y) * h)

    def neg_power(f):
        w = 2 * np.pi * f * h
        return -abs(np.dot(y, np.exp(-1j * w * k))) ** 2

    res = minimize_scalar(neg_power, bounds=(max(f0 - df, df / 2), f0 + df), method="bounded",
                          options={"xatol": df * 1e-4})
    return float(res.x)


def remove_regressors(resid: np.ndarray, ok: np.ndarray, columns: list) -> dict:
    """Least squares of ``resid`` (its ``ok`` samples) on the centred regressor ``columns`` (``[(name, (N,)), …]``):
    removes the fit from ``resid`` in place and returns ``{name: coefficient}`` (empty without columns)."""
    if not columns:
        return {}
    X = np.stack([c for _, c in columns], 1)[ok]
    X = X - X.mean(0)
    coef, *_ = np.linalg.lstsq(X, resid[ok], rcond=None)
    resid[ok] -= X @ coef
    return dict(zip((n for n, _ in columns), coef.tolist()))

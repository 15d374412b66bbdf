r"""Diagnostics of a fitted noise model against the measurements: where, and how, the model fails.

Every diagnostic is a test of the hypothesis "the data came from the fitted model", with a stated level
(default 1 %); inside a diagnostic, multiple comparisons (windows, bands, τ values, frequencies) are
Bonferroni-corrected, so its p-value is for the whole diagnostic. Their false-alarm rates on data drawn
from fitted models are measured in ``experiments/check/`` and in the tests.

They read the **standardised innovations** :math:`z_k = e_k/\sqrt{S_k}` of the exact Kalman filter at the
fitted values — independent standard normal when the model is right — and, for the Allan view, the data
themselves against the model's Allan deviation:

========== ============== =====================================================================================
name       domain         statistic (null distribution)
========== ============== =====================================================================================
nis        time           Σ z² in each of W windows (χ²_n per window, two-sided): the failing time ranges
change     time           CUSUM of z and of z² − 1 (sup of a Brownian bridge, Kolmogorov): a drift or a step
extremes   time           the largest |z| (exact: P(max > m) = 1 − (1 − 2Φ(−m))ⁿ): isolated outliers, shocks,
                          each listed with its time
ljung-box  lag            Ljung–Box Q on the first L lags of z (χ²_L)
spectrum   frequency      band means of 2π·periodogram(z) in log-spaced bands (Gamma(m)/m, two-sided): the
                          bands where the model's spectrum is too low (ratio > 1) or too high (< 1)
lines      frequency      each ordinate of 2π·periodogram(z) against the mean of its 100 neighbours (F(2, 200)),
                          the largest over the frequencies with 50 neighbours on each side (≥ 53 cycles per
                          record): narrow-band lines (vibration)
allan      Allan          the data's overlapping AVAR at octave τ against the model's (χ²_edf, Greenhall's EDF):
                          the τ ranges outside the band
temperature inputs        score test of a temperature-proportional term (z against the whitened temperature,
                          χ²₁) and correlation of z² with the temperature (normal): needs the channel
========== ============== =====================================================================================

Metrics (descriptive, not tests): ``nll_per_sample`` (−ℓ/N of the exact filter, nats), ``psd_misfit``
(mean |log₁₀| of the innovation band power: 0 when the model's spectrum has the data's shape and level —
under the model about 0.01–0.03 at N = 30 000 from the bands' own scatter), ``adev_misfit`` (mean |log₁₀(ADEV
data / ADEV model)| over the octave τ grid).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch
from scipy import stats

from ..core.search import (
    BAND_WIDTHS,
    against_neighbours,
    band_search,
    chirp_search,
    innovation_periodogram,
    max_abs_bound,
    max_abs_logp,
    max_abs_p,
    refine_chirp,
    smallest_of_logp,
)
from ..fitting.innovations import Innovations, gls_statistic, innovations, linear_lr, scan_lr, whiten, whiten_with_level
from . import allan

__all__ = ["Diagnostic", "Innovations", "innovations", "whiten", "run_diagnostics", "metrics", "DIAGNOSTICS", "FUNCTIONS",
           "stochastic_avar",
           "LEVEL",
           # defined in fitting.innovations and core.search, imported from here too
           "gls_statistic", "linear_lr", "scan_lr", "BAND_WIDTHS", "band_search", "chirp_search", "refine_chirp",
           "max_abs_p", "max_abs_logp", "max_abs_bound"]

#: Default level of each diagnostic.
LEVEL = 0.01
DIAGNOSTICS = ("nis", "change", "ljung-box", "spectrum", "lines", "allan", "temperature")


@dataclass
class Diagnostic:
    """One test. ``p_value`` is for the whole diagnostic (Bonferroni inside); ``passed`` is ``p ≥ level``, or
    None when it was not run (``summary`` says why). ``ranges`` are where it fails, in ``unit`` (s, Hz or τ in s),
    each with its direction in ``directions`` ("high": the data exceed the model there, "low": below)."""

    name: str
    domain: str
    statistic: float | None
    p_value: float | None
    level: float
    summary: str
    unit: str = ""
    ranges: list = field(default_factory=list)
    directions: list = field(default_factory=list)
    detail: dict = field(default_factory=dict)

    @property
    def passed(self) -> bool | None:
        return None if self.p_value is None else bool(self.p_value >= self.level)

    def as_dict(self) -> dict:
        return {"name": self.name, "domain": self.domain, "statistic": self.statistic, "p_value": self.p_value,
                "level": self.level, "passed": self.passed, "summary": self.summary, "unit": self.unit,
                "ranges": self.ranges, "directions": self.directions}

    def signature(self) -> tuple[str, list[str]]:
        """What kind of physical effect would fit this failure — ``(words, [effect names])`` — read from where and
        which way it fails (:data:`SIGNATURES`); ``("", [])`` when it passed or was not run."""
        if self.passed is not False or self.name not in SIGNATURES:
            return "", []
        return SIGNATURES[self.name](self)


def _where(d: Diagnostic) -> str:
    return "; ".join(f"{a:.3g}–{b:.3g} {d.unit}" if a != b else f"{a:.3g} {d.unit}" for a, b in d.ranges[:4])


def _sig_nis(d):
    if "high" in d.directions:
        return (f"the innovations are larger than the model allows at {_where(d)}: something happened then — a "
                "shock (spikes), a level step, or vibration for a while", ["spikes", "step"])
    return f"the innovations are smaller than the model expects at {_where(d)}: the noise level changed over time", []


def _sig_change(d):
    if d.directions and "mean" in d.directions[0]:
        return (f"the innovations' mean drifts or jumps near t = {_where(d)}: a level step, or a bias that wanders "
                "(Gauss–Markov, random walk)", ["step", "gauss-markov", "random-walk"])
    return f"the noise variance changes near t = {_where(d)}: a noise level that varies in time", []


def _sig_extremes(d):
    return (f"isolated innovations beyond what the record's length allows, at {_where(d)}: shocks (spikes), or a "
            "level step where the model has a random walk (it shows as one large innovation)", ["spikes", "step"])


def _sig_ljung_box(d):
    lags = (f"at lags {', '.join(str(a) for a, _ in d.ranges[:6])}" if d.ranges else
            "over the first lags together, none alone beyond its bound")
    return (f"the innovations are correlated ({lags}): a filter the model lacks (a sensor's digital filter, "
            "of higher order than one), a vibration band, or a line whose frequency wanders",
            ["low-pass", "digital-filter", "resonance", "drifting-line"])


def _sig_spectrum(d):
    top = max(d.detail.get("band_hi_hz") or [max(b for _, b in d.ranges)])
    words, names = [], []
    for (a, b), way in zip(d.ranges, d.directions):
        if way == "high" and b <= 0.05 * top:
            words.append(f"more slow power than the model below {b:.3g} Hz: a bias that wanders (Gauss–Markov, "
                         "random walk) or a temperature effect")
            names += ["gauss-markov", "random-walk", "thermal-lag"]
        elif way == "high":
            words.append(f"more power than the model at {a:.3g}–{b:.3g} Hz: a vibration band or a line that wanders")
            names += ["resonance", "drifting-line", "sinusoid"]
        elif a >= 0.2 * top:
            words.append(f"less power than the model at {a:.3g}–{b:.3g} Hz: the sensor's own filter")
            names += ["low-pass", "digital-filter"]
        else:
            words.append(f"less power than the model at {a:.3g}–{b:.3g} Hz: the model's spectrum has the wrong shape "
                         "there (a component too strong)")
    return "; ".join(words), list(dict.fromkeys(names))


def _sig_lines(d):
    return f"a line at {_where(d)}: a vibration (another sinusoid if the model has one)", ["sinusoid"]


def _sig_allan(d):
    words, names = [], []
    for (a, b), way in zip(d.ranges, d.directions):
        if way == "high" and a >= 1.0:
            words.append(f"the data wander more than the model at τ {a:.3g}–{b:.3g} s: a bias instability "
                         "(Gauss–Markov) or a random walk")
            names += ["gauss-markov", "random-walk"]
        elif way == "high":
            words.append(f"more short-term noise than the model at τ {a:.3g}–{b:.3g} s")
        else:
            words.append(f"the model wanders more than the data at τ {a:.3g}–{b:.3g} s: a component too strong")
    return "; ".join(words), list(dict.fromkeys(names))


def _sig_temperature(d):
    if d.detail.get("p_bias", 1.0) < d.level / 2:
        return ("the innovations follow the temperature: a temperature effect the model lacks — through a lag "
                "(the die is not where the sensor of temperature is) if the model has a bias per °C already",
                ["temperature-bias", "thermal-lag", "temperature-order"])
    return "the noise variance moves with the temperature: a temperature-dependent noise level", []


#: What kind of effect fits a failed diagnostic, by its name: a function of the diagnostic (where and which way
#: it fails) returning words and the names of effects that would fit (some may not be in the library).
SIGNATURES = {"nis": _sig_nis, "change": _sig_change, "extremes": _sig_extremes, "ljung-box": _sig_ljung_box,
              "spectrum": _sig_spectrum,
              "lines": _sig_lines, "allan": _sig_allan, "temperature": _sig_temperature}


def _merge(intervals: list[tuple[float, float, str]]) -> tuple[list, list]:
    """Merge touching intervals of the same direction."""
    out, dirs = [], []
    for lo, hi, d in sorted(intervals):
        if out and dirs[-1] == d and lo <= out[-1][1] * (1 + 1e-9) + 1e-12:
            out[-1][1] = max(out[-1][1], hi)
        else:
            out.append([float(lo), float(hi)])
            dirs.append(d)
    return out, dirs


def _two_sided(cdf: np.ndarray, sf: np.ndarray) -> np.ndarray:
    return np.minimum(1.0, 2.0 * np.minimum(cdf, sf))


# --------------------------------------------------------------------------- time

def nis_windows(z: np.ndarray, h: float, level: float = LEVEL, windows: int | None = None) -> Diagnostic:
    """Where in time the model fails: the series cut into W windows (``windows``, default one per 1000 samples, at
    most 30), Σz² of each against its χ²ₙ law, two-sided, at level ``level``/W each. Fails where a window's noise is
    louder (``high``) or quieter (``low``) than the model's; the statistic is the mean NIS of the whole series."""
    N = len(z)
    W = windows or int(min(30, max(1, N // 1000)))
    edges = np.linspace(0, N, W + 1).astype(int)
    p, nis, bad = [], [], []
    for w in range(W):
        zz = z[edges[w]:edges[w + 1]]
        zz = zz[np.isfinite(zz)]
        n = len(zz)
        s = float(zz @ zz)
        nis.append(s / n if n else math.nan)
        p.append(float(_two_sided(stats.chi2.cdf(s, n), stats.chi2.sf(s, n))) if n else 1.0)
    p = np.array(p)
    thr = level / W
    for w in np.nonzero(p < thr)[0]:
        bad.append((edges[w] * h, edges[w + 1] * h, "high" if nis[w] > 1 else "low"))
    ranges, dirs = _merge(bad)
    pmin = float(min(1.0, W * p.min()))
    zf = z[np.isfinite(z)]
    total = float(zf @ zf / len(zf))
    summary = (f"NIS {total:.3f} overall; {len(bad)} of {W} windows outside their band (level {level:g}/{W} each)"
               if bad else
               f"NIS {total:.3f} overall; all {W} windows inside their band")
    return Diagnostic("nis", "time", total, pmin, level, summary, "s", ranges, dirs,
                      {"window_edges_s": (edges * h).tolist(), "window_nis": nis, "window_p": p.tolist()})


def change(z: np.ndarray, h: float, level: float = LEVEL) -> Diagnostic:
    """A drift or a step: the CUSUM of z (a change of the innovations' mean) and of z² − 1 (of their variance),
    each scaled to a Brownian bridge whose supremum has the Kolmogorov law; Bonferroni over the two. Fails with the
    time of the largest excursion."""
    k = np.nonzero(np.isfinite(z))[0]
    zz = z[k]
    n = len(zz)
    stats_, where = [], []
    for x in (zz, zz * zz):
        c = np.cumsum(x - x.mean()) / (x.std() * math.sqrt(n))
        j = int(np.argmax(np.abs(c)))
        stats_.append(float(abs(c[j])))
        where.append(float(k[j] * h))
    p = np.array([stats.kstwobign.sf(s) for s in stats_])
    pmin = float(min(1.0, 2 * p.min()))
    which = int(np.argmin(p))
    kind = ("a drift of the innovations' mean", "a change of their variance")[which]
    summary = (f"{kind} around t = {where[which]:.1f} s (CUSUM {stats_[which]:.2f})" if pmin < level else
               f"no drift or step (CUSUM of z {stats_[0]:.2f}, of z² {stats_[1]:.2f})")
    return Diagnostic("change", "time", max(stats_), pmin, level, summary, "s",
                      [[where[which], where[which]]] if pmin < level else [], [kind] if pmin < level else [],
                      {"cusum_mean": stats_[0], "cusum_variance": stats_[1], "change_at_s": where})


def extremes(z: np.ndarray, h: float, level: float = LEVEL, listed: int = 20) -> Diagnostic:
    """The largest standardised innovation against its extreme-value law: under the model the n innovations are
    independent N(0, 1), so P(max |z| > m) = 1 − (1 − 2Φ(−m))ⁿ exactly. Fails where one is beyond what n samples
    allow — a shock, an isolated outlier (no other diagnostic looks at single samples: a few spikes barely move the
    windowed NIS or the Allan deviation). Lists every sample beyond the bound c with P(max |z| > c) = ``level``
    (the first ``listed`` by size, with their times and z)."""
    k = np.nonzero(np.isfinite(z))[0]
    a = np.abs(z[k])
    n = len(a)
    j = int(np.argmax(a))
    m = float(a[j])
    p = max_abs_p(m, n)
    bound = max_abs_bound(n, level)
    beyond = np.nonzero(a > bound)[0]
    beyond = beyond[np.argsort(-a[beyond])][:listed]
    times = [float(k[i] * h) for i in beyond]
    if p < level:
        where = ", ".join(f"{t:.2f} s (z {z[k[i]]:+.1f})" for t, i in zip(times[:6], beyond[:6]))
        more = f" and {len(beyond) - 6} more" if len(beyond) > 6 else ""
        summary = (f"{len(beyond)} innovation(s) beyond |z| {bound:.2f}, what {n} samples allow: at {where}{more}")
    else:
        summary = f"largest |z| {m:.2f} at {k[j] * h:.2f} s, within what {n} samples allow ({bound:.2f})"
    return Diagnostic("extremes", "time", m, p, level, summary, "s",
                      [[t, t] for t in times] if p < level else [],
                      ["high" for _ in times] if p < level else [],
                      {"bound": bound, "max_abs_z": m, "at_s": times, "z": [float(z[k[i]]) for i in beyond]})


# --------------------------------------------------------------------------- lag

def acf(x: np.ndarray, lags: int) -> np.ndarray:
    x = np.where(np.isfinite(x), x, 0.0)
    x = x - x.mean()
    n = len(x)
    f = np.fft.rfft(x, 2 * n)
    r = np.fft.irfft(f * np.conj(f))[: lags + 1]
    return r[1:] / r[0]


def ljung_box(z: np.ndarray, level: float = LEVEL, lags: int = 20) -> Diagnostic:
    """Correlation the model leaves in its innovations: Ljung–Box Q = n(n+2) Σ r_k²/(n−k) over the first ``lags``
    lags, χ² with ``lags`` degrees of freedom under the model."""
    n = int(np.isfinite(z).sum())
    r = acf(z, lags)
    Q = float(n * (n + 2) * np.sum(r * r / (n - np.arange(1, lags + 1))))
    p = float(stats.chi2.sf(Q, lags))
    bound = stats.norm.isf(level / (2 * lags)) / math.sqrt(n)
    big = np.nonzero(np.abs(r) > bound)[0] + 1
    summary = (f"innovations correlated (Q = {Q:.1f} on {lags} lags" +
               (f"; lags {', '.join(map(str, big[:6]))} beyond ±{bound:.3f})" if len(big) else ")")
               if p < level else f"innovations uncorrelated (Q = {Q:.1f} on {lags} lags)")
    return Diagnostic("ljung-box", "lag", Q, p, level, summary, "lag", [[int(b), int(b)] for b in big], [],
                      {"acf": r.tolist(), "band": float(bound)})


# --------------------------------------------------------------------------- frequency


def spectrum_bands(z: np.ndarray, h: float, level: float = LEVEL, bands: int = 24,
                   min_ordinates: int = 8) -> Diagnostic:
    """The frequency bands where the model's spectrum is too low or too high: the innovations' periodogram (2π ×,
    unit mean under the model) averaged over ``bands`` log-spaced bands of at least ``min_ordinates`` ordinates;
    a band mean of m ordinates is Gamma(m)/m, tested two-sided at ``level``/(bands). The statistic, ``psd_misfit``,
    is the bands' mean |log₁₀ ratio|."""
    j, u = innovation_periodogram(z)
    N = len(z)
    edges = np.unique(np.rint(np.geomspace(1, j[-1] + 1, bands + 1)).astype(int))
    merged = [edges[0]]
    for e in edges[1:]:
        if e - merged[-1] >= min_ordinates or e == edges[-1]:
            merged.append(e)
    if len(merged) > 2 and merged[-1] - merged[-2] < min_ordinates:
        merged.pop(-2)
    lo_hz, hi_hz, ratio, p, m = [], [], [], [], []
    for a, b in zip(merged[:-1], merged[1:]):
        sel = (j >= a) & (j < b)
        mm = int(sel.sum())
        if mm == 0:
            continue
        r = float(u[sel].mean())
        ratio.append(r)
        m.append(mm)
        lo_hz.append((a - 0.5) / (N * h))
        hi_hz.append((b - 0.5) / (N * h))
        p.append(float(_two_sided(stats.gamma.cdf(mm * r, mm), stats.gamma.sf(mm * r, mm))))
    p = np.array(p)
    B = len(p)
    bad = [(lo_hz[i], hi_hz[i], "high" if ratio[i] > 1 else "low") for i in np.nonzero(p < level / B)[0]]
    ranges, dirs = _merge(bad)
    pmin = float(min(1.0, B * p.min()))
    misfit = float(np.mean(np.abs(np.log10(ratio))))
    if bad:
        words = [f"{lo:.3g}–{hi:.3g} Hz ({'data above the model' if d == 'high' else 'model above the data'})"
                 for (lo, hi), d in zip(ranges, dirs)]
        summary = "spectrum misfit in " + "; ".join(words)
    else:
        summary = f"spectrum inside its band in all {B} bands"
    return Diagnostic("spectrum", "frequency", misfit, pmin, level, summary, "Hz", ranges, dirs,
                      {"band_lo_hz": lo_hz, "band_hi_hz": hi_hz, "ratio": ratio, "ordinates": m, "p": p.tolist()})


def lines(z: np.ndarray, h: float, level: float = LEVEL, neighbours: int = 50, guard: int = 2) -> Diagnostic:
    """Each ordinate against the mean of ``neighbours`` ordinates on each side (skipping ``guard`` next to it):
    u_j / ū ~ F(2, 2K) for independent exponentials, so broad misfit (a wrong slope) does not count as a line.
    Only ordinates with their full ``neighbours`` on both sides are tested (from ``guard + neighbours + 1``
    cycles per record up): at the lowest frequencies a drift the model lacks (random walk, ramp) stands out
    against neighbours on one side only, and a "line" of a cycle or two per record cannot be told from drift."""
    j, u = innovation_periodogram(z)
    N = len(z)
    idx, ratio, logp = against_neighbours(u, neighbours, guard)
    if len(idx) == 0:
        raise ValueError(f"the lines diagnostic needs more than {4 * (guard + neighbours)} samples, got {N}")
    M = len(idx)
    i = int(np.argmin(logp))
    p_any = float(-np.expm1(M * np.log1p(-math.exp(logp[i]))))  # P(min over M of p_j ≤ p) = 1 − (1 − p)^M
    log_p_any = smallest_of_logp(float(logp[i]), M)
    thr = math.log(level / M)
    hits = np.nonzero(logp < thr)[0]
    f_hz = j[idx] / (N * h)
    ranges = [[float(f_hz[k] - 1 / (N * h)), float(f_hz[k] + 1 / (N * h))] for k in hits]
    ranges, dirs = _merge([(a, b, "high") for a, b in ranges])
    summary = (f"narrow-band line(s) at {', '.join(f'{(a + b) / 2:.4g} Hz' for a, b in ranges[:5])}"
               if len(hits) else f"no narrow-band line (largest at {f_hz[i]:.4g} Hz, {ratio[i]:.1f}× its neighbours)")
    return Diagnostic("lines", "frequency", float(ratio[i]), p_any, level, summary, "Hz", ranges, dirs,
                      {"peak_hz": float(f_hz[i]), "peak_ratio": float(ratio[i]), "log_p": log_p_any})


# --------------------------------------------------------------------------- Allan

def stochastic_avar(model, values: dict, h: float, m, temperature=None, n_orders: int = 32) -> np.ndarray:
    """The model's AVAR at cluster sizes ``m``. A temperature-driven order makes the model non-stationary: its
    AVAR is then the average of the stationary AVARs at ``n_orders`` quantiles of the orders α_k the temperature
    gave (locally stationary — exact for τ short against the time the order takes to change)."""
    mod = next(iter(model.modifiers), None)
    if mod is None or temperature is None:
        return allan.model_avar(model, values, h, m)[0]
    order = model.order_name
    comp = dict(model.components)[mod]
    v = {p.name: torch.tensor([float(values[f"{mod}.{p.name}"])], dtype=torch.float64) for p in comp.params}
    a = comp.orders(v, torch.tensor([float(values[order])], dtype=torch.float64),
                    torch.as_tensor(np.asarray(temperature, dtype=np.float64)))[0].numpy()
    qs = np.quantile(a, (np.arange(n_orders) + 0.5) / n_orders)
    still = model.without(comp.name)  # the model at each of those orders held constant
    batch = {k: [float(values[k])] * n_orders for k in still.names}
    batch[order] = qs.tolist()
    return allan.model_avar(still, batch, h, m).mean(axis=0)


def allan_view(model, values: dict, inn: Innovations, h: float, level: float = LEVEL,
               temperature=None) -> Diagnostic:
    """The data's overlapping Allan variance at octave τ (allantools) against the model's own (its stochastic
    components in closed form, its means' deterministic AVAR), each τ χ² with Greenhall's equivalent degrees of
    freedom, two-sided at ``level``/(τ values). Fails at the τ ranges outside the band; the statistic,
    ``adev_misfit``, is the mean |log₁₀(ADEV data / ADEV model)|. Needs a complete series."""
    y = inn.y
    if not inn.observed.all():
        return Diagnostic("allan", "Allan", None, None, level, "not run: the overlapping ADEV needs a complete "
                          "series (this one has missing samples)", "s")
    m = allan.octave_clusters(len(y))
    stoch = stochastic_avar(model, values, h, m, temperature)
    det = allan.deterministic_avar(inn.mean - inn.mean.mean(), m)
    av_model = stoch + det
    ad = allan.data_adev(y, h, m)
    alpha = allan.power_law_alpha(av_model, m)
    edf = allan.allan_edf(alpha, m, len(y))
    x = edf * ad ** 2 / av_model
    p = _two_sided(stats.chi2.cdf(x, edf), stats.chi2.sf(x, edf))
    T = len(m)
    q_lo = stats.chi2.ppf(level / (2 * T), edf) / edf
    q_hi = stats.chi2.isf(level / (2 * T), edf) / edf
    tau = m * h
    bad = []
    for i in np.nonzero(p < level / T)[0]:
        lo = tau[i] / math.sqrt(2) if i == 0 else math.sqrt(tau[i - 1] * tau[i])
        hi = tau[i] * math.sqrt(2) if i == T - 1 else math.sqrt(tau[i] * tau[i + 1])
        bad.append((lo, hi, "high" if ad[i] ** 2 > av_model[i] else "low"))
    ranges, dirs = _merge(bad)
    misfit = float(np.mean(np.abs(np.log10(ad / np.sqrt(av_model)))))
    if bad:
        summary = "ADEV outside the model's band at τ " + "; ".join(
            f"{a:.3g}–{b:.3g} s ({'data above' if d == 'high' else 'data below'})" for (a, b), d in zip(ranges, dirs))
    else:
        summary = f"ADEV inside the model's band at all {T} octave τ"
    return Diagnostic("allan", "Allan", misfit, float(min(1.0, T * p.min())), level, summary, "s", ranges, dirs,
                      {"tau_s": tau.tolist(), "adev": ad.tolist(), "adev_model": np.sqrt(av_model).tolist(),
                       "adev_model_stochastic": np.sqrt(stoch).tolist(), "edf": edf.tolist(),
                       "band_lo": (np.sqrt(av_model * q_lo)).tolist(), "band_hi": (np.sqrt(av_model * q_hi)).tolist(),
                       "p": p.tolist()})


# --------------------------------------------------------------------------- inputs

def temperature_view(inn: Innovations, T, h: float, level: float = LEVEL, max_lag_s: float = 10.0) -> Diagnostic:
    """The innovations against the temperature ``T`` (°C): the score test of a term proportional to the
    temperature (z against the whitened temperature, χ²₁) and the correlation of z² − 1 with the temperature (a
    variance that moves with it, normal), Bonferroni over the two. Not run without a temperature channel. The
    cross-correlations at lags up to ``max_lag_s`` are kept for the figure."""
    if T is None:
        return Diagnostic("temperature", "inputs", None, None, level, "not run: no temperature channel "
                          "(--temperature COL)")
    T = np.asarray(T, dtype=np.float64)
    z = inn.z
    ok = np.isfinite(z)
    wl = whiten_with_level(inn, T - T[inn.observed].mean())  # = linear_lr, keeping w for the figure
    score, beta = gls_statistic(z, wl[:1], wl[1:])
    w = wl[0]
    p_bias = float(stats.chi2.sf(score, 1))
    Tc = T[ok] - T[ok].mean()
    zz = z[ok] ** 2 - 1.0
    n = int(ok.sum())
    r_var = float(np.corrcoef(zz, Tc)[0, 1]) if Tc.std() > 0 else 0.0
    z_var = r_var * math.sqrt(n)
    p_var = float(2 * stats.norm.sf(abs(z_var)))
    p = float(min(1.0, 2 * min(p_bias, p_var)))
    # cross-correlations at lags (for the figure): z with the whitened temperature, z² with the temperature
    L = int(min(max_lag_s / h, len(z) // 10))
    lags = np.arange(-L, L + 1)
    step = max(1, L // 100)
    lags = lags[::step]
    wz = np.where(ok, z, 0.0)
    ww = np.where(np.isfinite(w), w, 0.0)
    xc = [float(np.dot(wz[max(0, -k):len(wz) - max(0, k)], ww[max(0, k):len(ww) - max(0, -k)]) /
                math.sqrt(np.dot(wz, wz) * np.dot(ww, ww))) for k in lags]
    parts = []
    if p_bias < level / 2:
        parts.append(f"the innovations follow the (whitened) temperature (score {score:.1f}, ≈ {beta[0]:.3g} units/°C)")
    if p_var < level / 2:
        parts.append(f"their variance moves with the temperature (r = {r_var:+.3f})")
    summary = "; ".join(parts) if parts else "no temperature dependence of the innovations or their variance"
    return Diagnostic("temperature", "inputs", float(max(score, z_var * z_var)), p, level, summary, "",
                      [], [], {"score_bias": score, "p_bias": p_bias, "bias_per_degC_gls": float(beta[0]),
                               "r_variance": r_var, "p_variance": p_var, "lags_s": (lags * h).tolist(),
                               "xcorr_whitened": xc})


# --------------------------------------------------------------------------- all of them

def run_diagnostics(model, values: dict, inn: Innovations, h: float, temperature=None,
                    level: float = LEVEL) -> list[Diagnostic]:
    z = inn.z
    return [nis_windows(z, h, level), change(z, h, level), extremes(z, h, level), ljung_box(z, level),
            spectrum_bands(z, h, level),
            lines(z, h, level), allan_view(model, values, inn, h, level, temperature), temperature_view(inn, temperature, h, level)]


#: Each diagnostic :func:`run_diagnostics` runs, in its order: its name and the function that makes it (the
#: reference pages are made from this and the functions' docstrings).
FUNCTIONS = {"nis": nis_windows, "change": change, "extremes": extremes, "ljung-box": ljung_box,
             "spectrum": spectrum_bands, "lines": lines, "allan": allan_view, "temperature": temperature_view}


def metrics(inn: Innovations, diags: list[Diagnostic]) -> dict:
    d = {x.name: x for x in diags}
    return {"nll_per_sample": -inn.loglik / int(inn.observed.sum()),
            "psd_misfit": d["spectrum"].statistic,
            "adev_misfit": d["allan"].statistic,
            "nis": d["nis"].statistic}


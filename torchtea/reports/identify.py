"""The numbers of an identification and how far to trust them (paper §5): per channel the order α̂ and parameter ŵ,
final and over the last third, the filters' own σ, NIS, settling (:func:`summarise`), and where a result should not
be trusted (:func:`trust_warnings`): a filter whose innovations are far from the variance it predicts, an order stuck
at its bound, an estimate that never left its start value, an estimate still drifting at the end. Every number says
what it is and over which span (``summary["meaning"]``). The run itself is :func:`torchtea.identification.identify`.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch

from ..core.stats import last_third, mean_nis
from ..engines.results import TEAResult
from ..engines.settings import TEAConfig
from ..engines.tea import CLAMP_NOTE
from ..render.text import num

__all__ = ["identify_lines", "AXES", "mean_or_nan", "sd_or_nan", "MIN_SAMPLES", "NIS_TRUST_BAND", "SETTLE_BAND", "DRIFT_BAND",
           "ALPHA_SD_LIMIT", "summarise", "settle_time", "trust_warnings", "filter_sd_label", "estimate_meaning"]

AXES = ("x", "y", "z")


#: Fewest samples ``identify`` accepts: the last third, over which the estimates are summarised, then has
#: at least 33 samples.
MIN_SAMPLES = 100

#: A mean NIS over the last third outside this band means the filter's predicted innovation variance is
#: off by more than a factor of 2 from what the data show (1 for a consistent filter).
NIS_TRUST_BAND = (0.5, 2.0)

#: An order estimate has settled once it stays within this distance of its last-third mean.
SETTLE_BAND = 0.05

#: KFo's own σ of the order at the last sample above which the order is called poorly determined.
ALPHA_SD_LIMIT = 0.1

#: An estimate is still drifting when the means of the two halves of the last third differ by more than this
#: (times ``max(1, |ŵ|)`` for the parameter).
DRIFT_BAND = 0.025


def settle_time(est: np.ndarray, t: np.ndarray, target: float, band: float = SETTLE_BAND) -> float:
    """First time after which ``|est − target| ≤ band`` holds to the end; NaN unless that covers at
    least the last third (``target`` is the last-third mean, so less would say nothing)."""
    if not math.isfinite(target):
        return math.nan
    outside = np.flatnonzero(np.abs(est - target) > band)
    first = 0 if outside.size == 0 else outside[-1] + 1
    if first >= len(est) or first > len(est) - len(est) // 3:
        return math.nan
    return float(t[first])


def filter_sd_label(config: TEAConfig, which: str = "KFo") -> str:
    """What √Pᵒ (``which="KFo"``) or √Pʷ (``"KFw"``) is under ``config.estimate_uncertainty``."""
    if config.kfo_kfw == "joint":
        return (f"the {'order' if which == 'KFo' else 'parameter'}'s marginal standard deviation in the joint filter "
                "over order and pole (kfo_kfw = joint)")
    if config.estimate_uncertainty == "constant-truth":
        return (f"the standard deviation of {which}'s error if the true "
                f"{'order' if which == 'KFo' else 'parameter'} is constant (estimate_uncertainty = constant-truth)")
    return f"{which}'s own standard deviation"


def estimate_meaning(k0: int, N: int, h: float, config: TEAConfig) -> dict:
    """What each per-axis estimate of ``summary.json`` means, for a run whose last third starts at sample ``k0`` of
    ``N`` (sample time ``h``) with the TEA settings ``config``; the file carries it."""
    span = f"samples {k0}–{N - 1} ({k0 * h:.2f}–{(N - 1) * h:.2f} s)"
    return {
        "alpha": f"mean of the order estimate α̂ over the last third, {span}",
        "alpha_std_last_third": "standard deviation of α̂ over the last third: how much the estimate still "
                                "moves, not an uncertainty of the order",
        "alpha_final": "α̂ at the last sample",
        "alpha_filter_sd_final": f"√Pᵒ at the last sample: {filter_sd_label(config)} (not a calibrated "
                                 "interval; see experiments/montecarlo/README.md for its measured coverage)",
        "param": f"mean of the parameter estimate ŵ over the last third, {span}",
        "param_std_last_third": "standard deviation of ŵ over the last third (movement, not uncertainty)",
        "param_final": "ŵ at the last sample",
        "param_filter_sd_final": f"√Pʷ at the last sample: {filter_sd_label(config, 'KFw')}",
        "R": "measurement-noise variance R given to KFx [unit²]; KFo's and KFw's R "
             + ("KFx's innovation covariance of the step before where set to \"innovation\" (kfo.R/kfw.R), "
                "else this R" if config.innovation_r else "the same"),
        "innovation_nis": "mean normalised innovation squared e²/S of KFx over the whole run (observed samples, "
                          "k ≥ 1); 1 for a consistent filter",
        "innovation_nis_last_third": f"the same over the last third, {span}",
        "alpha_settle_s": f"time from which α̂ stays within ±{SETTLE_BAND} of its last-third mean (null: not "
                          "within the last third)",
        "alpha_drift_last_third": "mean of α̂ over the second half of the last third minus that over the first half "
                                  f"(warned about beyond ±{DRIFT_BAND})",
        "missing_samples": "samples of this series that were missing (predicted through, left out of statistics)",
        "alpha_at_bound_fraction": "fraction of the last third at which α̂ sits on a bound of order_bounds",
        "alpha_start": "KFo's initial order α₀", "param_start": "KFw's initial parameter w₀",
        "alpha_prior_sd": "√P₀ᵒ, KFo's initial standard deviation", "param_prior_sd": "√P₀ʷ, KFw's",
        "alpha_max_move": "largest |α̂ − α₀| over the run", "param_max_move": "largest |ŵ − w₀| over the run",
        "param_settle_s": "time from which ŵ stays within ±param_settle_band of its last-third mean (null: not "
                          "within the last third)",
        "param_settle_band": f"{SETTLE_BAND} × max(1, |ŵ|)",
        "param_drift_last_third": "as alpha_drift_last_third, for ŵ (warned about beyond "
                                  f"±{DRIFT_BAND} × max(1, |ŵ|))",
        "warnings": "where a number of this series should not be trusted, and why",
        "mean_removed": "the series' mean, removed before estimation (in unit)",
        "unit": "the channel's unit (m/s² for an accelerometer axis, rad/s for a gyroscope axis); R and every "
                "variance are in unit²",
        "memory_clamped_steps": "soe memory: steps at which a KFo sigma order left the kernel's range",
        "diverged": "the TEA flagged the run as diverged (estimates frozen from there)",
    }


def trust_warnings(axis: str, s: dict, config: TEAConfig) -> list[str]:
    """Where the summary ``s`` of one series (an entry of :func:`summarise`'s ``axes``) should not be trusted;
    ``axis`` names it in the messages (e.g. ``"axis x"``)."""
    out = []
    lo, hi = NIS_TRUST_BAND
    nis = s["innovation_nis_last_third"]
    if not math.isfinite(nis):
        out.append(f"{axis}: NIS over the last third cannot be computed (no observed sample there): the filter's "
                   "consistency with the data is unchecked")
    elif not lo <= nis <= hi:
        ratio = nis if nis > 1 else 1 / nis
        side = "smaller" if nis < 1 else "larger"
        out.append(f"{axis}: NIS over the last third is {nis:.3g}, outside [{lo:g}, {hi:g}]: the innovations' variance "
                   f"is {ratio:.3g}× {side} than KFx predicts, so the filter is not consistent with the data — the noise "
                   "levels (Q, R) do not match this sensor and α̂, ŵ are conditional on them")
    sd = s["alpha_filter_sd_final"]
    if sd > ALPHA_SD_LIMIT:
        out.append(f"{axis}: α̂ is poorly determined: σ at the last sample is {sd:.3g}, {filter_sd_label(config)} "
                   f"(α̂ ± 2σ = "
                   f"{s['alpha_final']:.3g} ± {2 * sd:.2g}), so these data do not pin the order down")
    b_lo, b_hi = config.order_bounds
    frac = s["alpha_at_bound_fraction"]
    if frac > 0.1:
        out.append(f"{axis}: α̂ sits at its bound (order_bounds [{b_lo:g}, {b_hi:g}]) at {frac * 100:.0f} % of the "
                   "last third: the order is not identified inside the bounds")
    for name, label, start, sd0 in (("alpha", "α̂", s["alpha_start"], s["alpha_prior_sd"]),
                                    ("param", "ŵ", s["param_start"], s["param_prior_sd"])):
        if s[f"{name}_max_move"] < 0.01 * sd0:
            out.append(f"{axis}: {label} never left its start value {start:g} (it moved at most "
                       f"{s[f'{name}_max_move']:.2g}, under 1 % of its prior sd {sd0:.3g}): the data did not inform it")
    for name, label, band in (("alpha", "α̂", DRIFT_BAND), ("param", "ŵ", DRIFT_BAND * max(1.0, abs(s["param"])))):
        drift = s[f"{name}_drift_last_third"]
        if not math.isfinite(drift):
            out.append(f"{axis}: too few steps to tell whether {label} still drifts")
        elif abs(drift) > band:
            limit = f"{band:.3g}" if name == "alpha" else f"{band:.3g} = {DRIFT_BAND} × max(1, |ŵ|)"
            out.append(f"{axis}: {label} is still drifting: its mean moved by {drift:+.3g} between the two halves of "
                       f"the last third (more than {limit}); a longer recording may give another value")
    return out


def mean_or_nan(x) -> float:
    """Mean of the entries; NaN when there are none."""
    return float(np.mean(x)) if np.size(x) else math.nan


def sd_or_nan(x) -> float:
    """Sample standard deviation; NaN with fewer than two entries."""
    return float(np.std(x, ddof=1)) if np.size(x) > 1 else math.nan


def summarise(result: TEAResult, configs, means=None, *, y: torch.Tensor | None = None, h: float = 1.0,
              names=AXES, label: str = "axis {}") -> dict:
    """Per-series order and parameter (final, and mean/std over the last third), the filter's own sd, NIS
    (observed samples only), settling, and the trust warnings, for a result of batch ``(B,)``.

    ``y`` ``(B, N, 1)`` marks missing samples (NaN) — the whole series, also when the run was interrupted
    before its end; ``h`` is the sample time; ``names`` the B series' keys and ``label`` how the warnings name
    them. Returns ``{"axes", "warnings", "meaning", "last_third"}``."""
    if result.steps is not None and result.steps.numel() > 1 and int(result.steps[1] - result.steps[0]) != 1:
        raise ValueError("summarise needs every step of the run (run_tea with record_every=1)")
    axes = {}
    warnings = []
    N = result.alpha.shape[-2]
    if N < MIN_SAMPLES:
        warnings.append(f"only {N} steps: the last-third statistics need at least {MIN_SAMPLES} and are not "
                        "meaningful below that")
    third = last_third(N)
    t = np.arange(N) * h
    k0 = third.start
    half = k0 + (N - k0) // 2
    for i, axis in enumerate(names[: result.alpha.shape[0]]):
        cfg = configs[i]
        a = result.alpha[i, :, 0].numpy()
        w = result.w[i, :, 0].numpy()
        observed = torch.ones(N, dtype=torch.bool) if y is None else ~torch.isnan(y[i, :N, 0])
        obs1 = observed.clone()
        obs1[0] = False  # k = 0 is KFx's update from its prior only
        nis_all = float(mean_nis(result.innovation[i], result.innovation_cov[i], obs1))
        obs3 = obs1.clone()
        obs3[:k0] = False
        nis_third = float(mean_nis(result.innovation[i], result.innovation_cov[i], obs3))
        s = {
            "alpha": mean_or_nan(a[third]),
            "param": mean_or_nan(w[third]),
            "alpha_std_last_third": sd_or_nan(a[third]),
            "param_std_last_third": sd_or_nan(w[third]),
            "alpha_final": float(a[-1]),
            "param_final": float(w[-1]),
            "alpha_filter_sd_final": math.sqrt(max(float(result.P_alpha[i, -1, 0, 0]), 0.0)),
            "param_filter_sd_final": math.sqrt(max(float(result.P_w[i, -1, 0, 0]), 0.0)),
            "R": float(cfg.kfx.R),
            "diverged": bool(result.diverged[i]),
            "innovation_nis": nis_all,
            "innovation_nis_last_third": nis_third,
            "missing_samples": int((~observed).sum()),
        }
        lo, hi = cfg.order_bounds
        s["alpha_at_bound_fraction"] = mean_or_nan((a[third] <= lo + 1e-9) | (a[third] >= hi - 1e-9))
        s["alpha_start"], s["param_start"] = float(cfg.kfo.x0), float(cfg.kfw.x0)
        s["alpha_prior_sd"] = math.sqrt(float(np.max(np.atleast_1d(cfg.kfo.P0))))
        s["param_prior_sd"] = math.sqrt(float(np.max(np.atleast_1d(cfg.kfw.P0))))
        s["alpha_max_move"] = float(np.max(np.abs(a - s["alpha_start"])))
        s["param_max_move"] = float(np.max(np.abs(w - s["param_start"])))
        s["alpha_settle_s"] = settle_time(a, t, s["alpha"])
        s["param_settle_band"] = SETTLE_BAND * max(1.0, abs(s["param"]))
        s["param_settle_s"] = settle_time(w, t, s["param"], band=s["param_settle_band"])
        s["alpha_drift_last_third"] = mean_or_nan(a[half:]) - mean_or_nan(a[k0:half])
        s["param_drift_last_third"] = mean_or_nan(w[half:]) - mean_or_nan(w[k0:half])
        if means is not None:
            s["mean_removed"] = float(means[i])
        if s["diverged"]:
            warnings.append(f"{label.format(axis)}: the TEA diverged at step {int(result.diverged_at[i])}; its estimates are "
                            "frozen at the last good step")
        s["warnings"] = trust_warnings(label.format(axis), s, cfg)
        if result.memory_clamped is not None:
            s["memory_clamped_steps"] = int(result.memory_clamped[i])
            if s["memory_clamped_steps"]:
                s["warnings"].append(f"{label.format(axis)}: " + CLAMP_NOTE.format(n=s["memory_clamped_steps"]))
        warnings += s["warnings"]
        axes[axis] = s
    if result.interrupted:
        total = N if y is None else y.shape[-2]
        warnings.append(f"interrupted (Ctrl-C) after {N} of {total} steps: every number covers only those steps, "
                        "and the outputs hold those steps only")
    return {"axes": axes, "warnings": warnings, "meaning": estimate_meaning(k0, N, h, configs[0]),
            "last_third": {"first_sample": k0, "last_sample": N - 1, "t0_s": k0 * h, "t1_s": (N - 1) * h}}


def identify_lines(ident, summary: dict, m, *, model, fits, r_mode: str, config_source: str | None, out_dir,
                   seconds: float) -> list[str]:
    """What ``torchtea identify`` prints for an identification ``ident`` of the channels ``m`` (its ``summary``, as
    :func:`~torchtea.reports.report.save_identification` wrote it to ``out_dir``): the recording and the settings,
    the channels' models in the TEA, each channel's fit, the missing samples, a table of the estimates (what each
    column means under it), where the outputs are. ``model``: the one model of every channel (None: each its
    checked one); ``fits``: the check's fits the channels ran, or None."""
    rec = m.recording
    used = "the paper's §5.1 MEMS settings" + (f" changed by {config_source}" if ident.changes else "")
    noise = {"measured": "measured variance",
             "fitted": "fitted r̂ and Q = fitted q̂ (" + (model.spec if model else "each channel's checked model")
             + (", check's fit" if fits else ", exact likelihood") + ")"}.get(r_mode, "paper values")
    lines = [f"{Path(rec.path).name}: {summary['samples']} samples at {rec.rate_hz:g} Hz (rate from "
             f"{rec.rate_source}), mean removed per channel, TEA with {used}, R = {noise}"]
    for a, v in zip(ident.labels, ident.views):
        if v.model.spec != "fractional+white":
            lines.append(f"{a}: {v.model.spec} in the TEA: " + "; ".join(f"{lb}: {v.notes[lb]}" for lb in v.notes))
    lines.append("channels: " + "; ".join(f"{c.label} = {c.title}" for c in m.channels))
    for a, fs in summary.get("fit", {}).items():
        lines.append(_fit_line(a, fs, summary["axes"][a]["unit"], ident.h))
    lines.append(f"missing samples: {ident.missing.describe()}")
    lines.append(f"{'chan':>4} {'R [unit²]':>12} {'α̂ last⅓':>9} {'sd last⅓':>9} {'α̂ final':>9} "
                 f"{'ŵ last⅓':>9} {'sd last⅓':>9} {'ŵ final':>9} {'NIS last⅓':>9}")
    for a, s in summary["axes"].items():
        lines.append(f"{a:>4} {s['R']:12.3e} {s['alpha']:9.4f} {s['alpha_std_last_third']:9.4f} "
                     f"{s['alpha_final']:9.4f} {s['param']:9.4f} {s['param_std_last_third']:9.4f} "
                     f"{s['param_final']:9.4f} {num(s['innovation_nis_last_third'], '9.3f')}"
                     + ("  DIVERGED" if s["diverged"] else ""))
    lines.append("last⅓: over samples {first_sample}–{last_sample}; sd: how much the estimate moves there, not an "
                 "uncertainty; NIS: 1 for a consistent filter".format(**summary["last_third"]))
    lines.append(f"outputs in {out_dir}/ (report.md; {seconds:.1f} s)")
    return lines


def _fit_line(a: str, fs: dict, unit: str, h: float) -> str:
    """One channel's fit in a line: α̂ with its interval, f̂, q̂, the other parameters, the white-noise density, the
    NIS of the fit."""
    p_ = fs["parameters"]
    c = p_["fractional.order"]["ci95"]
    others = ", ".join(f"{n} {p_[n]['value']:.3g}" for n in p_ if not n.startswith("fractional."))
    return (f"fit {a}: α̂ {p_['fractional.order']['value']:.3f} "
            + (f"({p_['fractional.order']['ci95_method']})" if c is None else f"[{c[0]:.3f}, {c[1]:.3f}] 95 % CI")
            + f", f̂ {p_['fractional.pole']['value']:.3g}, q̂ {p_['fractional.q']['value']:.3g}, {others}"
            + (f" (white-noise density {math.sqrt(p_['white.r']['value'] * h):.3g} {unit}/√Hz)"
               if "white.r" in p_ else "") + f", NIS of the fit {fs['nis']:.3f}")

"""The identification report: per-channel results as Markdown with PNG figures, and TensorBoard logs."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..core.stats import last_third
from ..identification import Identification
from ..noise.model import PAPER_MODEL
from ..sensors.datacheck import MISSING_POLICY
from .identify import NIS_TRUST_BAND, SETTLE_BAND, filter_sd_label, mean_or_nan, settle_time

__all__ = ["settle_time", "axis_statistics", "write_report", "log_identification", "orders_figure",
           "save_identification", "SUMMARY_MEANING"]


#: What the entries of ``summary.json`` that are not per-axis estimates mean (the estimates':
#: :func:`~torchtea.reports.identify.estimate_meaning`); the file carries both.
SUMMARY_MEANING = {
    "fit": "per channel: maximum-likelihood fit of the model (exact likelihood) whose r̂, q̂, α̂, f̂ (and its other "
           "states' drives) set the TEA (r_mode fitted); see torchtea fit --json for the meaning of its entries",
    "model": "the noise model fitted and run by the TEA ('per channel' when the channels' models differ: models)",
    "models": "each channel's model",
    "tea_model": "per channel, each component of its model: what the TEA does with it",
    "statistics": "per channel: noise variance and std over all samples used; over the last third the mean squared "
                  "innovation, its predicted value S and the residual y − x̂ variance; settling times [s]",
    "timing": "the file's time stamps against the rate in use (null: the file has no time column)",
    "rate_source": "where rate_hz came from", "channels": "each channel: its column, sensor, axis, unit (SI) "
    "and what the file held", "faults": "the recording's own faults, found before any fit (their samples are "
    "missing samples)", "r_mode": "fitted: R, Q and the start values from a likelihood fit; measured: R = each axis's "
              "variance; paper: the paper's printed R",
    "seconds": "wall-clock time of the TEA", "steps_done": "steps the TEA finished (samples unless interrupted)",
    "settings_changed": "settings that differ from the paper's §5.1 MEMS settings with measured R",
}


def _uncertainty_note(cfg) -> str:
    """What KFx's P and S and KFo's/KFw's covariances mean under the settings used (TEAConfig's two uncertainty
    settings, or the exact filter as KFx; the defaults are not the paper's for KFx)."""
    if cfg.kfx_filter == "exact":
        kfx = ("`kfx_filter = \"exact\"` (not in the paper): KFx is the exact Kalman filter of the model's state "
               "space, its P and S that filter's at the current order and parameter estimates")
    else:
        kfx = {"paper": "`kfx_uncertainty = \"paper\"`: KFx's P and S as the paper computes them (the order and "
                        "parameter taken as exact)",
               "paper-gain": "`kfx_uncertainty = \"paper-gain\"` (default, not in the paper): the paper's estimates, "
                             "with KFx's P and S including the order's and parameter's uncertainty",
               "propagated": "`kfx_uncertainty = \"propagated\"` (not in the paper): the order's and parameter's "
                             "uncertainty in KFx's prediction and gain"}[cfg.kfx_uncertainty]
    est = {"paper": "Pᵒ and Pʷ the filters' own", "constant-truth": "Pᵒ and Pʷ those of a constant order and "
                                                                        "parameter (`estimate_uncertainty`)"}
    if cfg.kfo_kfw == "joint":
        return (kfx + "; `kfo_kfw = \"joint\"` (not in the paper): one unscented filter over order and pole, Pᵒ and Pʷ "
                "the diagonal of its covariance (their cross term is not reported)")
    return kfx + "; " + est[cfg.estimate_uncertainty]


def axis_statistics(ident: Identification, axes: dict) -> dict:
    """Per axis: sample variance and standard deviation of the (mean-removed) noise over the part used,
    the KFx innovation variance (observed samples), its predicted variance and the residual variance over
    the last third, and the settling times of ``axes`` (``ident.summary()["axes"]``)."""
    res = ident.result
    N = ident.steps
    third = last_third(N)
    out = {}
    for i, axis in enumerate(ident.labels):
        y = ident.y[i, :N, 0].numpy()
        x = ident.output(i).numpy()
        e = res.innovation[i, :, 0].numpy()
        obs = ~np.isnan(y)
        s = axes[axis]
        out[axis] = {
            "noise_var": float(np.nanvar(y)),  # identify() guarantees observed samples on every axis
            "noise_std": float(np.nanstd(y)),
            "innovation_var_last_third": mean_or_nan(e[third][obs[third]] ** 2),
            "predicted_innovation_var_last_third": mean_or_nan(res.innovation_cov[i, third, 0, 0].numpy()[obs[third]]),
            "residual_var_last_third": mean_or_nan((y - x)[third][obs[third]] ** 2) - mean_or_nan((y - x)[third][obs[third]]) ** 2,
            "alpha_settle_s": s["alpha_settle_s"],
            "param_settle_s": s["param_settle_s"],
            "missing_samples": int((~obs).sum()),
        }
    return out


def _fmt(v: float, spec: str = ".4f") -> str:
    return "—" if v is None or (isinstance(v, float) and math.isnan(v)) else format(v, spec)


def write_report(path, ident: Identification, summary: dict, figures: list, *, command: str = "",
                 config_source: str | None = None) -> Path:
    """``report.md``: what was measured, the settings and what changed in them, the warnings, per-axis α̂,
    ŵ, noise variances and consistency — each number labelled with what it is and its span — and the
    figures (paths relative to the report)."""
    path = Path(path)
    rec = ident.recording
    n = ident.y.shape[-2]
    done = ident.steps
    lines = [f"# Noise identification: {Path(rec.path).name}", ""]
    if ident.result.interrupted:
        lines += [f"**Interrupted (Ctrl-C) after {done} of {n} steps: every number below covers only those steps.**",
                  ""]
    lines += _source_lines(ident, summary, command, config_source) + [""]
    if summary.get("fit"):
        lines += _fit_lines(ident, summary)
    lines += _results_lines(ident, summary)
    lines += _variance_lines(summary)
    if figures:
        lines += ["## Figures", ""]
        for f in figures:
            rel = Path(f).relative_to(path.parent) if Path(f).is_relative_to(path.parent) else Path(f)
            lines += [f"![{rel.stem}]({rel.as_posix()})", ""]
    lines += ["Trajectories: `trajectories.csv`; per-channel settings: `config_<channel>.toml` (reusable with "
              "`torchtea estimate --config`); TensorBoard: `tensorboard --logdir " + str(path.parent / "tb") + "`.", ""]
    path.write_text("\n".join(lines))
    return path


def _source_lines(ident: Identification, summary: dict, command: str, config_source: str | None) -> list[str]:
    """Writes the list of what was measured: recording, channels, samples, time stamps, faults, missing samples."""
    rec = ident.recording
    meta = rec.metadata
    n = ident.y.shape[-2]
    total = ident.measurements.total if ident.measurements is not None else rec.samples
    src = [f"- **Recording**: `{rec.path}`"]
    if "sensor" in meta:
        src.append(f"- **Sensor**: {meta['sensor']}, digital low-pass {meta.get('dlpf_hz', '?')} Hz")
    src.append("- **Channels**: " + "; ".join(f"{c.label} = column `{c.name}`, {c.sensor} {c.axis if c.sensor != 'signal' else ''}"
                                              f" in {c.unit} (the file: {c.source_unit})" for c in ident.channels))
    if "segment" in meta:
        src.append(f"- **Segment** {meta['segment']} of {len(meta['segments'])} (rows per segment: "
                   + ", ".join(f"{k}: {v}" for k, v in meta["segments"].items()) + ")")
    src.append(f"- **Samples**: {n} of {total} at {rec.rate_hz:g} Hz (rate from {rec.rate_source or 'the file'}), "
               f"{(n - 1) / rec.rate_hz:.1f} s" + ("" if n == total else " — `--samples all` uses the whole recording"))
    tm = ident.timing
    if tm is not None and tm.stamped < 2:
        src.append(f"- **Time stamps** (column `{tm.column}`): {tm.stamped} stamp(s), nothing to check the rate against")
    elif tm is not None:
        src.append(f"- **Time stamps** (column `{tm.column}`) of the samples used: they span {tm.span_s:.1f} s, a mean rate "
                   f"of {tm.stamp_rate_hz:.5g} Hz (the rate in use is {tm.rate_mismatch * 100:+.2f} % from it); intervals median {tm.interval_median_s * 1e3:.3g} ms, "
                   f"99th percentile {tm.interval_p99_s * 1e3:.3g} ms; {tm.irregular_fraction * 100:.1f} % outside 0.5–1.5 h"
                   + (" — see the warnings" if tm.warnings else " — consistent with the rate"))
    meas = ident.measurements
    if meas is not None and meas.faults:
        src.append("- **Recording faults** (treated as missing samples, never as physics): "
                   + " ".join(f"{f.kind}: {f.message}." for f in meas.faults.items))
    miss = ident.missing
    src.append("- **Missing samples** in the part used: " + (miss.describe() if miss is not None else "not checked")
               + ("; the filters predict through them and they are left out of every statistic"
                  if miss is not None and miss.count else ""))
    return src + _settings_lines(ident, summary, command, config_source)


def _settings_lines(ident: Identification, summary: dict, command: str, config_source: str | None) -> list[str]:
    """Writes the settings used, what was changed in them and the command."""
    src = []
    settings = ("- **Settings**: the paper's §5.1 MEMS settings with R = Rᵒ = Rʷ = "
                + {"measured": "each axis's measured noise variance",
                   "fitted": "each axis's fitted white-noise variance r̂, KFx's Q = the fitted drive q̂, KFo and KFw "
                             "started at the fitted α̂ and f̂ (see *Fitted noise model*)"}.get(
                    summary.get("r_mode"), "the paper's printed values")
                + f"; GL history `{summary.get('memory', 'exact')}`; each axis's mean removed"
                + f"; {_uncertainty_note(ident.configs[0])}"
                + ("; KFo's / KFw's R: KFx's innovation covariance of the step before where `R = \"innovation\"` "
                   "(not in the paper)" if ident.configs[0].innovation_r else "")
                + (" — except where listed below" if ident.changes else ""))
    src.append(settings)
    if ident.changes:
        src.append(f"- **Changed from those settings** by {('`' + config_source + '`') if config_source else 'overrides'}: "
                   + "; ".join(f"`{c}`" for c in ident.changes))
    if command:
        src.append(f"- **Command**: `{command}`")
    return src


def _fit_lines(ident: Identification, summary: dict) -> list[str]:
    """Writes the section of the fitted noise model: its table, how the TEA runs it, what the intervals are."""
    lines = ["## Fitted noise model (maximum likelihood, before the TEA)", "",
             (f"`{summary.get('model', 'fractional+white')}`" if summary.get("model") != "per channel" else
              "Each channel's model (below)") + " fitted to each channel by the exact likelihood (Kalman filter on the "
             "exponential-sum state; Whittle gives the start). Changed against the paper: the paper sets "
             "R = Rᵒ = Rʷ to the measurement noise and keeps Q = 0.01; here r and q are the values that make "
             "the model's innovations match the data (NIS of the fitted model ≈ 1), and KFo/KFw start at the "
             "fitted order and pole instead of 1 and 0. The TEA below then shows whether the order moves in "
             "time around that model.", "",
             "| channel | unit | α̂ [95 % CI] | f̂ ± se | q̂ [95 % CI] (unit²) | r̂ [95 % CI] (unit²) | white-noise density √(r̂h) (unit/√Hz) | other parameters | loglik | NIS (fit) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for a, fs in summary["fit"].items():
        lines.append(_fit_row(a, fs, summary["axes"][a]["unit"], ident.h))
    grown = [(a, v) for a, v in zip(ident.labels, ident.views) if v.model.spec != PAPER_MODEL]
    if grown:
        lines += ["", "How the TEA runs these models (each component's place in it):", ""]
        lines += [f"- {a} (`{v.model.spec}`): " + "; ".join(f"`{lb}` {note}" for lb, note in v.notes.items())
                  for a, v in grown]
    lines += ["", "Intervals: Wald on the logit (order) or log (q, r) scale from the exact observed information; "
              "'no interval' where that information is not positive definite (an estimate on a boundary). "
              "The Whittle profile interval of the order is in `summary.json` (`fit.<axis>.order_profile`); "
              "`torchtea fit` adds the test of whether the fractional part is there at all.", ""]
    return lines


def _fit_row(a: str, fs: dict, unit: str, h: float) -> str:
    """Writes one channel's row of the fitted noise model's table."""
    p_ = fs["parameters"]

    def ci(name, fmt):
        c = p_[name]["ci95"]
        return "no interval" if c is None else f"[{c[0]:{fmt}}, {c[1]:{fmt}}]"
    se = p_["fractional.pole"]["se"]
    return (f"| {a} | {unit} | {p_['fractional.order']['value']:.3f} {ci('fractional.order', '.3f')} | "
            f"{p_['fractional.pole']['value']:.3g}" + ("" if se is None else f" ± {se:.2g}")
            + f" | {p_['fractional.q']['value']:.3g} {ci('fractional.q', '.3g')} | "
            + (f"{p_['white.r']['value']:.3g} {ci('white.r', '.3g')} | "
               f"{math.sqrt(p_['white.r']['value'] * h):.3g} | " if "white.r" in p_ else "— | — | ")
            + (", ".join(f"{n} {p_[n]['value']:.3g}" for n in p_
                         if not n.startswith("fractional.") and n != "white.r") or "—")
            + f" | {fs['loglik']:.1f} | {fs['nis']:.3f} |")


def _results_lines(ident: Identification, summary: dict) -> list[str]:
    """Writes the warnings and the results table of α̂ and ŵ, with its footnotes."""
    stats = summary["statistics"]
    span = summary["last_third"]
    third = (f"last ⅓ = samples {span['first_sample']}–{span['last_sample']} "
             f"({span['t0_s']:.2f}–{span['t1_s']:.2f} s)" if span["last_sample"] >= span["first_sample"]
             else "last ⅓ = no samples (too few steps)")
    warns = summary.get("warnings", [])
    lines = ["## Warnings", ""]
    lines += [f"- {w}" for w in warns] if warns else [
        f"None: every axis has NIS over the last third within [{NIS_TRUST_BAND[0]:g}, {NIS_TRUST_BAND[1]:g}], α̂ off its "
        "bounds, α̂ and ŵ moved from their start values and no longer drift."]
    lines += ["", "## Results", "", f"Spans: {third}; final = the last sample.", "",
              "| channel | α̂ mean, last ⅓ | sd of α̂, last ⅓ ¹ | α̂ final | KFo σ(α̂), final ² | ŵ mean, last ⅓ | "
              "sd of ŵ, last ⅓ ¹ | ŵ final | KFw σ(ŵ), final ² | α̂ settled after [s] ³ | diverged |",
              "|---|---|---|---|---|---|---|---|---|---|---|"]
    for a, s in summary["axes"].items():
        st = stats[a]
        lines.append(f"| {a} | {_fmt(s['alpha'])} | {_fmt(s['alpha_std_last_third'])} | {_fmt(s['alpha_final'])} | "
                     f"{_fmt(s['alpha_filter_sd_final'])} | {_fmt(s['param'])} | {_fmt(s['param_std_last_third'])} | "
                     f"{_fmt(s['param_final'])} | {_fmt(s['param_filter_sd_final'])} | "
                     f"{_fmt(st['alpha_settle_s'], '.1f')} | {'**yes**' if s['diverged'] else 'no'} |")
    lines += ["", "¹ How much the estimate still moves over the last third: not an uncertainty of the order or "
              "parameter.  ",
              f"² √Pᵒ, √Pʷ at the last sample: {filter_sd_label(ident.configs[0])}, and the same for KFw: not a "
              "calibrated interval (the Monte Carlo studies in `experiments/montecarlo/README.md` measure its "
              "coverage).  ",
              f"³ The time from which α̂ stays within ±{SETTLE_BAND} of its last-third mean (—: not within the last third).",
              ""]
    return lines


def _variance_lines(summary: dict) -> list[str]:
    """Writes the table of noise variances and filter consistency (NIS)."""
    stats = summary["statistics"]
    lines = ["## Noise variances (in each channel's unit², the unit in the table) and filter consistency", "",
             "| channel | unit | mean removed | noise variance, all samples used | std | R given to KFx | "
             "mean squared innovation, last ⅓ | predicted S = C P̃ Cᵀ + R, last ⅓ | residual y − x̂ variance, last ⅓ | "
             "NIS, last ⅓ | NIS, whole run |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for a, s in summary["axes"].items():
        st = stats[a]
        lines.append(f"| {a} | {s['unit']} | {_fmt(s.get('mean_removed', math.nan), '.5g')} | {st['noise_var']:.4e} | "
                     f"{st['noise_std']:.4e} | {s['R']:.4e} | {st['innovation_var_last_third']:.4e} | "
                     f"{st['predicted_innovation_var_last_third']:.4e} | {st['residual_var_last_third']:.4e} | "
                     f"{_fmt(s['innovation_nis_last_third'], '.3f')} | {_fmt(s['innovation_nis'], '.3f')} |")
    lines += ["", "NIS: mean of e²/S over the observed samples (missing samples have no innovation and are left out); "
              f"1 for a consistent filter; outside [{NIS_TRUST_BAND[0]:g}, {NIS_TRUST_BAND[1]:g}] is warned about.", ""]
    return lines


def orders_figure(path, ident: Identification) -> Path:
    """α̂ of every channel on one plot with ±2σ (the filter's) — convergence at a glance."""
    from ..render.plots import pyplot, save_figure

    plt = pyplot()
    t = ident.t
    res = ident.result
    fig, ax = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    for i, a in enumerate(ident.labels):
        for panel, est, var in ((ax[0], res.alpha[i, :, 0], res.P_alpha[i, :, 0, 0]), (ax[1], res.w[i, :, 0], res.P_w[i, :, 0, 0])):
            e = est.numpy()
            sd = var.clamp(min=0).sqrt().numpy()
            panel.plot(t, e, lw=1.0, color=f"C{i}", label=f"{a}")
            panel.fill_between(t, e - 2 * sd, e + 2 * sd, color=f"C{i}", alpha=0.12, lw=0)
    ax[0].set_ylabel("order α̂")
    ax[1].set_ylabel("parameter ŵ")
    ax[1].set_xlabel("time [s]")
    ax[0].legend(loc="upper right", fontsize=8)
    ax[0].set_title(f"{Path(ident.recording.path).name}: estimates of the channels (±2σ of the filters)")
    return save_figure(plt, fig, path)


def log_identification(logdir, ident: Identification, summary: dict, *, max_points: int = 2000) -> Path:
    """TensorBoard: ``{order,param,innovation,noise}/<axis>`` over the sample index (decimated to
    ≤ ``max_points``) and the report's tables as text."""
    from torch.utils.tensorboard import SummaryWriter

    from ..studies.tblog import decimated_steps

    res = ident.result
    N = ident.steps
    logdir = Path(logdir)
    with SummaryWriter(log_dir=str(logdir)) as w:
        for k in decimated_steps(N, max_points):
            for i, a in enumerate(ident.labels):
                w.add_scalar(f"order/{a}", float(res.alpha[i, k, 0]), k)
                w.add_scalar(f"param/{a}", float(res.w[i, k, 0]), k)
                w.add_scalar(f"innovation/{a}", float(res.innovation[i, k, 0]), k)
                w.add_scalar(f"order_sd/{a}", math.sqrt(max(float(res.P_alpha[i, k, 0, 0]), 0.0)), k)
        table = ["| channel | α̂ mean, last ⅓ | ŵ mean, last ⅓ | R | NIS, last ⅓ |", "|---|---|---|---|---|"]
        table += [f"| {a} | {s['alpha']:.4f} | {s['param']:.4f} | {s['R']:.3e} | {s['innovation_nis_last_third']:.3f} |"
                  for a, s in summary["axes"].items()]
        if summary.get("warnings"):
            table += [""] + [f"- {x}" for x in summary["warnings"]]
        w.add_text("summary", "\n".join(table), 0)
    return logdir


def save_identification(ident: Identification, out_dir, *, plots: bool = True, r_mode: str = "measured",
                        seconds: float | None = None, command: str = "", config_source: str | None = None) -> dict:
    """Everything ``torchtea identify`` writes, into ``out_dir``: ``trajectories.csv``, ``config_<axis>.toml``,
    the figures (per axis like the paper's Figs. 12–20, and ``orders.png``), TensorBoard logs in ``tb/``,
    ``report.md``. Returns the summary (``summary.json`` is the caller's to write, with its warnings)."""
    from ..engines.config import write_config
    from ..sensors.io import write_columns

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rec, res, t = ident.recording, ident.result, ident.t
    N = ident.steps
    summary = ident.summary()
    cols = {"t": t}
    for i, a in enumerate(ident.labels):
        cols.update({f"y_{a}": ident.y[i, :N, 0], f"x_hat_{a}": ident.output(i), f"alpha_{a}": res.alpha[i, :, 0],
                     f"P_alpha_{a}": res.P_alpha[i, :, 0, 0], f"w_{a}": res.w[i, :, 0], f"P_w_{a}": res.P_w[i, :, 0, 0],
                     f"innovation_{a}": res.innovation[i, :, 0], f"innovation_var_{a}": res.innovation_cov[i, :, 0, 0]})
    write_columns(out_dir / "trajectories.csv", cols)
    for i, a in enumerate(ident.labels):
        write_config(out_dir / f"config_{a}.toml", ident.configs[i], {"h": ident.h, "channel": a})
    figures = []
    if plots:
        from ..render.plots import estimation_figure

        for i, (a, c) in enumerate(zip(ident.labels, ident.channels)):
            figures.append(str(estimation_figure(
                out_dir / f"channel_{a}.png", t, y=ident.y[i, :N, 0].numpy(), x_hat=ident.output(i).numpy(),
                alpha_hat=res.alpha[i, :, 0].numpy(), alpha_sd=res.P_alpha[i, :, 0, 0].clamp(min=0).sqrt().numpy(),
                w_hat=res.w[i, :, 0].numpy(), w_sd=res.P_w[i, :, 0, 0].clamp(min=0).sqrt().numpy(),
                title=f"{Path(rec.path).name}: {c.title} noise"
                      + (f" (cf. paper Figs. {12 + 3 * 'xyz'.index(c.axis)}–{14 + 3 * 'xyz'.index(c.axis)})"
                         if c.sensor == "accelerometer" else ""),
                state_label=f"noise [{c.unit}]", zoom=(t[-1] - 5.0, t[-1]))))
        figures.append(str(orders_figure(out_dir / "orders.png", ident)))
    summary.update({"recording": str(rec.path), "samples": int(ident.y.shape[-2]), "steps_done": N,
                    "interrupted": bool(res.interrupted), "h": ident.h, "rate_hz": rec.rate_hz,
                    "rate_source": rec.rate_source, "r_mode": r_mode, "memory": ident.configs[0].memory.spec(),
                    "settings": "the paper's §5.1 MEMS settings" + (f", changed by {config_source}" if ident.changes else ""),
                    "settings_changed": list(ident.changes),
                    "missing_samples": ident.missing.count if ident.missing is not None else None,
                    "missing": ident.missing.to_dict() if ident.missing is not None else None,
                    "missing_policy": MISSING_POLICY,
                    "timing": ident.timing.to_dict() if ident.timing is not None else None,
                    "out": str(out_dir), "figures": figures, "statistics": axis_statistics(ident, summary["axes"])})
    if ident.fits:
        from ..fitting.summary import axis_summary, fit_nis

        fy = ident.y if ident.fitted_y is None else ident.fitted_y
        summary["fit"] = {a: axis_summary(f, nis=fit_nis(f, fy[i, :, 0].numpy(), ident.h))
                          for i, (a, f) in enumerate(zip(ident.labels, ident.fits))}
        specs = {a: f.model.spec for a, f in zip(ident.labels, ident.fits)}
        summary["model"] = next(iter(specs.values())) if len(set(specs.values())) == 1 else "per channel"
        summary["models"] = specs
        if ident.views:
            summary["tea_model"] = {a: dict(v.notes) for a, v in zip(ident.labels, ident.views)}
    summary["meaning"].update(SUMMARY_MEANING)
    for i, c in enumerate(ident.channels):
        summary["axes"][c.label].update(unit=c.unit, sensor=c.sensor, column=c.name,
                                        mean_removed=float(ident.means[i]))
    summary["channels"] = {c.label: c.describe() for c in ident.channels}
    if ident.measurements is not None:
        summary["faults"] = ident.measurements.faults.to_dict()
        summary["warnings"] = [f"recording fault: {x}" for x in ident.measurements.faults.lines()] + summary["warnings"]
    if ident.timing is not None:
        summary["warnings"] = list(ident.timing.warnings) + summary["warnings"]
    if seconds is not None:
        summary["seconds"] = round(seconds, 3)
    if "segment" in rec.metadata:
        summary["segment"] = rec.metadata["segment"]
    summary["tensorboard"] = str(log_identification(out_dir / "tb", ident, summary))
    summary["report"] = str(write_report(out_dir / "report.md", ident, summary, figures, command=command,
                                         config_source=config_source))
    return summary

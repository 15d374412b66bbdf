"""The ``check`` report: ``report.md``, ``check.json`` and the figures, per channel, the sensors side by side.

Figures (matplotlib, Agg): the data's spectrum (log-band averages of the periodogram) against the model's,
with the 99 % band of the band averages and each component's own curve; the overlapping Allan deviation with
its band against the model and its components; the standardised innovations over time with the failing
windows shaded; their autocorrelation; the innovations against the temperature. When there is a
suggestion, the model with it is overlaid (dashed).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch
from scipy import stats

from ..fitting.datasheet import verdict_lines
from ..fitting.plan import plan_document, plan_lines
from ..fitting.windows import WINDOWS_MEANING
from ..likelihood.whittle import periodogram
from ..noise.model import parse_model
from ..render.plots import pyplot, save_figure
from ..render.strictjson import write
from ..sensors.measurements import DOCUMENT_MEANING, RECORDING_MEANING
from . import allan, replicates
from .check import CLOSE_BIC, CheckResult, change_words

__all__ = ["write_report", "axis_document", "figures", "MEANING"]

MEANING = {
    **DOCUMENT_MEANING,
    "adequate": "every diagnostic that ran passed at its level (a test of 'the data came from the fitted model')",
    "nll_per_sample": "−(exact log-likelihood)/(observed samples) at the fit, nats",
    "observed": "the samples the fit saw (missing ones not counted): the n of BIC and of plan's 'this record'",
    "psd_misfit": "mean |log10| of the innovations' band power over log-spaced bands (0 = the model's spectrum matches; 0.01–0.04 "
                  "is the bands' own scatter at 30 000 samples)",
    "adev_misfit": "mean |log10(ADEV data / ADEV model)| over octave τ",
    "failing_ranges_s": "time ranges [t0, t1] (s from the first sample) whose windowed NIS is outside its band",
    "gain": "BIC of the model − BIC with the effect (exact likelihood; > 0 = the effect is worth its parameters)",
    "p_value": "the screen's p-value for the effect (its test is named in 'screen'); suggested when below "
               "screen_level / (effects screened) and gain > 0",
    "repairs": "diagnostics that failed before and pass with the effect",
    "steps": "the checks of the loop (--add, --auto), first first: model, nll per sample, misfits, failed "
             "diagnostics; from the second on what changed (change: add, drop, simpler or swap; added, removed: "
             "the effects), its BIC gain, what it repaired and broke",
    "loop_end": "why --auto stopped: the model adequate, no effect passing its screen, or the step limit",
    "unexplained": "failed diagnostics that no suggestion repairs: where, what kind of effect would fit that "
                   "signature, and which of those effects check screened (in_library), the library has but does not "
                   "screen (add_by_hand: --add them) or lacks (not_in_library); for a failure located in time, the "
                   "--exclude flags that would leave those stretches out (exclude)",
    "seconds": "(per axis) wall-clock seconds of the axis's whole check, every step of the loop (seconds_this_step: "
               "the last step's; a step row's seconds and timings: that step's, by stage)",
    "excluded": "stretches left out on request (--exclude): their samples missing, or cut at the end",
    "refit_failed": "(a screen's row) its screen passed, but the exact refit of the model with it gained far less than "
                    "the screen's statistic and lowered no BIC: the fit failed, which is no evidence against it",
    "model": "the model the check ended with (with --auto: the loop's last), as a spec (components joined by +)",
    "base": "that model's fit: the metrics, failed diagnostics, parameters with se, ci95 and ci95_method, exact "
            "loglik, bic and observed, and its method",
    "method": "how the model was fitted: exact (the exact likelihood's maximum) or whittle (the long-record path: "
              "the Whittle likelihood's, the exact log-likelihood evaluated there — loglik and bic are the exact ones, "
              "the intervals from the exact likelihood's information at the estimate)",
    "diagnostics": "one row per diagnostic: name, domain, statistic, p_value, level, passed (null: not run), "
                   "summary, and where it fails (ranges in unit, directions: high = the data above the model)",
    "screens": "one row per effect screened: its test, statistic, p_value (log10_p), whether it passed, and why "
               "not screened where it was not",
    "suggestions": "the effects whose screen passed and whose exact refit lowers BIC, best first: gain, p_value, the "
                   "model with it, its parameters and ci95, the metrics after, what it repairs, notes",
    "seconds_this_step": "wall-clock seconds of the last step of the loop alone",
    "level": "the level of each diagnostic (Bonferroni inside it)",
    "screen_level": "the screens' family level: an effect passes below screen_level / (effects screened)",
    "notes": "what the check did that its numbers alone do not say (refits, restarts, effects skipped)",
    "before": "(after --add) the model before the effect, its metrics, failed diagnostics and bic",
    "sensor": "accelerometer, gyroscope or signal",
    "column": "the recording's column (or bag field) the channel came from",
    "white_noise_density": "√(r h) of the fitted white noise: its density in unit/√Hz",
    "unit": "the channel's unit (m/s² accelerometer, rad/s gyroscope); a parameter's 'units' is it",
    "datasheet": "(--datasheet) the axis's N, B, K held against the datasheet's, with a verdict per term",
    "axes": "one document per channel, by label (a single channel's is also at the top level)",
    "ties": "what the record cannot tell apart from the model the loop ended with: models fitted on the way whose "
            "BIC is within 6 above its own and that are adequate where it is (kind swap: one component for another; "
            "add: one more; drop: one fewer; other), the last step's suggestions that gain less than 6 (kind add, "
            "bic_difference below 0), the model with an effect whose screen did not pass but whose refit is within 6 "
            "either side (kind add), the alternatives up to 6 lower by BIC that fail a diagnostic the model "
            "passes, and the model without one of its effects up to 6 higher by BIC that fails a diagnostic (kind "
            "drop) (fails: those diagnostics; empty for the others); bic_difference: BIC of that model − BIC of "
            "this one; resolve_samples, "
            "resolve_seconds: the record length at which their BIC difference is expected to reach 12 (for add and "
            "drop: if the extra effect is there)",
    "stretch": "(the end of a loop) a stretch that differs which the loop did not fill with spikes or steps: "
               "from_s, to_s (s from the first sample; a range whose windowed NIS fails), spikes of the of outliers "
               "the spikes screen found lie there, exclude the flag that leaves it out; left_out and words where "
               "--exclude-start left it out and checked again; null when there is none",
    "alternatives": "the models the loop's simplification tried from this one (each component dropped, replaced by "
                    "its special cases, each added effect swapped): bic = exact-likelihood BIC (null: not refitted, its "
                    "Whittle BIC more than 20 above the model's), rejected = why one with a lower BIC was not kept",
    "plan": "how long to record: the expected 95 % intervals of the final model's noise numbers (N, K where it has "
            "them, its noise parameters) on records 1×, 4× and 10× this one, if the model at its fitted values is the "
            "truth (the Whittle likelihood's expected information; rows[].relative_half_width = half the interval's "
            "width over the value; torchtea plan for other lengths and targets)",
    "not_confirmed": "(a screen's row) its Whittle screen passed, but the exact likelihood at the screen's own point is "
                     "below the model's and the refit lowered no BIC: the cheap and the exact likelihood disagree on "
                     "this record, no evidence for the effect",
}


def axis_document(res: CheckResult) -> dict:
    d = res.as_dict()
    if res.before is not None:
        d["before"] = {"model": res.before.model.spec, **res.before.metrics, "failed": res.before.failed,
                       "bic": res.before.as_dict()["base"]["bic"]}
    d["plan"] = record_plan(res)
    return d


#: The record lengths, in multiples of this one's, of the plan every check report has.
PLAN_MULTIPLES = (1, 4, 10)


def record_plan(res: CheckResult) -> dict | None:
    """How long to record, from the model the check ended with taken as the truth
    (:func:`~torchtea.fitting.plan.plan_document`): the expected 95 % intervals of its noise numbers on a record as
    long as this one, 4× and 10× it; None where the model has no spectrum to plan from."""
    n = res.fit.n
    try:
        return plan_document(res.model, res.fit.values, res.h, [k * n for k in PLAN_MULTIPLES], recorded=n)
    except (ValueError, RuntimeError, NotImplementedError) as exc:
        return {"notes": [f"no plan: {exc}"], "rows": [], "targets": []}


def _component_models(res: CheckResult):
    """(label, one-component model, its values) for each stochastic component of the fitted model."""
    out = []
    for label, comp in res.model.components:
        if comp.kind in ("state", "measurement"):
            m = parse_model(comp.name)
            vals = {f"{comp.name}.{p.name}": res.fit.values[f"{label}.{p.name}"] for p in comp.params}
            out.append((label, m, vals))
    return out


def _band_average(I: np.ndarray, omega: np.ndarray, bins: int = 60):
    edges = np.unique(np.rint(np.geomspace(1, len(I) + 1, bins + 1)).astype(int)) - 1
    f, avg, m = [], [], []
    for a, b in zip(edges[:-1], edges[1:]):
        if b > a:
            f.append(float(np.exp(np.mean(np.log(omega[a:b])))))
            avg.append(float(I[a:b].mean()))
            m.append(b - a)
    return np.array(f), np.array(avg), np.array(m)


def figures(res: CheckResult, out: Path, tag: str, unit: str = "units") -> list[Path]:
    """The figures of one channel (``tag`` its label, ``unit`` its unit for the axes' labels)."""
    plt = pyplot()
    alt = res.suggestions[0] if res.suggestions else None
    paths = [_spectrum_figure(plt, res, out, tag, unit, alt), _allan_figure(plt, res, out, tag, unit, alt),
             _innovations_figure(plt, res, out, tag), _acf_figure(plt, res, out, tag),
             _temperature_figure(plt, res, out, tag)]
    return [p for p in paths if p is not None]


def _spectrum_figure(plt, res: CheckResult, out: Path, tag: str, unit: str, alt) -> Path:
    """Writes ``spectrum_<tag>.png``: the data's band-averaged spectrum against the model's and its components'."""
    h = res.h
    y = res.innovations.y
    resid = np.where(res.innovations.observed, y - res.innovations.mean, 0.0)
    # --- spectrum (one-sided PSD in units²/Hz: 2·2π·h·S(ω))
    omega, I = periodogram(torch.as_tensor(resid))
    omega, I = omega.numpy(), I.numpy()
    w, avg, m = _band_average(I, omega)
    to_hz, to_psd = 1.0 / (2 * math.pi * h), 4 * math.pi * h
    fig, ax = plt.subplots(figsize=(8, 5))
    model_w = res.model.spectrum(res.fit.values, torch.as_tensor(w), h)[0].numpy()
    lo, hi = stats.gamma.ppf(0.005, m) / m, stats.gamma.ppf(0.995, m) / m
    ax.fill_between(w * to_hz, model_w * lo * to_psd, model_w * hi * to_psd, color="C0", alpha=0.2,
                    label="99 % band of the band averages")
    ax.loglog(w * to_hz, avg * to_psd, "k.", ms=4, label="data (band-averaged periodogram)")
    ax.loglog(w * to_hz, model_w * to_psd, "C0", lw=2, label=f"model {res.model.spec}")
    for i, (label, cm, vals) in enumerate(_component_models(res)):
        ax.loglog(w * to_hz, cm.spectrum(vals, torch.as_tensor(w), h)[0].numpy() * to_psd, lw=1, ls=":",
                  color=f"C{i + 2}", label=f"  {label}")
    if alt is not None:
        s2 = alt.fit.model.spectrum(alt.fit.values, torch.as_tensor(w), h)[0].numpy()
        ax.loglog(w * to_hz, s2 * to_psd, "C1--", lw=1.5, label=f"with {alt.effect}")
    for (a, b), _direction in zip(res.diagnostic("spectrum").ranges, res.diagnostic("spectrum").directions):
        ax.axvspan(a, b, color="red", alpha=0.08)
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel(f"one-sided PSD (({unit})²/Hz)")
    ax.set_title(f"{tag}: spectrum (shaded: bands where the innovations fail)")
    ax.legend(fontsize=7)
    return save_figure(plt, fig, out / f"spectrum_{tag}.png")


def _allan_figure(plt, res: CheckResult, out: Path, tag: str, unit: str, alt) -> Path | None:
    """Writes ``allan_<tag>.png`` (where the Allan diagnostic ran): the data's ADEV against the model's band."""
    # --- Allan
    h = res.h
    da = res.diagnostic("allan")
    if da.p_value is None:
        return None
    d = da.detail
    tau = np.array(d["tau_s"])
    fig, ax = plt.subplots(figsize=(8, 5))
    ax.fill_between(tau, d["band_lo"], d["band_hi"], color="C0", alpha=0.2, label="model's band (Bonferroni)")
    ax.loglog(tau, d["adev"], "ko", ms=4, label="data (overlapping ADEV)")
    ax.loglog(tau, d["adev_model"], "C0", lw=2, label=f"model {res.model.spec}")
    mm = np.rint(tau / h).astype(int)
    for i, (label, cm, vals) in enumerate(_component_models(res)):
        ax.loglog(tau, np.sqrt(allan.model_avar(cm, vals, h, mm)[0]), lw=1, ls=":", color=f"C{i + 2}",
                  label=f"  {label}")
    if alt is not None:
        det = allan.deterministic_avar(alt.fit.model.mean(alt.fit.values, torch.arange(len(res.innovations.y)) * h,
                                                          res.inputs).numpy()[0], mm)
        ax.loglog(tau, np.sqrt(allan.model_avar(alt.fit.model, alt.fit.values, h, mm)[0] + det), "C1--",
                  label=f"with {alt.effect}")
    ax.set_xlabel("τ (s)")
    ax.set_ylabel(f"Allan deviation ({unit})")
    ax.set_title(f"{tag}: Allan deviation")
    ax.legend(fontsize=7)
    return save_figure(plt, fig, out / f"allan_{tag}.png")


def _innovations_figure(plt, res: CheckResult, out: Path, tag: str) -> Path:
    """Writes ``innovations_<tag>.png``: the standardised innovations over time and the NIS per window."""
    # --- innovations over time
    z = res.innovations.z
    t = np.arange(len(z)) * res.h
    step = max(1, len(z) // 20000)
    fig, ax = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    ax[0].plot(t[::step], z[::step], lw=0.3, color="0.3")
    dn = res.diagnostic("nis")
    for a, b in dn.ranges:
        for x in ax:
            x.axvspan(a, b, color="red", alpha=0.15)
    ax[0].set_ylabel("standardised innovation")
    e = np.array(dn.detail["window_edges_s"])
    ax[1].step(e[:-1], dn.detail["window_nis"], where="post", color="C0")
    ax[1].axhline(1.0, color="k", lw=0.8)
    ax[1].set_ylabel("NIS per window")
    ax[1].set_xlabel("t (s)")
    ax[0].set_title(f"{tag}: innovations (shaded: windows outside their band)")
    return save_figure(plt, fig, out / f"innovations_{tag}.png")


def _acf_figure(plt, res: CheckResult, out: Path, tag: str) -> Path:
    """Writes ``acf_<tag>.png``: the innovations' autocorrelation with the Ljung-Box band."""
    # --- ACF
    dl = res.diagnostic("ljung-box")
    r = np.array(dl.detail["acf"])
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.bar(np.arange(1, len(r) + 1), r, color="C0")
    ax.axhline(dl.detail["band"], color="k", ls="--", lw=0.8)
    ax.axhline(-dl.detail["band"], color="k", ls="--", lw=0.8)
    ax.set_xlabel("lag")
    ax.set_ylabel("autocorrelation of the innovations")
    ax.set_title(f"{tag}: {dl.summary}", fontsize=8)
    return save_figure(plt, fig, out / f"acf_{tag}.png")


def _temperature_figure(plt, res: CheckResult, out: Path, tag: str) -> Path | None:
    """Writes ``temperature_<tag>.png`` (where the temperature diagnostic ran): innovations against temperature."""
    # --- temperature
    dt = res.diagnostic("temperature")
    if dt.p_value is None:
        return None
    z = res.innovations.z
    step = max(1, len(z) // 20000)
    T = np.asarray(res.inputs["temperature"], dtype=np.float64)
    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    ax[0].plot(T[::step], z[::step], ",", color="0.3")
    ax[0].set_xlabel("temperature (°C)")
    ax[0].set_ylabel("standardised innovation")
    ax[1].plot(dt.detail["lags_s"], dt.detail["xcorr_whitened"], color="C0")
    n = int(res.innovations.observed.sum())
    ax[1].axhline(2.576 / math.sqrt(n), color="k", ls="--", lw=0.8)
    ax[1].axhline(-2.576 / math.sqrt(n), color="k", ls="--", lw=0.8)
    ax[1].set_xlabel("lag (s)")
    ax[1].set_ylabel("corr(innovation, whitened temperature)")
    fig.suptitle(f"{tag}: {dt.summary}", fontsize=8)
    return save_figure(plt, fig, out / f"temperature_{tag}.png")


def _fmt(x, f=".4g"):
    return "—" if x is None or (isinstance(x, float) and not math.isfinite(x)) else format(x, f)


def _sqrt_r(r: CheckResult) -> float | None:
    """√(r h) of the fitted white noise (its density, unit/√Hz), None without one."""
    rs = [v for n, v in r.fit.values.items() if n.split(".")[0].startswith("white") and n.endswith(".r")]
    return math.sqrt(sum(rs) * r.h) if rs else None


def write_report(out: Path, results: dict, meta: dict, plots: bool = True, datasheet: dict | None = None,
                 windows: dict | None = None) -> dict:
    """``check.json`` and ``report.md`` (and the figures) for ``results`` {channel label: CheckResult}; ``meta``
    describes the recording (``channels``: label → its column, sensor, axis and unit, as
    :meth:`~torchtea.sensors.measurements.Measurements.describe` writes them); ``datasheet``: label → the axis held
    against a datasheet (:func:`torchtea.fitting.datasheet.compare`); ``windows``: label → the noise over time
    (:func:`torchtea.fitting.windows.noise_over_time`). Returns the JSON document."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    channels = meta.get("channels", {})
    doc = _check_document(results, meta, datasheet)
    if windows:
        doc["meaning"].update(WINDOWS_MEANING)
        for a, w in windows.items():
            doc["axes"][a]["windows"] = w
        if len(results) == 1:
            doc["windows"] = next(iter(windows.values()))
    lines = _header_lines(meta, next(iter(results.values())))
    lines += _summary_lines(results, channels, doc)
    for a, r in results.items():
        lines += _channel_lines(r, a, channels.get(a, {}), doc["axes"][a], out, plots)
        if windows and a in windows:
            lines += _windows_lines(r, a, windows[a], doc["axes"][a]["unit"], out, plots)
    (out / "report.md").write_text("\n".join(lines))
    write(out / "check.json", doc)
    return doc


def _check_document(results: dict, meta: dict, datasheet: dict | None) -> dict:
    """Builds the ``check.json`` document: the recording's meta, the meanings and one document per channel."""
    channels = meta.get("channels", {})
    doc = dict(meta)
    doc["meaning"] = dict(RECORDING_MEANING, **MEANING)
    doc["axes"] = {}
    for a, r in results.items():
        d = axis_document(r)
        info = channels.get(a, {})
        d.update(sensor=info.get("sensor", "signal"), unit=info.get("unit", "units"), column=info.get("column", a),
                 white_noise_density=_sqrt_r(r))
        if datasheet and a in datasheet:
            d["datasheet"] = datasheet[a]
        doc["axes"][a] = d
    if len(results) == 1:
        doc.update(next(iter(doc["axes"].values())))
    return doc


def _header_lines(meta: dict, first: CheckResult) -> list[str]:
    """Writes the report's title, what its tests mean, the recording's faults and its warnings."""
    lines = [f"# torchtea check: {meta.get('recording', '')}", "",
             f"{meta.get('samples', '')} samples at {meta.get('rate_hz', 0):g} Hz. Each diagnostic is a test at level "
             f"{first.level:g} of 'the data came from the fitted model' (Bonferroni inside "
             "it); an effect is suggested when its screening p-value is below "
             f"{first.screen_level:g} / (effects screened) and its exact refit lowers BIC. "
             "`gain` = BIC before − BIC after.", ""]
    faults = meta.get("faults", {}).get("found", [])
    if faults:
        lines += ["## Recording faults (found before any fit; their samples are missing samples, never physics)", ""]
        lines += [f"- **{f['kind']}** ({', '.join(f['channels'])}): {f['message']}" for f in faults] + [""]
    for w in meta.get("warnings", []):
        if not w.startswith("recording fault"):
            lines.append(f"- warning: {w}")
    return lines


def _summary_lines(results: dict, channels: dict, doc: dict) -> list[str]:
    """Writes the summary table, the sensors side by side."""
    by_sensor: dict = {}
    for a in results:
        by_sensor.setdefault(channels.get(a, {}).get("sensor", "signal"), []).append(a)
    lines = ["## Summary, the sensors side by side", "",
             "| sensor | channel | unit | model | verdict | failed diagnostics | white-noise density (unit/√Hz) | "
             "fractional order | top suggestion (gain) |", "|---|---|---|---|---|---|---|---|---|"]
    for sensor, labels in by_sensor.items():
        for a in labels:
            r, d = results[a], doc["axes"][a]
            order = next((v for n, v in r.fit.values.items() if n.endswith("fractional.order")), None)
            top = r.suggestions[0] if r.suggestions else None
            lines.append(f"| {sensor} | {a} | {d['unit']} | `{r.model.spec}` | {'adequate' if r.adequate else '**NOT adequate**'} "
                         f"| {', '.join(r.failed) or '—'} | {_fmt(d['white_noise_density'], '.4g')} | "
                         f"{_fmt(order, '.3f')} | {'—' if top is None else f'{top.effect} ({top.gain:.1f})'} |")
    lines.append("")
    return lines


def _channel_lines(r: CheckResult, a: str, info: dict, axis_doc: dict, out: Path, plots: bool) -> list[str]:
    """Writes one channel's section (and its figures, with ``plots``)."""
    title = (f"{info['sensor']} {info['axis']} ({info['unit']}, column `{info['column']}`)"
             if info.get("sensor", "signal") != "signal" else f"column `{info.get('column', a)}`")
    lines = [f"## {a}: {title}: model `{r.model.spec}` — {'adequate' if r.adequate else 'NOT adequate'}", ""]
    lines += _loop_lines(r)
    lines += _fit_lines(r, axis_doc["unit"])
    lines += _suggestion_lines(r)
    lines += _unexplained_lines(r)
    lines += _datasheet_plan_lines(a, axis_doc)
    lines += ["", "Screens: " + "; ".join(
        f"{s.effect} {('p ' + _fmt(s.p_value, '.2g')) if s.p_value is not None else s.note}"
        for s in r.screens), ""]
    for note in r.notes:
        lines.append(f"Note: {note}")
    if plots:
        for p in figures(r, out, a, axis_doc["unit"]):
            lines.append(f"![{p.stem}]({p.name})")
    lines.append("")
    return lines


def _windows_lines(r: CheckResult, a: str, w: dict, unit: str, out: Path, plots: bool) -> list[str]:
    """One channel's noise over time: the tests in words, the parameters over time and the dynamic Allan deviation."""
    lines = [f"### {a}: the noise over time", ""] + replicates.windows_lines(w, markdown=True) + [""]
    if plots:
        plt = pyplot()
        for p in (replicates.windows_figure(plt, w, out, a, unit),
                  replicates.dynamic_allan_figure(plt, replicates.check_residual(r), r.h, w["length_s"], out, a,
                                                  unit)):
            lines.append(f"![{p.stem}]({p.name})")
        lines.append("")
    return lines


def _loop_lines(r: CheckResult) -> list[str]:
    """Writes the loop's steps and what the record cannot tell apart, or (after --add) before against after."""
    lines = []
    if len(r.steps) > 2 or r.loop_end:
        lines += ["The loop, one change per step — an effect added (+), taken away (−) or swapped (→) — (`gain`: "
                  "the BIC it gained; `repaired`: failed before, pass now):", "",
                  "| step | model | change | gain | nll/sample | psd misfit | adev misfit | failed | repaired |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for k, st in enumerate(r.step_rows()):
            lines.append(f"| {k} | `{st['model']}` | {change_words(st) if k else '—'} | "
                         f"{_fmt(st.get('gain'), '.1f') if 'gain' in st else '—'} | {st['nll_per_sample']:.5f} | "
                         f"{_fmt(st['psd_misfit'], '.4f')} | {_fmt(st['adev_misfit'], '.4f')} | "
                         f"{', '.join(st['failed']) or 'none'} | {', '.join(st.get('repaired', [])) or '—'} |")
        lines += ["", f"Loop end: {r.loop_end}." if r.loop_end else "", ""]
        if r.ties:
            lines += ["What this record cannot tell apart (BIC within "
                      f"{CLOSE_BIC:g} of the model's; a longer record would):", ""]
            lines += [f"- {t['words']} (`{t['model']}`)" for t in r.ties] + [""]
    elif r.before is not None:
        b = r.before
        lines += ["| | model | nll/sample | psd misfit | adev misfit | failed |", "|---|---|---|---|---|---|",
                  f"| before | `{b.model.spec}` | {b.metrics['nll_per_sample']:.5f} | {_fmt(b.metrics['psd_misfit'], '.4f')} "
                  f"| {_fmt(b.metrics['adev_misfit'], '.4f')} | {', '.join(b.failed) or 'none'} |",
                  f"| after | `{r.model.spec}` | {r.metrics['nll_per_sample']:.5f} | {_fmt(r.metrics['psd_misfit'], '.4f')} "
                  f"| {_fmt(r.metrics['adev_misfit'], '.4f')} | {', '.join(r.failed) or 'none'} |", ""]
    return lines


def _fit_lines(r: CheckResult, unit: str) -> list[str]:
    """Writes the parameter table, the diagnostics table and the metrics."""
    lines = [f"| parameter | value | 95 % interval | (units = {unit}) |", "|---|---|---|---|"]
    for n, v in r.fit.values.items():
        ci = r.fit.ci95.get(n)
        lines.append(f"| {n} | {v:.5g} | {'—' if ci is None else f'[{ci[0]:.4g}, {ci[1]:.4g}]'} | "
                     f"{r.model.param_spec(n).unit} |")
    lines += ["", "| diagnostic | domain | p-value | result |", "|---|---|---|---|"]
    for d in r.diagnostics:
        res_ = "not run" if d.passed is None else ("pass" if d.passed else "**FAIL**")
        lines.append(f"| {d.name} | {d.domain} | {_fmt(d.p_value, '.3g')} | {res_}: {d.summary} |")
    lines += ["", "Metrics: " + ", ".join(f"{k} {_fmt(v, '.5g')}" for k, v in r.metrics.items()), ""]
    return lines


def _suggestion_lines(r: CheckResult) -> list[str]:
    """Writes the suggestions table, or why there is no suggestion."""
    lines = []
    if r.suggestions:
        lines += ["| suggestion | gain (ΔBIC) | screening p | parameters | failed after | repairs |",
                  "|---|---|---|---|---|---|"]
        for s in r.suggestions:
            pars = ", ".join(f"{k} {v:.4g}" for k, v in s.parameters.items())
            lines.append(f"| {s.effect} | {s.gain:.1f} | {s.p_value:.2g} | {pars} | "
                         f"{', '.join(d.name for d in s.diagnostics if d.passed is False) or 'none'} | "
                         f"{', '.join(s.repairs) or '—'} |")
        lines.append("")
        lines += [f"{s.effect}: {s.note}." for s in r.suggestions if s.note]
        lines.append(f"Add the best with `--add {r.suggestions[0].effect}`.")
    elif r.failed_refits or r.unconfirmed:
        if r.failed_refits:
            lines.append(f"The screens of {', '.join(r.failed_refits)} passed, but their refits failed to find "
                         "what the screens saw: an optimiser's failure, not evidence against them (their rows "
                         "below say what was tried).")
        if r.unconfirmed:
            lines.append(f"The Whittle screens of {', '.join(r.unconfirmed)} passed, but the exact likelihood does "
                         "not confirm them: at the screens' own points it is below the model's, and their refits "
                         "gain nothing. The two likelihoods disagree on this record (the Whittle likelihood takes "
                         "it as stationary): no evidence for these effects (their rows below give the numbers).")
    else:
        lines.append("No effect of the library passes its screen: "
                     + ("nothing is missing that torchtea can add." if r.adequate else
                        "the model fails, and no candidate explains it."))
    return lines


def _unexplained_lines(r: CheckResult) -> list[str]:
    """Writes the failures no suggestion repairs: where, what would fit, and the --exclude flags."""
    lines = []
    if r.unexplained:
        lines += ["", "What no suggestion repairs — where the model fails, and what kind of effect would fit:", ""]
        for u in r.unexplained:
            lib = (f" Screened, not passing or not lowering BIC: {', '.join(u['in_library'])}."
                   if u["in_library"] else "")
            hand = (f" In the library, not screened (`--add`): {', '.join(u['add_by_hand'])}."
                    if u["add_by_hand"] else "")
            new = f" Not in the library: {', '.join(u['not_in_library'])}." if u["not_in_library"] else ""
            leave = (f" If it is a disturbance of the recording (a knock, a shock), leave it out: "
                     f"`{' '.join(u['exclude'][:3])}`." if u.get("exclude") else "")
            lines.append(f"- **{u['diagnostic']}** ({u['where']}): {u['would_fit']}.{lib}{hand}{new}{leave}")
    return lines


def _datasheet_plan_lines(a: str, axis_doc: dict) -> list[str]:
    """Writes the verdicts against the datasheet (--datasheet) and the plan of how long to record."""
    lines = []
    sheet = axis_doc.get("datasheet")
    if sheet:
        lines += ["", f"Against the datasheet {sheet['file']} ({sheet['source']}; its values are typical ones):",
                  ""]
        lines += verdict_lines(a, sheet, markdown=True)
    plan = axis_doc.get("plan")
    if plan and plan.get("rows"):
        lines += ["", "How long to record — the expected 95 % intervals of this model's noise numbers, ± half "
                      "the width over the value, if the model at these values is the truth (`torchtea plan`):", ""]
        lines += plan_lines(a, plan, markdown=True)
    return lines

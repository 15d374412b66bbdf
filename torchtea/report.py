"""The identification report: per-axis results as Markdown with PNG figures, and TensorBoard logs."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from .identify import AXES, Identification

__all__ = ["settle_time", "axis_statistics", "write_report", "log_identification", "orders_figure",
           "save_identification"]

#: An order estimate has settled once it stays within this distance of its last-third mean.
SETTLE_BAND = 0.05


def settle_time(est: np.ndarray, t: np.ndarray, target: float, band: float = SETTLE_BAND) -> float:
    """First time after which ``|est − target| ≤ band`` holds to the end; NaN unless that covers at
    least the last third (``target`` is the last-third mean, so less would say nothing)."""
    outside = np.flatnonzero(np.abs(est - target) > band)
    first = 0 if outside.size == 0 else outside[-1] + 1
    if first > len(est) - len(est) // 3:
        return math.nan
    return float(t[first])


def axis_statistics(ident: Identification, axes: dict) -> dict:
    """Per axis: sample variance and standard deviation of the (mean-removed) noise, the KFx
    innovation and residual variances over the last third, the settling time of α̂ and ŵ towards
    their last-third means in ``axes`` (``ident.summary()["axes"]``)."""
    res, t = ident.result, ident.t
    N = len(t)
    third = slice(N - N // 3, N)
    out = {}
    for i, axis in enumerate(AXES):
        y = ident.y[i, :, 0].numpy()
        x = res.x[i, :, 0].numpy()
        e = res.innovation[i, :, 0].numpy()
        obs = ~np.isnan(y)
        s = axes[axis]
        out[axis] = {
            "noise_var": float(np.nanvar(y)),
            "noise_std": float(np.nanstd(y)),
            "innovation_var_last_third": float(np.var(e[third][obs[third]])),
            "predicted_innovation_var_last_third": float(res.innovation_cov[i, third, 0, 0].mean()),
            "residual_var_last_third": float(np.nanvar((y - x)[third])),
            "alpha_settle_s": settle_time(res.alpha[i, :, 0].numpy(), t, s["alpha"]),
            "param_settle_s": settle_time(res.w[i, :, 0].numpy(), t, s["param"], band=SETTLE_BAND * max(1.0, abs(s["param"]))),
            "missing_samples": int((~obs).sum()),
        }
    return out


def _fmt(v: float, spec: str = ".4f") -> str:
    return "—" if v is None or (isinstance(v, float) and math.isnan(v)) else format(v, spec)


def write_report(path, ident: Identification, summary: dict, figures: list, *, command: str = "") -> Path:
    """``report.md``: what was measured, the settings, per-axis α̂, ŵ, noise variances, convergence,
    and the figures (paths relative to the report)."""
    path = Path(path)
    rec = ident.recording
    meta = rec.metadata
    n = ident.y.shape[-2]
    total = len(rec.accel_counts)
    stats = summary["statistics"]
    lines = [f"# Noise identification: {Path(rec.path).name}", ""]
    src = [f"- **Recording**: `{rec.path}`"]
    if "sensor" in meta:
        src.append(f"- **Sensor**: {meta['sensor']}, digital low-pass {meta.get('dlpf_hz', '?')} Hz, "
                   f"{rec.accel_lsb_per_g:g} LSB/g")
    if "segment" in meta:
        src.append(f"- **Segment** {meta['segment']} of {len(meta['segments'])} (rows per segment: "
                   + ", ".join(f"{k}: {v}" for k, v in meta["segments"].items()) + ")")
    src.append(f"- **Samples**: {n} of {total} at {rec.rate_hz:g} Hz ({n / rec.rate_hz:.1f} s)"
               + ("" if n == total else " — `--samples all` uses the whole recording"))
    missing = sum(s["missing_samples"] for s in stats.values()) // 3
    src.append(f"- **Missing samples** in the part used: {missing} (the filters predict through them)")
    src.append(f"- **Settings**: the paper's §5.1 MEMS settings; R, Rᵒ, Rʷ = "
               + ("each axis's measured noise variance" if summary.get("r_mode") == "measured" else "the paper's printed values")
               + f"; GL history `{summary.get('memory', 'exact')}`; each axis's mean removed")
    if command:
        src.append(f"- **Command**: `{command}`")
    lines += src + ["", "## Results", "",
                    "| axis | α̂ (last ⅓) | ± sd | α̂ final | ŵ (last ⅓) | ± sd | ŵ final | α̂ settled after [s] | diverged |",
                    "|---|---|---|---|---|---|---|---|---|"]
    for a, s in summary["axes"].items():
        st = stats[a]
        lines.append(f"| {a} | {_fmt(s['alpha'])} | {_fmt(s['alpha_std_last_third'])} | {_fmt(s['alpha_final'])} | "
                     f"{_fmt(s['param'])} | {_fmt(s['param_std_last_third'])} | {_fmt(s['param_final'])} | "
                     f"{_fmt(st['alpha_settle_s'], '.1f')} | {'**yes**' if s['diverged'] else 'no'} |")
    lines += ["", f"α̂ settled after: the time from which α̂ stays within ±{SETTLE_BAND} of its last-third mean "
              "(—: not within the last third).", "", "## Noise variances [(m/s²)²]", "",
              "| axis | mean removed [m/s²] | noise variance (= R) | std [m/s²] | innovation variance, last ⅓ | "
              "predicted (C P̃ Cᵀ + R) | residual y − x̂ | NIS |", "|---|---|---|---|---|---|---|---|"]
    for a, s in summary["axes"].items():
        st = stats[a]
        lines.append(f"| {a} | {_fmt(s.get('mean_removed_ms2', math.nan), '.5f')} | {st['noise_var']:.4e} | "
                     f"{st['noise_std']:.4e} | {st['innovation_var_last_third']:.4e} | "
                     f"{st['predicted_innovation_var_last_third']:.4e} | {st['residual_var_last_third']:.4e} | "
                     f"{s['innovation_nis']:.3f} |")
    lines += ["", "NIS: mean normalised innovation squared (1 for a consistent filter).", ""]
    if figures:
        lines += ["## Figures", ""]
        for f in figures:
            rel = Path(f).relative_to(path.parent) if Path(f).is_relative_to(path.parent) else Path(f)
            lines += [f"![{rel.stem}]({rel.as_posix()})", ""]
    lines += ["Trajectories: `trajectories.csv`; per-axis settings: `config_<axis>.toml` (reusable with "
              "`torchtea estimate --config`); TensorBoard: `tensorboard --logdir " + str(path.parent / "tb") + "`.", ""]
    path.write_text("\n".join(lines))
    return path


def orders_figure(path, ident: Identification) -> Path:
    """α̂ of the three axes on one plot with ±2σ (the filter's) — convergence at a glance."""
    from .plots import _plt, _save

    plt = _plt()
    t = ident.t
    res = ident.result
    fig, ax = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    for i, a in enumerate(AXES):
        for panel, est, var in ((ax[0], res.alpha[i, :, 0], res.P_alpha[i, :, 0, 0]), (ax[1], res.w[i, :, 0], res.P_w[i, :, 0, 0])):
            e = est.numpy()
            sd = var.clamp(min=0).sqrt().numpy()
            panel.plot(t, e, lw=1.0, color=f"C{i}", label=f"{a}")
            panel.fill_between(t, e - 2 * sd, e + 2 * sd, color=f"C{i}", alpha=0.12, lw=0)
    ax[0].set_ylabel("order α̂")
    ax[1].set_ylabel("parameter ŵ")
    ax[1].set_xlabel("time [s]")
    ax[0].legend(loc="upper right", fontsize=8)
    ax[0].set_title(f"{Path(ident.recording.path).name}: estimates of the three axes (±2σ of the filters)")
    return _save(plt, fig, path)


def log_identification(logdir, ident: Identification, summary: dict, *, max_points: int = 2000) -> Path:
    """TensorBoard: ``{order,param,innovation,noise}/<axis>`` over the sample index (decimated to
    ≤ ``max_points``) and the report's tables as text."""
    from torch.utils.tensorboard import SummaryWriter

    from .tblog import _steps

    res = ident.result
    N = ident.y.shape[-2]
    logdir = Path(logdir)
    with SummaryWriter(log_dir=str(logdir)) as w:
        for k in _steps(N, max_points):
            for i, a in enumerate(AXES):
                w.add_scalar(f"order/{a}", float(res.alpha[i, k, 0]), k)
                w.add_scalar(f"param/{a}", float(res.w[i, k, 0]), k)
                w.add_scalar(f"innovation/{a}", float(res.innovation[i, k, 0]), k)
                w.add_scalar(f"order_sd/{a}", math.sqrt(max(float(res.P_alpha[i, k, 0, 0]), 0.0)), k)
        table = ["| axis | α̂ | ŵ | R |", "|---|---|---|---|"]
        table += [f"| {a} | {s['alpha']:.4f} | {s['param']:.4f} | {s['R']:.3e} |" for a, s in summary["axes"].items()]
        w.add_text("summary", "\n".join(table), 0)
    return logdir


def save_identification(ident: Identification, out_dir, *, plots: bool = True, r_mode: str = "measured",
                        seconds: float | None = None, command: str = "") -> dict:
    """Everything ``torchtea identify`` writes, into ``out_dir``: ``trajectories.csv``, ``config_<axis>.toml``,
    the figures (per axis like the paper's Figs. 12–20, and ``orders.png``), TensorBoard logs in ``tb/``,
    ``report.md``. Returns the summary (``summary.json`` is the caller's to write, with its warnings)."""
    from .config import write_config
    from .io import write_columns

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    rec, res, t = ident.recording, ident.result, ident.t
    summary = ident.summary()
    cols = {"t": t}
    for i, a in enumerate(AXES):
        cols.update({f"y_{a}": ident.y[i, :, 0], f"x_hat_{a}": res.x[i, :, 0], f"alpha_{a}": res.alpha[i, :, 0],
                     f"P_alpha_{a}": res.P_alpha[i, :, 0, 0], f"w_{a}": res.w[i, :, 0], f"P_w_{a}": res.P_w[i, :, 0, 0],
                     f"innovation_{a}": res.innovation[i, :, 0], f"innovation_var_{a}": res.innovation_cov[i, :, 0, 0]})
    write_columns(out_dir / "trajectories.csv", cols)
    for i, a in enumerate(AXES):
        write_config(out_dir / f"config_{a}.toml", ident.configs[i], {"h": ident.h, "axis": a})
    figures = []
    if plots:
        from .plots import estimation_figure

        for i, a in enumerate(AXES):
            figures.append(str(estimation_figure(
                out_dir / f"axis_{a}.png", t, y=ident.y[i, :, 0].numpy(), x_hat=res.x[i, :, 0].numpy(),
                alpha_hat=res.alpha[i, :, 0].numpy(), alpha_sd=res.P_alpha[i, :, 0, 0].clamp(min=0).sqrt().numpy(),
                w_hat=res.w[i, :, 0].numpy(), w_sd=res.P_w[i, :, 0, 0].clamp(min=0).sqrt().numpy(),
                title=f"{Path(rec.path).name}: {a}-axis noise (cf. paper Figs. {12 + 3 * i}–{14 + 3 * i})",
                state_label="noise [m/s²]", zoom=(t[-1] - 5.0, t[-1]))))
        figures.append(str(orders_figure(out_dir / "orders.png", ident)))
    summary.update({"recording": str(rec.path), "samples": int(ident.y.shape[-2]), "h": ident.h, "r_mode": r_mode,
                    "memory": ident.configs[0].memory.spec(), "out": str(out_dir), "figures": figures,
                    "statistics": axis_statistics(ident, summary["axes"])})
    if seconds is not None:
        summary["seconds"] = round(seconds, 3)
    if "segment" in rec.metadata:
        summary["segment"] = rec.metadata["segment"]
    summary["tensorboard"] = str(log_identification(out_dir / "tb", ident, summary))
    summary["report"] = str(write_report(out_dir / "report.md", ident, summary, figures, command=command))
    return summary

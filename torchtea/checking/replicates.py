"""Several recordings of one sensor, and one record's windows, side by side: the lines and figures of ``check
--windows`` — each noise parameter over time with its band, the dynamic Allan deviation (the data's Allan deviation
per window: τ against time, as an image) — and of ``fit --together`` — the recordings' Allan deviations over each
other with the pooled model's. The numbers are :func:`torchtea.fitting.windows.noise_over_time`'s and
:func:`torchtea.fitting.together.fit_together`'s."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..render.plots import save_figure
from ..render.text import num
from . import allan

__all__ = ["windows_lines", "windows_figure", "check_residual", "dynamic_allan", "dynamic_allan_figure", "together_lines",
           "together_allan_figure", "pooled_lines", "pooled_report"]


def windows_lines(doc: dict, markdown: bool = False) -> list[str]:
    """The constancy tests and the changes found, in words."""
    lines = [f"noise over time ({len(doc['rows'])} windows of {doc['length_s']:g} s, half-overlapping; model "
             f"{doc['model']}): " + "; ".join(
                 f"{c['name']} {'CHANGES' if c['changes'] else 'constant'} (p {num(c['p_value'], '.3g')})"
                 for c in doc["constancy"])]
    for c in doc["changes"]:
        values = ", ".join(f"{n} {c['before'][n]:.4g} → {c['after'][n]:.4g}" for n in c["parameters"])
        lines.append(f"{'- ' if markdown else '    '}at {c['at_s']:.4g} s: {values}; {c['advice']}")
    for note in doc.get("notes", []):
        lines.append(f"{'- ' if markdown else '    '}note: {note}")
    return lines


def windows_figure(plt, doc: dict, out: Path, tag: str, unit: str) -> Path:
    """Writes ``windows_<tag>.png``: each noise parameter per window (at the window's middle) with its 95 % band,
    the changes marked."""
    names = [c["name"] for c in doc["constancy"]]
    rows = doc["rows"]
    mid = np.array([0.5 * (r["from_s"] + r["to_s"]) for r in rows])
    fig, axes = plt.subplots(len(names), 1, figsize=(8, 2.4 * len(names) + 0.6), sharex=True, squeeze=False)
    for ax, name in zip(axes[:, 0], names):
        v = np.array([r["parameters"][name] for r in rows])
        ci = [r["ci95"][name] for r in rows]
        lo = np.array([c[0] if c is not None else np.nan for c in ci])
        hi = np.array([c[1] if c is not None else np.nan for c in ci])
        positive = bool(np.all(v > 0))
        # a window where the parameter went to its bound (a variance to zero) has no interval worth drawing: its
        # value is marked apart and the axis is the other windows'
        typical = float(np.median(np.abs(v))) or 1.0
        bound = (np.abs(v) < 1e-4 * typical) | (positive & (hi / np.where(lo > 0, lo, np.nan) > 1e4))
        bound |= ~np.isfinite(lo) | ~np.isfinite(hi)
        ok = ~bound
        ax.fill_between(mid, np.where(ok, lo, np.nan), np.where(ok, hi, np.nan), color="C0", alpha=0.25,
                        label="95 % interval")
        ax.plot(mid, np.where(ok, v, np.nan), "C0o-", ms=3, label=name)
        if bound.any():
            floor = np.nanmin(np.where(ok, lo, np.nan)) if ok.any() else typical
            ax.plot(mid[bound], np.full(int(bound.sum()), floor), "v", color="C1", ms=6,
                    label="at its bound: none seen in that window")
        if positive:
            ax.set_yscale("log")
        for c in doc["changes"]:
            if name in c["parameters"]:
                ax.axvline(c["at_s"], color="C3", ls="--", label=f"change at {c['at_s']:.4g} s")
        test = next(c for c in doc["constancy"] if c["name"] == name)
        ax.set_title(f"{name}: {'changes' if test['changes'] else 'constant'} (p {num(test['p_value'], '.2g')})",
                     fontsize=9)
        ax.set_ylabel(name.split(".")[-1])
        ax.legend(fontsize=7, loc="best")
    axes[-1, 0].set_xlabel("time (s), window middle")
    fig.suptitle(f"{tag}: noise parameters over time ({unit})", fontsize=10)
    return save_figure(plt, fig, Path(out) / f"windows_{tag}.png")


def check_residual(res) -> np.ndarray:
    """What a check's model leaves of its series (its fitted mean removed), NaN where a sample is missing: the series
    the dynamic Allan deviation reads."""
    inn = res.innovations
    return np.where(inn.observed, inn.y - inn.mean, np.nan)


def dynamic_allan(y: np.ndarray, h: float, length_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The data's overlapping Allan deviation in windows of ``length_s`` seconds, half-overlapping: the windows'
    middles (s), the averaging times τ (s) and the deviations ``(windows, τ)`` (a missing sample filled with the window's mean; NaN where half the window is missing)."""
    y = np.asarray(y, dtype=np.float64)
    n = int(round(length_s / h))
    m = allan.octave_clusters(n)
    starts = range(0, len(y) - n + 1, max(1, n // 2))
    mids, rows = [], []
    for a in starts:
        w = y[a:a + n]
        mids.append((a + n / 2) * h)
        ok = np.isfinite(w)
        if ok.mean() < 0.5:  # (a window mostly missing: no deviation)
            rows.append(np.full(len(m), np.nan))
            continue
        rows.append(allan.data_adev(np.where(ok, w, np.mean(w[ok])), h, m))
    return np.array(mids), m * h, np.array(rows)


def dynamic_allan_figure(plt, y: np.ndarray, h: float, length_s: float, out: Path, tag: str, unit: str) -> Path:
    """Writes ``dadev_<tag>.png``: the dynamic Allan deviation, τ against time, log10 of the deviation in colour."""
    mids, taus, dev = dynamic_allan(y, h, length_s)
    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(8, 6.5), sharex=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        img = np.log10(dev.T)
        ratio = dev / np.nanmedian(dev, axis=0, keepdims=True)
    step = mids[1] - mids[0] if len(mids) > 1 else length_s
    extent = [mids[0] - step / 2, mids[-1] + step / 2, np.log10(taus[0]) - 0.15, np.log10(taus[-1]) + 0.15]
    im = ax.imshow(img, aspect="auto", origin="lower", extent=extent, cmap="viridis")
    fig.colorbar(im, ax=ax, label=f"log10 ADEV ({unit})")
    ax.set_ylabel("log10 τ (s)")
    ax.set_title(f"{tag}: dynamic Allan deviation (windows of {length_s:g} s)", fontsize=10)
    top = float(np.nanmax(np.abs(np.log2(ratio)))) if np.isfinite(ratio).any() else 1.0
    im2 = ax2.imshow(np.log2(ratio.T), aspect="auto", origin="lower", extent=extent, cmap="RdBu_r",
                     vmin=-max(top, 0.25), vmax=max(top, 0.25))
    fig.colorbar(im2, ax=ax2, label="log2 of ADEV / its median over time")
    ax2.set_ylabel("log10 τ (s)")
    ax2.set_xlabel("time (s), window middle")
    ax2.set_title("each τ against its median over the record: where the noise moves", fontsize=9)
    return save_figure(plt, fig, Path(out) / f"dadev_{tag}.png")


def together_lines(label: str, title: str, tg, unit: str) -> list[str]:
    """The text of one channel's fit together: the verdict, each noise parameter's pooled value and test, each
    recording's own value, and the bias's repeatability."""
    lines = [f"{label} ({title}): {tg.verdict}; pooled loglik {tg.loglik:.2f} (separate "
             f"{sum(f.loglik for f in tg.separate):.2f})"]
    width = max(len(name) for name in tg.recordings)
    for p in tg.parameters:
        ci = "(at its bound: no interval)" if p["ci95"] is None else f"[{p['ci95'][0]:.4g}, {p['ci95'][1]:.4g}]"
        if p["differs"]:
            ci = "(pooled, but it differs)"
        given = f" (tested with {', '.join(p['given'])} each recording's own)" if p.get("given") else ""
        lines.append(f"    {p['name']:22s} {p['value']:12.5g} {ci:27s} p {num(p['p_value'], '.3g')}"
                     + ("  DIFFERS" if p["differs"] else "") + given)
        for name, v in zip(tg.recordings, p["values"]):
            vci = "(at its bound: no interval)" if v["ci95"] is None else f"[{v['ci95'][0]:.4g}, {v['ci95'][1]:.4g}]"
            lines.append(f"        {name:{width}s} {v['value']:12.5g} {vci}")
    if tg.bias is not None:
        b = tg.bias
        lines.append(f"    turn-on bias repeatability (1σ between recordings) {b['spread']:.4g} {unit}, 95 % "
                     f"[{b['ci95'][0]:.3g}, {b['ci95'][1]:.3g}]; levels "
                     + ", ".join(f"{lv['level']:.5g} ± {lv['se']:.2g}" for lv in b["levels"])
                     + (" (an accelerometer's level holds gravity's projection: across mountings it is no "
                        "repeatability)" if "accelerometer" in title else ""))
    for note in tg.notes:
        lines.append(f"    note: {note}")
    return lines


def together_allan_figure(plt, tg, series: list, h: float, out: Path, tag: str, unit: str,
                          inputs: list | None = None) -> Path:
    """Writes ``allan_<tag>.png``: each recording's Allan deviation (its own mean terms removed) over the others',
    with the pooled model's."""
    import torch

    fig, ax = plt.subplots(figsize=(8, 5))
    n = min(len(y) for y in series)
    m = allan.octave_clusters(n)
    inputs = [None] * len(series) if inputs is None else inputs
    for k, (name, y, v, inp) in enumerate(zip(tg.recordings, series, tg.values, inputs)):
        t = torch.arange(len(y), dtype=torch.float64) * h
        resid = np.asarray(y, dtype=np.float64) - tg.model.mean(v, t, inp).numpy()[0]
        ok = np.isfinite(resid)
        if not ok.all():
            resid = np.where(ok, resid, np.nanmean(resid))
        ax.loglog(m * h, allan.data_adev(resid, h, m), "o", ms=4, color=f"C{k}", label=name)
    model_adev = np.sqrt(allan.model_avar(tg.model, tg.values[0], h, m)[0])
    ax.loglog(m * h, model_adev, "k-", lw=2, label=f"pooled model {tg.model.spec}")
    ax.set_xlabel("τ (s)")
    ax.set_ylabel(f"Allan deviation ({unit})")
    ax.set_title(f"{tag}: {tg.verdict}", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    return save_figure(plt, fig, Path(out) / f"allan_{tag}.png")


def pooled_lines(label: str, title: str, pc, unit: str, markdown: bool = False) -> list[str]:
    """The text of one channel's loop on several recordings (:func:`~.pooled.check_together`): its path — each step's
    model, change and pooled BIC, the candidates and what each recording fails —, why it ended, then the final
    model's fit together (:func:`together_lines`)."""
    bullet = "- " if markdown else "    "
    lines = [f"{label} ({title}): {pc.model.spec} — " + ("adequate in every recording" if pc.adequate else
                                                         "not adequate")]
    for k, s in enumerate(pc.steps):
        d = s.as_dict()
        gain = "" if d["gain"] is None else f", gain {d['gain']:.1f}"
        fails = "; ".join(f"{n} fails {', '.join(f)}" for n, f in d["failing"].items() if f) or "adequate in each"
        lines.append(f"{bullet}step {k}: {d['model']} ({d['change']}{gain}); pooled BIC {d['bic']:.1f}, k {d['k']}; "
                     f"{fails}")
        if d["candidates"]:
            lines.append(f"{bullet}    candidates: " + ", ".join(
                f"{c['effect']} {_gain(c['gain'])} ({_by(c['suggested_by'])})"
                for c in d["candidates"]))
        for f in d["faults"] if k == len(pc.steps) - 1 else ():  # (before, the model may lack what explains it)
            lines.append(f"{bullet}    {f['recording']} alone: {f['effect']} (gain {f['gain']:.1f} there): located in "
                         "that recording — its fault, not the sensor's")
    lines.append(f"{bullet}loop: {pc.loop_end}")
    tg = together_lines(label, title, pc.together, unit)
    lines.append(f"{bullet}verdict: {tg[0].split(': ', 1)[1]}")
    lines += [f"{bullet}{line.strip()}" for line in tg[1:]] if markdown else tg[1:]
    return lines


def _gain(gain) -> str:
    return "(no finite pooled likelihood)" if gain is None else f"{gain:+.1f}"


def _by(recordings: list) -> str:
    """Where a pooled candidate came from, in words."""
    named = [r for r in recordings if not r.startswith("the recordings' screens")]
    out = [f"suggested by {', '.join(named)}"] if named else []
    return "; ".join(out + [r for r in recordings if r not in named])


def pooled_report(lines: list, figures: list, names: list, rate_hz: float, units: dict, verdicts: dict) -> str:
    """``report.md`` of ``check --together``: per channel (``lines``: ``(label, title, result, unit)``) its path,
    verdict and Allan figure (``figures``, where drawn), the datasheet verdicts, the units."""
    from ..fitting.datasheet import verdict_lines

    md = [f"# {len(names)} recordings checked together", "",
          f"Recordings ({rate_hz:g} Hz): {', '.join(names)}. One model per channel: its noise parameters shared, each "
          "recording its own mean terms; gains are falls of the pooled BIC (the shared parameters counted once, each "
          "recording's own terms once per recording); adequacy is every recording's diagnostics at the pooled "
          "values, each at the level over the recordings.", ""]
    for (label, title, pc, unit), fig in zip(lines, figures or [None] * len(lines)):
        md += [f"## {label}", ""] + pooled_lines(label, title, pc, unit, markdown=True)[1:] + [""]
        if fig is not None:
            md += [f"![{label}: the recordings' Allan deviations and the pooled model]({fig.name})", ""]
        if label in verdicts:
            md += [f"Against {verdicts[label]['file']} (the pooled model):", ""]
            md += verdict_lines(label, verdicts[label], markdown=True) + [""]
    md.append("units: " + "; ".join(f"{k}: {v}" for k, v in units.items()))
    return "\n".join(md) + "\n"

"""Export fitted models of a recording's axes: the formats' files, ``export.json``, ``export.md`` and the Allan
figure (what ``torchtea export`` and ``fit``/``check --export`` write)."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..sensors.measurements import DOCUMENT_MEANING, RECORDING_MEANING
from .formats import FORMATS, FormatError
from .nees import nees_study
from .terms import IN_FORMATS, axis_terms

__all__ = ["EXPORT_MEANING", "export_axes", "write_export", "resolve_formats", "NEES_TAUS", "ExportPlan", "plan_export",
           "export_recording", "export_lines"]

#: The outages of the NEES study (s), those within a quarter of the record.
NEES_TAUS = (0.1, 1.0, 10.0, 60.0)

#: Samples of the NEES study's series (at most; the record's length if shorter).
NEES_SAMPLES = 30_000


#: What each entry of ``export.json`` means; the file carries it (with the recording's part,
#: :data:`~torchtea.sensors.measurements.RECORDING_MEANING`).
EXPORT_MEANING = {
    **RECORDING_MEANING,
    **DOCUMENT_MEANING,
    "bare": "N (white noise density) and K (bias random walk) as the fitted model has them",
    "pooled": "where several recordings were fitted together: their names, in words what comes from all of them (the "
              "noise parameters, with the pooled intervals) and what from the first (mean terms, the cover's data), "
              "and per axis the noise parameters in which the recordings differ (their pooled value a compromise)",
    "covered": "the least N, K whose Allan deviation covers the fitted model's over the horizon",
    "factor": "covered / bare (None where the model has none of the term)",
    "forced_by": "the τ where the cover touches the model and the component largest there",
    "ieee952": "IEEE Std 952 coefficients: Q angle quantisation, N angle/velocity random walk, B bias instability "
               "(ADEV minimum / 0.664), K rate random walk, R rate ramp",
    "nees": "the outage NEES study (torchtea.export.nees): bare and covered values in a static IMU's filter on series "
            "simulated from the fitted model",
    "values": "which values the formats' files hold: bare (the fit's) or covered (the Allan cover's)",
    "files": "each format's file, by format",
    "skipped": "each format the recording cannot fill, with why",
    "axes": "one entry per axis: its sensor, unit, model, N, B, K, the IEEE 952 terms with intervals, the cover and "
            "the datasheet verdict where one was given",
    "figure": "the Allan deviation figure of every axis, the model's and the cover's",
    "seconds": "wall-clock seconds of the whole export (fits, cover, NEES study)",
}


def resolve_formats(names) -> list:
    """``["kalibr", "all", …]`` → the formats' names; an unknown one is a ``ValueError`` naming it and the known."""
    out = []
    for name in names:
        for n in str(name).split(","):
            n = n.strip()
            if n == "all":
                out += [k for k in FORMATS if k not in out]
            elif n in FORMATS:
                out += [n] if n not in out else []
            else:
                raise ValueError(f"unknown export format {n!r}: one of {', '.join(FORMATS)} or all")
    return out


@dataclass(frozen=True)
class ExportPlan:
    """What an export will write, checked before any fitting: the formats, the horizon (s) the cover spans and the
    note that says where it was clipped to the recording (or None)."""

    formats: list
    horizon: tuple
    horizon_note: str | None


def plan_export(m, names, horizon: str | None) -> ExportPlan | None:
    """Check what an export of ``m`` (:class:`~torchtea.sensors.measurements.Measurements`) asks for before any
    fitting: the formats ``names`` (an unknown one, or one named that needs a sensor the recording lacks, is a
    ``ValueError`` saying so), the ``horizon`` (``"LO:HI"`` or None for the default) within the recording, SI sensor
    channels only (a plain signal column is an :class:`~torchtea.sensors.io.InputError`). None: no export asked."""
    if not names:
        return None
    from ..sensors.io import InputError
    from .terms import parse_horizon

    formats = resolve_formats(names)
    span, note = parse_horizon(horizon, m.h, m.samples)
    signals = [c.name for c in m.channels if c.sensor == "signal"]
    if signals:
        raise InputError(f"cannot export column(s) {', '.join(signals)}: not an accelerometer or gyroscope axis in "
                         "SI units (the formats take m/s^2 and rad/s); name the sensor columns with --columns and "
                         "--units")
    have = {c.sensor for c in m.channels}
    named = [n for x in names for n in str(x).split(",")]
    for f in formats:
        missing = [s for s in FORMATS[f].needs if s not in have]
        if missing and f in named:
            raise ValueError(f"export format {f}: the file needs {' and '.join(FORMATS[f].needs)} noise; "
                             f"{Path(m.recording.path).name} has no {' or '.join(missing)} channel analysed "
                             f"(--format ieee952 takes any axis)")
    return ExportPlan(formats, span, note)


def export_recording(m, plan: ExportPlan, fits: dict, out: Path, *, inputs: dict | None = None,
                     meta: dict | None = None, nees: int = 64, seed: int = 0, values: str = "covered",
                     plots: bool = True, sheets: dict | None = None,
                     repeatability: dict | None = None) -> tuple[dict, list]:
    """Export the fitted models ``fits`` (label → :class:`~torchtea.fitting.mle.Fit`) of ``m``'s channels as
    ``plan`` says, into ``out`` (:func:`export_axes`, then :func:`write_export` with ``meta`` and the plan's horizon
    note); ``repeatability``: label → the turn-on bias repeatability of recordings fitted together, held against the
    datasheet's. Returns the JSON document and the axes' terms."""
    axes = export_axes(fits, m.series(), {c.label: c.sensor for c in m.channels}, m.h, plan.horizon,
                       inputs=inputs, nees=nees, seed=seed)
    if sheets:
        from ..fitting.datasheet import compare

        for a in axes:
            if a.sensor in sheets:
                a.datasheet = compare(a, sheets[a.sensor], fits[a.label], m.h,
                                      repeatability=(repeatability or {}).get(a.label))
    doc = write_export(out, axes, plan.formats, dict(meta or {}, horizon_note=plan.horizon_note), which=values,
                       plots=plots)
    return doc, axes


def export_lines(doc: dict, axes: list, out: Path) -> list[str]:
    """An export's text summary: the files written (and those not, why), each axis's white noise N and random walk
    K bare → covered, and what forced them."""
    lines = [f"export {name}: {path}" for name, path in doc["files"].items()]
    lines += [f"export {name}: not written: {why}" for name, why in doc["skipped"].items()]
    for a in axes:
        lines.append(f"  {a.label}: N {a.bare['N'].value:.4g} → {a.covered['N'].value:.4g}, K {a.bare['K'].value:.4g} "
                     f"→ {a.covered['K'].value:.4g} {a.bare['K'].unit} (bare → covered)"
                     + "".join(f"; {t} forced by {v['component']} at τ {v['tau_s']:.3g} s"
                               for t, v in a.forced_by.items()))
    lines.append(f"export report: {Path(out) / 'export.md'}")
    return lines


def export_axes(fits: dict, series: dict, sensors: dict, h: float, horizon, inputs: dict | None = None,
                nees: int = 64, seed: int = 0) -> list:
    """``fits``/``series``/``sensors``: per axis label, its :class:`~torchtea.fitting.mle.Fit`, samples and sensor.
    Returns the :class:`~.terms.AxisTerms`, each with ``nees`` (the study with that many realisations; 0: none)."""
    out = []
    for label, fit in fits.items():
        y = np.asarray(series[label], dtype=np.float64)
        inp = inputs if inputs is not None and any(c.inputs for _, c in fit.model.components) else None
        a = axis_terms(fit, y, h, sensors[label], label, horizon, inputs=inp)
        if nees:
            n = min(len(y), NEES_SAMPLES)
            sets = {"bare": (a.bare["N"].value, a.bare["K"].value),
                    "covered": (a.covered["N"].value, a.covered["K"].value)}
            a.nees = nees_study(fit.model, fit.values, h, n, sets, NEES_TAUS, realisations=nees, seed=seed,
                                inputs=inp)
        out.append(a)
    return out


def write_export(out: Path, axes: list, formats: list, meta: dict, which: str = "covered",
                 plots: bool = True) -> dict:
    """Write each format's file (a format the recording cannot fill: its line in ``skipped``), ``export.json``,
    ``export.md`` and ``allan.png`` into ``out``. Returns the JSON document."""
    from ..render.strictjson import write

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    files, skipped = {}, {}
    for name in formats:
        fmt = FORMATS[name]
        try:
            text = fmt.render(axes, meta, which)
        except FormatError as exc:
            skipped[name] = str(exc)
            continue
        (out / fmt.filename).write_text(text)
        files[name] = str(out / fmt.filename)
    doc = {**meta, "values": which, "files": files, "skipped": skipped,
           "axes": {a.label: dict(a.as_dict(), nees=a.nees) for a in axes},
           "meaning": EXPORT_MEANING}
    if plots:
        doc["figure"] = str(allan_figure(out / "allan.png", axes))
    write(out / "export.json", doc)
    (out / "export.md").write_text(markdown(axes, doc))
    return doc


def _n(x, spec=".4g") -> str:
    return "—" if x is None else format(x, spec)


def _ci(num) -> str:
    return "—" if num is None or num.ci95 is None else f"[{num.ci95[0]:.3g}, {num.ci95[1]:.3g}]"


def markdown(axes: list, doc: dict) -> str:
    lines = [f"# Export of {doc.get('recording', '?')}", "",
             f"Files: {', '.join(Path(p).name for p in doc['files'].values()) or 'none'}; values written: "
             f"**{doc['values']}**. Continuous time: N a white noise density, K a bias random walk; a filter at Δt "
             "uses σ_d = N/√Δt and σ_bd = K·√Δt.", ""]
    if doc.get("pooled"):
        lines += [f"Pooled: {doc['pooled']['words']}."] + [
            f"- **{a}**: the recordings differ in {', '.join(d)}: its pooled value is their compromise, not the "
            "number of every recording" for a, d in doc["pooled"].get("differs", {}).items() if d] + [""]
    for name, why in doc["skipped"].items():
        lines += [f"- **{name} not written**: {why}"]
    lines += ["", "| axis | model | N bare [95 %] | N covered [95 %] (× factor) | K bare [95 %] | "
                  "K covered [95 %] (× factor) | forced by |", "|---|---|---|---|---|---|---|"]
    for a in axes:
        fb = "; ".join(f"{t}: {v['component']} at τ {v['tau_s']:.3g} s" for t, v in a.forced_by.items()) or "—"
        fN, fK = a.factor["N"], a.factor["K"]
        lines.append(f"| {a.label} | `{a.model}` | {_n(a.bare['N'].value)} {_ci(a.bare['N'])} | "
                     f"{_n(a.covered['N'].value)} {_ci(a.covered['N'])} (× {_n(fN.value if fN else None, '.3g')}) | "
                     f"{_n(a.bare['K'].value)} {_ci(a.bare['K'])} | {_n(a.covered['K'].value)} {_ci(a.covered['K'])} "
                     f"(× {_n(fK.value if fK else None, '.3g')}) | {fb} |")
    lines += ["", "Units: N in m/s²/√Hz (accelerometer) or rad/s/√Hz (gyroscope), K in m/s³/√Hz or rad/s²/√Hz. "
                  f"Horizon of the cover: {axes[0].horizon[0]:g}–{axes[0].horizon[1]:g} s." if axes else "", "",
              "## IEEE Std 952 coefficients", "", "| axis | Q | N | B | K | R |", "|---|---|---|---|---|---|"]
    for a in axes:
        cells = [f"{_n(a.ieee[s].value)} {_ci(a.ieee[s])} {a.ieee[s].unit}" for s in "QNBKR"]
        lines.append(f"| {a.label} | " + " | ".join(cells) + " |")
    lines += ["", "B is the model's ADEV minimum / 0.664; Q is not in any model (a rate's quantisation is white and "
                  "counts in N).", "", "## What the formats leave out", ""]
    left = [f"- {a.label}: {c['words']}" for a in axes for c in a.components if c["term"] not in IN_FORMATS]
    left += [f"- {a.label}: note: {x}" for a in axes for x in a.notes]
    lines += left or ["Nothing: every component is white noise, a random walk, a ramp or a constant level."]
    held = [a for a in axes if a.datasheet]
    if held:
        from ..fitting.datasheet import verdict_lines

        lines += ["", "## Against the datasheet", ""]
        for a in held:
            lines += [f"**{a.label}** against {a.datasheet['file']} ({a.datasheet['source']}):", ""]
            lines += verdict_lines(a.label, a.datasheet, markdown=True) + [""]
        lines.append("A datasheet's values are typical ones: within spec says the axis is no worse than the typical "
                     "part by this record.")
    study = [a for a in axes if a.nees]
    if study:
        s0 = study[0].nees
        lines += ["", "## The cover as a filter feels it (NEES)", "",
                  f"{s0['meaning']}. {s0['realisations']} realisations of {s0['samples']} samples; consistent "
                  f"band {s0['band'][0]:.2f}–{s0['band'][1]:.2f}.", "",
                  "| axis | outage τ (s) | NEES bare | NEES covered |", "|---|---|---|---|"]
        for a in study:
            for rb, rc in zip(a.nees["bare"]["outages"], a.nees["covered"]["outages"]):
                lines.append(f"| {a.label} | {rb['tau_s']:g} | {_n(rb['nees_end'], '.3g')} ({rb['verdict']}) | "
                             f"{_n(rc['nees_end'], '.3g')} ({rc['verdict']}) |")
    return "\n".join(lines) + "\n"


def allan_figure(path: Path, axes: list) -> Path:
    """Per sensor: the data's ADEV per axis, the model, its components, the bare and covered white + random-walk
    lines, and the IEEE slopes −1/2, 0, +1/2."""
    from ..render.plots import pyplot, save_figure

    plt = pyplot()
    fig, panels = plt.subplots(len(axes), 1, figsize=(8, 3.2 * len(axes)), squeeze=False)
    for ax, a in zip(panels[:, 0], axes):
        c = a.curves
        tau = np.asarray(c["tau_s"])
        if "adev_data" in c:
            ax.loglog(tau, c["adev_data"], "k.", ms=4, label="data")
        ax.loglog(tau, c["adev_model"], "k-", lw=1.5, label=f"model {a.model}")
        for k, v in c["adev_components"].items():
            if np.any(np.asarray(v) > 0):
                ax.loglog(tau, v, ":", lw=1, label=k)
        ax.loglog(tau, c["adev_bare"], "C0--", lw=1.2, label="white + walk, bare")
        ax.loglog(tau, c["adev_covered"], "C3-", lw=1.2, label="white + walk, covered")
        top = float(np.nanmax(c["adev_model"]))
        for slope, name in ((-0.5, "−1/2: N"), (0.0, "0: B"), (0.5, "+1/2: K")):
            ax.loglog(tau, top * (tau / tau[0]) ** slope * 0.3, color="0.75", lw=0.8)
            ax.annotate(name, (tau[-1], top * (tau[-1] / tau[0]) ** slope * 0.3), fontsize=7, color="0.4")
        ax.set_title(f"{a.label} ({a.sensor})", fontsize=9)
        ax.set_xlabel("τ [s]")
        ax.set_ylabel(f"ADEV [{a.ieee['B'].unit}]")
        ax.legend(fontsize=6, loc="best")
    return save_figure(plt, fig, path)

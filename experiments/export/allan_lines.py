"""The exported numbers beside what an Allan line fit gives on the same data (issue 31).

    python experiments/export/allan_lines.py real/unmoved_x_forward real/unmoved_z_front_x_up   # after run.sh

For each export directory (``torchtea export … --out DIR``) the recording it names is read again (the units and rate
of run.sh) and every axis's overlapping ADEV computed (allantools, octave τ). The line fit is the usual hand
procedure of the Allan tools: N is the ADEV line of slope −1/2 read at τ = 1 s, K the line of slope +1/2 read at
τ = 3 s, each fitted (intercept only, slope fixed) to the τ whose local slope lies within ±0.25 of it; B is the ADEV
minimum / 0.664. Where no τ has such a slope the line is not there (—). Writes ``real.md`` and ``real.json`` here.
"""
from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np

from torchtea.checking import allan
from torchtea.sensors.io import read_recording

HERE = Path(__file__).resolve().parent


def line_fit(y: np.ndarray, h: float) -> dict:
    """N, K, B of the hand procedure (module docstring), with the τ each used."""
    m = allan.octave_clusters(len(y), max_fraction=0.25)
    tau = m * h
    ad = allan.data_adev(y, h, m)
    lt, la = np.log(tau), np.log(ad)
    slope = np.gradient(la, lt)
    out = {"tau_s": tau.tolist(), "adev": ad.tolist()}
    for name, s, at in (("N", -0.5, 1.0), ("K", 0.5, 3.0)):
        sel = np.abs(slope - s) <= 0.25
        if not sel.any():
            out[name], out[name + "_taus"] = None, []
            continue
        b = float(np.mean(la[sel] - s * lt[sel]))  # log ADEV = b + s log τ
        out[name] = math.exp(b + s * math.log(at))
        out[name + "_taus"] = tau[sel].tolist()
    i = int(np.argmin(ad))
    out["B"], out["B_tau_s"] = float(ad[i] / 0.664), float(tau[i])
    return out


def _f(x, ci=None) -> str:
    if x is None:
        return "—"
    s = f"{x:.3g}"
    return s + (f" [{ci[0]:.3g}, {ci[1]:.3g}]" if ci else "")


def main(dirs: list[str]) -> None:
    rows, doc = [], {}
    for d in dirs:
        d = Path(d)
        ex = json.loads((d / "export.json").read_text())
        rec = read_recording(ex["recording"], units="g,g,g,deg/s,deg/s,deg/s", rate_hz=ex["rate_hz"],
                             temperature_column=ex.get("temperature_column"))
        name = Path(ex["recording"]).stem
        n = ex["samples"]
        doc[name] = {}
        for label, a in ex["axes"].items():
            y = rec.channel(label).values[:n]
            ok = np.isfinite(y)
            lf = line_fit(np.where(ok, y, np.nanmean(y)), rec.h) if ok.all() else None
            doc[name][label] = {"export": {k: a[k] for k in ("model", "bare", "covered", "factor", "forced_by")},
                                "B": a["ieee952"]["B"], "line_fit": lf}
            nb, nc, kb, kc = (a[w][t] for t in ("N", "K") for w in ("bare", "covered"))
            fN, fK = a["factor"]["N"], a["factor"]["K"]
            forced = "; ".join(f"{t}: {v['component']} at {v['tau_s']:.3g} s" for t, v in a["forced_by"].items())
            rows.append(f"| {name} | {label} | `{a['model']}` | {_f(nb['value'], nb['ci95'])} | "
                        f"{_f(nc['value'], nc['ci95'])} (× {_f(fN['value'] if fN else None)}) | "
                        f"{_f(lf['N'] if lf else None)} | {_f(kb['value'], kb['ci95'])} | "
                        f"{_f(kc['value'], kc['ci95'])} (× {_f(fK['value'] if fK else None)}) | "
                        f"{_f(lf['K'] if lf else None)} | {_f(a['ieee952']['B']['value'], a['ieee952']['B']['ci95'])} | "
                        f"{_f(lf['B'] if lf else None)} | {forced or '—'} |")
    head = ["| recording | axis | model (check --auto) | N bare [95 %] | N covered [95 %] (× factor) | N line fit | "
            "K bare [95 %] | K covered [95 %] (× factor) | K line fit | B [95 %] | B line fit | cover forced by |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    text = "\n".join(head + rows) + "\n"
    (HERE / "real.md").write_text(text)
    (HERE / "real.json").write_text(json.dumps(doc, indent=1))
    print(text)


if __name__ == "__main__":
    main(sys.argv[1:])

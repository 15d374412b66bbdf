"""Hidden-effect study of ``check`` (issue 12): does it name the effect that is in the data, and nothing on
clean data?

    python experiments/check/hidden.py                      # all cases (resumes: one JSON per case)
    python experiments/check/hidden.py --effects sinusoid --seeds 5
    python experiments/check/hidden.py --tables             # only the tables from what is saved
    # two processes, one thread each (two processes with numba's and torch's default threads run ~10× slower)
    export NUMBA_NUM_THREADS=1 OMP_NUM_THREADS=1
    python experiments/check/hidden.py --shard 0/2 & python experiments/check/hidden.py --shard 1/2

Data: MEMS-like base noise — ``fractional+white`` with :func:`torchtea.noise.default_values` (order 0.3, pole
at 40 % of its stability limit, drive q = r/h^{2α}, white r = 10⁻³ (m/s²)²), h = 0.01 s, 30 000 samples — and a
temperature that warms up by 3 °C (τ = 60 s) plus a 0.2 °C wander, in every case; plus one hidden effect at
the strength in :data:`STRENGTH` (or none). Each case is checked with the default model ``fractional+white``,
the temperature given, no intervals. Recorded per case: the top suggestion, whether the model was called
adequate, the failed diagnostics before and after adding the top suggestion, the metrics, the fitted
parameters of the effect against the truth, and the seconds.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from torchtea.checking import check
from torchtea.studies.hidden import BASE_MODEL, HIDDEN_STRENGTH, hidden_case

HERE = Path(__file__).resolve().parent
H, N = 0.01, 30_000
BASE = BASE_MODEL
STRENGTH = HIDDEN_STRENGTH
SEEDS = {"none": 100}
DEFAULT_SEEDS = 50


def case(effect: str, seed: int):
    return hidden_case(effect, seed, N, H)


def run_case(effect: str, seed: int) -> dict:
    y, T, truth = case(effect, seed)
    t0 = time.perf_counter()
    r = check(y, H, model=BASE, inputs={"temperature": T}, intervals=False)
    out = {"effect": effect, "seed": seed, "strength": STRENGTH[effect], "truth": truth, "adequate": r.adequate, "failed": r.failed,
           "metrics": r.metrics, "screens": [s.as_dict() for s in r.screens], "timings": r.timings, "seconds": time.perf_counter() - t0,
           "suggestions": [s.as_dict() for s in r.suggestions], "notes": r.notes}
    out["top"] = r.suggestions[0].effect if r.suggestions else None
    return out


def _iqr(x) -> str:
    q = np.percentile(x, [25, 50, 75])
    return f"{q[1]:.4g} [{q[0]:.4g}, {q[2]:.4g}]"


def tables(d: Path) -> str:
    rows = [json.loads(p.read_text()) for p in sorted(d.glob("*.json"))]
    if not rows:
        return "nothing saved yet"
    stale = [r for r in rows if r.get("strength", STRENGTH[r["effect"]]) != STRENGTH[r["effect"]]]
    rows = [r for r in rows if r not in stale]
    effects = [e for e in STRENGTH if any(r["effect"] == e for r in rows)]
    tops = sorted({str(r["top"]) for r in rows} | set(effects[1:]) | {"None"})
    out = ["**Confusion matrix** (hidden effect → top suggestion; `None`: no suggestion) and, for the cases with a "
           "suggestion, how often the model with the top suggestion added passes every diagnostic.", "",
           "| hidden effect | strength | seeds | " + " | ".join(f"→ {t}" for t in tops) +
           " | right first | inadequate before | adequate after adding the top |",
           "|---|---|---|" + "---|" * len(tops) + "---|---|---|"]
    for e in effects:
        rs = [r for r in rows if r["effect"] == e]
        counts = [sum(str(r["top"]) == t for r in rs) for t in tops]
        right = sum(r["top"] == (None if e == "none" else e) for r in rs)
        after = [not r["suggestions"][0]["after"]["failed"] for r in rs if r["suggestions"]]
        strength = ", ".join(f"{k.split('.', 1)[1]} {v:g}" for k, v in STRENGTH[e].items()) or "—"
        out.append(f"| {e} | {strength} | {len(rs)} | " + " | ".join(map(str, counts)) +
                   f" | {right}/{len(rs)} ({100 * right / len(rs):.0f} %) | {sum(not r['adequate'] for r in rs)}/{len(rs)}"
                   f" | {sum(after)}/{len(after)} |")
    out += ["", "**Error metrics before → after adding the top suggestion** (median over the seeds whose top "
            "suggestion is the hidden effect; nll/sample: the exact −ℓ per sample; misfits: mean |log₁₀| ratio of data to model in the PSD bands / at the Allan τ):", "",
            "| hidden effect | n | nll/sample before → after | PSD misfit before → after | ADEV misfit before → after "
            "| failed diagnostics before → after (total over the seeds) |", "|---|---|---|---|---|---|"]
    for e in effects[1:] if effects and effects[0] == "none" else effects:
        rs = [r for r in rows if r["effect"] == e and r["top"] == e]
        if not rs:
            continue
        cells = []
        for key in ("nll_per_sample", "psd_misfit", "adev_misfit"):
            b = np.median([r["metrics"][key] for r in rs])
            a = np.median([r["suggestions"][0]["after"][key] for r in rs])
            cells.append(f"{b:.4g} → {a:.4g}")
        fb = sum(len(r["failed"]) for r in rs)
        fa = sum(len(r["suggestions"][0]["after"]["failed"]) for r in rs)
        out.append(f"| {e} | {len(rs)} | " + " | ".join(cells) + f" | {fb} → {fa} |")
    out += ["", "**The effect's fitted parameters against the truth** (seeds whose top suggestion is the hidden "
            "effect; median [quartiles]):", "", "| hidden effect | parameter | truth | fitted |", "|---|---|---|---|"]
    for e in effects:
        rs = [r for r in rows if r["effect"] == e and r["top"] == e]
        for name, true in STRENGTH.get(e, {}).items():
            p = name.split(".", 1)[1]
            fitted = [r["suggestions"][0]["parameters"][p] for r in rs if p in r["suggestions"][0]["parameters"]]
            if fitted:
                out.append(f"| {e} | {p} | {true:g} | {_iqr(fitted)} |")
    secs = [r["seconds"] for r in rows]
    restarts = sum(any("local maximum" in n for n in r.get("notes", [])) for r in rows)
    out += ["", f"checks whose first fit of the model was a local maximum (run again from a candidate's better "
                f"point): {restarts}/{len(rows)}"]
    out += ["", f"seconds per check: median {np.median(secs):.1f}, max {np.max(secs):.1f} ({len(secs)} checks)"]
    if stale:
        out.append(f"({len(stale)} saved cases at an earlier strength left out)")
    return "\n".join(out)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--effects", default=",".join(STRENGTH))
    ap.add_argument("--seeds", type=int, help="seeds per effect (default 50, 100 for none)")
    ap.add_argument("--dir", default=str(HERE / "hidden"))
    ap.add_argument("--tables", action="store_true")
    ap.add_argument("--shard", default="0/1", help="i/k: run only the cases whose seed is i modulo k")
    args = ap.parse_args()
    d = Path(args.dir)
    d.mkdir(parents=True, exist_ok=True)
    if not args.tables:
        effects = args.effects.split(",")
        n = {e: args.seeds or SEEDS.get(e, DEFAULT_SEEDS) for e in effects}
        i, k = (int(x) for x in args.shard.split("/"))
        for seed in range(max(n.values())):  # every effect grows together
            if seed % k != i:
                continue
            for e in effects:
                path = d / f"{e}_{seed:03d}.json"
                if seed >= n[e] or path.exists():
                    continue
                res = run_case(e, seed)
                path.write_text(json.dumps(res))
                print(f"{e} seed {seed}: top {res['top']} ({res['seconds']:.0f} s)", flush=True)
    text = tables(d)
    d.with_suffix(".md").write_text(text + "\n")  # beside the cases (--dir /tmp/x → /tmp/x.md)
    print(text)


if __name__ == "__main__":
    main()

"""The long-record path against the exact one, on simulated records where both run.

For each model of ``CASES`` and each seed, a record of ``--n`` samples (default 12 000 at 100 Hz: above
``WHITTLE_PATH_SAMPLES``, below ``POLISH_SAMPLES``) is fitted three ways: the exact path (``fit_series``, exact
likelihood from several starts), the long-record path as ``check --fits auto`` runs it (the Whittle fit refined on the
exact likelihood from its best point) and the Whittle estimates alone (``--fits whittle``). Each estimate's distance
from the exact one is given in the exact path's standard errors; with ``--loop`` the whole ``check --auto`` runs with
``fits="exact"`` and ``fits="auto"`` and their final models and verdicts are compared.

    python experiments/fit/whittle_path_study.py [--seeds 5] [--n 12000] [--loop] [--out whittle_path_study.json]
    python experiments/fit/whittle_path_study.py --table [--out …]

Writes the JSON (per record: the three fits' estimates, their distances in standard errors, ℓ, seconds; the loops'
models and verdicts) and prints the table (markdown)."""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

HERE = Path(__file__).resolve().parent
H = 0.01
CASES = [("white+random-walk", {}), ("fractional+white", {}), ("white+gauss-markov", {"gauss-markov.tau_s": 5.0}),
         ("white+resonance", {"resonance.sigma": 0.01, "resonance.bandwidth_hz": 0.5}),
         ("fractional+white+random-walk", {})]


def one(spec: str, values: dict, seed: int, n: int, loop: bool) -> dict:
    from torchtea.checking import check
    from torchtea.fitting import whittle_path as wp
    from torchtea.fitting.mle import fit_series
    from torchtea.noise import default_values, simulate_model

    v = {**default_values(spec, H), **values}
    y = simulate_model(spec, v, n_steps=n, h=H, generator=torch.Generator().manual_seed(seed))[0, 0].numpy()
    row = {"model": spec, "seed": seed, "n": n}
    t = time.perf_counter()
    exact = fit_series(spec, [y], H, method="exact", intervals=True, profile=False)[0]
    row["exact"] = {"values": exact.values, "se": exact.se, "loglik": exact.loglik_exact,
                    "seconds": time.perf_counter() - t}
    for fits in ("auto", "whittle"):
        t = time.perf_counter()
        f = wp.whittle_estimate(spec, y, H, intervals=True, fits=fits)
        z = {k: (f.values[k] - exact.values[k]) / exact.se[k] for k in exact.values if exact.se.get(k)}
        row[fits] = {"values": f.values, "z": z, "max_abs_z": max(abs(x) for x in z.values()), "method": f.method,
                     "loglik": f.loglik_exact, "seconds": time.perf_counter() - t}
    if loop:
        for fits in ("exact", "auto"):
            t = time.perf_counter()
            r = check(y, H, fits=fits).auto()
            row[f"loop_{fits}"] = {"model": r.model.spec, "adequate": bool(r.adequate), "bic": r.fit.bic_exact,
                                   "failed": [d.name for d in r.diagnostics if d.passed is False],
                                   "seconds": time.perf_counter() - t}
    return row


def table(doc: dict) -> str:
    lines = [f"Records of {doc['n']} samples at {1 / H:.0f} Hz, seeds 0–{doc['seeds'] - 1}; distances in the exact "
             "path's standard errors (the largest over the model's parameters).\n",
             "| true model | refined (auto): largest \\|z\\| median / max | ℓ below exact, max (nats) | Whittle alone: "
             "largest \\|z\\| median / max | ℓ below exact, max | s exact / auto / Whittle |",
             "|---|---|---|---|---|---|"]
    for spec, _ in CASES:
        rows = [r for r in doc["rows"] if r["model"] == spec]
        if not rows:
            continue
        za = [r["auto"]["max_abs_z"] for r in rows]
        zw = [r["whittle"]["max_abs_z"] for r in rows]
        da = max(r["exact"]["loglik"] - r["auto"]["loglik"] for r in rows)
        dw = max(r["exact"]["loglik"] - r["whittle"]["loglik"] for r in rows)
        s = [np.mean([r[k]["seconds"] for r in rows]) for k in ("exact", "auto", "whittle")]
        lines.append(f"| {spec} | {np.median(za):.3f} / {max(za):.3f} | {da:.3f} | {np.median(zw):.3f} / "
                     f"{max(zw):.3f} | {dw:.3f} | {s[0]:.2f} / {s[1]:.2f} / {s[2]:.2f} |")
    loops = [r for r in doc["rows"] if "loop_exact" in r]
    if loops:
        lines += ["", "| true model | seed | exact loop: model, adequate, BIC, s | long-record loop: model, adequate, "
                  "BIC, s |", "|---|---|---|---|"]
        for r in loops:
            e, a = r["loop_exact"], r["loop_auto"]
            lines.append(f"| {r['model']} | {r['seed']} | {e['model']}, {e['adequate']}, {e['bic']:.1f}, "
                         f"{e['seconds']:.1f} | {a['model']}, {a['adequate']}, {a['bic']:.1f}, {a['seconds']:.1f} |")
        same = sum(r["loop_exact"]["model"] == r["loop_auto"]["model"] and
                   r["loop_exact"]["adequate"] == r["loop_auto"]["adequate"] for r in loops)
        lines.append(f"\nThe same model and verdict on {same} of {len(loops)} records.")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--n", type=int, default=12_000)
    ap.add_argument("--loop", action="store_true", help="also check --auto both ways")
    ap.add_argument("--out", default=str(HERE / "whittle_path_study.json"))
    ap.add_argument("--table", action="store_true")
    args = ap.parse_args()
    if args.table:
        print(table(json.loads(Path(args.out).read_text())))
        return 0
    doc = {"n": args.n, "seeds": args.seeds, "rows": []}
    for spec, values in CASES:
        for seed in range(args.seeds):
            doc["rows"].append(one(spec, values, seed, args.n, args.loop))
            print(spec, seed, f"auto {doc['rows'][-1]['auto']['max_abs_z']:.3f}",
                  f"whittle {doc['rows'][-1]['whittle']['max_abs_z']:.3f}", flush=True)
            Path(args.out).write_text(json.dumps(doc, indent=1))
    print(table(doc))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Issue 15: is the MEMS setting's order and pole identifiable at all from 3000 samples? The exact likelihood decides.

    python experiments/montecarlo/mems_identifiability.py [--realisations 40]

The MEMS truth of consistency.py (α 0.4, f −4, q 0.01, r 4e-4, h 0.01 s, 3000 samples, no input), one realisation
per seed (``simulate_noise_model``, what ``torchtea simulate --seed`` writes). Each is fitted by the exact maximum
likelihood of ``fractional+white`` (``torchtea.fitting.fit_series``, method "exact", every parameter free, the
Whittle multi-start first): the most a 3000-sample series says about α and f, whatever the estimator. Reported:
the bias, spread and RMSE of the MLE's α̂ and f̂ over realisations, how often the MLE's 95 % interval for f covers
the truth and excludes 0 (f = 0 is the pure fractional-integrated noise with no pole; a fit without an interval —
its observed information not positive definite — counts as neither), the median interval width,
and, beside them, the TEA's order and parameter RMSE on the same truth (consistency.json, paper filters). An
estimator cannot do much better than the MLE; where the MLE's own spread of f is as large as f, f is not
identifiable from this much data. Writes mems_identifiability.json and prints the table.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parents[1]))
from consistency import MEMS_TRUTH  # noqa: E402

from torchtea.engines.structure import ConstantOrder  # noqa: E402
from torchtea.engines.simulate import simulate_noise_model  # noqa: E402
from torchtea.fitting.mle import fit_series  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--realisations", type=int, default=40)
    args = ap.parse_args()
    t = MEMS_TRUTH
    alpha, f = float(t["order"]), float(t["param"])
    series = [simulate_noise_model(n_steps=t["n"], h=t["h"], order=ConstantOrder(alpha), param=f, q=t["q"], r=t["r"],
                                   seed=s).y.reshape(-1).numpy() for s in range(args.realisations)]
    t0 = time.perf_counter()
    fits = fit_series("fractional+white", series, t["h"], method="exact")
    seconds = time.perf_counter() - t0
    a = np.array([ft.values["fractional.order"] for ft in fits])
    p = np.array([ft.values["fractional.pole"] for ft in fits])
    # 95 % intervals, NaN where the fit gives none (its observed information is not positive definite there)
    interval = lambda ft, n: [math.nan, math.nan] if ft.ci95.get(n) is None else list(ft.ci95[n])  # noqa: E731
    ci = np.array([interval(ft, "fractional.pole") for ft in fits], dtype=float)  # (R, 2)
    ci_a = np.array([interval(ft, "fractional.order") for ft in fits], dtype=float)
    stats = lambda v, truth: {"bias": float(v.mean() - truth), "sd": float(v.std(ddof=1)),  # noqa: E731
                              "rmse": float(math.sqrt(((v - truth) ** 2).mean())),
                              "quartiles": [float(x) for x in np.percentile(v, [25, 50, 75])]}
    out = {
        "truth": t, "realisations": args.realisations, "fit_seconds": seconds,
        "converged": int(sum(ft.converged for ft in fits)),
        "order": {**stats(a, alpha), "ci95_covers": float(((ci_a[:, 0] <= alpha) & (alpha <= ci_a[:, 1])).mean()),
                  "no_interval": int(np.isnan(ci_a[:, 0]).sum()),
                  "ci95_median_width": float(np.nanmedian(ci_a[:, 1] - ci_a[:, 0]))},
        "pole": {**stats(p, f), "ci95_covers": float(((ci[:, 0] <= f) & (f <= ci[:, 1])).mean()),
                 "ci95_excludes_0": float((ci[:, 1] < 0).mean()), "no_interval": int(np.isnan(ci[:, 0]).sum()),
                 "ci95_median_width": float(np.nanmedian(ci[:, 1] - ci[:, 0]))},
        "per_realisation": [{"seed": s, "order": float(a[s]), "pole": float(p[s]), "pole_ci95": ci[s].tolist(),
                             "order_ci95": ci_a[s].tolist()} for s in range(args.realisations)],
    }
    cons = HERE / "consistency.json"
    if cons.exists():
        mems = json.loads(cons.read_text()).get("mems", {})
        paper = mems.get("paper / paper") or mems.get("paper")
        if paper:
            out["tea_paper"] = {"order_rmse": paper["order"]["rmse"], "param_rmse": paper["param"]["rmse"],
                                "param_bias": paper["param"]["bias"]}
    (HERE / "mems_identifiability.json").write_text(json.dumps(out, indent=2) + "\n")
    print(f"exact MLE of fractional+white, {args.realisations} realisations of the MEMS truth, "
          f"{out['converged']} converged, {seconds:.0f} s; no interval for the pole in {out['pole']['no_interval']}")
    print("| | truth | bias | sd | RMSE | quartiles | 95 % CI covers | CI excludes 0 | median CI width | TEA RMSE |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    tea = out.get("tea_paper", {})
    for name, truth, key in (("order α", alpha, "order_rmse"), ("pole f", f, "param_rmse")):
        s = out["order" if name.startswith("order") else "pole"]
        q = " / ".join(f"{x:.3g}" for x in s["quartiles"])
        excl = f"{s['ci95_excludes_0']:.2f}" if "ci95_excludes_0" in s else "–"
        cell = f"{tea[key]:.3g}" if key in tea else "–"
        print(f"| {name} | {truth:g} | {s['bias']:+.3g} | {s['sd']:.3g} | {s['rmse']:.3g} | {q} | "
              f"{s['ci95_covers']:.2f} | {excl} | {s['ci95_median_width']:.3g} | {cell} |")


if __name__ == "__main__":
    main()

"""Issue 15: is the MEMS setting's order and pole identifiable at all from 3000 samples? The exact likelihood decides.

    python experiments/montecarlo/mems_identifiability.py [--realisations 40]

The MEMS truth of consistency.py (α 0.4, f −4, q 0.01, r 4e-4, h 0.01 s, 3000 samples, no input), one realisation
per seed (``simulate_noise_model``, what ``torchtea simulate --seed`` writes). Each is fitted by the exact maximum
likelihood of ``fractional+white`` (``torchtea.fitting.fit_series``, method "exact", the Whittle multi-start
first) twice: with every parameter free, and with the drive q and the white noise r fixed at the truth, as the
TEA's MEMS study is given them. That is the most a 3000-sample series says about α and f. Reported:
the bias, spread and RMSE of the MLE's α̂ and f̂ over realisations, how often the MLE's 95 % interval for f covers
the truth and excludes 0 (f = 0 is the pure fractional-integrated noise with no pole), both over the fits that
have an interval (a fit whose observed information is not positive definite has none; they are counted), the
median interval width, the share of f̂ within [2f, f/2],
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
from torchtea.fitting.mle import fit_series  # noqa: E402
from torchtea.noise.simulate import simulate_noise_model  # noqa: E402

VARIANTS = {"all free": {}, "q, r fixed at the truth": {"fractional.q": MEMS_TRUTH["q"], "white.r": MEMS_TRUTH["r"]}}


def summary(fits, alpha: float, f: float, seconds: float) -> dict:
    a = np.array([ft.values["fractional.order"] for ft in fits])
    p = np.array([ft.values["fractional.pole"] for ft in fits])
    # 95 % intervals, NaN where the fit gives none (its observed information is not positive definite there)
    interval = lambda ft, n: [math.nan, math.nan] if ft.ci95.get(n) is None else list(ft.ci95[n])  # noqa: E731
    ci = {n: np.array([interval(ft, f"fractional.{n}") for ft in fits], dtype=float) for n in ("order", "pole")}

    def stats(v, truth, c):
        has = ~np.isnan(c[:, 0])
        out = {"bias": float(v.mean() - truth), "sd": float(v.std(ddof=1)),
               "rmse": float(math.sqrt(((v - truth) ** 2).mean())),
               "quartiles": [float(x) for x in np.percentile(v, [25, 50, 75])],
               "with_interval": int(has.sum()),
               "ci95_covers": float(((c[has, 0] <= truth) & (truth <= c[has, 1])).mean()),
               "ci95_median_width": float(np.median(c[has, 1] - c[has, 0]))}
        return out

    pole = stats(p, f, ci["pole"])
    has = ~np.isnan(ci["pole"][:, 0])
    pole["ci95_excludes_0"] = float((ci["pole"][has, 1] < 0).mean())
    pole["within_factor_2"] = float(((p <= f / 2) & (p >= 2 * f)).mean())
    return {"fit_seconds": seconds, "converged": int(sum(ft.converged for ft in fits)),
            "order": stats(a, alpha, ci["order"]), "pole": pole,
            "per_realisation": [{"seed": s, "order": float(a[s]), "pole": float(p[s]),
                                 "order_ci95": ci["order"][s].tolist(), "pole_ci95": ci["pole"][s].tolist()}
                                for s in range(len(fits))]}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--realisations", type=int, default=40)
    args = ap.parse_args()
    t = MEMS_TRUTH
    alpha, f = float(t["order"]), float(t["param"])
    series = [simulate_noise_model(n_steps=t["n"], h=t["h"], order=ConstantOrder(alpha), param=f, q=t["q"], r=t["r"],
                                   seed=s).y.reshape(-1).numpy() for s in range(args.realisations)]
    out = {"truth": t, "realisations": args.realisations, "variants": {}}
    for name, fixed in VARIANTS.items():
        t0 = time.perf_counter()
        fits = fit_series("fractional+white", series, t["h"], method="exact", fixed=fixed)
        out["variants"][name] = summary(fits, alpha, f, time.perf_counter() - t0)
    cons = HERE / "consistency.json"
    if cons.exists():
        mems = json.loads(cons.read_text()).get("mems", {})
        paper = mems.get("paper / paper") or mems.get("paper")
        if paper:
            out["tea_paper"] = {"order_rmse": paper["order"]["rmse"], "param_rmse": paper["param"]["rmse"],
                                "param_bias": paper["param"]["bias"]}
    (HERE / "mems_identifiability.json").write_text(json.dumps(out, indent=2) + "\n")
    tea = out.get("tea_paper", {})
    print(f"exact MLE of fractional+white on {args.realisations} realisations of the MEMS truth")
    print("| fit | | truth | bias | sd | RMSE | quartiles | within [2f, f/2] | 95 % CI covers | CI excludes 0 | "
          "median CI width | fits with an interval | TEA RMSE |")
    print("|---" * 13 + "|")
    for name, v in out["variants"].items():
        for label, truth, key, tk in (("order α", alpha, "order", "order_rmse"), ("pole f", f, "pole", "param_rmse")):
            s = v[key]
            q = " / ".join(f"{x:.3g}" for x in s["quartiles"])
            within = f"{s['within_factor_2']:.2f}" if "within_factor_2" in s else "–"
            excl = f"{s['ci95_excludes_0']:.2f}" if "ci95_excludes_0" in s else "–"
            cell = f"{tea[tk]:.3g}" if tk in tea else "–"
            print(f"| {name} ({v['converged']} converged, {v['fit_seconds']:.0f} s) | {label} | {truth:g} | "
                  f"{s['bias']:+.3g} | {s['sd']:.3g} | {s['rmse']:.3g} | {q} | {within} | {s['ci95_covers']:.2f} | "
                  f"{excl} | {s['ci95_median_width']:.3g} | {s['with_interval']} | {cell} |")


if __name__ == "__main__":
    main()

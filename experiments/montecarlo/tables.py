"""Markdown table of the example Monte Carlo studies from results.json.

    python experiments/montecarlo/tables.py
"""
from __future__ import annotations

import json
from pathlib import Path

HERE = Path(__file__).resolve().parent


def main():
    results = json.loads((HERE / "results.json").read_text())
    print("| study | runs | diverged | order: bias / std / RMSE (final) | order ±2σ coverage | order converged "
          "(\\|err\\| < 0.05 to the end), median time | param: bias / std / RMSE (final) | mean NEES [95 % band] "
          "| mean NIS | wall [s] |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, s in results.items():
        o, p = s["order"], s["param"]
        conv = o.get("convergence_time_quantiles", {}).get("50%")
        nees = s.get("nees")
        nees_txt = "–" if not nees else f"{nees['mean']:.2f} [{nees['band_95'][0]:.2f}, {nees['band_95'][1]:.2f}]"
        nis_txt = "–" if not s.get("nis") else f"{s['nis']['mean']:.2f}"
        print(f"| {name} | {s['realisations']} | {s['diverged_fraction']:.1%} | "
              f"{o['bias']:+.4f} / {o['std']:.4f} / {o['rmse']:.4f} | {o['coverage_2sigma']:.3f} | "
              f"{o['converged_fraction']:.1%}, {f'{conv:.2f} s' if conv is not None else '–'} | "
              f"{p['bias']:+.3f} / {p['std']:.3f} / {p['rmse']:.3f} | {nees_txt} | {nis_txt} | "
              f"{s.get('wall_seconds', s.get('seconds'))} |")


if __name__ == "__main__":
    main()

"""Markdown tables for experiments/paper/README.md from results.json, mems_windows.json and example3_noise.json.

    python experiments/paper/tables.py
"""
from __future__ import annotations

import json
from pathlib import Path

HERE = Path(__file__).resolve().parent


def fmt(s: dict, key="median", digits=4):
    return "–" if not s or s.get("n", 0) == 0 else f"{s[key]:.{digits}f}"


def main():
    r = json.loads((HERE / "results.json").read_text())
    print(f"### Examples 1–3, {r['seeds']} seeds each (seed k = `torchtea simulate --seed k`)\n")
    print("| example | settings | diverged | \\|mean α̂(5–6 s) − α\\| median (p95, max) | order RMSE 1–6 s median (p95) "
          "| runs with RMSE ≤ 0.05 | mean ŵ(5–6 s) median [p05, p95] | x̂ RMSE 1–6 s median | mean NIS |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, ex in r["examples"].items():
        for v, m in ex["variants"].items():
            e, rm, w = m["abs_alpha_error_5_6s"], m["order_rmse_1_6s"], m["param_mean_5_6s"]
            err = "–" if e.get("n", 0) == 0 else f"{e['median']:.4f} ({e['p95']:.4f}, {e['max']:.4f})"
            rmse = "–" if rm.get("n", 0) == 0 else f"{rm['median']:.4f} ({rm['p95']:.4f})"
            ws = "–" if w.get("n", 0) == 0 else f"{w['median']:.3f} [{w['p05']:.3f}, {w['p95']:.3f}]"
            print(f"| {name.replace('paper-', '')} | {v} | {m['diverged_fraction']:.0%} | {err} | {rmse} | "
                  f"{m['fraction_rmse_le_0.05']:.0%} | {ws} | {fmt(m['state_rmse_1_6s'], digits=5)} | "
                  f"{fmt(m['nis_mean_1_6s'], digits=2)} |")
    if "mems" in r:
        print("\n### MEMS section on the bundled MPU-6050 recording (mean over the last third ± its sd)\n")
        print("| samples | R | x: α̂ | x: ŵ | y: α̂ | y: ŵ | z: α̂ | z: ŵ | s |")
        print("|---|---|---|---|---|---|---|---|---|")
        for key, s in r["mems"].items():
            n, mode = key.split("_")
            cells = []
            for a in "xyz":
                v = s["axes"][a]
                cells += [f"{v['alpha']:.3f} ± {v['alpha_std_last_third']:.3f}", f"{v['param']:.3f} ± {v['param_std_last_third']:.3f}"]
            print(f"| {n} | {mode} | " + " | ".join(cells) + f" | {s['seconds']} |")
    wpath = HERE / "mems_windows.json"
    if wpath.exists():
        w = json.loads(wpath.read_text())
        print(f"\n### Repeatability: every non-overlapping {w['window_samples'] // 100} s window, one batch\n")
        print("| recording | windows | axis | α̂ mean ± sd [min, max] | ŵ mean ± sd [min, max] |")
        print("|---|---|---|---|---|")
        for rec in w["recordings"].values():
            for a, s in rec["axes"].items():
                print(f"| {rec['file']} | {rec['windows']} | {a} | {s['alpha_mean']:.3f} ± {s['alpha_sd']:.3f} "
                      f"[{s['alpha_min']:.3f}, {s['alpha_max']:.3f}] | {s['param_mean']:.3f} ± {s['param_sd']:.3f} "
                      f"[{s['param_min']:.3f}, {s['param_max']:.3f}] |")
    npath = HERE / "example3_noise.json"
    if npath.exists():
        n = json.loads(npath.read_text())
        times = [c["t"] for c in n["rows"][0]["by_time"]]
        print(f"\n### Example 3 against measurement noise ({n['seeds']} seeds; true α / median α̂)\n")
        print("| R | α* | " + " | ".join(f"t = {t:g} s" for t in times) + " |")
        print("|---|---|" + "---|" * len(times))
        for row in n["rows"]:
            print(f"| {row['R']:.0e} | {row['alpha_star']:.2f} | " + " | ".join(
                f"{c['true']:.2f} / {c['median_estimate']:.2f}" for c in row["by_time"]) + " |")


if __name__ == "__main__":
    main()

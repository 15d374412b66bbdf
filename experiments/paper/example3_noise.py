"""Why Example 3 stops tracking: the order is identifiable only while the fresh drive h^α·σ_u of one step is
not buried in the measurement noise σ_ν, i.e. below α* = ln(σ_ν/σ_u) / ln h.

    python experiments/paper/example3_noise.py [--seeds 6]

Runs Example 3 (torchtea defaults) with the measurement noise R (truth and filter) at 1e-5 (the paper's),
1e-7 and 1e-9, and prints the median α̂ over seeds at several times against the true parabola.
Writes example3_noise.json.
"""
from __future__ import annotations

import argparse
import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from experiments.common import simulate_seeds, write_json  # noqa: E402
from torchtea import SCENARIOS, Structure, TEAConfig, get_preset, make_params, run_tea  # noqa: E402

HERE = Path(__file__).resolve().parent


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=6)
    args = ap.parse_args()
    base = get_preset("paper-example3")
    times = (1.0, 2.0, 3.0, 4.0, 5.0, 5.9)
    out = {"seeds": args.seeds, "rows": []}
    print(f"{'R':>7} {'α*':>5}  " + "  ".join(f"t={t:g}: true/median α̂" for t in times))
    for r in (1e-5, 1e-7, 1e-9):
        sc = replace(SCENARIOS["paper-example3"], r=r)
        y, u, x, a = simulate_seeds(sc, range(args.seeds))
        cfg = TEAConfig.from_dict({"kfx": {"R": r}, "kfo": {"R": r}, "kfw": {"R": r}}, base)
        res = run_tea(y, h=sc.h, params=make_params(cfg, Structure()), inputs=u)
        astar = math.log(math.sqrt(r) / sc.input_std) / math.log(sc.h)
        cells = []
        for t in times:
            k = int(round(t / sc.h))
            cells.append({"t": t, "true": float(a[0, k, 0]), "median_estimate": float(np.median(res.alpha[:, k, 0].numpy()))})
        out["rows"].append({"R": r, "alpha_star": astar, "diverged": int(res.diverged.sum()), "by_time": cells})
        print(f"{r:7.0e} {astar:5.2f}  " + "  ".join(f"{c['true']:.2f}/{c['median_estimate']:.2f}".rjust(20) for c in cells))
    write_json(HERE / "example3_noise.json", out)


if __name__ == "__main__":
    main()

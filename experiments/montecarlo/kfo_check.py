"""Issue 15: how honest KFo's and KFw's covariances are, and what the Robbins–Monro δ does to them.

    python experiments/montecarlo/kfo_check.py [--realisations 200]

For Example 1 and the MEMS setting of consistency.py (same truths and seeds), with KFo's δ as the preset has it
and at 0.1, the ratio mean((α̂ − α)²) / mean(Pᵒ) and the ±2σ coverage of the order by thirds of the run, the same
ratio for the parameter, and the final order bias and RMSE. A ratio of 1 is an honest covariance; ½ is what a
random-walk model of a constant order gives at steady state (P = K R, while the error of the same filter has
variance K R / (2 − K) for a constant truth). Writes kfo_check.json and prints the table.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parents[1]))
from consistency import SETTINGS  # noqa: E402

from torchtea.studies.cluster import run_study  # noqa: E402
from torchtea.studies.montecarlo import build_study  # noqa: E402

CASES = [("example1", None), ("example1", 0.1), ("mems", None), ("mems", 0.1)]


def check(name: str, delta: float | None, realisations: int) -> dict:
    preset, truth, seed = SETTINGS[name]
    est = {"preset": preset, **({} if delta is None else {"kfo": {"delta": delta}})}
    study, _ = build_study({"realisations": realisations, "seed": seed, "truth": truth, "estimator": est})
    tr = run_study(study, trajectories=True).trajectories
    e, P = tr["alpha"] - tr["alpha_true"], tr["P_alpha"]
    ew, Pw = tr["w"] - study.truth.param, tr["P_w"]
    N = e.shape[1]
    thirds = [slice(0, N // 3), slice(N // 3, 2 * N // 3), slice(2 * N // 3, N)]
    by = lambda f: [float(f(s)) for s in thirds]  # noqa: E731
    return {
        "kfo_delta": study.estimator.kfo.delta,
        "order_error_over_P": by(lambda s: (e[:, s] ** 2).mean() / P[:, s].mean()),
        "order_coverage": by(lambda s: (e[:, s].abs() <= 2 * P[:, s].sqrt()).double().mean()),
        "param_error_over_P": by(lambda s: (ew[:, s] ** 2).mean() / Pw[:, s].mean()),
        "param_coverage": by(lambda s: (ew[:, s].abs() <= 2 * Pw[:, s].sqrt()).double().mean()),
        "order_bias": float(e[:, -1].mean()), "order_rmse": float(e[:, -1].pow(2).mean().sqrt()),
        "param_bias": float(ew[:, -1].mean()), "param_rmse": float(ew[:, -1].pow(2).mean().sqrt()),
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--realisations", type=int, default=200)
    args = ap.parse_args()
    out = {f"{name} δ={'preset' if d is None else d}": check(name, d, args.realisations) for name, d in CASES}
    (HERE / "kfo_check.json").write_text(json.dumps({"realisations": args.realisations, "cases": out}, indent=2) + "\n")
    f = lambda xs, spec: " / ".join(format(x, spec) for x in xs)  # noqa: E731
    print("| case | KFo δ | order e²/P (thirds) | order ±2σ coverage (thirds) | param e²/P (thirds) | "
          "order bias / RMSE | param bias / RMSE |\n|---|---|---|---|---|---|---|")
    for case, r in out.items():
        print(f"| {case.split()[0]} | {r['kfo_delta']:g} | {f(r['order_error_over_P'], '.2f')} | "
              f"{f(r['order_coverage'], '.3f')} | {f(r['param_error_over_P'], '.3g')} | "
              f"{r['order_bias']:+.4f} / {r['order_rmse']:.4f} | {r['param_bias']:+.3f} / {r['param_rmse']:.3f} |")


if __name__ == "__main__":
    main()

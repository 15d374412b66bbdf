"""Issue 15: why the TEA misses the MEMS setting's order and parameter — each filter alone, each start, and the
paper's random-walk settings against constant-order ones, on the same realisations.

    python experiments/montecarlo/mems_diagnosis.py [--realisations 200]   → mems_diagnosis.json

The truth is consistency.py's MEMS setting (α = 0.4, f = −4, q = 0.01, r = 4·10⁻⁴, h = 0.01, 3000 samples,
no input). "Pinned" fixes a filter at the truth (P₀ = Q₀ = 10⁻³⁰, δ = 0); "constant" sets KFo and KFw for a
constant order and parameter (Q₀ = 0, δ = 0) instead of the paper's random walk (Q₀ = 0.1 adapted by δ = 0.5);
"start at the truth" moves the filters' x0 there and keeps their P₀; "consistent prior" draws every
realisation's starts from the filters' P₀ around the truth (torchtea montecarlo --prior consistent). The last
rows repeat "KFo alone" for smaller measurement noise r (the truth's r and every filter's R), to show the order's
bias growing with the noise on the state history the replica treats as exact.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parents[1]))
from consistency import MEMS_TRUTH, SETTINGS  # noqa: E402

from torchtea import TEAConfig, get_preset  # noqa: E402
from torchtea.render import strictjson  # noqa: E402
from torchtea.studies.cluster import run_study  # noqa: E402
from torchtea.studies.montecarlo import Study, Truth, summarise  # noqa: E402

PRESET, _, SEED = SETTINGS["mems"]
ALPHA, PARAM = float(MEMS_TRUTH["order"]), MEMS_TRUTH["param"]
PIN_O = {"x0": ALPHA, "P0": 1e-30, "Q0": 1e-30, "delta": 0.0}
PIN_W = {"x0": PARAM, "P0": 1e-30, "Q0": 1e-30, "delta": 0.0}
CONST = {"Q0": 0.0, "delta": 0.0}
#: (name, KFo/KFw overrides of the MEMS setting's preset, prior, r)
CASES = (
    ("paper settings: the TEA", {}, "preset", 4e-4),
    ("paper settings: KFw alone (order pinned)", {"kfo": PIN_O}, "preset", 4e-4),
    ("paper settings: KFo alone (parameter pinned)", {"kfw": PIN_W}, "preset", 4e-4),
    ("paper settings: start at the truth", {"kfo": {"x0": ALPHA}, "kfw": {"x0": PARAM}}, "preset", 4e-4),
    ("paper settings: consistent prior", {}, "consistent", 4e-4),
    ("constant: the TEA", {"kfo": CONST, "kfw": CONST}, "preset", 4e-4),
    ("constant: start at the truth", {"kfo": {**CONST, "x0": ALPHA}, "kfw": {**CONST, "x0": PARAM}}, "preset", 4e-4),
    ("constant: consistent prior", {"kfo": CONST, "kfw": CONST}, "consistent", 4e-4),
    ("constant: KFw alone, P0 = 4", {"kfo": PIN_O, "kfw": {**CONST, "P0": 4.0}}, "preset", 4e-4),
    *((f"paper settings: KFo alone, r = {r:g}", {"kfw": PIN_W}, "preset", r) for r in (1e-4, 1e-5, 1e-6)),
)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--realisations", type=int, default=200)
    args = ap.parse_args()
    out = {}
    rows = ["| case | order bias / RMSE | order ±2σ coverage | param bias / RMSE | param ±2σ coverage | mean NEES | diverged |",
            "|---|---|---|---|---|---|---|"]
    for name, overrides, prior, r in CASES:
        truth = Truth(**{"n_steps" if k == "n" else k: v for k, v in MEMS_TRUTH.items()} | {"r": r})
        base = TEAConfig.from_dict({"kfx": {"R": r}, "kfo": {"R": r}, "kfw": {"R": r}}, get_preset(PRESET))
        cfg = TEAConfig.from_dict(overrides, base)
        t0 = time.perf_counter()
        s = summarise(run_study(Study(truth, cfg, realisations=args.realisations, seed=SEED, prior=prior)))
        o, p = s["order"], s["param"]
        out[name] = {"overrides": overrides, "prior": prior, "r": r, "summary": s}
        rows.append(f"| {name} | {o['bias']:+.4f} / {o['rmse']:.4f} | {o['coverage_2sigma']:.3f} | "
                    f"{p['bias']:+.3f} / {p['rmse']:.3f} | {p['coverage_2sigma']:.3f} | {s['nees']['mean']:.3g} | "
                    f"{s['diverged']} |")
        print(f"{name}: {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
    (HERE / "mems_diagnosis.json").write_text(strictjson.dumps(out, indent=2) + "\n")
    print("\n".join(rows))


if __name__ == "__main__":
    main()

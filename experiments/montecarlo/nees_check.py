"""Where KFx's inconsistency comes from: NEES with α and w estimated (the TEA) against α and w pinned at the
truth (P₀ = Q₀ ≈ 0, no adaptation), Example 1 truth over 2000 samples, 40 realisations each.

    python experiments/montecarlo/nees_check.py      → nees_check.json
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from torchtea import TEAConfig, get_preset  # noqa: E402
from torchtea.studies.cluster import run_study  # noqa: E402
from torchtea.studies.montecarlo import Study, Truth, summarise  # noqa: E402

HERE = Path(__file__).resolve().parent


def main():
    truth = Truth(h=1e-3, n_steps=2000, order="0.35", param=-1.0, q=1e-4, r=1e-3, input_std=1.0)
    base = TEAConfig.from_dict({"kfx_uncertainty": "paper"}, get_preset("paper-example1"))  # the paper's KFx
    pinned = TEAConfig.from_dict({"kfo": {"x0": 0.35, "P0": 1e-30, "Q0": 1e-30, "delta": 0.0},
                                  "kfw": {"x0": -1.0, "P0": 1e-30, "Q0": 1e-30, "delta": 0.0}}, base)
    out = {}
    for name, cfg in (("estimated (TEA)", base), ("pinned at the truth", pinned)):
        s = summarise(run_study(Study(truth, cfg, realisations=40, seed=9)))
        out[name] = {"nees_mean": s["nees"]["mean"], "nees_inside_band": s["nees"]["fraction_of_steps_inside_band"],
                     "nis_mean": s["nis"]["mean"], "nis_inside_band": s["nis"]["fraction_of_steps_inside_band"],
                     "band_95": s["nees"]["band_95"]}
        print(f"{name:22s} NEES {s['nees']['mean']:7.2f} (inside band {s['nees']['fraction_of_steps_inside_band']:.3f})"
              f"   NIS {s['nis']['mean']:.3f}   band {s['nees']['band_95'][0]:.2f}–{s['nees']['band_95'][1]:.2f}")
    (HERE / "nees_check.json").write_text(json.dumps(out, indent=2) + "\n")


if __name__ == "__main__":
    main()

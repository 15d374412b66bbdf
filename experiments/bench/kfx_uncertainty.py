"""Benchmark of issue 15's settings: what ``kfx_uncertainty = "propagated"`` and ``"paper-gain"``, and
``"paper-gain"`` with ``estimate_uncertainty = "constant-truth"``, cost next to the paper's filters, side by side in
one run.

    python experiments/bench/kfx_uncertainty.py          # ≈ 4 min on 2 cores

The MEMS setting of ``engines.py`` (case A's data, paper §5.1 x-axis filter settings): the compiled engine on
1000 realisations × 3000 samples with ``soe`` and ``exact`` memory, and the torch engine on 100 × 1000 with ``soe``.
The four settings are interleaved over three rounds; the best time of each is kept. "paper-gain" carries a second
covariance and its history (the paper's, which sets the gain), so its history sums are done twice;
"constant-truth" adds a few scalar operations per filter and step. Prints a table
and writes ``experiments/bench/kfx_uncertainty.json``.
"""
from __future__ import annotations

import sys
import time
from dataclasses import replace
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))
from experiments.bench.engines import MEMS, mems_data  # noqa: E402
from experiments.common import machine, write_json  # noqa: E402
from torchtea import MemoryConfig, Structure, get_preset, make_params, run_tea  # noqa: E402

#: label → (kfx_uncertainty, estimate_uncertainty)
SETTINGS = {"paper": ("paper", "paper"), "propagated": ("propagated", "paper"), "paper-gain": ("paper-gain", "paper"),
            "paper-gain + constant-truth": ("paper-gain", "constant-truth")}
MODES = tuple(SETTINGS)
CASES = [("numba", "soe", 1000, 3000), ("numba", "exact", 1000, 3000), ("torch", "soe", 100, 1000)]


def main():
    rows = []
    for engine, memory, B, N in CASES:
        y = mems_data(B, N, seed=B).y
        params = {m: make_params(replace(get_preset("paper-mems-x"), memory=MemoryConfig(memory), kfx_uncertainty=k,
                                         estimate_uncertainty=e), Structure()) for m, (k, e) in SETTINGS.items()}
        for m in MODES:  # outside the timing: kernel load, the soe kernel's design for N samples
            run_tea(y[:1], h=MEMS["h"], params=params[m], engine=engine)
        best = {m: float("inf") for m in MODES}
        for _ in range(3):
            for m in MODES:
                t0 = time.perf_counter()
                run_tea(y, h=MEMS["h"], params=params[m], engine=engine)
                best[m] = min(best[m], time.perf_counter() - t0)
        for m in MODES:
            rows.append({"engine": engine, "memory": memory, "realisations": B, "samples": N, "setting": m,
                         "kfx_uncertainty": SETTINGS[m][0], "estimate_uncertainty": SETTINGS[m][1],
                         "best_s": round(best[m], 3), "vs_paper": round(best[m] / best["paper"], 2)})
            print(f"  {engine} {memory} {B} × {N} {m}: {best[m]:.3f} s", flush=True)
    n = len(MODES)
    print("\n| engine | memory | realisations × samples | paper [s] | " + " | ".join(f"{m} [s] (× paper)" for m in MODES[1:])
          + " |")
    print("|---" * (n + 3) + "|")
    for i in range(0, len(rows), n):
        p, *others = rows[i:i + n]
        print(f"| {p['engine']} | {p['memory']} | {p['realisations']} × {p['samples']} | {p['best_s']:.3f} | "
              + " | ".join(f"{q['best_s']:.3f} ({q['vs_paper']:.2f})" for q in others) + " |")
    write_json(HERE / "kfx_uncertainty.json", {"machine": machine(), "rows": rows})


if __name__ == "__main__":
    main()

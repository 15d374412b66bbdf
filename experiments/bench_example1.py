"""Benchmark: paper Example 1 (6000 samples), batched TEA for 1, 100, 1000 realisations against the
scalar NumPy reference loop of the tests, side by side in one run.

    python experiments/bench_example1.py [--sizes 1 100 1000] [--n 6000] [--ref-runs 2]

Prints a table and writes experiments/results/bench_example1.json. The reference loop is timed on
--ref-runs realisations and scaled linearly (it is a loop over realisations).
"""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from experiments.common import ROOT, machine, write_json  # noqa: E402
from tests.reference_tea import settings_from_config, tea_reference  # noqa: E402
from torchtea import SCENARIOS, Structure, gaussian_input, get_preset, make_params, run_tea, simulate  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[1, 100, 1000])
    ap.add_argument("--n", type=int, default=6000)
    ap.add_argument("--ref-runs", type=int, default=2)
    ap.add_argument("--out", default=str(ROOT / "results" / "bench_example1.json"))
    args = ap.parse_args()
    sc = replace(SCENARIOS["paper-example1"], n_steps=args.n)
    cfg = get_preset("paper-example1")
    params = make_params(cfg, Structure())
    rows = []
    ref_per_run = None
    for B in args.sizes:
        g = torch.Generator().manual_seed(B)
        u = gaussian_input((B,), sc.n_steps, 1, sc.input_std, generator=g)
        t0 = time.perf_counter()
        sim = simulate(Structure(), n_steps=sc.n_steps, h=sc.h, order=sc.order, parameters=[sc.param],
                       process_noise=sc.q, measurement_noise=sc.r, inputs=u, batch_shape=(B,), generator=g)
        t_sim = time.perf_counter() - t0
        t0 = time.perf_counter()
        res = run_tea(sim.y, h=sc.h, params=params, inputs=u)
        t_tea = time.perf_counter() - t0
        if ref_per_run is None:
            s = settings_from_config(cfg)
            t0 = time.perf_counter()
            refs = [tea_reference(sim.y[i % B, :, 0].numpy(), u[i % B, :, 0].numpy(), sc.h, s)
                    for i in range(args.ref_runs)]
            ref_per_run = (time.perf_counter() - t0) / args.ref_runs
            agree = max(float(np.abs(res.alpha[i % B, :, 0].numpy() - r["a"]).max()) for i, r in enumerate(refs))
        alpha_last = res.alpha[:, -int(1.0 / sc.h):, 0].mean(-1)
        rows.append({
            "realisations": B, "samples": sc.n_steps, "simulate_s": round(t_sim, 3), "tea_batched_s": round(t_tea, 3),
            "tea_per_realisation_s": round(t_tea / B, 5), "reference_loop_s_scaled": round(ref_per_run * B, 2),
            "speedup_vs_reference": round(ref_per_run * B / t_tea, 2),
            "diverged": int(res.diverged.sum()), "alpha_mean_last_second_median": round(float(alpha_last.median()), 4),
        })
        print(f"done B={B}: TEA {t_tea:.1f} s", file=sys.stderr, flush=True)
    out = {"benchmark": "paper Example 1, exact full-history TEA", "machine": machine(),
           "reference_seconds_per_realisation": round(ref_per_run, 3), "reference_runs_timed": args.ref_runs,
           "max_abs_alpha_difference_batched_vs_reference": agree, "paper_seconds_per_realisation": 495.0,
           "rows": rows}
    write_json(Path(args.out), out)
    print(f"Example 1, {sc.n_steps} samples; scalar NumPy reference: {ref_per_run:.2f} s per realisation "
          f"(timed on {args.ref_runs}); max |α̂ batched − α̂ reference| = {agree:.1e}; paper (MATLAB): 495 s")
    print(f"{'realisations':>12} {'simulate s':>10} {'TEA batched s':>14} {'s/realisation':>13} "
          f"{'reference s':>11} {'speed-up':>8} {'diverged':>8}")
    for r in rows:
        print(f"{r['realisations']:>12} {r['simulate_s']:>10.2f} {r['tea_batched_s']:>14.2f} "
              f"{r['tea_per_realisation_s']:>13.4f} {r['reference_loop_s_scaled']:>11.1f} "
              f"{r['speedup_vs_reference']:>8.1f} {r['diverged']:>8}")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()

"""Benchmark suite of the history sums: exact vs. exponential sums (soe), side by side in one run.

    python experiments/bench/run.py [--quick] [--skip-long]

Cases (issue 4):
1. Monte Carlo throughput on the MEMS setting (h = 0.01 s, 3000 samples, paper §5.1 x-axis settings,
   truth α 0.4, f −4, Q 0.01, R 4e−4): 1, 100, 1000 realisations, ``exact`` and ``soe`` (eager),
   against the scalar NumPy reference loop of the tests (timed on a few realisations, scaled).
2. A long recording: 3 axes × 10⁶ samples with ``soe`` and torch.compile, outputs stored every 100th
   step; wall time (compile included, and with the compile cache warm) and the process's peak memory,
   in a fresh subprocess so that its peak is its own.
3. Time per step against the step index k (= history length) for ``exact`` and ``soe`` in one long run
   each (plot ``step_time.png``).
4. Accuracy: max |α̂_soe − α̂_exact|, |x̂_soe − x̂_exact| on the same data (case 1's batches and
   paper Example 1).

Prints a table and writes ``experiments/bench/results.json``.
"""
from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))
from experiments.common import machine, write_json  # noqa: E402
from tests.reference_tea import settings_from_config, tea_reference  # noqa: E402
from torchtea import (SCENARIOS, ConstantOrder, MemoryConfig, Structure, gaussian_input, get_preset,  # noqa: E402
                      make_params, run_tea, simulate)

MEMS = dict(h=0.01, order=0.4, param=-4.0, q=0.01, r=4e-4)


def mems_data(B: int, N: int, seed: int):
    g = torch.Generator().manual_seed(seed)
    return simulate(Structure(), n_steps=N, h=MEMS["h"], order=ConstantOrder(MEMS["order"]),
                    parameters=[MEMS["param"]], process_noise=MEMS["q"], measurement_noise=MEMS["r"],
                    batch_shape=(B,), generator=g, memory="soe" if N > 20000 else "exact")


def with_memory(cfg, kind):
    return replace(cfg, memory=MemoryConfig(kind))


def timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


def diff(a, b):
    return float((a - b).abs().max())


# --------------------------------------------------------------------------- case 1 and 4


def throughput(sizes, N, ref_runs):
    cfg = get_preset("paper-mems-x")
    rows = []
    s = settings_from_config(cfg)
    sim1 = mems_data(max(ref_runs, 1), N, seed=1)
    t0 = time.perf_counter()
    for i in range(ref_runs):
        tea_reference(sim1.y[i, :, 0].numpy(), None, MEMS["h"], s)
    ref_per = (time.perf_counter() - t0) / ref_runs
    for B in sizes:
        sim = mems_data(B, N, seed=B)
        res, t = {}, {}
        for kind in ("soe", "exact"):
            params = make_params(with_memory(cfg, kind), Structure())
            res[kind], t[kind] = timed(lambda: run_tea(sim.y, h=MEMS["h"], params=params))
        rows.append({
            "realisations": B, "samples": N,
            "exact_s": round(t["exact"], 2), "soe_s": round(t["soe"], 2),
            "reference_loop_s_scaled": round(ref_per * B, 1),
            "soe_speedup_vs_exact": round(t["exact"] / t["soe"], 2),
            "max_abs_dalpha": diff(res["soe"].alpha, res["exact"].alpha),
            "max_abs_dx": diff(res["soe"].x, res["exact"].x),
            "max_abs_dw": diff(res["soe"].w, res["exact"].w),
            "max_abs_x": float(res["exact"].x.abs().max()),
            "diverged_exact": int(res["exact"].diverged.sum()), "diverged_soe": int(res["soe"].diverged.sum()),
        })
        print(f"  {B:5d} realisations: exact {t['exact']:7.2f} s, soe {t['soe']:6.2f} s, "
              f"reference ×{B} {ref_per * B:8.1f} s, max|Δα̂| {rows[-1]['max_abs_dalpha']:.1e}", flush=True)
    return rows, ref_per


def example1_accuracy(B=10):
    sc = SCENARIOS["paper-example1"]
    g = torch.Generator().manual_seed(11)
    u = gaussian_input((B,), sc.n_steps, 1, sc.input_std, generator=g)
    sim = simulate(Structure(), n_steps=sc.n_steps, h=sc.h, order=sc.order, parameters=[sc.param],
                   process_noise=sc.q, measurement_noise=sc.r, inputs=u, batch_shape=(B,), generator=g)
    cfg = get_preset("paper-example1")
    out = {}
    for kind in ("soe", "exact"):
        out[kind], _ = timed(lambda: run_tea(sim.y, h=sc.h, params=make_params(with_memory(cfg, kind), Structure()),
                                             inputs=u))
    return {"realisations": B, "samples": sc.n_steps,
            "max_abs_dalpha": diff(out["soe"].alpha, out["exact"].alpha),
            "max_abs_dx": diff(out["soe"].x, out["exact"].x), "max_abs_x": float(out["exact"].x.abs().max()),
            "max_rel_dP": float(((out["soe"].P - out["exact"].P).abs() / out["exact"].P.abs()).max())}


# --------------------------------------------------------------------------- case 3


def step_times(N, B):
    """Per-step wall time against k for one run of each memory kind (timestamps from the progress hook)."""
    cfg = get_preset("paper-mems-x")
    sim = mems_data(B, N, seed=7)
    curves = {}
    for kind in ("soe", "exact"):
        stamps = np.zeros(N)

        def hook(k, total, stamps=stamps):
            stamps[k] = time.perf_counter()

        stamps[0] = time.perf_counter()
        run_tea(sim.y, h=MEMS["h"], params=make_params(with_memory(cfg, kind), Structure()), progress=hook)
        dt = np.diff(stamps)  # dt[k-1] = time of step k
        edges = np.unique(np.geomspace(100, N - 1, 12).astype(int))
        curves[kind] = [{"k": int(k), "us_per_step_median": round(float(np.median(dt[max(k - 200, 0):k])) * 1e6, 1)}
                        for k in edges]
        print(f"  {kind}: " + ", ".join(f"k={c['k']}: {c['us_per_step_median']:.0f} µs" for c in curves[kind]),
              flush=True)
    return curves


def plot_step_times(curves, path, B):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for kind, rows in curves.items():
        ax.loglog([r["k"] for r in rows], [r["us_per_step_median"] for r in rows], "o-", label=kind)
    ax.set_xlabel("step k (history length)")
    ax.set_ylabel("wall time per step [µs] (median of 200 steps)")
    ax.set_title(f"TEA time per step, {B} realisations, MEMS settings")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


# --------------------------------------------------------------------------- case 2


def long_recording_child(N, every, compile_):
    """Runs in a subprocess: 3 axes × N samples, soe; prints one JSON line."""
    sim, t_sim = timed(lambda: mems_data(3, N, seed=3))
    y = sim.y.clone()
    del sim
    cfg = with_memory(get_preset("paper-mems-x"), "soe")
    params = make_params(cfg, Structure())
    res, t = timed(lambda: run_tea(y, h=MEMS["h"], params=params, record_every=every, compile=compile_))
    peak_mib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps({"samples": N, "axes": 3, "record_every": every, "compile": compile_,
                      "simulate_s": round(t_sim, 1), "tea_s": round(t, 1), "peak_rss_mib": round(peak_mib),
                      "stored_rows": int(res.alpha.shape[-2]), "diverged": int(res.diverged.sum()),
                      "alpha_final": [round(float(a), 4) for a in res.alpha[:, -1, 0]]}))


def long_recording(N, every, compile_):
    cmd = [sys.executable, __file__, "--child-long", str(N), str(every), "1" if compile_ else "0"]
    t0 = time.perf_counter()
    out = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if out.returncode != 0:
        raise RuntimeError(f"long-recording child failed:\n{out.stderr[-3000:]}")
    row = json.loads(out.stdout.strip().splitlines()[-1])
    row["process_wall_s"] = round(wall, 1)
    return row


# --------------------------------------------------------------------------- main


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small sizes (a smoke run, not the issue's cases)")
    ap.add_argument("--skip-long", action="store_true", help="skip case 2 (3 × 10⁶ samples)")
    ap.add_argument("--out", default=str(HERE / "results.json"))
    ap.add_argument("--child-long", nargs=3, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child_long:
        n, every, comp = args.child_long
        long_recording_child(int(n), int(every), comp == "1")
        return
    sizes, N, ref_runs = ([1, 10], 600, 1) if args.quick else ([1, 100, 1000], 3000, 2)
    results = {"machine": machine(), "command": " ".join(sys.argv)}

    print("case 1: Monte Carlo throughput, MEMS setting", flush=True)
    results["throughput"], ref_per = throughput(sizes, N, ref_runs)
    results["reference_loop_s_per_realisation"] = round(ref_per, 3)

    print("case 4: accuracy on paper Example 1", flush=True)
    results["accuracy_example1"] = example1_accuracy(3 if args.quick else 10)

    print("case 3: time per step against k", flush=True)
    Nk, Bk = (2000, 10) if args.quick else (16000, 10)
    results["step_time"] = {"realisations": Bk, "curves": step_times(Nk, Bk)}
    plot_step_times(results["step_time"]["curves"], HERE / "step_time.png", Bk)

    if not args.skip_long:
        N_long = 20000 if args.quick else 1_000_000
        print(f"case 2: long recording, 3 × {N_long} samples, soe + torch.compile (two runs: cold, warm cache)",
              flush=True)
        results["long_recording"] = [long_recording(N_long, 100, True) for _ in range(2)]
        for r in results["long_recording"]:
            print(f"  TEA {r['tea_s']} s, peak RSS {r['peak_rss_mib']} MiB, simulate {r['simulate_s']} s", flush=True)

    write_json(Path(args.out), results)
    print_table(results)
    print(f"wrote {args.out}")


def print_table(r):
    print("\n| realisations | exact | soe | scalar NumPy reference (scaled) | soe vs exact | max |Δα̂| | max |Δx̂| |")
    print("|---|---|---|---|---|---|---|")
    for row in r["throughput"]:
        print(f"| {row['realisations']} | {row['exact_s']} s | {row['soe_s']} s | {row['reference_loop_s_scaled']} s "
              f"| {row['soe_speedup_vs_exact']}× | {row['max_abs_dalpha']:.1e} | {row['max_abs_dx']:.1e} |")
    a = r["accuracy_example1"]
    print(f"\nExample 1 ({a['realisations']} × {a['samples']}): max|Δα̂| {a['max_abs_dalpha']:.1e}, "
          f"max|Δx̂| {a['max_abs_dx']:.1e} (max|x̂| {a['max_abs_x']:.2f}), max rel ΔP {a['max_rel_dP']:.1e}")
    for row in r.get("long_recording", []):
        print(f"long recording 3 × {row['samples']}: TEA {row['tea_s']} s (compile={row['compile']}), "
              f"peak RSS {row['peak_rss_mib']} MiB")


if __name__ == "__main__":
    main()

"""Benchmark suite of the history sums: exact vs. exponential sums (soe), side by side in one run.

    python experiments/bench/run.py [--quick] [--skip-long]

Cases (issue 4):
1. Monte Carlo throughput on the MEMS setting (h = 0.01 s, 3000 samples, paper §5.1 x-axis settings,
   truth α 0.4, f −4, Q 0.01, R 4e−4): 1, 100, 1000 realisations, ``exact`` and ``soe`` (eager),
   against the scalar NumPy reference loop of the tests (timed on a few realisations, scaled).
2. A long recording: 3 axes × 10⁶ samples (simulated once with ``soe``), the TEA with ``soe`` and
   torch.compile, outputs stored every 100th step; wall time (cold and warm compile cache) and memory, in
   fresh subprocesses: the process's peak RSS and the peak of the TEA phase alone.
3. Time per step against the step index k (= history length) for ``exact`` and ``soe`` in one long run
   each (plot ``step_time.png``).
4. Accuracy: max |α̂_soe − α̂_exact|, |x̂_soe − x̂_exact| on the same data (case 1's batches and
   paper Example 1), and how much the TEA itself amplifies a 1e−12 change of the data on the MEMS setting.
Also: glibc's allocator defaults against ``torchtea.core.alloc.tune_allocator`` (fresh processes).

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
from torchtea import (  # noqa: E402
    SCENARIOS,
    ConstantOrder,
    MemoryConfig,
    Structure,
    gaussian_input,
    get_preset,
    make_params,
    simulate,
)
from torchtea import run_tea as _run_tea  # noqa: E402
from torchtea.core.alloc import tune_allocator  # noqa: E402


def run_tea(*args, **kw):
    """This suite measures the batched torch engine's history sums (its results.json predates the compiled engine,
    which ``run_tea`` now picks for the scalar model on the CPU; ``engines.py`` compares the two)."""
    return _run_tea(*args, engine="torch", **kw)


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
        clean = res["soe"].memory_clamped == 0  # realisations whose sigma orders stayed inside the kernel's range
        rows.append({
            "realisations": B, "samples": N,
            "soe_clamped_realisations": int((~clean).sum()),
            "max_abs_dalpha_unclamped": diff(res["soe"].alpha[clean], res["exact"].alpha[clean]) if clean.any() else None,
            "median_abs_dalpha_final": float((res["soe"].alpha[:, -1] - res["exact"].alpha[:, -1]).abs().median()),
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
              f"reference ×{B} {ref_per * B:8.1f} s, max|Δα̂| {rows[-1]['max_abs_dalpha']:.1e} "
              f"({rows[-1]['soe_clamped_realisations']} clamped; unclamped {rows[-1]['max_abs_dalpha_unclamped']})",
              flush=True)
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


def conditioning(B, N):
    """How much the TEA itself amplifies tiny input changes on the MEMS setting: exact vs. exact with the
    measurements scaled by (1 + 1e−12), next to soe vs. exact, per realisation."""
    cfg = get_preset("paper-mems-x")
    sim = mems_data(B, N, seed=4242)
    run = lambda y, kind: run_tea(y, h=MEMS["h"], params=make_params(with_memory(cfg, kind), Structure()))  # noqa: E731
    exact, soe, pert = run(sim.y, "exact"), run(sim.y, "soe"), run(sim.y * (1 + 1e-12), "exact")
    clean = soe.memory_clamped == 0
    per = lambda a, b: (a.alpha - b.alpha).abs().amax((-2, -1))  # noqa: E731
    d_soe, d_pert = per(soe, exact), per(pert, exact)
    q = lambda t: {"median": float(t.median()), "p90": float(t.quantile(0.9)), "max": float(t.max())}  # noqa: E731
    out = {"realisations": B, "samples": N, "soe_clamped_realisations": int((~clean).sum()),
           "exact_vs_exact_y_times_1_plus_1e-12": q(d_pert), "soe_vs_exact_unclamped": q(d_soe[clean]),
           "soe_vs_exact_clamped": q(d_soe[~clean]) if (~clean).any() else None}
    print(f"  max|Δα̂| per realisation (median / p90 / max): exact vs exact·(1+1e−12): "
          f"{out['exact_vs_exact_y_times_1_plus_1e-12']}; soe vs exact (unclamped): {out['soe_vs_exact_unclamped']}; "
          f"{out['soe_clamped_realisations']} clamped", flush=True)
    return out


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


def _status_mib(field):
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1]) / 1024
    return float("nan")


def long_recording_child(path, every, compile_):
    """Runs in a subprocess: the TEA on 3 axes of a saved series, soe; prints one JSON line.

    Memory: the process's peak RSS, and the peak of the TEA phase alone (the high-water mark is reset
    through /proc/self/clear_refs once the data are loaded and torch is imported)."""
    y = torch.load(path)
    N = y.shape[-2]
    cfg = with_memory(get_preset("paper-mems-x"), "soe")
    params = make_params(cfg, Structure())
    rss_before = _status_mib("VmRSS")
    try:
        Path("/proc/self/clear_refs").write_text("5")
        reset = True
    except OSError:
        reset = False
    res, t = timed(lambda: run_tea(y, h=MEMS["h"], params=params, record_every=every, compile=compile_))
    peak_mib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    tea_peak = _status_mib("VmHWM") if reset else float("nan")
    print(json.dumps({"samples": N, "axes": 3, "record_every": every, "compile": compile_,
                      "tea_s": round(t, 1), "peak_rss_mib": round(peak_mib), "rss_before_tea_mib": round(rss_before),
                      "tea_phase_peak_rss_mib": round(tea_peak), "input_mib": round(y.numel() * 8 / 2**20),
                      "stored_rows": int(res.alpha.shape[-2]), "diverged": int(res.diverged.sum()),
                      "alpha_final": [round(float(a), 4) for a in res.alpha[:, -1, 0]]}))


def allocator_child(B, N, tune):
    """Runs in a subprocess: soe TEA on B MEMS realisations, with or without tune_allocator."""
    if tune:
        tune_allocator()
    sim = mems_data(B, N, seed=B)
    params = make_params(with_memory(get_preset("paper-mems-x"), "soe"), Structure())
    times = [timed(lambda: run_tea(sim.y, h=MEMS["h"], params=params))[1] for _ in range(2)]
    print(json.dumps({"realisations": B, "samples": N, "tune_allocator": tune, "soe_s": [round(x, 2) for x in times]}))


def child(*argv):
    out = subprocess.run([sys.executable, __file__, *map(str, argv)], capture_output=True, text=True)
    if out.returncode != 0:
        raise RuntimeError(f"child {argv} failed:\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def long_recording(path, every, compile_):
    row, wall = timed(lambda: child("--child-long", path, every, "1" if compile_ else "0"))
    row["process_wall_s"] = round(wall, 1)
    return row


# --------------------------------------------------------------------------- main


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small sizes (a smoke run, not the issue's cases)")
    ap.add_argument("--skip-long", action="store_true", help="skip case 2 (3 × 10⁶ samples)")
    ap.add_argument("--out", default=str(HERE / "results.json"))
    ap.add_argument("--child-long", nargs=3, help=argparse.SUPPRESS)
    ap.add_argument("--child-alloc", nargs=3, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child_long:
        n, every, comp = args.child_long
        long_recording_child(n, int(every), comp == "1")
        return
    if args.child_alloc:
        b, n, tune = args.child_alloc
        allocator_child(int(b), int(n), tune == "1")
        return
    sizes, N, ref_runs = ([1, 10], 600, 1) if args.quick else ([1, 100, 1000], 3000, 2)
    results = {"machine": machine(), "command": " ".join(sys.argv)}

    print("case 1: Monte Carlo throughput, MEMS setting", flush=True)
    results["throughput"], ref_per = throughput(sizes, N, ref_runs)
    results["reference_loop_s_per_realisation"] = round(ref_per, 3)

    print("case 4b: conditioning of the TEA on the MEMS setting", flush=True)
    results["conditioning_mems"] = conditioning(20 if args.quick else 100, N)

    print("case 4: accuracy on paper Example 1", flush=True)
    results["accuracy_example1"] = example1_accuracy(3 if args.quick else 10)

    print("case 3: time per step against k", flush=True)
    Nk, Bk = (2000, 10) if args.quick else (16000, 10)
    results["step_time"] = {"realisations": Bk, "curves": step_times(Nk, Bk)}
    plot_step_times(results["step_time"]["curves"], HERE / "step_time.png", Bk)

    Ba, Na = (50, 300) if args.quick else (1000, 1000)
    print(f"allocator: soe, {Ba} × {Na}, glibc defaults vs tune_allocator (fresh processes, 2 runs each)", flush=True)
    results["allocator"] = [child("--child-alloc", Ba, Na, t) for t in ("0", "1", "0", "1")]
    for r in results["allocator"]:
        print(f"  tune_allocator={r['tune_allocator']}: {r['soe_s']} s", flush=True)

    if not args.skip_long:
        N_long = 20000 if args.quick else 1_000_000
        print(f"case 2: long recording, 3 × {N_long} samples, soe + torch.compile (two runs: cold, warm cache)",
              flush=True)
        sim, t_sim = timed(lambda: mems_data(3, N_long, seed=3))
        print(f"  simulated with soe memory in {t_sim:.0f} s", flush=True)
        import tempfile

        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "y.pt"
            torch.save(sim.y.clone(), path)
            del sim
            results["long_recording"] = [long_recording(path, 100, True) for _ in range(2)]
        results["long_recording_simulate_s"] = round(t_sim, 1)
        for r in results["long_recording"]:
            print(f"  TEA {r['tea_s']} s, peak RSS {r['peak_rss_mib']} MiB (TEA phase {r['tea_phase_peak_rss_mib']} MiB)",
                  flush=True)

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
              f"peak RSS {row['peak_rss_mib']} MiB, TEA phase {row['tea_phase_peak_rss_mib']} MiB "
              f"(RSS before {row['rss_before_tea_mib']} MiB)")


if __name__ == "__main__":
    main()

"""Benchmark of the TEA engines (issue 13): the compiled scalar engine (numba) against the batched torch engine and
the scalar NumPy reference loop, side by side in one run.

    python experiments/bench/engines.py            # ≈ 8 min on 2 cores; --quick for a smoke run; --skip-fit

Cases, each with its baseline measured in the same run:
A. TEA alone, MEMS setting (h = 0.01 s, α 0.4, f −4, Q 0.01, R 4e−4; paper §5.1 x-axis settings), 1000 realisations
   × 3000 samples: numba and torch, ``soe`` and ``exact``; the reference loop timed on 2 realisations and scaled.
   Also max |Δ| between the engines' outputs.
B. One realisation × 3000 samples: the same engines (best of 3) against one reference run.
C. ``torchtea montecarlo`` of case A's study end to end (simulation, TEA, statistics, TensorBoard), a fresh process.
D. ``torchtea identify --samples all --memory soe`` on the bundled 449 s recording, a fresh process: with
   ``--r measured`` (the TEA's work) and with the default ``--r fitted`` (exact-likelihood fit of the noise levels,
   with intervals) unless ``--skip-fit``.
E. Time per step and realisation against N (numba, soe and exact, 10 realisations), the sizes interleaved over
   three rounds so that the machine's drift cannot fake a slope.
F. The compiled engine's start-up in a fresh process (numba loading its cached kernel; compiling on a cold cache).
G. The exact log-likelihood of ``fractional+white`` (the compiled Kalman filter on the soe state) for 10⁶ samples,
   one parameter set: the first call (designing the soe kernel for 10⁶ lags) and a second one. The data are white
   noise: the filter's work does not depend on the values.

Prints a table and writes ``experiments/bench/engines.json``.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import torch

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))
from experiments.common import machine, write_json  # noqa: E402
from tests.reference_tea import settings_from_config, tea_reference  # noqa: E402
from torchtea import ConstantOrder, MemoryConfig, Structure, get_preset, make_params, run_tea, simulate  # noqa: E402

MEMS = dict(h=0.01, order=0.4, param=-4.0, q=0.01, r=4e-4)
TRUTH_FLAGS = ["--h", "0.01", "--order", "0.4", "--param", "-4", "--q", "0.01", "--r", "4e-4"]


def mems_data(B: int, N: int, seed: int):
    g = torch.Generator().manual_seed(seed)
    return simulate(Structure(), n_steps=N, h=MEMS["h"], order=ConstantOrder(MEMS["order"]), parameters=[MEMS["param"]],
                    process_noise=MEMS["q"], measurement_noise=MEMS["r"], batch_shape=(B,), generator=g, memory="soe")


def params_for(kind: str):
    return make_params(replace(get_preset("paper-mems-x"), memory=MemoryConfig(kind)), Structure())


def timed(fn, repeat: int = 1):
    best, out = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return out, best


def maxdiff(a, b) -> float:
    return max(float((getattr(a, f) - getattr(b, f)).abs().max()) for f in ("x", "P", "alpha", "w", "innovation"))


def engines_case(B: int, N: int, repeat: int, ref_runs: int, device: str = "cpu"):
    sim = mems_data(B, N, seed=B)
    s = settings_from_config(get_preset("paper-mems-x"))
    _, t_ref = timed(lambda: [tea_reference(sim.y[i, :, 0].numpy(), None, MEMS["h"], s) for i in range(ref_runs)])
    ref = t_ref / ref_runs * B
    rows = []
    for kind in ("soe", "exact"):
        p = params_for(kind)
        # outside the timing: numba loads its kernel, and the soe kernel for N samples is designed (cached per N)
        run_tea(sim.y[:1], h=MEMS["h"], params=p, engine="numba")
        # the first run in the process pays the first touch of its output memory (240 MB for 1000 × 3000; ~12 µs per
        # 4 kB page on this project's VMs), later runs reuse it: both are recorded
        fast, t_first = timed(lambda: run_tea(sim.y, h=MEMS["h"], params=p, engine="numba"))
        if repeat > 1:
            fast, t_fast = timed(lambda: run_tea(sim.y, h=MEMS["h"], params=p, engine="numba"), repeat - 1)
            t_fast = min(t_fast, t_first)
        else:
            t_fast = t_first
        slow, t_slow = timed(lambda: run_tea(sim.y, h=MEMS["h"], params=p, engine="torch"), 1 if B > 1 else repeat)
        rows.append({"realisations": B, "samples": N, "memory": kind, "numba_s": round(t_fast, 3),
                     "numba_first_s": round(t_first, 3),
                     "torch_s": round(t_slow, 3), "reference_s": round(ref, 2),
                     "numba_vs_torch": round(t_slow / t_fast, 1), "numba_vs_reference": round(ref / t_fast, 1),
                     "max_abs_diff_numba_torch": maxdiff(fast, slow)})
        if device != "cpu":  # the torch engine on the accelerator, against the same numbers on the CPU
            yd, pd = sim.y.to(device), make_params(replace(get_preset("paper-mems-x"), memory=MemoryConfig(kind)),
                                                    Structure(), device=device)
            run_tea(yd[:1], h=MEMS["h"], params=pd)
            on_dev, t_dev = timed(lambda: (run_tea(yd, h=MEMS["h"], params=pd), torch.cuda.synchronize()
                                           if device.startswith("cuda") else None)[0], repeat)
            rows[-1].update({"device": device, "device_s": round(t_dev, 3), "device_vs_numba": round(t_fast / t_dev, 2),
                             "max_abs_diff_device_numba": max(float((getattr(on_dev, f).cpu() - getattr(fast, f)).abs().max())
                                                              for f in ("x", "alpha", "w"))})
        print(f"  {B} × {N} {kind}: numba {t_fast:.3f} s, torch {t_slow:.2f} s, reference {ref:.1f} s "
              f"(max|Δ| {rows[-1]['max_abs_diff_numba_torch']:.1e})", flush=True)
    return rows


def command(args: list[str]) -> dict:
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "torchtea.cli", *args], capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"torchtea {' '.join(args)} failed:\n{proc.stderr[-2000:]}")
    return {"command": "torchtea " + " ".join(args), "wall_s": round(wall, 2)}


def montecarlo_case(B: int, N: int, device: str = "cpu") -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        row = command(["montecarlo", "--preset", "paper-mems-x", "--realisations", str(B), "--n", str(N), *TRUTH_FLAGS,
                       "--memory", "soe", "--seed", "1", "--logdir", f"{tmp}/mc", "--json", "--device", device])
        row["study_s"] = json.loads((Path(tmp) / "mc" / "summary.json").read_text())["seconds"]
    return row


def identify_case(r_mode: str, samples: str) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        row = command(["identify", "--samples", samples, "--memory", "soe", "--r", r_mode, "--no-plots",
                       "--out", f"{tmp}/id"])
        row["reported_s"] = json.loads((Path(tmp) / "id" / "summary.json").read_text())["seconds"]
    return row


def step_times(sizes, B: int, rounds: int = 3) -> list[dict]:
    data = {N: mems_data(B, N, seed=N) for N in sizes}
    times = {(kind, N): [] for kind in ("soe", "exact") for N in sizes}
    for N in sizes:  # the soe kernel for each N is designed once (cached), outside the timing
        run_tea(data[N].y[:1], h=MEMS["h"], params=params_for("soe"), engine="numba")
    for _ in range(rounds):
        for N in sizes:  # interleaved: every size once per round
            for kind in ("soe", "exact"):
                _, t = timed(lambda: run_tea(data[N].y, h=MEMS["h"], params=params_for(kind), engine="numba"))
                times[(kind, N)].append(t)
    return [{"memory": kind, "samples": N, "realisations": B, "us_per_step_realisation": [round(t / (N * B) * 1e6, 3) for t in ts]}
            for (kind, N), ts in times.items()]


def startup() -> dict:
    code = ("import time, torch; t0 = time.perf_counter(); from torchtea import run_tea, make_params, get_preset, Structure; "
            "from dataclasses import replace; from torchtea import MemoryConfig; "
            "p = make_params(replace(get_preset('paper-mems-x'), memory=MemoryConfig('soe')), Structure()); t1 = time.perf_counter(); "
            "run_tea(torch.zeros(1, 10, 1, dtype=torch.float64), h=0.01, params=p, engine='numba'); "
            "print(t1 - t0, time.perf_counter() - t1)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    return {"import_s": round(float(out[0]), 2), "first_call_s": round(float(out[1]), 2)}


def exact_likelihood(N: int) -> dict:
    import numpy as np

    from torchtea.fitting.mle import exact_loglik

    vals = {"fractional.order": 0.3, "fractional.pole": -2.0, "fractional.q": 1e-3, "white.r": 1e-3}
    y = np.random.default_rng(0).normal(0.0, 0.05, N)
    exact_loglik("fractional+white", vals, y[:1000], 0.01)  # numba's kernel, outside the timing
    _, first = timed(lambda: exact_loglik("fractional+white", vals, y, 0.01))
    _, second = timed(lambda: exact_loglik("fractional+white", vals, y, 0.01))
    return {"samples": N, "first_s": round(first, 2), "second_s": round(second, 2)}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small sizes (a smoke run, not the issue's cases)")
    ap.add_argument("--skip-fit", action="store_true", help="case D without the default fitted-R identify")
    ap.add_argument("--out", default=str(HERE / "engines.json"))
    ap.add_argument("--device", default="cpu", help="also time the torch engine (and montecarlo) on this device")
    ap.add_argument("--cases", default="FABCDEG", help="which cases to run (letters), e.g. AC")
    ap.add_argument("--repeat", type=int, default=3, help="case A: runs of the compiled engine (first and best kept)")
    args = ap.parse_args()
    B, N = (50, 600) if args.quick else (1000, 3000)
    res = {"machine": machine(), "command": " ".join(sys.argv), "torch_threads": torch.get_num_threads()}
    C = set(args.cases.upper())
    if "F" in C:
        print("F: start-up of the compiled engine (fresh process)", flush=True)
        res["startup"] = startup()
    if "A" in C:
        print(f"A: TEA alone, {B} × {N}", flush=True)
        res["batch"] = engines_case(B, N, args.repeat, 2, args.device)
    if "B" in C:
        print(f"B: one realisation × {N}", flush=True)
        res["single"] = engines_case(1, N, 3, 1, args.device)
    if "C" in C:
        print("C: torchtea montecarlo end to end", flush=True)
        res["montecarlo"] = montecarlo_case(B, N)
        if args.device != "cpu":
            res["montecarlo_device"] = montecarlo_case(B, N, args.device)
        print(f"  {res['montecarlo']['wall_s']} s wall, study {res['montecarlo']['study_s']} s", flush=True)
    if "D" in C:
        print("D: torchtea identify --samples all --memory soe", flush=True)
        samples = "3000" if args.quick else "all"
        res["identify"] = [identify_case("measured", samples)] + ([] if args.skip_fit else [identify_case("fitted", samples)])
        for r in res["identify"]:
            print(f"  {r['command']}: {r['wall_s']} s wall ({r['reported_s']} s reported)", flush=True)
    if "E" in C:
        print("E: time per step against N (interleaved)", flush=True)
        res["step_times"] = step_times([300, 1000, 3000] if args.quick else [1000, 3000, 10000, 30000], 10)
    if "G" in C:
        print("G: exact likelihood", flush=True)
        res["exact_likelihood"] = exact_likelihood(100_000 if args.quick else 1_000_000)
    write_json(Path(args.out), res)
    print_table(res)
    print(f"wrote {args.out}")


def print_table(r):
    print("\n| case | memory | numba (best) | numba (first run) | torch | scalar reference | numba vs torch | numba vs reference | max |Δ| |")
    print("|---|---|---|---|---|---|---|---|---|")
    for row in r.get("batch", []) + r.get("single", []):
        print(f"| {row['realisations']} × {row['samples']} | {row['memory']} | {row['numba_s']} s | {row['numba_first_s']} s | {row['torch_s']} s | "
              f"{row['reference_s']} s | {row['numba_vs_torch']}× | {row['numba_vs_reference']}× | "
              f"{row['max_abs_diff_numba_torch']:.1e} |")
    for row in r.get("batch", []) + r.get("single", []):
        if "device_s" in row:
            print(f"{row['realisations']} × {row['samples']} {row['memory']} on {row['device']}: {row['device_s']} s "
                  f"({row['device_vs_numba']}× the compiled engine's speed; max|Δ| {row['max_abs_diff_device_numba']:.1e})")
    for key in ("montecarlo", "montecarlo_device"):
        if key in r:
            mc = r[key]
            print(f"\n{mc['command']}: {mc['wall_s']} s wall (study {mc['study_s']} s)")
    for row in r.get("identify", []):
        print(f"{row['command']}: {row['wall_s']} s wall ({row['reported_s']} s reported)")
    print("\n| memory | N | µs per step and realisation (3 interleaved rounds) |\n|---|---|---|")
    for row in r.get("step_times", []):
        print(f"| {row['memory']} | {row['samples']} | {', '.join(map(str, row['us_per_step_realisation']))} |")
    if "startup" not in r or "exact_likelihood" not in r:
        return
    s = r["startup"]
    print(f"\nstart-up: import {s['import_s']} s, first call (kernel from numba's cache) {s['first_call_s']} s")
    e = r["exact_likelihood"]
    print(f"exact likelihood of {e['samples']} samples: {e['first_s']} s (first, kernel designed), {e['second_s']} s")


if __name__ == "__main__":
    main()

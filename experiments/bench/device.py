"""Benchmark of the torch engine on an accelerator (issue 13), with the CPU baselines in the same run.

    python experiments/bench/device.py --device cuda      # ≈ 4 min on one H100; --quick for a smoke run

Cases:
A. TEA alone, MEMS setting (as engines.py's case A), ``soe``, the torch engine on the device for 10³, 10⁴ and 10⁵
   realisations × 3000 samples (one run each after a warm-up on 8 realisations), against, in the same run, the
   compiled engine on this machine's CPU (10³ realisations, its cores in parallel) and the scalar NumPy reference
   loop (2 realisations, scaled). max |Δα̂| and |Δx̂| between the device and the compiled CPU engine on the same
   10³ realisations.
B. The ``soe`` truth simulation of 10⁵ × 3000 on the device, against the compiled CPU simulation of 10⁴ (scaled).
C. ``torchtea montecarlo`` end to end (fresh process) with 10⁴ realisations on the device and on the CPU.

Writes JSON (``--out``) and prints a table; records the device's name.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))
from experiments.bench.engines import MEMS, TRUTH_FLAGS, params_for  # noqa: E402
from experiments.common import machine, write_json  # noqa: E402
from tests.reference_tea import settings_from_config, tea_reference  # noqa: E402
from torchtea import ConstantOrder, Structure, get_preset, make_params, run_tea, simulate  # noqa: E402


def sync(dev):
    if dev.type == "cuda":
        torch.cuda.synchronize(dev)


def truths(B, N, dev, seed=0):
    g = torch.Generator(device=dev).manual_seed(seed)
    return simulate(Structure(), n_steps=N, h=MEMS["h"], order=ConstantOrder(MEMS["order"]), parameters=[MEMS["param"]],
                    process_noise=MEMS["q"], measurement_noise=MEMS["r"], batch_shape=(B,), generator=g, memory="soe",
                    device=dev)


def timed(fn, dev):
    sync(dev)
    t0 = time.perf_counter()
    out = fn()
    sync(dev)
    return out, time.perf_counter() - t0


def montecarlo(R, N, device):
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        proc = subprocess.run([sys.executable, "-m", "torchtea.cli", "montecarlo", "--preset", "paper-mems-x",
                               "--realisations", str(R), "--n", str(N), *TRUTH_FLAGS, "--memory", "soe", "--seed", "1",
                               "--logdir", f"{tmp}/mc", "--json", "--device", device], capture_output=True, text=True)
        wall = time.perf_counter() - t0
        if proc.returncode != 0:
            raise RuntimeError(proc.stderr[-2000:])
        summary = json.loads((Path(tmp) / "mc" / "summary.json").read_text())
    return {"device": device, "realisations": R, "samples": N, "wall_s": round(wall, 2), "study_s": summary["seconds"],
            "order_rmse": summary["order"]["rmse"]}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--out", default=str(HERE / "device.json"))
    args = ap.parse_args()
    dev = torch.device(args.device)
    N = 300 if args.quick else 3000
    sizes = [100, 1000] if args.quick else [1000, 10_000, 100_000]
    res = {"machine": machine(), "command": " ".join(sys.argv), "device": str(dev),
           "device_name": torch.cuda.get_device_name(dev) if dev.type == "cuda" else "cpu",
           "cpu_threads": torch.get_num_threads()}
    p_dev, p_cpu = params_for("soe"), params_for("soe")
    p_dev = make_params(p_dev.config, Structure(), device=dev)
    run_tea(truths(8, N, dev).y, h=MEMS["h"], params=p_dev)  # warm-up: kernels, the soe kernel's design
    rows = []
    for B in sizes:
        sim = truths(B, N, dev, seed=B)
        out, t = timed(lambda: run_tea(sim.y, h=MEMS["h"], params=p_dev), dev)
        row = {"realisations": B, "samples": N, "device_s": round(t, 2), "ms_per_step": round(1e3 * t / N, 2),
               "diverged": int(out.diverged.sum())}
        if B == sizes[0]:  # the CPU baselines on the same realisations
            y = sim.y.cpu()
            run_tea(y[:1], h=MEMS["h"], params=p_cpu)
            ref, t_cpu = timed(lambda: run_tea(y, h=MEMS["h"], params=p_cpu), torch.device("cpu"))
            s = settings_from_config(get_preset("paper-mems-x"))
            _, t_loop = timed(lambda: [tea_reference(y[i, :, 0].numpy(), None, MEMS["h"], s) for i in range(2)],
                              torch.device("cpu"))
            row.update({"cpu_compiled_s": round(t_cpu, 3), "reference_loop_s_scaled": round(t_loop / 2 * B, 1),
                        "max_abs_diff_alpha": float((out.alpha.cpu() - ref.alpha).abs().max()),
                        "max_abs_diff_x": float((out.x.cpu() - ref.x).abs().max()),
                        "realisations_differing_1e-6": int(((out.alpha.cpu() - ref.alpha).abs().amax(dim=(1, 2)) > 1e-6).sum())})
        rows.append(row)
        print(row, flush=True)
        sim = out = None  # free the device memory before the next size
        if dev.type == "cuda":
            torch.cuda.empty_cache()
    res["tea"] = rows
    Bs = sizes[-1]
    _, t_sim = timed(lambda: truths(Bs, N, dev, seed=1), dev)
    Bc = max(1, Bs // 10)
    _, t_sim_cpu = timed(lambda: truths(Bc, N, torch.device("cpu"), seed=1), torch.device("cpu"))
    res["simulation"] = {"realisations": Bs, "samples": N, "device_s": round(t_sim, 2),
                         "cpu_compiled_s_scaled": round(t_sim_cpu * Bs / Bc, 2)}
    print(res["simulation"], flush=True)
    R = 200 if args.quick else 10_000
    res["montecarlo"] = [montecarlo(R, N, str(dev)), montecarlo(R, N, "cpu")]
    for r in res["montecarlo"]:
        print(r, flush=True)
    write_json(Path(args.out), res)
    print(f"\ndevice: {res['device_name']}; CPU threads {res['cpu_threads']}")
    print("| realisations × samples | torch engine on the device | ms per step | compiled engine, CPU | reference loop (scaled) |")
    print("|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['realisations']} × {r['samples']} | {r['device_s']} s | {r['ms_per_step']} | "
              f"{r.get('cpu_compiled_s', '')} | {r.get('reference_loop_s_scaled', '')} |")
    print(f"simulation {Bs} × {N}: device {res['simulation']['device_s']} s, CPU compiled (scaled) "
          f"{res['simulation']['cpu_compiled_s_scaled']} s")
    for r in res["montecarlo"]:
        print(f"montecarlo {r['realisations']} × {r['samples']} on {r['device']}: {r['wall_s']} s wall (study {r['study_s']} s)")


if __name__ == "__main__":
    main()

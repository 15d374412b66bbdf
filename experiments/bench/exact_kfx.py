"""Benchmark of ``kfx_filter = "exact"`` (torchtea.noise.tea_exact) next to the paper's KFx, side by side in one run.

    python experiments/bench/exact_kfx.py          # ≈ 8 min on 2 cores

1. **A study's batch**: the ``fractional+white+random-walk`` data of experiments/tea_models (order 0.4, pole −2,
   walk σ 0.05; 32 realisations × 6000 steps, seed 5), the grown model's view under the ``constant`` settings, KFw
   free: the TEA (torch engine: a view of two states) against the exact-filter KFx, alternating, best of three.
2. **The bundled recording**: ``identify`` on its six channels (accelerometer and gyroscope axes, 44 930 samples at
   100 Hz) with the same model, fitted once outside the timing (the fits passed to both), and the same settings; paper against exact,
   best of two.

α̂ over the last third is printed beside each time (the two KFx differ by design: the bias they differ by is the
point of experiments/tea_models/fixed_point.py). Prints a table and writes ``experiments/bench/exact_kfx.json``.
"""
from __future__ import annotations

import sys
import time
from dataclasses import replace
from pathlib import Path

import torch

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))
sys.path.insert(0, str(HERE.parents[1] / "experiments" / "tea_models"))
from grown_model import FW, H, tea_config  # noqa: E402

from experiments.common import machine, write_json  # noqa: E402
from torchtea.core.stats import last_third  # noqa: E402
from torchtea.engines.tea import make_params, run_tea  # noqa: E402
from torchtea.noise import simulate_model  # noqa: E402
from torchtea.noise.tea import tea_view  # noqa: E402
from torchtea.noise.tea_exact import run_tea_exact  # noqa: E402

MODEL = "fractional+white+random-walk"
CONSTANT = {"R": "innovation", "Q0": 1e-5}


def best(fns: dict, repeats: int) -> dict:
    """``{name: (best seconds, last result)}``, the functions alternating round by round."""
    out = {k: (float("inf"), None) for k in fns}
    for _ in range(repeats):
        for k, f in fns.items():
            t0 = time.perf_counter()
            r = f()
            out[k] = (min(out[k][0], time.perf_counter() - t0), r)
    return out


def batch_case() -> dict:
    truth = dict(FW, **{"random-walk.sigma": 0.05})
    y = simulate_model(MODEL, truth, n_steps=6000, h=H, realisations=32, generator=torch.Generator().manual_seed(5))[0]
    y = y - y.mean(-1, keepdim=True)
    v = tea_view(MODEL, truth, H)
    paper = tea_config(v, "constant", False)
    exact = tea_config(v, "exact-kfx", False)
    sl = last_third(6000)
    fns = {"paper": lambda: run_tea(y.unsqueeze(-1), h=H, params=make_params(paper, v.structure), structure=v.structure),
           "exact": lambda: run_tea_exact(replace(v, config=exact), y, h=H)}
    res = best(fns, 3)
    return {"case": "32 × 6000, fractional+white+random-walk, constant settings, KFw free",
            **{f"{k}_s": round(t, 3) for k, (t, _) in res.items()},
            **{f"{k}_alpha_bias": round(float(r.alpha[:, sl, 0].mean() - FW["fractional.order"]), 4)
               for k, (_, r) in res.items()}}


def recording_case() -> dict:
    from torchtea.fitting import fit_series
    from torchtea.identification import identify
    from torchtea.sensors.io import bundled_recording, read_recording
    from torchtea.sensors.measurements import prepare

    rec = read_recording(bundled_recording())
    m = prepare(rec)
    y = [c.values - c.values.mean() for c in m.channels]
    fits = fit_series(MODEL, y, rec.h, method="exact")
    over = {"kfo": CONSTANT, "kfw": CONSTANT}
    fns = {"paper": lambda: identify(m, model=MODEL, overrides=over, fits=fits),
           "exact": lambda: identify(m, model=MODEL, overrides=dict(over, kfx_filter="exact"), fits=fits)}
    res = best(fns, 2)
    sl = last_third(m.samples)
    return {"case": f"identify, bundled recording, {len(m.channels)} channels × {m.samples}, {MODEL} (fits given), "
                    "constant settings",
            **{f"{k}_s": round(t, 3) for k, (t, _) in res.items()},
            "channels": [c.label for c in m.channels],
            **{f"{k}_alpha_last_third": [round(float(a), 4) for a in r.result.alpha[:, sl, 0].mean(-1)]
               for k, (_, r) in res.items()}}


def main():
    rows = [batch_case()]
    print(rows[-1], flush=True)
    rows.append(recording_case())
    print(rows[-1], flush=True)
    print("\n| case | paper KFx [s] | exact KFx [s] | exact / paper |\n|---|---|---|---|")
    for r in rows:
        print(f"| {r['case']} | {r['paper_s']:.2f} | {r['exact_s']:.2f} | {r['exact_s'] / r['paper_s']:.2f} |")
    write_json(HERE / "exact_kfx.json", {"machine": machine(), "rows": rows})


if __name__ == "__main__":
    main()

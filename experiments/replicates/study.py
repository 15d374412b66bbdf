"""Recordings fitted together (``torchtea fit A B … --together``): are the tests calibrated and how much do they see?

    python experiments/replicates/study.py [--seeds 100] [--cases agree,white,bias,change,still]

Cases, each over seeded simulated recordings of white+random-walk at 100 Hz (the simulator's typical MEMS values:
white r = 1e-3 units², random-walk σ = 2e-3 units/√s):

* ``agree`` — two recordings of one law, 30 min each: how often the verdict is "agree" at the family level 0.05
  (target ≥ 95 %), and the pooled random-walk σ's interval against one recording's (relative widths, log scale:
  target about 1/√2);
* ``white`` — the second recording's white noise density 20 % above the first's (r × 1.44): how often the verdict
  names white.r (target ≥ 90 %);
* ``bias`` — five recordings of 5 min, each with its own turn-on bias drawn from N(0, 0.01²): how often the turn-on
  repeatability's 95 % interval holds 0.01 (target ≥ 90 %);
* ``change`` — one recording of 10 min whose white variance doubles at a time t₀ drawn uniformly from 20–80 % of
  it, checked in windows of 30 s (``check --windows 30``'s analysis): how often a change of white.r is found within
  5 % of the record (30 s) of t₀ (target ≥ 90 %);
* ``still`` — the same recordings without the change: how often no change is claimed (target ≥ 95 %).

Writes ``results.json`` (every seed's numbers, written after each, so a stopped run keeps them and a rerun goes on
from them) and ``results.md`` (the table) beside this file.
"""
from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np
import torch

from torchtea.fitting.together import fit_together
from torchtea.noise import default_values, simulate_model

HERE = Path(__file__).parent
H = 0.01
MODEL = "white+random-walk"
LAW = default_values(MODEL, H)
BIAS_SPREAD = 0.01


def _series(n: int, seed: int, law: dict) -> np.ndarray:
    return simulate_model(MODEL, law, n_steps=n, h=H, generator=torch.Generator().manual_seed(seed))[0, 0].numpy()


def _width(ci) -> float:
    return math.log(ci[1] / ci[0]) if ci is not None and ci[0] > 0 else math.nan


def run_case(case: str, seed: int) -> dict:
    t0 = time.perf_counter()
    if case == "agree":
        ys = [_series(180_000, 1000 * seed + k, LAW) for k in range(2)]
        tg = fit_together(MODEL, ys, H)
        single = [_width(f.ci95["random-walk.sigma"]) for f in tg.separate]
        out = {"agree": not tg.differs, "differs": tg.differs,
               "width_ratio": _width(tg.ci95["random-walk.sigma"]) / float(np.mean(single)),
               "p_values": {p["name"]: p["p_value"] for p in tg.parameters}}
    elif case == "white":
        law2 = dict(LAW, **{"white.r": LAW["white.r"] * 1.2 ** 2})
        ys = [_series(180_000, 1000 * seed, LAW), _series(180_000, 1000 * seed + 1, law2)]
        tg = fit_together(MODEL, ys, H)
        out = {"white_named": "white.r" in tg.differs, "differs": tg.differs}
    elif case == "bias":
        rng = np.random.default_rng(seed)
        biases = rng.normal(0.0, BIAS_SPREAD, 5)
        ys = [_series(30_000, 1000 * seed + k, LAW) + b for k, b in enumerate(biases)]
        tg = fit_together(MODEL, ys, H)
        lo, hi = tg.bias["ci95"]
        out = {"covered": bool(lo <= BIAS_SPREAD <= hi), "spread": tg.bias["spread"], "ci95": [lo, hi],
               "sample_sd": float(np.std(biases, ddof=1))}
    elif case in ("change", "still"):
        from torchtea.fitting.windows import noise_over_time

        n = 60_000
        y = _series(n, 1000 * seed, LAW)
        t_change = float(np.random.default_rng(seed).uniform(0.2, 0.8)) * n * H
        if case == "change":
            k = int(round(t_change / H))
            y[k:] += np.random.default_rng(10_000 + seed).standard_normal(n - k) * math.sqrt(LAW["white.r"])
        d = noise_over_time(MODEL, y, H, 30.0)
        found = [c for c in d["changes"] if "white.r" in c["parameters"]]
        out = {"claimed": [[c["at_s"], c["parameters"]] for c in d["changes"]],
               "t0": t_change if case == "change" else None,
               "found": bool(found and abs(found[0]["at_s"] - t_change) <= 0.05 * n * H) if case == "change" else None,
               "p_values": {c["name"]: c["p_value"] for c in d["constancy"]}}
    else:
        raise ValueError(case)
    out.update(seed=seed, seconds=time.perf_counter() - t0)
    return out


def table(results: dict) -> str:
    rows = ["| case | seeds | result | target |", "|---|---|---|---|"]
    if results.get("agree"):
        r = results["agree"]
        rate = np.mean([x["agree"] for x in r])
        ratio = np.nanmedian([x["width_ratio"] for x in r])
        rows.append(f"| two recordings of one law, 30 min | {len(r)} | \"agree\" in {rate:.1%}; pooled K interval "
                    f"{ratio:.2f} × one recording's (median) | ≥ 95 %; about 0.71 |")
    if results.get("white"):
        r = results["white"]
        rate = np.mean([x["white_named"] for x in r])
        rows.append(f"| white density 20 % apart, 30 min each | {len(r)} | \"differ in white.r\" in {rate:.1%} | "
                    "≥ 90 % |")
    if results.get("bias"):
        r = results["bias"]
        rate = np.mean([x["covered"] for x in r])
        rows.append(f"| five recordings, turn-on biases N(0, 0.01²), 5 min each | {len(r)} | spread 0.01 inside its "
                    f"95 % interval in {rate:.1%} | ≥ 90 % |")
    if results.get("change"):
        r = results["change"]
        rate = np.mean([x["found"] for x in r])
        rows.append(f"| white variance doubles at t₀ (20–80 % of 10 min), windows of 30 s | {len(r)} | change of "
                    f"white.r found within 30 s of t₀ in {rate:.1%} | ≥ 90 % |")
    if results.get("still"):
        r = results["still"]
        rate = np.mean([not x["claimed"] for x in r])
        rows.append(f"| the same records without the change | {len(r)} | no change claimed in {rate:.1%} | ≥ 95 % |")
    return "\n".join(rows)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=100)
    ap.add_argument("--cases", default="agree,white,bias,change,still")
    args = ap.parse_args()
    path = HERE / "results.json"
    results = json.loads(path.read_text()) if path.exists() else {}
    for case in args.cases.split(","):
        done = {x["seed"] for x in results.get(case, [])}
        for seed in range(1, args.seeds + 1):
            if seed in done:
                continue
            results.setdefault(case, []).append(run_case(case, seed))
            path.write_text(json.dumps(results, indent=1))
            last = results[case][-1]
            print(f"{case} seed {seed}: {json.dumps({k: v for k, v in last.items() if k != 'seed'})}", flush=True)
    (HERE / "results.md").write_text(table(results) + "\n")
    print(table(results))


if __name__ == "__main__":
    main()

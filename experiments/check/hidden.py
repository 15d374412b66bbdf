"""Hidden-effect study of ``check`` (issue 12): does it name the effect that is in the data, and nothing on
clean data?

    python experiments/check/hidden.py                      # all cases (resumes: one JSON per case)
    python experiments/check/hidden.py --effects sinusoid --seeds 5
    python experiments/check/hidden.py --tables             # only the tables from what is saved

Data: MEMS-like base noise — ``fractional+white`` with :func:`torchtea.noise.default_values` (order 0.3, pole
at 40 % of its stability limit, drive q = r/h^{2α}, white r = 10⁻³ (m/s²)²), h = 0.01 s, 30 000 samples — and a
temperature that warms up by 3 °C (τ = 60 s) plus a 0.2 °C wander, in every case; plus one hidden effect at
the strength in :data:`STRENGTH` (or none). Each case is checked with the default model ``fractional+white``,
the temperature given, no intervals. Recorded per case: the top suggestion, whether the model was called
adequate, the failed diagnostics before and after adding the top suggestion, the metrics, the fitted
parameters of the effect against the truth, and the seconds.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from torchtea.checking import check
from torchtea.noise import default_values, parse_model, simulate_model, temperature_profile

HERE = Path(__file__).resolve().parent
H, N = 0.01, 30_000
BASE = "fractional+white"
#: The hidden effects and their strengths (parameters not named here are default_values').
STRENGTH = {
    "none": {},
    "random-walk": {"random-walk.sigma": 3e-3},
    "sinusoid": {"sinusoid.frequency_hz": 3.37, "sinusoid.amplitude": 4e-3},
    "temperature-bias": {"temperature-bias.bias_per_degC": 0.01},
    "temperature-order": {"temperature-order.order_per_degC": 0.04},
    "low-pass": {"low-pass.cutoff_hz": 8.0},
}
SEEDS = {"none": 100}
DEFAULT_SEEDS = 50


def case(effect: str, seed: int):
    spec = BASE if effect == "none" else ("fractional+low-pass+white" if effect == "low-pass" else f"{BASE}+{effect}")
    model = parse_model(spec)
    gen = torch.Generator().manual_seed(10_000 * (list(STRENGTH).index(effect) + 1) + seed)
    T = temperature_profile(N, H, generator=gen)
    values = default_values(model, H, T)
    values.update(STRENGTH[effect])
    y = simulate_model(model, values, n_steps=N, h=H, inputs={"temperature": T}, generator=gen)[0, 0].numpy()
    return y, T.numpy(), values


def run_case(effect: str, seed: int) -> dict:
    y, T, truth = case(effect, seed)
    t0 = time.perf_counter()
    r = check(y, H, model=BASE, inputs={"temperature": T}, intervals=False)
    out = {"effect": effect, "seed": seed, "truth": truth, "adequate": r.adequate, "failed": r.failed,
           "metrics": r.metrics, "screens": r.screens, "timings": r.timings, "seconds": time.perf_counter() - t0,
           "suggestions": [s.as_dict() for s in r.suggestions]}
    out["top"] = r.suggestions[0].effect if r.suggestions else None
    return out


def tables(d: Path) -> str:
    rows = [json.loads(p.read_text()) for p in sorted(d.glob("*.json"))]
    if not rows:
        return "nothing saved yet"
    effects = [e for e in STRENGTH if any(r["effect"] == e for r in rows)]
    tops = sorted({str(r["top"]) for r in rows} | set(effects[1:]) | {"None"})
    lines = ["| hidden effect | seeds | " + " | ".join(f"top: {t}" for t in tops) + " | right first | adequate after |",
             "|---|---|" + "---|" * len(tops) + "---|---|"]
    for e in effects:
        rs = [r for r in rows if r["effect"] == e]
        counts = [sum(str(r["top"]) == t for r in rs) for t in tops]
        right = sum(r["top"] == (None if e == "none" else e) for r in rs)
        after = [not r["suggestions"][0]["after"]["failed"] for r in rs if r["suggestions"]]
        lines.append(f"| {e} | {len(rs)} | " + " | ".join(map(str, counts)) +
                     f" | {right}/{len(rs)} | {sum(after)}/{len(after)} |")
    secs = [r["seconds"] for r in rows]
    lines += ["", f"seconds per check: median {np.median(secs):.1f}, max {np.max(secs):.1f} ({len(secs)} checks)"]
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--effects", default=",".join(STRENGTH))
    ap.add_argument("--seeds", type=int, help="seeds per effect (default 50, 100 for none)")
    ap.add_argument("--dir", default=str(HERE / "hidden"))
    ap.add_argument("--tables", action="store_true")
    args = ap.parse_args()
    d = Path(args.dir)
    d.mkdir(parents=True, exist_ok=True)
    if not args.tables:
        effects = args.effects.split(",")
        n = {e: args.seeds or SEEDS.get(e, DEFAULT_SEEDS) for e in effects}
        for seed in range(max(n.values())):  # every effect grows together
            for e in effects:
                path = d / f"{e}_{seed:03d}.json"
                if seed >= n[e] or path.exists():
                    continue
                res = run_case(e, seed)
                path.write_text(json.dumps(res))
                print(f"{e} seed {seed}: top {res['top']} ({res['seconds']:.0f} s)", flush=True)
    text = tables(d)
    (HERE / "hidden.md").write_text(text + "\n")
    print(text)


if __name__ == "__main__":
    main()

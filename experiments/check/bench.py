"""Benchmark of ``check``: one 30 000-sample axis (h = 0.01 s), every candidate screened (issue 12's target:
≤ 60 s on the 2-core machine). Two cases: clean ``fractional+white`` data (nothing to refit) and data with a
hidden 3.37 Hz line (the base model misspecified, one effect refitted); with and without the intervals. A third,
without intervals: the hidden-effect study's random-walk seed 7, where the model's first fit is a local maximum
and the check runs again from a candidate's better point (the restart, 23 of the study's 50 random-walk seeds).

    python experiments/check/bench.py        # prints a table, writes experiments/check/bench.json
"""
from __future__ import annotations

import json
import platform
from pathlib import Path

import torch

from torchtea.checking import check
from torchtea.noise import default_values, parse_model, simulate_model, temperature_profile

HERE = Path(__file__).resolve().parent
H, N = 0.01, 30_000


def series(spec: str):
    m = parse_model(spec)
    gen = torch.Generator().manual_seed(1)
    T = temperature_profile(N, H, generator=gen)
    y = simulate_model(m, default_values(m, H, T), n_steps=N, h=H, inputs={"temperature": T}, generator=gen)[0, 0]
    return y.numpy(), T.numpy()


def main():
    check(*series("fractional+white")[:1], H, intervals=False)  # warm-up: numba's compile is not timed
    rows = []
    for name, spec in (("clean", "fractional+white"), ("hidden line", "fractional+white+sinusoid")):
        y, T = series(spec)
        for intervals in (False, True):
            r = check(y, H, inputs={"temperature": T}, intervals=intervals)
            rows.append({"case": name, "intervals": intervals, "seconds": r.seconds, "timings": r.timings,
                         "top": r.suggestions[0].effect if r.suggestions else None, "adequate": r.adequate})
    from torchtea.studies.hidden import hidden_case

    y, T, _ = hidden_case("random-walk", 7)
    r = check(y, H, inputs={"temperature": T}, intervals=False)
    rows.append({"case": "random walk, restart", "intervals": False, "seconds": r.seconds, "timings": r.timings,
                 "top": r.suggestions[0].effect if r.suggestions else None, "adequate": r.adequate,
                 "restarted": any("local maximum" in n for n in r.notes)})
    print("| case | intervals | seconds | fit | diagnostics | screens | refits | intervals | top suggestion |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        t = r["timings"]
        print(f"| {r['case']} | {r['intervals']} | {r['seconds']:.1f} | {t['fit']:.1f} | {t['diagnostics']:.1f} | "
              f"{t['screen']:.1f} | {t['refits']:.1f} | {t['intervals']:.1f} | {r['top']} |")
    (HERE / "bench.json").write_text(json.dumps({"machine": platform.processor() or platform.machine(),
                                                  "threads": torch.get_num_threads(), "n": N, "h": H,
                                                  "target_s": 60, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()

"""Benchmarks of the noise-model engines (issue 11's targets), side by side in one run.

    python experiments/fit/bench.py            # prints a table, writes experiments/fit/bench.json

Rows: Whittle log-likelihood of 10⁶ samples (target ≤ 1 s); exact log-likelihood of 10⁶ samples by the
compiled filter (target ≤ 60 s), and the torch reference filter on 10⁴ samples (scaled ×100 in its label);
a whole ``fit`` of 3 axes × 30 000 samples, exact method (target ≤ 30 s; and with the order's profile)
and Whittle method (with the profile, its order interval); the 99-replicate fractional test of those 3 axes. Each timing is the best of
``--repeat`` runs after one warm-up (numba compile excluded); the single-run rows (exact 10⁶, reference,
test) are one timed run after the warm-up.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import torch

from torchtea.fitting import fit_series
from torchtea.fitting.presence import fractional_test
from torchtea.likelihood import kalman_filter, loglik_fast, periodogram, whittle_loglik
from torchtea.noise import parse_model, simulate_model

H = 0.01
TRUTH = {"fractional.order": 0.3, "fractional.pole": -2.0, "fractional.q": 0.02, "white.r": 1e-3}


def best(fn, repeat):
    fn()
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--out", default=str(Path(__file__).with_name("bench.json")))
    args = ap.parse_args()
    m = parse_model("fractional+white")
    rows = []
    N = 1_000_000
    y = simulate_model(m, TRUTH, n_steps=N, h=H, generator=torch.Generator().manual_seed(0))[0, 0]

    def whittle():
        omega, I = periodogram(y - y.mean())
        return whittle_loglik(m.spectrum(TRUTH, omega, H), I)

    rows.append(("Whittle log-likelihood, N = 10⁶", best(whittle, args.repeat), 1.0))
    ss = m.state_space(TRUTH, H, N, "soe")
    rows.append((f"exact log-likelihood, N = 10⁶, compiled, soe:1e-8 ({ss.n} states)",
                 best(lambda: loglik_fast(ss, y), 1), 60.0))
    n_ref = 10_000
    ss_ref = m.state_space(TRUTH, H, n_ref, "soe")
    t_ref = best(lambda: kalman_filter(ss_ref, y[:n_ref]), 1)
    rows.append((f"exact log-likelihood, torch reference filter, N = 10⁴ (×100 = {t_ref * 100:.0f} s for 10⁶)", t_ref, None))
    y3 = simulate_model(m, TRUTH, n_steps=30000, h=H, realisations=3, generator=torch.Generator().manual_seed(1))[0]
    series = [y3[i].numpy() + 9.81 for i in range(3)]
    rows.append(("fit, 3 axes × 30 000, exact (Whittle start; as `torchtea fit`)",
                 best(lambda: fit_series(m, series, H, method="exact"), args.repeat), 30.0))
    rows.append(("fit, 3 axes × 30 000, exact, with the order's Whittle profile (`fit --profile`)",
                 best(lambda: fit_series(m, series, H, method="exact", profile=True), args.repeat), None))
    rows.append(("fit, 3 axes × 30 000, Whittle (with profile)",
                 best(lambda: fit_series(m, series, H, method="whittle"), args.repeat), None))
    rows.append(("fractional test, 99 bootstrap replicates (shared by the 3 axes: white null)",
                 best(lambda: fractional_test(m, series, H, n_boot=99), 1), None))
    print(f"{'benchmark':80s} {'seconds':>9s} {'target':>7s}")
    for name, t, target in rows:
        print(f"{name:80s} {t:9.2f} {'' if target is None else f'≤ {target:g}':>7s}")
    doc = {"machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "torch": torch.__version__,
                       "threads": torch.get_num_threads()},
           "rows": [{"name": n, "seconds": t, "target_s": g} for n, t, g in rows]}
    Path(args.out).write_text(json.dumps(doc, indent=1))


if __name__ == "__main__":
    main()

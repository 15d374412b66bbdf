"""Issue 32's refactors against the code before them, side by side in one run: the same numbers and the same speed.

    python experiments/bench/issue32.py [--old ad7220d] [--repeats 3]

The old tree is checked out from git (``git worktree``, removed afterwards); each case runs in a child process whose
``sys.path`` starts with one tree, alternating old/new ``--repeats`` times (best time kept). Cases, each what a
refactor touched:

* ``compiled_tea`` — the compiled TEA (named arguments, the memory plan): paper-mems-x settings, soe memory,
  200 realisations × 3000 steps of fractional+white (noise simulator, seed 1);
* ``compiled_tea_branches`` — the same with the kernel's other branches: window:40 memory, ``paper-gain``,
  ``constant-truth``, KFo's R from KFx's innovation covariance;
* ``identify_exact`` — ``identify`` with ``kfx_filter = "exact"`` on the bundled recording's six channels (44 930
  samples, fractional+white+random-walk fitted before the timing, the ``constant`` settings);
* ``torch_tea`` — the torch engine (shared types moved, the memory plan): the same settings and data, 20 realisations;
* ``paper_example1`` — the paper reproduction's setting: Example 1 (known input, exact memory, the compiled engine),
  20 realisations × 6000 steps;
* ``simulate_paper`` — the paper-model simulator (the memory plan): Example 1, 200 realisations, soe;
* ``exact_loglik`` — the exact likelihood (moved to fitting/exact.py): fractional+white+random-walk on 30 000 samples,
  16 parameter sets;
* ``check`` — the screens (given ctx/Innovations instead of importing): ``check`` of 6000 samples with a hidden
  sinusoid, every candidate.

Each case prints a digest of its numbers (sums of the estimates, log-likelihoods, the check's ranking and
statistics) that must be equal between the trees; writes experiments/bench/issue32.json.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]

CHILD = r'''
import json, sys, time
import numpy as np
import torch
torch.set_num_threads(1)
case = sys.argv[1]
from torchtea.noise import simulate_model
H = 0.01
FW = {"fractional.order": 0.4, "fractional.pole": -2.0, "fractional.q": 0.02, "white.r": 1e-3}

def tea(B, engine, branches=False):
    from dataclasses import replace
    from torchtea.core.memory import parse_memory
    from torchtea.engines.presets import get_preset
    from torchtea.engines.tea import make_params, run_tea
    from torchtea.engines.structure import Structure
    y = simulate_model("fractional+white", FW, n_steps=3000, h=H, realisations=B,
                       generator=torch.Generator().manual_seed(1))[0]
    cfg = get_preset("paper-mems-x")
    cfg = replace(cfg, memory=replace(cfg.memory, kind="soe"))
    if branches:  # the kernel's other branches: window memory, the paper's gain, constant truth, KFo's R from KFx
        cfg = replace(cfg, memory=parse_memory("window:40"), kfx_uncertainty="paper-gain",
                      estimate_uncertainty="constant-truth", kfo=replace(cfg.kfo, R="innovation"))
    p = make_params(cfg, Structure())
    run_tea(y[:2].unsqueeze(-1), h=H, params=p, engine=engine)  # compile / warm up
    t = time.perf_counter()
    r = run_tea(y.unsqueeze(-1), h=H, params=p, engine=engine)
    dt = time.perf_counter() - t
    return dt, {"alpha_sum": float(r.alpha[:, -1].sum()), "w_sum": float(r.w[:, -1].sum()),
                "nis_sum": float((r.innovation ** 2 / r.innovation_cov[..., 0]).sum())}

if case == "compiled_tea":
    dt, digest = tea(200, "numba")
elif case == "compiled_tea_branches":
    dt, digest = tea(200, "numba", branches=True)
elif case == "torch_tea":
    dt, digest = tea(20, "torch")
elif case == "paper_example1":
    from torchtea import SCENARIOS, Structure, gaussian_input, get_preset, make_params, run_tea, simulate
    sc = SCENARIOS["paper-example1"]
    g = torch.Generator().manual_seed(11)
    u = gaussian_input((20,), sc.n_steps, 1, sc.input_std, generator=g)
    s = simulate(Structure(), n_steps=sc.n_steps, h=sc.h, order=sc.order, parameters=[sc.param], process_noise=sc.q,
                 measurement_noise=sc.r, inputs=u, generator=torch.Generator().manual_seed(12))
    p = make_params(get_preset("paper-example1"), Structure())
    run_tea(s.y[:1, :100], h=sc.h, params=p, inputs=u[:1, :100])
    t = time.perf_counter()
    r = run_tea(s.y, h=sc.h, params=p, inputs=u)
    dt = time.perf_counter() - t
    digest = {"alpha_sum": float(r.alpha[:, -1].sum()), "w_sum": float(r.w[:, -1].sum()),
              "P_sum": float(r.P[:, -1].sum()), "x_sum": float(s.x.sum())}
elif case == "simulate_paper":
    from torchtea import SCENARIOS, Structure, gaussian_input, simulate
    sc = SCENARIOS["paper-example1"]
    g = torch.Generator().manual_seed(3)
    u = gaussian_input((200,), sc.n_steps, 1, sc.input_std, generator=g)
    simulate(Structure(), n_steps=200, h=sc.h, order=sc.order, parameters=[sc.param], process_noise=sc.q,
             measurement_noise=sc.r, inputs=u[:, :200], generator=torch.Generator().manual_seed(4), memory="soe")
    t = time.perf_counter()
    s = simulate(Structure(), n_steps=sc.n_steps, h=sc.h, order=sc.order, parameters=[sc.param], process_noise=sc.q,
                 measurement_noise=sc.r, inputs=u, generator=torch.Generator().manual_seed(4), memory="soe")
    dt = time.perf_counter() - t
    digest = {"x_sum": float(s.x.sum()), "y_sum": float(s.y.sum())}
elif case == "simulate_paper_exact":
    from torchtea import SCENARIOS, Structure, gaussian_input, simulate
    sc = SCENARIOS["paper-example2"]  # a linear order schedule
    g = torch.Generator().manual_seed(3)
    u = gaussian_input((20,), sc.n_steps, 1, sc.input_std, generator=g)
    t = time.perf_counter()
    s = simulate(Structure(), n_steps=sc.n_steps, h=sc.h, order=sc.order, parameters=[sc.param], process_noise=sc.q,
                 measurement_noise=sc.r, inputs=u, generator=torch.Generator().manual_seed(4))
    dt = time.perf_counter() - t
    digest = {"x_sum": float(s.x.sum()), "y_sum": float(s.y.sum()), "x_abs_sum": float(s.x.abs().sum())}
elif case == "simulate_model":
    spec = "fractional+white+random-walk"
    v = dict(FW, **{"random-walk.sigma": 0.01})
    simulate_model(spec, v, n_steps=200, h=H, realisations=4, generator=torch.Generator().manual_seed(5))
    t = time.perf_counter()
    y = simulate_model(spec, v, n_steps=3000, h=H, realisations=200, generator=torch.Generator().manual_seed(5))
    dt = time.perf_counter() - t
    digest = {"y_sum": float(y.sum()), "y_abs_sum": float(y.abs().sum())}
elif case == "montecarlo_paper":
    from torchtea.studies.montecarlo import build_study, run_range
    study, _ = build_study({"seed": 9, "realisations": 256, "estimator": {"preset": "paper-mems-x"},
                            "truth": {"n_steps": 3000, "h": 0.01, "order": "0.3", "param": -3.0, "q": 0.1, "r": 1e-3}})
    run_range(study, 0, 2)
    t = time.perf_counter()
    r = run_range(study, 0, 256)
    dt = time.perf_counter() - t
    digest = {"alpha_sum": float(r.final["alpha"].sum()), "w_sum": float(r.final["w"].sum()),
              "nees_sum": float(r.nees_sum.sum())}
elif case == "identify_exact":
    from torchtea.fitting import fit_series
    from torchtea.identification import identify
    from torchtea.sensors.io import bundled_recording, read_recording
    from torchtea.sensors.measurements import prepare
    spec = "fractional+white+random-walk"
    m = prepare(read_recording(bundled_recording()))
    fits = fit_series(spec, [c.values - c.values.mean() for c in m.channels], m.recording.h, method="exact")
    over = {"kfx_filter": "exact", "kfo": {"R": "innovation", "Q0": 1e-5}, "kfw": {"R": "innovation", "Q0": 1e-5}}
    t = time.perf_counter()
    ident = identify(m, model=spec, overrides=over, fits=fits)
    dt = time.perf_counter() - t
    r = ident.result
    digest = {"alpha_last_third": [float(a) for a in r.alpha[:, -(m.samples // 3):, 0].mean(-1)],
              "w_final": [float(w) for w in r.w[:, -1, 0]], "innovation_sum": float(r.innovation.abs().sum())}
elif case == "exact_loglik":
    from torchtea.fitting.mle import exact_loglik
    spec = "fractional+white+random-walk"
    v = dict(FW, **{"random-walk.sigma": 0.01})
    y = simulate_model(spec, v, n_steps=30000, h=H, generator=torch.Generator().manual_seed(2))[0, 0].numpy()
    batch = {k: [x * (1 + 0.01 * i) if k != "fractional.order" else x for i in range(16)] for k, x in v.items()}
    exact_loglik(spec, v, y[:500], H)
    t = time.perf_counter()
    ll = exact_loglik(spec, batch, y - y.mean(), H)
    dt = time.perf_counter() - t
    digest = {"loglik": [float(x) for x in ll]}
elif case == "check":
    from torchtea.checking import check
    v = dict(FW)
    y = simulate_model("fractional+white", v, n_steps=6000, h=H, generator=torch.Generator().manual_seed(7))[0, 0].numpy()
    y = y + 0.004 * np.sin(2 * np.pi * 7.3 * np.arange(6000) * H)
    t = time.perf_counter()
    r = check(y, H, intervals=False)
    dt = time.perf_counter() - t
    digest = {"adequate": r.adequate,
              "screens": [(s.effect, None if s.statistic is None else round(float(s.statistic), 9))
                          for s in r.screens],
              "suggestions": [(s.effect, round(float(s.gain), 9)) for s in r.suggestions]}
print(json.dumps({"seconds": dt, "digest": digest}))
'''

CASES = ("compiled_tea", "torch_tea", "paper_example1", "simulate_paper", "exact_loglik", "check")
#: the one simulator (the paper's simulator made a view of the model's): python experiments/bench/issue32.py --old
#: 30fb53f --cases simulate_paper_exact simulate_paper simulate_model montecarlo_paper --out experiments/bench/simulator.json
SIMULATOR_CASES = ("simulate_paper_exact", "simulate_paper", "simulate_model", "montecarlo_paper")
#: the compiled kernel as the torch step's twins: python experiments/bench/issue32.py --old 989a8d6 --cases
#: compiled_tea compiled_tea_branches paper_example1 montecarlo_paper --out experiments/bench/kernel_twins.json
KERNEL_CASES = ("compiled_tea_branches",)
#: identify's exact KFx, its channels as one batch: python experiments/bench/issue32.py --old da0789a --cases
#: identify_exact --repeats 2 --out experiments/bench/exact_batch.json
EXACT_CASES = ("identify_exact",)


def rel_diff(a, b) -> float:
    """The largest relative difference between the numbers of two digests (0.0 for equal ones)."""
    if isinstance(a, dict):
        return max((rel_diff(a[k], b[k]) for k in a), default=0.0)
    if isinstance(a, (list, tuple)):
        return max((rel_diff(x, y) for x, y in zip(a, b)), default=0.0)
    if isinstance(a, (int, float)) and not isinstance(a, bool):
        return abs(a - b) / max(abs(a), abs(b), 1e-300) if a != b else 0.0
    return 0.0 if a == b else float("inf")


def run(tree: Path, case: str) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree), NUMBA_NUM_THREADS="1", OMP_NUM_THREADS="1")
    out = subprocess.run([sys.executable, "-c", CHILD, case], env=env, capture_output=True, text=True, cwd=tree)
    if out.returncode:
        raise RuntimeError(f"{case} in {tree}: {out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--old", default="ad7220d", help="the commit before issue 32's refactors")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--cases", nargs="+", default=list(CASES), choices=CASES + SIMULATOR_CASES + KERNEL_CASES + EXACT_CASES)
    ap.add_argument("--out", default=str(HERE / "issue32.json"))
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="tt-old-"))
    old = tmp / "tree"
    subprocess.run(["git", "worktree", "add", "-q", "--detach", str(old), args.old], cwd=ROOT, check=True)
    rows = []
    try:
        for case in args.cases:
            best = {"old": None, "new": None}
            digests = {}
            for _ in range(args.repeats):
                for name, tree in (("old", old), ("new", ROOT)):
                    r = run(tree, case)
                    digests[name] = r["digest"]
                    best[name] = r["seconds"] if best[name] is None else min(best[name], r["seconds"])
            same = digests["old"] == digests["new"]
            rows.append({"case": case, "old_s": best["old"], "new_s": best["new"],
                         "new_over_old": best["new"] / best["old"], "same_numbers": same,
                         "max_relative_difference": rel_diff(digests["old"], digests["new"]),
                         "digest_old": digests["old"], "digest_new": digests["new"]})
            print(f"{case:15s} old {best['old']:8.3f} s  new {best['new']:8.3f} s  ratio {best['new'] / best['old']:.3f}"
                  f"  same numbers: {same} (largest relative difference {rows[-1]['max_relative_difference']:.1e})",
                  flush=True)
    finally:
        subprocess.run(["git", "worktree", "remove", "--force", str(old)], cwd=ROOT, check=False)
    meta = {"old": args.old, "new": subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT,
                                                    capture_output=True, text=True).stdout.strip(),
            "repeats": args.repeats, "threads": 1, "when": time.strftime("%Y-%m-%d %H:%M"),
            "meaning": "best of the repeats per tree, old and new alternating; same_numbers: the digests equal"}
    Path(args.out).write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    print("| case | old [s] | new [s] | new/old | same numbers | largest relative difference |\n|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['case']} | {r['old_s']:.3f} | {r['new_s']:.3f} | {r['new_over_old']:.3f} | {r['same_numbers']} "
              f"| {r['max_relative_difference']:.1e} |")
    return 0 if all(r["same_numbers"] for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())

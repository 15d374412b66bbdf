"""Monte Carlo study of the order estimators and the fractional test (issue 11).

    python experiments/fit/study.py                  # all settings and methods, 200 realisations each
    python experiments/fit/study.py --tables         # only print the tables from what is saved

Settings: h = 0.01 s, N = 30 000, ``fractional+white`` with order α ∈ {0.1, 0.3, 0.5}, the pole at 40 % of
its stability limit (ρ = −f h^α / 2^α = 0.4) and the drive at the white-noise level (q h^{2α} = r = 10⁻³);
and α = 0 with the pole 0, where the fractional state is white and the series is white noise of variance
q + r — the null of the fractional test. Every series is simulated by :func:`torchtea.noise.simulate_model`
(soe memory) from its own seed.

Per realisation:

- **Whittle** MLE (``fit_series(method="whittle")``): Wald 95 % intervals (the order's on the logit scale,
  q and r on the log scale, the pole plain); the order's Whittle-profile interval — what ``fit --method
  whittle`` reports — on the first ``--profile-realisations`` (it costs several times the fit).
- **Exact** MLE (``method="exact"``, the Whittle fit as start): Wald intervals from the finite-difference
  observed information; on the first :data:`EXACT_REALISATIONS` realisations of each setting (none at α = 0).
- **TEA** as the paper runs it — the MEMS preset (KFo from α₀ = 1, KFw from f₀ = 0, adaptive Q), soe memory —
  but with the *true* q and r (the most favourable noise levels it could be given); α̂ is the mean over the
  last third of the run, as ``identify`` reports it. The TEA gives no interval.
- **Fractional test** (:func:`torchtea.fitting.presence.fractional_test`): Whittle LR against white noise,
  p-value from one parametric bootstrap of ``--boot`` white series fitted exactly as the data, shared by
  every realisation and setting (the null distribution depends on N only).

Coverage is the share of realisations whose interval holds the truth, with its binomial standard error; it
is not defined at α = 0 (the truth is on the boundary and the pole is not identified).

Results are saved per setting and method under ``experiments/fit/study/`` as they finish (a rerun skips
what is there and resumes the exact fits; ``--force`` redoes everything), and summarised in
``experiments/fit/study.json``. "At a bound": the order estimate within 10⁻³ of 0 or 1 (the TEA's order
bounds are (0, 2.5), so not counted for it).
"""
from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from torchtea.core.stats import last_third
from torchtea.engines.presets import get_preset
from torchtea.engines.structure import Structure
from torchtea.engines.tea import make_params, run_tea
from torchtea.fitting import fit_series
from torchtea.fitting.presence import fractional_test
from torchtea.noise import parse_model, simulate_model
from torchtea.noise.tea import tea_view

HERE = Path(__file__).resolve().parent
H, N, R_WHITE, RHO = 0.01, 30_000, 1e-3, 0.4
ORDERS = (0.0, 0.1, 0.3, 0.5)
#: Realisations of the exact MLE per setting (this 2-core machine: ≈ 9 s per series at α > 0, ≈ 40 s at
#: α = 0, where the order and pole are not identified and the refinement wanders a flat ridge). They run in
#: chunks, a chunk per setting in turn, saved as they finish: an interrupted run resumes where it stopped.
EXACT_REALISATIONS = {0.0: 0, 0.1: 200, 0.3: 200, 0.5: 200}
MODEL = parse_model("fractional+white")
PARAMS = MODEL.names


def truth(alpha: float) -> dict:
    return {"fractional.order": alpha, "fractional.pole": -RHO * 2 ** alpha / H ** alpha if alpha > 0 else 0.0,
            "fractional.q": R_WHITE / H ** (2 * alpha), "white.r": R_WHITE}


def series(alpha: float, n_real: int) -> np.ndarray:
    gen = torch.Generator().manual_seed(1000 + int(round(alpha * 100)))
    y = simulate_model(MODEL, truth(alpha), n_steps=N, h=H, realisations=n_real, generator=gen)[0]
    return y.numpy()


def _row(f, dt):
    return {"values": f.values, "ci95": f.ci95, "ci95_method": f.ci95_method, "converged": f.converged,
            "loglik": f.loglik, "seconds": dt}


#: Series per batched Whittle call (larger batches are memory-bound on this CPU, not faster per series).
WHITTLE_BATCH = 25


def _batched(ys, **kw) -> list:
    return [f for s in range(0, len(ys), WHITTLE_BATCH)
            for f in fit_series(MODEL, list(ys[s:s + WHITTLE_BATCH]), H, method="whittle", **kw)]


def run_whittle(ys, n_profile: int) -> list:
    """Whittle fits of every series (Wald intervals; the order's on the logit scale), and the profile
    interval of the order — what ``fit --method whittle`` reports — on the first ``n_profile``."""
    t = time.perf_counter()
    fits = _batched(ys, profile=False)
    dt = (time.perf_counter() - t) / len(fits)
    rows = [_row(f, dt) for f in fits]
    if n_profile:
        t = time.perf_counter()
        prof = _batched(ys[:n_profile], profile=True)
        dtp = (time.perf_counter() - t) / n_profile
        for r, f in zip(rows, prof):
            r["ci95_profile"] = f.ci95["fractional.order"]
            r["seconds_with_profile"] = dtp
    return rows


def run_exact_round(ys, path: Path, chunk: int, target: int) -> bool:
    """``chunk`` more exact fits of the series in order (saved to the partial file with the number of
    realisations they were simulated with: the series depend on it); True once ``target`` are done."""
    part = path.with_suffix(".partial.json")
    saved = json.loads(part.read_text()) if part.exists() else {"realisations": len(ys), "rows": []}
    if saved["realisations"] != len(ys):
        raise SystemExit(f"{part} holds fits of series simulated as {saved['realisations']} realisations, not "
                         f"{len(ys)}: run with --realisations {saved['realisations']} or --force")
    rows = saved["rows"]
    start = len(rows)
    if start >= target:
        return True
    t = time.perf_counter()
    fits = fit_series(MODEL, list(ys[start:min(start + chunk, target)]), H, method="exact", profile=False)
    dt = (time.perf_counter() - t) / len(fits)
    rows += [_row(f, dt) for f in fits]
    part.write_text(json.dumps(saved))
    print(f"  exact {path.stem}: {len(rows)}/{target} ({dt:.1f} s per series)", flush=True)
    return len(rows) >= target


def run_tea_rows(ys, alpha: float) -> list:
    v = truth(alpha)
    base = get_preset("paper-mems-x")
    cfg = tea_view(MODEL, v, H, base).config
    cfg = replace(cfg, kfo=replace(cfg.kfo, x0=base.kfo.x0), kfw=replace(cfg.kfw, x0=base.kfw.x0),
                  memory=replace(base.memory, kind="soe"))
    t = time.perf_counter()
    res = run_tea(torch.as_tensor(ys).unsqueeze(-1), h=H, params=make_params(cfg, Structure()))
    dt = (time.perf_counter() - t) / len(ys)
    a = res.alpha[:, last_third(N), 0].mean(-1)
    return [{"values": {"fractional.order": float(x)}, "diverged": bool(d), "seconds": dt}
            for x, d in zip(a, res.diverged)]


NULL_CACHE: dict = {}


def run_test(ys, n_boot: int) -> list:
    t = time.perf_counter()
    out = fractional_test(MODEL, list(ys), H, n_boot=n_boot, seed=0, null_cache=NULL_CACHE)
    dt = (time.perf_counter() - t) / len(ys)
    return [dict(o, seconds=dt) for o in out]


def summarise(alpha: float, rows: dict) -> dict:
    v = truth(alpha)
    out = {"truth": v}
    for method in ("whittle", "exact", "tea"):
        r = rows.get(method)
        if not r:
            continue
        a = np.array([x["values"]["fractional.order"] for x in r])
        s = {"n": len(a), "order_mean": float(a.mean()), "order_bias": float(a.mean() - alpha),
             "order_sd": float(a.std(ddof=1)), "order_rmse": float(np.sqrt(np.mean((a - alpha) ** 2))),
             "order_bias_se": float(a.std(ddof=1) / math.sqrt(len(a))),
             "order_at_bound": (int(np.sum((a < 1e-3) | (a > 1 - 1e-3))) if method != "tea" else None),
             "seconds_per_series": float(np.mean([x["seconds"] for x in r]))}
        if method != "tea":
            s["not_converged"] = int(sum(not x["converged"] for x in r))
            if alpha > 0:
                cov = {}
                for p in PARAMS:
                    hit = [x["ci95"][p] is not None and x["ci95"][p][0] <= v[p] <= x["ci95"][p][1] for x in r]
                    c = float(np.mean(hit))
                    cov[p] = {"coverage": c, "se": math.sqrt(c * (1 - c) / len(hit)),
                              "no_interval": int(sum(x["ci95"][p] is None for x in r))}
                s["coverage95"] = cov
                prof = [x for x in r if x.get("ci95_profile")]
                if prof:
                    hit = [x["ci95_profile"][0] <= alpha <= x["ci95_profile"][1] for x in prof]
                    c = float(np.mean(hit))
                    s["order_profile_coverage95"] = {"coverage": c, "se": math.sqrt(c * (1 - c) / len(hit)),
                                                     "n": len(hit)}
        else:
            s["diverged"] = int(sum(x["diverged"] for x in r))
        out[method] = s
    t = rows.get("test")
    if t:
        p = np.array([x["p_value"] for x in t])
        rej = float(np.mean(p <= 0.05))
        out["test"] = {"n": len(p), "n_boot": t[0]["n_boot"], "rejection_rate_5pct": rej,
                       "se": math.sqrt(rej * (1 - rej) / len(p)), "null_lr_quantile95": t[0]["null_lr_quantile95"],
                       "seconds_per_series": float(np.mean([x["seconds"] for x in t]))}
    return out


def tables(summary: dict) -> str:
    lines = ["| α | method | mean α̂ | bias (± se) | sd | RMSE | at a bound | s/series |",
             "|---|---|---|---|---|---|---|---|"]
    for key, s in summary.items():
        for m in ("whittle", "exact", "tea"):
            if m in s:
                x = s[m]
                lines.append(f"| {key} | {m} | {x['order_mean']:.3f} | {x['order_bias']:+.3f} (± {x['order_bias_se']:.3f}) "
                             f"| {x['order_sd']:.3f} | {x['order_rmse']:.3f} "
                             f"| {'—' if x['order_at_bound'] is None else x['order_at_bound']}/{x['n']} "
                             f"| {x['seconds_per_series']:.2f} |")
    lines += ["", "| α | method | " + " | ".join(PARAMS) + " |", "|---|---|" + "---|" * len(PARAMS)]
    for key, s in summary.items():
        for m in ("whittle", "exact"):
            if m in s and "coverage95" in s[m]:
                c = s[m]["coverage95"]
                lines.append(f"| {key} | {m} | " + " | ".join(
                    f"{100 * c[p]['coverage']:.1f} % (± {100 * c[p]['se']:.1f})" for p in PARAMS) + " |")
    lines += ["", "| α | Whittle profile interval of the order: coverage (± se) | realisations |", "|---|---|---|"]
    for key, s in summary.items():
        p = s.get("whittle", {}).get("order_profile_coverage95")
        if p:
            lines.append(f"| {key} | {100 * p['coverage']:.1f} % (± {100 * p['se']:.1f}) | {p['n']} |")
    lines += ["", "| α | rejections at 5 % (± se) | bootstrap replicates | null LR 95 % quantile |", "|---|---|---|---|"]
    for key, s in summary.items():
        if "test" in s:
            x = s["test"]
            lines.append(f"| {key} | {100 * x['rejection_rate_5pct']:.1f} % (± {100 * x['se']:.1f}) | {x['n_boot']} "
                         f"| {x['null_lr_quantile95']:.2f} |")
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--realisations", type=int, default=200)
    ap.add_argument("--orders", default=",".join(map(str, ORDERS)))
    ap.add_argument("--methods", default="whittle,tea,test,exact")
    ap.add_argument("--boot", type=int, default=199)
    ap.add_argument("--chunk", type=int, default=20)
    ap.add_argument("--exact-realisations", type=int, default=None,
                    help="realisations of the exact MLE per setting (default: EXACT_REALISATIONS)")
    ap.add_argument("--dir", default=str(HERE / "study"), help="per-setting results (default experiments/fit/study/)")
    ap.add_argument("--out", default=str(HERE / "study.json"), help="the summary (default experiments/fit/study.json)")
    ap.add_argument("--profile-realisations", type=int, default=50,
                    help="realisations per setting whose Whittle fit also gets the order's profile interval")
    ap.add_argument("--force", action="store_true")
    ap.add_argument("--tables", action="store_true", help="only summarise what is saved")
    args = ap.parse_args()
    d = Path(args.dir)
    d.mkdir(parents=True, exist_ok=True)
    orders = [float(a) for a in args.orders.split(",")]
    methods = args.methods.split(",")
    cache = {}

    def data(alpha):
        if alpha not in cache:
            cache[alpha] = series(alpha, args.realisations)
        return cache[alpha]

    if not args.tables:
        # the cheap methods on every setting first
        for method in [m for m in methods if m != "exact"]:
            for alpha in orders:
                path = d / f"a{alpha:g}_{method}.json"
                if path.exists() and not args.force:
                    continue
                ys = data(alpha)
                print(f"α = {alpha:g}, {method} …", flush=True)
                if method == "whittle":
                    rows = run_whittle(ys, args.profile_realisations)
                elif method == "tea":
                    rows = run_tea_rows(ys, alpha)
                elif method == "test":
                    rows = run_test(ys, args.boot)
                else:
                    raise SystemExit(f"unknown method {method!r}")
                path.write_text(json.dumps(rows))
        # then the exact MLE, a chunk per setting in turn, so every setting grows together
        if "exact" in methods:
            targets = {a: min(args.realisations, EXACT_REALISATIONS.get(a, args.realisations)
                              if args.exact_realisations is None else args.exact_realisations) for a in orders}
            if args.force:
                for a in orders:
                    (d / f"a{a:g}_exact.partial.json").unlink(missing_ok=True)
            pending = [a for a in orders if targets[a] > 0]
            while pending:
                for alpha in list(pending):
                    path = d / f"a{alpha:g}_exact.json"
                    if run_exact_round(data(alpha), path, args.chunk, targets[alpha]):
                        pending.remove(alpha)
    summary = {}
    for alpha in sorted(orders):
        rows = {}
        for m in ("whittle", "exact", "tea", "test"):
            f = d / (f"a{alpha:g}_{m}.partial.json" if m == "exact" else f"a{alpha:g}_{m}.json")
            if f.exists():
                rows[m] = json.loads(f.read_text())
                if m == "exact":
                    rows[m] = rows[m]["rows"]
        if rows:
            summary[f"{alpha:g}"] = summarise(alpha, rows)
    doc = {"settings": {"h": H, "n": N, "model": MODEL.spec, "pole_fraction": RHO, "r": R_WHITE,
                        "q": "r / h^(2α)", "realisations": args.realisations, "bootstrap": args.boot},
           "command": "python experiments/fit/study.py", "results": summary}
    Path(args.out).write_text(json.dumps(doc, indent=1))
    print(tables(summary))


if __name__ == "__main__":
    main()

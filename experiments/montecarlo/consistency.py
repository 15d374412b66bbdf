"""Issue 15: the TEA's consistency with the order's and parameter's uncertainty in KFx and honest KFo/KFw
covariances, against the paper's filters.

    python experiments/montecarlo/consistency.py [--realisations 200] [--only NAME ...] [--prior consistent]

Every setting runs as a `torchtea montecarlo` sweep over ``estimator.kfx_uncertainty = ["paper", "propagated",
"paper-gain"]`` × ``estimator.estimate_uncertainty = ["paper", "constant-truth"]`` (same seed: the six combinations
see the same realisations) into experiments/montecarlo/runs/consistency/<setting>/, one TensorBoard run per
sub-study (the HParams tab compares them: metric/nees_mean, metric/order_coverage, …).
The settings are those of README.md's table: Examples 1–3, the MEMS setting and the 3 × 3 sweep of Example 1.
A further setting, ``mems_constant``, is the MEMS truth with KFo and KFw set for a constant order and parameter
(Q₀ = 0, δ = 0) instead of the paper's random walk of variance 0.1 per step.
Writes consistency.json (the summaries) and prints the before/after table of README.md.

``--prior consistent`` starts every realisation's filters from draws of their own priors around the truth
(``torchtea montecarlo --prior consistent``) instead of the presets' fixed starts, which lie up to 40 prior
standard deviations from the truth; it writes consistency_prior.json and runs/consistency_prior/ (same
realisations: the draws of the starts come from a stream of their own).
"""
from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from torchtea.cli import main as cli  # noqa: E402

HERE = Path(__file__).resolve().parent
KFX = ("paper", "propagated", "paper-gain")
ESTIMATE = ("paper", "constant-truth")
#: (kfx_uncertainty, estimate_uncertainty) of every sub-study; the first is the paper's filters ("before")
MODES = tuple((k, e) for e in ESTIMATE for k in KFX)
MEMS_TRUTH = {"h": 0.01, "n": 3000, "order": "0.4", "param": -4.0, "q": 0.01, "r": 4e-4}
SETTINGS = {
    "example1": ("paper-example1", {}, 1),
    "example2": ("paper-example2", {}, 2),
    "example3": ("paper-example3", {}, 3),
    "mems": ("paper-mems-x", MEMS_TRUTH, 4),
    "mems_constant": ("paper-mems-x", MEMS_TRUTH, 4, {"kfo": {"Q0": 0.0, "delta": 0.0}, "kfw": {"Q0": 0.0, "delta": 0.0}}),
    **{f"sweep_a{o}_f{p}": ("paper-example1", {"order": o, "param": float(p)}, 5)
       for o in ("0.2", "0.35", "0.6") for p in ("-0.5", "-1", "-2")},
}


def toml_value(v):
    return f'"{v}"' if isinstance(v, str) else repr(v)


def runs_dir(prior: str) -> Path:
    return HERE / "runs" / ("consistency" if prior == "preset" else "consistency_prior")


def run(name: str, preset: str, truth: dict, seed: int, realisations: int, estimator: dict | None = None,
        prior: str = "preset") -> dict:
    runs = runs_dir(prior)
    cfg = runs / f"{name}.toml"
    cfg.parent.mkdir(parents=True, exist_ok=True)
    lines = [f"realisations = {realisations}", f"seed = {seed}", f'prior = "{prior}"', "[estimator]", f'preset = "{preset}"']
    for table_name, values in (estimator or {}).items():
        lines += [f"[estimator.{table_name}]"] + [f"{k} = {toml_value(v)}" for k, v in values.items()]
    if truth:
        lines += ["[truth]"] + [f"{k} = {toml_value(v)}" for k, v in truth.items()]
    lines += ["[sweep.estimator]", "kfx_uncertainty = [" + ", ".join(f'"{m}"' for m in KFX) + "]",
              "estimate_uncertainty = [" + ", ".join(f'"{m}"' for m in ESTIMATE) + "]"]
    cfg.write_text("\n".join(lines) + "\n")
    t0 = time.perf_counter()
    (runs / name / "sweep.json").unlink(missing_ok=True)  # never read back an earlier run's table
    with contextlib.redirect_stdout(io.StringIO()):  # the sweep's JSON is read back from sweep.json below
        code = cli(["montecarlo", "--config", str(cfg), "--logdir", str(runs / name), "--json"])
    if code != 0:
        raise SystemExit(f"{name}: torchtea montecarlo exited {code}")
    table = json.loads((runs / name / "sweep.json").read_text())
    print(f"{name}: {time.perf_counter() - t0:.1f} s (exit {code})", file=sys.stderr, flush=True)
    return {key(s["sweep"]["values"]["estimator.kfx_uncertainty"], s["sweep"]["values"]["estimator.estimate_uncertainty"]): s
            for s in table["studies"]}


def key(kfx: str, estimate: str) -> str:
    return f"{kfx} / {estimate}"


def fmt(v, spec):
    return "–" if v is None else format(v, spec)


def table(results: dict) -> str:
    rows = ["| setting | KFx / KFo-KFw covariance | mean NEES (thirds) | order ±2σ coverage (thirds) | param ±2σ coverage | order bias / RMSE | "
            "param bias / RMSE | mean NIS |", "|---|---|---|---|---|---|---|---|"]
    for name, by_mode in results.items():
        for mode in MODES:
            s = by_mode[key(*mode)]
            o, p = s["order"], s["param"]
            thirds = lambda xs, spec: " / ".join(fmt(x, spec) for x in xs)  # noqa: E731
            rows.append(f"| {name} | {key(*mode)} | {s['nees']['mean']:.3g} ({thirds(s['nees']['mean_by_third'], '.3g')}) | "
                        f"{o['coverage_2sigma']:.3f} ({thirds(o['coverage_2sigma_by_third'], '.3f')}) | "
                        f"{p['coverage_2sigma']:.3f} | {o['bias']:+.4f} / {o['rmse']:.4f} | "
                        f"{p['bias']:+.3f} / {p['rmse']:.3f} | {s['nis']['mean']:.3f} |")
    return "\n".join(rows)


#: the before/after pair of the issue's table: the paper's filters, and the default KFx with constant-truth
#: order and parameter covariances
BEFORE, AFTER = ("paper", "paper"), ("paper-gain", "constant-truth")


def before_after(results: dict) -> str:
    """One row per setting: the paper's filters → paper-gain with constant-truth covariances."""
    rows = ["| setting | mean NEES | order ±2σ coverage | param ±2σ coverage | order bias / RMSE | param bias / RMSE |",
            "|---|---|---|---|---|---|"]
    for name, by_mode in results.items():
        b, a = by_mode[key(*BEFORE)], by_mode[key(*AFTER)]
        arrow = lambda f, spec: f"{format(f(b), spec)} → {format(f(a), spec)}"  # noqa: E731
        rows.append(f"| {name} | {arrow(lambda s: s['nees']['mean'], '.3g')} | "
                    f"{arrow(lambda s: s['order']['coverage_2sigma'], '.3f')} | "
                    f"{arrow(lambda s: s['param']['coverage_2sigma'], '.3f')} | "
                    f"{arrow(lambda s: s['order']['bias'], '+.4f')} / {arrow(lambda s: s['order']['rmse'], '.4f')} | "
                    f"{arrow(lambda s: s['param']['bias'], '+.3f')} / {arrow(lambda s: s['param']['rmse'], '.3f')} |")
    return "\n".join(rows)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--realisations", type=int, default=200)
    ap.add_argument("--only", nargs="*")
    ap.add_argument("--prior", choices=("preset", "consistent"), default="preset")
    args = ap.parse_args()
    path = HERE / ("consistency.json" if args.prior == "preset" else "consistency_prior.json")
    results = json.loads(path.read_text()) if path.exists() else {}
    for name, (preset, truth, seed, *estimator) in SETTINGS.items():
        if args.only and name not in args.only:
            continue
        results[name] = run(name, preset, truth, seed, args.realisations, *estimator, prior=args.prior)
        path.write_text(json.dumps(results, indent=2) + "\n")
    done = {k: results[k] for k in SETTINGS if k in results}
    print(table(done))
    print()
    print(before_after(done))


if __name__ == "__main__":
    main()

"""Reproduce the paper's Examples 1–3 over many seeds, and its MEMS section on the bundled recording.

    python experiments/paper/reproduce.py [--seeds 50] [--examples 1 2 3] [--no-mems]

For every example: seeds 0…S−1 are simulated exactly as `torchtea simulate --seed K` would (so any run can be
replayed from the command line), then the TEA runs on all seeds as one batch for each settings variant:

* ``torchtea``    — the paper's printed numbers with torchtea's defaults for the open points (standard UT
                    sums from i = 0, h^α-scaled process noise in KFx, α̂ ∈ [0, 2.5], adapted Q capped at Q₀);
* ``sums-from-1``, ``unscaled-Q``, ``no-Q-cap`` — one open point at a time read as printed;
* ``as-printed``  — all three read as printed (sums from i = 1, unscaled Q in (31), (25) uncapped);
* ``fixed-Qw``    — torchtea defaults and no Robbins–Monro adaptation of Qʷ (δʷ = 0).

Writes experiments/paper/results.json, figures in experiments/paper/figures/, and prints the tables.
"""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from experiments.common import machine, simulate_seeds, write_json  # noqa: E402
from torchtea import SCENARIOS, Structure, TEAConfig, get_preset, make_params, run_tea  # noqa: E402
from torchtea.render.plots import estimation_figure, fan_figure  # noqa: E402

HERE = Path(__file__).resolve().parent


def variants(name: str) -> dict:
    """Settings variants: torchtea's defaults for the open points, each open point read as printed, and both
    alternatives for the adaptive Q (open point 4)."""
    base = replace(get_preset(name), kfx_uncertainty="paper")  # the paper's KFx: its P and S (NIS) as printed
    none = {"kfo": {"Q_max": "none"}, "kfw": {"Q_max": "none"}}
    return {
        "torchtea": base,
        "sums-from-1": TEAConfig.from_dict({"sigma_sum_start": 1}, base),
        "unscaled-Q": TEAConfig.from_dict({"noise_scaling": "unscaled"}, base),
        "no-Q-cap": TEAConfig.from_dict(none, base),
        "as-printed": TEAConfig.from_dict({"sigma_sum_start": 1, "noise_scaling": "unscaled", **none}, base),
        "fixed-Qw": TEAConfig.from_dict({"kfw": {"delta": 0.0}}, base),
    }


def metrics(example: int, t, alpha_true, x_true, res) -> dict:
    a = res.alpha[..., 0].numpy()
    w = res.w[..., 0].numpy()
    div = res.diverged.numpy()
    ok = ~div
    out = {"diverged_fraction": float(div.mean()), "runs": int(len(div))}
    last = (t >= 5.0) & (t < 6.0)
    out["alpha_mean_5_6s"] = _stats(a[:, last].mean(1)[ok])
    out["abs_alpha_error_5_6s"] = _stats(np.abs(a[:, last].mean(1) - alpha_true[:, last].mean(1))[ok])
    out["param_mean_5_6s"] = _stats(w[:, last].mean(1)[ok])
    band = (t >= 1.0) & (t <= 6.0)
    rmse = np.sqrt(((a[:, band] - alpha_true[:, band]) ** 2).mean(1))
    out["order_rmse_1_6s"] = _stats(rmse[ok])
    out["order_rmse_1_6s_all_runs"] = _stats(rmse)
    out["fraction_rmse_le_0.05"] = float(((rmse <= 0.05) & ok).mean())  # diverged runs count as failures
    # KFx: state error and consistency (mean NIS ≈ 1 when the predicted innovation variance is right)
    xe = res.x[..., 0].numpy() - x_true
    out["state_rmse_1_6s"] = _stats(np.sqrt((xe[:, band] ** 2).mean(1))[ok])
    nis = (res.innovation[..., 0] ** 2 / res.innovation_cov[..., 0, 0]).numpy()
    out["nis_mean_1_6s"] = _stats(nis[:, band].mean(1)[ok])
    return out


def _stats(v) -> dict:
    v = np.asarray(v, dtype=float)
    if v.size == 0:
        return {"n": 0}
    return {"n": int(v.size), "mean": float(v.mean()), "std": float(v.std(ddof=1)) if v.size > 1 else 0.0,
            "median": float(np.median(v)), "p05": float(np.quantile(v, 0.05)), "p95": float(np.quantile(v, 0.95)),
            "max": float(v.max()), "min": float(v.min())}


def run_examples(examples, seeds, fig_dir: Path) -> dict:
    results = {}
    for ex in examples:
        name = f"paper-example{ex}"
        sc = SCENARIOS[name]
        t0 = time.perf_counter()
        y, u, x, alpha = simulate_seeds(sc, range(seeds))
        t_sim = time.perf_counter() - t0
        t = np.arange(sc.n_steps) * sc.h
        results[name] = {"simulate_s": round(t_sim, 2), "variants": {}}
        for vname, cfg in variants(name).items():
            t0 = time.perf_counter()
            res = run_tea(y, h=sc.h, params=make_params(cfg, Structure()), inputs=u)
            el = time.perf_counter() - t0
            m = metrics(ex, t, alpha[..., 0].numpy(), x[..., 0].numpy(), res)
            m["tea_s"] = round(el, 2)
            results[name]["variants"][vname] = m
            print(f"{name:15s} {vname:9s} {el:6.1f}s  diverged {m['diverged_fraction']:.2f}  "
                  f"|α̂(5–6s)−α| median {m['abs_alpha_error_5_6s'].get('median', float('nan')):.4f}  "
                  f"RMSE(1–6s) median {m['order_rmse_1_6s'].get('median', float('nan')):.4f}  "
                  f"ŵ(5–6s) median {m['param_mean_5_6s'].get('median', float('nan')):.3f}  "
                  f"x RMSE {m['state_rmse_1_6s'].get('median', float('nan')):.2e}  "
                  f"NIS {m['nis_mean_1_6s'].get('median', float('nan')):.2f}", flush=True)
            if vname in ("torchtea", "as-printed"):
                tag = f"example{ex}_{vname}"
                sd = lambda P: P[0, :, 0, 0].clamp(min=0).sqrt().numpy()  # noqa: E731
                estimation_figure(
                    fig_dir / f"{tag}_seed0.png", t, y=y[0, :, 0].numpy(), x_true=x[0, :, 0].numpy(),
                    x_hat=res.x[0, :, 0].numpy(), alpha_true=alpha[0, :, 0].numpy(), alpha_hat=res.alpha[0, :, 0].numpy(),
                    alpha_sd=sd(res.P_alpha), w_true=np.full_like(t, sc.param), w_hat=res.w[0, :, 0].numpy(),
                    w_sd=sd(res.P_w), zoom=(2.0, 2.5),
                    title=f"Example {ex}, seed 0, settings '{vname}' (cf. paper Figs. {2 + 3 * (ex - 1)}–{4 + 3 * (ex - 1)})")
                ok = ~res.diverged.numpy()
                if not ok.any():
                    continue
                fan_figure(fig_dir / f"{tag}_alpha_fan.png", t, alpha[0, :, 0].numpy(), res.alpha[ok, :, 0].numpy(),
                           ylabel="order α̂", title=f"Example {ex}, '{vname}': α̂ over {ok.sum()} non-diverged seeds")
                fan_figure(fig_dir / f"{tag}_param_fan.png", t, np.full_like(t, sc.param), res.w[ok, :, 0].numpy(),
                           ylabel="parameter ŵ", title=f"Example {ex}, '{vname}': ŵ over {ok.sum()} non-diverged seeds")
    return results


def run_mems(fig_dir: Path) -> dict:
    from torchtea.identification import identify
    from torchtea.sensors.io import read_recording

    rec = read_recording()
    out = {}
    for n in (3000, 12000):
        for r_mode in ("measured", "paper"):
            t0 = time.perf_counter()
            ident = identify(rec, n_samples=n, r_mode=r_mode)
            el = time.perf_counter() - t0
            s = ident.summary()
            s["seconds"] = round(el, 2)
            out[f"{n}_{r_mode}"] = s
            print(f"MEMS {n} samples, R {r_mode}: " + ", ".join(
                f"{a}: α̂ {v['alpha']:.3f}±{v['alpha_std_last_third']:.3f} ŵ {v['param']:.3f}±{v['param_std_last_third']:.3f}"
                for a, v in s["axes"].items()) + f"  ({el:.1f} s)", flush=True)
            if n == 3000 and r_mode == "measured":
                t = ident.t
                res = ident.result
                for i, a in enumerate("xyz"):
                    estimation_figure(
                        fig_dir / f"mems_{a}.png", t, y=ident.y[i, :, 0].numpy(), x_hat=res.x[i, :, 0].numpy(),
                        alpha_hat=res.alpha[i, :, 0].numpy(), alpha_sd=res.P_alpha[i, :, 0, 0].clamp(min=0).sqrt().numpy(),
                        w_hat=res.w[i, :, 0].numpy(), w_sd=res.P_w[i, :, 0, 0].clamp(min=0).sqrt().numpy(),
                        state_label="noise [m/s²]", zoom=(25.0, 30.0),
                        title=f"MPU-6050 {a}-axis, first 30 s (cf. paper Figs. {12 + 3 * i}–{14 + 3 * i})")
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=50)
    ap.add_argument("--examples", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--no-mems", action="store_true")
    ap.add_argument("--out", default=str(HERE / "results.json"))
    args = ap.parse_args()
    fig_dir = HERE / "figures"
    data = {"machine": machine(), "seeds": args.seeds, "examples": run_examples(args.examples, args.seeds, fig_dir)}
    if not args.no_mems:
        data["mems"] = run_mems(fig_dir)
    write_json(Path(args.out), data)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()

"""Where the TEA's residual order bias on grown-model data comes from: KFx's prediction, not KFo.

The ``fractional+white+random-walk`` data of grown_model.py (order 0.4, pole −2 held, q 0.02, r 1e-5; walk σ 0,
0.01, 0.05; 32 realisations × 6000 steps, seed 5, each realisation's mean removed), three runs per σ:

1. **KFx at the truth.** The TEA with the grown model's view and KFo and KFw frozen at the truth (P0 = Q0 = 1e-12),
   so KFx alone runs, against the exact Kalman filter of the model's state space (``soe`` memory, the state space
   the data were simulated from) at the same values. Over the last two thirds: each filter's one-step prediction
   error ``mean e²`` (the exact filter's is the smallest any predictor from the past can have), its NIS, and the
   lag-1 autocorrelation of its standardised innovations (0 for the exact filter). KFx predicts from its filtered
   past ``x̂_{k−j|k−j}`` and never revises it; the exact filter's state holds the whole past and every new sample
   revises it.
2. **The TEA** under grown_model.py's ``constant`` settings (KFo's R = KFx's innovation covariance of the step
   before, Qᵒ 1e-5 adapted by (25)), pole held, started at the truth: α̂ over the last third.
3. **The same KFo on the exact filter** (``kfx_filter = "exact"``, :func:`torchtea.noise.tea_exact.run_tea_exact`):
   KFo's unscented update with the TEA's sigma points, weights, R and adaptation, its replicas predicting ``y_k``
   from the exact filter's state at ``k−1`` under each sigma order (``C F(αᵢ) ẑ_{k−1}``: only the fractional block's
   first row of ``F`` depends on the order), and the exact filter then run with ``F(α̂_k)``. The one difference
   from run 2 is KFx. (A first version of this study had its own copy of that loop; it and the library's agree to
   2e-8 in α̂, the difference of their ``soe`` kernels.)

If run 3 is unbiased where run 2 is not, the residual is KFx's: KFo settles where its innovations stop correlating
with the order's regressor, and KFx's innovations at the truth still correlate with the past (run 1), so that point
is not the truth.

    python experiments/tea_models/fixed_point.py [--realisations 32] [--out experiments/tea_models]

writes fixed_point.json and fixed_point.md there (about 2 min on one core).
"""
from __future__ import annotations

import math
import time
from dataclasses import replace

import torch
from grown_model import FW, SIGMAS, H, arguments, data, tea_config, write_outputs

from torchtea.core.stats import last_third
from torchtea.engines.tea import make_params, run_tea
from torchtea.likelihood.kalman import kalman_filter
from torchtea.noise.model import parse_model
from torchtea.noise.tea import tea_view
from torchtea.noise.tea_exact import run_tea_exact

MODEL = "fractional+white+random-walk"
FROZEN = {"P0": 1e-12, "Q0": 1e-12}


def truth(sigma: float) -> dict:
    return dict(FW, **{"random-walk.sigma": max(sigma, 1e-12)})


def innovation_stats(e: torch.Tensor, S: torch.Tensor) -> dict:
    """Over the last two thirds of ``e``, ``S`` ``(R, N)``: mean e², NIS, lag-1 autocorrelation of e/√S
    (means over realisations)."""
    N = e.shape[-1]
    e, S = e[:, N // 3:], S[:, N // 3:]
    z = e / S.sqrt()
    z = z - z.mean(-1, keepdim=True)
    rho = (z[:, 1:] * z[:, :-1]).sum(-1) / (z * z).sum(-1)
    return {"mse": float((e * e).mean()), "nis": float((e * e / S).mean()), "rho1": float(rho.mean()),
            "rho1_se": float(rho.std() / math.sqrt(rho.numel()))}


def kfx_at_truth(y: torch.Tensor, sigma: float) -> dict:
    v = tea_view(MODEL, truth(sigma), H)
    cfg = tea_config(v, "constant", True)
    cfg = replace(cfg, kfo=replace(cfg.kfo, **FROZEN))
    res = run_tea(y.unsqueeze(-1), h=H, params=make_params(cfg, v.structure), structure=v.structure)
    tea = innovation_stats(res.innovation[..., 0], res.innovation_cov[..., 0, 0])
    ss = parse_model(MODEL).state_space(truth(sigma), H, y.shape[-1], memory="soe")
    kf = kalman_filter(ss.expand(y.shape[0]), y)
    return {"kfx": tea, "exact": innovation_stats(kf.innovation, kf.variance)}


def tea_alpha(y: torch.Tensor, sigma: float) -> torch.Tensor:
    v = tea_view(MODEL, truth(sigma), H)
    cfg = tea_config(v, "constant", True)
    res = run_tea(y.unsqueeze(-1), h=H, params=make_params(cfg, v.structure), structure=v.structure)
    return res.alpha[:, last_third(y.shape[-1]), 0].mean(-1)


def exact_kfx(y: torch.Tensor, sigma: float) -> torch.Tensor:
    """The same KFo and settings on the exact filter (``kfx_filter = "exact"``, torchtea.noise.tea_exact); α̂ over
    the last third."""
    v = tea_view(MODEL, truth(sigma), H)
    v = replace(v, config=replace(tea_config(v, "constant", True), kfx_filter="exact"))
    return run_tea_exact(v, y, h=H).alpha[:, last_third(y.shape[-1]), 0].mean(-1)


def summary(a: torch.Tensor) -> dict:
    t = FW["fractional.order"]
    return {"mean": float(a.mean()), "bias": float(a.mean() - t), "sd": float(a.std()),
            "se": float(a.std() / math.sqrt(a.numel()))}


def main(argv=None) -> int:
    args = arguments(__doc__, argv)
    rows = []
    for sigma in SIGMAS:
        t0 = time.perf_counter()
        y = data(truth(sigma), args)
        kfx = kfx_at_truth(y, sigma)
        tea = summary(tea_alpha(y, sigma))
        dual = summary(exact_kfx(y, sigma))
        rows.append({"sigma": sigma, "kfx_at_truth": kfx, "tea": tea, "exact_kfx": dual,
                     "seconds": time.perf_counter() - t0})
        print(f"σ {sigma}: KFx mse/exact {kfx['kfx']['mse'] / kfx['exact']['mse']:.3f} ρ1 {kfx['kfx']['rho1']:+.3f} "
              f"(exact {kfx['exact']['rho1']:+.3f}); TEA bias {tea['bias']:+.4f} ± {tea['se']:.4f}; "
              f"KFo on the exact filter {dual['bias']:+.4f} ± {dual['se']:.4f} ({rows[-1]['seconds']:.0f} s)",
              flush=True)
    meta = {"steps": args.steps, "realisations": args.realisations, "seed": args.seed,
            "meaning": "kfx_at_truth: one-step prediction error mean e² (mse), NIS and lag-1 autocorrelation of the "
                       "standardised innovations (rho1, mean over realisations, rho1_se its standard error) over the "
                       "last two thirds, of the TEA's KFx and of the exact filter, both at the true values; tea and "
                       "exact_kfx: α̂ averaged over the last third of each run — mean, bias (truth 0.4), sd across "
                       "realisations and the standard error of the mean"}
    lines = ["| walk σ | KFx mean e² / exact's | KFx NIS | KFx ρ₁ | exact ρ₁ | TEA α̂ bias | KFo on the exact filter: α̂ bias |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        k, e = r["kfx_at_truth"]["kfx"], r["kfx_at_truth"]["exact"]
        lines.append(f"| {r['sigma']:g} | {k['mse'] / e['mse']:.3f} | {k['nis']:.2f} | {k['rho1']:+.3f} ± "
                     f"{k['rho1_se']:.3f} | {e['rho1']:+.3f} ± {e['rho1_se']:.3f} | {r['tea']['bias']:+.4f} ± "
                     f"{r['tea']['se']:.4f} | {r['exact_kfx']['bias']:+.4f} ± {r['exact_kfx']['se']:.4f} |")
    write_outputs(args.out, "fixed_point", meta, rows, lines)
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

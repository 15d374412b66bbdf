"""Issue 15, prototype (not in the package): the paper's estimates with an honest covariance.

    python experiments/montecarlo/paper_gain_prototype.py [--realisations 40] [--n 1500]

The package's ``kfx_uncertainty = "propagated"`` puts the order's and parameter's uncertainty into KFx's P̃ and
therefore into its gain, which moves the estimates (experiments/montecarlo/README.md). The alternative tested here
keeps the paper's filter untouched: its gain K, its x̂, α̂, ŵ. Next to it, it runs a second covariance, the
covariance of the error of that filter,

    P̃ʰ_k = F² Pʰ_{k−1} + h^{2α} Q + Σ_{j≥2} c_j² Pʰ_{k−j} + J_α² Pᵒ_k + J_w² Pʷ_{k−1},
    Pʰ_k = (1 − K)² P̃ʰ_k + K² R    (Joseph form with the paper's K),

with J_α and J_w the sensitivities of the prediction as the package takes them (statistical linearisation over
KFo's and KFw's sigma points). The filter is the scalar NumPy reference loop of the tests
(``tests/reference_tea.tea_reference(..., honest=True)``); it is slow (O(N²) in Python), hence the small sizes. Prints the NEES of x̂ against P
(the paper's) and against Pʰ, per setting, and the same realisations' NEES under the package's "propagated"
setting for comparison. ``--r-from-kfx`` adds a first look at KFo's honesty: KFo and KFw with KFx's last
innovation covariance as their measurement covariance, and the order's ±2σ coverage of both variants.
"""
from __future__ import annotations

import argparse
import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from tests.reference_tea import settings_from_config, tea_reference  # noqa: E402
from torchtea.engines.presets import get_preset  # noqa: E402
from torchtea.engines.structure import Structure  # noqa: E402
from torchtea.noise.simulate import simulate  # noqa: E402
from torchtea.studies.cluster import run_study  # noqa: E402
from torchtea.studies.montecarlo import Study, Truth, draw_realisation  # noqa: E402

SETTINGS = {
    "example1": (dict(h=1e-3, order="0.35", param=-1.0, q=1e-4, r=1e-3, input_std=1.0), "paper-example1"),
    "sweep_a0.6_f-2": (dict(h=1e-3, order="0.6", param=-2.0, q=1e-4, r=1e-3, input_std=1.0), "paper-example1"),
    "mems": (dict(h=0.01, order="0.4", param=-4.0, q=0.01, r=4e-4, input_std=None), "paper-mems-x"),
}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--realisations", type=int, default=40)
    ap.add_argument("--n", type=int, default=1500)
    ap.add_argument("--r-from-kfx", action="store_true",
                    help="also the variant whose KFo and KFw take KFx's last S as their measurement covariance")
    args = ap.parse_args()
    print(f"{'setting':<16} {'variant':<10} {'NEES paper P':>13} {'NEES Pʰ':>9} {'NEES propagated':>16} "
          f"{'order ±2σ cov.':>15} {'order RMSE':>11}  (NEES: means over realisations and steps 1…N−1; the order's "
          "coverage over (realisation, step) pairs, RMSE at the last sample)")
    for name, (truth, preset) in SETTINGS.items():
        tr = Truth(n_steps=args.n, **truth)
        cfg = get_preset(preset)
        s = settings_from_config(cfg)
        alpha_true = tr.schedule().values(tr.n_steps, tr.h, 1)[:, 0].numpy()
        prop = run_study(Study(tr, replace(cfg, kfx_uncertainty="propagated"), realisations=args.realisations, seed=7))
        nees_prop = float(prop.nees_sum[1:].sum() / (prop.kept * (args.n - 1)))
        for variant in (("paper R", False), ("R = S", True))[: 2 if args.r_from_kfx else 1]:
            nees_p, nees_h, cover, final = [], [], [], []
            for i in range(args.realisations):
                u, z_w, z_v = draw_realisation(tr, 7, i)
                sim = simulate(Structure(), n_steps=tr.n_steps, h=tr.h, order=tr.schedule(), parameters=[tr.param],
                               process_noise=tr.q, measurement_noise=tr.r,
                               inputs=None if u is None else u.unsqueeze(0),
                               standard_draws=(z_w.unsqueeze(0), z_v.unsqueeze(0)), memory="soe")
                y = sim.y[0, :, 0].numpy()
                xt = sim.x[0, :, 0].numpy()
                out = tea_reference(y, None if u is None else u[:, 0].numpy(), tr.h, s, honest=True,
                                    r_from_kfx=variant[1])
                x, P, Ph, a, Po = out["x"], out["P"], out["Ph"], out["a"], out["Po"]
                err2 = (x - xt) ** 2
                nees_p.append(np.mean(err2[1:] / P[1:]))
                nees_h.append(np.mean(err2[1:] / Ph[1:]))
                cover.append(np.mean(np.abs(a - alpha_true) <= 2 * np.sqrt(Po)))
                final.append(a[-1] - alpha_true[-1])
            print(f"{name:<16} {variant[0]:<10} {np.mean(nees_p):13.3f} {np.mean(nees_h):9.3f} {nees_prop:16.3f} "
                  f"{np.mean(cover):15.3f} {math.sqrt(np.mean(np.square(final))):11.4f}", flush=True)


if __name__ == "__main__":
    torch.set_num_threads(1)
    main()

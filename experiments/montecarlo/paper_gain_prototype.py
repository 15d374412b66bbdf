"""Issue 15, prototype (not in the package): the paper's estimates with an honest covariance.

    python experiments/montecarlo/paper_gain_prototype.py [--realisations 40] [--n 1500]

The package's ``kfx_uncertainty = "propagated"`` puts the order's and parameter's uncertainty into KFx's P̃ and
therefore into its gain, which moves the estimates (experiments/montecarlo/README.md). The alternative tested here
keeps the paper's filter untouched: its gain K, its x̂, α̂, ŵ. Next to it, it runs a second covariance, the
covariance of the error of that filter,

    P̃ʰ_k = F² Pʰ_{k−1} + h^{2α} Q + Σ_{j≥2} c_j² Pʰ_{k−j} + J_α² Pᵒ_k + J_w² Pʷ_{k−1},
    Pʰ_k = (1 − K)² P̃ʰ_k + K² R    (Joseph form with the paper's K),

with J_α and J_w the sensitivities of the prediction as the package takes them (statistical linearisation over
KFo's and KFw's sigma points). The filter is the scalar NumPy reference loop of the tests (tests/reference_tea.py),
extended by these lines; it is slow (O(N²) in Python), hence the small sizes. Prints the NEES of x̂ against P
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
from tests.reference_tea import gl, settings_from_config  # noqa: E402
from torchtea.engines.presets import get_preset  # noqa: E402
from torchtea.studies.montecarlo import Study, Truth, draw_realisation, run_study  # noqa: E402
from torchtea.engines.simulate import simulate  # noqa: E402
from torchtea.engines.structure import Structure  # noqa: E402


def tea_with_honest_cov(y, u, h, s, r_from_kfx=False):
    """The reference TEA (paper's gain) returning x̂, P, the honest Pʰ, α̂ and Pᵒ. ``r_from_kfx``: KFo's and KFw's
    measurement covariance is KFx's last innovation covariance S_{k−1} instead of the fixed Rᵒ, Rʷ."""
    N = len(y)
    u = np.zeros(N) if u is None else np.asarray(u, dtype=float)
    lam = s["ua"] ** 2 * (1 + s["kappa"]) - 1
    Wm = [lam / (1 + lam), 1 / (2 * (1 + lam)), 1 / (2 * (1 + lam))]
    Wc = [Wm[0] + 1 - s["ua"] ** 2 + s["ub"], Wm[1], Wm[2]]
    x, P = s["x0"], s["P0"]
    S = P + s["R"]
    K = P / S
    x, P = x + K * (y[0] - x), max(P - K * S * K, 0.0)
    Ph = P
    a, Po, Qo, w, Pw, Qw = s["a0"], s["P0o"], s["Q0o"], s["w0"], s["P0w"], s["Q0w"]
    xs, Ps, Phs = [x], [P], [Ph]
    out_x, out_P, out_Ph, out_a, out_Po = [x], [P], [Ph], [a], [Po]

    def ut(mean, Pt, pts, Ys, R, yk):
        yp = sum(Wm[i] * Ys[i] for i in range(3))
        Pyy = sum(Wc[i] * (Ys[i] - yp) ** 2 for i in range(3)) + R
        Pxy = sum(Wc[i] * (pts[i] - mean) * (Ys[i] - yp) for i in range(3))
        Kk = Pxy / Pyy
        e = yk - yp
        return mean + Kk * e, max(Pt - Kk * Pyy * Kk, 0.0), Kk, e

    def adapt(Q, Kk, e, delta, qmax):
        Qn = (1 - delta) * Q + delta * (Kk * e) ** 2
        return min(Qn, qmax) if qmax is not None else Qn

    for k in range(1, N):
        past, pastP, pastPh = np.array(xs[::-1]), np.array(Ps[::-1]), np.array(Phs[::-1])
        x_prev, u_prev = xs[-1], u[k - 1]

        def model(order, param):
            c = gl(order, k)
            return h**order * (param * x_prev + u_prev) - float(np.dot(c[1:], past))

        Pot = Po + Qo
        ro = math.sqrt((1 + lam) * Pot)
        pts = [a, a + ro, a - ro]
        Yo = [model(p, w) for p in pts]
        a_new, Po, Kk, e = ut(a, Pot, pts, Yo, S if r_from_kfx else s["Ro"], y[k])
        a_new = min(max(a_new, s["lo"]), s["hi"])
        Qo = adapt(Qo, Kk, e, s["delta_o"], s["Qmax_o"])
        Pw_prev = Pw
        Pwt = Pw + Qw
        rw = math.sqrt((1 + lam) * Pwt)
        ptw = [w, w + rw, w - rw]
        Yw = [model(a, p) for p in ptw]
        w_new, Pw, Kk, e = ut(w, Pwt, ptw, Yw, S if r_from_kfx else s["Rw"], y[k])
        Qw = adapt(Qw, Kk, e, s["delta_w"], s["Qmax_w"])
        # the sensitivities, as the package's "propagated" setting takes them
        Jo = Wc[1] * ro * (Yo[1] - Yo[2]) / Pot if Pot > 0 else 0.0
        Jw = Wc[1] * rw * (Yw[1] - Yw[2]) / Pwt if Pwt > 0 else 0.0
        c = gl(a_new, k)
        hp = h**a_new
        xp = hp * (w * x_prev + u_prev) - float(np.dot(c[1:], past))
        Q = s["Q"] * hp * hp if s["scaled"] else s["Q"]
        F2 = (hp * w + a_new) ** 2
        Pp = F2 * pastP[0] + Q + float(np.dot(c[2:] ** 2, pastP[1:]))
        Pph = F2 * pastPh[0] + Q + float(np.dot(c[2:] ** 2, pastPh[1:])) + Jo * Jo * Po + Jw * Jw * Pw_prev
        S = Pp + s["R"]
        K = Pp / S
        x = xp + K * (y[k] - xp)
        P = max(Pp - K * S * K, 0.0)
        Ph = (1 - K) ** 2 * Pph + K * K * s["R"]
        a, w = a_new, w_new
        xs.append(x)
        Ps.append(P)
        Phs.append(Ph)
        out_x.append(x)
        out_P.append(P)
        out_Ph.append(Ph)
        out_a.append(a)
        out_Po.append(Po)
    return tuple(np.array(v) for v in (out_x, out_P, out_Ph, out_a, out_Po))


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
                x, P, Ph, a, Po = tea_with_honest_cov(y, None if u is None else u[:, 0].numpy(), tr.h, s, variant[1])
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

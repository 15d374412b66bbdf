"""The TEA with the exact filter as KFx (torchtea.noise.tea_exact): with KFo and KFw frozen it is the likelihood's
Kalman filter to rounding; its first steps are those of the dense state spaces by the obvious path; on grown-model data its
order estimate is unbiased where the paper's KFx's is not; identify and montecarlo run it; every refusal."""
from __future__ import annotations

import math
from dataclasses import replace

import pytest
import torch

from torchtea.core.stats import last_third
from torchtea.engines.settings import TEAConfig
from torchtea.engines.tea import make_params, run_tea
from torchtea.likelihood.kalman import kalman_filter
from torchtea.noise import parse_model, simulate_model
from torchtea.noise.model import state_memory
from torchtea.noise.tea import tea_view
from torchtea.noise.tea_exact import KERNEL_ORDERS, run_tea_exact

H = 0.01
GROWN = "fractional+white+random-walk"
VALUES = {"fractional.order": 0.4, "fractional.pole": -2.0, "fractional.q": 0.02, "white.r": 1e-5,
          "random-walk.sigma": 0.05}
#: grown_model.py's ``constant`` settings: KFo's and KFw's R the innovation covariance, a constant order and pole
CONSTANT = {"R": "innovation", "Q0": 1e-5}


def view_for(spec, values, *, held=False, memory="soe", **kfo):
    v = tea_view(spec, values, H)
    cfg = replace(v.config, memory=replace(v.config.memory, kind=memory), kfx_filter="exact",
                  kfo=replace(v.config.kfo, **dict(CONSTANT, **kfo)), kfw=replace(v.config.kfw, **CONSTANT))
    if held:
        cfg = replace(cfg, kfw=replace(cfg.kfw, P0=0.0, Q0=0.0))
    return replace(v, config=cfg)


def grown_data(realisations, n, seed=5):
    y = simulate_model(GROWN, VALUES, n_steps=n, h=H, realisations=realisations,
                       generator=torch.Generator().manual_seed(seed))[0]
    return y - y.mean(-1, keepdim=True)


def dense_state_space(start, N):
    """The obvious path's model: ``ss(a, f)`` the grown model's whole state space at ``start`` with order a and pole
    f (dense F and Q = G Gᵀ, assembled anew by NoiseModel.state_space), and its C and R."""
    model, mem = parse_model(GROWN), state_memory("soe", N, orders=KERNEL_ORDERS)

    def ss(a, f):
        s = model.state_space(dict(start, **{"fractional.order": a, "fractional.pole": f}), H, N, memory=mem)
        return s.F[0], s.G[0] @ s.G[0].mT

    s0 = model.state_space(start, H, N, memory=mem)
    return ss, s0.C[0], float(s0.R[0])


def test_with_kfo_and_kfw_frozen_kfx_is_the_likelihoods_filter():
    """P0 = Q0 = 0 for both: the order and pole stay at their starts, and KFx's innovations, their variances and the
    view states' estimates are the exact filter's (likelihood.kalman_filter on the same state space) to rounding —
    with a missing sample in one series."""
    y = grown_data(3, 700)
    y[1, 300] = float("nan")
    v = view_for(GROWN, VALUES, held=True, P0=0.0, Q0=0.0)
    res = run_tea_exact(v, y, h=H)
    assert torch.equal(res.alpha, torch.full_like(res.alpha, 0.4)) and torch.equal(res.w, torch.full_like(res.w, -2.0))
    ss = parse_model(GROWN).state_space(VALUES, H, 700, memory=state_memory("soe", 700, orders=KERNEL_ORDERS))
    kf = kalman_filter(ss.expand(3), y, keep_states=True)
    ok = ~torch.isnan(y)
    e, S = res.innovation[..., 0], res.innovation_cov[..., 0, 0]
    assert torch.allclose(e[ok], kf.innovation[ok], rtol=0, atol=1e-12 * float(y[ok].abs().max()))
    assert torch.allclose(S, kf.variance, rtol=1e-12, atol=0)
    assert e[1, 300] == 0.0
    cols = [ss.blocks["fractional"].start, ss.blocks["random-walk"].start]
    assert torch.allclose(res.x, kf.filtered[..., cols], rtol=0, atol=1e-12 * float(y[ok].abs().max()))


def test_the_first_steps_are_the_obvious_paths():
    """Six steps by the obvious path, one series at a time: at every sigma order and pole the model's whole state space
    assembled anew by NoiseModel.state_space (dense F and G), the unscented updates written out (weights, R = KFx's
    S of the step before, adaptation (25) capped at Q0), and the exact filter's prediction at α̂_k, ŵ_{k−1}: α̂, ŵ,
    the innovations and their variances of run_tea_exact to rounding, from starts away from the truth."""
    N, steps = 40, 6
    y = grown_data(2, N, seed=8)
    start = dict(VALUES, **{"fractional.order": 0.3, "fractional.pole": -1.5})
    v = view_for(GROWN, start, P0=2e-3)
    v = replace(v, config=replace(v.config, kfw=replace(v.config.kfw, P0=0.05, Q0=1e-3)))
    res = run_tea_exact(v, y, h=H)
    ko, kw = v.config.kfo, v.config.kfw
    ss, C, r = dense_state_space(start, N)
    wm = [2 / 3, 1 / 6, 1 / 6]  # L = 1, ut_alpha 1, kappa 3 − L: λ = 2
    wc = [2 / 3 + 2, 1 / 6, 1 / 6]

    def ukf(mean, P, Q, delta, predict, yk, S_prev, q_max):
        d = math.sqrt(3 * (P + Q))
        pts = [mean, mean + d, mean - d]
        Y = [predict(p) for p in pts]
        yp = sum(w * u for w, u in zip(wm, Y))
        Pyy = sum(w * (u - yp) ** 2 for w, u in zip(wc, Y)) + S_prev
        Pxy = sum(w * (p - mean) * (u - yp) for w, p, u in zip(wc, pts, Y))
        K = Pxy / Pyy
        return mean + K * (yk - yp), P + Q - K * K * Pyy, min((1 - delta) * Q + delta * (K * (yk - yp)) ** 2, q_max)

    for i in range(2):
        z = torch.zeros(C.shape[0], dtype=torch.float64)
        P = torch.zeros(C.shape[0], C.shape[0], dtype=torch.float64)
        a, Pa, Qa, w, Pw, Qw, S = 0.3, ko.P0, ko.Q0, -1.5, kw.P0, kw.Q0, None
        for k in range(steps):
            yk = float(y[i, k])
            if k == 0:
                zp, Pp = z, P
            else:
                a1, Pa, Qa = ukf(a, Pa, Qa, ko.delta, lambda o: float(C @ ss(o, w)[0] @ z), yk, S, ko.Q0)
                w, Pw, Qw = ukf(w, Pw, Qw, kw.delta, lambda f: float(C @ ss(a, f)[0] @ z), yk, S, kw.Q0)
                a = min(max(a1, v.config.order_bounds[0]), v.config.order_bounds[1])
                F, Q = ss(a, float(res.w[i, k - 1, 0]))  # KFx at α̂_k and ŵ_{k−1}
                zp, Pp = F @ z, F @ P @ F.mT + Q
            S = float(C @ Pp @ C) + r
            e = yk - float(C @ zp)
            K = Pp @ C / S
            z, P = zp + K * e, Pp - torch.outer(K, K) * S
            assert math.isclose(float(res.alpha[i, k, 0]), a, rel_tol=1e-12), (i, k)
            assert math.isclose(float(res.w[i, k, 0]), w, rel_tol=1e-12), (i, k)
            assert math.isclose(float(res.innovation_cov[i, k, 0, 0]), S, rel_tol=1e-12), (i, k)
            assert math.isclose(float(res.innovation[i, k, 0]), e, rel_tol=1e-10, abs_tol=1e-15), (i, k)
    # the order and pole moved (by 9e-5 … 3e-3 here): the check is not of a filter at rest
    assert float((res.alpha[:, steps - 1, 0] - 0.3).abs().min()) > 1e-5
    assert float((res.w[:, steps - 1, 0] + 1.5).abs().min()) > 1e-5


def test_the_joint_filters_first_steps_are_the_obvious_paths():
    """kfo_kfw = "joint": one unscented filter over (order, pole), written out for five steps with the textbook weights
    of two dimensions, a Cholesky root for the sigma points, the model's dense state space at every sigma point,
    adaptation capped at the larger Q0, and KFx at α̂_k and ŵ_k: run_tea_exact's α̂, ŵ and innovations to rounding."""
    N, steps = 40, 5
    y = grown_data(2, N, seed=9)
    start = dict(VALUES, **{"fractional.order": 0.3, "fractional.pole": -1.5})
    v = view_for(GROWN, start, P0=2e-3)
    cfg = replace(v.config, kfo_kfw="joint", kfw=replace(v.config.kfw, P0=0.05, Q0=1e-3))
    res = run_tea_exact(replace(v, config=cfg), y, h=H)
    ko, kw = cfg.kfo, cfg.kfw
    lam = 1.0 * (2 + 1) - 2  # ut_alpha² (L + κ) − L with L = 2, κ = 3 − L
    wm = torch.tensor([lam / (2 + lam)] + [1 / (2 * (2 + lam))] * 4, dtype=torch.float64)
    wc = wm.clone()
    wc[0] += 1 - 1.0 + 2.0  # + 1 − ut_alpha² + β
    q_max = max(ko.Q0, kw.Q0)
    ss, C, r = dense_state_space(start, N)
    for i in range(2):
        z = torch.zeros(C.shape[0], dtype=torch.float64)
        P = torch.zeros(C.shape[0], C.shape[0], dtype=torch.float64)
        th = torch.tensor([0.3, -1.5], dtype=torch.float64)
        Pt = torch.diag(torch.tensor([ko.P0, kw.P0], dtype=torch.float64))
        Qt = torch.diag(torch.tensor([ko.Q0, kw.Q0], dtype=torch.float64))
        S = None
        for k in range(steps):
            yk = float(y[i, k])
            if k == 0:
                zp, Pp = z, P
            else:
                L = torch.linalg.cholesky(3 * (Pt + Qt))  # scale L + λ = 3
                pts = [th] + [th + L[:, j] for j in range(2)] + [th - L[:, j] for j in range(2)]
                Y = torch.tensor([float(C @ ss(float(p[0]), float(p[1]))[0] @ z) for p in pts], dtype=torch.float64)
                yp = float(wm @ Y)
                Pyy = float(wc @ (Y - yp) ** 2) + S
                Pxy = sum(wc[j] * (pts[j] - th) * (Y[j] - yp) for j in range(5))
                K = Pxy / Pyy
                th, Pt = th + K * (yk - yp), Pt + Qt - torch.outer(K, K) * Pyy
                Qn = (1 - ko.delta) * Qt + ko.delta * torch.outer(K, K) * (yk - yp) ** 2
                Qt = Qn * min(1.0, q_max / float(Qn.diagonal().max()))
                th[0] = min(max(float(th[0]), cfg.order_bounds[0]), cfg.order_bounds[1])
                F, Q = ss(float(th[0]), float(th[1]))  # KFx at α̂_k and ŵ_k
                zp, Pp = F @ z, F @ P @ F.mT + Q
            S = float(C @ Pp @ C) + r
            e = yk - float(C @ zp)
            Kx = Pp @ C / S
            z, P = zp + Kx * e, Pp - torch.outer(Kx, Kx) * S
            assert math.isclose(float(res.alpha[i, k, 0]), float(th[0]), rel_tol=1e-11), (i, k)
            assert math.isclose(float(res.w[i, k, 0]), float(th[1]), rel_tol=1e-11), (i, k)
            assert math.isclose(float(res.P_w[i, k, 0, 0]), float(Pt[1, 1]), rel_tol=1e-9), (i, k)
            assert math.isclose(float(res.P_alpha[i, k, 0, 0]), float(Pt[0, 0]), rel_tol=1e-9), (i, k)
            assert math.isclose(float(res.Q_alpha[i, k, 0, 0]), float(Qt[0, 0]), rel_tol=1e-9), (i, k)
            assert math.isclose(float(res.Q_w[i, k, 0, 0]), float(Qt[1, 1]), rel_tol=1e-9), (i, k)
            assert math.isclose(float(res.innovation_cov[i, k, 0, 0]), S, rel_tol=1e-11), (i, k)
            assert math.isclose(float(res.innovation[i, k, 0]), e, rel_tol=1e-9, abs_tol=1e-15), (i, k)
    assert float((res.alpha[:, steps - 1, 0] - 0.3).abs().min()) > 1e-5
    assert float((res.w[:, steps - 1, 0] + 1.5).abs().min()) > 1e-5


def test_joint_refusals():
    """kfo_kfw 'joint' only with the exact KFx (at the settings' construction, so run_tea, which refuses the exact
    KFx, never runs it), and with KFw's filter settings equal to KFo's, which the one filter takes."""
    with pytest.raises(ValueError, match="kfx_filter 'exact' only"):
        TEAConfig(kfo_kfw="joint")
    with pytest.raises(ValueError, match="kfo_kfw must be"):
        TEAConfig(kfo_kfw="both")
    v = view_for(GROWN, VALUES)
    cfg = replace(v.config, kfo_kfw="joint", kfw=replace(v.config.kfw, delta=0.1, R=1e-3))
    with pytest.raises(ValueError, match="KFo's delta, R; KFw's differ"):
        run_tea_exact(replace(v, config=cfg), grown_data(1, 50), h=H)
    with pytest.raises(ValueError, match="kfx_filter 'exact'"):
        run_tea(grown_data(1, 50).unsqueeze(-1), h=H, params=make_params(replace(v.config, kfo_kfw="joint"),
                                                                        v.structure), structure=v.structure)


def test_identify_runs_each_channel_through_the_exact_kfx():
    """identify with ``kfx_filter = "exact"`` in its overrides: soe memory chosen for it, each channel's result that
    of run_tea_exact on the channel's own view and series; refused without a model (r_mode measured) and with a
    covariance setting that does not apply, before anything runs."""
    from torchtea.fitting import fit_series
    from torchtea.identification import identify
    from torchtea.sensors.io import read_recording
    from torchtea.sensors.measurements import prepare

    m = prepare(read_recording(columns=["ax", "az"]), samples=500)
    y = [c.values - c.values.mean() for c in m.channels]
    fits = fit_series(GROWN, y, m.recording.h, method="whittle")
    over = {"kfx_filter": "exact", "kfo": CONSTANT, "kfw": CONSTANT}
    ident = identify(m, model=GROWN, overrides=over, fits=fits)
    assert all(c.memory.kind == "soe" and c.kfx_filter == "exact" for c in ident.configs)
    for i in range(2):
        direct = run_tea_exact(replace(ident.views[i], config=ident.configs[i]), ident.y[i, :, 0], h=m.recording.h)
        for f in ("alpha", "w", "x", "innovation", "innovation_cov"):  # one batch: products round in the last bits
            torch.testing.assert_close(getattr(ident.result, f)[i], getattr(direct, f)[0], rtol=1e-12, atol=1e-15)
    with pytest.raises(ValueError, match="r_mode 'fitted'"):
        identify(m, r_mode="measured", overrides={"kfx_filter": "exact"})
    with pytest.raises(ValueError, match="do not apply"):
        identify(m, model=GROWN, overrides=dict(over, estimate_uncertainty="constant-truth"), fits=fits)


def test_progress_and_ctrl_c_keep_the_finished_steps():
    """progress(k, N) as run_tea calls it; a Ctrl-C with partial=True returns the finished steps, the full run's to
    the bit, interrupted, with the clamp count of those steps only; without partial it raises."""
    y = grown_data(2, 400)
    v = view_for(GROWN, VALUES, P0=1.0)  # KFo's first sigma orders leave the kernel's range: clamped steps
    calls = []
    full = run_tea_exact(v, y, h=H, progress=lambda k, n: calls.append((k, n)))
    assert calls[0] == (0, 400) and calls[-1] == (399, 400) and [k for k, _ in calls] == sorted(k for k, _ in calls)
    assert not full.interrupted and full.alpha.shape[-2] == 400

    def stop(k, n):
        if k == 128:
            raise KeyboardInterrupt

    cut = run_tea_exact(v, y, h=H, progress=stop, partial=True)
    assert cut.interrupted and cut.alpha.shape[-2] == 129 and torch.equal(cut.steps, torch.arange(129))
    for name in ("x", "P", "alpha", "P_alpha", "w", "innovation", "innovation_cov"):
        assert torch.equal(getattr(cut, name), getattr(full, name)[:, :129]), name
    # the clamp count of steps 1 … 128, rebuilt from the outputs: KFo's sigma orders (from step k − 1's α̂, Pᵒ, Qᵒ)
    # or α̂_k outside the kernel's range
    lo_k, hi_k = state_memory(v.config.memory, 400, orders=KERNEL_ORDERS).kernel.order_range
    a, spread = full.alpha[:, :, 0], (3 * (full.P_alpha + full.Q_alpha)[:, :, 0, 0]).sqrt()  # scale L + λ = 3
    out = ((a[:, :128] - spread[:, :128]) < lo_k) | ((a[:, :128] + spread[:, :128]) > hi_k) \
        | (a[:, 1:129] < lo_k) | (a[:, 1:129] > hi_k)
    assert torch.equal(cut.memory_clamped, out.sum(-1)) and int(cut.memory_clamped.min()) > 0
    with pytest.raises(KeyboardInterrupt):
        run_tea_exact(v, y, h=H, progress=stop)

    def at_once(k, n):
        raise KeyboardInterrupt

    none = run_tea_exact(v, y, h=H, progress=at_once, partial=True)  # before step 0 finished: nothing kept
    assert none.interrupted and none.alpha.shape[-2] == 0 and not none.diverged.any()


def test_identify_batches_channels_of_one_model_reports_progress_and_keeps_a_ctrl_c():
    """Channels of one model run as one batch (progress counts one channel's steps; each result that of its own run,
    test_identify_runs_each_channel_through_the_exact_kfx); channels of two models run one after another: progress
    counts the steps of both, and a Ctrl-C in the first keeps its finished steps while the second runs those samples
    only (its own run of that length)."""
    from torchtea.fitting import fit_series
    from torchtea.identification import identify
    from torchtea.sensors.io import read_recording
    from torchtea.sensors.measurements import prepare

    m = prepare(read_recording(columns=["ax", "az"]), samples=300)
    y = [c.values - c.values.mean() for c in m.channels]
    over = {"kfx_filter": "exact", "kfo": CONSTANT, "kfw": CONSTANT}
    calls = []
    identify(m, model=GROWN, overrides=over, fits=fit_series(GROWN, y, m.recording.h, method="whittle"),
             progress=lambda d, t: calls.append((d, t)))
    assert {t for _, t in calls} == {299} and calls[-1] == (299, 299)  # one batch

    fits = (fit_series(GROWN, y[:1], m.recording.h, method="whittle")
            + fit_series("fractional+white", y[1:], m.recording.h, method="whittle"))
    calls = []
    identify(m, overrides=over, fits=fits, progress=lambda d, t: calls.append((d, t)))
    assert {t for _, t in calls} == {2 * 299} and calls[-1] == (598, 598)  # two batches, one after another
    assert [d for d, _ in calls] == sorted(d for d, _ in calls)

    seen = []

    def stop(d, t):
        seen.append(d)
        if d == 128 and seen.count(128) == 1:  # once, in the first channel
            raise KeyboardInterrupt

    ident = identify(m, overrides=over, fits=fits, progress=stop, partial=True)
    assert ident.result.interrupted and ident.result.alpha.shape[-2] == 129
    assert seen[-1] == 128 + 128  # the second batch counted on from the 128 steps the first finished
    second = run_tea_exact(replace(ident.views[1], config=ident.configs[1]), ident.y[1, :129, 0], h=m.recording.h)
    assert torch.equal(ident.result.alpha[1], second.alpha[0])


def test_a_batch_of_views_is_each_views_own_run():
    """Views of one model with other values and settings (q, walk, order start, bounds, R numbers) run as one batch:
    each series' estimates are its own run's (to the last bits: the batch's products may round differently); views
    that differ in batch_key are refused by name."""
    y = grown_data(2, 600)
    y[1, 50:60] = float("nan")
    v1 = view_for(GROWN, VALUES)
    v2 = view_for(GROWN, dict(VALUES, **{"fractional.q": 0.05, "random-walk.sigma": 0.02}))
    cfg = v2.config
    v2 = replace(v2, config=replace(cfg, order_bounds=(0.1, 0.95), kfo=replace(cfg.kfo, x0=0.5, R=2e-3)))
    v1 = replace(v1, config=replace(v1.config, kfo=replace(v1.config.kfo, R=1e-3)))
    both = run_tea_exact([v1, v2], y, h=H)
    for i, v in enumerate((v1, v2)):
        one = run_tea_exact(v, y[i], h=H)
        for f in ("x", "P", "alpha", "w", "innovation", "innovation_cov", "P_alpha", "Q_w"):
            torch.testing.assert_close(getattr(both, f)[i], getattr(one, f)[0], rtol=1e-12, atol=1e-15, msg=f)
    assert not torch.equal(both.alpha[0], both.alpha[1])
    joint = [replace(u, config=replace(u.config, kfo_kfw="joint", kfw=replace(u.config.kfw, R=u.config.kfo.R)))
             for u in (v1, v2)]
    both = run_tea_exact(joint, y, h=H)
    for i, v in enumerate(joint):
        one = run_tea_exact(v, y[i], h=H)
        for f in ("alpha", "w", "P_alpha", "P_w", "innovation"):
            torch.testing.assert_close(getattr(both, f)[i], getattr(one, f)[0], rtol=1e-12, atol=1e-15, msg=f)
    with pytest.raises(ValueError, match="batch_key"):
        run_tea_exact([v1, view_for("fractional+white", VALUES)], y, h=H)
    with pytest.raises(ValueError, match="one per series"):
        run_tea_exact([v1, v2], grown_data(3, 100), h=H)


@pytest.mark.slow
def test_the_exact_kfx_estimates_the_order_the_paper_kfx_misses():
    """Walk σ 0.05, pole held, 16 realisations × 6000 steps under the ``constant`` settings: the paper's KFx puts α̂
    below the truth (−0.012 in experiments/tea_models, sd 0.006), the exact filter's is within 3 standard errors of
    its own spread of 0.4; the plain model's view, blind to the walk, is far off under either KFx."""
    y = grown_data(16, 6000)
    sl = last_third(6000)
    exact = run_tea_exact(view_for(GROWN, VALUES, held=True), y, h=H).alpha[:, sl, 0].mean(-1)
    se = float(exact.std() / math.sqrt(16))
    assert abs(float(exact.mean()) - 0.4) < 3 * se, (float(exact.mean()), se)
    pv = view_for(GROWN, VALUES, held=True)
    cfg = replace(pv.config, kfx_filter="paper")
    paper = run_tea(y.unsqueeze(-1), h=H, params=make_params(cfg, pv.structure),
                    structure=pv.structure).alpha[:, sl, 0].mean(-1)
    assert float(paper.mean()) - 0.4 < -3 * float(paper.std() / math.sqrt(16))
    plain = {k: v for k, v in VALUES.items() if not k.startswith("random-walk")}
    blind = run_tea_exact(view_for("fractional+white", plain, held=True), y, h=H).alpha[:, sl, 0].mean(-1)
    assert float(blind.mean()) - 0.4 > 0.25


def test_what_the_exact_kfx_refuses_is_refused_by_name():
    v = view_for(GROWN, VALUES)
    with pytest.raises(ValueError, match="kfx_filter must be one of"):
        TEAConfig(kfx_filter="smoother")
    with pytest.raises(ValueError, match="run_tea_exact"):
        run_tea(torch.zeros(1, 10, 1), h=H, params=make_params(v.config, v.structure), structure=v.structure)
    with pytest.raises(ValueError, match="not 'exact'"):
        run_tea_exact(view_for(GROWN, VALUES, memory="exact"), torch.zeros(10), h=H)
    with pytest.raises(ValueError, match="do not apply"):
        run_tea_exact(replace(v, config=replace(v.config, estimate_uncertainty="constant-truth")), torch.zeros(10), h=H)
    with pytest.raises(ValueError, match="a number or 'innovation'"):
        run_tea_exact(replace(v, config=replace(v.config, kfo=replace(v.config.kfo, R=[[1.0, 0.0], [0.0, 1.0]]))),
                      torch.zeros(10), h=H)
    with pytest.raises(ValueError, match="order modifier"):
        tv = tea_view(GROWN + "+temperature-order", dict(VALUES, **{"temperature-order.order_per_degC": 0.0,
                                                                      "temperature-order.t_ref": 20.0}), H)
        run_tea_exact(replace(tv, config=v.config), torch.zeros(10), h=H)
    # the adaptation's cap as the TEA reads it: "none" (no cap) and a number
    for cap in ("none", 1e-4):
        cfg = replace(v.config, kfo=replace(v.config.kfo, Q_max=cap), kfw=replace(v.config.kfw, Q_max=cap))
        assert run_tea_exact(replace(v, config=cfg), grown_data(1, 50)[0], h=H).alpha.isfinite().all()


def test_montecarlo_runs_the_exact_kfx_and_refuses_what_it_cannot():
    """A study with ``kfx_filter = "exact"`` runs each chunk through the exact-KFx TEA: the same estimates as calling
    it on the study's own realisations; a paper truth, a consistent prior or exact memory is refused at load."""
    from torchtea.studies.montecarlo import build_study, estimator_view, run_range, simulate_model_truth

    data = {"realisations": 4, "seed": 3, "chunk": 2,
            "truth": {"model": GROWN, "h": H, "n": 600, "values": VALUES},
            "estimator": {"preset": "paper-mems-x", "memory": {"kind": "soe"}, "kfx_filter": "exact",
                          "kfo": CONSTANT, "kfw": CONSTANT}}
    study, _ = build_study(data)
    result = run_range(study, 0, 4, trajectories=True)
    view = estimator_view(study)
    sim = simulate_model_truth(study, view, range(2, 4))
    direct = run_tea_exact(view, sim.y[..., 0], h=H)
    assert torch.allclose(result.trajectories["alpha"][2:], direct.alpha[..., 0], rtol=0, atol=1e-14)
    for change, what in (({"prior": "consistent"}, "prior 'preset'"),
                         ({"estimator": dict(data["estimator"], memory={"kind": "exact"})}, "not 'exact'"),
                         ({"estimator": dict(data["estimator"], estimate_uncertainty="constant-truth")}, "do not apply"),
                         ({"truth": {"h": H, "n": 600, "order": 0.4, "param": -2.0, "q": 0.02, "r": 1e-5}}, "model truth")):
        with pytest.raises(ValueError, match=what):
            build_study(dict(data, **change))

"""TEA: batched PyTorch and the compiled scalar engine against the scalar NumPy reference, sigma batching, guards,
Example 1."""
import math

import numpy as np
import pytest
import torch

from torchtea.engines.history import _ExactMemory
from torchtea.engines.presets import SCENARIOS, get_preset
from torchtea.engines.settings import TEAConfig
from torchtea.engines.structure import ConstantOrder, Structure
from torchtea.engines.tea import _Model, _replica, make_params, run_tea, sigma_points, stack_params, ut_weights
from torchtea.noise.simulate import gaussian_input, simulate

from .reference_tea import settings_from_config, tea_reference

FIELDS = {"x": "x", "P": "P", "a": "alpha", "Po": "P_alpha", "Qo": "Q_alpha", "w": "w", "Pw": "P_w",
          "Qw": "Q_w", "e": "innovation", "S": "innovation_cov"}


def _data(batch_shape, n=240, seed=0, order=None):
    g = torch.Generator().manual_seed(seed)
    u = gaussian_input(batch_shape, n, 1, 1.0, generator=g)
    sim = simulate(Structure(), n_steps=n, h=1e-3, order=order or ConstantOrder(0.35), parameters=[-1.0],
                   process_noise=1e-4, measurement_noise=1e-3, inputs=u, batch_shape=batch_shape, generator=g)
    return sim, u


VARIANTS = {
    "torchtea-defaults": {},
    # everything read as printed (sums from i = 1, unscaled Q in (31), (25) uncapped); these settings
    # diverge often (experiments/paper), so this case uses data on which they stay finite (seed 101, found
    # by search): a run that is about to diverge is chaotic and amplifies rounding beyond any fixed tolerance
    "as-printed": {"sigma_sum_start": 1, "noise_scaling": "unscaled", "kfo": {"Q_max": "none"},
                   "kfw": {"Q_max": "none"}},
    "printed-sums": {"sigma_sum_start": 1},
    "unscaled-noise": {"noise_scaling": "unscaled"},
    "capped-q": {"kfo": {"Q_max": 0.05}, "kfw": {"Q_max": 0.02}, "order_bounds": [0.1, 0.9]},
    "fixed-q": {"kfo": {"delta": 0.0}, "kfw": {"delta": 0.0, "ut_alpha": 0.5, "kappa": 1.0}},
}


@pytest.mark.parametrize("engine", ["torch", "numba"])
@pytest.mark.parametrize("batch_shape", [(), (5,), (2, 4)])
@pytest.mark.parametrize("variant", list(VARIANTS))
def test_batched_matches_scalar_reference(batch_shape, variant, engine):
    """The paper's filters (kfx_uncertainty = "paper"), every field against the reference loop."""
    cfg = TEAConfig.from_dict({**VARIANTS[variant], "kfx_uncertainty": "paper"}, get_preset("paper-example1"))
    y, u, res = _reference_case(cfg, variant, batch_shape, engine)
    assert res.x.shape == batch_shape + (240, 1)
    assert res.P.shape == batch_shape + (240, 1, 1)
    assert res.alpha.shape == batch_shape + (240, 1)
    assert res.diverged.shape == batch_shape
    s = settings_from_config(cfg)
    yf, uf = y.reshape(-1, 240), u.reshape(-1, 240)
    for i in range(yf.shape[0]):
        ref = tea_reference(yf[i].numpy(), uf[i].numpy(), 1e-3, s)
        for rk, name in FIELDS.items():
            got = getattr(res, name).reshape(-1, 240)[i].numpy()
            np.testing.assert_allclose(got, ref[rk], rtol=1e-10, atol=1e-10, err_msg=f"{name} realisation {i}")
    assert not res.diverged.any()


def _reference_case(cfg, variant, batch_shape, engine):
    base_seed = 101 if variant == "as-printed" else 7 * len(variant)
    sim, u = _data(batch_shape, seed=base_seed + len(batch_shape))
    y = sim.y.clone()
    y[..., 50:53, :] = float("nan")  # a gap: predict without update
    return y, u, run_tea(y, h=1e-3, params=make_params(cfg, Structure()), inputs=u, engine=engine)


@pytest.mark.parametrize("engine", ["torch", "numba"])
@pytest.mark.parametrize("variant", list(VARIANTS))
def test_default_kfx_setting_matches_the_reference_loops_honest_covariance(variant, engine):
    """The default (kfx_uncertainty = "paper-gain"): the paper's estimates, innovations and KFo/KFw covariances, with
    P and S the reference loop's covariance of that filter's error (``honest``)."""
    cfg = TEAConfig.from_dict(VARIANTS[variant], get_preset("paper-example1"))
    assert cfg.kfx_uncertainty == "paper-gain"
    y, u, res = _reference_case(cfg, variant, (3,), engine)
    s = settings_from_config(cfg)
    for i in range(3):
        ref = tea_reference(y[i, :, 0].numpy(), u[i, :, 0].numpy(), 1e-3, s, honest=True)
        for rk, name in {**FIELDS, "P": "P", "S": "innovation_cov"}.items():
            got = getattr(res, name)[i].reshape(240).numpy()
            want = ref[{"P": "Ph", "S": "Sh"}.get(rk, rk)]
            np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-10, err_msg=f"{name} realisation {i}")
    assert not res.diverged.any()


def test_stacked_params_per_axis_match_separate_runs():
    sim, u = _data((3,), n=150, seed=3)
    cfgs = [TEAConfig.from_dict({"kfx": {"R": r}, "kfo": {"R": r}, "kfw": {"R": r}}, get_preset("paper-example1"))
            for r in (1e-3, 1.5e-3, 2e-3)]
    # (With R = 4e-4 on these data KFo turns erratic — α̂ jumps between 0.2 and 2 — and rounding-level
    # differences of batched kernels grow exponentially; that run is a poor test of stacking.)
    stacked = stack_params([make_params(c, Structure()) for c in cfgs])
    res = run_tea(sim.y, h=1e-3, params=stacked, inputs=u)
    for i, c in enumerate(cfgs):
        one = run_tea(sim.y[i], h=1e-3, params=make_params(c, Structure()), inputs=u[i])
        torch.testing.assert_close(res.alpha[i], one.alpha, rtol=1e-10, atol=1e-12)
        torch.testing.assert_close(res.w[i], one.w, rtol=1e-10, atol=1e-12)


def test_stack_rejects_different_options():
    a = make_params(get_preset("paper-example1"), Structure())
    b = make_params(TEAConfig.from_dict({"sigma_sum_start": 1}, get_preset("paper-example1")), Structure())
    with pytest.raises(ValueError, match="may differ only"):
        stack_params([a, b])


def test_sigma_points_batched_equal_one_at_a_time():
    """The replica on all KFo + KFw sigma points at once equals evaluating each point alone."""
    g = torch.Generator().manual_seed(5)
    B, n, k = (2, 3), 1, 40
    model = _Model(Structure(), torch.tensor(0.01, dtype=torch.float64), torch.ones(1, 1, dtype=torch.float64),
                   torch.ones(1, 1, dtype=torch.float64))
    xh = torch.randn(B + (n, k), generator=g, dtype=torch.float64)
    x_prev = xh[..., 0]
    u_prev = torch.randn(B + (1,), generator=g, dtype=torch.float64)
    alpha = 0.3 + 0.1 * torch.rand(B + (1,), generator=g, dtype=torch.float64)
    w = -1.0 + 0.2 * torch.randn(B + (1,), generator=g, dtype=torch.float64)
    sig_o = sigma_points(alpha, torch.full(B + (1, 1), 0.05, dtype=torch.float64), 3.0)
    sig_w = sigma_points(w, torch.full(B + (1, 1), 0.2, dtype=torch.float64), 3.0)
    Y, chi = _replica(model, _ExactMemory(), (xh, None), sig_o, w, sig_w, x_prev, u_prev)
    assert Y.shape == B + (6, 1) and torch.equal(chi, Y)  # C = 1: the outputs are the states
    for i in range(3):
        one_o = _replica(model, _ExactMemory(), (xh, None), sig_o[..., i : i + 1, :], w, sig_w[..., :1, :], x_prev, u_prev)[0]
        torch.testing.assert_close(Y[..., i, :], one_o[..., 0, :], rtol=0, atol=1e-14)
        one_w = _replica(model, _ExactMemory(), (xh, None), sig_o[..., :1, :], w, sig_w[..., i : i + 1, :], x_prev, u_prev)[0]
        torch.testing.assert_close(Y[..., 3 + i, :], one_w[..., 1, :], rtol=0, atol=1e-14)
    # and each equals the model formula written out, (17) and (42)
    from torchtea.core.gl import gl_coefficients
    for i in range(3):
        a_i = sig_o[..., i, 0]
        c = gl_coefficients(a_i, k)[..., 1:]
        direct = 0.01 ** a_i * (w[..., 0] * x_prev[..., 0] + u_prev[..., 0]) - (c * xh[..., 0, :]).sum(-1)
        torch.testing.assert_close(Y[..., i, 0], direct, rtol=1e-13, atol=1e-14)


def test_ut_weights_paper_values():
    wm, wc, s = ut_weights(1, 1.0, 2.0, None)
    # L = 1, 𝔄 = 1, κ = 2: λ = 2, sigma points α̃ ± √(3 P̃)
    assert s == 3.0
    torch.testing.assert_close(wm, torch.tensor([2 / 3, 1 / 6, 1 / 6], dtype=torch.float64))
    torch.testing.assert_close(wc, torch.tensor([2 / 3 + 2, 1 / 6, 1 / 6], dtype=torch.float64))
    assert math.isclose(float(wm.sum()), 1.0)


def test_kfw_on_linear_replica_equals_linear_kalman_update():
    """The replica is linear in w, so one KFw step must equal the plain KF update on w."""
    cfg = TEAConfig.from_dict({"kfo": {"P0": 1e-30, "Q0": 0.0, "delta": 0.0}}, get_preset("paper-example1"))
    sim, u = _data((), n=2, seed=11)
    res = run_tea(sim.y, h=1e-3, params=make_params(cfg, Structure()), inputs=u)
    x0 = float(res.x[0, 0])
    a0 = float(cfg.kfo.x0)
    hp = 1e-3**a0
    Pt = cfg.kfw.P0 + cfg.kfw.Q0
    H = hp * x0  # dY/dw
    y_pred = hp * (cfg.kfw.x0 * x0 + float(u[0, 0])) - (-a0) * x0  # c_1 = −α
    S = H * Pt * H + cfg.kfw.R
    K = Pt * H / S
    w1 = cfg.kfw.x0 + K * (float(sim.y[1, 0]) - y_pred)
    assert float(res.w[1, 0]) == pytest.approx(w1, rel=1e-9)
    assert float(res.P_w[1, 0, 0]) == pytest.approx(Pt - K * S * K, rel=1e-9)


def test_all_missing_keeps_priors_and_predicts():
    cfg = get_preset("paper-example1")
    sim, u = _data((2,), n=30, seed=2)
    y = torch.full_like(sim.y, float("nan"))
    res = run_tea(y, h=1e-3, params=make_params(cfg, Structure()), inputs=u)
    assert torch.all(res.alpha == cfg.kfo.x0)
    assert torch.all(res.w == cfg.kfw.x0)
    assert torch.all(res.innovation == 0)
    assert torch.all(torch.isfinite(res.x))
    # covariance grows without measurements
    assert torch.all(res.P[:, -1] > res.P[:, 1])


def test_divergent_realisation_is_flagged_frozen_and_isolated():
    cfg = get_preset("paper-example1")
    sim, u = _data((4,), n=120, seed=4)
    y = sim.y.clone()
    y[2, 60:, :] = 1e12  # one corrupt realisation
    res = run_tea(y, h=1e-3, params=make_params(cfg, Structure()), inputs=u)
    assert res.diverged.tolist() == [False, False, True, False]
    k = int(res.diverged_at[2])
    assert 60 <= k < 120
    assert torch.all(torch.isfinite(res.x)) and torch.all(torch.isfinite(res.alpha))
    # frozen after the flag: the last good values are kept
    assert torch.all(res.alpha[2, k:] == res.alpha[2, k - 1])
    # the others are bit-for-bit what they are in the same batch without the corrupt data
    clean = run_tea(sim.y, h=1e-3, params=make_params(cfg, Structure()), inputs=u)
    for i in (0, 1, 3):
        for name in ("x", "P", "alpha", "w", "innovation"):
            torch.testing.assert_close(getattr(res, name)[i], getattr(clean, name)[i], rtol=0, atol=0)


def test_order_estimate_respects_bounds():
    """The projection onto order_bounds is active (the free run leaves [0.5, 0.6]) and exact: every bounded
    estimate after k = 0 lies in the interval, and the bounds are reached."""
    base = get_preset("paper-example1")
    cfg = TEAConfig.from_dict({"order_bounds": [0.5, 0.6]}, base)
    sim, u = _data((3,), n=200, seed=6)
    free = run_tea(sim.y, h=1e-3, params=make_params(base, Structure()), inputs=u)
    res = run_tea(sim.y, h=1e-3, params=make_params(cfg, Structure()), inputs=u)
    assert float(free.alpha[:, 1:].min()) < 0.5 or float(free.alpha[:, 1:].max()) > 0.6  # the bounds have work to do
    a = res.alpha[:, 1:]
    assert float(a.min()) >= 0.5 and float(a.max()) <= 0.6
    assert bool(((a == 0.5) | (a == 0.6)).any())  # projected onto the bound itself, not near it


def test_config_roundtrip_and_errors():
    cfg = get_preset("paper-mems-z")
    assert TEAConfig.from_dict(cfg.to_dict(), TEAConfig()) == cfg
    with pytest.raises(ValueError, match="unknown TEA settings"):
        TEAConfig.from_dict({"kfz": {}})
    with pytest.raises(ValueError, match=r"unknown settings in \[kfo\]"):
        TEAConfig.from_dict({"kfo": {"gain": 1}})
    with pytest.raises(ValueError, match="sigma_sum_start"):
        TEAConfig(sigma_sum_start=2)


def test_vector_state_with_fixed_integer_order_runs_and_matches_scalar_when_decoupled():
    """Two decoupled states (fractional + a fixed order-1 bias) leave the fractional estimate as in the scalar run
    when the bias state is unobserved — the structure and NaN paths of the vector code."""
    sim, u = _data((), n=100, seed=9)
    cfg = get_preset("paper-example1")
    st = Structure(
        A=__import__("torchtea.engines.structure", fromlist=["ParametricMatrix"]).ParametricMatrix(
            torch.zeros(2, 2, dtype=torch.float64), torch.tensor([[[1.0, 0.0], [0.0, 0.0]]], dtype=torch.float64)),
        B=torch.tensor([[1.0], [0.0]], dtype=torch.float64),
        C=torch.eye(2, dtype=torch.float64),
        estimated=(True, False), fixed_orders=torch.tensor([0.0, 1.0], dtype=torch.float64))
    vcfg = TEAConfig.from_dict({"kfx": {"x0": [0.0, 0.0], "P0": [0.01, 0.01], "Q0": [1e-4, 1e-6],
                                        "R": [1e-3, 1e-3]}, "kfo": {"R": [1e-3, 1e-3]},
                                "kfw": {"R": [1e-3, 1e-3]}}, cfg)
    y2 = torch.cat([sim.y, torch.full_like(sim.y, float("nan"))], dim=-1)
    res = run_tea(y2, h=1e-3, params=make_params(vcfg, st), structure=st, inputs=u)
    one = run_tea(sim.y, h=1e-3, params=make_params(cfg, Structure()), inputs=u)
    assert res.x.shape == (100, 2) and res.alpha.shape == (100, 1)
    torch.testing.assert_close(res.alpha, one.alpha, rtol=1e-10, atol=1e-12)
    torch.testing.assert_close(res.x[:, :1], one.x, rtol=1e-10, atol=1e-12)


@pytest.mark.slow
def test_example1_seeded_order_within_0p02():
    """Paper Example 1 (α = 0.35, f = −1, 6000 samples): mean α̂ over the last second within 0.02.

    Over 50 seeds (experiments/paper) the per-run |mean α̂(5–6 s) − 0.35| stays far below 0.02.
    """
    sc = SCENARIOS["paper-example1"]
    g = torch.Generator().manual_seed(2022)
    u = gaussian_input((), sc.n_steps, 1, sc.input_std, generator=g)
    sim = simulate(Structure(), n_steps=sc.n_steps, h=sc.h, order=sc.order, parameters=[sc.param],
                   process_noise=sc.q, measurement_noise=sc.r, inputs=u, generator=g)
    res = run_tea(sim.y, h=sc.h, params=make_params(get_preset("paper-example1"), Structure()), inputs=u)
    last = res.alpha[-1000:, 0].mean().item()
    assert abs(last - 0.35) < 0.02
    assert not bool(res.diverged)


def test_adaptive_q_cap_default_and_none():
    """Default: the adapted Qᵒ, Qʷ never exceed Q₀; with Q_max = "none" (25) is free to grow past it."""
    sim, u = _data((4,), n=300, seed=12)
    base = get_preset("paper-example1")
    capped = run_tea(sim.y, h=1e-3, params=make_params(base, Structure()), inputs=u)
    assert float(capped.Q_alpha.max()) <= base.kfo.Q0 * (1 + 1e-12)
    assert float(capped.Q_w.max()) <= base.kfw.Q0 * (1 + 1e-12)
    free_cfg = TEAConfig.from_dict({"kfo": {"Q_max": "none"}, "kfw": {"Q_max": "none"}}, base)
    free = run_tea(sim.y, h=1e-3, params=make_params(free_cfg, Structure()), inputs=u)
    assert float(free.Q_alpha.max()) > base.kfo.Q0 or float(free.Q_w.max()) > base.kfw.Q0
    with pytest.raises(ValueError, match="Q_max"):
        TEAConfig.from_dict({"kfo": {"Q_max": "always"}})


def test_dtype_follows_input():
    sim, u = _data((2,), n=60, seed=13)
    res32 = run_tea(sim.y.float(), h=1e-3, params=make_params(get_preset("paper-example1"), Structure()),
                    inputs=u.float())
    assert res32.alpha.dtype == torch.float32 and res32.x.dtype == torch.float32
    res64 = run_tea(sim.y, h=1e-3, params=make_params(get_preset("paper-example1"), Structure()), inputs=u)
    torch.testing.assert_close(res32.alpha.double(), res64.alpha, rtol=0, atol=1e-3)

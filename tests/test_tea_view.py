"""The TEA reads the noise model (torchtea.noise.tea.tea_view): the paper's scalar model exactly as before, a
check-grown model's other states as KFx states whose transition and drive are the exact filter's."""
from __future__ import annotations

from dataclasses import replace

import pytest
import torch

from torchtea.core.stats import last_third, mean_nis
from torchtea.engines.presets import get_preset
from torchtea.engines.structure import Structure
from torchtea.engines.tea import make_params, run_tea
from torchtea.noise import parse_model, simulate_model
from torchtea.noise.tea import same_structure, tea_view

H = 0.01
FW = {"fractional.order": 0.4, "fractional.pole": -2.0, "fractional.q": 0.02, "white.r": 1e-5}


def test_the_paper_model_is_the_scalar_structure_with_the_old_settings():
    """fractional+white: the default scalar Structure (so the compiled engine takes it) and the settings the
    one-way bridge gave: Q0 = q, R = r (all three filters), KFo at the order, KFw at the pole, scaled drive."""
    base = get_preset("paper-mems-y")
    v = tea_view("fractional+white", FW, H, base)
    assert same_structure(v.structure, Structure())
    expected = replace(base, noise_scaling="scaled", kfx=replace(base.kfx, R=1e-5, Q0=0.02),
                       kfo=replace(base.kfo, R=1e-5, x0=0.4), kfw=replace(base.kfw, R=1e-5, x0=-2.0))
    assert v.config == expected
    assert v.orders == ("fractional",) and v.params == ("fractional.pole",) and v.states == ("fractional",)
    q = dict(FW, **{"quantisation.step": 0.01})
    assert tea_view("fractional+white+quantisation", q, H).config.kfx.R == pytest.approx(1e-5 + 1e-4 / 12)


def test_other_states_are_the_exact_filters_blocks():
    """A random walk, a Gauss–Markov bias and a vibration band: the TEA's order-1 form x_{k+1} = h(A x_k + ω) + x_k
    with A = (F − I)/h and the scaled drive h Q0 h is the state space's F and G Gᵀ, entry for entry."""
    spec = "fractional+white+random-walk+gauss-markov+resonance"
    vals = dict(FW, **{"random-walk.sigma": 0.01, "gauss-markov.sigma": 0.02, "gauss-markov.tau_s": 3.0,
                       "resonance.frequency_hz": 12.0, "resonance.bandwidth_hz": 0.5, "resonance.sigma": 0.003})
    v = tea_view(spec, vals, H)
    ss = parse_model(spec).state_space(vals, H, 100, "window:1")  # the fractional block: one lag
    st = v.structure
    assert st.n_states == 5 and v.states == ("fractional", "random-walk", "gauss-markov", "resonance", "resonance")
    assert st.estimated == (True, False, False, False, False) and st.n_params == 1
    assert torch.equal(st.C, torch.tensor([[1.0, 1.0, 1.0, 1.0, 0.0]], dtype=torch.float64))
    assert torch.equal(st.B[:, 0], torch.tensor([1.0, 0.0, 0.0, 0.0, 0.0], dtype=torch.float64))  # input: fractional
    w = torch.tensor([FW["fractional.pole"]], dtype=torch.float64)
    A = st.A(w)
    Q0 = torch.as_tensor(v.config.kfx.Q0, dtype=torch.float64)
    F, Q = ss.F[0], ss.Q[0]
    eye = torch.eye(4, dtype=torch.float64)
    torch.testing.assert_close(eye + H * A[1:, 1:], F[1:, 1:], rtol=1e-12, atol=1e-14)
    torch.testing.assert_close(H * Q0[1:, 1:] * H, Q[1:, 1:], rtol=1e-12, atol=1e-18)
    assert float(A[0, 0]) == FW["fractional.pole"] and float(Q0[0, 0]) == FW["fractional.q"]
    # the fractional state keeps the paper's prior, the others start at zero as the model's states do
    P0 = torch.as_tensor(v.config.kfx.P0, dtype=torch.float64)
    assert float(P0[0, 0]) == get_preset("paper-mems-x").kfx.P0 and float(P0[1:].abs().sum()) == 0.0


def test_what_the_tea_cannot_run_is_refused_by_name():
    with pytest.raises(ValueError, match="low-pass.*no fixed A"):
        tea_view("fractional+white+low-pass", dict(FW, **{"low-pass.cutoff_hz": 5.0}), H)
    with pytest.raises(ValueError, match="no fractional state"):
        tea_view("white+random-walk", {"white.r": 1e-3, "random-walk.sigma": 0.01}, H)
    with pytest.raises(ValueError, match="no measurement noise"):
        tea_view("fractional", {k: v for k, v in FW.items() if k != "white.r"}, H)
    two = dict(FW, **{f"fractional2.{k.split('.')[1]}": v for k, v in FW.items() if k.startswith("fractional.")})
    with pytest.raises(ValueError, match="2 fractional states"):
        tea_view("fractional+white+fractional", two, H)
    with pytest.raises(ValueError, match="one parameter set"):
        tea_view("fractional+white", {k: [v, v] for k, v in FW.items()}, H)


def test_means_leave_the_series_and_the_modifier_is_noted():
    """A ramp and a sinusoid at their values are removed (what is left is the stochastic part); the temperature's
    order modifier is no state (KFo tracks the order)."""
    spec = "fractional+white+offset+ramp+sinusoid"
    vals = dict(FW, **{"offset.value": 0.3, "ramp.slope": 0.002, "sinusoid.frequency_hz": 7.0,
                       "sinusoid.amplitude": 0.05, "sinusoid.phase": 0.4})
    m = parse_model(spec)
    missing = set(m.names) - set(vals)
    assert not missing, missing
    y, states = simulate_model(m, vals, n_steps=500, h=H, generator=torch.Generator().manual_seed(1),
                               return_states=True)
    v = tea_view(m, vals, H)
    assert v.structure.n_states == 1 and "removed" in v.notes["sinusoid"]
    t = torch.arange(500, dtype=torch.float64) * H
    r = v.residual(y[0, 0], t)
    stochastic = y[0, 0] - m.mean(vals, t)[0]
    torch.testing.assert_close(r, stochastic, rtol=0, atol=1e-12)
    tv = dict(FW, **{"temperature-order.order_per_degC": 0.01, "temperature-order.t_ref": 25.0})
    v = tea_view("fractional+white+temperature-order", tv, H)
    assert v.structure.n_states == 1 and "KFo" in v.notes["temperature-order"]


@pytest.mark.slow
def test_the_grown_model_makes_kfx_consistent_where_the_plain_one_is_not():
    """Data with a random walk (σ 0.05 units/√s beside the fractional part): KFx with the order and pole held at the
    truth predicts its innovations (mean NIS near 1: 0.96 in a trial) with the grown model's view; the plain
    model's KFx, blind to the walk, does not (27). 16 realisations × 3000 steps, last third, seeded; the NIS's
    spread across realisations is ~0.1."""
    truth = dict(FW, **{"random-walk.sigma": 0.05})
    N, B = 3000, 16
    y = simulate_model("fractional+white+random-walk", truth, n_steps=N, h=H, realisations=B,
                       generator=torch.Generator().manual_seed(5))[0]
    sl = last_third(N)
    obs = torch.ones(B, N - sl.start, dtype=torch.bool)

    def nis(spec, vals):
        v = tea_view(spec, vals, H)
        held = lambda f: replace(f, P0=1e-12, Q0=1e-12)  # noqa: E731
        cfg = replace(v.config, kfo=held(v.config.kfo), kfw=held(v.config.kfw))
        res = run_tea(y.unsqueeze(-1), h=H, params=make_params(cfg, v.structure), structure=v.structure)
        return float(mean_nis(res.innovation[:, sl], res.innovation_cov[:, sl], obs).mean())

    assert 0.8 < nis("fractional+white+random-walk", truth) < 1.25
    assert nis("fractional+white", FW) > 5


def test_what_the_engines_ask_of_a_component_is_its_own_attribute():
    """The order, stationarity and order-driving are the components' attributes (no engine switches on a name):
    the model's order name, whether the Whittle likelihood can fit it, and the fixed-parameter rule of the pole."""
    from torchtea.fitting.mle import fit_series

    assert parse_model("fractional+white").order_name == "fractional.order"
    assert parse_model("white+random-walk").order_name is None
    m = parse_model("fractional+white+temperature-order")
    assert not m.stationary and parse_model("fractional+white+ramp").stationary
    y = simulate_model("fractional+white", FW, n_steps=300, h=H, generator=torch.Generator().manual_seed(2))[0, 0]
    with pytest.raises(ValueError, match="temperature-order makes the model non-stationary"):
        fit_series(m, [y.numpy()], H, method="whittle", inputs=[{"temperature": torch.zeros(300)}])
    with pytest.raises(ValueError, match="pole cannot be fixed while fractional.order is free"):
        fit_series("fractional+white", [y.numpy()], H, fixed={"fractional.pole": -2.0})


def test_identify_reuses_each_channels_view_for_its_settings():
    """identify builds each channel's view once, on the channel's preset, and axis_configs starts from its settings:
    the same configs as building the views again (with and without overrides; a preset override builds them anew)."""
    from torchtea.fitting.mle import fit_series
    from torchtea.identification import axis_configs

    spec = "fractional+white+random-walk"
    vals = dict(FW, **{"random-walk.sigma": 0.02})
    y = simulate_model(spec, vals, n_steps=400, h=H, realisations=2, generator=torch.Generator().manual_seed(5))[0]
    fits = fit_series(spec, [y[0].numpy(), y[1].numpy()], H, method="whittle")
    presets = ["paper-mems-x", "paper-mems-z"]
    views = tuple(tea_view(f.model, f.values, H, get_preset(p)) for f, p in zip(fits, presets))
    yy = y.unsqueeze(-1)
    for overrides in (None, {"kfo": {"Q0": 1e-5}}, {"preset": "paper-example1", "kfo": {"Q0": 1e-5}}):
        again = axis_configs(yy, "fitted", overrides, fits, presets, h=H)
        reused = axis_configs(yy, "fitted", overrides, fits, presets, h=H, views=views)
        assert again == reused
    assert axis_configs(yy, "fitted", None, fits, presets, h=H, views=views)[1].kfx.P0 == views[1].config.kfx.P0
    assert axis_configs(yy, "fitted", None, fits, presets, h=H)[0] != axis_configs(yy, "fitted", None, fits, presets,
                                                                                   h=H)[1]

"""Simulator: the model equation holds exactly; randomness is explicit; the spectrum matches theory."""
import math

import numpy as np
import pytest
import torch

from torchtea.core.gl import difference
from torchtea.engines.structure import (
    ConstantOrder,
    FunctionOrder,
    InputOrder,
    LinearOrder,
    ParabolicOrder,
    Structure,
    parse_order_spec,
)
from torchtea.noise.simulate import gaussian_input, simulate


@pytest.mark.parametrize("order", [ConstantOrder(0.4), LinearOrder(0.2, 0.5), ParabolicOrder(0.2, 0.3),
                                   FunctionOrder(lambda t: 0.5 + 0.2 * torch.sin(3 * t))])
@pytest.mark.parametrize("batch", [(), (3,), (2, 2)])
def test_model_equation_holds(order, batch):
    """A-type: h^{-α_{k+1}} Σ_j c_j(α_{k+1}) x_{k+1−j} = f x_k + u_k + ω_k, paper (9)."""
    g = torch.Generator().manual_seed(0)
    n, h, f = 150, 0.01, -1.7
    u = gaussian_input(batch, n, 1, 0.5, generator=g)
    s = simulate(Structure(), n_steps=n, h=h, order=order, parameters=[f], process_noise=0.01,
                 measurement_noise=1e-3, inputs=u, batch_shape=batch, generator=g)
    assert s.x.shape == batch + (n, 1) and s.y.shape == batch + (n, 1) and s.alpha.shape == batch + (n, 1)
    x, a = s.x[..., 0], s.alpha[..., 0]
    lhs = difference(x, a, h, "A")[..., 1:]
    rhs = (f * x + s.u[..., 0] + s.process_noise[..., 0])[..., :-1]
    torch.testing.assert_close(lhs, rhs, rtol=1e-9, atol=1e-9)
    torch.testing.assert_close(s.y, s.x + s.measurement_noise)
    assert torch.all(s.x[..., 0, :] == 0)


def test_generator_reproducible_and_seed_sensitive():
    def run(seed):
        g = torch.Generator().manual_seed(seed)
        return simulate(Structure(), n_steps=50, h=0.01, order=ConstantOrder(0.3), parameters=[-1.0],
                        process_noise=1e-2, measurement_noise=1e-3, batch_shape=(2,), generator=g).y
    assert torch.equal(run(1), run(1))
    assert not torch.equal(run(1), run(2))


def test_batched_parameters_and_input_driven_order():
    g = torch.Generator().manual_seed(4)
    w = torch.tensor([[-1.0], [-2.0], [-3.0]], dtype=torch.float64)
    temp = torch.linspace(0, 1, 80, dtype=torch.float64).expand(3, 80).unsqueeze(-1)
    s = simulate(Structure(), n_steps=80, h=0.01, order=InputOrder(0.3, 0.4), parameters=w, process_noise=1e-2,
                 measurement_noise=0.0, inputs=temp * 0.0 + temp, generator=g)
    assert s.x.shape == (3, 80, 1)
    torch.testing.assert_close(s.alpha[..., 0], 0.3 + 0.4 * temp[..., 0])
    for i in range(3):
        lhs = difference(s.x[i, :, 0], s.alpha[i, :, 0], 0.01, "A")[1:]
        rhs = (w[i, 0] * s.x[i, :, 0] + s.u[i, :, 0] + s.process_noise[i, :, 0])[:-1]
        torch.testing.assert_close(lhs, rhs, rtol=1e-9, atol=1e-9)


def test_order_spec_parsing():
    assert parse_order_spec("0.35") == ConstantOrder(0.35)
    assert parse_order_spec("linear:0.2,0.1") == LinearOrder(0.2, 0.1)
    assert parse_order_spec("parabolic:0.2,0.05") == ParabolicOrder(0.2, 0.05)
    assert parse_order_spec(0.35) == ConstantOrder(0.35) and parse_order_spec(1) == ConstantOrder(1.0)  # TOML numbers
    for bad in ("", "abc", "linear:0.2", "cubic:1,2", "linear:a,b", "nan", float("inf"), True, None):
        with pytest.raises(ValueError, match="SPEC"):
            parse_order_spec(bad)


def test_stationary_spectrum_matches_theory():
    """Averaged periodogram of x against S_x(ω) = σ² h^{2α} / (2π |(1−e^{−iω})^α − a e^{−iω}|²), a = f h^α
    (ALGORITHMS.md §5). 96 realisations: each band average of 96×8 periodogram ordinates has a relative
    standard deviation of about 1/√768 ≈ 3.6 %, so 15 % is a > 4σ bound."""
    g = torch.Generator().manual_seed(7)
    alpha, f, h, q = 0.4, -2.0, 0.05, 1.0
    n, burn, R = 1536, 512, 96
    s = simulate(Structure(), n_steps=n, h=h, order=ConstantOrder(alpha), parameters=[f], process_noise=q,
                 measurement_noise=0.0, batch_shape=(R,), generator=g)
    x = s.x[:, burn:, 0].numpy()
    m = x.shape[1]
    I = np.abs(np.fft.rfft(x, axis=1)) ** 2 / (2 * math.pi * m)
    omega = 2 * math.pi * np.arange(I.shape[1]) / m
    a = f * h**alpha
    z = np.exp(-1j * omega)
    S = q * h ** (2 * alpha) / (2 * math.pi * np.abs((1 - z) ** alpha - a * z) ** 2)
    Ibar = I.mean(0)
    for lo in range(8, I.shape[1] - 8, 64):
        band = slice(lo, lo + 8)
        assert Ibar[band].mean() / S[band].mean() == pytest.approx(1.0, abs=0.15), f"band at ω={omega[lo]:.2f}"


def test_standard_draws_replace_the_generator():
    g = torch.Generator().manual_seed(21)
    n = 40
    z_w = torch.randn(3, n, 1, generator=g, dtype=torch.float64)
    z_v = torch.randn(3, n, 1, generator=g, dtype=torch.float64)
    s = simulate(Structure(), n_steps=n, h=0.01, order=ConstantOrder(0.4), parameters=[-1.0], process_noise=4.0,
                 measurement_noise=0.25, standard_draws=(z_w, z_v))
    assert s.x.shape == (3, n, 1)
    torch.testing.assert_close(s.process_noise, 2.0 * z_w)
    torch.testing.assert_close(s.measurement_noise, 0.5 * z_v)
    # realisation 1 alone gives the same series as inside the batch
    one = simulate(Structure(), n_steps=n, h=0.01, order=ConstantOrder(0.4), parameters=[-1.0], process_noise=4.0,
                   measurement_noise=0.25, standard_draws=(z_w[1], z_v[1]))
    torch.testing.assert_close(one.y, s.y[1], rtol=0, atol=1e-13)
    with pytest.raises(ValueError, match="standard_draws"):
        simulate(Structure(), n_steps=n, h=0.01, order=ConstantOrder(0.4), parameters=[-1.0], process_noise=1.0,
                 measurement_noise=1.0, standard_draws=(z_w[..., :10, :], z_v))


def test_order_spec_roundtrip():
    for sched in (ConstantOrder(0.35), LinearOrder(0.2, 0.1), ParabolicOrder(0.2, 0.05)):
        assert parse_order_spec(sched.spec()) == sched
    with pytest.raises(ValueError, match="no command-line SPEC"):
        FunctionOrder(lambda t: t).spec()


def _paper_values(B=1):
    one = lambda v: torch.full((B,), v, dtype=torch.float64)  # noqa: E731
    return {"fractional.order": one(0.4), "fractional.pole": one(-2.0), "fractional.q": one(0.01), "white.r": one(1e-3)}


@pytest.mark.parametrize("order", [None, LinearOrder(0.2, 0.05), FunctionOrder(lambda t: 0.5 + 0.2 * torch.sin(3 * t))])
@pytest.mark.parametrize("forced", [False, True])
def test_exact_recursion_equals_the_state_space_with_the_whole_past(order, forced):
    """Two recursions of one model: the fractional component's own (``run_exact``, the GL sum over the whole past) and
    the state space's with ``exact`` memory (every past sample a state, row 0 the GL coefficients; forced here by a
    random walk of zero drive beside it, which makes the model one of several states). Same draws, same orders and
    forcing, x0 ≠ 0: the same series to float64 rounding (they sum in other orders)."""
    from torchtea.noise import simulate_states

    N, R = 300, 3
    g = torch.Generator().manual_seed(8)
    xi = torch.randn(1, R, N, 2, generator=g, dtype=torch.float64)
    nu = torch.randn(1, R, N, generator=g, dtype=torch.float64)
    u = 0.3 * torch.randn(1, R, N, generator=g, dtype=torch.float64) if forced else None
    a = None if order is None else order.values(N, 0.01, 1)[:, 0]
    kw = dict(n_steps=N, h=0.01, realisations=R, memory="exact", orders=a, forcing=u, x0=0.05, keep=[0])
    own = simulate_states("fractional+white", _paper_values(), draws=(xi[..., :1], nu), **kw)
    v = dict(_paper_values(), **{"random-walk.sigma": torch.zeros(1, dtype=torch.float64)})
    stacked = simulate_states("fractional+white+random-walk", v, draws=(xi, nu), **kw)
    scale = float(own.x.abs().max())
    torch.testing.assert_close(own.x, stacked.x, rtol=0, atol=1e-12 * scale)
    torch.testing.assert_close(own.y, stacked.y, rtol=0, atol=1e-12 * scale)
    assert torch.equal(own.alpha, stacked.alpha) and own.alpha.shape == (1, R, N, 1)
    assert float(own.x[..., 0, 0].sub(0.05).abs().max()) == 0.0
    if order is not None:
        torch.testing.assert_close(own.alpha[0, 0, :, 0], a)


@pytest.mark.parametrize("order", [ConstantOrder(0.4), LinearOrder(0.2, 0.05), FunctionOrder(lambda t: 0.5 + 0.2 * torch.sin(3 * t))])
@pytest.mark.parametrize("batch", [(), (3,), (2, 2)])
def test_soe_memory_against_the_whole_past(order, batch):
    """The paper's simulator under ``soe`` memory (the model's state space, compiled) against its exact recursion,
    same draws: within the kernel's tolerance (every coefficient to relative 1e-8, so the series to far less than
    1e-6 of its scale). ``window:L`` against the model whose GL sum stops after L lags: tests/test_memory.py."""
    def run(mem):
        g = torch.Generator().manual_seed(11)
        u = gaussian_input(batch, 800, 1, 0.3, generator=g)
        return simulate(Structure(), n_steps=800, h=0.01, order=order, parameters=[-2.0], process_noise=0.01,
                        measurement_noise=1e-3, inputs=u, batch_shape=batch, generator=g, memory=mem)

    bounded, exact = run("soe"), run("exact")
    assert bounded.x.shape == exact.x.shape == batch + (800, 1)
    assert torch.equal(bounded.alpha, exact.alpha) and torch.equal(bounded.process_noise, exact.process_noise)
    assert torch.equal(bounded.u, exact.u)
    scale = float(exact.x.abs().max())
    assert 0 < float((bounded.x - exact.x).abs().max()) <= 1e-6 * scale


def test_the_paper_simulator_refuses_what_it_does_not_run():
    from torchtea.engines.structure import ParametricMatrix

    two = Structure(A=ParametricMatrix(torch.zeros(2, 2, dtype=torch.float64), torch.eye(2, dtype=torch.float64)[None]),
                    B=torch.ones(2, 1, dtype=torch.float64), C=torch.ones(1, 2, dtype=torch.float64),
                    estimated=(True, False), fixed_orders=torch.ones(2, dtype=torch.float64))
    with pytest.raises(ValueError, match="scalar structure"):
        simulate(two, n_steps=10, h=0.01, order=ConstantOrder(0.4), parameters=[-1.0], process_noise=1.0,
                 measurement_noise=1.0)
    with pytest.raises(ValueError, match="does not differentiate"):
        simulate(Structure(), n_steps=10, h=0.01, order=ConstantOrder(0.4),
                 parameters=torch.tensor([-1.0], dtype=torch.float64, requires_grad=True), process_noise=1.0,
                 measurement_noise=1.0)


def test_the_model_simulator_names_what_it_cannot_take():
    from torchtea.noise import simulate_states

    with pytest.raises(ValueError, match="no fractional component"):
        simulate_states("random-walk+white", {"random-walk.sigma": [0.1], "white.r": [1e-3]}, n_steps=10, h=0.01,
                        forcing=torch.zeros(10))
    with pytest.raises(ValueError, match="orders must have shape"):
        simulate_states("fractional+white", _paper_values(), n_steps=10, h=0.01, orders=torch.full((7,), 0.3))
    with pytest.raises(ValueError, match="draws must have shapes"):
        simulate_states("fractional+white", _paper_values(), n_steps=10, h=0.01,
                        draws=(torch.zeros(1, 1, 9, 1), torch.zeros(1, 1, 10)))
    with pytest.raises(ValueError, match="keep"):
        simulate_states("fractional+white", _paper_values(), n_steps=10, h=0.01, keep=[999])


@pytest.mark.parametrize("name", ["paper-example1", "paper-example2", "paper-example3"])
def test_the_paper_examples_under_soe_are_their_exact_series(name):
    """Every paper example under ``soe`` memory (a Monte Carlo truth's default) against its exact recursion, same
    draws: Example 3's order rises to 2, beyond the model's order bounds, so the kernel must be designed for the orders
    run (it once served 0 … 1 only, and every realisation diverged); the known trajectory's rows are exact per order,
    so the series agree to the kernel's tolerance (measured: ≤ 1.6e-9 of the scale)."""
    from torchtea import SCENARIOS

    sc = SCENARIOS[name]

    def run(mem):
        g = torch.Generator().manual_seed(7)
        u = gaussian_input((2,), sc.n_steps, 1, sc.input_std, generator=g)
        return simulate(Structure(), n_steps=sc.n_steps, h=sc.h, order=sc.order, parameters=[sc.param],
                        process_noise=sc.q, measurement_noise=sc.r, inputs=u, generator=g, memory=mem).x

    soe, exact = run("soe"), run("exact")
    assert bool(torch.isfinite(soe).all())
    assert float((soe - exact).abs().max()) <= 1e-8 * float(exact.abs().max())


def test_a_constant_order_beyond_the_bounds_under_soe():
    """An order of 1.5 (outside the model's 0 … 1) under ``soe``: its own kernel, the exact series to its tolerance."""
    def run(mem):
        return simulate(Structure(), n_steps=1500, h=0.01, order=ConstantOrder(1.5), parameters=[-0.5],
                        process_noise=1e-4, measurement_noise=1e-6, generator=torch.Generator().manual_seed(2),
                        memory=mem).x

    soe, exact = run("soe"), run("exact")
    assert float((soe - exact).abs().max()) <= 1e-8 * float(exact.abs().max())


def test_forcing_follows_a_temperature_driven_order():
    """A forcing enters as h^{α_{k+1}} u_k with the order the modifier gives that step (it once took the constant
    order), under exact memory (a model of one fractional state with a temperature-driven order runs the state space):
    the A-type equation holds with the orders the simulation reports."""
    from torchtea.noise import simulate_states

    N, h = 300, 0.01
    T = 25.0 + 20.0 * (1.0 - torch.exp(-torch.arange(N, dtype=torch.float64) * h / 0.5))
    v = {"fractional.order": [0.3], "fractional.pole": [-2.0], "fractional.q": [0.0], "white.r": [1e-6],
         "temperature-order.order_per_degC": [0.02], "temperature-order.t_ref": [25.0]}
    u = 0.3 * torch.randn(1, 1, N, generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    sim = simulate_states("fractional+temperature-order+white", v, n_steps=N, h=h, memory="exact",
                          inputs={"temperature": T}, forcing=u, keep=[0], generator=torch.Generator().manual_seed(4))
    x, a = sim.x[0, 0, :, 0], sim.alpha[0, 0, :, 0]
    assert float(a[-1] - a[0]) > 0.3  # the order moved
    lhs = difference(x, a, h, "A")[1:]
    torch.testing.assert_close(lhs, (-2.0 * x + u[0, 0])[:-1], rtol=1e-9, atol=1e-9 * float(lhs.abs().max()))


def test_every_realisation_of_a_batch_is_its_own_run():
    """The compiled loop advances realisations 16 at a time: each of 21 (a short last group; a random walk beside the
    fractional state, a forcing, x0) equals its run alone, bit for bit; a sensor filter's first draw comes from
    ``draws`` when given (the third), and without it such a model refuses ``draws`` by name."""
    from torchtea.noise import simulate_states

    N, R = 400, 21
    v = dict(_paper_values(), **{"random-walk.sigma": torch.full((1,), 0.05, dtype=torch.float64)})
    g = torch.Generator().manual_seed(12)
    xi, nu = torch.randn(1, R, N, 2, generator=g, dtype=torch.float64), torch.randn(1, R, N, generator=g,
                                                                                   dtype=torch.float64)
    u = torch.randn(1, R, N, generator=g, dtype=torch.float64)
    kw = dict(n_steps=N, h=0.01, memory="soe", x0=0.1, keep="all")
    batch = simulate_states("fractional+white+random-walk", v, draws=(xi, nu), forcing=u, realisations=R, **kw)
    for r in (0, 15, 16, 20):
        one = simulate_states("fractional+white+random-walk", v, draws=(xi[:, r:r + 1], nu[:, r:r + 1]),
                              forcing=u[:, r:r + 1], **kw)
        assert torch.equal(one.y[0, 0], batch.y[0, r]) and torch.equal(one.x[0, 0], batch.x[0, r])
    lp = {"fractional.order": [0.4], "fractional.pole": [-2.0], "fractional.q": [0.01], "white.r": [1e-3],
          "low-pass.cutoff_hz": [5.0]}
    g = torch.Generator().manual_seed(5)
    ref = simulate_states("fractional+white+low-pass", lp, n_steps=N, h=0.01, realisations=2, generator=g)
    g = torch.Generator().manual_seed(5)
    m = ref.process_noise.shape[-1]
    d = (torch.randn(1, 2, N, m, generator=g, dtype=torch.float64), torch.randn(1, 2, N, generator=g,
                                                                                dtype=torch.float64),
         torch.randn(1, 2, 1, generator=g, dtype=torch.float64)[..., 0])
    assert torch.equal(simulate_states("fractional+white+low-pass", lp, n_steps=N, h=0.01, realisations=2,
                                       draws=d).y, ref.y)
    with pytest.raises(ValueError, match="third of draws"):
        simulate_states("fractional+white+low-pass", lp, n_steps=N, h=0.01, realisations=2, draws=d[:2])

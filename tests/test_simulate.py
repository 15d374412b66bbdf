"""Simulator: the model equation holds exactly; randomness is explicit; the spectrum matches theory."""
import math

import numpy as np
import pytest
import torch

from torchtea.core.gl import difference
from torchtea.engines.structure import (ConstantOrder, FunctionOrder, InputOrder, LinearOrder, ParabolicOrder, Structure,
                            parse_order_spec)
from torchtea.engines.simulate import gaussian_input, simulate


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
    for bad in ("", "abc", "linear:0.2", "cubic:1,2", "linear:a,b", "nan"):
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


@pytest.mark.parametrize("memory", ["soe", "window:40"])
# orders that keep the recursion stable (an order rising to 4 amplifies rounding by ~100 over these 800 steps)
@pytest.mark.parametrize("order", [ConstantOrder(0.4), LinearOrder(0.2, 0.05), FunctionOrder(lambda t: 0.5 + 0.2 * torch.sin(3 * t))])
@pytest.mark.parametrize("batch", [(), (3,), (2, 2)])
def test_compiled_bounded_simulation_equals_the_torch_loop(monkeypatch, memory, order, batch):
    """Fast path against the obvious one: the compiled loop (scalar model, bounded memory, CPU, float64) and the
    torch loop give the same series to float64 rounding (they sum the window and the modes in other orders)."""
    import torchtea.engines.simulate as sim_mod

    def run():
        g = torch.Generator().manual_seed(11)
        u = gaussian_input(batch, 800, 1, 0.3, generator=g)
        return simulate(Structure(), n_steps=800, h=0.01, order=order, parameters=[-2.0], process_noise=0.01,
                        measurement_noise=1e-3, inputs=u, batch_shape=batch, generator=g, memory=memory)

    fast = run()
    monkeypatch.setattr(sim_mod, "fast_path_reason", lambda *a: "the torch loop, for the comparison")
    slow = run()
    scale = float(slow.x.abs().max())
    assert float((fast.x - slow.x).abs().max()) <= 1e-12 * scale
    torch.testing.assert_close(fast.y, slow.y, rtol=0, atol=1e-12 * scale)
    assert torch.equal(fast.alpha, slow.alpha) and torch.equal(fast.process_noise, slow.process_noise)

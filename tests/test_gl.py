"""GL coefficients and variable-order differences: exact identities (ALGORITHMS.md §1–2)."""
import math

import mpmath as mp
import numpy as np
import pytest
import torch
from scipy.special import binom

from torchtea.core.gl import difference, gl_coefficients, history_sum

ORDERS = torch.tensor([-0.9, -0.4, 0.0, 0.02, 0.35, 0.5, 0.98, 1.0, 1.5, 2.3], dtype=torch.float64)


def test_against_binomial_definition():
    c = gl_coefficients(ORDERS, 30)
    j = np.arange(31)
    for a, row in zip(ORDERS.tolist(), c):
        np.testing.assert_allclose(row.numpy(), (-1.0) ** j * binom(a, j), rtol=1e-12, atol=1e-15)


def test_first_coefficient_and_shape():
    a = torch.rand(2, 3, dtype=torch.float64)
    c = gl_coefficients(a, 5)
    assert c.shape == (2, 3, 6)
    assert torch.all(c[..., 0] == 1)
    torch.testing.assert_close(c[..., 1], -a)


def test_partial_sums_constant_and_ramp_history():
    k = 200
    c = gl_coefficients(ORDERS, k)
    cm1 = gl_coefficients(ORDERS - 1, k)
    cm2 = gl_coefficients(ORDERS - 2, k)
    # Σ_{j≤k} c_j(α) = c_k(α−1)
    torch.testing.assert_close(torch.cumsum(c, -1), cm1, rtol=1e-10, atol=1e-13)
    # Σ_{j≤k} c_j(α)(k−j) = c_{k−1}(α−2)
    for kk in (1, 7, 50, 200):
        ramp = (c[..., : kk + 1] * (kk - torch.arange(kk + 1, dtype=torch.float64))).sum(-1)
        torch.testing.assert_close(ramp, cm2[..., kk - 1], rtol=1e-10, atol=1e-12)


def test_fractional_order_weights_sum_to_minus_one():
    a = torch.tensor([0.3, 0.6, 0.9], dtype=torch.float64)
    c = gl_coefficients(a, 200_000)
    assert torch.all(c[..., 1:] < 0)
    partial = c[..., 1:].sum(-1)
    # Σ_{j=1}^{n} c_j = c_n(α−1) − 1, and c_n(α−1) → 0 like n^{−α}: the weights sum to −1
    torch.testing.assert_close(partial, gl_coefficients(a - 1, 200_000)[..., -1] - 1.0, rtol=1e-9, atol=1e-12)
    assert torch.all((partial + 1).abs() < 0.05)


@pytest.mark.parametrize("a", [0.1, 0.3, 0.75])
def test_sum_of_squares_closed_form(a):
    n = 200_000
    c = gl_coefficients(torch.tensor(a, dtype=torch.float64), n)
    exact = math.gamma(1 + 2 * a) / math.gamma(1 + a) ** 2
    partial = float((c**2).sum())
    # tail Σ_{j>n} c_j² ≈ n^{−1−2α} / (Γ(−α)² (1+2α))
    tail = n ** (-1 - 2 * a) / (math.gamma(-a) ** 2 * (1 + 2 * a))
    assert partial + tail == pytest.approx(exact, rel=1e-9)


def test_recursion_against_mpmath_at_large_lag():
    n = 100_000
    mp.mp.dps = 40
    for a in (0.05, 0.35, 0.77, -0.6):
        c = gl_coefficients(torch.tensor(a, dtype=torch.float64), n)
        am = mp.mpf(a)
        for j in (10, 1000, n):
            ref = mp.gamma(j - am) / (mp.gamma(-am) * mp.gamma(j + 1))
            assert float(c[j]) == pytest.approx(float(ref), rel=1e-12)


@pytest.mark.parametrize("batch", [(), (5,), (2, 4)])
def test_dualities_variable_order(batch):
    g = torch.Generator().manual_seed(1)
    n = 60
    x = torch.randn(batch + (n,), generator=g, dtype=torch.float64)
    a = -0.9 + 1.8 * torch.rand(batch + (n,), generator=g, dtype=torch.float64)
    for fwd, back in (("D", "A"), ("E", "B")):
        y = difference(x, a, 0.01, fwd)
        assert y.shape == batch + (n,)
        torch.testing.assert_close(difference(y, -a, 0.01, back), x, rtol=1e-9, atol=1e-10)
        # and the other way round
        z = difference(x, a, 0.01, back)
        torch.testing.assert_close(difference(z, -a, 0.01, fwd), x, rtol=1e-9, atol=1e-10)


def test_constant_order_all_types_agree_with_convolution():
    g = torch.Generator().manual_seed(2)
    x = torch.randn(40, generator=g, dtype=torch.float64)
    a, h = 0.45, 0.1
    c = gl_coefficients(torch.tensor(a, dtype=torch.float64), 39).numpy()
    ref = np.convolve(c, x.numpy())[:40] / h**a
    for kind in ("A", "B"):
        np.testing.assert_allclose(difference(x, a, h, kind).numpy(), ref, rtol=1e-12, atol=1e-12)
    # D and E with constant order invert the A/B difference of order −α
    for kind in ("D", "E"):
        back = difference(difference(x, a, h, kind), -a, h, "A")
        np.testing.assert_allclose(back.numpy(), x.numpy(), rtol=1e-10, atol=1e-11)


def test_variable_order_A_and_B_differ_as_defined():
    x = torch.ones(3, dtype=torch.float64)
    a = torch.tensor([0.2, 0.5, 0.9], dtype=torch.float64)
    h = 0.5
    A = difference(x, a, h, "A")
    B = difference(x, a, h, "B")
    c = lambda al, j: float(gl_coefficients(torch.tensor(al, dtype=torch.float64), 2)[j])  # noqa: E731
    assert float(A[2]) == pytest.approx(h**-0.9 * (c(0.9, 0) + c(0.9, 1) + c(0.9, 2)))
    assert float(B[2]) == pytest.approx(h**-0.9 * c(0.9, 0) + h**-0.5 * c(0.5, 1) + h**-0.2 * c(0.2, 2))


def test_history_sum_matches_difference():
    g = torch.Generator().manual_seed(3)
    x = torch.randn(2, 30, generator=g, dtype=torch.float64)
    a = torch.tensor([[0.3], [0.7]], dtype=torch.float64)
    k = 29
    hist = x[..., :k].flip(-1).unsqueeze(-2)  # (2, 1, k) newest first: x_{k-1} … x_0
    S = history_sum(a.unsqueeze(-1).expand(2, 4, 1), hist)  # four identical "sigma points"
    assert S.shape == (2, 4, 1)
    full = difference(x[..., : k + 1], a, 1.0, "A")[..., k]  # Σ_{j=0}^{k} c_j x_{k−j}
    torch.testing.assert_close(S[:, 0, 0], full - x[..., k], rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(S[:, 1:, 0], S[:, :1, 0].expand(2, 3))


def test_bad_kind():
    with pytest.raises(ValueError, match="kind"):
        difference(torch.zeros(3), 0.5, 1.0, "C")

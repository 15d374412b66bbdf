"""Monte Carlo statistics against NumPy / SciPy computed independently."""
import math

import numpy as np
import pytest
import torch
from scipy.stats import chi2

from torchtea.core.stats import chi2_band, convergence_time, coverage, nees, nis, over_realisations


def _data(seed=0, R=7, N=11, q=2):
    rng = np.random.default_rng(seed)
    est = rng.normal(size=(R, N, q))
    truth = rng.normal(size=(N, q))
    keep = np.array([True, False, True, True, True, False, True])[:R]
    return est, truth, keep


def test_over_realisations_matches_numpy():
    est, truth, keep = _data()
    out = over_realisations(torch.tensor(est), torch.tensor(truth), torch.tensor(keep))
    e = est[keep]
    assert out["count"] == keep.sum()
    np.testing.assert_allclose(out["mean"].numpy(), e.mean(0), rtol=1e-13)
    np.testing.assert_allclose(out["bias"].numpy(), (e - truth).mean(0), rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(out["std"].numpy(), e.std(0, ddof=1), rtol=1e-12)
    np.testing.assert_allclose(out["rmse"].numpy(), np.sqrt(((e - truth) ** 2).mean(0)), rtol=1e-12)
    np.testing.assert_allclose(out["quantiles"].numpy(), np.quantile(e, [0.05, 0.25, 0.5, 0.75, 0.95], axis=0),
                               rtol=1e-12)
    assert out["mean"].shape == (11, 2) and out["quantiles"].shape == (5, 11, 2)


def test_over_realisations_none_kept():
    est, truth, _ = _data()
    out = over_realisations(torch.tensor(est), torch.tensor(truth), torch.zeros(7, dtype=torch.bool))
    assert out["count"] == 0 and torch.isnan(out["rmse"]).all()


def test_convergence_time_against_loop():
    rng = np.random.default_rng(3)
    R, N, h, tol = 6, 30, 0.1, 0.5
    est = np.zeros((R, N, 1))
    for r in range(R):
        est[r, :, 0] = rng.normal(scale=2.0, size=N) * np.exp(-np.arange(N) / (3 + 2 * r))
    est[0, :, 0] = 0.0  # within tolerance from the start
    est[1, -1, 0] = 5.0  # never settles
    got = convergence_time(torch.tensor(est), torch.zeros(N, 1, dtype=torch.float64), tol, h).numpy()[:, 0]
    for r in range(R):
        bad = [k for k in range(N) if abs(est[r, k, 0]) >= tol]
        expect = math.nan if bad and bad[-1] == N - 1 else (0.0 if not bad else (bad[-1] + 1) * h)
        if math.isnan(expect):
            assert math.isnan(got[r])
        else:
            assert got[r] == pytest.approx(expect)
    assert got[0] == 0.0 and math.isnan(got[1])


def test_nees_nis_against_numpy():
    rng = np.random.default_rng(5)
    n = 3
    M = rng.normal(size=(4, 5, n, n))
    P = M @ np.swapaxes(M, -1, -2) + n * np.eye(n)
    xh, x = rng.normal(size=(4, 5, n)), rng.normal(size=(4, 5, n))
    got = nees(torch.tensor(xh), torch.tensor(x), torch.tensor(P)).numpy()
    e = xh - x
    expect = np.einsum("...i,...i->...", e, np.linalg.solve(P, e[..., None])[..., 0])
    np.testing.assert_allclose(got, expect, rtol=1e-12)
    np.testing.assert_allclose(nis(torch.tensor(e), torch.tensor(P)).numpy(), expect, rtol=1e-12)


def test_chi2_band_and_a_consistent_filter_falls_inside():
    lo, hi = chi2_band(1, 200)
    assert lo == pytest.approx(chi2.ppf(0.025, 200) / 200) and hi == pytest.approx(chi2.ppf(0.975, 200) / 200)
    # innovations that really have the stated variance: the averaged NIS lies in the band ~95 % of the time
    g = torch.Generator().manual_seed(0)
    S = torch.full((200, 400, 1, 1), 2.5, dtype=torch.float64)
    e = torch.randn(200, 400, 1, generator=g, dtype=torch.float64) * math.sqrt(2.5)
    avg = nis(e, S).mean(0)
    inside = ((avg >= lo) & (avg <= hi)).double().mean().item()
    # 400 Bernoulli(0.95) steps: sd ≈ 0.011, so 0.90–0.99 is a > 4σ bound
    assert 0.90 <= inside <= 0.99
    # a filter that states 1/1.6 of the true variance: averaged NIS ≈ 1.6 with sd ≈ 1.6·√(2/200) = 0.16, above the
    # band's upper edge (≈ 1.20) by 2.5 sd, so it lands inside on ≈ 0.6 % of steps; < 5 % is a safe bound
    avg_bad = nis(e, S / 1.6).mean(0)
    assert ((avg_bad >= lo) & (avg_bad <= hi)).double().mean().item() < 0.05


def test_coverage():
    est = torch.tensor([0.0, 1.0, 2.5, 3.0], dtype=torch.float64)
    var = torch.tensor([1.0, 1.0, 0.25, 0.0], dtype=torch.float64)
    got = coverage(est, torch.tensor(1.0, dtype=torch.float64), var)
    assert got.tolist() == [True, True, False, False]

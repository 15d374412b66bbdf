"""Statistics of an estimator over many realisations (Monte Carlo studies).

Conventions: estimates ``(R, N, q)`` — realisations, time, components; the truth broadcasts to it; ``keep``
``(R,)`` selects the realisations to summarise (diverged ones are excluded by the caller and counted).

References: NEES/NIS consistency tests and their χ² acceptance bands, Bar-Shalom, Li & Kirubarajan,
*Estimation with Applications to Tracking and Navigation* (2001), §5.4.2 (eqs. 5.4.2-7…5.4.2-10).
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import Tensor

__all__ = ["QUANTILES", "over_realisations", "convergence_time", "nees", "nis", "chi2_band", "coverage", "last_third",
           "mean_nis"]

QUANTILES = (0.05, 0.25, 0.5, 0.75, 0.95)


def over_realisations(est: Tensor, truth: Tensor, keep: Tensor | None = None,
                      quantiles: Sequence[float] = QUANTILES) -> dict:
    """Mean, bias, sample standard deviation (ddof 1), RMSE and quantiles over realisations.

    est ``(R, N, q)``; truth broadcastable to it; keep ``(R,)`` bool. Every entry of the result has shape
    ``(N, q)`` except ``quantiles``, ``(len(quantiles), N, q)``.
    """
    truth = truth.to(est).expand_as(est)
    if keep is not None:
        est, truth = est[keep], truth[keep]
    err = est - truth
    count = est.shape[0]
    if count == 0:
        nan = torch.full(est.shape[1:], math.nan, dtype=est.dtype, device=est.device)
        return {"count": 0, "mean": nan, "bias": nan, "std": nan, "rmse": nan,
                "quantiles": nan.expand((len(quantiles),) + nan.shape)}
    q = torch.tensor(list(quantiles), dtype=est.dtype, device=est.device)
    return {
        "count": count,
        "mean": est.mean(0),
        "bias": err.mean(0),
        "std": est.std(0, correction=1) if count > 1 else torch.zeros_like(est[0]),
        "rmse": err.pow(2).mean(0).sqrt(),
        "quantiles": torch.quantile(est, q, dim=0),
    }


def convergence_time(est: Tensor, truth: Tensor, tolerance: float, h: float) -> Tensor:
    """Time after which ``|est − truth| < tolerance`` holds until the end; NaN where it never settles.

    est ``(R, N, q)`` → ``(R, q)``. A run that is within tolerance from the first sample converges at 0.
    """
    bad = ~((est - truth.to(est)).abs_() < tolerance)  # (R, N, q); NaN counts as not settled
    N = est.shape[-2]
    idx = torch.arange(N, dtype=torch.int32, device=est.device).view(1, N, 1)
    last_bad = torch.where(bad, idx, -1).amax(dim=-2).long()  # (R, q)
    t = (last_bad + 1).to(est.dtype) * h
    return torch.where(last_bad == N - 1, torch.full_like(t, math.nan), t)


def nees(x_hat: Tensor, x: Tensor, P: Tensor) -> Tensor:
    """Normalised estimation error squared ``(x̂ − x)ᵀ P⁻¹ (x̂ − x)``: ``(…, n)``, ``(…, n, n)`` → ``(…)``."""
    if P.shape[-1] == 1:  # one state: e·(e/P), the arithmetic of the solve below without its LU per step
        e = x_hat[..., 0] - x[..., 0]
        return e * (e / P[..., 0, 0])
    e = (x_hat - x).unsqueeze(-1)
    sol, info = torch.linalg.solve_ex(P, e)
    if bool((info != 0).any()):  # a singular P (a state known exactly, e.g. a model's state at its start): the
        bad = info != 0  # pseudo-inverse, i.e. the NEES of the directions with variance
        sol = torch.where(bad[..., None, None], torch.linalg.pinv(P, hermitian=True) @ e, sol)
    return (e.mT @ sol).squeeze(-1).squeeze(-1)


def nis(innovation: Tensor, cov: Tensor) -> Tensor:
    """Normalised innovation squared ``eᵀ S⁻¹ e`` (zero where the innovation is zero, i.e. missing)."""
    return nees(innovation, torch.zeros_like(innovation), cov)


def last_third(n: int) -> slice:
    """The samples ``n − ⌊n/3⌋ … n − 1``: the span over which torchtea reports settled estimates."""
    return slice(n - n // 3, n)


def mean_nis(innovation: Tensor, cov: Tensor, observed: Tensor) -> Tensor:
    """Mean NIS over the observed steps only (a missing sample has no innovation, not a zero one).

    innovation ``(…, N, p)``, cov ``(…, N, p, p)``, observed ``(…, N)`` bool → ``(…)``; NaN where no step
    is observed.
    """
    v = torch.where(observed, nis(innovation, cov), 0.0)  # a masked step's S may be anything, even 0
    return v.sum(-1) / observed.to(v.dtype).sum(-1)


def chi2_band(dof: int, realisations: int, level: float = 0.95) -> tuple[float, float]:
    """Two-sided acceptance band for a statistic averaged over ``realisations`` independent runs.

    If each run's statistic is χ² with ``dof`` degrees of freedom, ``R`` times the average is χ² with ``R·dof``:
    the band is ``[χ²_{R·dof}((1−level)/2), χ²_{R·dof}((1+level)/2)] / R``.
    """
    from scipy.special import chdtri  # the χ² quantile (chi2.ppf(p, k) = chdtri(k, 1 − p)) without scipy.stats' import

    a = (1.0 - level) / 2.0
    total = dof * realisations
    return float(chdtri(total, 1.0 - a) / realisations), float(chdtri(total, a) / realisations)


def coverage(est: Tensor, truth: Tensor, variance: Tensor, k: float = 2.0) -> Tensor:
    """Indicator that the truth lies within ``est ± k·√variance`` (same shapes; boolean)."""
    bound = variance.clamp(min=0).sqrt_().mul_(k)  # in place: two temporaries instead of five
    return (est - truth.to(est)).abs_() <= bound

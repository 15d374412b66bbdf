r"""Allan deviation of a model and of data, with the data's confidence band (ALGORITHMS.md §7).

The model's overlapping Allan variance at cluster size m (τ = m h) is, for its stationary part,

.. math::  \mathrm{AVAR}(m) = \int_{-\pi}^{\pi} S(\omega)\, \frac{2\sin^4(m\omega/2)}{m^2\sin^2(\omega/2)}\, d\omega,

integrated here on a uniform midpoint grid of (0, π] (the integrand is finite at 0 even for a random walk).
The deterministic part (ramp, sinusoid, temperature terms) adds the Allan variance of its own series,
computed on the recording's samples: the estimator is unbiased for a process with stationary increments, so
the expected data AVAR is the sum. A ``temperature-order`` model is not stationary; its curve is that at the
reference temperature.

The data's overlapping ADEV comes from allantools (``oadev``); its equivalent degrees of freedom from
Greenhall's algorithm (``allantools.edf_greenhall``) with the power-law noise type read off the *model's*
local slope at each τ (the model is the null hypothesis), and AVAR·edf/AVAR_model ~ χ²_edf.
"""
from __future__ import annotations

import math

import numpy as np
import torch

__all__ = ["octave_clusters", "model_avar", "data_adev", "deterministic_avar", "power_law_alpha", "allan_edf"]

#: Midpoints of the ω grid for the model's integral (2¹⁷: > 30 points per lobe of the kernel at m = N/4,
#: N = 30 000; against the closed forms white r/m and random walk σ²h(2m²+1)/(6m) to < 1e-6 relative).
GRID = 2 ** 17


def octave_clusters(n: int, max_fraction: float = 0.125) -> np.ndarray:
    """Cluster sizes m = 1, 2, 4 … up to ``max_fraction`` of the series (an estimate needs many clusters)."""
    top = max(1, int(n * max_fraction))
    return 2 ** np.arange(int(math.log2(top)) + 1)


def _kernel(m: np.ndarray, omega: torch.Tensor) -> torch.Tensor:
    m = torch.as_tensor(m, dtype=torch.float64).unsqueeze(-1)
    return 2.0 * torch.sin(m * omega / 2.0) ** 4 / (m * m * torch.sin(omega / 2.0) ** 2)


def model_avar(model, values, h: float, m: np.ndarray, grid: int = GRID, by_component: bool = False):
    """Overlapping AVAR of the model's stochastic part at cluster sizes ``m`` → ``(B, len(m))``; with
    ``by_component`` each stochastic component's share, label → ``(B, len(m))`` (they sum to the total)."""
    omega = (torch.arange(grid, dtype=torch.float64) + 0.5) * (math.pi / grid)
    K = _kernel(np.asarray(m), omega)  # (M, W)
    if by_component:
        return {k: (2.0 * (math.pi / grid) * (S @ K.mT)).numpy()
                for k, S in model.component_spectra(values, omega, h).items()}
    S = model.spectrum(values, omega, h)  # (B, W)
    return (2.0 * (math.pi / grid) * (S @ K.mT)).numpy()


def deterministic_avar(d: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Overlapping AVAR of a given (deterministic) series at cluster sizes ``m`` (its sample value)."""
    d = np.asarray(d, dtype=np.float64)
    c = np.concatenate([[0.0], np.cumsum(d)])
    out = []
    for mm in np.asarray(m, dtype=int):
        avg = (c[mm:] - c[:-mm]) / mm  # moving averages of length m
        diff = avg[mm:] - avg[:-mm]
        out.append(0.5 * float(np.mean(diff * diff)) if len(diff) else math.nan)
    return np.array(out)


def data_adev(y: np.ndarray, h: float, m: np.ndarray) -> np.ndarray:
    """The data's overlapping ADEV at cluster sizes ``m`` (allantools, frequency-type data)."""
    import allantools

    taus = np.asarray(m, dtype=np.float64) * h
    t, ad, _, _ = allantools.oadev(np.asarray(y, dtype=np.float64), rate=1.0 / h, data_type="freq", taus=taus)
    if len(t) != len(taus) or not np.allclose(t, taus):
        raise ValueError(f"allantools returned τ {t} for the requested {taus}")
    return ad


def power_law_alpha(avar: np.ndarray, m: np.ndarray) -> np.ndarray:
    """The power-law frequency-noise exponent (S ∝ f^α; white 0, flicker −1, random walk −2, white phase 2)
    closest to the local log–log slope μ of ADEV (ADEV ∝ τ^μ, α = −2μ − 1), for Greenhall's EDF."""
    lm, la = np.log(np.asarray(m, dtype=np.float64)), 0.5 * np.log(avar)
    mu = np.gradient(la, lm) if len(lm) > 1 else np.full_like(la, -0.5)
    a = np.rint(-2.0 * mu - 1.0)
    return np.where(mu < -0.75, 2, np.clip(a, -2, 0)).astype(int)


def allan_edf(alpha: np.ndarray, m: np.ndarray, n: int) -> np.ndarray:
    """Greenhall's equivalent degrees of freedom of the overlapping AVAR of ``n`` frequency samples."""
    import allantools

    return np.array([float(allantools.edf_greenhall(alpha=int(a), d=2, m=int(mm), N=n + 1, overlapping=True,
                                                    modified=False)) for a, mm in zip(alpha, m)])

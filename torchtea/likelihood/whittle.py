r"""Whittle likelihood: the spectrum's fit to the periodogram, O(N log N) (ALGORITHMS.md §5, §7).

With Fourier frequencies :math:`\omega_j = 2\pi j/N`, :math:`0 < j < N/2`, and the periodogram
:math:`I(\omega) = |\sum_k y_k e^{-i\omega k}|^2 / (2\pi N)` of the series with its deterministic part
removed,

.. math::  \ell_W = -\sum_j \left[\log 4\pi^2 S(\omega_j) + I(\omega_j)/S(\omega_j)\right],

which approximates the Gaussian log-likelihood :math:`-\tfrac12[N\log 2\pi + \log\det\Sigma + y^T\Sigma^{-1}y]`
on the same scale (:math:`\log\det\Sigma \approx \sum_j \log 2\pi S(\omega_j)` over all N frequencies;
each pair ±ω_j counted once, the zero frequency — the mean — and Nyquist left out). Exact for no finite N; the approximation is good for
long stationary series, and for a random walk (not stationary) it is the usual pseudo-likelihood.
"""
from __future__ import annotations

import math

import torch
from torch import Tensor

__all__ = ["periodogram", "whittle_loglik"]


def periodogram(y: Tensor) -> tuple[Tensor, Tensor]:
    """``(ω (W,), I (*B, W))`` at the Fourier frequencies ``0 < j < N/2`` of ``y`` ``(*B, N)``.

    The series must be complete: a NaN raises ``ValueError`` (the exact filter handles missing samples)."""
    y = torch.as_tensor(y, dtype=torch.float64)
    if torch.isnan(y).any():
        raise ValueError("the Whittle likelihood needs a complete series (it has missing samples); "
                         "use the exact method, which predicts through gaps")
    N = y.shape[-1]
    if N < 8:
        raise ValueError(f"the Whittle likelihood needs at least 8 samples, got {N}")
    d = torch.fft.rfft(y, dim=-1)
    j = torch.arange(1, (N - 1) // 2 + 1)
    I = d[..., j].abs() ** 2 / (2.0 * math.pi * N)
    return 2.0 * math.pi * j.to(torch.float64) / N, I


def whittle_loglik(spectrum: Tensor, I: Tensor) -> Tensor:
    """``ℓ_W`` of periodogram ``I`` ``(*B, W)`` under spectral density ``spectrum`` ``(*B, W)`` → ``(*B,)``."""
    return -(torch.log(4.0 * math.pi ** 2 * spectrum) + I / spectrum).sum(-1)

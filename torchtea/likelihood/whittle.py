r"""Whittle likelihood: the spectrum's fit to the periodogram, O(N log N) (ALGORITHMS.md §5, §7).

With Fourier frequencies :math:`\omega_j = 2\pi j/N`, :math:`0 < j < N/2`, and the periodogram
:math:`I(\omega) = |\sum_k y_k e^{-i\omega k}|^2 / (2\pi N)` of the series with its deterministic part
removed,

.. math::  \ell_W = -\sum_j \left[\log 4\pi^2 S(\omega_j) + I(\omega_j)/S(\omega_j)\right],

which approximates the Gaussian log-likelihood :math:`-\tfrac12[N\log 2\pi + \log\det\Sigma + y^T\Sigma^{-1}y]`
on the same scale (:math:`\log\det\Sigma \approx \sum_j \log 2\pi S(\omega_j)` over all N frequencies;
each pair ±ω_j counted once, the zero frequency — the mean — and Nyquist left out). Exact for no finite N; the approximation is good for
long stationary series, and for a random walk (not stationary) it is the usual pseudo-likelihood.

**Binned.** The model spectra are smooth, so their terms need not be evaluated at all N/2 frequencies:
:func:`whittle_data` keeps the lowest ordinates one by one and groups the others in bins whose width is a
fixed fraction (``resolution``, default 1/200) of their frequency, about 1 300 terms for any N above a few
thousand. In each bin b of :math:`m_b` ordinates the sum becomes
:math:`m_b [\log 4\pi^2 S(\bar\omega_b) + \bar I_b / S(\tilde\omega_b)]`, with :math:`\bar I_b` the mean
ordinate, :math:`\bar\omega_b` the geometric mean frequency of the bin and :math:`\tilde\omega_b` the
frequency whose logarithm is the :math:`I`-weighted mean of the bin's log frequencies. Both are the centres
that make the first-order term of :math:`\log S` and :math:`1/S` in :math:`\log\omega` vanish, so a bin's
error is second order in its width (relative :math:`\approx (\mathrm d\log S/\mathrm d\log\omega)^2 \delta^2/24`,
about 10⁻⁶ at δ = 1/200 for a power law of slope −1); and a line in the data — power on one ordinate — pulls
:math:`\tilde\omega_b` onto its own frequency, so its term is that of the full sum. ``resolution=None`` keeps
every ordinate (the full sum above, term for term).
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

__all__ = ["periodogram", "whittle_loglik", "WhittleData", "whittle_data", "whittle_scores", "Regressors",
           "regressors_data", "RESOLUTION"]

#: Relative width of the binned Whittle sum's bins (:func:`whittle_data`).
RESOLUTION = 1.0 / 200.0


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


@dataclass(frozen=True)
class WhittleData:
    """The terms of a (binned) Whittle sum of ``S`` series: per term its number of Fourier ordinates ``weight``
    ``(W,)``, the frequency of its log-spectrum ``omega_log`` ``(W,)``, the frequency of its ratio term ``omega_I``
    ``(S, W)`` and the mean periodogram ordinate ``I`` ``(S, W)``; and the sum's full resolution: each term's first
    ordinate ``first`` ``(W,)``, every ordinate's frequency ``omega_full`` ``(W₀,)`` and periodogram ``I_full``
    ``(S, W₀)`` (a rough bin is summed from them, :meth:`rough`). With ``weight`` all ones and both frequencies the
    Fourier frequencies it is the full sum."""

    weight: Tensor
    omega_log: Tensor
    omega_I: Tensor
    I: Tensor
    first: Tensor
    omega_full: Tensor
    I_full: Tensor
    #: a linear mean's regressors in the frequency domain (the sum is profiled over their coefficients), or None
    regressors: Regressors | None = None

    @property
    def terms(self) -> int:
        return int(self.weight.shape[-1])

    def rows(self, rows: Tensor) -> WhittleData:
        """The data of series ``rows``."""
        return WhittleData(self.weight, self.omega_log, self.omega_I[rows], self.I[rows], self.first,
                           self.omega_full, self.I_full[rows],
                           None if self.regressors is None else self.regressors.rows(rows))

    def frequencies(self) -> Tensor:
        """``(S, 2W)``: where a spectrum must be evaluated — the log frequencies, then the ratio frequencies."""
        S = self.I.shape[0]
        return torch.cat([self.omega_log.expand(S, -1), self.omega_I], dim=-1)

    def loglik(self, spectrum: Tensor) -> Tensor:
        """``ℓ_W`` ``(S,)`` of the binned terms from the spectrum evaluated at :meth:`frequencies` ``(S, 2W)`` (or
        ``(B, 2W)`` with B = S) — without the full resolution of rough bins (:meth:`rough`; the fits add it)."""
        W = self.terms
        s_log, s_I = spectrum[..., :W], spectrum[..., W:]
        return -(self.weight * (torch.log(4.0 * math.pi ** 2 * s_log) + self.I / s_I)).sum(-1)

    def rough(self, spectrum: Tensor) -> Tensor:
        """``(B, W)``: the bins (of more than one ordinate) across which the spectrum at :meth:`frequencies` ``(B,
        2W)`` is not smooth — its logarithm at the ratio term's frequency more than :data:`ROUGHNESS` from its
        logarithm at the log term's (a smooth spectrum moves by about its log-log slope times a 200th there), or its
        log-log slope to a neighbouring term steeper than :data:`STEEP`. A
        bin's terms hold only where the spectrum is smooth across it: a narrow band of the model inside a bin —
        a resonance narrower than the bin, placed on the ratio term's frequency — would take the bin's ratio term
        without paying its log term. The fits sum a rough bin at full resolution (:meth:`ordinates`)."""
        W = self.terms
        log_s = torch.log(spectrum[..., :W])
        rough = torch.log(spectrum[..., W:] / spectrum[..., :W]).abs() > ROUGHNESS
        slope = (torch.diff(log_s, dim=-1) / torch.diff(torch.log(self.omega_log))).abs() > STEEP
        rough[..., :-1] |= slope
        rough[..., 1:] |= slope
        return rough & (self.weight > 1)

    def ordinates(self, terms: Tensor) -> Tensor:
        """The indices (into :attr:`omega_full`, :attr:`I_full`) of every ordinate of the terms where ``terms``
        ``(W,)`` (a mask) is set."""
        return terms[self.term_of].nonzero().squeeze(-1)

    @functools.cached_property
    def term_of(self) -> Tensor:
        """``(W₀,)``: each ordinate's term."""
        return torch.repeat_interleave(torch.arange(self.terms), torch.diff(torch.cat([
            self.first, self.first.new_tensor([self.omega_full.shape[-1]])])))


#: A bin is rough (:meth:`WhittleData.rough`) where the log-spectrum differs by more than ROUGHNESS between its two
#: frequencies, or where its log-log slope to a neighbouring term is steeper than STEEP (a sensor's two-stage filter
#: falls at −4, a power law at −2α: only a band's flanks are steeper).
ROUGHNESS, STEEP = 0.05, 10.0


def bin_edges(W: int, resolution: float | None) -> Tensor:
    """Start indices of the bins over the ordinates 0 … W−1 (ordinate i is Fourier frequency i + 1), and W at the
    end: single ordinates while ``resolution · j < 1``, then bins of ``⌊resolution · j⌋`` ordinates."""
    if resolution is None:
        return torch.arange(W + 1)
    edges, j = [], 1
    while j <= W:
        edges.append(j - 1)
        j += max(1, int(resolution * j))
    edges.append(W)
    return torch.tensor(edges)


def whittle_data(omega: Tensor, I: Tensor, resolution: float | None = RESOLUTION, *, residual: Tensor | None = None,
                 columns: Tensor | None = None) -> WhittleData:
    """:class:`WhittleData` of periodograms ``I`` ``(S, W)`` (or ``(W,)``) at Fourier frequencies ``omega`` ``(W,)``,
    binned at ``resolution`` (module docstring; None: every ordinate its own term). With ``columns`` ``(S, p, N)``, a
    linear mean's centred regressors, and ``residual`` ``(S, N)``, the series with the rest of its mean removed
    (``I`` then the periodogram of its least-squares residual, which places the ratio terms' frequencies), the sum is
    profiled over the regressors' coefficients (:class:`Regressors`)."""
    I = torch.as_tensor(I, dtype=torch.float64)
    I = I.unsqueeze(0) if I.ndim == 1 else I
    omega = torch.as_tensor(omega, dtype=torch.float64)
    W = omega.shape[-1]
    edges = torch.arange(W + 1) if resolution is None else bin_edges(W, resolution)
    reg = None if columns is None or columns.shape[-2] == 0 else regressors_data(
        torch.as_tensor(residual, dtype=torch.float64), torch.as_tensor(columns, dtype=torch.float64), edges)
    if resolution is None:
        return WhittleData(torch.ones(W, dtype=torch.float64), omega, omega.expand(I.shape[0], -1).clone(), I,
                           torch.arange(W), omega, I, reg)
    counts = (edges[1:] - edges[:-1]).to(torch.float64)
    starts = edges[:-1].numpy()
    lw = torch.log(omega)

    def bin_sum(x):  # sums over each bin of the last dimension, each in order (deterministic, unlike a threaded
        # index_add_, whose rounding changed with the threads' timing and moved a fit's estimate by 1e-8)
        return torch.from_numpy(np.add.reduceat(x.numpy(), starts, axis=-1))

    omega_log = torch.exp(bin_sum(lw) / counts)
    total = bin_sum(I)
    safe = torch.where(total > 0, total, torch.ones_like(total))
    omega_I = torch.where(total > 0, torch.exp(bin_sum(I * lw) / safe), omega_log.expand_as(total))
    return WhittleData(counts, omega_log, omega_I, total / counts, edges[:-1].clone(), omega, I, reg)


@dataclass(frozen=True)
class Regressors:
    r"""A linear mean's regressors in the frequency domain: the Whittle sum of :math:`y - Xeta` profiled over
    :math:`eta` (generalised least squares under the spectrum, not ordinary least squares before it — a trend
    removed by the latter takes a random walk's slow power with it). Per series the transforms of the series with
    the rest of its mean removed ``Y`` ``(S, W₀)`` and of its p centred regressors ``X`` ``(S, p, W₀)`` at the Fourier
    ordinates (complex, over :math:`\sqrt{2\pi N}`, so that :math:`|Y_j|^2` is the periodogram), and per term the
    sums ``A`` ``(S, W)`` of :math:`|Y_j|^2`, ``c`` ``(S, p, W)`` of :math:`\mathrm{Re}\,ar Y_j X_j` and ``M``
    ``(S, p, p, W)`` of :math:`\mathrm{Re}\,ar X_j X_j^T`: a term's periodogram at β is
    :math:`(A - 2c^Teta + eta^T M eta)/m`."""

    Y: Tensor
    X: Tensor
    A: Tensor
    c: Tensor
    M: Tensor

    def rows(self, rows: Tensor) -> Regressors:
        return Regressors(self.Y[rows], self.X[rows], self.A[rows], self.c[rows], self.M[rows])

    def ordinates(self, series: Tensor, ords: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        r"""At the ordinates ``ords`` ``(K,)`` of the series ``series`` ``(k,)``: :math:`|Y_j|^2` ``(k, K)``,
        :math:`\mathrm{Re}\,\bar Y_j X_j` ``(k, p, K)`` and :math:`\mathrm{Re}\,\bar X_j X_j^T` ``(k, p, p, K)``."""
        Y, X = self.Y[series][:, ords], self.X[series][..., ords]
        return ((Y.conj() * Y).real, (Y.conj().unsqueeze(1) * X).real,
                (X.conj().unsqueeze(2) * X.unsqueeze(1)).real)


def regressors_data(residual: Tensor, columns: Tensor, edges: Tensor) -> Regressors:
    """:class:`Regressors` of series ``residual`` ``(S, N)`` (the rest of the mean removed) and their centred
    regressors ``columns`` ``(S, p, N)``, summed over the terms that start at ``edges`` (:func:`bin_edges`)."""
    N = residual.shape[-1]
    j = torch.arange(1, (N - 1) // 2 + 1)
    scale = math.sqrt(2.0 * math.pi * N)
    Y = torch.fft.rfft(residual, dim=-1)[..., j] / scale
    X = torch.fft.rfft(columns, dim=-1)[..., j] / scale
    starts = edges[:-1].numpy()

    def bin_sum(x):
        return torch.from_numpy(np.add.reduceat(x.numpy(), starts, axis=-1))

    A = bin_sum((Y.conj() * Y).real)
    c = bin_sum((Y.conj().unsqueeze(1) * X).real)
    M = bin_sum((X.conj().unsqueeze(2) * X.unsqueeze(1)).real)
    return Regressors(Y, X, A, c, M)


def whittle_scores(weight: Tensor, I: Tensor, spectrum: Tensor, derivatives: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    r"""−ℓ_W ``(B,)`` of a (binned) Whittle sum, its gradient ``(B, F)`` and its expected information ``(B, F, F)`` from
    the spectrum at :meth:`WhittleData.frequencies` ``(B, 2W)`` and its derivatives ``(B, F, 2W)`` along F
    coordinates; ``weight`` ``(W,)`` (or ``(B, W)``: a row's own, 0 for a term summed apart) and the mean ordinates
    ``I`` ``(B, W)`` (or ``(1, W)``) as :class:`WhittleData` holds them; for the full sum both frequencies are the
    same and ``spectrum`` may be given once, ``(B, W)``. With :math:`d_j = \nabla\log S(\omega_j)`:

    .. math::  \nabla(-\ell_W) = \sum_j m_j \big[d_j^{\log} - (\bar I_j/S_j^{I})\,d_j^{I}\big], \qquad
               \mathcal I = \sum_j m_j\, d_j^{I} d_j^{I\,T},

    the second the expectation of the Hessian where :math:`E\,\bar I_j = S_j` (the second derivatives of
    :math:`\log S` cancel between the two terms: Whittle's Fisher information, as in Dzhaparidze, *Parameter
    Estimation and Hypothesis Testing in Spectral Analysis of Stationary Time Series*, 1986): positive
    semi-definite by construction, so the method of scoring takes no indefinite step."""
    W = I.shape[-1]
    once = spectrum.shape[-1] == W
    s_log, s_I = (spectrum, spectrum) if once else (spectrum[..., :W], spectrum[..., W:])
    ratio = I / s_I
    value = (weight * (torch.log(4.0 * math.pi ** 2 * s_log) + ratio)).sum(-1)
    d_log = (derivatives if once else derivatives[..., :W]) / s_log.unsqueeze(-2)
    d_I = d_log if once else derivatives[..., W:] / s_I.unsqueeze(-2)
    w = weight.unsqueeze(-2)
    grad = (d_log * w).sum(-1) - (d_I * (weight * ratio).unsqueeze(-2)).sum(-1)
    info = (d_I * w) @ d_I.mT
    return value, grad, info

"""The filters' linear algebra: the product of the small matrices (:func:`_mm`), projections onto the PSD cone, square
roots, the unscented transform's sigma points and update (paper (15)–(24)), the error covariance under a constant
truth, and the Robbins–Monro adaptation of a drive (25) — what KFo and KFw (and the exact-KFx TEA,
:mod:`torchtea.noise.tea_exact`) are made of."""
from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["sigma_points", "ut_update", "adapt_q", "sqrt_psd", "MATMUL_DEVICES"]


#: Devices where :func:`_mm` calls the matrix product (elsewhere: a broadcast product and sum).
MATMUL_DEVICES = {"cpu"}


def _mm(a: Tensor, b: Tensor) -> Tensor:
    """``a @ b``. While torch.compile traces, and off the CPU, a broadcast product and sum instead, which the
    compiler fuses with its neighbours: the matrices here are a few rows wide, and an external GEMM call per
    product costs more than its arithmetic (on a GPU a batched 1×1 GEMM over 10⁵ realisations took ~50 µs,
    the elementwise product ~5 µs)."""
    if torch.compiler.is_compiling() or a.device.type not in MATMUL_DEVICES:
        return (a.unsqueeze(-1) * b.unsqueeze(-3)).sum(-2)
    return a @ b


def _symmetrise(M: Tensor) -> Tensor:
    return 0.5 * (M + M.mT)


def _psd(M: Tensor) -> Tensor:
    """Project a batch of symmetric matrices onto the PSD cone."""
    M = _symmetrise(M)
    if M.shape[-1] == 1:
        return M.clamp(min=0.0)
    vals, vecs = torch.linalg.eigh(M)
    return _mm(vecs * vals.clamp(min=0.0).unsqueeze(-2), vecs.mT)


def sqrt_psd(M: Tensor) -> Tensor:
    """A square root ``S`` with ``S Sᵀ = M``: Cholesky (the paper's choice), eigen fallback."""
    if M.shape[-1] == 1:
        return M.clamp(min=0.0).sqrt()
    Lc, info = torch.linalg.cholesky_ex(M)
    if bool((info != 0).any()):
        vals, vecs = torch.linalg.eigh(_symmetrise(M))
        alt = vecs * vals.clamp(min=0.0).sqrt().unsqueeze(-2)
        Lc = torch.where((info != 0)[..., None, None], alt, Lc)
    return Lc


def sigma_points(mean: Tensor, cov: Tensor, scale: float) -> Tensor:
    """Sigma points (15)/(40): ``[m, m + Sᵢ, m − Sᵢ]`` with ``S Sᵀ = scale · cov``; ``(*B, 2L+1, L)``."""
    S = sqrt_psd(scale * cov).mT  # rows are the columns of the root
    m = mean.unsqueeze(-2)
    return torch.cat([m, m + S, m - S], dim=-2)


def _gain(Pxy: Tensor, Pyy: Tensor, mask: Tensor) -> Tensor:
    """Kalman gain ``Pxy Pyy⁻¹`` (22)/(33) with unobserved outputs (``mask`` False) ignored.

    Pxy ``(*B, q, p)``, Pyy ``(*B, p, p)``, mask ``(*B, p)`` → ``(*B, q, p)``;
    columns of missing outputs are zero.
    """
    if Pyy.shape[-1] == 1:
        return torch.where(mask.unsqueeze(-2), Pxy / Pyy, torch.zeros_like(Pxy))
    both = mask.unsqueeze(-1) & mask.unsqueeze(-2)
    eye = torch.eye(Pyy.shape[-1], dtype=Pyy.dtype, device=Pyy.device)
    Pyy_m = torch.where(both, Pyy, eye.expand_as(Pyy))
    Pxy_m = torch.where(mask.unsqueeze(-2), Pxy, torch.zeros_like(Pxy))
    return torch.linalg.solve(Pyy_m, Pxy_m.mT).mT


def ut_update(points, Y, prior_mean, prior_cov, R, y, mask, wm, wc, start):
    """Unscented update (19)–(24): returns (mean, cov, gain, innovation, Pyy, Pxy).

    points ``(*B, S, q)``, Y ``(*B, S, p)``; sums over sigma points ``i ≥ start`` in (20)–(21).
    """
    y_pred = _mm(wm.unsqueeze(-2), Y).squeeze(-2)  # (19): Σ_i W_i^m Y_i
    dY = (Y - y_pred.unsqueeze(-2))[..., start:, :]
    dX = (points - prior_mean.unsqueeze(-2))[..., start:, :]
    wdY = dY * wc[start:].unsqueeze(-1)
    Pyy = _mm(wdY.mT, dY) + R  # (20)
    Pxy = _mm(dX.mT, wdY)  # (21)
    K = _gain(Pxy, Pyy, mask)  # (22)
    e = torch.where(mask, y - y_pred, torch.zeros_like(y_pred))
    mean = prior_mean + _mm(K, e.unsqueeze(-1)).squeeze(-1)  # (23)
    cov = _psd(prior_cov - _mm(_mm(K, Pyy), K.mT))  # (24)
    return mean, cov, K, e, Pyy, Pxy


def _constant_truth_cov(Sigma, prior_cov, K, Pyy, Pxy):
    """The covariance of an unscented filter's error after its update when the truth is constant
    (``estimate_uncertainty = "constant-truth"``): ``(I − K H) Σ (I − K H)ᵀ + K (P_yy − H P̃ Hᵀ) Kᵀ`` with ``H =
    P_σyᵀ P̃⁻¹`` (statistical linearisation over the sigma points drawn with ``prior_cov`` = P̃) and ``Σ`` the
    previous error covariance, no ``Q`` added. ``K`` has zero columns for missing outputs, so a missing sample
    leaves ``Σ`` as it is. Where P̃ is zero, ``H`` is zero."""
    H = _over_cov(Pxy.mT, prior_cov)  # (*B, p, L)
    R_eff = _psd(Pyy - _mm(_mm(H, prior_cov), H.mT))
    return _psd(_joseph(Sigma, K, H, R_eff))


def _joseph(P, K, H, R):
    """``(I − K H) P (I − K H)ᵀ + K R Kᵀ``: the covariance of an update's error with gain ``K`` for a measurement
    ``H`` with noise ``R`` whatever ``P`` the gain came from (not symmetrised)."""
    IKH = torch.eye(P.shape[-1], dtype=P.dtype, device=P.device) - _mm(K, H)
    return _mm(_mm(IKH, P), IKH.mT) + _mm(_mm(K, R), K.mT)


def adapt_q(Q, K, e, delta: float, q_max: Tensor, observed):
    """Robbins–Monro adaptation (25): ``Q ← (1−δ) Q + δ (K e)(K e)ᵀ``, scaled down so that its largest
    diagonal entry stays ≤ ``q_max`` (``(*B,)``, +inf for no cap)."""
    if delta == 0.0:
        return Q
    Ke = _mm(K, e.unsqueeze(-1))
    Qn = (1.0 - delta) * Q + delta * _mm(Ke, Ke.mT)
    top = torch.diagonal(Qn, dim1=-2, dim2=-1).amax(-1).clamp(min=torch.finfo(Qn.dtype).tiny)
    Qn = Qn * (q_max / top).clamp(max=1.0)[..., None, None]
    return torch.where(observed[..., None, None], Qn, Q)


def _over_cov(M, prior_cov):
    """``M P̃⁻¹``, the statistical linearisation's division by the covariance the sigma points were drawn with:
    M ``(*B, r, L)``, prior_cov ``(*B, L, L)``; a scalar P̃ divides (zero where P̃ is zero), a matrix one takes the
    pseudo-inverse."""
    if prior_cov.shape[-1] == 1:
        p = prior_cov[..., 0, 0]
        return torch.where((p > 0)[..., None, None], M / torch.where(p > 0, p, 1.0)[..., None, None], 0.0)
    return _mm(M, torch.linalg.pinv(prior_cov, hermitian=True))

r"""The exact Kalman filter on a model's stacked state (ALGORITHMS.md §4 last paragraph, §7).

With ``soe`` memory the fractional component is a finite linear Gaussian state
``[x_k … x_{k−J₀+1}, H_1 … H_L, R]``, so one ordinary Kalman filter on the stacked state of all components
gives the innovations :math:`e_k`, their variances :math:`S_k` and the log-likelihood

.. math::  \ell = -\tfrac12 \sum_{k\ \text{observed}} \left(\log 2\pi S_k + e_k^2/S_k\right)

exact to the kernel's tolerance — none of the fractional KF's neglected cross-covariances. A missing
sample (NaN) is predicted through: no update, no term in ℓ, and its innovation is NaN.

Two implementations of one algorithm, tested against each other:

* :func:`kalman_filter` — torch, batched over parameter sets, differentiable, any device; it also
  returns the filtered states and, with ``smooth=True``, the Rauch–Tung–Striebel smoothed ones;
* :func:`loglik_fast` — the same recursion compiled by numba on the CPU, exploiting the transition's
  sparsity (O(n²) per step instead of O(n³)): the engine for long series and for fitting.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from ..noise.model import StateSpace, varying_kernel_args
from ..noise.simulate_kernel import csr

__all__ = ["FilterResult", "kalman_filter", "loglik_fast", "filter_fast"]


@dataclass(frozen=True)
class FilterResult:
    """Innovations ``e`` and their variances ``S`` ``(B, N)`` (NaN / predicted variance where missing),
    the one-step predictions of the measurement ``prediction`` ``(B, N)``, ``loglik`` ``(B,)``,
    ``observed`` (number of terms in ℓ); with ``keep_states``, filtered means ``(B, N, n)`` and, with
    ``smooth``, also the smoothed means ``(B, N, n)``."""

    innovation: Tensor
    variance: Tensor
    prediction: Tensor
    loglik: Tensor
    observed: int
    filtered: Tensor | None = None
    smoothed: Tensor | None = None

    @property
    def standardized(self) -> Tensor:
        """``e_k / √S_k``: standard normal and white when the model is right."""
        return self.innovation / torch.sqrt(self.variance)


def _as_series(y, B: int) -> Tensor:
    y = torch.as_tensor(y, dtype=torch.float64)
    if y.ndim == 1:
        y = y.unsqueeze(0)
    return y.expand(B, -1) if y.shape[0] == 1 and B > 1 else y


def kalman_filter(ss: StateSpace, y, mean=None, *, keep_states: bool = False, smooth: bool = False,
                  level: bool = False) -> FilterResult:
    """Run the exact filter on ``y`` ``(B, N)`` (or ``(N,)``), ``mean`` the deterministic part ``(B, N)``.

    ``level=True``: ``y`` has an unknown constant level c besides ``mean``. The filter is linear in the data and its
    gains do not depend on them, so the innovations of ``y − c`` are ``e − c w`` with ``w`` the innovations of the
    constant 1 through the same filter, and ℓ is quadratic in c: ``ℓ(c) = ℓ(0) + c Σ e w/S − ½ c² Σ w²/S``, at
    its maximum at the generalised-least-squares level ``ĉ = Σ e w/S / Σ w²/S``. The returned log-likelihood is
    the density integrated over c (a flat prior: the *diffuse* likelihood),
    ``ℓ(ĉ) + ½ log(2π / Σ w²/S)``, and the innovations are ``e − ĉ w``. Unlike removing the sample mean this is
    exact for any model, a random walk's included (whose path need not start at the series' mean). Integrated
    rather than maximised: where the first sample's variance can go to 0 (a low-pass with nothing after it, its
    white noise → 0) the maximised ℓ grows without bound as the level pins that sample, the integrated one does
    not. The quadratic term is accumulated by recursive least squares, so a tiny S does not cancel digits."""
    F, Q, C, R = ss.F, ss.Q, ss.C, ss.R
    B, n = F.shape[0], F.shape[-1]
    if smooth and (ss.varying is not None or level):
        raise NotImplementedError("the smoother with a time-varying order (temperature-order) or an unknown level "
                                  "is not implemented")
    y = _as_series(y, B)
    N = y.shape[-1]
    mu = torch.zeros_like(y) if mean is None else _as_series(mean, B).to(y)
    z = y.new_zeros(B, n)
    g0 = ss.initial.to(y)
    P = g0.unsqueeze(-1) * g0.unsqueeze(-2)
    es, Ss, preds, zs, Ps, zps, Pps = [], [], [], [], [], [], []
    # the level's regressor w (the constant 1 through the filter) and its recursive least squares
    lv = {"w": y.new_zeros(B, n), "ws": [], "sww": y.new_zeros(B), "beta": y.new_zeros(B),
          "rss": y.new_zeros(B)} if level else None
    ll = y.new_zeros(B)
    observed = 0
    Ft = F.mT
    for k in range(N):
        if smooth:
            zps.append(z)
            Pps.append(P)
        Pc = (P @ C.unsqueeze(-1)).squeeze(-1)  # (B, n)
        S = (C * Pc).sum(-1) + R
        pred = mu[:, k] + (C * z).sum(-1)
        e = y[:, k] - pred
        ok = ~torch.isnan(e)
        if bool(ok.any()):
            observed += int(ok.sum())
            z, P, ll = _update(z, P, ll, C, Pc, S, e, ok, lv)
        elif level:
            lv["ws"].append(1.0 - (C * lv["w"]).sum(-1))
        es.append(e)
        Ss.append(S)
        preds.append(pred)
        if keep_states or smooth:
            zs.append(z)
            Ps.append(P)
        Fk, Ftk, Qk = _transition(ss, F, Ft, Q, k)
        z = (z.unsqueeze(-2) @ Ftk).squeeze(-2)
        if level:
            lv["w"] = (lv["w"].unsqueeze(-2) @ Ftk).squeeze(-2)
        P = Fk @ P @ Ftk + Qk
    filtered = torch.stack(zs, dim=1) if (keep_states or smooth) else None
    smoothed = _smooth(zs, Ps, zps, Pps, Ft, N) if smooth else None
    e_all, pred_all = torch.stack(es, 1), torch.stack(preds, 1)
    if level:
        e_all, pred_all, ll = _level_result(e_all, pred_all, ll, lv)
    return FilterResult(e_all, torch.stack(Ss, 1), pred_all, ll, observed, filtered, smoothed)


def _update(z, P, ll, C, Pc, S, e, ok, lv):
    """The measurement update of one sample (where ``ok``: observed) of the state, its covariance and ℓ."""
    e0 = torch.where(ok, e, torch.zeros_like(e))
    K = Pc / S.unsqueeze(-1)
    okf = ok.to(e.dtype).unsqueeze(-1)
    z = z + okf * K * e0.unsqueeze(-1)
    P = P - okf.unsqueeze(-1) * (K.unsqueeze(-1) * Pc.unsqueeze(-2))
    P = 0.5 * (P + P.mT)
    if lv is not None:
        ll = ll - 0.5 * torch.where(ok, torch.log(2.0 * math.pi * S), torch.zeros_like(S))
        _level_step(lv, C, S, e0, ok, okf, K)
    else:
        ll = ll - 0.5 * torch.where(ok, torch.log(2.0 * math.pi * S) + e0 * e0 / S, torch.zeros_like(S))
    return z, P, ll


def _level_step(lv: dict, C, S, e0, ok, okf, K) -> None:
    """One observed sample's step of the level's regressor and its recursive least squares (``lv``, in place)."""
    sww, beta, rss, w = lv["sww"], lv["beta"], lv["rss"], lv["w"]
    ew = torch.where(ok, 1.0 - (C * w).sum(-1), torch.zeros_like(e0))
    lv["ws"].append(ew)
    # recursive weighted least squares of e on w, as the compiled filter does
    started = sww > 0
    d = e0 - beta * ew
    safe = torch.where(started, sww, torch.ones_like(sww))
    rss = rss + torch.where(started, d * d / (S + ew * ew / safe),
                            torch.where(ew != 0, torch.zeros_like(S), e0 * e0 / S))
    sww_new = sww + ew * ew / S
    beta = torch.where(started, beta + (ew / S) * d / torch.where(started, sww_new, torch.ones_like(sww)),
                       torch.where(ew != 0, e0 / torch.where(ew != 0, ew, torch.ones_like(ew)), beta))
    lv["sww"], lv["beta"], lv["rss"] = sww_new, beta, rss
    lv["w"] = w + okf * K * ew.unsqueeze(-1)


def _transition(ss: StateSpace, F, Ft, Q, k: int):
    """Step k's ``(F, Fᵀ, Q)``: with a time-varying order, row i of F and Q[i, i] of this step."""
    if ss.varying is None:
        return F, Ft, Q
    v = ss.varying
    Fk, Qk = F.clone(), Q.clone()
    Fk[:, v.i] = v.row(k)
    Qk[:, v.i, v.i] = v.loading(k) ** 2
    return Fk, Fk.mT, Qk


def _smooth(zs: list, Ps: list, zps: list, Pps: list, Ft, N: int) -> Tensor:
    """The Rauch–Tung–Striebel smoothed means ``(B, N, n)`` from the filtered and predicted ones."""
    zsm = zs[-1]
    Psm = Ps[-1]
    out = [zsm]
    for k in range(N - 2, -1, -1):
        Pp = Pps[k + 1]
        # J = P_k|k Fᵀ P_{k+1|k}⁺ (pseudo-inverse: the zero-variance start has singular predictions)
        J = Ps[k] @ Ft @ torch.linalg.pinv(Pp, hermitian=True)
        zsm = zs[k] + (J @ (zsm - zps[k + 1]).unsqueeze(-1)).squeeze(-1)
        Psm = Ps[k] + J @ (Psm - Pp) @ J.mT
        out.append(zsm)
    return torch.stack(out[::-1], dim=1)


def _level_result(e_all, pred_all, ll, lv: dict):
    """The innovations, predictions and ℓ with the level at its estimate (ℓ integrated over it)."""
    W = torch.stack(lv["ws"], 1)
    beta, rss, sww = lv["beta"], lv["rss"], lv["sww"]
    e_all = e_all - beta.unsqueeze(-1) * W
    pred_all = pred_all + beta.unsqueeze(-1) * W
    ll = ll - 0.5 * rss + torch.where(sww > 0, 0.5 * torch.log(2.0 * math.pi / torch.where(sww > 0, sww, torch.ones_like(sww))),
                                      torch.zeros_like(ll))
    return e_all, pred_all, ll


# --------------------------------------------------------------------------- the compiled fast path

def _compiled():
    """The Riccati batch kernel (numba; compiled on first use, then loaded from numba's on-disk cache)."""
    try:
        from ._kernels import riccati_batch
    except ImportError as exc:  # pragma: no cover - numba is a dependency
        raise ImportError("the fast exact filter needs numba (pip install numba)") from exc
    return riccati_batch


#: The compiled exact filter's engines: ``"chandrasekhar"`` (:mod:`.chandrasekhar`, O(n r) per sample, for a
#: time-invariant model) and ``"riccati"`` (the textbook covariance update, O(n²) per sample, any model); ``"auto"``
#: takes the first where it applies.
ENGINES = ("auto", "chandrasekhar", "riccati")


def _engine(ss: StateSpace, engine: str | None) -> str:
    from .settings import current

    engine = engine or current().exact
    if engine not in ENGINES:
        raise ValueError(f"engine must be one of {ENGINES}, got {engine!r}")
    if engine == "chandrasekhar" and ss.varying is not None:
        raise ValueError("the Chandrasekhar recursions need a time-invariant model; a temperature-driven order makes "
                         "the transition vary (engine='riccati' or 'auto')")
    if engine == "auto":
        return "riccati" if ss.varying is not None else "chandrasekhar"
    return engine


def _rows(x, B: int) -> np.ndarray:
    """``(1, N)`` or ``(B, N)`` C-contiguous float64 for the kernels, which read row 0 for every parameter set when
    there is one: one series for all B sets is not copied B times (a likelihood's 11 difference points on 2·10⁶
    samples would copy 190 MB), and every call has the same array types, so numba compiles each kernel once."""
    a = np.ascontiguousarray(torch.as_tensor(x, dtype=torch.float64).detach().cpu().numpy(), dtype=np.float64)
    a = a.reshape(1, -1) if a.ndim == 1 else a
    if a.shape[0] not in (1, B):
        raise ValueError(f"{a.shape[0]} series for {B} parameter sets")
    return a


def _fast(ss: StateSpace, y, mean, keep: bool, level: bool = False, engine: str | None = None):
    F = ss.F.detach().cpu().numpy()
    B = F.shape[0]
    ya = _rows(y, B)
    N = ya.shape[-1]
    mu = np.zeros((1, N)) if mean is None else _rows(mean, B)
    C = ss.C.detach().cpu().numpy()
    cidx = np.nonzero((C != 0).any(axis=0))[0].astype(np.int64)
    indptr, indices, fvals = csr(F)
    e_out = np.zeros((B, N) if keep else (B, 1))
    s_out = np.zeros_like(e_out)
    w_out = np.zeros((B, N) if (keep and level) else (B, 1))
    R = np.ascontiguousarray(ss.R.detach().cpu().numpy(), dtype=np.float64)
    if _engine(ss, engine) == "chandrasekhar":
        from ._kernels import chandrasekhar_batch
        from .chandrasekhar import initial_factor

        G = ss.G.detach().cpu().numpy()
        g0 = None if ss.g0 is None else ss.g0.detach().cpu().numpy()
        first = np.broadcast_to(~np.isnan(ya[:, 0] - mu[:, 0]), (B,))  # whether sample 0 is observed, per set
        L0, M0, b0, S0 = initial_factor(F, G, C, R, g0, first)
        ll = chandrasekhar_batch(indptr, indices, fvals, np.ascontiguousarray(L0), np.ascontiguousarray(M0),
                                 np.ascontiguousarray(b0), np.ascontiguousarray(S0), np.ascontiguousarray(C), cidx, R,
                                 ya, mu, e_out, s_out, w_out, keep, bool(level))
        return ll, e_out, s_out
    tv_i, tv_T, tv_g, tv_j, tv_w, _ = varying_kernel_args(ss.varying, B, F.shape[-1])
    g0 = np.ascontiguousarray(ss.initial.detach().cpu().numpy(), dtype=np.float64)
    ll = _compiled()(indptr, indices, fvals, np.ascontiguousarray(ss.Q.detach().cpu().numpy()),
                     np.ascontiguousarray(C), cidx, R, ya, mu, e_out, s_out, w_out, keep, tv_i, tv_T, tv_g, tv_j, tv_w,
                     g0, bool(level))
    return ll, e_out, s_out


def loglik_fast(ss: StateSpace, y, mean=None, *, level: bool = False, engine: str | None = None) -> np.ndarray:
    """The exact log-likelihood ``(B,)`` as :func:`kalman_filter` computes it, compiled (CPU, float64,
    the parameter sets spread over the CPU's cores; no gradients). ``level=True``: integrated over an unknown
    constant added to ``y`` (see :func:`kalman_filter`). ``engine``: one of :data:`ENGINES` (default: the
    :mod:`.settings` in force, ``"auto"``)."""
    return _fast(ss, y, mean, False, level, engine)[0]


def filter_fast(ss: StateSpace, y, mean=None, *, level: bool = False, engine: str | None = None):
    """``(loglik (B,), innovations (B, N), variances (B, N))`` from the compiled filter (``level``, ``engine``: as in
    :func:`loglik_fast`; the innovations are then those of ``y`` minus the estimated constant)."""
    return _fast(ss, y, mean, True, level, engine)

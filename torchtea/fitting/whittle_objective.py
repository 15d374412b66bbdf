"""The Whittle sum as the method of scoring reads it (:class:`WhittleObjective`): its value, its gradient and its
expected information from the components' closed-form spectral derivatives, a rough bin summed at full
resolution, and the observed information at a maximum; :func:`whittle_value` at one point."""
from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

from ..likelihood.whittle import WhittleData, whittle_scores
from ..noise.derivatives import spectrum_jacobian
from ..noise.model import NoiseModel

__all__ = ["WhittleObjective", "whittle_value", "HESSIAN_STEP"]


class WhittleObjective:
    """−ℓ_W of K starts (rows of ``U0`` ``(K, P)``, unconstrained; row k fits series ``owner[k]`` of ``data``) as the
    method of scoring reads it (:func:`~.scoring.score`): over the coordinates ``idx``, the others held at ``U0``'s;
    :meth:`vgi` with its gradient and expected information from the components' closed-form spectral derivatives
    (:func:`~torchtea.noise.derivatives.spectrum_jacobian`, :func:`~torchtea.likelihood.whittle.whittle_scores`),
    :meth:`values` the value alone. +1e300 (zero gradient and information) where ℓ_W is not finite."""

    def __init__(self, model: NoiseModel, data: WhittleData, h: float, U0: Tensor, owner: Tensor, idx: np.ndarray):
        self.model, self.data, self.h, self.idx = model, data, h, torch.as_tensor(idx, dtype=torch.long)
        self.U0, self.owner = U0.detach().to(torch.float64), owner
        self.one = bool((owner == owner[0]).all())  # one series: its frequencies broadcast over the rows
        self.frequencies = data.frequencies()

    def _at(self, points, rows):
        rows = torch.as_tensor(np.asarray(rows), dtype=torch.long)
        U = self.U0[rows].clone()
        U[:, self.idx] = torch.as_tensor(np.asarray(points), dtype=torch.float64)
        series = self.owner[rows[:1]] if self.one else self.owner[rows]
        return U, self.frequencies[series], series

    def _spectrum(self, U: Tensor, omega: Tensor, grad: bool):
        """The model's spectrum at ``omega`` and, with ``grad``, its derivatives (else None)."""
        if grad:
            return spectrum_jacobian(self.model, U, omega, self.h, self.idx.tolist())
        return self.model.spectrum(self.model.from_unconstrained(U, self.h), omega, self.h), None

    def vgi(self, points, rows):
        U, omega, series = self._at(points, rows)
        S, dS = self._spectrum(U, omega, True)
        t = self._terms(U, rows, S, grad=True)
        f, g, info = whittle_scores(self.data.weight * ~t.rough, t.I, S, dS)
        if t.some is not None:  # (rough bins at full resolution: every row that has one in one batch)
            fj, gj, ij = whittle_scores(t.mask.to(torch.float64), t.Ij, t.Sj, t.dSj)
            some = t.some
            f[some], g[some], info[some] = f[some] + fj, g[some] + gj, info[some] + ij
        f, g, info = f.numpy(), g.numpy(), info.numpy()
        bad = ~(np.isfinite(f) & np.isfinite(g).all(-1) & np.isfinite(info).all((-1, -2)))
        return (np.where(bad, 1e300, f), np.where(bad[:, None], 0.0, g),
                np.where(bad[:, None, None], 0.0, info))

    def values(self, points, rows):
        U, omega, _ = self._at(points, rows)
        return self.minus_loglik(U, omega, rows)

    def minus_loglik(self, U: Tensor, omega: Tensor, rows) -> np.ndarray:
        """−ℓ_W ``(k,)`` at the points ``U`` ``(k, P)`` of the starts ``rows`` and their frequencies ``omega``: the
        binned terms, a rough bin's at full resolution, a linear mean's coefficients profiled out (+1e300 where not
        finite)."""
        S, _ = self._spectrum(U, omega, False)
        t = self._terms(U, rows, S, grad=False)
        W = self.data.terms
        f = (self.data.weight * ~t.rough * (torch.log(4.0 * math.pi ** 2 * S[..., :W]) + t.I / S[..., W:])).sum(-1)
        if t.some is not None:
            f[t.some] = f[t.some] + (t.mask * (torch.log(4.0 * math.pi ** 2 * t.Sj) + t.Ij / t.Sj)).sum(-1)
        f = f.numpy()
        return np.where(np.isfinite(f), f, 1e300)

    def beta(self, U: Tensor, rows) -> Tensor:
        """The linear mean's coefficients ``(k, p)`` the sum is profiled over at the points ``U`` of the starts
        ``rows`` (``(k, 0)`` without regressors)."""
        rows = torch.as_tensor(np.asarray(rows), dtype=torch.long)
        omega = self.frequencies[self.owner[rows]]
        S, _ = self._spectrum(U, omega, False)
        return self._terms(U, rows, S, grad=False).beta

    def _terms(self, U: Tensor, rows, S: Tensor, grad: bool) -> _Terms:
        """What the sum's terms read at the points ``U`` whose spectrum at the terms is ``S`` ``(k, 2W)``: which bins
        are rough, each rough row's ordinates, their spectrum (and its derivatives with ``grad``), and the
        periodogram of the terms and of those ordinates — with regressors, at the generalised-least-squares
        coefficients under this spectrum (:class:`~torchtea.likelihood.whittle.Regressors`)."""
        data, W = self.data, self.data.terms
        rows = torch.as_tensor(np.asarray(rows), dtype=torch.long)
        series = self.owner[rows]
        rough = data.rough(S)
        some = rough.any(-1).nonzero().squeeze(-1)
        t = _Terms(rough, data.I[series[:1]] if self.one else data.I[series])
        if len(some):
            t.some = some
            t.ords = data.ordinates(rough[some].any(0))
            t.mask = rough[some][:, data.term_of[t.ords]]
            t.Ij = data.I_full[series[some]][:, t.ords]
            t.Sj, t.dSj = self._spectrum(U[some], data.omega_full[t.ords], grad)
        reg = data.regressors
        if reg is None:
            t.beta = U.new_zeros(len(rows), 0)
            return t
        # the coefficients under this spectrum: Σ (M β − c)/S = 0 over the smooth terms and the rough ordinates
        q = (~rough) / S[..., W:]
        G = torch.einsum("kw,kpqw->kpq", q, reg.M[series])
        r = torch.einsum("kw,kpw->kp", q, reg.c[series])
        if t.some is not None:
            Aj, cj, Mj = reg.ordinates(series[t.some], t.ords)
            qj = t.mask / t.Sj
            G[t.some] += torch.einsum("kj,kpqj->kpq", qj, Mj)
            r[t.some] += torch.einsum("kj,kpj->kp", qj, cj)
        beta = torch.linalg.solve(G, r.unsqueeze(-1)).squeeze(-1)
        t.beta = beta
        fitted = (reg.A[series] - 2.0 * torch.einsum("kpw,kp->kw", reg.c[series], beta)
                  + torch.einsum("kp,kpqw,kq->kw", beta, reg.M[series], beta))
        t.I = torch.clamp(fitted / data.weight, min=0.0)
        if t.some is not None:
            b = beta[t.some]
            t.Ij = torch.clamp(Aj - 2.0 * torch.einsum("kpj,kp->kj", cj, b)
                               + torch.einsum("kp,kpqj,kq->kj", b, Mj, b), min=0.0)
        return t

    def hessian(self, U: Tensor, rows) -> Tensor:
        """The observed information (the Hessian of −ℓ_W) at the points ``U`` ``(k, P)`` of the starts ``rows``, over
        the coordinates ``idx`` by central differences of the closed-form gradient (2F gradients in one batch,
        step :data:`HESSIAN_STEP`), zero rows and columns for the others ``(k, P, P)``."""
        k, F = U.shape[0], len(self.idx)
        P = U.shape[-1]
        H = torch.zeros(k, P, P, dtype=torch.float64)
        if not F or not k:
            return H
        x = U[:, self.idx].numpy()
        E = np.eye(F) * HESSIAN_STEP
        points = np.concatenate([x[:, None, :] + E[None], x[:, None, :] - E[None]], axis=1).reshape(-1, F)
        rows = np.repeat(np.asarray(rows), 2 * F)
        _, g, _ = self.vgi(points, rows)
        g = g.reshape(k, 2, F, F)
        Hf = (g[:, 0] - g[:, 1]) / (2.0 * HESSIAN_STEP)
        Hf = 0.5 * (Hf + np.swapaxes(Hf, -1, -2))
        H[:, self.idx.unsqueeze(-1), self.idx] = torch.as_tensor(Hf)
        return H


def whittle_value(model: NoiseModel, data: WhittleData, values: dict, h: float) -> float:
    """ℓ_W of the first series of ``data`` at ``values`` (a rough bin at full resolution, as the fits sum it)."""
    U = model.to_unconstrained({n: [values[n]] for n in model.names}, h)
    objective = WhittleObjective(model, data, h, U, torch.zeros(1, dtype=torch.long), np.zeros(0, dtype=np.int64))
    return -float(objective.minus_loglik(U, data.frequencies()[:1], [0])[0])


#: Central-difference step (unconstrained coordinates) of the Whittle fit's observed information from its closed-form
#: gradients: they carry no differencing error, so the step trades the truncation, O(step²), against their rounding.
HESSIAN_STEP = 1e-4


class _Terms:
    """What :meth:`WhittleObjective._terms` found: ``rough`` ``(k, W)``, the terms' periodogram ``I`` ``(k, W)`` (or
    ``(1, W)``), the coefficients ``beta`` ``(k, p)``, and for the rows ``some`` with a rough bin their ordinates
    ``ords`` ``(K,)``, which are each row's ``mask`` ``(k', K)``, their periodogram ``Ij``, spectrum ``Sj`` and its
    derivatives ``dSj``."""

    def __init__(self, rough: Tensor, I: Tensor):
        self.rough, self.I = rough, I
        self.some = self.ords = self.mask = self.Ij = self.Sj = self.dSj = None
        self.beta = None

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
        return U, self.frequencies[series], self.data.I[series]

    def vgi(self, points, rows):
        U, omega, I = self._at(points, rows)
        S, dS = spectrum_jacobian(self.model, U, omega, self.h, self.idx.tolist())
        rough = self.data.rough(S)
        weight = self.data.weight * ~rough
        f, g, info = whittle_scores(weight, I, S, dS)
        some, ords, mask, Ij = self._rough(rough, rows)
        if some is not None:  # (rough bins at full resolution: every row that has one in one batch)
            Sj, dSj = spectrum_jacobian(self.model, U[some], self.data.omega_full[ords], self.h, self.idx.tolist())
            fj, gj, ij = whittle_scores(mask.to(torch.float64), Ij, Sj, dSj)
            f[some], g[some], info[some] = f[some] + fj, g[some] + gj, info[some] + ij
        f, g, info = f.numpy(), g.numpy(), info.numpy()
        bad = ~(np.isfinite(f) & np.isfinite(g).all(-1) & np.isfinite(info).all((-1, -2)))
        return (np.where(bad, 1e300, f), np.where(bad[:, None], 0.0, g),
                np.where(bad[:, None, None], 0.0, info))

    def values(self, points, rows):
        U, omega, I = self._at(points, rows)
        return self.minus_loglik(U, omega, I, rows)

    def minus_loglik(self, U: Tensor, omega: Tensor, I: Tensor, rows) -> np.ndarray:
        """−ℓ_W ``(k,)`` at the points ``U`` ``(k, P)`` of the starts ``rows``, their frequencies ``omega`` and mean
        ordinates ``I``: the binned terms, a rough bin's at full resolution (+1e300 where not finite)."""
        values = self.model.from_unconstrained(U, self.h)
        S = self.model.spectrum(values, omega, self.h)
        rough = self.data.rough(S)
        W = self.data.terms
        weight = self.data.weight * ~rough
        f = (weight * (torch.log(4.0 * math.pi ** 2 * S[..., :W]) + I / S[..., W:])).sum(-1)
        some, ords, mask, Ij = self._rough(rough, rows)
        if some is not None:
            Sj = self.model.spectrum({k: x[some] for k, x in values.items()}, self.data.omega_full[ords], self.h)
            f[some] = f[some] + (mask * (torch.log(4.0 * math.pi ** 2 * Sj) + Ij / Sj)).sum(-1)
        f = f.numpy()
        return np.where(np.isfinite(f), f, 1e300)

    def _rough(self, rough: Tensor, rows):
        """The rows with a rough bin ``(k,)``, the ordinates of every rough bin of any of them ``(K,)``, which are
        each row's ``(k, K)`` and their periodogram ``(k, K)``; ``(None, …)`` where no bin is rough."""
        some = rough.any(-1).nonzero().squeeze(-1)
        if not len(some):
            return None, None, None, None
        ords = self.data.ordinates(rough[some].any(0))
        mask = rough[some][:, self.data.term_of[ords]]
        series = self.owner[torch.as_tensor(np.asarray(rows), dtype=torch.long)[some]]
        return some, ords, mask, self.data.I_full[series][:, ords]

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
    return -float(objective.minus_loglik(U, data.frequencies()[:1], data.I[:1], [0])[0])


#: Central-difference step (unconstrained coordinates) of the Whittle fit's observed information from its closed-form
#: gradients: they carry no differencing error, so the step trades the truncation, O(step²), against their rounding.
HESSIAN_STEP = 1e-4

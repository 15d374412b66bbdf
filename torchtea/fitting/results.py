"""A fit's result (:class:`Fit`): its values, standard errors and 95 % intervals from the observed information by the
delta method on the unconstrained scale (:func:`intervals_from_hessian`), its likelihoods, and the one BIC
(:func:`bic`; :meth:`Fit.count`, the one rule of what it counts)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch
from torch import Tensor

from ..noise.model import NoiseModel

__all__ = ["Fit", "bic", "intervals_from_hessian", "estimates_from_hessian", "Z95"]


Z95 = 1.959963984540054


@dataclass
class Fit:
    """One series' fit. ``values``/``se``/``ci95`` keyed by ``component.parameter`` (``se`` None for a
    fixed parameter); ``ci95_method`` says how each interval was made; ``loglik`` of ``method``;
    ``loglik_exact`` the exact log-likelihood at the estimate (also for a Whittle fit);
    ``free`` the names estimated; ``n`` samples; ``notes`` what a reader must know."""

    model: NoiseModel
    method: str
    values: dict
    se: dict
    ci95: dict
    ci95_method: dict
    loglik: float
    loglik_exact: float | None
    n: int
    free: list
    converged: bool
    profile: dict | None = None
    notes: list = field(default_factory=list)
    #: The estimate on the optimisers' unconstrained scale ``(P,)`` and the Hessian of −ℓ there ``(P, P)``
    #: (zero rows for fixed parameters; None when not computed).
    u: Tensor | None = None
    hessian: Tensor | None = None

    @property
    def k(self) -> int:
        return len(self.free)

    @property
    def aic(self) -> float:
        return 2.0 * self.k - 2.0 * self.loglik

    @property
    def bic(self) -> float:
        """BIC on the likelihood of its ``method`` (``fit``'s number)."""
        return bic(self.k, self.n, self.loglik)

    @property
    def bic_exact(self) -> float:
        """BIC on the exact likelihood (what ``check`` compares models by, whatever the fit's method)."""
        return bic(self.k, self.n, self.loglik_exact)

    def count(self, estimates: dict) -> None:
        """The one rule of what BIC counts: a parameter a fit holds where the data put it (a step's time, a line's
        frequency at the refined periodogram peak — :meth:`~torchtea.noise.model.NoiseModel.held_estimates`) is an
        estimate all the same, so ``estimates`` (name → the words for its interval) join the fit's estimated
        parameters ``free`` (its ``k``); a reference (a temperature's ``t_ref``) never does."""
        for n, words in estimates.items():
            if n not in self.free:
                self.free.append(n)
            self.ci95_method[n] = words


def bic(k: int, n: int, loglik: float) -> float:
    """The Bayesian information criterion k ln n − 2ℓ of a fit of ``k`` estimated parameters to ``n`` samples with
    log-likelihood ``loglik`` (which likelihood: the caller's, and said where the number is written)."""
    return k * math.log(n) - 2.0 * loglik


def intervals_from_hessian(model: NoiseModel, u: Tensor, H: Tensor, free: Tensor, h: float):
    """Delta-method standard errors and 95 % intervals on the unconstrained scale, mapped back."""
    idx = free.nonzero().squeeze(-1)
    se, ci, how = {}, {}, {}
    values = {n: float(x) for n, x in zip(model.names, model.as_matrix(model.from_unconstrained(u, h))[0])}
    Hf = H[idx][:, idx]
    try:
        evals = torch.linalg.eigvalsh(Hf)
        cov_u = torch.linalg.inv(Hf) if bool((evals > 0).all()) else None
    except RuntimeError:
        cov_u = None
    for n in model.names:
        se[n], ci[n], how[n] = None, None, "fixed"
    if cov_u is None:
        for n in (model.names[i] for i in idx.tolist()):
            how[n] = "observed information not positive definite: no interval"
        return values, se, ci, how

    def natural(uu):
        return model.as_matrix(model.from_unconstrained(uu.unsqueeze(0), h))[0]

    J = torch.autograd.functional.jacobian(natural, u.detach())[:, idx]  # (P, F)
    cov = J @ cov_u @ J.mT
    for k, i in enumerate(idx.tolist()):
        n = model.names[i]
        sd_u = float(torch.sqrt(cov_u[k, k]))
        se[n] = float(torch.sqrt(cov[i, i].clamp(min=0)))
        spec = model.param_spec(n)
        if spec.scale != "identity" and spec.kind != "fraction":  # (a pole: Wald on its own scale, below)
            lo_u, hi_u = u.clone(), u.clone()
            lo_u[i] -= Z95 * sd_u
            hi_u[i] += Z95 * sd_u
            a, b = float(natural(lo_u)[i]), float(natural(hi_u)[i])
            ci[n] = [min(a, b), max(a, b)]
            # (a frequency below the Nyquist frequency: the logit of its share of it)
            how[n] = f"Wald on the {spec.scale} scale"
        else:
            ci[n] = [values[n] - Z95 * se[n], values[n] + Z95 * se[n]]
            how[n] = "Wald"
        if not (math.isfinite(se[n]) and all(math.isfinite(c) for c in ci[n])):
            se[n], ci[n] = None, None
            how[n] = ("no interval: the likelihood is all but flat along it (an estimate at its bound — a variance "
                      "at zero, an order at 0 or 1 — or not identified beside the others)")
    return values, se, ci, how


def estimates_from_hessian(model: NoiseModel, u: Tensor, H: Tensor | None, free: Tensor, h: float):
    """:func:`intervals_from_hessian`, or, without a Hessian (``H`` None), the values alone."""
    if H is not None:
        return intervals_from_hessian(model, u, H, free, h)
    vals = {n: float(x) for n, x in zip(model.names, model.as_matrix(model.from_unconstrained(u, h))[0])}
    how = {n: "not computed (intervals=False)" if f else "fixed" for n, f in zip(model.names, free.tolist())}
    return vals, {n: None for n in model.names}, {n: None for n in model.names}, how

"""What the TEA's engines share: the filter's state between steps (:class:`Carry`), a step's innovation
(:class:`StepOutput`), a run's result (:class:`TEAResult`) and the unscented weights (:func:`ut_weights`). The torch
engine (:mod:`.tea`) and the compiled one (:mod:`.fast`) both read them from here, so neither imports the other's
module for its types."""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import NamedTuple

import torch
from torch import Tensor

__all__ = ["Carry", "StepOutput", "TEAResult", "STEP_OUTPUTS", "ut_weights"]


def ut_weights(L: int, ut_alpha: float, ut_beta: float, kappa: float | None, *, dtype=torch.float64, device=None):
    """Unscented weights, paper (26)–(28).

    ``λ = 𝔄²(L+κ) − L``; ``W₀ᵐ = λ/(L+λ)``, ``W₀ᶜ = W₀ᵐ + 1 − 𝔄² + 𝔅``,
    ``Wᵢᵐ = Wᵢᶜ = 1/(2(L+λ))``. Returns ``(Wm, Wc, L+λ)`` with weights of shape ``(2L+1,)``.
    """
    k = 3.0 - L if kappa is None else kappa
    lam = ut_alpha**2 * (L + k) - L
    if L + lam <= 0:
        raise ValueError(f"L + λ = {L + lam} must be positive (check ut_alpha and kappa)")
    wi = 1.0 / (2.0 * (L + lam))
    wm = torch.full((2 * L + 1,), wi, dtype=dtype, device=device)
    wc = wm.clone()
    wm[0] = lam / (L + lam)
    wc[0] = lam / (L + lam) + (1.0 - ut_alpha**2 + ut_beta)
    return wm, wc, L + lam


class Carry(NamedTuple):
    """Filter state between steps (all at time ``k−1``)."""

    x: Tensor  # (*B, n)
    P: Tensor  # (*B, n, n)
    alpha: Tensor  # (*B, L)
    Po: Tensor  # (*B, L, L)
    Qo: Tensor  # (*B, L, L)
    w: Tensor  # (*B, m)
    Pw: Tensor  # (*B, m, m)
    Qw: Tensor  # (*B, m, m)
    diverged: Tensor  # (*B,) bool
    #: ``kfx_uncertainty = "paper-gain"`` only: the paper's KFx covariance, which sets the gain (``P`` is then the
    #: covariance of that filter's error with the order's and parameter's uncertainty included); else None
    Pg: Tensor | None = None
    #: ``estimate_uncertainty = "constant-truth"`` only: KFo's and KFw's own covariances, which set their gains
    #: (``Po`` and ``Pw`` are then the covariances of their errors for a constant truth); else None
    Pog: Tensor | None = None
    Pwg: Tensor | None = None
    #: ``kfo.R`` or ``kfw.R`` = "innovation" only: KFx's innovation covariance ``C P̃ Cᵀ + R`` at ``k−1`` from the
    #: ``P̃`` that set its gain (*B, p, p), the R those filters take at ``k``; else None
    S: Tensor | None = None

    @property
    def Po_own(self) -> Tensor:
        """KFo's own covariance, the one its sigma points and gain come from."""
        return self.Po if self.Pog is None else self.Pog

    @property
    def Pw_own(self) -> Tensor:
        """KFw's own covariance, the one its sigma points and gain come from."""
        return self.Pw if self.Pwg is None else self.Pwg


class StepOutput(NamedTuple):
    innovation: Tensor  # (*B, p), KFx: y_k − C x̃_k (0 where missing)
    innovation_cov: Tensor  # (*B, p, p), C P̃ Cᵀ + R


@dataclass(frozen=True)
class TEAResult:
    """Per-step TEA outputs; time is dimension ``-2`` (``-3`` for covariances).

    Attributes
    ----------
    x, P : state estimates ``(*B, T, n)`` and covariances ``(*B, T, n, n)`` (KFx).
    alpha, P_alpha, Q_alpha : order estimates ``(*B, T, L)`` and their covariance and
        adapted noise ``(*B, T, L, L)`` (KFo).
    w, P_w, Q_w : parameter estimates ``(*B, T, m)``, covariances ``(*B, T, m, m)`` (KFw).
    innovation, innovation_cov : KFx innovations ``(*B, T, p)`` and their predicted
        covariance ``(*B, T, p, p)``; zero innovation where ``y`` was missing.
    diverged : ``(*B,)`` bool; diverged_at : ``(*B,)`` first step flagged, −1 if never.
    steps : ``(T,)`` the sample index of each stored row (``0, every, 2·every, …``; all ``N`` by default).
    memory_clamped : ``(*B,)`` ``soe`` only: steps at which a KFo sigma order may have left the
        exponential-sum kernel's range (by default one order beyond ``order_bounds``, but not below −0.95,
        where (★) stops holding); there the tail of the memory sum used the clamped order, so the run
        departs from ``exact``. ``None`` otherwise.
    interrupted : True when :func:`run_tea` was stopped by Ctrl-C with ``partial=True``: the rows hold the
        steps that finished (``steps`` says which), nothing after them.
    """

    x: Tensor
    P: Tensor
    alpha: Tensor
    P_alpha: Tensor
    Q_alpha: Tensor
    w: Tensor
    P_w: Tensor
    Q_w: Tensor
    innovation: Tensor
    innovation_cov: Tensor
    diverged: Tensor
    diverged_at: Tensor
    steps: Tensor | None = None
    memory_clamped: Tensor | None = None
    interrupted: bool = False

    def to(self, device) -> TEAResult:
        """The same result with every tensor on ``device`` (e.g. back to the CPU for a report)."""
        from dataclasses import fields

        return replace(self, **{f.name: getattr(self, f.name).to(device) for f in fields(self)
                                if isinstance(getattr(self, f.name), Tensor)})


#: The per-step fields of :class:`TEAResult` (time is their dimension −2, −3 for covariances).
STEP_OUTPUTS = ("x", "P", "alpha", "P_alpha", "Q_alpha", "w", "P_w", "Q_w", "innovation", "innovation_cov")

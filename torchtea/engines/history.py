"""The TEA's memory of the past states in the GL sums: the whole history (:class:`_ExactMemory`, the paper's
Σ_{j≥1} c_j x_{k+1−j}) or a bounded one — exact lags plus an exponential-sum tail or a window
(:class:`_BoundedMemory`, :mod:`torchtea.core.memory`) — behind one interface (:func:`_make_memory`)."""
from __future__ import annotations

import torch

from ..core.gl import gl_tail_coefficients, history_sum
from ..core.memory import BoundedHistory, MemoryConfig, cov_tail_mass, gl_coefficients_at, memory_plan
from .settings import TEAConfig


class _ExactMemory:
    """Full-history sums (O(k) per step). ``hist = (xh, Ph)``: the KFx history newest first,
    ``x̂_{k−1} … x̂_0`` ``(*B, n, k)`` and ``P_{k−1} … P_0`` ``(*B, n, n, k)``; with ``kfx_uncertainty =
    "paper-gain"`` a third entry, the gain's covariances ``Pg`` in the same form."""

    bounded = False
    code = 0  # the compiled engine's switch (core.memory.MemoryPlan.code)

    def mean_sums(self, hist, orders):
        return history_sum(orders, hist[0])

    def kfx_sums(self, hist, a, k):
        """``(Σ_j c_j x̂_{k−j}, Σ_{j≥2} c_j² P_{k−j}, the same over Pg or None)``."""
        xh = hist[0]
        c = gl_tail_coefficients(a, xh.shape[-1])  # (*B, n, k): c_1 … c_k
        mean = (c.unsqueeze(-2) @ xh.unsqueeze(-1))[..., 0, 0]
        cj = c[..., 1:]  # lags 2…k

        def cov(Ph):
            if cj.shape[-1]:
                return torch.einsum("...sj,...tj,...stj->...st", cj, cj, Ph[..., 1:])
            return torch.zeros_like(Ph[..., 0])

        return mean, cov(hist[1]), cov(hist[2]) if len(hist) > 2 else None


class _BoundedMemory:
    """``soe`` or ``window`` memory: constant work per step.

    ``hist = (BoundedHistory, Pwin, Phead)``: ``Pwin`` ``(*B, n, n, J_P)`` = ``P_{k−1} … P_{k−J_P}`` and
    (``soe``) ``Phead`` ``(*B, n, n, H)`` = ``P_0 … P_{H−1}``, the start-up covariances whose terms stay exact;
    with ``kfx_uncertainty = "paper-gain"`` two more entries, the gain's covariances ``Pg`` in the same form.
    """

    bounded = True

    def __init__(self, cfg: MemoryConfig, order_bounds, horizon: int, dtype, device):
        # sigma points leave the order bounds (by ±√(3 P̃ᵒ), ~0.9 on the MEMS settings): a soe kernel serves one
        # order beyond them on both sides (down to −0.95 at most, where (★) stops)
        plan = memory_plan(cfg, horizon, (order_bounds[0] - 1.0, order_bounds[1] + 1.0))
        self.kernel, self.code = plan.kernel, plan.code
        self.decay = self.inject = None
        if self.kernel is not None:
            _, _, self.decay, self.inject = self.kernel.tensors(dtype, device)
        self.x_lags, self.p_lags, self.n_modes, self.head = plan.x_lags, plan.p_lags, plan.n_modes, plan.head
        self.head_index = torch.arange(self.head, dtype=dtype, device=device)

    def init(self, batch, n: int, dtype, device, gain: bool = False):
        """An empty history; ``gain``: with the gain's covariances (``kfx_uncertainty = "paper-gain"``)."""
        z = lambda *s: torch.zeros(tuple(batch) + s, dtype=dtype, device=device)  # noqa: E731
        return (BoundedHistory.zeros(batch, n, self.x_lags, self.n_modes, dtype=dtype, device=device),
                z(n, n, self.p_lags), z(n, n, self.head)) + ((z(n, n, self.p_lags), z(n, n, self.head)) if gain else ())

    def push(self, hist, x, P, k, Pg=None):
        """Append ``x̂_k``, ``P_k`` (and ``Pg_k`` where the history keeps them; ``k`` the step they belong to)."""
        slot = (self.head_index == k).to(P.dtype)  # P_k goes to head slot k while k < H

        def cov(Pwin, Phead, P):
            if self.head:
                Phead = Phead + P.unsqueeze(-1) * slot
            return torch.cat([P.unsqueeze(-1), Pwin[..., :-1]], dim=-1), Phead

        out = (hist[0].push(x, self.decay, self.inject),) + cov(hist[1], hist[2], P)
        return out + cov(hist[3], hist[4], Pg) if len(hist) > 3 else out

    def mean_sums(self, hist, orders):
        c = gl_tail_coefficients(orders, self.x_lags)
        return hist[0].sum(c, orders, self.kernel)

    def kfx_sums(self, hist, a, k):
        """``(Σ_j c_j x̂_{k−j}, Σ_{j≥2} c_j² P_{k−j}, the same over Pg or None)``, bounded as the class says."""
        xhist = hist[0]
        c = gl_tail_coefficients(a, self.p_lags)  # (*B, n, J_P)
        mean = xhist.sum(c[..., : self.x_lags].unsqueeze(-3), a.unsqueeze(-2), self.kernel)[..., 0, :]
        cj = c[..., 1:]
        mass = ch = None
        if self.kernel is not None:
            J, H = self.p_lags, self.head
            ac = a.clamp(min=max(-0.49, self.kernel.order_range[0]))  # Gauss's sum needs a + b > −1
            # lags J+1 … k−H: coefficient mass × the oldest windowed covariance
            mass = cov_tail_mass(ac.unsqueeze(-1), ac.unsqueeze(-2), c.unsqueeze(-2), c.unsqueeze(-3), k - H)
            if H:
                # lags k−H+1 … k (P_{H−1} … P_0), where beyond the window: exact terms
                lags = k - self.head_index  # lag of P_i is k − i
                ch = gl_coefficients_at(ac.unsqueeze(-1), lags.clamp(min=J + 1))  # (*B, n, H)
                ch = ch * (lags > J).to(ch.dtype)

        def cov(Pwin, Phead):
            out = torch.einsum("...sj,...tj,...stj->...st", cj, cj, Pwin[..., 1:])
            if mass is not None:
                out = out + mass * Pwin[..., -1]
            if ch is not None:
                out = out + torch.einsum("...sj,...tj,...stj->...st", ch, ch, Phead)
            return out

        return mean, cov(hist[1], hist[2]), cov(hist[3], hist[4]) if len(hist) > 3 else None


def _make_memory(cfg: TEAConfig, horizon: int, dtype, device):
    if not cfg.memory.bounded:
        return _ExactMemory()
    return _BoundedMemory(cfg.memory, cfg.order_bounds, horizon, dtype, device)

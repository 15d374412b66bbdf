r"""The Triple Estimation Algorithm (TEA): KFx, KFo and KFw, batched.

Paper §3 (Macias, Sierociuk & Malesza, *Sensors* 2022, eqs. (12)–(42)); the
original description is Sierociuk & Macias, *Sensors* 2021, 21, 8159.

One step ``k ≥ 1`` (time is the loop; every tensor carries leading batch dims ``*B``):

1. **KFo** (order, unscented; (12)–(25)): ``α̃ = α̂_{k−1}``, ``P̃ᵒ = Pᵒ + Qᵒ``, sigma
   points of α; each goes through the model replica (16)–(18) with ``x̂`` history
   and ``ŵ_{k−1}``; unscented update; Robbins–Monro adaptation (25) of ``Qᵒ``.
2. **KFw** (parameters, unscented; (37)–(42)): the same with sigma points of ``w``
   and the order fixed at ``α̂_{k−1}``.
   The sigma points of KFo and KFw pass through the replica as **one** batched
   evaluation (:func:`_replica`).
3. **KFx** (state, fractional KF; (29)–(35)): prediction with ``α̂_k`` and
   ``ŵ_{k−1}`` — the indices of (31); covariance
   ``P̃ = (h^α A + α) P (…)ᵀ + Q + Σ_{j=2}^{k} c_j P_{k−j} c_j`` and update with ``y_k``.

At ``k = 0`` only KFx updates, from its prior ``x₀, P₀``.

The paper's open points (ALGORITHMS.md §3) are options of :class:`TEAConfig`;
``experiments/paper/README.md`` has the measurements behind the defaults.

Shapes: ``n`` states, ``L`` estimated orders, ``m`` parameters, ``d`` inputs,
``p`` outputs; sigma points sit between the batch and the event dimensions.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import NamedTuple, Sequence

import torch
from torch import Tensor

from ..core.gl import broadcast_shapes, gl_tail_coefficients, history_sum
from ..core.memory import BoundedHistory, MemoryConfig, cov_tail_mass, gl_coefficients_at, memory_plan
from .results import STEP_OUTPUTS, Carry, StepOutput, TEAResult, ut_weights
from .settings import TEAConfig
from .structure import Structure

__all__ = [
    "TEAParams",
    "TEAResult",
    "make_params",
    "stack_params",
    "run_tea",
    "TEAStream",
    "ut_weights",
    "STEP_OUTPUTS",
    # the unscented filters' parts, which the exact-KFx TEA (torchtea.noise.tea_exact) and the studies reuse
    "sigma_points",
    "ut_update",
    "adapt_q",
    "q_cap",
    "sqrt_psd",
]


# --------------------------------------------------------------------------- tensors


def _mat(value, size: int, like: Tensor, name: str) -> Tensor:
    t = torch.as_tensor(value, dtype=like.dtype, device=like.device)
    eye = torch.eye(size, dtype=like.dtype, device=like.device)
    if t.ndim == 0:
        return t * eye
    if t.ndim == 1:
        if t.shape[0] != size:
            raise ValueError(f"{name}: expected {size} diagonal entries, got {t.shape[0]}")
        return torch.diag(t)
    if t.shape[-2:] != (size, size):
        raise ValueError(f"{name}: expected a {size}x{size} matrix, got {tuple(t.shape)}")
    return t


def _vec(value, size: int, like: Tensor, name: str) -> Tensor:
    t = torch.as_tensor(value, dtype=like.dtype, device=like.device)
    if t.ndim == 0:
        return t.expand(size).clone()
    if t.shape[-1] != size:
        raise ValueError(f"{name}: expected {size} entries, got {tuple(t.shape)}")
    return t


class TEAParams(NamedTuple):
    """Tensor form of a :class:`TEAConfig` for one :class:`Structure`.

    Tensor fields have a leading batch shape (possibly empty) that broadcasts
    with the data; :func:`stack_params` stacks configs of e.g. three axes.
    """

    x0: Tensor  # (*B, n)
    P0: Tensor  # (*B, n, n)
    Q: Tensor  # (*B, n, n)
    R: Tensor  # (*B, p, p)
    alpha0: Tensor  # (*B, L)
    P0o: Tensor  # (*B, L, L)
    Q0o: Tensor  # (*B, L, L)
    Ro: Tensor  # (*B, p, p)
    w0: Tensor  # (*B, m)
    P0w: Tensor  # (*B, m, m)
    Q0w: Tensor  # (*B, m, m)
    Rw: Tensor  # (*B, p, p)
    Qmax_o: Tensor  # (*B,), +inf for no cap
    Qmax_w: Tensor  # (*B,)
    config: TEAConfig


def make_params(config: TEAConfig, structure: Structure, *, dtype=torch.float64, device=None) -> TEAParams:
    """Turn a config into tensors shaped for ``structure``."""
    like = torch.empty((), dtype=dtype, device=device)
    n, p, L, m = structure.n_states, structure.n_outputs, structure.n_estimated_orders, structure.n_params
    x, o, w = config.kfx, config.kfo, config.kfw
    Q0o, Q0w = _mat(o.Q0, L, like, "kfo.Q0"), _mat(w.Q0, m, like, "kfw.Q0")
    return TEAParams(
        x0=_vec(x.x0, n, like, "kfx.x0"), P0=_mat(x.P0, n, like, "kfx.P0"),
        Q=_mat(x.Q0, n, like, "kfx.Q0"), R=_mat(x.R, p, like, "kfx.R"),
        alpha0=_vec(o.x0, L, like, "kfo.x0"), P0o=_mat(o.P0, L, like, "kfo.P0"),
        Q0o=Q0o, Ro=_r(o, p, like, "kfo.R"),
        w0=_vec(w.x0, m, like, "kfw.x0"), P0w=_mat(w.P0, m, like, "kfw.P0"),
        Q0w=Q0w, Rw=_r(w, p, like, "kfw.R"),
        Qmax_o=q_cap(o.Q_max, Q0o, like),
        Qmax_w=q_cap(w.Q_max, Q0w, like),
        config=config,
    )


def _r(f, size: int, like: Tensor, name: str) -> Tensor:
    """KFo's or KFw's R (``f`` its :class:`UnscentedConfig`) as a matrix; NaN for ``"innovation"`` (the step takes
    ``Carry.S`` then, never this)."""
    if f.uses_innovation:
        return torch.full((size, size), math.nan, dtype=like.dtype, device=like.device)
    return _mat(f.R, size, like, name)


def q_cap(q_max, Q0: Tensor, like: Tensor) -> Tensor:
    if q_max == "none":
        return torch.tensor(math.inf, dtype=like.dtype, device=like.device)
    if q_max == "Q0":
        return torch.diagonal(Q0, dim1=-2, dim2=-1).amax(-1)
    return torch.tensor(float(q_max), dtype=like.dtype, device=like.device)


def stack_params(params: Sequence[TEAParams]) -> TEAParams:
    """Stack parameter sets (e.g. one per axis) along a new leading batch dimension.

    The non-tensor settings (UT constants, δ, options) must agree.
    """
    params = list(params)
    if not params:
        raise ValueError("nothing to stack")
    first = params[0].config

    def strip(c: TEAConfig):
        keep = lambda f: replace(f, x0=0, P0=0, Q0=0, R=0)  # noqa: E731
        # KFo's and KFw's: the cap's kind and whether R is "innovation" must agree, not their numbers
        cap = lambda f: replace(keep(f), Q_max=1.0 if f.Q_max != "none" else "none",  # noqa: E731
                                R=f.R if f.uses_innovation else 0)
        return replace(c, kfx=keep(c.kfx), kfo=cap(c.kfo), kfw=cap(c.kfw))

    for p in params[1:]:
        if strip(p.config) != strip(first):
            raise ValueError("stacked configs may differ only in x0, P0, Q0, R and the Q cap")
    tensors = [torch.stack([getattr(p, name) for p in params]) for name in TEAParams._fields[:-1]]
    return TEAParams(*tensors, config=first)


# --------------------------------------------------------------------------- unscented pieces


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


# --------------------------------------------------------------------------- one step


@dataclass(frozen=True)
class _Model:
    """The structure as tensors of one dtype/device (internal)."""

    structure: Structure
    h: Tensor
    B: Tensor
    C: Tensor

    def A(self, w):
        return self.structure.A(w)

    def full(self, est):
        return self.structure.full_orders(est)


def _drive(model: _Model, A: Tensor, x: Tensor, u: Tensor | None) -> Tensor:
    """``A x + B u`` — the right-hand side of (9); A ``(*B, S, n, n)`` or ``(*B, n, n)`` with x ``(*B, n)``."""
    extra = A.ndim - x.ndim - 1  # sigma dimensions in A that x lacks
    xs = x.reshape(x.shape[:-1] + (1,) * extra + x.shape[-1:])
    out = _mm(A, xs.unsqueeze(-1)).squeeze(-1)
    if u is not None:
        bu = _mm(u, model.B.mT)
        out = out + bu.reshape(bu.shape[:-1] + (1,) * extra + bu.shape[-1:])
    return out


def _replica(model: _Model, memory, hist, orders_o, w_prev, sigma_w, x_prev, u_prev):
    """Model replica (16)–(18) and (41)–(42) for the sigma points of KFo **and** KFw at once.

    orders_o ``(*B, So, n)`` (KFo sigma orders, with ``A(ŵ_{k−1})``); sigma_w
    ``(*B, Sw, m)`` (KFw sigma parameters, with order ``α̂_{k−1}``). KFw's order is KFo's
    centre sigma point (sigma point 0 is the mean), so one GL history evaluation over the ``So``
    orders serves both, and one batched matrix product every drive term. Returns predicted
    outputs ``(*B, So + Sw, p)`` and the predicted states ``(*B, So + Sw, n)`` they come from.
    """
    So, Sw = orders_o.shape[-2], sigma_w.shape[-2]
    mem_sum = memory.mean_sums(hist, orders_o)  # (*B, So, n)
    hpow = model.h ** orders_o
    A_all = torch.cat([model.A(w_prev).unsqueeze(-3).expand(x_prev.shape[:-1] + (So,) + (x_prev.shape[-1],) * 2),
                       model.A(sigma_w)], dim=-3)  # (*B, So+Sw, n, n)
    drive = _drive(model, A_all, x_prev, u_prev)
    centre = lambda t: t[..., :1, :].expand(t.shape[:-2] + (Sw, t.shape[-1]))  # noqa: E731
    hp = torch.cat([hpow, centre(hpow)], dim=-2)
    mem = torch.cat([mem_sum, centre(mem_sum)], dim=-2)
    chi = hp * drive - mem
    return _mm(chi, model.C.mT), chi


# --------------------------------------------------------------------------- memory strategies


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


def _tea_step(model: _Model, params: TEAParams, weights, memory, carry: Carry, y, u_prev, hist, k, branchless=False):
    """One TEA step ``k ≥ 1`` — a pure function of its arguments.

    y ``(*B, p)`` (NaN = missing); u_prev ``(*B, d)`` or None; ``hist`` the KFx history up to
    ``x̂_{k−1}, P_{k−1}`` in the form ``memory`` keeps it; ``k`` the step (int or 0-d tensor).
    Returns ``(Carry, StepOutput)`` at time ``k``.
    """
    cfg = params.config
    (wm_o, wc_o, scale_o), (wm_w, wc_w, scale_w) = weights
    start = cfg.sigma_sum_start
    mask = ~torch.isnan(y)
    observed = mask.any(-1)
    y0 = torch.where(mask, y, torch.zeros_like(y))

    # KFo and KFw predictions (13)–(15), (38)–(40), from the covariances that set their gains
    Po_t = carry.Po_own + carry.Qo
    Pw_t = carry.Pw_own + carry.Qw
    sig_o = sigma_points(carry.alpha, Po_t, scale_o)
    sig_w = sigma_points(carry.w, Pw_t, scale_w)
    Y, chi = _replica(model, memory, hist, model.full(sig_o), carry.w, sig_w, carry.x, u_prev)
    So = sig_o.shape[-2]
    Ro = carry.S if cfg.kfo.uses_innovation else params.Ro
    Rw = carry.S if cfg.kfw.uses_innovation else params.Rw
    alpha, Po, Ko, eo, Pyy_o, Pxy_o = ut_update(sig_o, Y[..., :So, :], carry.alpha, Po_t, Ro, y0, mask,
                                                 wm_o, wc_o, start)
    lo, hi = cfg.order_bounds
    alpha = alpha.clamp(lo, hi)
    Qo = adapt_q(carry.Qo, Ko, eo, cfg.kfo.delta, params.Qmax_o, observed)
    w, Pw, Kw, ew, Pyy_w, Pxy_w = ut_update(sig_w, Y[..., So:, :], carry.w, Pw_t, Rw, y0, mask,
                                             wm_w, wc_w, start)
    Qw = adapt_q(carry.Qw, Kw, ew, cfg.kfw.delta, params.Qmax_w, observed)

    # KFx (29)–(35) with α̂_k and ŵ_{k−1}
    a = model.full(alpha)  # (*B, n)
    mem_mean, mem_cov, mem_cov_g = memory.kfx_sums(hist, a, k)
    hp = model.h ** a
    A = model.A(carry.w)
    x_pred = hp * _drive(model, A, carry.x, u_prev) - mem_mean
    F = hp.unsqueeze(-1) * A + torch.diag_embed(a)
    Qx = params.Q * (hp.unsqueeze(-1) * hp.unsqueeze(-2)) if cfg.noise_scaling == "scaled" else params.Q
    P_pred = _mm(_mm(F, carry.P), F.mT) + Qx + mem_cov
    if cfg.kfx_uncertainty != "paper":
        # with the filters' own covariances, also under "constant-truth" (TEAConfig.estimate_uncertainty says why)
        P_pred = P_pred + _estimate_uncertainty(chi[..., :So, :], sig_o, carry.alpha, Po_t, Po, wc_o) \
            + _estimate_uncertainty(chi[..., So:, :], sig_w, carry.w, Pw_t, carry.Pw_own, wc_w)
    P_pred = _symmetrise(P_pred)
    Pg = None
    if cfg.kfx_uncertainty == "paper-gain":
        # the paper's KFx sets the gain; P is the covariance of that filter's error (Joseph form)
        Pg_pred = _symmetrise(_mm(_mm(F, carry.Pg), F.mT) + Qx + mem_cov_g)
        x, Pg, e, S_gain, K = _kfx_update(model, params, x_pred, Pg_pred, y0, mask)
        S = _mm(_mm(model.C, P_pred), model.C.mT) + params.R
        P = _symmetrise(_joseph(P_pred, K, model.C, params.R))
    else:
        x, P, e, S, _ = _kfx_update(model, params, x_pred, P_pred, y0, mask)
        S_gain = S

    Pog = Pwg = None
    if cfg.estimate_uncertainty == "constant-truth":
        # the filters' own covariances set the gains; Po and Pw become those of their errors for a constant truth
        Pog, Pwg = Po, Pw
        Po = _constant_truth_cov(carry.Po, Po_t, Ko, Pyy_o, Pxy_o)
        Pw = _constant_truth_cov(carry.Pw, Pw_t, Kw, Pyy_w, Pxy_w)
    new = Carry(x, P, alpha, Po, Qo, w, Pw, Qw, carry.diverged, Pg, Pog, Pwg, S_gain if cfg.innovation_r else None)
    return _guard(new, carry, cfg.divergence_limit, branchless), StepOutput(e, S)


def _estimate_uncertainty(chi, points, mean, prior_cov, cov, wc):
    """``J P Jᵀ``: the spread that an estimate's covariance ``cov`` puts into KFx's predicted state.

    ``J`` is the statistical linearisation of the replica state ``χ`` over the estimate's sigma points:
    ``J = P_χσ P̃⁻¹`` with ``P_χσ = Σᵢ Wᵢᶜ (χᵢ − χ̄)(σᵢ − m)ᵀ`` and ``P̃`` the covariance the points were drawn
    with (for the symmetric set, ``(χ₊ᵢ − χ₋ᵢ)/2`` over the root's column: a central difference). chi
    ``(*B, S, n)``, points ``(*B, S, L)``, mean ``(*B, L)``, prior_cov and cov ``(*B, L, L)``; zero where
    ``P̃`` is zero.
    """
    dX = points - mean.unsqueeze(-2)
    dC = chi - chi.mean(-2, keepdim=True)  # any centre: Σᵢ Wᵢᶜ dXᵢ = 0 for the symmetric points
    P_cs = _mm((dC * wc.unsqueeze(-1)).mT, dX)  # (*B, n, L)
    J = _over_cov(P_cs, prior_cov)
    return _mm(_mm(J, cov), J.mT)


def _over_cov(M, prior_cov):
    """``M P̃⁻¹``, the statistical linearisation's division by the covariance the sigma points were drawn with:
    M ``(*B, r, L)``, prior_cov ``(*B, L, L)``; a scalar P̃ divides (zero where P̃ is zero), a matrix one takes the
    pseudo-inverse."""
    if prior_cov.shape[-1] == 1:
        p = prior_cov[..., 0, 0]
        return torch.where((p > 0)[..., None, None], M / torch.where(p > 0, p, 1.0)[..., None, None], 0.0)
    return _mm(M, torch.linalg.pinv(prior_cov, hermitian=True))


def _kfx_update(model: _Model, params: TEAParams, x_pred, P_pred, y, mask):
    """KFx measurement update (33)–(35), symmetric form ``P = P̃ − K S Kᵀ``; returns ``(x, P, e, S, K)``."""
    C = model.C
    PCt = _mm(P_pred, C.mT)
    S = _mm(C, PCt) + params.R
    K = _gain(PCt, S, mask)
    e = torch.where(mask, y - _mm(x_pred.unsqueeze(-2), C.mT).squeeze(-2), torch.zeros_like(y))
    x = x_pred + _mm(K, e.unsqueeze(-1)).squeeze(-1)
    P = _psd(P_pred - _mm(_mm(K, S), K.mT))
    return x, P, e, S, K


def _guard(new: Carry, old: Carry, limit: float, branchless: bool = False) -> Carry:
    """Flag realisations whose carry became non-finite or left ``[−limit, limit]``; freeze them.

    ``branchless`` always applies the freeze (no data-dependent Python branch, for torch.compile).
    """
    nb = old.diverged.ndim
    names = [f for f in Carry._fields if f != "diverged" and getattr(new, f) is not None]
    flat = torch.cat([getattr(new, f).reshape(getattr(new, f).shape[:nb] + (-1,)) for f in names], dim=-1)
    bad = ~torch.isfinite(flat).all(-1) | (flat.abs() > limit).any(-1)
    diverged = old.diverged | bad
    if not branchless and not bool(diverged.any()):
        return new._replace(diverged=diverged)
    out = {}
    for f in names:
        tn, to = getattr(new, f), getattr(old, f)
        out[f] = torch.where(diverged.reshape(diverged.shape + (1,) * (tn.ndim - nb)), to, tn)
    return new._replace(diverged=diverged, **out)


# --------------------------------------------------------------------------- the loop


def _outputs(c: Carry, o: StepOutput):
    return (c.x, c.P, c.alpha, c.Po, c.Qo, c.w, c.Pw, c.Qw, o.innovation, o.innovation_cov)


#: The warning for ``TEAResult.memory_clamped`` steps (``{n}``: their count).
CLAMP_NOTE = ("soe memory: at {n} steps a KFo sigma order left the exponential-sum range; "
              "those steps used the clamped order and differ from --memory exact")

#: Steps per compiled call of the bounded-memory loop (amortises the call overhead of a compiled graph).
COMPILE_BLOCK = 8


def _model_and_weights(structure: Structure, params: TEAParams, h: float, dtype, device):
    like = torch.empty((), dtype=dtype, device=device)
    model = _Model(structure, torch.as_tensor(h, dtype=dtype, device=device), structure.B.to(like), structure.C.to(like))
    cfg = params.config
    if cfg.kfx_filter != "paper":
        raise ValueError(f"kfx_filter {cfg.kfx_filter!r} runs on a noise model's state space, which this engine does "
                         "not have: call torchtea.noise.tea_exact.run_tea_exact with the model's TEA view")
    L, m = structure.n_estimated_orders, structure.n_params
    weights = (ut_weights(L, cfg.kfo.ut_alpha, cfg.kfo.ut_beta, cfg.kfo.kappa, dtype=dtype, device=device),
               ut_weights(m, cfg.kfw.ut_alpha, cfg.kfw.ut_beta, cfg.kfw.kappa, dtype=dtype, device=device))
    return model, weights


def _first_step(model: _Model, params: TEAParams, y_0: Tensor, batch) -> tuple[Carry, StepOutput]:
    """k = 0: the KFx update from the prior only; KFo and KFw start at their priors."""
    n, L, m = params.x0.shape[-1], params.alpha0.shape[-1], params.w0.shape[-1]
    ex = lambda t, ev: t.expand(batch + ev).clone()  # noqa: E731
    mask0 = ~torch.isnan(y_0)
    x, P, e, S, _ = _kfx_update(model, params, ex(params.x0, (n,)), ex(params.P0, (n, n)),
                                torch.where(mask0, y_0, torch.zeros_like(y_0)), mask0)
    gain = params.config.kfx_uncertainty == "paper-gain"  # at k = 0 both covariances are the prior's update
    constant = params.config.estimate_uncertainty == "constant-truth"  # both start at the prior's
    carry = Carry(x, P, ex(params.alpha0, (L,)), ex(params.P0o, (L, L)), ex(params.Q0o, (L, L)),
                  ex(params.w0, (m,)), ex(params.P0w, (m, m)), ex(params.Q0w, (m, m)),
                  torch.zeros(batch, dtype=torch.bool, device=y_0.device), P.clone() if gain else None,
                  ex(params.P0o, (L, L)) if constant else None, ex(params.P0w, (m, m)) if constant else None,
                  S if params.config.innovation_r else None)  # at k = 0 the gain's S is the prior's
    prior = carry._replace(x=ex(params.x0, (n,)), P=ex(params.P0, (n, n)), Pg=ex(params.P0, (n, n)) if gain else None)
    return _guard(carry, prior, params.config.divergence_limit), StepOutput(e, S)


class TEAStream:
    """The TEA one sample at a time, for data that arrive while it runs (``torchtea record --live``).

    Needs bounded memory (``soe`` or ``window``): the history is kept in O(1) per step, designed for
    ``horizon`` samples (beyond it the ``soe`` kernel's error bound no longer holds). A stream fed the
    samples of a series gives exactly what :func:`run_tea` gives on the whole series.

    ``step(y_k)`` with ``y_k`` of shape ``(*batch, p)`` (NaN = missing) returns ``(Carry, StepOutput)``
    at the sample's time; ``k`` counts the samples taken. ``engine``: as in :func:`run_tea` (the compiled
    scalar engine by default where it applies).
    """

    def __init__(self, *, h: float, params: TEAParams, batch=(), structure: Structure | None = None,
                 horizon: int = 10**6, dtype=torch.float64, device=None, engine: str = "auto"):
        self.structure = structure or Structure.scalar_noise()
        cfg = params.config
        if not cfg.memory.bounded:
            raise ValueError("TEAStream needs bounded memory: set config.memory to soe or window")
        self.params = TEAParams(*[t.to(device=device, dtype=dtype) for t in params[:-1]], config=cfg)
        self.batch = broadcast_shapes(tuple(batch), self.params.x0.shape[:-1], self.params.R.shape[:-2])
        self.model, self.weights = _model_and_weights(self.structure, self.params, h, dtype, device)
        self.memory = _make_memory(cfg, horizon, dtype, device)
        self.dtype, self.device = dtype, device
        self.k = 0
        self.carry: Carry | None = None
        self._hist = None
        from .fast import use_compiled

        #: the compiled scalar engine (:mod:`.fast`) where it applies; ``engine`` as in :func:`run_tea`
        self._fast = use_compiled(engine, self.structure, dtype, device)
        self._engine = None

    def step(self, y_k: Tensor, u_prev: Tensor | None = None) -> tuple[Carry, StepOutput]:
        y_k = torch.as_tensor(y_k, dtype=self.dtype, device=self.device).expand(self.batch + (self.structure.n_outputs,))
        if self.k == 0:
            self.carry, out = _first_step(self.model, self.params, y_k, self.batch)
            self._hist = self.memory.init(self.batch, self.structure.n_states, self.dtype, self.device,
                                          self.carry.Pg is not None)
        elif self._fast:
            return self._fast_step(y_k, u_prev)
        else:
            self.carry, out = _tea_step(self.model, self.params, self.weights, self.memory, self.carry, y_k, u_prev,
                                        self._hist, self.k)
        if self._fast and self.k == 0:
            from .fast import FastTEA

            self._engine = FastTEA(h=float(self.model.h), params=self.params, batch=self.batch, memory=self.memory,
                                   horizon=1, carry=self.carry, has_u=self.structure.n_inputs > 0)
        else:
            self._hist = self.memory.push(self._hist, self.carry.x, self.carry.P, self.k, self.carry.Pg)
        self.k += 1
        return self.carry, out

    def _fast_step(self, y_k: Tensor, u_prev: Tensor | None):
        import numpy as np

        eng, B, k = self._engine, self._engine.B, self.k
        y = np.zeros((B, 2))
        y[:, 1] = y_k.reshape(B).numpy()
        u = None
        if u_prev is not None:
            u = np.zeros((B, 2))
            u[:, 0] = torch.as_tensor(u_prev, dtype=self.dtype).expand(self.batch + (1,)).reshape(B).numpy()
        outs = {name: np.empty((B, 1)) for name in STEP_OUTPUTS}
        eng.advance(k, k + 1, y, u, outs, yoff=k - 1, ooff=k)
        self.carry = eng.carry()
        t = lambda a: torch.from_numpy(a[:, 0]).reshape(self.batch)  # noqa: E731
        out = StepOutput(innovation=t(outs["innovation"]).unsqueeze(-1),
                         innovation_cov=t(outs["innovation_cov"]).unsqueeze(-1).unsqueeze(-1))
        self.k += 1
        return self.carry, out


def run_tea(
    y: Tensor,
    *,
    h: float,
    params: TEAParams,
    structure: Structure | None = None,
    inputs: Tensor | None = None,
    progress=None,
    record_every: int = 1,
    compile: bool = False,
    partial: bool = False,
    engine: str = "auto",
) -> TEAResult:
    """Run the TEA over a batch of measurement series.

    Parameters
    ----------
    y : Tensor, shape ``(*B, N, p)``
        Measurements; NaN marks a missing sample (predict without update).
    h : float
        Sample time.
    params : TEAParams
        From :func:`make_params` (or :func:`stack_params`); its batch shape
        broadcasts with ``*B``. ``params.config.memory`` selects the history sums.
    structure : Structure, optional
        Model structure (default: the paper's scalar noise model).
    inputs : Tensor, shape ``(*B, N, d)``, optional
        Known inputs ``u``; ``u_{k−1}`` drives step ``k``.
    progress : callable, optional
        Called as ``progress(k, N)`` as steps complete (for progress bars).
    record_every : int
        Store every this many steps (``k = 0, every, …``); the filter still runs every step.
        Long recordings need not keep millions of rows.
    compile : bool
        ``soe``/``window`` memory only: run blocks of :data:`COMPILE_BLOCK` steps through
        ``torch.compile`` (worth it for long series: compiling takes ~1 min on a 2-core CPU, then
        steps are several times cheaper). Falls back to eager with a warning if compiling fails.
    partial : bool
        On Ctrl-C (``KeyboardInterrupt``), return the steps that finished, with ``interrupted=True``,
        instead of raising — so a long run that is stopped still leaves its results.
    engine : str
        ``"auto"`` (default): the compiled scalar engine (:mod:`.fast`, numba, the same recursion) where it
        applies — float64 on the CPU, the scalar structure, no ``compile`` — else the batched torch engine;
        ``"torch"``: always the torch engine; ``"numba"``: the compiled engine or a ``ValueError`` saying why not.

    Returns
    -------
    TEAResult
    """
    structure = structure or Structure.scalar_noise()
    y = torch.as_tensor(y)
    if not y.is_floating_point():
        y = y.to(torch.float64)
    dtype, device = y.dtype, y.device
    n, p, L, m = structure.n_states, structure.n_outputs, structure.n_estimated_orders, structure.n_params
    if y.ndim < 2 or y.shape[-1] != p:
        raise ValueError(f"y must have shape (*B, N, {p}), got {tuple(y.shape)}")
    if int(record_every) < 1:
        raise ValueError(f"record_every must be >= 1, got {record_every}")
    every = int(record_every)
    N = y.shape[-2]
    params = TEAParams(*[t.to(device=device, dtype=dtype) for t in params[:-1]], config=params.config)
    shapes = [y.shape[:-2], params.x0.shape[:-1], params.R.shape[:-2], params.Ro.shape[:-2], params.Rw.shape[:-2],
              params.alpha0.shape[:-1], params.w0.shape[:-1], params.P0.shape[:-2], params.Q.shape[:-2],
              params.Qmax_o.shape, params.Qmax_w.shape]
    if inputs is not None:
        inputs = torch.as_tensor(inputs, dtype=dtype, device=device)
        if inputs.shape[-2:] != (N, structure.n_inputs):
            raise ValueError(f"inputs must have shape (*B, {N}, {structure.n_inputs}), got {tuple(inputs.shape)}")
        shapes.append(inputs.shape[:-2])
    batch = broadcast_shapes(*shapes)
    nb = len(batch)
    model, weights = _model_and_weights(structure, params, h, dtype, device)
    cfg = params.config
    memory = _make_memory(cfg, N, dtype, device)
    y = y.expand(batch + (N, p))
    if inputs is not None:
        inputs = inputs.expand(batch + (N, structure.n_inputs))

    carry, first = _first_step(model, params, y[..., 0, :], batch)
    from .fast import run_tea_fast, use_compiled

    grad = y.requires_grad or (inputs is not None and inputs.requires_grad) or any(t.requires_grad for t in params[:-1])
    if use_compiled(engine, structure, y.dtype, y.device, compile, grad):
        return run_tea_fast(y, h=h, params=params, inputs=inputs, progress=progress, record_every=every,
                            partial=partial, batch=batch, memory=memory, first=(carry, first))
    # per-step outputs, preallocated (rows k = 0, every, 2·every, …)
    n_out = (N - 1) // every + 1
    events = ((n,), (n, n), (L,), (L, L), (L, L), (m,), (m, m), (m, m), (p,), (p, p))
    out = {name: torch.empty(batch + (n_out,) + ev, dtype=dtype, device=device) for name, ev in zip(STEP_OUTPUTS, events)}

    def record_block(k0: int, tensors, stacked: bool):
        """Store outputs of steps k0 … (one step, or a block stacked along dim nb)."""
        if not stacked:
            if k0 % every == 0:
                for name, t in zip(STEP_OUTPUTS, tensors):
                    out[name].select(nb, k0 // every).copy_(t)
            return
        T = tensors[0].shape[nb]
        first = (-k0) % every  # offset of the first stored step in the block
        if first >= T:
            return
        rows = torch.arange(first, T, every, device=device)
        i0 = (k0 + first) // every
        for name, t in zip(STEP_OUTPUTS, tensors):
            out[name].narrow(nb, i0, rows.shape[0]).copy_(t.index_select(nb, rows))

    record_block(0, _outputs(carry, first), False)
    clamped = torch.zeros(batch, dtype=torch.long, device=device)
    try:
        completed, carry, diverged_at, clamped = _loop(
            model, params, weights, memory, carry, y, inputs, batch, N, n, nb, device, dtype, progress, compile,
            record_block, clamped)
    except _Interrupted as stop:
        if not partial:
            raise KeyboardInterrupt from None
        completed, carry, diverged_at, clamped = stop.state
    rows = (completed - 1) // every + 1
    if rows < n_out:
        out = {name: t.narrow(nb, 0, rows) for name, t in out.items()}
    diverged = (diverged_at >= 0) & (diverged_at < completed)
    return TEAResult(**out, diverged=diverged, diverged_at=torch.where(diverged, diverged_at, -1),
                     steps=torch.arange(0, completed, every, device=device),
                     memory_clamped=clamped if memory.bounded and memory.kernel is not None else None,
                     interrupted=completed < N)


class _Interrupted(Exception):
    """Ctrl-C inside the loop, carrying the state after the last stored step."""

    def __init__(self, state):
        super().__init__("interrupted")
        self.state = state


def _loop(model, params, weights, memory, carry, y, inputs, batch, N, n, nb, device, dtype, progress, compile,
          record_block, clamped):
    """Steps 1 … N−1 of :func:`run_tea`; returns ``(completed, carry, diverged_at, clamped)``. Ctrl-C becomes
    :class:`_Interrupted` with the state after the last step whose outputs were stored."""
    diverged_at = torch.where(carry.diverged, 0, torch.full(batch, -1, dtype=torch.long, device=device))
    u_at = (lambda k: None) if inputs is None else (lambda k: inputs[..., k, :])  # noqa: E731
    stored = (1, carry, diverged_at, clamped)  # the state after the last step whose outputs are stored
    try:
        if not memory.bounded:
            # the KFx history is kept time-reversed so that each step reads one contiguous slice
            xh = torch.zeros(batch + (n, N), dtype=dtype, device=device)
            # P, and the gain's covariance Pg where it is kept apart ("paper-gain")
            covs = lambda c: (c.P,) if c.Pg is None else (c.P, c.Pg)  # noqa: E731
            Ps = [torch.zeros(batch + (n, n, N), dtype=dtype, device=device) for _ in covs(carry)]
            xh[..., N - 1] = carry.x
            for Ph, c in zip(Ps, covs(carry)):
                Ph[..., N - 1] = c
            for k in range(1, N):
                carry, o = _tea_step(model, params, weights, memory, carry, y[..., k, :], u_at(k - 1),
                                     (xh[..., N - k:],) + tuple(Ph[..., N - k:] for Ph in Ps), k, device.type != "cpu")
                xh[..., N - 1 - k] = carry.x
                for Ph, c in zip(Ps, covs(carry)):
                    Ph[..., N - 1 - k] = c
                record_block(k, _outputs(carry, o), False)
                diverged_at = torch.where(carry.diverged & (diverged_at < 0), k, diverged_at)
                stored = (k + 1, carry, diverged_at, clamped)
                if progress is not None:
                    progress(k, N)
            return stored
        hist = memory.push(memory.init(batch, n, dtype, device, carry.Pg is not None), carry.x, carry.P, 0, carry.Pg)

        kernel_low, kernel_high = (-math.inf, math.inf) if memory.kernel is None else memory.kernel.order_range
        scale_o = weights[0][2]

        def one_step(carry, hist, diverged_at, clamped, y_k, u_prev, k, branchless):
            # extreme KFo sigma orders, bounded through the diagonal of P̃ᵒ (conservative)
            spread = (scale_o * torch.diagonal(carry.Po_own + carry.Qo, dim1=-2, dim2=-1)).clamp(min=0).sqrt()
            outside = ((carry.alpha - spread) < kernel_low) | ((carry.alpha + spread) > kernel_high)
            clamped = clamped + outside.any(-1).to(clamped.dtype)
            carry, o = _tea_step(model, params, weights, memory, carry, y_k, u_prev, hist, k, branchless)
            hist = memory.push(hist, carry.x, carry.P, k, carry.Pg)
            diverged_at = torch.where(carry.diverged & (diverged_at < 0), k, diverged_at)
            return carry, hist, diverged_at, clamped, _outputs(carry, o)

        def advance(carry, hist, diverged_at, clamped, ys, us, k0):
            """Steps k0 … k0+T−1 (T = ys.shape[nb]), branch-free for the compiler; outputs stacked along dim nb."""
            rows = []
            for t in range(ys.shape[nb]):
                carry, hist, diverged_at, clamped, row = one_step(
                    carry, hist, diverged_at, clamped, ys.select(nb, t), None if us is None else us.select(nb, t),
                    k0 + t, True)
                rows.append(row)
            return carry, hist, diverged_at, clamped, tuple(torch.stack(r, dim=nb) for r in zip(*rows))

        compiled = _compiled(advance) if compile else None
        k = 1
        while k < N:
            if compiled is not None and k + COMPILE_BLOCK <= N:
                try:
                    carry, hist, diverged_at, clamped, rows = compiled(
                        carry, hist, diverged_at, clamped, y.narrow(nb, k, COMPILE_BLOCK),
                        None if inputs is None else inputs.narrow(nb, k - 1, COMPILE_BLOCK), torch.tensor(k, device=device))
                except Exception as exc:  # noqa: BLE001 — any compiler failure: keep going in eager mode
                    import warnings

                    warnings.warn(f"torch.compile failed ({type(exc).__name__}: {exc}); continuing eagerly", stacklevel=2)
                    compiled = None
                    continue
                record_block(k, rows, True)
                k += COMPILE_BLOCK
            else:
                # off the CPU the guard is branch-free: no host-device synchronisation per step
                carry, hist, diverged_at, clamped, row = one_step(carry, hist, diverged_at, clamped, y[..., k, :],
                                                                  u_at(k - 1), k, device.type != "cpu")
                record_block(k, row, False)
                k += 1
            stored = (k, carry, diverged_at, clamped)
            if progress is not None:
                progress(k - 1, N)
        return stored
    except KeyboardInterrupt:
        raise _Interrupted(stored) from None


def _compiled(fn):
    try:
        return torch.compile(fn, dynamic=False, options={"cpp_wrapper": True})
    except Exception as exc:  # noqa: BLE001 — e.g. a platform without a C++ compiler
        import warnings

        warnings.warn(f"torch.compile unavailable ({type(exc).__name__}: {exc}); running eagerly", stacklevel=3)
        return None

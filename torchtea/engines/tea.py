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

import contextlib
import math
from dataclasses import dataclass

import torch
from torch import Tensor

from ..core.gl import broadcast_shapes
from .batch import _batched, _recorder, _result
from .history import _make_memory
from .params import TEAParams, make_params, q_cap, stack_params
from .results import STEP_OUTPUTS, Carry, StepOutput, TEAResult, ut_weights
from .structure import Structure
from .unscented import (
    _constant_truth_cov,
    _gain,
    _joseph,
    _mm,
    _over_cov,
    _psd,
    _symmetrise,
    adapt_q,
    sigma_points,
    sqrt_psd,
    ut_update,
)

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
        ``torch.compile`` (worth it for long series: compiling takes about a minute on two CPU cores, then
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
    y, params, inputs, batch, every = _batched(y, params, inputs, structure, record_every)
    dtype, device = y.dtype, y.device
    n, p, L, m = structure.n_states, structure.n_outputs, structure.n_estimated_orders, structure.n_params
    N = y.shape[-2]
    nb = len(batch)
    model, weights = _model_and_weights(structure, params, h, dtype, device)
    memory = _make_memory(params.config, N, dtype, device)
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
    record_block = _recorder(out, every, nb, device)
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
    return _result(out, completed, every, nb, N, diverged_at, clamped, memory, device)


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
    state = [(1, carry, diverged_at, clamped)]  # the state after the last step whose outputs are stored
    try:
        if not memory.bounded:
            return _loop_full(model, params, weights, memory, carry, y, u_at, batch, N, n, device, dtype, progress,
                              record_block, diverged_at, clamped, state)
        return _loop_bounded(model, params, weights, memory, carry, y, inputs, u_at, batch, N, n, nb, device, dtype,
                             progress, compile, record_block, diverged_at, clamped, state)
    except KeyboardInterrupt:
        raise _Interrupted(state[0]) from None


def _loop_full(model, params, weights, memory, carry, y, u_at, batch, N, n, device, dtype, progress, record_block,
               diverged_at, clamped, state):
    """:func:`_loop` with the whole history: the KFx states and covariances kept time-reversed, so that each step reads
    one contiguous slice; ``state[0]`` the state after the last stored step."""
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
        state[0] = (k + 1, carry, diverged_at, clamped)
        if progress is not None:
            progress(k, N)
    return state[0]


def _loop_bounded(model, params, weights, memory, carry, y, inputs, u_at, batch, N, n, nb, device, dtype, progress,
                  compile, record_block, diverged_at, clamped, state):
    """:func:`_loop` with a bounded memory (exact lags and an exponential-sum tail, or a window), step by step or in
    compiled blocks of :data:`COMPILE_BLOCK` steps; counts the steps whose KFo sigma orders leave the kernel's range;
    ``state[0]`` the state after the last stored step."""
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
    with _quiet_tracing() if compiled is not None else contextlib.nullcontext():
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
            state[0] = (k, carry, diverged_at, clamped)
            if progress is not None:
                progress(k - 1, N)
    return state[0]


@contextlib.contextmanager
def _quiet_tracing():
    """While torch.compile traces and compiles the filter: Dynamo's note that it traces through a
    ``functools.lru_cache`` (the memory kernel's tensors, cached by dtype and device: the traced values are those
    constants, and Dynamo guards on dtype and device), and the deprecation notes torch's compiler raises about its
    own code (``torch.jit``, ``torch._inductor``), are set aside: nothing a user of torchtea can act on. Every other
    warning passes."""
    import warnings

    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r"Dynamo detected a call to a `functools.lru_cache`",
                                category=UserWarning)
        for module in (r"torch\.jit", r"torch\._inductor", r"torch\._dynamo"):
            warnings.filterwarnings("ignore", category=DeprecationWarning, module=module)
            warnings.filterwarnings("ignore", category=FutureWarning, module=module)
        yield


def _compiled(fn):
    try:
        with _quiet_tracing():  # (importing torch's compiler raises its own deprecation notes)
            return torch.compile(fn, dynamic=False, options={"cpp_wrapper": True})
    except Exception as exc:  # noqa: BLE001 — e.g. a platform without a C++ compiler
        import warnings

        warnings.warn(f"torch.compile unavailable ({type(exc).__name__}: {exc}); running eagerly", stacklevel=3)
        return None

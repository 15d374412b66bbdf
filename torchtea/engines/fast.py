r"""The TEA for the paper's scalar noise model, compiled by numba on the CPU (issue 13).

The batched torch engine (:mod:`.tea`) takes any :class:`~torchtea.engines.structure.Structure` on any device,
but one step is ~1000 small tensor operations; for a scalar model (one state, one order, one parameter
``A = f``, ``B = C = 1``, the MEMS and paper settings) the arithmetic per realisation and step is a few hundred
multiply-adds and exponentials. This module runs exactly the same recursion — the same sigma points, the
same unscented updates, Robbins–Monro adaptation and caps, the same ``exact`` / ``soe`` / ``window`` history
sums, the divergence guard and the ``soe`` clamp count — as one compiled loop per realisation, realisations
in parallel (``numba.prange``). :func:`run_tea_fast` returns the same :class:`~.tea.TEAResult` as
:func:`~.tea.run_tea`, to float64 rounding (the tests compare them to 1e-10).

:func:`~.tea.run_tea` uses it by default whenever it applies (:func:`fast_path_reason` says why not when it
does not): float64 on the CPU, the scalar structure, no ``compile``. Steps run in blocks of
:data:`BLOCK` so that progress is reported and Ctrl-C keeps the finished steps.
"""
from __future__ import annotations

import math

import numpy as np
import torch

from .results import Carry, TEAResult, ut_weights

__all__ = ["fast_path_reason", "use_compiled", "run_tea_fast", "BLOCK"]

#: Steps per compiled call (progress and Ctrl-C are handled between calls).
BLOCK = 256

_KERNEL = None


def fast_path_reason(structure, dtype, device, compile: bool = False, requires_grad: bool = False) -> str | None:
    """``None`` when the compiled engine can run this problem, else why not (one phrase)."""
    if compile:
        return "compile=True asks for the torch.compile engine"
    if torch.device(device or "cpu").type != "cpu":
        return f"the data are on {device}, the compiled engine runs on the CPU"
    if dtype != torch.float64:
        return f"the data are {dtype}, the compiled engine is float64"
    if structure.n_states != 1 or structure.n_outputs != 1 or structure.n_params != 1 or structure.n_inputs > 1:
        return "the structure is not scalar (one state, output and parameter, at most one input)"
    A = structure.A
    if float(A.base.reshape(-1)[0]) != 0.0 or float(A.basis.reshape(-1)[0]) != 1.0:
        return "A(w) is not w"
    if (structure.n_inputs and float(structure.B.reshape(-1)[0]) != 1.0) or float(structure.C.reshape(-1)[0]) != 1.0:
        return "B or C is not 1"
    if requires_grad:
        return "the data or parameters require gradients (numpy arrays cannot carry them)"
    return None


def use_compiled(engine: str, structure, dtype, device, compile: bool = False, requires_grad: bool = False) -> bool:
    """Whether ``engine`` (``"auto"``, ``"torch"`` or ``"numba"``, as in :func:`~.tea.run_tea`) means the compiled
    engine for this problem; ``"numba"`` where it cannot run is a ``ValueError`` saying why."""
    if engine not in ("auto", "torch", "numba"):
        raise ValueError(f"engine must be 'auto', 'torch' or 'numba', got {engine!r}")
    if engine == "torch":
        return False
    reason = fast_path_reason(structure, dtype, device, compile, requires_grad)
    if engine == "numba" and reason is not None:
        raise ValueError(f"engine='numba' cannot run this problem: {reason}")
    return reason is None


def _kernel():
    global _KERNEL
    if _KERNEL is None:
        from ._fast_kernel import advance

        _KERNEL = advance
    return _KERNEL


def _lag_tables(n: int):
    """``(1 − 1/j, −1/j)`` at index ``j = 1 … n`` (index 0 unused), as :func:`torchtea.core.gl._lag_constants`
    computes them, so that the recursion rounds alike."""
    from ..core.gl import _lag_constants

    a, b = _lag_constants(n, torch.float64, torch.device("cpu"))
    la, lb = np.zeros(n + 1), np.zeros(n + 1)
    la[1:], lb[1:] = a.numpy(), b.numpy()
    return la, lb


class FastTEA:
    """The compiled engine's state for a batch of realisations (flattened to ``B``): the carry, the history and
    the settings as numpy arrays, advanced in place by the kernel. ``horizon``: the ``exact`` history's length."""

    def __init__(self, *, h: float, params, batch, memory, horizon: int, carry, has_u: bool):
        from .settings import KFX_UNCERTAINTIES

        cfg = params.config
        self.batch = tuple(batch)
        B = self.B = int(np.prod(self.batch, dtype=np.int64)) if self.batch else 1
        self.has_u = has_u

        def flat(t, event):
            """Broadcast ``t`` (``event`` trailing size-1 dims) to the batch, drop the event dims, flatten."""
            t = t.reshape(t.shape[: t.ndim - event]).expand(self.batch)
            return np.ascontiguousarray(t.reshape(B).cpu().numpy(), dtype=np.float64)

        Q, R, Ro, Rw = flat(params.Q, 2), flat(params.R, 2), flat(params.Ro, 2), flat(params.Rw, 2)
        qmax_o, qmax_w = flat(params.Qmax_o, 0), flat(params.Qmax_w, 0)
        (wm_o, wc_o, sc_o), (wm_w, wc_w, sc_w) = [
            (wm.numpy(), wc.numpy(), float(sc)) for wm, wc, sc in (
                ut_weights(1, cfg.kfo.ut_alpha, cfg.kfo.ut_beta, cfg.kfo.kappa),
                ut_weights(1, cfg.kfw.ut_alpha, cfg.kfw.ut_beta, cfg.kfw.kappa))]
        lo, hi = (float(v) for v in cfg.order_bounds)
        zeros = lambda *s: np.zeros((B,) + s)  # noqa: E731
        kind = self.kind = memory.code  # the one dispatch: core.memory.MemoryPlan.code
        ka = kb = decay = inject = np.zeros(0)
        eta, klo, khi = 1.0, -math.inf, math.inf
        gain = cfg.kfx_uncertainty == "paper-gain"  # the gain's covariance kept apart: its history too
        if kind == 0:
            xl = pl = H = 0
            self.hist = [zeros(horizon), zeros(horizon), zeros(1), zeros(0), zeros(1), zeros(0),
                         zeros(horizon if gain else 1), zeros(1), zeros(0)]
        else:
            xl, pl, H = memory.x_lags, memory.p_lags, memory.head
            if kind == 1:
                ka, kb, decay, inject = (t.numpy() for t in memory.kernel.tensors(torch.float64, torch.device("cpu")))
                eta = float(memory.kernel.eta)
                klo, khi = (float(v) for v in memory.kernel.order_range)
            self.hist = [zeros(1), zeros(1), zeros(xl), zeros(ka.shape[0]), zeros(pl), zeros(H),
                         zeros(1), zeros(pl if gain else 1), zeros(H if gain else 0)]
        self.settings = (float(h), Q, R, Ro, Rw, qmax_o, qmax_w, cfg.noise_scaling == "scaled", int(cfg.sigma_sum_start),
                         lo, hi, float(cfg.divergence_limit), float(cfg.kfo.delta), float(cfg.kfw.delta),
                         KFX_UNCERTAINTIES.index(cfg.kfx_uncertainty),
                         cfg.estimate_uncertainty == "constant-truth",
                         wm_o, wc_o, sc_o, wm_w, wc_w, sc_w,
                         kind, xl, pl, H, ka, kb, float(np.abs(kb[:-1]).max(initial=0.0)), decay, inject, eta, klo, khi,
                         klo if kind == 1 else -math.inf, khi if kind == 1 else math.inf, *_lag_tables(horizon if kind == 0 else max(xl, pl)))
        # the carry after step 0 (tea._first_step) and its history
        self.state = [np.array(t.reshape(B, -1)[:, 0].numpy(), dtype=np.float64) for t in carry[:8]]
        self.gain = gain
        self.pg = np.array(carry.Pg.reshape(B).numpy(), dtype=np.float64) if gain else zeros()
        # KFo's and KFw's own covariances, which set their gains (equal to Po, Pw unless "constant-truth")
        self.constant = carry.Pog is not None
        self.pog, self.pwg = (np.array(t.reshape(B).numpy(), dtype=np.float64) for t in (carry.Po_own, carry.Pw_own))
        self.div = np.array(carry.diverged.reshape(B).numpy(), dtype=np.bool_)
        self.dat = np.where(self.div, 0, -1).astype(np.int64)
        self.clamp = np.zeros(B, dtype=np.int64)
        xh, Ph, win, modes, Pwin, Phead, Pgh, Pwin_g, Phead_g = self.hist
        x0, P0 = self.state[0], self.state[1]
        if kind == 0:
            xh[:, 0], Ph[:, 0], Pgh[:, 0] = x0, P0, self.pg
        else:
            win[:, 0], Pwin[:, 0], Pwin_g[:, 0] = x0, P0, self.pg
            if H > 0:
                Phead[:, 0] += P0
                if gain:
                    Phead_g[:, 0] += self.pg
        self._advance = _kernel()

    def advance(self, k0: int, k1: int, y: np.ndarray, u: np.ndarray | None, outs, *, yoff: int = 0, ooff: int = 0,
                every: int = 1):
        """Steps ``k0 … k1−1``: ``y[:, k − yoff]``, ``u[:, k − 1 − yoff]``; outputs of the steps ``k`` with
        ``k % every == 0`` into row ``k // every − ooff`` of the ten arrays ``outs``."""
        self._advance(k0, k1, yoff, ooff, every, y, np.zeros((1, 1)) if u is None else u, u is not None,
                      *self.settings, *self.state, self.div, self.dat, self.clamp, self.pg, self.pog, self.pwg, *self.hist,
                      *outs)

    def carry(self):
        """The current carry as torch tensors of :class:`~.tea.Carry`'s shapes."""
        t = lambda a: torch.from_numpy(a.copy()).reshape(self.batch)  # noqa: E731
        x, P, al, Po, Qo, w, Pw, Qw = (t(a) for a in self.state)
        v, m = (lambda a: a.unsqueeze(-1)), (lambda a: a.unsqueeze(-1).unsqueeze(-1))
        own = (m(t(self.pog)), m(t(self.pwg))) if self.constant else (None, None)
        return Carry(v(x), m(P), v(al), m(Po), m(Qo), v(w), m(Pw), m(Qw), t(self.div), m(t(self.pg)) if self.gain else None,
                     *own)


def block_steps(eng: "FastTEA", k: int, B: int) -> int:
    """Steps of the next compiled call: :data:`BLOCK`, fewer where a block would take more than about half a
    second (progress and Ctrl-C act between calls) — ``exact`` memory costs ~4·k·B multiply-adds per step,
    bounded memory ~0.5 µs per realisation and step."""
    per_step = 4e-9 * k * B if eng.kind == 0 else 5e-7 * B
    return max(1, min(BLOCK, int(0.5 / max(per_step, 1e-12))))


def run_tea_fast(y, *, h: float, params, inputs=None, progress=None, record_every: int = 1, partial: bool = False,
                 batch=None, memory=None, first=None):
    """:func:`~.tea.run_tea` for the scalar structure on the CPU (module docstring). Called by ``run_tea``,
    which has checked the shapes and built ``batch``, the memory strategy and the first step's carry."""
    N = y.shape[-2]
    every = int(record_every)
    carry, out0 = first
    eng = FastTEA(h=h, params=params, batch=batch, memory=memory, horizon=N, carry=carry, has_u=inputs is not None)
    B = eng.B
    yv = np.ascontiguousarray(y.reshape(B, N).cpu().numpy())
    uv = None if inputs is None else np.ascontiguousarray(inputs.reshape(B, N).cpu().numpy())
    n_out = (N - 1) // every + 1
    outs = [np.empty((B, n_out)) for _ in range(10)]
    for o, v in zip(outs, [*eng.state, out0.innovation.reshape(B).numpy(), out0.innovation_cov.reshape(B).numpy()]):
        o[:, 0] = v
    completed = 1
    clamp = eng.clamp.copy()  # the clamp count of the finished blocks (a Ctrl-C drops the block it interrupts)
    try:
        if progress is not None:
            progress(0, N)  # the work starts (a progress clock starts with it)
        k = 1
        while k < N:
            k1 = min(N, k + block_steps(eng, k, B))
            eng.advance(k, k1, yv, uv, outs, every=every)
            k = completed = k1
            clamp = eng.clamp.copy()
            if progress is not None:
                progress(k - 1, N)
    except KeyboardInterrupt:
        if not partial:
            raise
    rows = (completed - 1) // every + 1
    t = lambda a: torch.from_numpy(a[:, :rows]).reshape(tuple(batch) + (rows,))  # noqa: E731
    vec = lambda a: t(a).unsqueeze(-1)  # noqa: E731
    mat = lambda a: t(a).unsqueeze(-1).unsqueeze(-1)  # noqa: E731
    ox, oP, oa, oPo, oQo, ow, oPw, oQw, oe, oS = outs
    diverged = (eng.dat >= 0) & (eng.dat < completed)
    return TEAResult(vec(ox), mat(oP), vec(oa), mat(oPo), mat(oQo), vec(ow), mat(oPw), mat(oQw), vec(oe), mat(oS),
                     diverged=torch.from_numpy(diverged).reshape(batch),
                     diverged_at=torch.from_numpy(np.where(diverged, eng.dat, -1)).reshape(batch),
                     steps=torch.arange(0, completed, every),
                     memory_clamped=torch.from_numpy(clamp).reshape(batch) if eng.kind == 1 else None,
                     interrupted=completed < N)

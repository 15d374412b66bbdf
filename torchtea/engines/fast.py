r"""The TEA for the paper's scalar noise model, compiled by numba on the CPU.

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
from typing import NamedTuple

import numpy as np
import torch

from .results import STEP_OUTPUTS, Carry, TEAResult, ut_weights

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


class Settings(NamedTuple):
    """The kernel's settings, by name (the compiled kernel :func:`~._fast_kernel.advance` takes them in this order;
    tests/test_fast.py checks the names against its signature)."""

    h: float
    Q: np.ndarray
    R: np.ndarray
    Ro: np.ndarray
    Rw: np.ndarray
    qmax_o: np.ndarray
    qmax_w: np.ndarray
    scaled: bool  # noise_scaling == "scaled"
    start: int  # sigma_sum_start
    lo: float  # order_bounds
    hi: float
    limit: float  # divergence_limit
    delta_o: float
    delta_w: float
    mode: int  # kfx_uncertainty: KFX_UNCERTAINTIES.index
    const: bool  # estimate_uncertainty == "constant-truth"
    inn_o: bool  # kfo.R == "innovation"
    inn_w: bool  # kfw.R == "innovation"
    wm_o: np.ndarray  # KFo's unscented weights and scale
    wc_o: np.ndarray
    scale_o: float
    wm_w: np.ndarray  # KFw's
    wc_w: np.ndarray
    scale_w: float
    kind: int  # the memory plan's code (core.memory.MemoryPlan.code)
    xl: int  # lags of the mean sum, of the covariance sum, start-up covariances kept
    pl: int
    H: int
    ka: np.ndarray  # the soe kernel (empty otherwise)
    kb: np.ndarray
    kbig: float
    decay: np.ndarray
    inject: np.ndarray
    eta: float
    klo: float
    khi: float
    count_lo: float  # the range outside which a sigma order counts as clamped
    count_hi: float
    la: np.ndarray  # the lag tables of the GL coefficients
    lb: np.ndarray


class State(NamedTuple):
    """The carry per realisation (``(B,)`` arrays, advanced in place): KFx's x̂ and P, KFo's α̂, P, Q, KFw's ŵ, P, Q,
    the divergence flag and step, the clamp count, the gain's covariance, KFo's and KFw's own covariances and KFx's
    innovation covariance of the gain."""

    X: np.ndarray
    P: np.ndarray
    AL: np.ndarray
    PO: np.ndarray
    QO: np.ndarray
    W: np.ndarray
    PW: np.ndarray
    QW: np.ndarray
    DIV: np.ndarray
    DAT: np.ndarray
    CLAMP: np.ndarray
    PG: np.ndarray
    POG: np.ndarray
    PWG: np.ndarray
    SS: np.ndarray  # KFx's innovation covariance of the step before (kfo.R or kfw.R = "innovation"; else zeros)


class History(NamedTuple):
    """KFx's history as the memory keeps it (``exact``: ``xh``, ``Ph``, ``Pgh`` the whole past; bounded: the
    windows, the modes and the start-up covariances), in place."""

    xh: np.ndarray
    Ph: np.ndarray
    win: np.ndarray
    modes: np.ndarray
    Pwin: np.ndarray
    Phead: np.ndarray
    Pgh: np.ndarray
    Pwin_g: np.ndarray
    Phead_g: np.ndarray


#: The kernel's output arrays by the :class:`~.results.TEAResult` field each fills (``STEP_OUTPUTS`` order).
OUTPUTS = {"x": "o_x", "P": "o_P", "alpha": "o_a", "P_alpha": "o_Po", "Q_alpha": "o_Qo", "w": "o_w", "P_w": "o_Pw",
           "Q_w": "o_Qw", "innovation": "o_e", "innovation_cov": "o_S"}

#: The kernel's leading arguments (the steps and the data), before the named groups.
LEADING = ("k0", "k1", "yoff", "ooff", "every", "y", "u", "has_u")


def kernel_arguments() -> tuple:
    """The names of the compiled kernel's arguments as :class:`FastTEA` passes them."""
    return LEADING + Settings._fields + State._fields + History._fields + tuple(OUTPUTS.values())


def _kernel():
    global _KERNEL
    if _KERNEL is None:
        from ._fast_kernel import advance

        _KERNEL = advance
    return _KERNEL


def _lag_tables(n: int):
    """``(1 − 1/j, −1/j)`` at index ``j = 1 … n`` (index 0 unused), as :func:`torchtea.core.gl.lag_constants`
    computes them, so that the recursion rounds alike."""
    from ..core.gl import lag_constants

    a, b = lag_constants(n, torch.float64, torch.device("cpu"))
    la, lb = np.zeros(n + 1), np.zeros(n + 1)
    la[1:], lb[1:] = a.numpy(), b.numpy()
    return la, lb


def memory_arrays(memory, horizon: int, B: int, gain: bool) -> tuple[dict, History]:
    """The memory plan ``memory`` (``core.memory.MemoryPlan``, or the torch engine's memory) as the kernel reads it:
    its :class:`Settings` fields from ``kind`` to ``lb`` by name, and an empty :class:`History` of ``B``
    realisations (``horizon``: the ``exact`` history's length; ``gain``: with the gain's covariances)."""
    zeros = lambda *s: np.zeros((B,) + s)  # noqa: E731
    kind = memory.code  # the one dispatch: core.memory.MemoryPlan.code
    ka = kb = decay = inject = np.zeros(0)
    eta, klo, khi = 1.0, -math.inf, math.inf
    if kind == 0:
        xl = pl = H = 0
        hist = History(xh=zeros(horizon), Ph=zeros(horizon), win=zeros(1), modes=zeros(0), Pwin=zeros(1),
                       Phead=zeros(0), Pgh=zeros(horizon if gain else 1), Pwin_g=zeros(1), Phead_g=zeros(0))
    else:
        xl, pl, H = memory.x_lags, memory.p_lags, memory.head
        if kind == 1:
            ka, kb, decay, inject = (t.numpy() for t in memory.kernel.tensors(torch.float64, torch.device("cpu")))
            eta = float(memory.kernel.eta)
            klo, khi = (float(v) for v in memory.kernel.order_range)
        hist = History(xh=zeros(1), Ph=zeros(1), win=zeros(xl), modes=zeros(ka.shape[0]), Pwin=zeros(pl),
                       Phead=zeros(H), Pgh=zeros(1), Pwin_g=zeros(pl if gain else 1), Phead_g=zeros(H if gain else 0))
    la, lb = _lag_tables(horizon if kind == 0 else max(xl, pl))
    settings = dict(kind=kind, xl=xl, pl=pl, H=H, ka=ka, kb=kb, kbig=float(np.abs(kb[:-1]).max(initial=0.0)),
                    decay=decay, inject=inject, eta=eta, klo=klo, khi=khi, count_lo=klo if kind == 1 else -math.inf,
                    count_hi=khi if kind == 1 else math.inf, la=la, lb=lb)
    return settings, hist


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
        gain = cfg.kfx_uncertainty == "paper-gain"  # the gain's covariance kept apart: its history too
        mem, hist = memory_arrays(memory, horizon, B, gain)
        self.kind = mem["kind"]
        self.settings = Settings(
            h=float(h), Q=Q, R=R, Ro=Ro, Rw=Rw, qmax_o=qmax_o, qmax_w=qmax_w, scaled=cfg.noise_scaling == "scaled",
            start=int(cfg.sigma_sum_start), lo=lo, hi=hi, limit=float(cfg.divergence_limit),
            delta_o=float(cfg.kfo.delta), delta_w=float(cfg.kfw.delta),
            mode=KFX_UNCERTAINTIES.index(cfg.kfx_uncertainty), const=cfg.estimate_uncertainty == "constant-truth",
            inn_o=cfg.kfo.uses_innovation, inn_w=cfg.kfw.uses_innovation,
            wm_o=wm_o, wc_o=wc_o, scale_o=sc_o, wm_w=wm_w, wc_w=wc_w, scale_w=sc_w,
            **mem)
        # the carry after step 0 (tea._first_step) and its history
        col = lambda t: np.array(t.reshape(B, -1)[:, 0].numpy(), dtype=np.float64)  # noqa: E731
        self.gain = gain
        # KFo's and KFw's own covariances, which set their gains (equal to Po, Pw unless "constant-truth")
        self.constant = carry.Pog is not None
        self.innovation = carry.S is not None  # KFo or KFw takes KFx's innovation covariance as R
        div = np.array(carry.diverged.reshape(B).numpy(), dtype=np.bool_)
        self.state = State(X=col(carry.x), P=col(carry.P), AL=col(carry.alpha), PO=col(carry.Po), QO=col(carry.Qo),
                           W=col(carry.w), PW=col(carry.Pw), QW=col(carry.Qw), DIV=div,
                           DAT=np.where(div, 0, -1).astype(np.int64), CLAMP=np.zeros(B, dtype=np.int64),
                           PG=np.array(carry.Pg.reshape(B).numpy(), dtype=np.float64) if gain else zeros(),
                           POG=np.array(carry.Po_own.reshape(B).numpy(), dtype=np.float64),
                           PWG=np.array(carry.Pw_own.reshape(B).numpy(), dtype=np.float64),
                           SS=np.array(carry.S.reshape(B).numpy(), dtype=np.float64) if self.innovation else zeros())
        self.hist = hist
        self._groups = (*self.settings, *self.state, *self.hist)
        s = self.state
        if self.kind == 0:
            hist.xh[:, 0], hist.Ph[:, 0], hist.Pgh[:, 0] = s.X, s.P, s.PG
        else:
            hist.win[:, 0], hist.Pwin[:, 0], hist.Pwin_g[:, 0] = s.X, s.P, s.PG
            if mem["H"] > 0:
                hist.Phead[:, 0] += s.P
                if gain:
                    hist.Phead_g[:, 0] += s.PG
        self._advance = _kernel()

    def advance(self, k0: int, k1: int, y: np.ndarray, u: np.ndarray | None, outs: dict, *, yoff: int = 0,
                ooff: int = 0, every: int = 1):
        """Steps ``k0 … k1−1``: ``y[:, k − yoff]``, ``u[:, k − 1 − yoff]``; outputs of the steps ``k`` with
        ``k % every == 0`` into row ``k // every − ooff`` of ``outs`` (a ``(B, rows)`` array per
        :data:`~.results.STEP_OUTPUTS` name). The arguments go by name (:func:`kernel_arguments`)."""
        # in kernel_arguments() order: the leading ones, then the named groups (their arrays change in place only,
        # so they are put together once), then the outputs by TEAResult field
        self._advance(k0, k1, yoff, ooff, every, y, np.zeros((1, 1)) if u is None else u, u is not None,
                      *self._groups, *(outs[name] for name in OUTPUTS))

    def carry(self):
        """The current carry as torch tensors of :class:`~.tea.Carry`'s shapes."""
        t = lambda a: torch.from_numpy(a.copy()).reshape(self.batch)  # noqa: E731
        v = lambda a: t(a).unsqueeze(-1)  # noqa: E731
        m = lambda a: t(a).unsqueeze(-1).unsqueeze(-1)  # noqa: E731
        s = self.state
        return Carry(x=v(s.X), P=m(s.P), alpha=v(s.AL), Po=m(s.PO), Qo=m(s.QO), w=v(s.W), Pw=m(s.PW), Qw=m(s.QW),
                     diverged=t(s.DIV), Pg=m(s.PG) if self.gain else None,
                     Pog=m(s.POG) if self.constant else None, Pwg=m(s.PWG) if self.constant else None,
                     S=m(s.SS) if self.innovation else None)


def block_steps(eng: FastTEA, k: int, B: int) -> int:
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
    outs = {name: np.empty((B, n_out)) for name in STEP_OUTPUTS}
    s = eng.state
    first_row = dict(x=s.X, P=s.P, alpha=s.AL, P_alpha=s.PO, Q_alpha=s.QO, w=s.W, P_w=s.PW, Q_w=s.QW,
                     innovation=out0.innovation.reshape(B).numpy(), innovation_cov=out0.innovation_cov.reshape(B).numpy())
    for name in STEP_OUTPUTS:
        outs[name][:, 0] = first_row[name]
    completed = 1
    clamp = s.CLAMP.copy()  # the clamp count of the finished blocks (a Ctrl-C drops the block it interrupts)
    try:
        if progress is not None:
            progress(0, N)  # the work starts (a progress clock starts with it)
        k = 1
        while k < N:
            k1 = min(N, k + block_steps(eng, k, B))
            eng.advance(k, k1, yv, uv, outs, every=every)
            k = completed = k1
            clamp = eng.state.CLAMP.copy()
            if progress is not None:
                progress(k - 1, N)
    except KeyboardInterrupt:
        if not partial:
            raise
    rows = (completed - 1) // every + 1
    t = lambda a: torch.from_numpy(a[:, :rows]).reshape(tuple(batch) + (rows,))  # noqa: E731
    vec = lambda a: t(a).unsqueeze(-1)  # noqa: E731
    mat = lambda a: t(a).unsqueeze(-1).unsqueeze(-1)  # noqa: E731
    covariances = {"P", "P_alpha", "Q_alpha", "P_w", "Q_w", "innovation_cov"}
    dat = eng.state.DAT
    diverged = (dat >= 0) & (dat < completed)
    return TEAResult(**{name: (mat if name in covariances else vec)(outs[name]) for name in STEP_OUTPUTS},
                     diverged=torch.from_numpy(diverged).reshape(batch),
                     diverged_at=torch.from_numpy(np.where(diverged, dat, -1)).reshape(batch),
                     steps=torch.arange(0, completed, every),
                     memory_clamped=torch.from_numpy(clamp).reshape(batch) if eng.kind == 1 else None,
                     interrupted=completed < N)

r"""The TEA with the exact filter as its KFx: KFo and KFw as the TEA has them, KFx the Kalman filter of the
model's own state space (:meth:`~torchtea.noise.model.NoiseModel.state_space`, the one the likelihood runs).

Why. The paper's KFx predicts from its filtered past, :math:`\tilde x_k = h^\alpha A \hat x_{k-1} - \sum_j c_j
\hat x_{k-j|k-j}`, and never revises that past; its covariance drops the cross-covariances of the past errors. When
the fractional state is nearly observed (the paper's models) this is the optimal predictor to many digits. When
another state shares the output — a random walk, a Gauss–Markov bias that ``check`` added — each new sample revises
how the past splits between them, and KFx's innovations at the true values stay correlated with the past (lag-1
autocorrelation −0.03 at walk σ 0.05, experiments/tea_models/fixed_point.py). KFo settles where its innovations
stop correlating with the order's regressor, and with such innovations that point is not the truth: α̂ −0.012
(sd 0.006). With the exact filter, whose state holds the whole (``soe``-compressed) past and whose innovations are
white at the truth, the same KFo gives +0.001 ± 0.001.

How. Every step ``k ≥ 1``, as :func:`torchtea.engines.tea.run_tea` orders it:

1. KFo's sigma orders ``αᵢ`` (with ``ŵ_{k−1}``) and KFw's sigma poles ``wᵢ`` (with ``α̂_{k−1}``) each predict
   ``y_k = C F(αᵢ, wᵢ) ẑ_{k−1|k−1}``. Only the fractional block's first row of ``F`` depends on the order and pole
   (:meth:`~torchtea.noise.components.Fractional.first_row`), so a replica is that row times the block's state;
2. KFo and KFw update with the TEA's own unscented update, R (a number or ``"innovation"``: KFx's ``S_{k−1}``),
   adaptation (25) and order bounds (:mod:`torchtea.engines.tea`'s functions, not copies);
3. KFx: the exact filter's prediction with ``F(α̂_k, ŵ_{k−1})`` and the drive ``h^{α̂_k}√q``, then its update.

At ``k = 0`` the exact filter updates from the model's initial state; KFo and KFw start at the view's starts. With
``kfo_kfw = "joint"`` steps 1–2 are one unscented filter over (order, pole) (five sigma points ``(αᵢ, wᵢ)``, each a
replica) and KFx runs at ``α̂_k, ŵ_k``.

What it is not: the paper's KFx (its estimates differ, by design), nor a smoother. Its ``P`` is the exact filter's at
the current estimates (``kfx_uncertainty`` and ``estimate_uncertainty`` do not apply and are refused unless at their
defaults); the result's ``x`` and ``P`` are each view state's current value (the block's first state) and their
covariance. The state holds ``lags + modes`` values of the fractional state (71 for 6000 samples under ``soe``), and
each step updates a covariance of that size (``F`` applied sparse): about the TEA's torch engine's time on a batch
of series. A batch may hold one view per series (``identify``: the channels of one model, each with its own values
and settings; :func:`batch_key` says what they share): the bundled recording's six channels in 34 s, against 154 s
one at a time (experiments/bench/README.md). Torch, on the CPU; progress and Ctrl-C (``partial``) as ``run_tea`` has
them. A series whose estimates leave ``divergence_limit`` (or become non-finite) is flagged in ``diverged``, not
frozen.
"""
from __future__ import annotations

import torch
from torch import Tensor

from ..engines.results import TEAResult, ut_weights
from ..engines.tea import adapt_q, q_cap, sigma_points, ut_update
from .model import state_memory
from .tea import TEAView

__all__ = ["run_tea_exact", "check_exact", "KERNEL_ORDERS"]

#: The orders a ``soe`` kernel of the exact-KFx TEA serves: the model's 0 … 1 and half an order beyond on each side,
#: where KFo's sigma points go (±√(3 P̃ᵒ)). Every state of the fractional block is in each step's dense covariance
#: update, so the kernel is kept this narrow (63 modes at 6000 samples, against 86 for the TEA's −0.95 … 3.5).
KERNEL_ORDERS = (-0.5, 1.5)

#: Steps between two progress calls (a step takes ~0.5 ms on the bundled recording's models).
PROGRESS_STEPS = 64


def _first(v) -> float:
    """A setting that may be written as a number or a one-entry list (``Q0 = [1e-5]``), as a number."""
    return float(torch.as_tensor(v, dtype=torch.float64).reshape(-1)[0])


def _number(R, name: str) -> float | None:
    """A filter's R: None for ``"innovation"`` (KFx's S of the step before), else one number."""
    if isinstance(R, str):
        return None
    t = torch.as_tensor(R, dtype=torch.float64)
    if t.numel() != 1:
        raise ValueError(f"{name}.R: the exact-KFx TEA runs one output and takes a number or 'innovation', got {R!r}")
    return float(t.reshape(()))


def check_exact(view: TEAView) -> None:
    """Raise ``ValueError`` naming what :func:`run_tea_exact` cannot run in ``view`` (its settings or its model), so
    that a workflow refuses before it starts: the two covariance settings, one order and one pole, KFo's and KFw's
    R a number or "innovation", a bounded memory, no order modifier; with ``kfo_kfw = "joint"`` KFw's filter settings
    those of KFo (the one filter's)."""
    cfg = view.config
    if cfg.kfx_uncertainty not in ("paper", "paper-gain") or cfg.estimate_uncertainty != "paper":
        raise ValueError("the exact-KFx TEA reports the exact filter's covariance: kfx_uncertainty and "
                         "estimate_uncertainty do not apply (leave them at 'paper-gain'/'paper' and 'paper')")
    if len(view.orders) != 1 or len(view.params) != 1:
        raise ValueError(f"the exact-KFx TEA estimates one order and one pole; the view of {view.model.spec!r} has "
                         f"{view.orders} and {view.params}")
    _number(cfg.kfo.R, "kfo")
    _number(cfg.kfw.R, "kfw")
    if not cfg.memory.bounded:
        raise ValueError("kfx_filter 'exact' carries the past in the filter's state: give memory 'soe' (or "
                         "'window:L'), not 'exact', which would make every past sample a state")
    if cfg.kfo_kfw == "joint":  # one filter with KFo's settings: KFw's own would be ignored, so they must agree
        differ = [f for f in ("ut_alpha", "ut_beta", "kappa", "delta", "Q_max")
                  if getattr(cfg.kfo, f) != getattr(cfg.kfw, f)]
        if isinstance(cfg.kfo.R, str) != isinstance(cfg.kfw.R, str) or (
                not isinstance(cfg.kfo.R, str) and _number(cfg.kfo.R, "kfo") != _number(cfg.kfw.R, "kfw")):
            differ.append("R")
        if differ:
            raise ValueError(f"kfo_kfw 'joint' runs one filter with KFo's {', '.join(differ)}; KFw's differ "
                             f"({', '.join(f'{f} {getattr(cfg.kfw, f)!r} vs {getattr(cfg.kfo, f)!r}' for f in differ)}): "
                             "give KFw the same, or leave them at KFo's")
    if any(c.kind == "modifier" for _, c in view.model.components):  # tea_view drops it: KFo tracks the order
        raise ValueError(f"model {view.model.spec!r}: its order modifier makes the state space's rows vary in time; "
                         "the exact-KFx TEA runs the model without it (as KFo estimates the order's variation): drop it")


def batch_key(view: TEAView) -> tuple:
    """What the series of one :func:`run_tea_exact` batch share: the model, the memory and the filters' form (sigma
    points, adaptation's gain, R a number or the innovation's, the sum's start). Numbers (the model's values, starts,
    P0, Q0, R, caps, bounds, limits) may differ from series to series."""
    cfg = view.config
    unscented = tuple((u.ut_alpha, u.ut_beta, u.kappa, float(u.delta), isinstance(u.R, str))
                      for u in (cfg.kfo, cfg.kfw))
    return (view.model.spec, view.orders, view.params, view.states, cfg.memory, cfg.sigma_sum_start, unscented,
            cfg.kfo_kfw)


def run_tea_exact(view, y, *, h: float, progress=None, partial: bool = False) -> TEAResult:
    """Run the TEA with the exact filter of ``view.model``'s state space at ``view.values`` as KFx.

    ``y`` ``(N,)`` or ``(R, N)`` (R series, e.g. realisations; NaN = missing) at the view's sample interval ``h``;
    ``view`` one :class:`TEAView` for every series, or a sequence of R (e.g. one per channel of a recording, each with
    its fitted values and settings) that share :func:`batch_key`. A view's ``config`` sets KFo and KFw (starts, P0,
    Q0, R, sigma points, adaptation, ``order_bounds``, ``sigma_sum_start``) and, by its ``memory``, the state space's
    (``soe``, its kernel covering :data:`KERNEL_ORDERS`, or ``window``: each lag a state; ``exact`` would make every
    past sample a state and is refused). ``progress``: called as ``progress(k, N)`` as steps complete, as
    :func:`~torchtea.engines.tea.run_tea` calls it; ``partial``: on Ctrl-C return the finished steps with
    ``interrupted=True`` instead of raising. Returns a :class:`TEAResult` with time at −2 (``memory_clamped``: steps
    at which a sigma order or α̂ left the kernel's range and its row was taken at the range's end)."""
    views, y = _checked(view, y)
    run = _ExactRun(views, y, h)
    N = y.shape[1]
    completed = 0  # steps whose outputs are stored: a Ctrl-C keeps them
    try:
        if progress is not None:
            progress(0, N)  # the work starts (a progress clock starts with it)
        for k in range(N):
            run.step(k)
            completed = k + 1
            if progress is not None and (k % PROGRESS_STEPS == 0 or k == N - 1):
                progress(k, N)
    except KeyboardInterrupt:
        if not partial:
            raise
    return run.result(completed)


def _checked(view, y) -> tuple[list, Tensor]:
    """The views (one, or one per series, sharing :func:`batch_key`) and the series ``(R, N)``, checked; ``ValueError``
    naming what does not fit."""
    views = [view] if isinstance(view, TEAView) else list(view)
    if not views:
        raise ValueError("run_tea_exact needs a view")
    for v in views:
        check_exact(v)
    view = views[0]
    key = batch_key(view)
    for i, v in enumerate(views[1:], 1):
        if batch_key(v) != key:
            raise ValueError(f"view {i} ({v.model.spec!r}) differs from view 0 ({view.model.spec!r}) in its model, memory "
                             "or filters' form (batch_key): run them apart")
    y = torch.as_tensor(y, dtype=torch.float64)
    y = y.unsqueeze(0) if y.ndim == 1 else y
    if y.ndim != 2:
        raise ValueError(f"y must be (N,) or (R, N), got shape {tuple(y.shape)}")
    if len(views) not in (1, y.shape[0]):
        raise ValueError(f"{len(views)} views for {y.shape[0]} series: give one view, or one per series")
    return views, y


class _ExactRun:
    """One :func:`run_tea_exact`: the state space at the views' values (its transition with the fractional block's
    varying row, :class:`_Transition`), KFo's and KFw's states (or the joint filter's), the exact filter's state and
    covariance, and the outputs written in place step by step."""

    def __init__(self, views: list, y: Tensor, h: float):
        view = views[0]
        self.views, self.y, self.h, self.cfg = views, y, h, view.config
        self.Rn, self.N = y.shape
        self.B = B = len(views)  # parameter sets: 1 (every series) or one per series
        model, label = view.model, view.orders[0]
        self.comp = dict(model.components)[label]
        self.mem = mem = state_memory(self.cfg.memory, self.N, orders=KERNEL_ORDERS)
        dicts = [model.as_dict(v.values) for v in views]
        values = {k: torch.cat([d[k].reshape(-1) for d in dicts]) for k in dicts[0]}
        ss = model.state_space(values, h, self.N, memory=mem)
        self.sl = sl = ss.blocks[label]
        self.row0 = row0 = sl.start
        F0, G0, self.C, self.r = ss.F, ss.G, ss.C, ss.R  # (B, D, D), (B, D, m), (B, D), (B,)
        self.Q0 = G0 @ G0.mT
        self.q = values[f"{label}.q"].reshape(B, 1)
        self.c0 = self.C[:, row0:row0 + 1]  # (B, 1): the fractional state's loading on the output
        D = F0.shape[-1]
        self.k_lo, self.k_hi = (mem.kernel.order_range if mem.kernel is not None else (-torch.inf, torch.inf))
        self._filters()
        self.trans = _Transition(F0, row0, sl)
        # the exact filter from the model's initial state
        g0 = ss.initial  # (B, D)
        self.z = torch.zeros(self.Rn, D, dtype=torch.float64)
        self.P = (g0.unsqueeze(-1) * g0.unsqueeze(-2)).expand(self.Rn, D, D).clone()
        self.idx = idx = _state_index(view, ss)
        n = len(idx)
        # the outputs, written in place step by step (small tensors kept per step would pin the freed covariance
        # temporaries in the heap: 20 GB for 32 × 12000 steps)
        self.shapes = {"x": (n,), "P": (n, n), "alpha": (1,), "P_alpha": (1, 1), "Q_alpha": (1, 1), "w": (1,),
                       "P_w": (1, 1), "Q_w": (1, 1), "innovation": (1,), "innovation_cov": (1, 1)}
        self.out = {k: torch.empty((self.Rn, self.N) + sh, dtype=torch.float64) for k, sh in self.shapes.items()}
        self.S_prev = None

    def _filters(self) -> None:
        """KFo's and KFw's weights, starts, P0, Q0, R and caps per series — or the joint filter's over (order,
        pole) — and the order bounds."""
        cfg = self.cfg
        self.ko, self.kw = ko, kw = cfg.kfo, cfg.kfw
        self.wm_o, self.wc_o, self.scale_o = ut_weights(1, ko.ut_alpha, ko.ut_beta, ko.kappa)
        self.wm_w, self.wc_w, self.scale_w = ut_weights(1, kw.ut_alpha, kw.ut_beta, kw.kappa)
        self.start = cfg.sigma_sum_start
        col, sq = self.col, self.sq
        self.alpha, self.Po, self.Qo = col(lambda c: c.kfo.x0), sq(lambda c: c.kfo.P0), sq(lambda c: c.kfo.Q0)
        self.w, self.Pw, self.Qw = col(lambda c: c.kfw.x0), sq(lambda c: c.kfw.P0), sq(lambda c: c.kfw.Q0)
        # KFo's and KFw's R: None for "innovation" (KFx's S of the step before), else a number per series
        self.Ro_num = None if isinstance(ko.R, str) else sq(lambda c: _number(c.kfo.R, "kfo"))
        self.Rw_num = None if isinstance(kw.R, str) else sq(lambda c: _number(c.kfw.R, "kfw"))
        self.joint = cfg.kfo_kfw == "joint"
        if self.joint:  # one filter over θ = (order, pole): KFo's settings, the two starts
            self.wm_j, self.wc_j, self.scale_j = ut_weights(2, ko.ut_alpha, ko.ut_beta, ko.kappa)
            self.theta = torch.cat([self.alpha, self.w], dim=-1)  # (R, 2)
            self.Pj = torch.diag_embed(torch.cat([self.Po[..., 0], self.Pw[..., 0]], dim=-1))
            self.Qj = torch.diag_embed(torch.cat([self.Qo[..., 0], self.Qw[..., 0]], dim=-1))
            # KFo's cap over the 2 × 2 Q: its largest diagonal entry stays under it ("Q0": the larger of the two Q0)
            self.qmax_o = self.qmax(lambda c: c.kfo.Q_max, lambda c: c.kfo.Q0, lambda c: c.kfw.Q0)
        else:
            self.qmax_o = self.qmax(lambda c: c.kfo.Q_max, lambda c: c.kfo.Q0)
            self.qmax_w = self.qmax(lambda c: c.kfw.Q_max, lambda c: c.kfw.Q0)
        self.lo, self.hi = col(lambda c: c.order_bounds[0]), col(lambda c: c.order_bounds[1])
        self.clamped = torch.zeros(self.Rn, dtype=torch.int64)

    def per_series(self, numbers) -> Tensor:
        """``(R,)``: one number per view, for every series (one view: the same for all)."""
        t = torch.as_tensor(numbers, dtype=torch.float64).reshape(self.B)
        return t.expand(self.Rn) if self.B == 1 else t

    def col(self, get):
        """``(R, 1)``: a number of each view's settings (``get(config)``), per series."""
        return self.per_series([_first(get(v.config)) for v in self.views]).reshape(self.Rn, 1).clone()

    def sq(self, get):
        return self.col(get).unsqueeze(-1)

    def qmax(self, Q_max, *Q0s):
        """The TEA's cap (``Q_max``: "none", "Q0" or a number) per series for a filter whose Q starts at ``Q0s`` (each
        ``get(config)``): a vector filter's caps its Q's largest diagonal entry (engines.tea.adapt_q)."""
        like = torch.zeros((), dtype=torch.float64)
        return self.per_series([float(q_cap(Q_max(v.config), torch.diag(torch.tensor(
            [_first(q(v.config)) for q in Q0s], dtype=torch.float64)), like)) for v in self.views])

    def row(self, a, f):
        """The fractional block's first row ``(…, J + M)`` and noise loading under orders a and poles f."""
        a_in = a.clamp(self.k_lo, self.k_hi)
        return self.comp.first_row({"pole": f, "q": self.q}, a_in, self.h, self.mem)

    def dot_c(self, M):
        """``C z`` for states ``M`` ``(R, D)`` (one parameter set: the product as it always was)."""
        C = self.C
        return M @ C[0] if self.B == 1 else (M.unsqueeze(-2) @ C.unsqueeze(-1))[..., 0, 0]

    def step(self, k: int) -> None:
        """Step ``k``: KFo and KFw (k ≥ 1), KFx's prediction under their estimates and its update; the outputs
        stored at ``k``."""
        yk = self.y[:, k:k + 1]
        mask = ~torch.isnan(yk)
        y0 = torch.where(mask, yk, torch.zeros_like(yk))
        if k == 0:
            z_pred, P_pred = self.z, self.P
        else:
            z_pred, P_pred, step_clamped = self._predict(mask, y0)
        C, z = self.C, self.z
        Pc = P_pred @ C[0] if self.B == 1 else (P_pred @ C.unsqueeze(-1))[..., 0]
        S = ((C * Pc).sum(-1) + self.r).reshape(self.Rn, 1, 1)
        e = torch.where(mask, yk - self.dot_c(z_pred).unsqueeze(-1), torch.zeros_like(yk))
        K = torch.where(mask, Pc / S[:, :, 0], torch.zeros_like(Pc))
        z = z_pred + K * e
        P = P_pred - K.unsqueeze(-1) * Pc.unsqueeze(-2)
        P = 0.5 * (P + P.mT)
        self.z, self.P, self.S_prev = z, P, S
        idx = self.idx
        for name, t in zip(self.shapes, (z[:, idx], P[:, idx][:, :, idx], self.alpha, self.Po, self.Qo, self.w,
                                         self.Pw, self.Qw, e, S)):
            self.out[name][:, k] = t
        if k:
            self.clamped += step_clamped  # counted with the step's outputs (a Ctrl-C drops the step it interrupts)

    def _predict(self, mask, y0):
        """KFo and KFw (or the joint filter) from the replicas of the output under their sigma points, then the exact
        filter's prediction with their estimates: ``(ẑ, P̃, steps whose orders left the kernel's range)``."""
        z, P, trans, k_lo, k_hi = self.z, self.P, self.trans, self.k_lo, self.k_hi
        Fz = trans.constant(z.unsqueeze(-1))  # F ẑ but its varying row: every replica's and KFx's own
        base = self.dot_c(Fz[..., 0])  # (R,): the output's part that no order or pole changes
        zs = z[:, None, self.sl]  # (R, 1, J+M)
        c0 = self.c0
        replica = lambda rows: (base.unsqueeze(-1) + c0 * (rows * zs).sum(-1)).unsqueeze(-1)  # noqa: E731
        Ro = self.S_prev if self.Ro_num is None else self.Ro_num
        observed = mask.any(-1)
        if self.joint:
            out_o, w_kfx = self._joint(replica, Ro, y0, mask, observed)
        else:
            out_o, w_kfx = self._separate(replica, Ro, y0, mask, observed)
        alpha = self.alpha
        out_o = out_o | (alpha < k_lo) | (alpha > k_hi)
        step_clamped = out_o.any(-1).to(torch.int64)
        # KFx: the exact filter's prediction under the estimates
        ra, ga = self.row(alpha, w_kfx)
        z_pred = trans.apply(z.unsqueeze(-1), ra[:, 0], Fz)[..., 0]
        Q0, row0 = self.Q0, self.row0
        P_pred = trans.apply(trans.apply(P, ra[:, 0]).mT, ra[:, 0]) + Q0  # F P Fᵀ (P symmetric) + Q
        P_pred[:, row0, row0] += (ga * ga)[:, 0] - Q0[:, row0, row0]
        self.w = self.w_new
        return z_pred, P_pred, step_clamped

    def _joint(self, replica, Ro, y0, mask, observed):
        """One unscented filter over (order, pole): sigma points (α, w)ᵢ, each a replica; KFx at α̂_k and ŵ_k."""
        k_lo, k_hi = self.k_lo, self.k_hi
        Pj_t = self.Pj + self.Qj
        sig = sigma_points(self.theta, Pj_t, self.scale_j)  # (R, 5, 2)
        out_o = (sig[..., 0] < k_lo) | (sig[..., 0] > k_hi)
        rj, _ = self.row(sig[..., 0], sig[..., 1])
        theta, Pj, Kj, ej, _, _ = ut_update(sig, replica(rj), self.theta, Pj_t, Ro, y0, mask, self.wm_j, self.wc_j,
                                            self.start)
        self.theta = theta = torch.cat([theta[:, :1].clamp(self.lo, self.hi), theta[:, 1:]], dim=-1)
        self.Pj, self.Qj = Pj, Qj = Pj, adapt_q(self.Qj, Kj, ej, self.ko.delta, self.qmax_o, observed)
        self.alpha, self.w_new = theta[:, :1], theta[:, 1:]
        self.Po, self.Qo, self.Pw, self.Qw = Pj[:, :1, :1], Qj[:, :1, :1], Pj[:, 1:, 1:], Qj[:, 1:, 1:]
        return out_o, self.w_new  # KFx at α̂_k and ŵ_k

    def _separate(self, replica, Ro, y0, mask, observed):
        """KFo over the sigma orders (with ŵ_{k−1}) and KFw over the sigma poles (with α̂_{k−1}), each from its
        replicas; KFx at α̂_k and ŵ_{k−1}, as the paper's."""
        k_lo, k_hi, alpha, w = self.k_lo, self.k_hi, self.alpha, self.w
        Po_t, Pw_t = self.Po + self.Qo, self.Pw + self.Qw
        sig_o = sigma_points(alpha, Po_t, self.scale_o)  # (R, 3, 1)
        sig_w = sigma_points(w, Pw_t, self.scale_w)
        out_o = (sig_o[..., 0] < k_lo) | (sig_o[..., 0] > k_hi)
        ro, _ = self.row(sig_o[..., 0], w)  # KFo: sigma orders, ŵ_{k−1}
        rw, _ = self.row(alpha.expand(-1, sig_w.shape[-2]), sig_w[..., 0])  # KFw: α̂_{k−1}, sigma poles
        Yo, Yw = replica(ro), replica(rw)  # (R, 3, 1)
        Rw = self.S_prev if self.Rw_num is None else self.Rw_num
        alpha, self.Po, Ko, eo, _, _ = ut_update(sig_o, Yo, alpha, Po_t, Ro, y0, mask, self.wm_o, self.wc_o, self.start)
        self.alpha = alpha.clamp(self.lo, self.hi)
        self.Qo = adapt_q(self.Qo, Ko, eo, self.ko.delta, self.qmax_o, observed)
        self.w_new, self.Pw, Kw, ew, _, _ = ut_update(sig_w, Yw, w, Pw_t, Rw, y0, mask, self.wm_w, self.wc_w,
                                                      self.start)
        self.Qw = adapt_q(self.Qw, Kw, ew, self.kw.delta, self.qmax_w, observed)
        return out_o, w  # KFx at α̂_k and ŵ_{k−1}, as the paper's

    def result(self, completed: int) -> TEAResult:
        """The :class:`TEAResult` of the ``completed`` steps: flagged as the TEA flags them (non-finite or beyond the
        limit), not frozen."""
        out, Rn, N = self.out, self.Rn, self.N
        if completed < N:
            out = {name: t[:, :completed] for name, t in out.items()}
        lim = self.per_series([float(v.config.divergence_limit) for v in self.views]).reshape(Rn, 1, 1)
        steps = torch.arange(completed)
        finite = torch.stack([(out[k].flatten(2).abs() <= lim).all(-1)  # (Rn, completed), also for none
                              for k in ("x", "P", "alpha", "w")]).all(0)
        diverged = ~finite.all(-1)
        first_bad = torch.where(~finite, steps, completed).amin(-1) if completed else torch.zeros(Rn, dtype=torch.long)
        return TEAResult(**out, diverged=diverged, diverged_at=torch.where(diverged, first_bad, -1), steps=steps,
                         memory_clamped=self.clamped if self.mem.kernel is not None else None,
                         interrupted=completed < N)


class _Transition:
    """``F`` ``(B, D, D)`` (B parameter sets) whose one row ``row0`` varies (over columns ``sl``): the other rows as a
    padded table of their non-zero entries (the columns any set has non-zero), so that ``F M`` costs ``O(D² W)`` (W
    their most entries in a row: 2 for a fractional block's shift and modes) instead of a dense ``O(D³)`` product.
    The same sums as the dense product but for the order of terms."""

    def __init__(self, F0: Tensor, row0: int, sl: slice):
        Fc = F0.clone()
        Fc[:, row0] = 0.0
        nz = (Fc != 0).any(0)  # (D, D): entries non-zero in some set
        W = max(int(nz.sum(-1).max()), 1)
        D = F0.shape[-1]
        self.cols = torch.zeros(D, W, dtype=torch.long)
        self.vals = torch.zeros(F0.shape[0], D, W, dtype=F0.dtype)
        for i in range(D):
            c = torch.nonzero(nz[i]).reshape(-1)
            self.cols[i, :c.numel()], self.vals[:, i, :c.numel()] = c, Fc[:, i, c]
        self.row0, self.sl = row0, sl

    def constant(self, M: Tensor) -> Tensor:
        """``F M`` for ``M`` ``(R, D, K)`` with the varying row zero: what every order and pole share."""
        out = self.vals[:, :, 0, None] * M.index_select(1, self.cols[:, 0])
        for j in range(1, self.cols.shape[1]):
            out = out + self.vals[:, :, j, None] * M.index_select(1, self.cols[:, j])
        return out

    def apply(self, M: Tensor, row: Tensor, constant: Tensor | None = None) -> Tensor:
        """``F M`` for ``M`` ``(R, D, K)``, with the varying row ``row`` ``(R, |sl|)``; ``constant``: the product's
        constant rows already computed (:meth:`constant` of ``M``), reused."""
        out = self.constant(M) if constant is None else constant.clone()
        out[:, self.row0, :] = (row.unsqueeze(-2) @ M[:, self.sl, :])[:, 0]
        return out


def _state_index(view: TEAView, ss) -> list:
    """Each view state's index in the state space: a component's block holds its states first (the fractional block
    its current value, then its past)."""
    idx, seen = [], {}
    for label in view.states:
        i = seen.get(label, 0)
        idx.append(ss.blocks[label].start + i)
        seen[label] = i + 1
    return idx

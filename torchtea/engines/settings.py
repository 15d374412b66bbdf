"""The TEA's settings: KFx (:class:`StateFilterConfig`), KFo and KFw (:class:`UnscentedConfig`) and the whole
algorithm (:class:`TEAConfig`) as frozen dataclasses, kept out of the filter module (:mod:`.tea`) so that
presets, TOML files and the noise-model adapter build them without importing the filter."""
from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import Any

from ..core.memory import MemoryConfig, parse_memory

__all__ = ["StateFilterConfig", "UnscentedConfig", "TEAConfig", "NOISE_SCALINGS", "INNOVATION"]


# --------------------------------------------------------------------------- configuration


@dataclass(frozen=True)
class StateFilterConfig:
    """KFx settings, paper (29)–(36).

    Attributes
    ----------
    x0 : initial state estimate ``x₀``.
    P0 : initial covariance ``P₀``.
    Q0 : process-noise covariance ``Q`` of ω (the paper's ``Q₀``; constant).
    R : measurement-noise covariance ``R`` of ν.

    A number means that value times the identity; a list of numbers a diagonal;
    a nested list a full matrix.
    """

    x0: Any = 0.0
    P0: Any = 0.01
    Q0: Any = 1e-4
    R: Any = 1e-3


@dataclass(frozen=True)
class UnscentedConfig:
    """KFo or KFw settings, paper (12)–(28) and (37)–(42).

    Attributes
    ----------
    x0 : initial estimate (``α₀`` for KFo, ``w₀`` for KFw).
    P0 : initial covariance ``P₀ᵒ`` / ``P₀ʷ``.
    Q0 : initial random-walk covariance ``Q₀ᵒ`` / ``Q₀ʷ`` (adapted by (25)).
    R : the filter's measurement covariance ``Rᵒ`` / ``Rʷ``: a number, diagonal or matrix as for KFx, or
        ``"innovation"``: at each step KFx's innovation covariance of the step before, ``S_{k−1} = C P̃ Cᵀ + R``
        with the ``P̃`` that sets KFx's gain (:data:`INNOVATION`). The paper's ``Rᵒ = Rʷ = R`` (its presets) tells
        the filters that a predicted output misses the measurement by the measurement noise alone, while it also
        misses by KFx's own state error; where other states (a random walk, a bias) share the output that error is
        far larger than ``R``, and the filters read it as a wrong order or pole. With ``"innovation"`` the
        unscented filters weigh their innovations by what KFx predicts for them, as a dual filter's parameter
        filter does (experiments/tea_models/README.md measures it).
    ut_alpha : 𝔄, spread of the sigma points.
    ut_beta : 𝔅, prior knowledge of the distribution (2 for Gaussian).
    kappa : κ; ``None`` means ``3 − L``.
    delta : δ, Robbins–Monro forgetting factor of (25); 0 keeps ``Q`` fixed.
    Q_max : upper bound on the adapted ``Q`` (its largest diagonal entry): ``"Q0"`` (default) caps it
        at the initial ``Q₀``, a number caps it there, ``"none"`` adapts exactly as (25). The cap is
        the guard against (25) feeding on itself (open point 4): ``Q`` may shrink as the filter
        settles but never grow past what the user declared plausible.
    """

    x0: Any = 0.0
    P0: Any = 0.01
    Q0: Any = 0.1
    R: Any = 1e-3
    ut_alpha: float = 1.0
    ut_beta: float = 2.0
    kappa: float | None = None
    delta: float = 0.5
    Q_max: float | str = "Q0"

    @property
    def uses_innovation(self) -> bool:
        """Whether ``R`` is ``"innovation"`` (KFx's innovation covariance), not a number."""
        return isinstance(self.R, str) and self.R == INNOVATION

    def __post_init__(self):
        if isinstance(self.R, str) and self.R != INNOVATION:
            raise ValueError(f"R must be a number, a list of numbers or {INNOVATION!r}, got {self.R!r}")
        if isinstance(self.Q_max, str):
            if self.Q_max not in ("Q0", "none"):
                raise ValueError(f"Q_max must be a number, 'Q0' or 'none', got {self.Q_max!r}")
        elif not (float(self.Q_max) > 0):
            raise ValueError(f"Q_max must be positive, got {self.Q_max}")


#: ``UnscentedConfig.R`` that takes KFx's innovation covariance of the step before as KFo's or KFw's R.
INNOVATION = "innovation"

NOISE_SCALINGS = ("scaled", "unscaled")
#: How KFx's prediction sees the order and parameter estimates (TEAConfig.kfx_uncertainty).
KFX_UNCERTAINTIES = ("paper", "propagated", "paper-gain")
#: Which covariance KFo and KFw report for their estimates (TEAConfig.estimate_uncertainty).
ESTIMATE_UNCERTAINTIES = ("paper", "constant-truth")
#: Which filter is KFx (TEAConfig.kfx_filter).
KFX_FILTERS = ("paper", "exact")
#: How the order and the parameter are estimated (TEAConfig.kfo_kfw).
KFO_KFW = ("separate", "joint")


@dataclass(frozen=True)
class TEAConfig:
    """Settings of the whole Triple Estimation Algorithm.

    Attributes
    ----------
    kfx, kfo, kfw : the three filters' settings.
    sigma_sum_start : 0 or 1 — first sigma point in the covariance sums (20)–(21).
        The paper prints ``i = 1``; the standard unscented transform uses ``i = 0``
        (open point 1). Default 0.
    noise_scaling : "scaled" or "unscaled" — whether KFx adds ``h^α Q h^α`` (the
        process noise as it enters the model (10)) or ``Q`` as printed in (31)
        (open point 2). Default "scaled".
    order_bounds : (low, high) — every order estimate is projected onto this
        interval after each update (open point 3). Sigma points are not clipped.
    divergence_limit : a realisation whose estimates or covariances leave
        ``[−limit, limit]`` or become non-finite is flagged and frozen.
    memory : how the GL history sums of all three filters are evaluated
        (:class:`torchtea.core.memory.MemoryConfig`: ``exact``, ``soe`` or ``window``).
    kfx_uncertainty : "paper-gain" (default), "paper" or "propagated". "paper": KFx's prediction treats α̂_k
        and ŵ_{k−1} as exact. "propagated": it adds their uncertainty to P̃ (so to the gain):
        ``J_α P_α J_αᵀ + J_w P_w J_wᵀ``, with the sensitivities ``J`` of the predicted
        state to the order and parameter taken by statistical linearisation over
        KFo's and KFw's sigma points (``J = P_χσ P̃_σ⁻¹``, the replica values the
        step computes anyway), ``P_α`` KFo's covariance after its update and ``P_w``
        KFw's covariance of ŵ_{k−1}. Approximations: J is taken around α̂_{k−1} (where
        the sigma points are) while KFx predicts at α̂_k, and the cross-covariances of
        x̂_{k−1} with α̂ and ŵ, and of α̂_k with the measurement noise at k (α̂_k has
        already used y_k), are neglected.
        "paper-gain": the paper's filter — its gain, so its estimates, bit for bit — and, as ``P`` and
        the innovation covariance ``S``, the covariance of that filter's error with the same term:
        ``P̃ = F P Fᵀ + Q + Σ_{j≥2} c_j P_{k−j} c_jᵀ + J_α P_α J_αᵀ + J_w P_w J_wᵀ`` over the history of these
        ``P``, and ``P = (I − K C) P̃ (I − K C)ᵀ + K R Kᵀ`` (Joseph form) with the paper's ``K``, which is
        computed from the paper's covariance, carried alongside (``Carry.Pg``). The divergence guard also checks
        this larger ``P``: a realisation whose reported ``P`` leaves ``divergence_limit`` is frozen where the
        paper setting would go on (none did in experiments/montecarlo's studies).
        The default is "paper-gain": the paper's estimates, with a ``P`` whose NEES is 0.7–2.5 where the paper's is
        23–931, and 3.9 where the paper's is 1370 (α = 0.6, f = −2; experiments/montecarlo/README.md). The paper
        reproduction pins "paper".
    estimate_uncertainty : "paper" or "constant-truth" — the covariance KFo and KFw report for the order and
        parameter estimates (``P_alpha``, ``P_w``); nothing else changes. "paper": the filters' own covariances, those
        of their random-walk models ``α_k =
        α_{k−1} + noise`` with covariance ``Qᵒ``; for a constant true order they are about twice the variance of
        the error once the filter has settled (error variance ``K R / (H (2 − K H))`` against ``P = K R / H``, scalar
        case), so a ±2σ interval covers the truth ~99.5 % of the time, not 95 %. "constant-truth": the filters
        run as the paper's (their gains, so every estimate, bit for bit, from their own covariances, carried
        alongside as ``Carry.Pog``, ``Carry.Pwg``), and report the covariance of their error when the true
        order and parameter are constant: ``Σ_k = (I − K H) Σ_{k−1} (I − K H)ᵀ + K (P_yy − H P̃ Hᵀ) Kᵀ``,
        ``Σ_0 = P₀``, with ``H = P_σyᵀ P̃⁻¹`` the statistical linearisation of the replica over the sigma points
        (P̃ the covariance they were drawn with) and no ``Q`` (a constant truth does not move). ``P_yy − H P̃ Hᵀ``
        is the filters' ``R`` plus what the linearisation leaves over, so it is honest only where that ``R``
        matches the noise in their innovations, and only for a constant truth: for a time-varying order it is too
        small. The projection of α̂ onto ``order_bounds`` is not in it. It treats KFo's innovation noise as white,
        which it is not (KFx's state errors are correlated in time); experiments/montecarlo/README.md measures
        the result. KFx's term of ``kfx_uncertainty`` keeps the filters' own covariances: with these smaller
        ones it under-predicts KFx's error (NEES 1.2–1.7 where it is 0.7–1.0, and 3.9–7.8 at α = 0.6, in
        experiments/montecarlo's studies), because an order error persists over many steps and its effects on
        the state history add coherently, which the first-order term, independent from step to step, leaves out.
    kfx_filter : "paper" (default) or "exact" — which filter KFx is. "paper": the paper's (29)–(35), predicting from
        its filtered past and never revising it (this engine). "exact": the Kalman filter of the noise model's own
        state space, whose state holds the (``soe``-compressed) past and is revised by every sample — run by
        :func:`torchtea.noise.tea_exact.run_tea_exact` on a model's TEA view (``identify`` and ``montecarlo`` with a
        model do; :func:`~torchtea.engines.tea.run_tea` refuses it, having no model). With another state sharing the
        output (a random walk …) the paper's KFx leaves its innovations correlated with the past, and KFo's order
        settles off the truth (−0.012 at walk σ 0.05); the exact filter's does not (experiments/tea_models).
    kfo_kfw : "separate" (default) or "joint" — how the order and the parameter are estimated. "separate": the
        paper's KFo and KFw, each a scalar unscented filter that takes the other's current estimate as exact.
        "joint" (not in the paper; ``kfx_filter = "exact"`` only): one unscented filter over (order, pole) with their
        cross-covariance, five sigma points; it takes KFo's sigma-point settings, R, adaptation and cap (the largest
        diagonal entry of its 2×2 Q under the cap, as the TEA caps a vector filter; ``"Q0"``: the larger of the two
        Q0), KFo's start, P0 and Q0 for the order and KFw's for the pole, and KFx runs at both current estimates
        (ŵ_k, not ŵ_{k−1}). On long runs the filters can walk along the order–pole ridge of the likelihood (poles more
        than 0.5 from the truth, the log-likelihood 60–3160 below the truth's, where the likelihood's own maximum is
        at the truth): with no process noise on the order and pole the joint filter's median stays closer to that
        maximum than the two separate ones' (−3 against −19, pole sd 0.18 against 0.52 over 32 runs of 18 000
        steps), but 2 of 32 poles still drift (experiments/tea_models/kfw_drift.py).
    """

    kfx: StateFilterConfig = field(default_factory=StateFilterConfig)
    kfo: UnscentedConfig = field(default_factory=lambda: UnscentedConfig(x0=1.0))
    kfw: UnscentedConfig = field(default_factory=UnscentedConfig)
    sigma_sum_start: int = 0
    noise_scaling: str = "scaled"
    order_bounds: tuple = (0.0, 2.5)
    divergence_limit: float = 1e8
    memory: MemoryConfig = field(default_factory=MemoryConfig)
    kfx_uncertainty: str = "paper-gain"
    estimate_uncertainty: str = "paper"
    kfx_filter: str = "paper"
    kfo_kfw: str = "separate"

    def __post_init__(self):
        if self.kfx_filter not in KFX_FILTERS:
            raise ValueError(f"kfx_filter must be one of {KFX_FILTERS}, got {self.kfx_filter!r}")
        if self.kfo_kfw not in KFO_KFW:
            raise ValueError(f"kfo_kfw must be one of {KFO_KFW}, got {self.kfo_kfw!r}")
        if self.kfo_kfw == "joint" and self.kfx_filter != "exact":
            raise ValueError("kfo_kfw 'joint' runs with kfx_filter 'exact' only (torchtea.noise.tea_exact)")
        if self.kfx_uncertainty not in KFX_UNCERTAINTIES:
            raise ValueError(f"kfx_uncertainty must be one of {KFX_UNCERTAINTIES}, got {self.kfx_uncertainty!r}")
        if self.estimate_uncertainty not in ESTIMATE_UNCERTAINTIES:
            raise ValueError(f"estimate_uncertainty must be one of {ESTIMATE_UNCERTAINTIES}, "
                             f"got {self.estimate_uncertainty!r}")
        if self.sigma_sum_start not in (0, 1):
            raise ValueError("sigma_sum_start must be 0 or 1")
        if self.noise_scaling not in NOISE_SCALINGS:
            raise ValueError(f"noise_scaling must be one of {NOISE_SCALINGS}")
        lo, hi = self.order_bounds
        if not lo < hi:
            raise ValueError("order_bounds must be (low, high) with low < high")
        for f in (self.kfo, self.kfw):
            if not 0.0 <= f.delta <= 1.0:
                raise ValueError("delta must lie in [0, 1]")

    def to_dict(self) -> dict:
        """Plain nested dict (TOML-friendly; ``None`` entries dropped)."""

        def conv(obj):
            out = {}
            for f in fields(obj):
                v = getattr(obj, f.name)
                if v is None:
                    continue
                out[f.name] = conv(v) if hasattr(v, "__dataclass_fields__") else (list(v) if isinstance(v, tuple) else v)
            return out

        return conv(self)

    @property
    def innovation_r(self) -> bool:
        """Whether KFo or KFw takes KFx's innovation covariance as its R (``R = "innovation"``)."""
        return self.kfo.uses_innovation or self.kfw.uses_innovation

    @classmethod
    def from_dict(cls, data: dict, base: TEAConfig | None = None) -> TEAConfig:
        """Build from a nested dict (e.g. parsed TOML), overriding ``base`` (default settings)."""
        base = base or cls()
        known = {f.name for f in fields(cls)}
        unknown = set(data) - known
        if unknown:
            raise ValueError(f"unknown TEA settings: {sorted(unknown)}")
        kw = {}
        for name, value in data.items():
            current = getattr(base, name)
            if name == "memory":
                kw[name] = parse_memory(value if isinstance(value, (str, MemoryConfig)) else {**current.to_dict(), **value})
                continue
            if hasattr(current, "__dataclass_fields__"):
                if not isinstance(value, dict):
                    raise ValueError(f"[{name}] must be a table")
                sub = {f.name for f in fields(current)}
                bad = set(value) - sub
                if bad:
                    raise ValueError(f"unknown settings in [{name}]: {sorted(bad)}")
                kw[name] = replace(current, **value)
            else:
                kw[name] = tuple(value) if isinstance(value, list) else value
        return replace(base, **kw)

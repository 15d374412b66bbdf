r"""A fitted model in the terms navigation filters take: noise density N and bias random walk K, the IEEE Std 952
coefficients, and the cover (ALGORITHMS.md §7: Allan variance from a spectrum).

Conventions (continuous time, as Kalibr's IMU noise model states them):

* **N**, the white noise density (unit/√Hz; for a gyroscope rad/s/√Hz = rad/√s, IEEE 952's angle random walk):
  a white component of variance r per sample of Δt has :math:`N = \sqrt{r\,\Delta t}`, and a filter running at
  Δt uses :math:`\sigma_d = N/\sqrt{\Delta t}` per sample. Quantisation (Δ²/12, white) adds to r.
* **K**, the bias random walk (unit·√Hz⁻¹/s; rad/s²/√Hz, IEEE 952's rate random walk): the model's
  ``random-walk.sigma``; the filter's per-step bias increment has :math:`\sigma_{bd} = K\sqrt{\Delta t}`.
* **B**, bias instability: the model's Allan deviation at its minimum divided by 0.664 (the flicker floor's
  ADEV is :math:`B\sqrt{2\ln 2/\pi} \approx 0.664 B`, IEEE Std 952-1997 annex C); where the minimum lies at the
  end of the τ range the ADEV still falls, and B is an upper bound (said so).
* **R**, rate ramp: a ``ramp`` component's slope (AVAR :math:`R^2\tau^2/2`). **Q**, angle quantisation (AVAR
  :math:`3Q^2/\tau^2`): no component has that τ⁻² law (a rate's quantisation is white and counts in N).

**The cover.** The formats know N and K only. The fitted model's AVAR (its stochastic part from its spectrum, its
means' on the recording's samples) is compared with the AVAR of the format's model, white noise plus a random walk
sampled at Δt — linear in :math:`(N^2, K^2)`: :math:`N^2/\tau + K^2 (2m^2+1)\Delta t/(6m)`, m = τ/Δt — over the
time scales of the horizon. The covered values are the smallest pair, not below the bare ones, whose AVAR is
nowhere below the model's there, "smallest" meaning the least :math:`N^2/N_s^2 + K^2/K_s^2`, where N_s alone
covers the shortest τ and K_s alone the longest (a linear programme). A white + random-walk model's cover is its
own values. Each raised value names the τ that forced it and the component that contributes most there.

**Intervals.** N and K carry the fit's 95 % intervals (its method named). Derived numbers (B, the covered values,
the factors) get theirs by the delta method on the log scale: central differences of the whole computation on the
optimisers' unconstrained scale, with the inverse of the fit's observed information there. (Draws from that
normal law were tried first: along the order–pole ridge of a fractional fit a draw leaves the ridge and its Allan
deviation explodes — upper bounds of 10¹⁷ on real axes — while the ADEV, what the cover reads, is well
determined; the local, linear propagation follows the ridge.) Where the observed information is not positive
definite (an order at its bound) there is no interval, and the notes say so.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch

from ..checking import allan
from ..noise.navigation import nav_note, nav_term_of

__all__ = ["AxisTerms", "axis_terms", "parse_horizon", "DEFAULT_HORIZON", "UNITS", "BIAS_INSTABILITY_FACTOR"]

#: The time scales a navigation filter works on, by default (s): from 200 Hz updates to 100 s without aiding.
DEFAULT_HORIZON = (0.005, 100.0)

#: ADEV of flicker (bias instability) noise at its floor, over B: √(2 ln 2 / π) (IEEE Std 952-1997, C.1.4).
BIAS_INSTABILITY_FACTOR = math.sqrt(2.0 * math.log(2.0) / math.pi)

#: The terms Kalibr, VINS and ORB-SLAM3 hold (a constant level is their bias state's start).
IN_FORMATS = ("N", "K", "bias")

#: |logit| beyond which a bounded parameter is at its bound for the intervals (held there).
AT_BOUND = 8.0

#: Units of N, K, B, R (and the rate) per sensor (SI; the formats' documented units).
UNITS = {"accelerometer": {"rate": "m/s^2", "N": "m/s^2/sqrt(Hz)", "K": "m/s^3/sqrt(Hz)", "B": "m/s^2",
                           "R": "m/s^3", "Q": "m/s"},
         "gyroscope": {"rate": "rad/s", "N": "rad/s/sqrt(Hz)", "K": "rad/s^2/sqrt(Hz)", "B": "rad/s",
                       "R": "rad/s^2", "Q": "rad"}}

#: τ points of the cover per decade of the horizon.
PER_DECADE = 24


def parse_horizon(text: str | None, h: float, n: int) -> tuple[tuple[float, float], str]:
    """``"LO:HI"`` (s) → the horizon and a note. It must lie within what the recording shows: τ from one sample
    (Δt) to half the record (two clusters). ``None``: :data:`DEFAULT_HORIZON` clipped to that span (the note says
    where). Raises ``ValueError`` naming the input otherwise."""
    lo_ok, hi_ok = h, (n // 2) * h
    if text is None:
        lo, hi = max(DEFAULT_HORIZON[0], lo_ok), min(DEFAULT_HORIZON[1], hi_ok)
        note = ""
        if (lo, hi) != DEFAULT_HORIZON:
            note = (f"horizon {lo:g}–{hi:g} s: the default {DEFAULT_HORIZON[0]:g}–{DEFAULT_HORIZON[1]:g} s clipped "
                    f"to what the recording shows (one sample, {h:g} s, to half its {n * h:g} s)")
        return (lo, hi), note
    try:
        a, b = (float(x) for x in text.split(":"))
    except ValueError:
        raise ValueError(f"--horizon {text!r}: expected LO:HI in seconds, e.g. 0.01:100") from None
    if not (0 < a < b) or not all(map(math.isfinite, (a, b))):
        raise ValueError(f"--horizon {text!r}: needs 0 < LO < HI")
    if a < lo_ok * (1 - 1e-9) or b > hi_ok * (1 + 1e-9):
        raise ValueError(f"--horizon {text!r} lies outside what the recording shows: τ from its sample time "
                         f"{lo_ok:g} s to half its length, {hi_ok:g} s")
    return (a, b), ""


@dataclass
class Number:
    """One exported number: value, 95 % interval (None when there is none) and how it was made."""

    value: float | None
    ci95: tuple | None
    unit: str
    how: str

    def as_dict(self) -> dict:
        return {"value": self.value, "ci95": None if self.ci95 is None else list(self.ci95), "unit": self.unit,
                "how": self.how}


@dataclass
class AxisTerms:
    """One axis's exported numbers. ``bare``: N and K as the model has them; ``covered``: the cover's; ``factor``:
    covered/bare per term (None where the bare value is 0); ``forced_by``: per raised term, the τ and component
    that forced it; ``ieee``: Q N B K R; ``components``: each component with its term or what the formats miss;
    ``curves``: τ and the ADEVs (data, model, components, bare, covered) for the report."""

    label: str
    sensor: str
    h: float
    model: str
    horizon: tuple
    bare: dict
    covered: dict
    factor: dict
    forced_by: dict
    ieee: dict
    components: list
    curves: dict
    notes: list = field(default_factory=list)
    #: the NEES study (:func:`~.nees.nees_study`), when run
    nees: dict | None = None
    #: the axis against a datasheet (:func:`~.datasheet.compare`), when one was given for its sensor
    datasheet: dict | None = None

    def as_dict(self) -> dict:
        num = lambda d: {k: (v.as_dict() if isinstance(v, Number) else v) for k, v in d.items()}  # noqa: E731
        return {"sensor": self.sensor, "model": self.model, "sample_time_s": self.h, "horizon_s": list(self.horizon),
                "bare": num(self.bare), "covered": num(self.covered), "factor": num(self.factor),
                "forced_by": self.forced_by, "ieee952": num(self.ieee), "components": self.components,
                "notes": self.notes, **({"datasheet": self.datasheet} if self.datasheet else {})}


# --------------------------------------------------------------------------- the format's model

def format_avar(m: np.ndarray, h: float) -> np.ndarray:
    """AVAR of the format's model per unit of (r, K²) at cluster sizes ``m``: columns white (r = 1: 1/m) and
    random walk (K = 1: (2m²+1)h/(6m)), the closed forms of the discrete model (``(len(m), 2)``)."""
    m = np.asarray(m, dtype=np.float64)
    return np.stack([1.0 / m, (2.0 * m * m + 1.0) * h / (6.0 * m)], axis=1)


def cover(avar: np.ndarray, basis: np.ndarray, r0: float, k0: float) -> tuple[float, float, np.ndarray]:
    """The least (r, K²) ≥ (r0, K0²), weighted as the module says, with ``basis @ (r, K²) ≥ avar`` at every τ.
    Returns r, K² and the τ indices where the cover touches the model (the binding ones)."""
    from scipy.optimize import linprog

    a_s = avar[0] / basis[0, 0]
    b_s = avar[-1] / basis[-1, 1]
    # in units of (a_s, b_s) and rows divided by the model's AVAR: well conditioned whatever the scales
    A = np.stack([basis[:, 0] * a_s, basis[:, 1] * b_s], 1) / avar[:, None]
    res = linprog(c=[1.0, 1.0], A_ub=-A, b_ub=-np.ones(len(avar)),
                  bounds=[(r0 / a_s, None), (k0 * k0 / b_s, None)], method="highs")
    if res.status != 0:
        raise RuntimeError(f"the cover's linear programme failed: {res.message}")
    x, y = res.x
    ratio = A @ res.x
    binding = np.nonzero(ratio <= 1.0 + 1e-7)[0]
    return float(x * a_s), float(y * b_s), binding


# --------------------------------------------------------------------------- one axis

def _taus(horizon, h: float) -> np.ndarray:
    lo, hi = horizon
    k = max(8, int(math.ceil(PER_DECADE * math.log10(hi / lo))))
    m = np.unique(np.rint(np.logspace(math.log10(lo / h), math.log10(hi / h), k)).astype(int))
    return m[m >= 1]


def _delta_intervals(fit, h: float, fn, keys: tuple) -> tuple[dict, str, list]:
    """95 % intervals of the derived numbers ``fn(values) -> {key: value}`` by the delta method on the log scale:
    central differences on the optimisers' unconstrained scale, the covariance the inverse of the fit's Hessian
    there (its free parameters). A number that is 0 gets the linear-scale interval clipped at 0. Returns
    ``({key: (lo, hi) or None}, why-none, the parameters held at a bound)``."""
    none = {k: None for k in keys}
    if fit.u is None or fit.hessian is None:
        return none, "no Hessian (the fit ran without intervals)", []
    H = fit.hessian.detach().to(torch.float64)
    u0 = fit.u.detach().to(torch.float64).reshape(-1)
    names = fit.model.names
    free = torch.nonzero(H.abs().sum(1) > 0).flatten().tolist()
    # a parameter at a bound of its range (an order at 1, a logit beyond ±8: within 3e-4 of the end) carries no
    # information there; it is held at its estimate and the others' law taken given it (said so)
    held = [names[i] for i in free if fit.model.param_spec(names[i]).scale == "logit"
            and abs(float(u0[i])) > AT_BOUND]
    free = [i for i in free if names[i] not in held]
    if not free:
        return none, "the fit's Hessian is zero: no parameter's information", held
    Hf = H[free][:, free]
    w, V = torch.linalg.eigh(0.5 * (Hf + Hf.T))
    if bool((w <= 0).any()):
        return none, "the observed information is not positive definite at the estimate", held
    cov = (V / w) @ V.T

    def at(u):
        v = fit.model.from_unconstrained(u.reshape(1, -1), h)
        return fn({k: float(x[0]) for k, x in v.items()})

    g0 = at(u0)
    pairs = []  # every (step, value up, value down) first: log or linear scale is then decided once per number
    for i in free:
        d = 1e-4 * max(1.0, abs(float(u0[i])))
        up, dn = u0.clone(), u0.clone()
        up[i] += d
        dn[i] -= d
        pairs.append((d, at(up), at(dn)))
    grads, lin = {}, {}
    for k in keys:
        if g0[k] is None or any(gu[k] is None or gd[k] is None for _, gu, gd in pairs):
            continue
        lin[k] = not (g0[k] > 0 and all(gu[k] > 0 and gd[k] > 0 for _, gu, gd in pairs))
        grads[k] = np.array([(gu[k] - gd[k]) / (2 * d) if lin[k] else
                             (math.log(gu[k]) - math.log(gd[k])) / (2 * d) for d, gu, gd in pairs])
    C = cov.numpy()
    out = {}
    for k in keys:
        if k not in grads:
            out[k] = None
            continue
        sd = math.sqrt(max(float(grads[k] @ C @ grads[k]), 0.0))
        if lin[k]:
            out[k] = (max(0.0, g0[k] - 1.96 * sd), g0[k] + 1.96 * sd)
        elif 1.96 * sd > 700.0:  # (a factor beyond a float's range: the record does not bound it — a collapsed walk)
            out[k] = (0.0, math.inf)
        else:
            out[k] = (g0[k] * math.exp(-1.96 * sd), g0[k] * math.exp(1.96 * sd))
    return out, "", held


def axis_terms(fit, y: np.ndarray, h: float, sensor: str, label: str, horizon,
               inputs: dict | None = None) -> AxisTerms:
    """The exported numbers of one axis from its ``fit`` (:class:`~torchtea.fitting.mle.Fit`) to ``y`` (sample
    time ``h``; ``inputs`` the temperature when the model reads it) — see the module docstring."""
    if sensor not in UNITS:
        raise ValueError(f"{label}: a {sensor} channel has no navigation-filter units (accelerometer or gyroscope)")
    model, values = fit.model, dict(fit.values)
    units = UNITS[sensor]
    notes = []
    n = len(y)
    m = _taus(horizon, h)
    tau = m * h
    temperature = None if inputs is None else inputs.get("temperature")
    parts, det_avar, stoch = _model_avars(model, values, h, m, n, inputs, temperature)
    total = stoch + det_avar

    # bare values: N from the white measurement variance (white + quantisation), K from a random walk
    r0, k_label, k0, bare = _bare_numbers(fit, model, values, h, units)

    basis = format_avar(m, h)
    rc, kc2, binding = cover(total, basis, r0, k0)
    forced = _forced(model, parts, tau, binding, rc, kc2, r0, k0)

    mb, avar_b, b_how = _bias_instability(model, values, h, n, temperature)
    point, ci, why, held = _derived_intervals(fit, values, h, m, mb, temperature, det_avar, basis, k_label,
                                               stoch, avar_b)
    if why:
        notes.append(f"no intervals for B and the covered values: {why}")
    if held:
        notes.append(f"{', '.join(held)} at the bound of its range: the intervals are those given it held there")
    how = "95 % interval by the delta method (log scale) from the fit's observed information" + (
        f", {', '.join(held)} held at its bound" if held else "")
    for t, key in (("N", "N0"), ("K", "K0")):  # the fit's own interval, else the delta method's
        if bare[t].ci95 is None and ci.get(key) is not None and bare[t].value > 0:
            bare[t] = Number(bare[t].value, ci[key], bare[t].unit, bare[t].how.split("; 95 %")[0] + "; " + how)
    covered = {"N": Number(point["Nc"], ci["Nc"], units["N"], "the cover (module docstring); " + how),
               "K": Number(point["Kc"], ci["Kc"], units["K"], "the cover (module docstring); " + how)}
    factor = {t: None if point["f" + t] is None else  # (≥ 1 by construction: its interval is clipped there)
              Number(point["f" + t], None if ci["f" + t] is None else (max(1.0, ci["f" + t][0]), ci["f" + t][1]), "",
                     "covered / bare; " + how) for t in ("N", "K")}
    ieee = _ieee(fit, model, values, units, bare, Number(point["B"], ci["B"], units["B"], b_how + "; " + how))

    comps = _component_words(model, values, h)
    if any(c.kind == "filter" for _, c in model.components):
        notes.append(next(cc["words"] for cc, (_, c) in zip(comps, model.components) if c.kind == "filter"))

    curves = _curves(y, h, m, tau, total, parts, basis, (r0, k0 * k0), (rc, kc2))
    return AxisTerms(label, sensor, h, model.spec, tuple(horizon), bare, covered, factor, forced, ieee, comps,
                     curves, notes)


def _model_avars(model, values: dict, h: float, m: np.ndarray, n: int, inputs, temperature):
    """Each component's AVAR at cluster sizes ``m`` (a mean's on the recording's samples), the deterministic part's
    and the stochastic part's."""
    t = torch.arange(n, dtype=torch.float64) * h
    inp = None if inputs is None else {k: torch.as_tensor(v, dtype=torch.float64) for k, v in inputs.items()}
    from ..checking.diagnostics import stochastic_avar

    parts = allan.model_avar(model, values, h, m, by_component=True)
    parts = {k: v[0] for k, v in parts.items()}
    mean_labels = [lb for lb, c in model.components if c.kind == "mean"]
    byc = model._by_component(model.as_dict(values))
    for lb in mean_labels:  # each mean's AVAR on the recording's samples (for the attribution)
        d = dict(model.components)[lb].mean(byc[lb], t, inp or {})[0].numpy()
        parts[lb] = allan.deterministic_avar(d - d.mean(), m)
    det = model.mean(values, t, inp).numpy()[0] if mean_labels else np.zeros(n)
    det_avar = allan.deterministic_avar(det - det.mean(), m)
    stoch = stochastic_avar(model, values, h, m, temperature)
    return parts, det_avar, stoch


def _bare_numbers(fit, model, values: dict, h: float, units: dict):
    """The white variance r0, the random walk's label and K0, and the bare N and K (:class:`Number`)."""
    r0 = float(model.measurement_variance(values)[0])
    k_label = next((lb for lb, c in model.components if nav_term_of(c).term == "K"), None)
    k0 = float(values[f"{k_label}.sigma"]) if k_label else 0.0
    w_labels = [lb for lb, c in model.components if nav_term_of(c).term == "N"]
    N0 = math.sqrt(r0 * h)
    bare = {"N": Number(N0, _white_ci(fit, w_labels, h), units["N"],
                        _how(fit, [f"{lb}.{p.name}" for lb in w_labels for p in dict(model.components)[lb].params],
                             "√(r Δt), r the white variance per sample") if w_labels else
                        "the model has no white noise: 0"),
            "K": Number(k0, tuple(fit.ci95[f"{k_label}.sigma"]) if k_label and fit.ci95.get(f"{k_label}.sigma")
                        else None, units["K"],
                        _how(fit, [f"{k_label}.sigma"], "random-walk.sigma") if k_label else
                        "the model has no random walk: 0")}
    return r0, k_label, k0, bare


def _forced(model, parts: dict, tau: np.ndarray, binding: np.ndarray, rc: float, kc2: float, r0: float,
            k0: float) -> dict:
    """Per term the cover raised: the τ that forced it and the component (outside the formats) largest there."""
    forced = {}
    other = {lb: parts[lb] for lb, c in model.components if nav_term_of(c).term not in IN_FORMATS and lb in parts}
    if rc > r0 * (1 + 1e-6) and len(binding):
        i = int(binding.min())
        forced["N"] = {"tau_s": float(tau[i]), "component": _largest(other, i)}
    if kc2 > k0 * k0 * (1 + 1e-6) and len(binding):
        i = int(binding.max())
        forced["K"] = {"tau_s": float(tau[i]), "component": _largest(other, i)}
    return forced


def _bias_instability(model, values: dict, h: float, n: int, temperature):
    """B's cluster sizes (every τ the recording shows), the stochastic AVAR there and how B is made."""
    from ..checking.diagnostics import stochastic_avar

    # B: the stochastic ADEV's minimum over all τ the recording shows
    mb = np.unique(np.rint(np.logspace(0, math.log10(max(1, n // 2)), 64)).astype(int))
    avar_b = stochastic_avar(model, values, h, mb, temperature)
    adev_b = np.sqrt(avar_b)
    ib = int(np.argmin(adev_b))
    b_how = (f"ADEV minimum {adev_b[ib]:.4g} at τ {mb[ib] * h:.4g} s / 0.664 (the model's stochastic part, τ from "
             f"{h:g} s to {mb[-1] * h:.4g} s)")
    if ib == len(mb) - 1:
        b_how += "; the ADEV still falls at the longest τ the recording shows: B is an upper bound"
    return mb, avar_b, b_how


def _derived_intervals(fit, values: dict, h: float, m, mb, temperature, det_avar, basis, k_label, stoch, avar_b):
    """The derived numbers at the estimate (the point's AVARs ``stoch``, ``avar_b``) and their delta-method
    intervals: ``(point, intervals, why-none, the parameters held at a bound)``."""
    from ..checking.diagnostics import stochastic_avar

    model = fit.model

    def derived(v: dict, avar_m=None, avar_mb=None) -> dict:
        """B, the covered values and their factors at parameter values ``v`` (the deterministic part held);
        ``avar_m``, ``avar_mb``: the stochastic AVAR at ``m`` and ``mb`` when already computed for ``v``."""
        avar_m = stochastic_avar(model, v, h, m, temperature) if avar_m is None else avar_m
        avar_mb = stochastic_avar(model, v, h, mb, temperature) if avar_mb is None else avar_mb
        r, k = float(model.measurement_variance(v)[0]), float(v[f"{k_label}.sigma"]) if k_label else 0.0
        a, b2, _ = cover(avar_m + det_avar, basis, r, k)
        nc, kc = math.sqrt(a * h), math.sqrt(b2)
        return {"N0": math.sqrt(r * h), "K0": k, "B": float(np.sqrt(avar_mb).min() / BIAS_INSTABILITY_FACTOR),
                "Nc": nc, "Kc": kc, "fN": nc / math.sqrt(r * h) if r > 0 else None, "fK": kc / k if k > 0 else None}

    point = derived(values, stoch, avar_b)  # (the point's AVARs, computed above)
    ci, why, held = _delta_intervals(fit, h, derived, tuple(point))
    return point, ci, why, held


def _ieee(fit, model, values: dict, units: dict, bare: dict, B: Number) -> dict:
    """IEEE Std 952's Q N B K R (Q not in any model; R a ramp's slope)."""
    ramp = next((lb for lb, c in model.components if nav_term_of(c).term == "R"), None)
    return {"Q": Number(None, None, units["Q"], "not in the model: no component has the τ⁻¹ ADEV slope of angle "
                                                "quantisation (a rate's quantisation is white and counts in N)"),
            "N": bare["N"], "B": B,
            "K": bare["K"],
            "R": Number(abs(float(values[f"{ramp}.slope"])) if ramp else 0.0,
                        None if not ramp or not fit.ci95.get(f"{ramp}.slope") else
                        _abs_ci(fit.ci95[f"{ramp}.slope"]), units["R"],
                        _how(fit, [f"{ramp}.slope"], "|ramp.slope|") if ramp else "the model has no ramp: 0")}


def _component_words(model, values: dict, h: float) -> list:
    """Each component with its term, or what the formats miss of it."""
    comps = []
    for lb, c in model.components:
        v = {p.name: float(values[f"{lb}.{p.name}"]) for p in c.params if f"{lb}.{p.name}" in values}
        term = nav_term_of(c).term
        if term in ("N", "K"):
            words = f"{lb}: the format's {'white noise density N' if term == 'N' else 'bias random walk K'}"
        elif term == "bias":
            words = f"{lb}: a constant level, which the filter's bias state holds"
        elif term == "R":
            words = (f"{lb}: a rate ramp, IEEE 952's R (slope {v['slope']:.4g}); Kalibr, VINS and ORB-SLAM3 have no "
                     "term for it: covered by raising K")
        else:
            words = nav_note(c, lb, v, h)
        comps.append({"label": lb, "effect": c.name, "term": term, "words": words})
    return comps


def _curves(y: np.ndarray, h: float, m: np.ndarray, tau: np.ndarray, total: np.ndarray, parts: dict,
            basis: np.ndarray, bare: tuple, covered: tuple) -> dict:
    """τ and the ADEVs for the report: the model's, its components', the format's bare and covered ((r, K²) each)
    and the data's."""
    n = len(y)
    fmt = basis @ np.array([bare[0], bare[1]])
    fmt_c = basis @ np.array([covered[0], covered[1]])
    curves = {"tau_s": tau.tolist(), "adev_model": np.sqrt(total).tolist(),
              "adev_components": {k: np.sqrt(np.maximum(v, 0)).tolist() for k, v in parts.items()},
              "adev_bare": np.sqrt(fmt).tolist(), "adev_covered": np.sqrt(fmt_c).tolist()}
    if np.isfinite(y).all():  # (the data's ADEV where a quarter of the record holds at least its cluster)
        ok = m <= n // 4
        ad = np.full(len(m), np.nan)
        if ok.any():
            ad[ok] = allan.data_adev(y, h, m[ok])
        curves["adev_data"] = ad.tolist()
    return curves


def _largest(parts: dict, i: int) -> str | None:
    if not parts:
        return None
    return max(parts, key=lambda k: float(parts[k][i]))


def _how(fit, names: list, words: str) -> str:
    methods = sorted({str(fit.ci95_method.get(n)) for n in names if fit.ci95_method.get(n)})
    return words + (f"; 95 % interval: {', '.join(methods)}" if methods else "")


def _abs_ci(c):
    lo, hi = c
    if lo <= 0 <= hi:
        return (0.0, max(abs(lo), abs(hi)))
    return tuple(sorted((abs(lo), abs(hi))))


def _white_ci(fit, labels: list, h: float):
    """N's interval from the white component's (a monotone map); with quantisation beside it, none."""
    if len(labels) != 1:
        return None
    lb = labels[0]
    comp = dict(fit.model.components)[lb]
    name = f"{lb}.{comp.params[0].name}"
    c = fit.ci95.get(name)
    if not c:
        return None
    r = [comp.measurement_variance({comp.params[0].name: torch.tensor([float(x)], dtype=torch.float64)})
         for x in c]
    return tuple(math.sqrt(max(float(x[0]), 0.0) * h) for x in r)

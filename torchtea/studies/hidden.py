"""Recordings with a known hidden effect: the data on which :func:`~torchtea.checking.check` is tested.

Base noise is MEMS-like ``fractional+white`` with :func:`torchtea.noise.default_values` (order 0.3, pole at 40 %
of its stability limit, drive q = r/h^{2α}, white r = 10⁻³ (m/s²)²) and a temperature channel that warms up by
3 °C (time constant 60 s) plus a 0.2 °C wander (:func:`torchtea.noise.temperature_profile`). One effect is added
at the strength in :data:`HIDDEN_STRENGTH`: strong enough to show in the view made for it (spectrum, Allan
deviation, temperature) on 30 000 samples at 100 Hz, too weak to see in the raw time plot
(``experiments/check/README.md`` shows both).
"""
from __future__ import annotations

import math

import numpy as np
import torch

from ..noise import default_values, parse_model, simulate_model, temperature_profile
from ..noise.components import COMPONENTS
from ..noise.grammar import token_for
from ..noise.model import PAPER_MODEL

__all__ = ["HIDDEN_STRENGTH", "BASE_MODEL", "hidden_model", "hidden_case", "DRAWS", "random_case"]

BASE_MODEL = PAPER_MODEL
#: Each hidden effect's parameters (the others are :func:`~torchtea.noise.default_values`'), ``"none"``: clean.
HIDDEN_STRENGTH = {
    "none": {},
    "random-walk": {"random-walk.sigma": 8e-4},
    "sinusoid": {"sinusoid.frequency_hz": 3.37, "sinusoid.amplitude": 4e-3},
    "temperature-bias": {"temperature-bias.bias_per_degC": 0.003},
    "temperature-order": {"temperature-order.order_per_degC": 0.025},
    "low-pass": {"low-pass.cutoff_hz": 20.0},
}


def hidden_model(effect: str) -> str:
    """The spec that generates data with ``effect`` (a low-pass filters the whole signal, white noise included,
    as a sensor's digital filter does)."""
    if effect not in HIDDEN_STRENGTH:
        raise ValueError(f"unknown hidden effect {effect!r}; choose from: {', '.join(HIDDEN_STRENGTH)}")
    if effect == "none":
        return BASE_MODEL
    return f"{BASE_MODEL}+{effect}"


def hidden_case(effect: str, seed: int, n: int = 30_000, h: float = 0.01, strength: dict | None = None):
    """``(y, temperature, truth)`` — one seeded recording with ``effect`` hidden in it; ``truth``: every
    parameter's value. The seed stream is the effect's own (seed 0 of two effects are different draws)."""
    model = parse_model(hidden_model(effect))
    gen = torch.Generator().manual_seed(10_000 * (list(HIDDEN_STRENGTH).index(effect) + 1) + seed)
    T = temperature_profile(n, h, generator=gen)
    values = default_values(model, h, T)
    values.update(HIDDEN_STRENGTH[effect] if strength is None else strength)
    y = simulate_model(model, values, n_steps=n, h=h, inputs={"temperature": T}, generator=gen)[0, 0].numpy()
    return y, np.asarray(T.numpy()), values


def _log_uniform(rng, lo, hi):
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def _sign(rng):
    return float(rng.choice((-1.0, 1.0)))


#: How a randomised study draws each effect's parameters: a function of (random generator, white-noise standard
#: deviation σ_w (units), sample time h (s), record length (s), the temperature's warm-up (°C)) → values. The ranges
#: centre on :data:`HIDDEN_STRENGTH`'s settings relative to σ_w and reach a factor of about 2 either way: from an
#: effect the check should just find to one it finds easily. A set's seed stream is keyed by the positions of its
#: effects here: a new effect goes at the end, so that the studies' saved cases can be drawn again.
DRAWS = {
    "random-walk": lambda g, s, h, span, dT: {"random-walk.sigma": s * _log_uniform(g, 0.015, 0.05)},
    "sinusoid": lambda g, s, h, span, dT: {"sinusoid.frequency_hz": g.uniform(0.02, 0.45) / h,
                                           "sinusoid.amplitude": s * _log_uniform(g, 0.08, 0.3),
                                           "sinusoid.phase": g.uniform(-math.pi, math.pi)},
    "temperature-bias": lambda g, s, h, span, dT: {
        "temperature-bias.bias_per_degC": _sign(g) * s * _log_uniform(g, 0.2, 0.6) / dT},
    "temperature-order": lambda g, s, h, span, dT: {
        "temperature-order.order_per_degC": _sign(g) * _log_uniform(g, 0.04, 0.1) / dT},
    "low-pass": lambda g, s, h, span, dT: {"low-pass.cutoff_hz": g.uniform(0.08, 0.25) / h},
    "gauss-markov": lambda g, s, h, span, dT: {"gauss-markov.sigma": s * _log_uniform(g, 0.15, 0.5),
                                               "gauss-markov.tau_s": span * _log_uniform(g, 0.01, 0.1)},
    "thermal-lag": lambda g, s, h, span, dT: {"thermal-lag.bias_per_degC": _sign(g) * s * _log_uniform(g, 0.4, 1.2) / dT,
                                              "thermal-lag.tau_s": _log_uniform(g, 20.0, 200.0)},
    "step": lambda g, s, h, span, dT: {"step.size": _sign(g) * s * _log_uniform(g, 0.3, 0.8),
                                       "step.t_step": round(g.uniform(0.15, 0.85) * span / h) * h},
    "drifting-line": lambda g, s, h, span, dT: {"drifting-line.frequency_hz": g.uniform(0.05, 0.4) / h,
                                                "drifting-line.rate_hz_per_s": _sign(g) * g.uniform(0.3, 3.0) / span,
                                                "drifting-line.amplitude": s * _log_uniform(g, 0.15, 0.4),
                                                "drifting-line.phase": g.uniform(-math.pi, math.pi)},
    "spikes": lambda g, s, h, span, dT: _spikes(g, s, h, span),
    "digital-filter": lambda g, s, h, span, dT: {"digital-filter.cutoff_hz": g.uniform(0.08, 0.25) / h},
    "resonance": lambda g, s, h, span, dT: {"resonance.frequency_hz": g.uniform(0.05, 0.45) / h,
                                            "resonance.bandwidth_hz": _log_uniform(g, 0.002, 0.03) / h,
                                            "resonance.sigma": s * _log_uniform(g, 0.15, 0.5)},
}


def _spikes(g, s, h, span) -> dict:
    """3–15 spikes at distinct random samples, each of σ_w·[6, 12] (log-uniform) with a random sign."""
    count = int(g.integers(3, 16))
    ks = np.sort(g.choice(int(round(span / h)), size=count, replace=False))
    out = {}
    for j, k in enumerate(ks, start=1):
        out[f"spikes.size{j}"] = _sign(g) * s * _log_uniform(g, 6.0, 12.0)
        out[f"spikes.t{j}"] = float(k * h)
    return out


def random_case(effects, seed: int, n: int = 30_000, h: float = 0.01):
    """``(y, temperature, truth)`` — a recording with ``effects`` (a list of names, empty: clean) hidden in it, where
    everything is drawn at random for each seed: the base noise (order U(0.15, 0.6), pole at U(0.2, 0.7) of its
    stability limit, white variance r log-uniform in [3·10⁻⁴, 3·10⁻³] (units²), drive q = r/h^{2α}), the
    temperature (start U(20, 35) °C, a warm-up of U(1.5, 5) °C with a time constant U(30, 150) s, a wander of
    U(0.1, 0.3) °C with U(50, 200) s) and each effect's parameters (:data:`DRAWS`). The seed stream is the set's
    own: seed 0 of two sets are different draws."""
    effects = list(effects)
    unknown = [e for e in effects if e not in DRAWS]
    if unknown:
        raise ValueError(f"no random draw for {', '.join(unknown)}; choose from: {', '.join(DRAWS)}")
    key = sum((list(DRAWS).index(e) + 1) * 16 ** i for i, e in enumerate(sorted(effects)))
    g = np.random.default_rng([seed, key])
    gen = torch.Generator().manual_seed(int(g.integers(2 ** 62)))
    span = n * h
    dT = g.uniform(1.5, 5.0)
    T = temperature_profile(n, h, start=g.uniform(20.0, 35.0), warmup=dT, tau_s=g.uniform(30.0, 150.0),
                            wander=g.uniform(0.1, 0.3), wander_tau_s=g.uniform(50.0, 200.0), generator=gen)
    alpha, r = g.uniform(0.15, 0.6), _log_uniform(g, 3e-4, 3e-3)
    base = {"fractional.order": alpha, "fractional.pole": -g.uniform(0.2, 0.7) * 2 ** alpha / h ** alpha,
            "fractional.q": r / h ** (2 * alpha), "white.r": r}
    drawn = {}
    for e in effects:
        drawn.update(DRAWS[e](g, math.sqrt(r), h, span, dT))
    model = parse_model("+".join([BASE_MODEL, *(token_for(COMPONENTS[e], e, drawn) for e in effects)]))
    values = default_values(model, h, T)
    values.update(base)
    values.update(drawn)
    y = simulate_model(model, values, n_steps=n, h=h, inputs={"temperature": T}, generator=gen)[0, 0].numpy()
    return y, np.asarray(T.numpy()), values

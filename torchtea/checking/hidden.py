"""Recordings with a known hidden effect: the data on which :func:`~torchtea.checking.check` is tested.

Base noise is MEMS-like ``fractional+white`` with :func:`torchtea.noise.default_values` (order 0.3, pole at 40 %
of its stability limit, drive q = r/h^{2α}, white r = 10⁻³ (m/s²)²) and a temperature channel that warms up by
3 °C (time constant 60 s) plus a 0.2 °C wander (:func:`torchtea.noise.temperature_profile`). One effect is added
at the strength in :data:`HIDDEN_STRENGTH`: strong enough to show in the view made for it (spectrum, Allan
deviation, temperature) on 30 000 samples at 100 Hz, too weak to see in the raw time plot
(``experiments/check/README.md`` shows both).
"""
from __future__ import annotations

import numpy as np
import torch

from ..noise import default_values, parse_model, simulate_model, temperature_profile

__all__ = ["HIDDEN_STRENGTH", "BASE_MODEL", "hidden_model", "hidden_case"]

BASE_MODEL = "fractional+white"
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

r"""The physical parts of a sensor's noise model, each with named parameters, a spectrum and a state block.

Conventions (ALGORITHMS.md §7): sample time ``h``, ω in rad/sample, two-sided spectra with
``var = ∫_{−π}^{π} S(ω) dω``. The measurement is the sum of the components; a ``low-pass`` filters the
sum of the stochastic components listed before it — state and white alike, as a sensor's digital filter
filters its whole signal — and white / quantisation noise listed after it enters unfiltered (e.g. the
output's rounding): ``fractional+white+low-pass`` filters everything, ``fractional+low-pass+white`` only the
fractional part.

Three kinds of component:

* **state** components (``fractional``, ``random-walk``, ``gauss-markov``, ``resonance``) and **filters**
  (``low-pass``, ``digital-filter``) are linear Gaussian state-space
  blocks — the exact Kalman filter and the simulator stack them (:mod:`torchtea.noise.model`);
* **measurement** components (``white``, ``quantisation``) add independent white noise of variance ``r``;
* **mean** components (``offset``, ``ramp``, ``step``, ``spikes``, ``sinusoid``, ``drifting-line``,
  ``temperature-bias``, ``thermal-lag``) are deterministic functions
  of time and the input channels. The Whittle likelihood removes them by regression first (lines are not
  spectral densities); the exact filter subtracts them.

Parameters are given in natural units (``fractional.order``, ``white.r`` …) and every parameter has a
transform to an unconstrained real number for the optimisers (log for a positive value, logit for a bounded
one). The fractional pole's admissible range depends on the order (stability: ``−2^α < f h^α < 0``), so it
is stored as the fraction ``ρ = −f h^α / 2^α ∈ (0, 1)`` internally and reported as ``f``.


The package holds one module per family of effects — :mod:`.base` (the :class:`Component` every effect is, its
parameters, its place in the TEA), :mod:`.fractional`, :mod:`.markov` (random walk, Gauss–Markov, resonance),
:mod:`.filters`, :mod:`.measurement` (white, quantisation), :mod:`.levels` (offset, ramp, step), :mod:`.lines`
(sinusoid, drifting line), :mod:`.thermal` and :mod:`.outliers` (spikes) — and the registry :data:`COMPONENTS`
(a user's effect joins it through :func:`torchtea.effects.register`). How ``check`` screens an effect lives apart,
in :mod:`torchtea.checking.screens`, and how the fits start it in :mod:`torchtea.fitting.starts`. Its layer is the model's: it may import ``torchtea.core`` (the GL coefficients,
the searches on a series), numpy, torch and scipy's filters and optimisers (no statistical tests), nothing above.
"""
from __future__ import annotations

from ...core.registry import Registry
from .base import (
    KIND_BASES,
    ORDER_BOUNDS,
    STOCHASTIC_KINDS,
    Component,
    FilterEffect,
    FractionalState,
    MeanEffect,
    MeasurementEffect,
    Modifier,
    ParamSpec,
    StateEffect,
    logit,
)
from .filters import DigitalFilter, LowPass
from .fractional import Fractional
from .levels import Offset, Ramp, Step
from .lines import DriftingLine, Sinusoid
from .markov import GaussMarkov, RandomWalk, Resonance
from .measurement import Quantisation, White
from .outliers import Spikes
from .thermal import TemperatureBias, TemperatureOrder, ThermalLag

__all__ = ["ParamSpec", "Component", "StateEffect", "FractionalState", "MeasurementEffect", "MeanEffect",
           "FilterEffect", "Modifier", "KIND_BASES", "STOCHASTIC_KINDS", "COMPONENTS", "ORDER_BOUNDS", "logit",
           # the built-in effects
           "Fractional", "White", "Quantisation", "RandomWalk", "LowPass", "Offset", "Ramp", "Sinusoid",
           "TemperatureBias", "TemperatureOrder", "GaussMarkov", "ThermalLag", "Step", "DriftingLine",
           "DigitalFilter", "Spikes", "Resonance"]


#: The effects by name (:func:`torchtea.effects.register` adds a user's, under the rule of
#: :class:`~torchtea.core.registry.Registry` for registering again and unregistering).
COMPONENTS = Registry("effect")
for _c in (Fractional(), White(), Quantisation(), RandomWalk(), LowPass(), Offset(), Ramp(), Sinusoid(),
           TemperatureBias(), TemperatureOrder(), GaussMarkov(), ThermalLag(), Step(), DriftingLine(), DigitalFilter(),
           Spikes(), Resonance()):
    COMPONENTS.add(_c.name, _c)
COMPONENTS.seal()
del _c

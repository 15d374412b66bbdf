"""Which effects ``check`` screens and how it treats each as a candidate (:class:`~.registry.Screening`): its row in
check's table, the failed diagnostics it explains, the simpler effects it contains, whether a second one may join,
and when a model cannot be screened for it. The built-in effects' entries, in one table; a user's effect registers
its own with :func:`~.registry.register_screening` (or has the defaults)."""
from __future__ import annotations

from ...noise.components import (
    DigitalFilter,
    DriftingLine,
    Fractional,
    GaussMarkov,
    LowPass,
    Offset,
    Quantisation,
    Ramp,
    RandomWalk,
    Resonance,
    Sinusoid,
    Spikes,
    Step,
    TemperatureBias,
    TemperatureOrder,
    ThermalLag,
    White,
)
from .registry import register_screening


def _quantisation_beside_white(comp, model):
    if any(c.kind == "measurement" and type(c) is not type(comp) for _, c in model.components):
        return "quantisation noise is white, indistinguishable from the white component"
    return None


# the base parts of every model: not screened; the fractional part's special cases are tried in its place
register_screening(Fractional, candidate=False, special_cases=("random-walk", "gauss-markov"))
register_screening(White, candidate=False)
register_screening(Offset, candidate=False)
# the candidates, in the order of check's table
register_screening(RandomWalk, order=10)
register_screening(GaussMarkov, order=15, add_again=True)  # a second of another correlation time (bias instability)
register_screening(Sinusoid, order=20, explains=("lines",), add_again=True)  # a second line
register_screening(DriftingLine, order=25, explains=("spectrum",), add_again=True)
register_screening(Resonance, order=27, explains=("spectrum",), add_again=True)
register_screening(TemperatureBias, order=30, explains=("temperature",))
register_screening(ThermalLag, order=35, explains=("temperature",))
register_screening(TemperatureOrder, order=40, explains=("temperature",))
register_screening(LowPass, order=50)
register_screening(DigitalFilter, order=55)
register_screening(Ramp, order=60)
register_screening(Spikes, order=60, explains=("extremes",), add_again=True)
register_screening(Step, order=65, add_again=True)
register_screening(Quantisation, order=70, not_screened=_quantisation_beside_white)

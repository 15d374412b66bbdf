"""The fractional state's start: the order given, the pole at half its stability limit, the drive from the variance
the white level leaves."""
from __future__ import annotations

from ...noise.components import Fractional
from .registry import Starts, register_start


@register_start(Fractional)
class FractionalStarts(Starts):
    """The order the fit's grid gives, the pole at half its stability limit, the drive from the variance the
    white level leaves; scaled to the periodogram."""

    def start(self, comp, param, data):
        a = data.order
        return {"order": a, "pole": -0.5 * 2.0 ** a / data.h ** a,
                "q": max(data.var - data.white, 0.1 * data.var) / data.n_state}[param]

    def grid_start(self, comp, label, v, white, order, fraction, h):
        v[f"{label}.order"] = order
        v[f"{label}.pole"] = -fraction * 2.0 ** order / h ** order

    def scale_drive(self, comp, label, v, s, fixed):
        if f"{label}.q" not in fixed:
            v[f"{label}.q"] = v[f"{label}.q"] * s

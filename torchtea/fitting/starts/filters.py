"""The sensor filters' starts: a cut-off at half the Nyquist frequency; refits from 0.4× and 0.1× of it."""
from __future__ import annotations

from ...noise.components import LowPass
from .registry import Starts, register_start


@register_start(LowPass)  # (and the digital filter, its subclass)
class LowPassStarts(Starts):
    """A cut-off at half the Nyquist frequency; refits from 0.4× and 0.1× of it."""

    def start(self, comp, param, data):
        return 0.25 / data.h

    def strengths(self, comp, label, model, values, h, n):
        return [{f"{label}.cutoff_hz": c / (2 * h)} for c in (0.4, 0.1)]  # 0.4× and 0.1× the Nyquist frequency

    def vanishing(self, comp, label, model, values, h, n):
        return {f"{label}.cutoff_hz": 10.0 / h}  # a = e^{−20π}: the filter passes every frequency unchanged

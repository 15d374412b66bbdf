"""The spikes' start for a model written by hand: the samples farthest from their neighbours' median."""
from __future__ import annotations

import numpy as np

from ...noise.components import Spikes
from .registry import Starts, register_start


@register_start(Spikes)
class SpikesStarts(Starts):
    """The samples farthest from their neighbours' median (a model written by hand; check finds spikes by the
    extremes law)."""

    def fit_residual(self, comp, label, resid, t, ok, h, start, inputs):
        """The ``count`` samples farthest from the median of their ±5 neighbours (a local level: a wander or a step
        does not count), in units of the median absolute deviation of those excesses (a scale the spikes do not
        inflate); each spike's size its excess. A start for a model written by hand: ``check`` finds the spikes by
        the extremes law and their sizes by GLS (its screen, :func:`torchtea.checking.screens.outliers.spikes`)."""
        from scipy.ndimage import generic_filter

        r = np.where(ok, resid, np.nan)
        fill = np.where(ok, resid, np.nanmedian(r))
        local = generic_filter(fill, lambda w: np.median(np.r_[w[:5], w[6:]]), size=11, mode="nearest")
        ex = np.where(ok, fill - local, 0.0)
        mad = float(np.median(np.abs(ex[ok]))) or 1.0
        score = np.where(ok, np.abs(ex) / mad, -np.inf)
        ks = sorted(int(k) for k in np.argsort(-score)[:comp.count])
        out = {}
        for j, k in enumerate(ks, start=1):
            size = float(ex[k])
            resid[k] -= size
            out[f"{label}.size{j}"] = size
            out[f"{label}.t{j}"] = float(t[k])
        return out

"""Outliers: spikes at located samples, each with its own size."""
from __future__ import annotations

import torch

from .base import MeanEffect, ParamSpec


class Spikes(MeanEffect):
    r"""Isolated spikes (shocks, a knock on the bench, a corrupted sample): ``count`` additive outliers, spike j of
    size :math:`s_j` at sample :math:`k_j` (time :math:`t_j`), :math:`\mu_k = \sum_j s_j [k = k_j]` — the additive
    outlier of time-series analysis (Box & Tiao 1975; Chen & Liu 1993). Written ``spikes:K`` in a spec (K its count).
    A handful of 6–10 σ spikes moves no averaged diagnostic (NIS windows, Allan deviation, spectrum) but wrecks a
    fit: the white level absorbs them, and an Allan line fit breaks on them. ``check`` finds them with the
    ``extremes`` diagnostic's law: every standardised innovation beyond the bound that n samples allow at the
    diagnostic's level, the samples found set aside (missing) and the model's filter run again until no new one
    appears (a spike's neighbours are disturbed through the filter's gains; so is the bound, by the spike's own
    weight). Sizes are GLS at the model's noise parameters (whitened impulses), times the samples found; both are
    held in every fit (a time is not a smooth parameter, and a size with its time fixed is a linear mean term,
    orthogonal to the noise parameters) and both count as estimated in BIC (2K parameters)."""

    name = "spikes"
    #: more outliers than this are not isolated spikes but heavy-tailed noise, which no mean term describes
    MAX_SPIKES = 50
    #: how many times the filter is rerun with the spikes found set aside
    ROUNDS = 10
    #: in one round, an exceedance counts only where it is the largest within this many samples either side
    NEAR = 3
    WORDS = "the sample of an outlier beyond the extremes bound (held): no interval"
    SIZE_WORDS = ("GLS at the noise parameters of the check that found it, or by hand the excess over its neighbours' "
                  "median (held in the fits): no interval")

    def __init__(self, count: int = 0):
        self.count = int(count)
        self.params = tuple(p for j in range(1, self.count + 1)
                            for p in (ParamSpec(f"size{j}", "free", "units"),
                                      ParamSpec(f"t{j}", "free", "t (s from the first sample)")))
        self.held = {p.name: self.WORDS if p.name.startswith("t") else self.SIZE_WORDS for p in self.params}
        self.located = tuple(p.name for p in self.params)

    def mean(self, v, t, inputs):
        h = float(t[1] - t[0]) if t.shape[-1] > 1 else 1.0
        B = v["size1"].shape[0]
        out = t.new_zeros(B, t.shape[-1])
        for j in range(1, self.count + 1):
            at = (torch.abs(t - v[f"t{j}"].unsqueeze(-1)) < 0.5 * h).to(t.dtype)  # (B, N): the spike's sample
            out = out + v[f"size{j}"].unsqueeze(-1) * at
        return out

    def typical(self, param, h, t_ref):
        j = int(param[4:] if param.startswith("size") else param[1:])
        return 0.05 * (-1) ** j if param.startswith("size") else round((5.0 + 10.0 * (j - 1)) / h) * h


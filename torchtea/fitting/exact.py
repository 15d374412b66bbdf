"""The exact likelihood of a series at given parameter values (the compiled Kalman filter of
:mod:`torchtea.likelihood.kalman` on the model's state space): its value for a batch of parameter sets
(:func:`exact_loglik`) and one pass with its innovations (:func:`exact_pass`), on the series as the likelihood sees
it (:func:`centred`, the level integrated out where :func:`unknown_level`). The fits (:mod:`.mle`), the innovations'
tests (:mod:`.innovations`) and ``check`` read it from here."""
from __future__ import annotations

from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor

from ..likelihood.kalman import filter_fast, loglik_fast
from ..noise.model import NoiseModel, StateSpace, parse_model, state_memory

__all__ = ["FIT_MEMORY", "exact_loglik", "centred", "unknown_level", "ExactPass", "exact_pass"]


#: The exact likelihood's memory while fitting (``soe`` to this relative coefficient error; the
#: log-likelihood moves by < 1e-6 nats against 1e-8 on 30 000 MEMS-like samples).
FIT_MEMORY = "soe:1e-4"


def exact_loglik(model, values, y, h: float, *, inputs: dict | None = None, memory=FIT_MEMORY) -> np.ndarray:
    """Exact log-likelihood ``(B,)`` of one series for ``B`` parameter sets (compiled filter)."""
    model = parse_model(model)
    y = torch.as_tensor(np.asarray(y, dtype=np.float64))
    N = y.shape[-1]
    v = model.as_dict(values)
    ss = model.state_space(v, h, N, state_memory(memory, N), inputs=inputs)
    t = torch.arange(N, dtype=torch.float64) * h
    mean = model.mean(v, t, inputs)
    return loglik_fast(ss, y, mean, level=unknown_level(model))


def centred(model: NoiseModel, y) -> np.ndarray:
    """The series the exact likelihood sees: its mean removed unless the model has an ``offset`` to fit it (the
    likelihood then integrates the level out, :func:`unknown_level`, so removing the mean only keeps the numbers
    small)."""
    y = np.asarray(y, dtype=np.float64)
    return y if model.has_level else y - np.nanmean(y)


def unknown_level(model: NoiseModel) -> bool:
    """Whether the exact likelihood of ``model`` treats the level as an unknown constant and integrates it out
    (``level=True`` of :func:`~torchtea.likelihood.kalman.kalman_filter`, the diffuse likelihood): always, unless
    the model has an ``offset`` that fits it as a parameter. A random walk's path then need not start at the
    series' mean."""
    return not model.has_level


class ExactPass(NamedTuple):
    """One pass of the exact filter at one parameter set, as the exact likelihood sees the series."""

    y: np.ndarray  # the series the filter saw (:func:`centred`)
    ss: StateSpace
    mean: Tensor  # the deterministic part (1, N)
    loglik: float
    innovation: np.ndarray  # (N,), of y minus the integrated level where :func:`unknown_level`
    variance: np.ndarray  # (N,)


def exact_pass(model, values: dict, y, h: float, *, inputs: dict | None = None, memory=FIT_MEMORY) -> ExactPass:
    """The compiled exact filter at ``values`` on :func:`centred` ``y``, the level integrated out where
    :func:`unknown_level` — the innovations the diagnostics and the NIS read."""
    model = parse_model(model)
    y = centred(model, y)
    N = len(y)
    ss = model.state_space(values, h, N, state_memory(memory, N), inputs=inputs)
    mean = model.mean(values, torch.arange(N, dtype=torch.float64) * h, inputs)
    ll, e, S = filter_fast(ss, y, mean, level=unknown_level(model))
    return ExactPass(y, ss, mean, float(ll[0]), e[0], S[0])

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

from ..core import forward
from ..likelihood.kalman import filter_fast, loglik_fast
from ..noise.derivatives import state_space_derivatives
from ..noise.model import NoiseModel, StateSpace, parse_model, state_memory

__all__ = ["FIT_MEMORY", "exact_loglik", "centred", "unknown_level", "ExactPass", "exact_pass", "exact_loglik_grad",
           "gradient_supported"]


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


def gradient_supported(model: NoiseModel, y) -> str | None:
    """Why the exact likelihood's gradient of ``model`` on ``y`` is taken by central differences here (None: the
    sensitivity filter of :mod:`torchtea.likelihood.gradient` gives it): a time-varying order or missing samples."""
    if model.modifiers:
        return "a temperature-driven order makes the transition vary"
    if np.isnan(np.asarray(y, dtype=np.float64)).any():
        return "the series has missing samples"
    return None


def exact_loglik_grad(model, U: Tensor, y, h: float, free, *, inputs: dict | None = None, memory=FIT_MEMORY):
    """The exact log-likelihood ``(B,)`` of one series at ``B`` points ``U`` ``(B, P)`` of the unconstrained
    coordinates (:meth:`~torchtea.noise.model.NoiseModel.from_unconstrained`), its gradient ``(B, F)`` over the
    coordinates ``free`` (indices, F of them) and the scoring information ``(B, F, F)`` there — from the sensitivity
    filter (:func:`torchtea.likelihood.gradient.loglik_grad`) on the state space's matrices and their derivatives,
    assembled from each component's own (:func:`~torchtea.noise.derivatives.state_space_derivatives`; a mean's by
    forward-mode automatic differentiation, :func:`torch.func.jacfwd`). ``y`` as the likelihood sees it (:func:`centred`); where :func:`gradient_supported` says why not, ``ValueError``."""
    from ..likelihood.gradient import loglik_grad

    model = parse_model(model)
    why = gradient_supported(model, y)
    if why is not None:
        raise ValueError(f"no sensitivity gradient for {model.spec}: {why}")
    y = np.asarray(y, dtype=np.float64)
    N = len(y)
    U = torch.as_tensor(U, dtype=torch.float64).reshape(-1, len(model.names))
    free = torch.as_tensor(np.asarray(free, dtype=np.int64))
    if free.numel() == 0:  # nothing free: the likelihood alone
        ll = exact_loglik(model, model.from_unconstrained(U, h), y, h, inputs=inputs, memory=memory)
        return ll, np.zeros((len(U), 0)), np.zeros((len(U), 0, 0))
    mem = state_memory(memory, N)
    t = torch.arange(N, dtype=torch.float64) * h
    inp = None if inputs is None else {k: torch.as_tensor(v, dtype=torch.float64) for k, v in inputs.items()}
    kinds = {n: dict(model.components)[n.rsplit(".", 1)[0]].kind for n in model.names}
    mean_dirs = [q for q, i in enumerate(free.tolist()) if kinds[model.names[i]] == "mean"]
    ss, dF, dG, dR, dg0 = state_space_derivatives(model, U, h, N, mem, free.tolist())
    means, dmeans = [], []
    for u in U:
        means.append(model.mean(model.from_unconstrained(u, h), t, inp)[0])
        if mean_dirs:
            sub = free[mean_dirs]

            def mean_of(um, u=u, sub=sub):
                return model.mean(model.from_unconstrained(u.index_put((sub,), um), h), t, inp)[0]

            try:  # every direction in one batched forward-mode pass …
                dmeans.append(forward.jacfwd(mean_of)(u[sub]).mT)  # (D, N)
            except RuntimeError:  # … or one pass each, where a mean holds a function of its own derivative (a
                # thermal lag's filter) that vmap cannot batch
                eye = torch.eye(len(sub), dtype=torch.float64)
                dmeans.append(torch.stack([forward.jvp(mean_of, (u[sub],), (eye[d],))[1]
                                           for d in range(len(sub))]))
    row = np.full(len(free), -1, dtype=np.int64)
    row[mean_dirs] = np.arange(len(mean_dirs))
    dmean = torch.stack(dmeans).numpy() if mean_dirs else None
    a = lambda x: x.detach().numpy()  # noqa: E731
    return loglik_grad(a(ss.F), a(dF), a(ss.G), a(dG), a(ss.C), a(ss.R), a(dR), a(ss.initial), a(dg0),
                       y, torch.stack(means).detach().numpy(), dmean, row, level=unknown_level(model))

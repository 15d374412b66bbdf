"""Simulation of any :class:`~torchtea.noise.model.NoiseModel`, batched over parameter sets and realisations.

It runs the very state space the exact Kalman filter reads (:meth:`NoiseModel.state_space`), so the
simulator and the filter cannot disagree about the model; the deterministic part comes from
:meth:`NoiseModel.mean`. With ``soe`` memory the fractional history is exact to the kernel's tolerance
(default 1e-8 relative per coefficient) at O(1) cost per step.
"""
from __future__ import annotations

import math

import torch

from .model import parse_model, varying_kernel_args

__all__ = ["simulate_model", "temperature_profile", "default_values"]


def simulate_model(model, values, *, n_steps: int, h: float, realisations: int = 1, memory="soe",
                   inputs: dict | None = None, generator: torch.Generator | None = None,
                   return_states: bool = False):
    """Simulate ``realisations`` series for each of the ``B`` parameter sets in ``values``.

    Returns ``y`` of shape ``(B, realisations, N)`` (and the stacked states ``(B, realisations, N, n)``
    with ``return_states``). ``inputs``: channels the mean components read (``{"temperature": (N,)}``).
    Draw order: the state noise of every step, then the measurement noise, then (only for a state that does not
    start at zero) the initial state — fixed, so a seed gives the same series whatever the batch.
    """
    model = parse_model(model)
    if n_steps < 1:
        raise ValueError("n_steps must be >= 1")
    v = model.as_dict(values)
    ss = model.state_space(v, h, n_steps, memory, inputs=inputs)
    B, n, m = ss.G.shape
    R_ = int(realisations)
    xi = torch.randn(B, R_, n_steps, m, generator=generator, dtype=torch.float64)
    nu = torch.randn(B, R_, n_steps, generator=generator, dtype=torch.float64)
    z = torch.zeros(B, R_, n, dtype=torch.float64)
    if ss.g0 is not None:  # a state that does not start at zero (a low-pass of white noise): drawn last
        z = ss.g0.unsqueeze(1) * torch.randn(B, R_, 1, generator=generator, dtype=torch.float64)
    out, states = _run(ss, z, xi, return_states)
    t = torch.arange(n_steps, dtype=torch.float64) * h
    y = out + torch.sqrt(ss.R).reshape(B, 1, 1) * nu + model.mean(v, t, inputs).unsqueeze(1)
    return (y, states) if return_states else y


def _run(ss, z0: torch.Tensor, xi: torch.Tensor, keep: bool):
    """The state recursion ``z_{k+1} = F z_k + G ξ_k`` (row i of F per step for a time-varying order) and the outputs
    ``C z_k`` ``(B, R, N)`` (and the states ``(B, R, N, n)`` with ``keep``), compiled: O(nonzeros of F) per step and
    no O(N n) noise array, so a three-hour recording's six channels take seconds and little memory."""
    import numpy as np

    from ._simulate_kernel import csr
    from ._simulate_kernel import simulate_batch

    F = ss.F.detach().cpu().numpy()
    B, R_, N, _ = xi.shape
    n = F.shape[-1]
    indptr, indices, fvals = csr(F)
    out = np.empty((B, R_, N))
    states = np.empty((B, R_, N, n)) if keep else np.empty((1, 1, 1, 1))
    tv = varying_kernel_args(ss.varying, B, n)
    simulate_batch(indptr, indices, fvals, np.ascontiguousarray(ss.G.numpy()), np.ascontiguousarray(ss.C.numpy()),
                   np.ascontiguousarray(z0.numpy()), np.ascontiguousarray(xi.numpy()), out, states, keep, *tv)
    return torch.from_numpy(out), torch.from_numpy(states) if keep else None


def temperature_profile(n_steps: int, h: float, *, start: float = 25.0, warmup: float = 3.0, tau_s: float = 60.0,
                        wander: float = 0.2, wander_tau_s: float = 100.0,
                        generator: torch.Generator | None = None) -> torch.Tensor:
    """A sensor's temperature (°C) after power-on: ``start`` plus an exponential warm-up of ``warmup`` °C with
    time constant ``tau_s``, plus a slow wander — an Ornstein–Uhlenbeck process of standard deviation ``wander``
    °C and time constant ``wander_tau_s`` (started in its stationary law)."""
    t = torch.arange(n_steps, dtype=torch.float64) * h
    T = start + warmup * (1.0 - torch.exp(-t / tau_s))
    if wander > 0:
        a = math.exp(-h / wander_tau_s)
        xi = torch.randn(n_steps, generator=generator, dtype=torch.float64) * wander * math.sqrt(1 - a * a)
        from scipy.signal import lfilter

        w0 = float(torch.randn(1, generator=generator, dtype=torch.float64)[0]) * wander
        xi[0] = w0
        T = T + torch.as_tensor(lfilter([1.0], [1.0, -a], xi.numpy()))  # w_k = a w_{k−1} + ξ_k
    return T


def default_values(model, h: float, temperature=None) -> dict:
    """MEMS-like values of every parameter of ``model`` (units m/s², h the sample time): the fractional part
    of the Monte Carlo studies (order 0.3, pole at 40 % of its stability limit, drive q = r / h^{2α}), white
    r = 10⁻³, and effects of moderate strength — a starting point for ``torchtea simulate --model``, each
    value replaced by ``--set``."""
    model = parse_model(model)
    out = {}
    t_ref = 25.0 if temperature is None else float(torch.as_tensor(temperature, dtype=torch.float64).mean())
    for label, comp in model.components:
        for p in comp.params:
            out[f"{label}.{p.name}"] = comp.typical(p.name, h, t_ref)
    return out

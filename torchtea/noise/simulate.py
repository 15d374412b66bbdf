"""The simulator: realisations of any :class:`~torchtea.noise.model.NoiseModel`, batched over parameter sets and
realisations — the one every engine's data come from.

It runs the very state space the exact Kalman filter reads (:meth:`NoiseModel.state_space`), so the simulator and
the filter cannot disagree about the model; the deterministic part comes from :meth:`NoiseModel.mean`. With ``soe``
memory the fractional history is exact to the kernel's tolerance (default 1e-8 relative per coefficient) at O(1) cost
per step; with ``exact`` memory a model whose one state is the fractional component runs that component's own
recursion over the whole past (:meth:`~torchtea.noise.components.Fractional.run_exact`, any length, on any device).

One batch convention: a :class:`Simulation` holds ``(*B, N, ·)`` tensors — the batch first, time at ``-2``, channels
last; :func:`simulate_states` gives ``*B = (parameter sets, realisations)``. :func:`simulate_model` is its series
alone ``(B, R, N)`` (time last, the likelihood's layout), :func:`simulate` the paper's scalar A-type model (43)–(45)
as the TEA's ``Structure`` describes it, with the paper's order schedules and known input, ``*B`` as the caller's.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from ..core.gl import broadcast_shapes
from ..core.memory import parse_memory
from .model import PAPER_MODEL, parse_model, state_memory, varying_kernel_args

__all__ = ["simulate_recording", "parse_sets", "parse_temperature_profile", "TRUTH_MEANING", "Simulation", "simulate_states", "simulate_model", "simulate", "gaussian_input", "simulate_noise_model",
           "simulate_columns", "temperature_profile", "default_values"]


@dataclass(frozen=True)
class Simulation:
    """A batch of simulated realisations; time is dimension ``-2``.

    Attributes
    ----------
    t : Tensor ``(N,)``; known inputs ``u`` ``(*B, N, d)``; states ``x`` ``(*B, N, n)``; outputs ``y`` ``(*B, N, p)``;
    orders ``alpha`` ``(*B, N, ·)`` (the fractional state's); the draws ``process_noise`` ``(*B, N, ·)`` (drives step
    k → k+1) and ``measurement_noise`` ν ``(*B, N, p)``. From :func:`simulate` these are the paper's: ω ~ N(0, Q) of
    (9), ``x`` the fractional state; from :func:`simulate_states` the state space's: standard-normal ξ (loaded by its
    G), ``x`` the states asked for.
    """

    t: Tensor
    u: Tensor
    x: Tensor
    y: Tensor
    alpha: Tensor
    process_noise: Tensor
    measurement_noise: Tensor

    def reshape(self, batch: tuple) -> Simulation:
        """The same realisations with the batch dimensions ``batch`` (as many realisations in all)."""
        def r(t):
            return t.reshape(tuple(batch) + t.shape[-2:])
        return Simulation(self.t, r(self.u), r(self.x), r(self.y), r(self.alpha), r(self.process_noise),
                          r(self.measurement_noise))

    def to(self, device) -> Simulation:
        return Simulation(*(t.to(device) for t in (self.t, self.u, self.x, self.y, self.alpha, self.process_noise,
                                                   self.measurement_noise)))


def simulate_states(model, values, *, n_steps: int, h: float, realisations: int = 1, memory="soe",
                    inputs: dict | None = None, generator: torch.Generator | None = None, orders=None, forcing=None,
                    draws: tuple | None = None, x0=None, keep=(), device=None) -> Simulation:
    """Simulate ``realisations`` series for each of the ``B`` parameter sets in ``values``: a :class:`Simulation`
    with ``*B = (B, realisations)``.

    Parameters
    ----------
    model, values : the model (or its spec) and its parameter sets (``{name: (B,)}`` or a ``(B, P)`` matrix).
    inputs : channels the components read (``{"temperature": (N,)}``).
    orders : Tensor ``(B, N)`` or ``(N,)``, optional
        A known trajectory of the fractional component's order (step k → k+1 uses ``orders[k+1]``), instead of its
        constant ``order`` value.
    forcing : Tensor ``(B, R, N)`` (broadcast), optional
        A known input ``u_k`` driving the fractional state inside ``h^α(…)`` (the paper's ``B u_k``).
    draws : ``(ξ (B, R, N, m), ν (B, R, N))``, optional
        Standard-normal draws instead of the generator's (a study whose realisation i must not depend on its chunk);
        a model that starts from a draw (a sensor filter's first sample) takes a third, ``(B, R)``.
    x0 : the fractional state's value at k = 0 (zero by default; ``(B, R)`` broadcast).
    keep : indices of the stacked state to return as ``x``, or ``"all"``.

    Draw order from ``generator``: the state noise of every step, then the measurement noise, then (only for a state
    that does not start at zero) the initial state — fixed, so a seed gives the same series whatever the batch.
    """
    model = parse_model(model)
    if n_steps < 1:
        raise ValueError("n_steps must be >= 1")
    v = model.as_dict(values)
    B = next(iter(v.values())).shape[0]
    R_ = int(realisations)
    N = n_steps
    t = torch.arange(N, dtype=torch.float64) * h
    mean = model.mean(v, t, inputs)  # (B, N); checks the mean components' inputs first
    frac = model.order_labels[0] if model.order_labels else None
    if (orders is not None or forcing is not None or x0 is not None) and frac is None:
        raise ValueError(f"model {model.spec!r} has no fractional component for orders, forcing or x0 to act on")
    if forcing is not None:
        forcing = torch.as_tensor(forcing, dtype=torch.float64).expand(B, R_, N)
    if x0 is not None:
        x0 = torch.as_tensor(x0, dtype=torch.float64).expand(B, R_)
    modified = bool(model.modifiers)  # a temperature-driven order
    run = model.orders_in_time(v, N, inputs, orders)  # (B, N): the trajectory, the modifier's, or the constant
    if orders is not None:
        orders = run
    exact = (not parse_memory(memory).bounded and model.labels("state") == [frac] and not model.labels("filter")
             and not modified)
    if exact:  # the fractional component's own recursion over the whole past
        xi, nu, rv, out, states, alpha = _states_exact(model, v, frac, run, h, B, R_, N, draws, generator, forcing,
                                                       x0, keep, device)
    else:
        xi, nu, rv, out, states, alpha = _states_stacked(model, v, frac, run, h, B, R_, N, memory, inputs, orders,
                                                         draws, generator, forcing, x0, keep)
    dev = lambda a: a.to(device) if device is not None else a  # noqa: E731
    meas = torch.sqrt(rv).reshape(B, 1, 1) * nu
    y = dev(out) + dev(meas) + dev(mean).unsqueeze(1)
    u = dev(forcing.unsqueeze(-1)) if forcing is not None else torch.zeros(B, R_, N, 0, dtype=torch.float64,
                                                                             device=device)
    return Simulation(t=dev(t), u=u, x=dev(states), y=y.unsqueeze(-1), alpha=dev(alpha),
                      process_noise=dev(xi), measurement_noise=dev(meas).unsqueeze(-1))


def _states_exact(model, v: dict, frac: str, run: Tensor, h: float, B: int, R_: int, N: int, draws, generator,
                  forcing, x0, keep, device):
    """:func:`simulate_states` by the fractional component's own recursion: ``(ξ, ν, R, outputs, states, orders)``."""
    xi, nu = _draws(draws, generator, B, R_, N, 1)
    rv = model.measurement_variance(v)  # (B,): no filter, so all of it is measured
    comp = dict(model.components)[frac]
    fv = {k.split(".", 1)[1]: x for k, x in v.items() if k.startswith(frac + ".")}
    alpha = run.to(device)
    S = B * R_
    fv = {k: x.repeat_interleave(R_).to(device) for k, x in fv.items()}
    x = comp.run_exact(fv, alpha.repeat_interleave(R_, dim=0), h, xi.reshape(S, N).to(device),
                       None if forcing is None else forcing.reshape(S, N).to(device),
                       None if x0 is None else x0.reshape(S).to(device)).reshape(B, R_, N)
    # the state space's exact memory holds x_k, x_{k-1}, ... (N - 1 states): state i at step k is x_{k-i}
    lags = max(N - 1, 1)
    idx = list(range(lags)) if keep == "all" else [int(i) for i in keep]
    if any(not 0 <= i < lags for i in idx):
        raise ValueError(f"keep: model {model.spec!r} has states 0 ... {lags - 1} under exact memory, not {keep!r}")
    states = (torch.stack([torch.nn.functional.pad(x, (i, 0))[..., :N] for i in idx], -1) if idx
              else x.new_zeros(B, R_, N, 0))
    alpha = alpha.unsqueeze(1).expand(B, R_, N).unsqueeze(-1)
    return xi, nu, rv, x, states, alpha


def _states_stacked(model, v: dict, frac, run: Tensor, h: float, B: int, R_: int, N: int, memory, inputs, orders,
                    draws, generator, forcing, x0, keep):
    """:func:`simulate_states` on the model's stacked state space: ``(ξ, ν, R, outputs, states, orders)``."""
    mem = memory
    if frac is not None and parse_memory(memory).bounded:  # a soe kernel for every order run (Example 3: up to 2)
        mem = state_memory(memory, N, (float(run.min()), float(run.max())))
    ss = model.state_space(v, h, N, mem, inputs=inputs, orders=orders)
    n, m = ss.n, ss.G.shape[-1]
    xi, nu = _draws(draws, generator, B, R_, N, m)
    rv = ss.R  # the white noise after a sensor filter (before it, it is a state's drive)
    z = torch.zeros(B, R_, n, dtype=torch.float64)
    if ss.g0 is not None:  # a state that does not start at zero (a low-pass of white noise): drawn last
        if draws is not None and len(draws) < 3:
            raise ValueError(f"model {model.spec!r} starts from a draw (its sensor filter's first sample): give it "
                             "as the third of draws, (B, R), or draw from a generator")
        z0 = (torch.as_tensor(draws[2], dtype=torch.float64).expand(B, R_).unsqueeze(-1) if draws is not None
              else torch.randn(B, R_, 1, generator=generator, dtype=torch.float64))
        z = ss.g0.unsqueeze(1) * z0
    row = -1 if frac is None else ss.blocks[frac].start
    if x0 is not None:
        z[..., row] = x0
    idx = list(range(n)) if keep == "all" else [int(i) for i in keep]
    if any(not 0 <= i < n for i in idx):
        raise ValueError(f"keep: model {model.spec!r} has states 0 … {n - 1} under {memory!r} memory, not {keep!r}")
    drive = None
    if forcing is not None:  # enters the row as h^{α_{k+1}} u_k, like the drive
        a_next = torch.cat([run[:, 1:], run[:, -1:]], dim=1)
        drive = (torch.tensor(h, dtype=torch.float64) ** a_next).unsqueeze(1) * forcing
    out, states = _run(ss, z, xi, idx, row if drive is not None else -1, drive)
    alpha = (torch.zeros(B, R_, N, 0, dtype=torch.float64) if frac is None
             else run.unsqueeze(1).expand(B, R_, N).unsqueeze(-1))
    return xi, nu, rv, out, states, alpha


def _draws(draws, generator, B: int, R_: int, N: int, m: int):
    """Standard-normal ξ ``(B, R, N, m)`` and ν ``(B, R, N)``: given, or drawn in that order."""
    if draws is None:
        return (torch.randn(B, R_, N, m, generator=generator, dtype=torch.float64),
                torch.randn(B, R_, N, generator=generator, dtype=torch.float64))
    xi, nu = (torch.as_tensor(d, dtype=torch.float64).cpu() for d in draws[:2])
    if (xi.shape[-2:] != (N, m) or nu.shape[-1] != N
            or any(a not in (1, b) for a, b in zip(xi.shape[-4:-2][::-1], (R_, B))) or xi.ndim > 4 or nu.ndim > 3):
        raise ValueError(f"draws must have shapes (B, R, {N}, {m}) and (B, R, {N}), got {tuple(xi.shape)} and "
                         f"{tuple(nu.shape)}")
    return xi.expand(B, R_, N, m), nu.expand(B, R_, N)


def simulate_model(model, values, *, n_steps: int, h: float, realisations: int = 1, memory="soe",
                   inputs: dict | None = None, generator: torch.Generator | None = None,
                   return_states: bool = False):
    """The series of :func:`simulate_states` alone: ``y`` of shape ``(B, realisations, N)`` (and every stacked
    state ``(B, realisations, N, n)`` with ``return_states``) — time last, as the likelihood and the fits read
    series. Same draws as :func:`simulate_states` with the same generator."""
    sim = simulate_states(model, values, n_steps=n_steps, h=h, realisations=realisations, memory=memory,
                          inputs=inputs, generator=generator, keep="all" if return_states else ())
    y = sim.y[..., 0]
    return (y, sim.x) if return_states else y


def gaussian_input(batch_shape, n_steps: int, n_inputs: int, std: float, *, generator=None,
                   dtype=torch.float64, device=None) -> Tensor:
    """Known input ``u_k ~ N(0, std²)`` of shape ``(*batch_shape, N, d)``."""
    z = torch.randn(tuple(batch_shape) + (n_steps, n_inputs), generator=generator, dtype=dtype, device=device)
    return std * z


def _variance(value, name: str, like: Tensor) -> Tensor:
    """``Q`` or ``R`` of the scalar structure: a float, or a ``(*B, 1, 1)`` / ``(1, 1)`` tensor → ``(*B,)``."""
    c = torch.as_tensor(value, dtype=torch.float64).to(like.device)
    if c.ndim >= 2:
        if c.shape[-2:] != (1, 1):
            raise ValueError(f"{name} must be 1x1 for the scalar structure, got {tuple(c.shape)}")
        c = c[..., 0, 0]
    if bool((c < 0).any()):
        raise ValueError(f"{name} must not be negative, got {c}")
    return c


def simulate(structure, *, n_steps: int, h: float, order, parameters, process_noise, measurement_noise,
             inputs: Tensor | None = None, x0=None, batch_shape=(), generator: torch.Generator | None = None,
             standard_draws: tuple[Tensor, Tensor] | None = None, memory="exact", dtype=torch.float64,
             device=None) -> Simulation:
    r"""Simulate realisations of paper (9)–(11) for the TEA's scalar ``structure`` (43)–(45): the noise model
    ``fractional+white`` with the paper's order schedule and known input, by :func:`simulate_states`.

    ``x_0 = x0`` (zero by default) and, for ``k = 0 … N−2``,
    ``x_{k+1} = h^{α_{k+1}} (f x_k + u_k + ω_k) − Σ_{j=1}^{k+1} c_j(α_{k+1}) x_{k+1−j}``,
    ``y_k = x_k + ν_k`` with ``ω ~ N(0, q)``, ``ν ~ N(0, r)``.

    Parameters
    ----------
    structure : Structure
        The scalar structure (``Structure()``); a model of several states is simulated from its
        :class:`~torchtea.noise.model.NoiseModel` (:func:`simulate_states`).
    n_steps : int
        ``N``, number of samples (including ``k = 0``).
    h : float
        Sample time.
    order : OrderSchedule
        True orders; evaluated to ``(*B, N, 1)``.
    parameters : Tensor, shape ``(*B, 1)`` or ``(1,)``
        True ``f``.
    process_noise, measurement_noise : float or Tensor ``(*B, 1, 1)``
        ``q`` and ``r``.
    inputs : Tensor, shape ``(*B, N, 1)``, optional
        Known inputs (zero when absent).
    batch_shape : tuple
        Number of realisations; broadcast with the batch shapes of the other arguments.
    generator : torch.Generator, optional
        Source of all random draws (ω first, then ν, each ``(*B, N, 1)``).
    standard_draws : (Tensor ``(*B, N, 1)``, Tensor ``(*B, N, 1)``), optional
        Standard-normal draws to use instead of the generator (scaled by ``√q`` and ``√r``) — for Monte Carlo
        studies whose realisation i must not depend on how the batch is chunked.
    memory : str or MemoryConfig
        How the GL sums see the past (:mod:`torchtea.core.memory`): ``"exact"`` (default, O(k) per step, on
        ``device``), ``"soe"``/``"soe:TOL"`` (the model's exponential sums, O(1) per step, compiled on the CPU —
        for long series; the kernel serves every order run, beyond the model's 0 … 1 too) or ``"window:L"``.
    dtype : the result's floating type (computed in float64).

    Returns
    -------
    Simulation
        ``(*B, N, ·)``: ``x`` the fractional state, ``process_noise`` ω, ``measurement_noise`` ν.
    """
    if n_steps < 1:
        raise ValueError("n_steps must be >= 1")
    n, p, d = structure.n_states, structure.n_outputs, structure.n_inputs
    _check_scalar(structure)
    cpu = torch.empty((), dtype=torch.float64)
    w, alpha, q, r, inputs, shapes = _scalar_arguments(order, parameters, process_noise, measurement_noise, inputs,
                                                       n_steps, h, d, batch_shape, cpu)
    batch = broadcast_shapes(*shapes)
    z_omega, z_nu, batch = _standard_draws(standard_draws, generator, batch, n_steps, n, p, dtype, device)
    # one parameter set for the whole batch when nothing but the draws and the input varies; else one per member
    per_member = any(len(s) for s in shapes[1:5])
    S = math.prod(batch)
    B, R_ = (S, 1) if per_member else (1, S)
    values = {"fractional.order": alpha[..., 0, 0].expand(batch).reshape(-1)[:B],
              "fractional.pole": w[..., 0].expand(batch).reshape(-1)[:B],
              "fractional.q": q.expand(batch).reshape(-1)[:B], "white.r": r.expand(batch).reshape(-1)[:B]}
    a = alpha[..., 0].expand(batch + (n_steps,)).reshape(S, n_steps)[:B]
    constant = bool(torch.all(a == a[:, :1]))
    draws = (z_omega.to(cpu).expand(batch + (n_steps, n)).reshape(B, R_, n_steps, 1),
             z_nu.to(cpu).expand(batch + (n_steps, p)).reshape(B, R_, n_steps))
    forcing = None if inputs is None else inputs[..., 0].expand(batch + (n_steps,)).reshape(B, R_, n_steps)
    grad = any(torch.is_tensor(t) and t.requires_grad for t in (parameters, inputs, x0, process_noise, measurement_noise,
                                                                *(standard_draws or ())))
    if grad:
        raise ValueError("simulate does not differentiate: pass tensors that do not require grad")
    sim = simulate_states(PAPER_MODEL, values, n_steps=n_steps, h=h, realisations=R_, memory=memory,
                          orders=None if constant else a, forcing=forcing, draws=draws,
                          x0=None if x0 is None else _initial(x0, batch, B, R_),
                          keep=[0], device=device)
    return _paper_result(sim, values["fractional.q"], inputs is not None, B, R_, n_steps, d, batch, dtype)


def _paper_result(sim: Simulation, q: Tensor, has_inputs: bool, B: int, R_: int, n_steps: int, d: int, batch: tuple,
                  dtype) -> Simulation:
    """:func:`simulate`'s result from :func:`simulate_states`' ``sim``: ω scaled by √q, the batch ``batch``."""
    omega = sim.process_noise * torch.sqrt(q).to(sim.y).reshape(B, 1, 1, 1)
    out = Simulation(t=sim.t, u=sim.u if has_inputs else torch.zeros(B, R_, n_steps, d, device=sim.y.device,
                                                                     dtype=torch.float64),
                     x=sim.x, y=sim.y, alpha=sim.alpha, process_noise=omega, measurement_noise=sim.measurement_noise)
    out = out.reshape(batch)
    return Simulation(*(t.to(dtype) for t in (out.t, out.u, out.x, out.y, out.alpha, out.process_noise,
                                              out.measurement_noise)))


def _check_scalar(structure) -> None:
    """Raise unless ``structure`` is the paper's scalar one (``Structure()``), the only one :func:`simulate` runs."""
    from ..engines.structure import Structure

    scalar = Structure()
    if (structure.n_states, structure.n_outputs, structure.n_inputs) != (1, 1, 1) or structure.n_params != 1 or not all(
            torch.equal(a, b) for a, b in ((structure.A.base, scalar.A.base), (structure.A.basis, scalar.A.basis),
                                           (structure.B, scalar.B), (structure.C, scalar.C))):
        raise ValueError("simulate runs the paper's scalar structure (Structure()); simulate a model of several "
                         "states from its noise model (torchtea.noise.simulate_states)")


def _scalar_arguments(order, parameters, process_noise, measurement_noise, inputs, n_steps: int, h: float, d: int,
                      batch_shape, cpu: Tensor):
    """:func:`simulate`'s ``f``, orders, ``q``, ``r`` and inputs on the CPU, and the batch shapes to broadcast."""
    w = torch.as_tensor(parameters, dtype=torch.float64).cpu()
    if w.ndim == 0:
        w = w.reshape(1)
    alpha = order.values(n_steps, h, 1, inputs).to(cpu)  # (N, 1) or (*B, N, 1)
    q = _variance(process_noise, "process_noise", cpu)
    r = _variance(measurement_noise, "measurement_noise", cpu)
    shapes = [tuple(batch_shape), w.shape[:-1], alpha.shape[:-2], q.shape, r.shape]
    if inputs is not None:
        inputs = torch.as_tensor(inputs).to(cpu)
        if inputs.shape[-2:] != (n_steps, d):
            raise ValueError(f"inputs must have shape (*B, {n_steps}, {d}), got {tuple(inputs.shape)}")
        shapes.append(inputs.shape[:-2])
    return w, alpha, q, r, inputs, shapes


def _standard_draws(standard_draws, generator, batch: tuple, n_steps: int, n: int, p: int, dtype, device):
    """:func:`simulate`'s standard-normal ω and ν draws (given, or drawn in that order) and the batch with theirs."""
    if standard_draws is None:
        z_omega = torch.randn(batch + (n_steps, n), generator=generator, dtype=dtype, device=device)
        z_nu = torch.randn(batch + (n_steps, p), generator=generator, dtype=dtype, device=device)
    else:
        z_omega, z_nu = (torch.as_tensor(z) for z in standard_draws)
        if z_omega.shape[-2:] != (n_steps, n) or z_nu.shape[-2:] != (n_steps, p):
            raise ValueError(f"standard_draws must have shapes (*B, {n_steps}, {n}) and (*B, {n_steps}, {p})")
        batch = broadcast_shapes(batch, z_omega.shape[:-2], z_nu.shape[:-2])
    return z_omega, z_nu, batch


def _initial(x0, batch: tuple, B: int, R_: int) -> Tensor:
    """``x0`` (a number, ``(1,)`` or ``(*B, 1)``) as ``(B, R)``."""
    x = torch.as_tensor(x0, dtype=torch.float64)
    if x.ndim and x.shape[-1] == 1:
        x = x[..., 0]
    return x.expand(batch).reshape(B, R_)


def simulate_noise_model(*, n_steps: int, h: float, order, param: float, q: float, r: float,
                         input_std: float | None = None, seed: int = 0, memory="exact", device=None) -> Simulation:
    """One realisation of the paper's scalar noise model (43)–(45) from one seed.

    The known input ``u ~ N(0, input_std²)`` is drawn first (none when ``input_std`` is None), then ω, then ν,
    all from ``torch.Generator().manual_seed(seed)`` — exactly what ``torchtea simulate --seed`` writes. On another
    ``device`` the draws are the same (made on the CPU) and the recursion runs there; the result stays there.
    """
    from ..engines.structure import Structure

    g = torch.Generator().manual_seed(seed)
    u = None if input_std is None else gaussian_input((), n_steps, 1, input_std, generator=g)
    # ω, then ν, drawn on the CPU in the order simulate draws them from a generator; the recursion on ``device``
    draws = tuple(torch.randn(n_steps, 1, generator=g, dtype=torch.float64).to(device) for _ in range(2))
    return simulate(Structure(), n_steps=n_steps, h=h, order=order, parameters=[param], process_noise=q,
                    measurement_noise=r, inputs=None if u is None else u.to(device), standard_draws=draws,
                    memory=memory, device=device)


def _run(ss, z0: torch.Tensor, xi: torch.Tensor, keep: list, fr_i: int, forcing):
    """The state recursion ``z_{k+1} = F z_k + G ξ_k`` (row i of F per step for a time-varying order; plus a known
    forcing of row ``fr_i``) and the outputs ``C z_k`` ``(B, R, N)`` and the states ``keep`` ``(B, R, N, K)``,
    compiled: O(nonzeros of F) per step and no O(N n) noise array, so a three-hour recording's six channels take
    seconds and little memory."""
    import numpy as np

    from .simulate_kernel import csr, simulate_batch

    F = ss.F.detach().cpu().numpy()
    B, R_, N, _ = xi.shape
    n = F.shape[-1]
    indptr, indices, fvals = csr(F)
    gptr, gcol, gvals = csr(ss.G.detach().cpu().numpy())
    C = np.ascontiguousarray(ss.C.detach().cpu().numpy())
    cidx = np.flatnonzero((C != 0).any(axis=0)).astype(np.int64)
    out = np.empty((B, R_, N))
    states = np.empty((B, R_, N, len(keep)))
    fr = np.ascontiguousarray(forcing.numpy()) if fr_i >= 0 else np.zeros((1, 1, 1))
    tv = varying_kernel_args(ss.varying, B, n)
    simulate_batch(indptr, indices, fvals, gptr, gcol, gvals, cidx, C, np.ascontiguousarray(z0.numpy()),
                   np.ascontiguousarray(xi.numpy()), out, states, np.asarray(keep, dtype=np.int64), int(fr_i), fr, *tv)
    return torch.from_numpy(out), torch.from_numpy(states)


def simulate_columns(model, *, n_steps: int, h: float, columns=("y",), values: dict | None = None, seed: int = 0,
                     temperature=(25.0, 3.0, 60.0, 0.2), memory="soe") -> tuple[dict, dict]:
    """The columns of one simulated recording of ``model`` — what ``torchtea simulate --model`` writes.

    One generator seeded ``seed`` draws the temperature (:func:`temperature_profile` with ``temperature`` = start °C,
    warm-up °C, its time constant s, wander sd °C) and then every column's series, each column its own parameter set
    (one batch, so a seed gives a column the same series whatever the other columns): the MEMS-like defaults
    (:func:`default_values`) with ``values[column]`` (``{name: value}``) on top. Returns the columns
    ``{"t", *columns, "temp"}`` (tensors ``(N,)``) and each column's parameter values."""
    model = parse_model(model)
    columns = list(columns)
    values = values or {}
    unknown = sorted(set(values) - set(columns))
    if unknown:
        raise ValueError(f"values for {', '.join(unknown)}: not among the columns {', '.join(columns)}")
    gen = torch.Generator().manual_seed(seed)
    start, warmup, tau_s, wander = temperature
    T = temperature_profile(n_steps, h, start=start, warmup=warmup, tau_s=tau_s, wander=wander, generator=gen)
    base = default_values(model, h, T)
    per = {}
    for c in columns:
        bad = sorted(set(values.get(c, {})) - set(base))
        if bad:
            raise ValueError(f"column {c}: {', '.join(bad)} not parameters of {model.spec} ({', '.join(base)})")
        per[c] = dict(base, **values.get(c, {}))
    batch = {k: [per[c][k] for c in columns] for k in base}
    y = simulate_model(model, batch, n_steps=n_steps, h=h, inputs={"temperature": T}, generator=gen,
                       memory=memory)[:, 0]
    t = torch.arange(n_steps, dtype=torch.float64) * h
    return {"t": t, **{c: y[i] for i, c in enumerate(columns)}, "temp": T}, per


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


# --------------------------------------------------------------------------- a simulated recording, as simulate writes it

#: What the truth file beside a simulated recording (``REC.truth.json``) holds.
TRUTH_MEANING = {
    "model": "the model simulated (its spec)",
    "values": "its parameter values: name → value for one column y, else column → {name → value}",
    "h": "the sample time (s)", "n": "the number of samples", "seed": "the generator's seed",
    "temperature_profile": "the temperature's T0,WARMUP,TAU_S,WANDER (°C, °C, s, °C): temperature_profile's arguments",
    "columns": "the simulated columns, in the file's order (beside t and temp)",
}


def parse_temperature_profile(text: str) -> tuple:
    """``"T0,WARMUP,TAU_S,WANDER"`` → four floats (:func:`temperature_profile`'s start, warm-up, time constant and
    wander); raises ``ValueError`` naming ``--temperature-profile`` otherwise."""
    try:
        profile = tuple(float(x) for x in text.split(","))
        if len(profile) != 4 or not all(math.isfinite(x) for x in profile):
            raise ValueError
    except ValueError:
        raise ValueError(f"--temperature-profile needs four numbers T0,WARMUP,TAU_S,WANDER, got {text!r}") from None
    return profile


def parse_sets(items, names, columns) -> dict:
    """The ``--set`` grammar: each item ``NAME=VALUE`` (every column) or ``COLUMN:NAME=VALUE`` (one), ``NAME`` one of
    the model's parameter ``names``, ``VALUE`` a finite number → ``{column: {name: value}}``. Raises ``ValueError``
    naming the item."""
    values: dict = {c: {} for c in columns}
    for item in items:
        target, sep, text = item.partition("=")
        col, colon, name = target.rpartition(":")
        if not sep or name not in names or (colon and col not in columns):
            raise ValueError(f"--set {item!r}: expected NAME=VALUE or COLUMN:NAME=VALUE with NAME one of "
                             f"{', '.join(names)} and COLUMN one of {', '.join(columns)}")
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not math.isfinite(value):
            raise ValueError(f"--set {item!r}: the value must be a finite number")
        for c in [col] if colon else columns:
            values[c][name] = value
    return values


def simulate_recording(model, out, *, n_steps: int, h: float, columns=("y",), sets=(), seed: int = 0,
                       temperature_profile: str = "25,3,60,0.2", memory="soe"):
    """Simulate a recording of ``model`` and write it — what ``torchtea simulate --model`` does: the columns
    (:func:`simulate_columns`: ``t``, each of ``columns``, ``temp``) to ``out`` and, beside it, the truth file
    ``out.truth.json`` (:data:`TRUTH_MEANING`). ``sets``: the ``--set`` items (:func:`parse_sets`) on top of the
    MEMS-like defaults. Returns ``(the recording's path, the truth file's path, the model)``; raises ``ValueError``
    naming a bad argument before anything is written."""
    import json
    from pathlib import Path

    from ..sensors.io import write_columns

    model = parse_model(model)
    profile = parse_temperature_profile(temperature_profile)
    columns = [c.strip() for c in columns]
    if not all(columns) or len(set(columns)) != len(columns) or any(c in ("t", "temp") for c in columns):
        raise ValueError(f"--columns {','.join(columns)!r}: distinct names, not t or temp")
    values = parse_sets(sets, model.names, columns)
    data, per = simulate_columns(model, n_steps=n_steps, h=h, columns=columns, values=values, seed=seed,
                                 temperature=profile, memory=memory)
    path = write_columns(out, data)
    truth = Path(str(path) + ".truth.json")
    doc = {"model": model.spec, "values": per[columns[0]] if columns == ["y"] else per, "h": h, "n": n_steps,
           "seed": seed, "temperature_profile": temperature_profile, "columns": columns}
    truth.write_text(json.dumps(doc, indent=1))
    return path, truth, model

"""Batched simulator of the A-type DFVOSS model, paper (9)–(11) and (43)–(45)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from ..core.gl import broadcast_shapes, gl_tail_coefficients
from ..core.memory import BoundedHistory, memory_plan
from .fast import fast_path_reason
from .structure import OrderSchedule, Structure

__all__ = ["Simulation", "simulate", "gaussian_input", "simulate_noise_model"]


@dataclass(frozen=True)
class Simulation:
    """A batch of simulated realisations; time is dimension ``-2``.

    Attributes
    ----------
    t : Tensor ``(N,)``; inputs ``u`` ``(*B, N, d)``; states ``x`` ``(*B, N, n)``;
    outputs ``y`` ``(*B, N, p)``; orders ``alpha`` ``(*B, N, n)``; the noise draws
    ``process_noise`` ω ``(*B, N, n)`` (ω_k drives x_{k+1}) and ``measurement_noise`` ν ``(*B, N, p)``.
    """

    t: Tensor
    u: Tensor
    x: Tensor
    y: Tensor
    alpha: Tensor
    process_noise: Tensor
    measurement_noise: Tensor


def _chol(cov, size: int, like: Tensor) -> Tensor:
    c = torch.as_tensor(cov, dtype=like.dtype, device=like.device)
    if c.ndim == 0:
        c = c * torch.eye(size, dtype=like.dtype, device=like.device)
    if c.shape[-2:] != (size, size):
        raise ValueError(f"covariance must be {size}x{size}, got {tuple(c.shape)}")
    if torch.all(c == 0):
        return c
    return torch.linalg.cholesky(c)


def gaussian_input(batch_shape, n_steps: int, n_inputs: int, std: float, *, generator=None,
                   dtype=torch.float64, device=None) -> Tensor:
    """Known input ``u_k ~ N(0, std²)`` of shape ``(*batch_shape, N, d)``."""
    z = torch.randn(tuple(batch_shape) + (n_steps, n_inputs), generator=generator, dtype=dtype, device=device)
    return std * z


def simulate(
    structure: Structure,
    *,
    n_steps: int,
    h: float,
    order: OrderSchedule,
    parameters,
    process_noise,
    measurement_noise,
    inputs: Tensor | None = None,
    x0=None,
    batch_shape=(),
    generator: torch.Generator | None = None,
    standard_draws: tuple[Tensor, Tensor] | None = None,
    memory="exact",
    dtype=torch.float64,
    device=None,
) -> Simulation:
    r"""Simulate realisations of paper (9)–(11).

    ``x_0 = x0`` (zero by default) and, for ``k = 0 … N−2``,
    ``x_{k+1} = h^{α_{k+1}} (A(w) x_k + B u_k + ω_k) − Σ_{j=1}^{k+1} c_j(α_{k+1}) x_{k+1−j}``,
    ``y_k = C x_k + ν_k`` with ``ω ~ N(0, Q)``, ``ν ~ N(0, R)``. The GL sums run over
    the whole history (exact).

    Parameters
    ----------
    structure : Structure
    n_steps : int
        ``N``, number of samples (including ``k = 0``).
    h : float
        Sample time.
    order : OrderSchedule
        True orders; evaluated to ``(*B, N, n)``.
    parameters : Tensor, shape ``(*B, m)`` or ``(m,)``
        True ``w``.
    process_noise, measurement_noise : float or Tensor ``(n, n)`` / ``(p, p)``
        ``Q`` and ``R``; a float means ``value · I``.
    inputs : Tensor, shape ``(*B, N, d)``, optional
        Known inputs (zero when absent).
    batch_shape : tuple
        Number of realisations; broadcast with the batch shapes of the other arguments.
    generator : torch.Generator, optional
        Source of all random draws (ω first, then ν).
    standard_draws : (Tensor ``(*B, N, n)``, Tensor ``(*B, N, p)``), optional
        Standard-normal draws to use instead of the generator (scaled by the
        Cholesky factors of Q and R) — for Monte Carlo studies whose realisation i
        must not depend on how the batch is chunked.
    memory : str or MemoryConfig
        How the GL sums see the past (:mod:`torchtea.core.memory`): ``"exact"`` (default, O(k) per step),
        ``"soe"``/``"soe:TOL"`` (exponential sums over the orders simulated, O(1) per step — for long
        series) or ``"window:L"``.

    Returns
    -------
    Simulation
    """
    if n_steps < 1:
        raise ValueError("n_steps must be >= 1")
    ref = torch.empty((), dtype=dtype, device=device)
    n, p, d = structure.n_states, structure.n_outputs, structure.n_inputs
    w = torch.as_tensor(parameters, dtype=dtype, device=device)
    if w.ndim == 0:
        w = w.reshape(1)
    alpha = order.values(n_steps, h, n, inputs).to(ref)
    shapes = [tuple(batch_shape), w.shape[:-1], alpha.shape[:-2]]
    if inputs is not None:
        inputs = torch.as_tensor(inputs).to(ref)
        if inputs.shape[-2:] != (n_steps, d):
            raise ValueError(f"inputs must have shape (*B, {n_steps}, {d}), got {tuple(inputs.shape)}")
        shapes.append(inputs.shape[:-2])
    batch = broadcast_shapes(*shapes)
    u = torch.zeros(batch + (n_steps, d), dtype=dtype, device=device) if inputs is None else inputs.expand(batch + (n_steps, d))
    alpha = alpha.expand(batch + (n_steps, n))
    A = structure.A(w).expand(batch + (n, n))
    B = structure.B.to(ref)
    C = structure.C.to(ref)
    Lq = _chol(process_noise, n, ref)
    Lr = _chol(measurement_noise, p, ref)
    if standard_draws is None:
        z_omega = torch.randn(batch + (n_steps, n), generator=generator, dtype=dtype, device=device)
        z_nu = torch.randn(batch + (n_steps, p), generator=generator, dtype=dtype, device=device)
    else:
        z_omega, z_nu = (torch.as_tensor(z).to(ref) for z in standard_draws)
        if z_omega.shape[-2:] != (n_steps, n) or z_nu.shape[-2:] != (n_steps, p):
            raise ValueError(f"standard_draws must have shapes (*B, {n_steps}, {n}) and (*B, {n_steps}, {p})")
        batch = broadcast_shapes(batch, z_omega.shape[:-2], z_nu.shape[:-2])
        u = u.expand(batch + (n_steps, d))
        alpha = alpha.expand(batch + (n_steps, n))
        A = A.expand(batch + (n, n))
    omega = z_omega.expand(batch + (n_steps, n)) @ Lq.mT
    nu = z_nu.expand(batch + (n_steps, p)) @ Lr.mT

    x = torch.empty(batch + (n_steps, n), dtype=dtype, device=device)
    x[..., 0, :] = 0.0 if x0 is None else torch.as_tensor(x0).to(ref)
    hpow = torch.as_tensor(h, dtype=dtype, device=device) ** alpha
    constant = bool(torch.all(alpha == alpha[..., :1, :]))
    # the one dispatch (core.memory): a soe kernel serves the simulated orders
    plan = memory_plan(memory, n_steps, (float(alpha.min()) - 0.01, float(alpha.max()) + 0.01))

    def drive(k):
        return (A @ x[..., k, :, None]).squeeze(-1) + u[..., k, :] @ B.mT + omega[..., k, :]

    if not plan.bounded:
        # Past states newest first: hist[..., i] = x_{k-i}; kept time-reversed so
        # that every step reads one contiguous slice (no flip copies).
        hist = torch.zeros(batch + (n, n_steps), dtype=dtype, device=device)
        hist[..., n_steps - 1] = x[..., 0, :]
        if constant:
            coeff_all = gl_tail_coefficients(alpha[..., 0, :], n_steps)  # (*B, n, N): c_1 … c_N
        for k in range(n_steps - 1):
            a = alpha[..., k + 1, :]
            past = hist[..., n_steps - 1 - k :]  # x_k … x_0, length k+1
            c = coeff_all[..., : k + 1] if constant else gl_tail_coefficients(a, k + 1)
            x[..., k + 1, :] = hpow[..., k + 1, :] * drive(k) - (c * past).sum(-1)
            hist[..., n_steps - 2 - k] = x[..., k + 1, :]
    else:
        kernel, decay, inject, lags, modes = plan.kernel, None, None, plan.x_lags, plan.n_modes
        if kernel is not None:
            _, _, decay, inject = kernel.tensors(dtype, device)
        coeff = weights = None
        if constant:
            coeff = gl_tail_coefficients(alpha[..., 0, :], lags).unsqueeze(-3)  # (*B, 1, n, J)
            if kernel is not None:  # the exponential sum's mode weights, once (issue 13)
                weights = kernel.weights(alpha[..., 0, :].unsqueeze(-2))
        grad = any(t.requires_grad for t in (w, alpha, omega, u, x))
        if lags >= 1 and fast_path_reason(structure, dtype, x.device, False, grad) is None:
            _simulate_compiled(x, hpow, w.expand(batch + (1,)), u, omega, alpha, constant, coeff, weights, kernel, lags)
        else:
            past = BoundedHistory.zeros(batch, n, lags, modes, dtype=dtype, device=device).push(x[..., 0, :], decay,
                                                                                                 inject)
            for k in range(n_steps - 1):
                a = alpha[..., k + 1, :]
                c = coeff if constant else gl_tail_coefficients(a, lags).unsqueeze(-3)
                memory_sum = past.sum(c, a.unsqueeze(-2), kernel, weights)[..., 0, :]
                x[..., k + 1, :] = hpow[..., k + 1, :] * drive(k) - memory_sum
                past = past.push(x[..., k + 1, :], decay, inject)
    y = x @ C.mT + nu
    t = torch.arange(n_steps, dtype=dtype, device=device) * h
    return Simulation(t=t, u=u, x=x, y=y, alpha=alpha, process_noise=omega, measurement_noise=nu)


def _simulate_compiled(x, hpow, w, u, omega, alpha, constant, coeff, weights, kernel, lags):
    """The bounded-memory loop of :func:`simulate` for the scalar structure on the CPU in float64, compiled
    (:func:`._fast_kernel.simulate_bounded`; ~50× the torch loop for 1000 × 3000 ``soe``). Fills ``x`` in place."""
    import numpy as np

    from ._fast_kernel import simulate_bounded
    from .fast import _lag_tables

    flat = lambda t: np.ascontiguousarray(t.reshape(-1, t.shape[-2]).numpy())  # (*B, N, 1) → (B, N)  # noqa: E731
    B = int(np.prod(x.shape[:-2], dtype=np.int64))
    xv = np.ascontiguousarray(x[..., 0].reshape(B, -1).numpy())
    if kernel is not None:
        ka, kb, decay, inject = (t.numpy() for t in kernel.tensors(torch.float64, torch.device("cpu")))
        eta, (klo, khi) = float(kernel.eta), (float(v) for v in kernel.order_range)
    else:
        ka = kb = decay = inject = np.zeros(0)
        eta, klo, khi = 1.0, -math.inf, math.inf
    M = decay.shape[0]
    cf = np.ascontiguousarray(coeff.reshape(B, lags).numpy()) if constant else np.zeros((B, lags))
    wt = np.ascontiguousarray(weights.reshape(B, M).numpy()) if constant and M else np.zeros((B, M))
    simulate_bounded(xv, flat(hpow), np.ascontiguousarray(w.reshape(B).numpy()), flat(u), flat(omega), flat(alpha),
                     bool(constant), cf, wt, int(lags), ka, kb, eta, klo, khi, decay, inject, *_lag_tables(lags))
    x.copy_(torch.from_numpy(xv).reshape(x.shape))


def simulate_noise_model(*, n_steps: int, h: float, order: OrderSchedule, param: float, q: float, r: float,
                         input_std: float | None = None, seed: int = 0, memory="exact", device=None) -> Simulation:
    """One realisation of the paper's scalar noise model (43)–(45) from one seed.

    The known input ``u ~ N(0, input_std²)`` is drawn first (none when ``input_std`` is None), then ω, then ν,
    all from ``torch.Generator().manual_seed(seed)`` — exactly what ``torchtea simulate --seed`` writes. On another
    ``device`` the draws are the same (made on the CPU) and the recursion runs there; the result stays there.
    """
    g = torch.Generator().manual_seed(seed)
    u = None if input_std is None else gaussian_input((), n_steps, 1, input_std, generator=g)
    # ω, then ν, drawn on the CPU in the order simulate draws them from a generator; the recursion on ``device``
    draws = tuple(torch.randn(n_steps, 1, generator=g, dtype=torch.float64).to(device) for _ in range(2))
    return simulate(Structure(), n_steps=n_steps, h=h, order=order, parameters=[param], process_noise=q,
                    measurement_noise=r, inputs=None if u is None else u.to(device), standard_draws=draws,
                    memory=memory, device=device)

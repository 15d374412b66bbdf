"""A batched damped-Newton minimiser: many independent small problems (axes × starts × bootstrap
replicates × profile points) solved in one batch, with exact autograd gradients and Hessians."""
from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

__all__ = ["NewtonResult", "newton"]


@dataclass(frozen=True)
class NewtonResult:
    """``u`` ``(B, P)`` minimisers, ``loss`` ``(B,)``, ``hessian`` ``(B, P, P)`` at ``u`` (free block; zero rows
    and columns for fixed parameters), ``converged`` ``(B,)`` bool, ``iterations``."""

    u: Tensor
    loss: Tensor
    hessian: Tensor
    converged: Tensor
    iterations: int


def _value_grad_hess(loss_fn, u: Tensor, free: Tensor, rows: Tensor):
    u = u.detach().requires_grad_(True)
    f = loss_fn(u, rows)
    g, = torch.autograd.grad(f.sum(), u, create_graph=True)
    P = u.shape[-1]
    # every row of the Hessian in one batched backward pass (vmap over the one-hot output gradients)
    eye = torch.eye(P, dtype=u.dtype)[free]  # (F, P): the free coordinates' rows
    seeds = eye.unsqueeze(1).expand(-1, u.shape[0], -1)  # (F, B, P)
    rows, = torch.autograd.grad(g, u, grad_outputs=seeds, is_grads_batched=True)
    H = u.new_zeros(u.shape[0], P, P)
    H[:, free] = rows.transpose(0, 1)
    fm = free.to(u.dtype)
    H = (H * fm.unsqueeze(-1) * fm.unsqueeze(-2)).detach()
    g = (g * fm).detach()
    f = f.detach()
    bad = ~(torch.isfinite(f) & torch.isfinite(g).all(-1) & torch.isfinite(H).flatten(1).all(-1))
    if bool(bad.any()):  # a row that left the finite region: freeze it (its loss is +inf)
        H = torch.where(bad.unsqueeze(-1).unsqueeze(-1), torch.eye(P, dtype=u.dtype), H)
        g = torch.where(bad.unsqueeze(-1), torch.zeros_like(g), g)
        f = torch.where(bad, torch.full_like(f, float("inf")), f)
    return f, g, H


def newton(loss_fn, u0: Tensor, free: Tensor | None = None, *, max_iter: int = 60, gtol: float = 1e-5,
           ftol: float = 1e-10, dtol: float = 1e-6) -> NewtonResult:
    """Minimise ``loss_fn(u, rows) → (len(rows),)`` from ``u0`` ``(B, P)``: the losses of problems ``rows``
    (indices into the batch) at their parameters ``u`` ``(len(rows), P)`` — row b's loss depends on its
    own parameters only, so each iteration evaluates only the problems not yet finished.

    Each iteration takes the Newton step on the Hessian with its eigenvalues made positive (|λ| + μ),
    μ a Levenberg damping that shrinks after an accepted step and grows after a rejected one. A row
    stops when its gradient's largest entry is below ``gtol`` or its loss changes by less than
    ``ftol · (1 + |loss|)`` or its Newton decrement ``½ gᵀH⁻¹g`` (the loss still to gain, where H is
    positive definite) is below ``dtol``. ``free`` ``(P,)`` bool: parameters held at ``u0`` where False.
    """
    u = u0.detach().clone()
    B, P = u.shape
    free = torch.ones(P, dtype=torch.bool) if free is None else free.to(torch.bool)
    mu = torch.full((B,), 1e-3, dtype=u.dtype)
    done = torch.zeros(B, dtype=torch.bool)
    f, g, H = _value_grad_hess(loss_fn, u, free, torch.arange(B))
    fixed_diag = (~free).to(u.dtype)
    it = 0
    for it in range(1, max_iter + 1):
        evals, evecs = torch.linalg.eigh(H + torch.diag(fixed_diag))
        proj = (evecs.mT @ g.unsqueeze(-1)).squeeze(-1)
        decrement = 0.5 * (proj * proj / evals.clamp(min=1e-300)).sum(-1)
        done = done | ((evals > 0).all(-1) & (decrement < dtol))
        if bool(done.all()):
            break
        evals = evals.abs() + mu.unsqueeze(-1)
        step = -(evecs @ ((evecs.mT @ g.unsqueeze(-1)) / evals.unsqueeze(-1))).squeeze(-1)
        step = step * free.to(u.dtype)
        # keep steps moderate in the unconstrained coordinates
        big = step.abs().amax(-1, keepdim=True).clamp(min=1e-300)
        step = torch.where(big > 3.0, step * 3.0 / big, step)
        step = torch.where(done.unsqueeze(-1), torch.zeros_like(step), step)
        active = (~done).nonzero().squeeze(-1)
        f_new = f.clone()
        with torch.no_grad():
            f_new[active] = loss_fn((u + step)[active], active)
        ok = torch.isfinite(f_new) & (f_new <= f) & ~done
        small = ok & ((f - f_new).abs() <= ftol * (1.0 + f.abs()))
        u = torch.where(ok.unsqueeze(-1), u + step, u)
        mu = torch.where(done, mu, torch.where(ok, mu / 4.0, mu * 8.0).clamp(1e-12, 1e12))  # a finished row keeps its μ
        moved = ok.nonzero().squeeze(-1)
        if moved.numel():
            f2, g2, H2 = _value_grad_hess(loss_fn, u[moved], free, moved)
            f[moved], g[moved], H[moved] = f2, g2, H2
        done = done | small | (g.abs().amax(-1) < gtol) | (mu >= 1e12)
        if bool(done.all()):
            break
    converged = done & (mu < 1e12) & torch.isfinite(f)
    return NewtonResult(u, f, H, converged, it)

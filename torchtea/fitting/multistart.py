"""The exact fit's multi-start (:func:`exact_multistart`): the exact likelihood maximised from the Whittle fit's modes
and, where the model has a free fractional order, from the Whittle grid's starts too — the Whittle sum and the exact
likelihood need not share their modes on the order–pole ridge of a short record."""
from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

from . import scoring
from .exact import exact_loglik, gradient_supported

__all__ = ["exact_multistart", "EXACT_MODE_MARGIN", "GRID_GAIN"]


#: The exact fit's multi-start refines every Whittle mode whose exact ℓ at the Whittle optimum is within this many
#: nats of the best one's (at most :data:`~.mle.MAX_MODES`), and keeps the highest exact maximum.
EXACT_MODE_MARGIN = 10.0


#: A maximum reached from the grid replaces the best reached from the Whittle modes only where it is higher by more
#: than this (nats): the same maximum reached twice differs by the convergence tolerance.
GRID_GAIN = 0.01


def exact_multistart(model, y, h, modes: list, free: Tensor, inputs, memory, hessian: bool, grid: Tensor | None = None):
    """:func:`~.scoring.exact_refine` from the Whittle ``modes`` (``(u, ℓ_W, H_W)`` each) whose exact ℓ is within
    :data:`EXACT_MODE_MARGIN` of the best; the best exact maximum, with its Hessian when ``hessian``. ``grid``
    ``(k, P)``: the Whittle fit's grid of starts, also refined where the
    model's fractional order is free and the exact gradient applies — on a short record the exact likelihood's
    order–pole ridge can hold a higher maximum than any the Whittle sum leads to —, as a batch of their own (the modes
    run as without them), their best kept where higher than the modes' by :data:`GRID_GAIN`. Returns ``(u, ℓ, H or None,
    converged, notes)``."""
    notes = []
    if len(modes) > 1:
        U = torch.stack([m[0] for m in modes])
        ll0 = exact_loglik(model, model.from_unconstrained(U, h), y, h, inputs=inputs, memory=memory)
        ll0 = np.where(np.isfinite(ll0), ll0, -np.inf)
        order = [int(i) for i in np.argsort(-ll0) if ll0[i] >= ll0.max() - EXACT_MODE_MARGIN]
        modes = [modes[i] for i in order]
    batched = gradient_supported(model, y) is None
    name = model.order_name
    if grid is not None and (not batched or name is None or not bool(free[model.names.index(name)])):
        grid = None
    if len(modes) == 1 or not batched:
        runs = [scoring.exact_refine(model, y, h, m[0].clone(), free, inputs, memory, m[2], hessian=False) for m in modes]
    else:  # every mode's scoring iterations as one batch
        runs = _batch(model, y, h, torch.stack([m[0] for m in modes]), free, inputs, memory)
    U0 = torch.stack([r[0] for r in runs])
    if grid is not None:  # the grid's starts as a batch of their own (racing the modes would cut a mode short)
        G = grid.clone().to(U0)
        G[:, ~free] = U0[0, ~free]  # (the held coordinates are the modes')
        runs += _batch(model, y, h, G, free, inputs, memory)
        U0 = torch.cat([U0, G])

    def top(rows):
        return max(rows, key=lambda i: runs[i][1] if math.isfinite(runs[i][1]) else -math.inf)

    best = top(range(len(modes)))
    if len(runs) > len(modes):  # a grid start's maximum only where it is higher by more than rounding
        other = top(range(len(modes), len(runs)))
        best = other if runs[other][1] > runs[best][1] + GRID_GAIN else best
    u, ll, _, ok, _ = runs[best]
    if best >= len(modes):
        a0 = float(model.from_unconstrained(U0[best][None], h)[name][0])
        notes.append(f"the exact likelihood's best maximum (ℓ {ll:.2f}) came from the start at order {a0:.1f} of the "
                     f"grid, not from the Whittle fit's modes (the best of those ℓ {max(r[1] for r in runs[:len(modes)]):.2f})")
    elif best != 0:
        notes.append(f"the exact likelihood's best maximum (ℓ {ll:.2f}) came from the Whittle fit's mode number "
                     f"{best + 1} of {len(modes)}, not from its best one (exact ℓ there {runs[0][1]:.2f})")
    H = scoring.exact_hessian(model, y, h, u, free, inputs, memory) if hessian else None
    return u, ll, H, ok, notes


def _batch(model, y, h, U0: Tensor, free: Tensor, inputs, memory) -> list:
    """The starts ``U0`` scored as one batch (:func:`~.scoring.score_batch`): per start ``(u, ℓ, None, converged,
    iterations)``."""
    X, f, ok, its = scoring.score_batch(model, y, h, U0, free, inputs, memory)
    runs = []
    for k in range(len(U0)):
        u = U0[k].clone()
        u[free] = torch.as_tensor(X[k])
        runs.append((u, -float(f[k]), None, bool(ok[k]), int(its[k])))
    return runs

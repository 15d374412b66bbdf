"""Grünwald–Letnikov (GL) coefficients and fractional variable-order differences.

Conventions (see :mod:`torchtea` for the package-wide batch convention):

* ``order`` tensors may have any shape; coefficients gain one trailing lag
  dimension ``j = 0 … n``.
* Series functions (:func:`difference`) take time as the **last** dimension,
  ``x`` of shape ``(*batch, N)``, and an order sequence broadcastable to it.

References
----------
Paper: Macias, Sierociuk & Malesza, *Sensors* 2022, 22, 527, eqs. (1)–(2).
Variable-order types A, B, D, E: Sierociuk, Malesza & Macias, *Appl. Math.
Model.* 39 (2015) 3876 and *Circuits Syst. Signal Process.* 34 (2015) 1077.
"""
from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["gl_coefficients", "gl_tail_coefficients", "difference", "history_sum", "KINDS", "lag_constants"]

KINDS = ("A", "B", "D", "E")


_LAG_CACHE: dict = {}


def broadcast_shapes(*shapes) -> torch.Size:
    """:func:`torch.broadcast_shapes` by numpy's rule (the same rule): torch's first call imports its symbolic-shape
    machinery (sympy, ~0.8 s of a command's start-up)."""
    import numpy as np

    return torch.Size(np.broadcast_shapes(*(tuple(int(d) for d in s) for s in shapes)))


def lag_constants(n: int, dtype, device):
    """``(1 − 1/j, −1/j)`` for ``j = 1 … n``, cached per dtype and device (sliced from the longest built)."""
    key = (dtype, str(device))
    cached = _LAG_CACHE.get(key)
    if cached is None or cached[0].shape[0] < n:
        size = max(n, 1024 if cached is None else 2 * cached[0].shape[0])
        j = torch.arange(1, size + 1, dtype=dtype, device=device)
        cached = (1.0 - 1.0 / j, -1.0 / j)
        _LAG_CACHE[key] = cached
    return cached[0][:n], cached[1][:n]


#: Devices where :func:`gl_tail_coefficients` scans along the last dimension (elsewhere along the first).
INNER_SCAN_DEVICES = {"cpu"}


def gl_tail_coefficients(order: Tensor, n: int) -> Tensor:
    r"""GL coefficients without the leading ``c_0 = 1``: ``c_1 … c_n``, shape ``(*S, n)``.

    The recursion factor is written :math:`1 - (1+\alpha)/j = (1 - 1/j) + \alpha\,(-1/j)`, one fused
    multiply-add per lag, followed by one cumulative product.
    """
    order = torch.as_tensor(order)
    if not order.is_floating_point():
        order = order.to(torch.get_default_dtype())
    if n < 0:
        raise ValueError(f"n must be >= 0, got {n}")
    a, b = lag_constants(n, order.dtype, order.device)
    factors = torch.addcmul(a, order.unsqueeze(-1), b)
    if order.device.type not in INNER_SCAN_DEVICES and order.dim() > 0:
        # a GPU's scan along the innermost dimension is slow for short rows over a wide batch (1.3 ms for
        # 9 lags × 3·10⁵ rows on an H100); along the outer dimension it is one pass: the same products
        return torch.cumprod(factors.movedim(-1, 0), dim=0).movedim(0, -1)
    return torch.cumprod(factors, dim=-1)


def gl_coefficients(order: Tensor, n: int) -> Tensor:
    r"""GL coefficients :math:`c_j(\alpha) = (-1)^j \binom{\alpha}{j}`, ``j = 0 … n``.

    Computed with the stable recursion :math:`c_j = c_{j-1}(1 - (1+\alpha)/j)`
    (ALGORITHMS.md §1), as one cumulative product over the lag dimension.

    Parameters
    ----------
    order : Tensor, shape ``(*S)``
        Orders α, any real values, any shape.
    n : int
        Largest lag.

    Returns
    -------
    Tensor, shape ``(*S, n + 1)``
        ``out[..., j] = c_j(order)``; ``out[..., 0] = 1``.
    """
    tail = gl_tail_coefficients(order, n)
    ones = torch.ones(tail.shape[:-1] + (1,), dtype=tail.dtype, device=tail.device)
    return torch.cat([ones, tail], dim=-1)


def history_sum(order: Tensor, history: Tensor) -> Tensor:
    r"""Exact GL history sum :math:`\sum_{j=1}^{k} c_j(\alpha) x_{k-j}` for many orders at once.

    This is the memory term of the A-type model (paper (10), (17), (30)).

    Parameters
    ----------
    order : Tensor, shape ``(*B, S, n)``
        ``S`` candidate orders (sigma points) for each of ``n`` states.
    history : Tensor, shape ``(*B, n, k)``
        Past values newest first: ``history[..., i] = x_{k-1-i}``.

    Returns
    -------
    Tensor, shape ``(*B, S, n)``
    """
    k = history.shape[-1]
    if k == 0:
        return torch.zeros_like(order)
    c = gl_tail_coefficients(order, k)  # (*B, S, n, k)
    # (*B, n, S, k) @ (*B, n, k, 1) -> (*B, n, S, 1)
    out = torch.matmul(c.transpose(-3, -2), history.unsqueeze(-1)).squeeze(-1)
    return out.transpose(-1, -2)


def difference(x: Tensor, order: Tensor, h: float, kind: str = "A") -> Tensor:
    r"""Fractional variable-order difference of a series, exact full-history sums.

    With orders :math:`\alpha_k` and sample time ``h`` (ALGORITHMS.md §2):

    * A: :math:`h^{-\alpha_k}\sum_{j=0}^{k} c_j(\alpha_k) x_{k-j}` — paper (2);
    * B: :math:`\sum_{j=0}^{k} h^{-\alpha_{k-j}} c_j(\alpha_{k-j}) x_{k-j}`;
    * D: :math:`y_k = h^{-\alpha_k}x_k - \sum_{j=1}^{k} c_j(-\alpha_k) y_{k-j}`;
    * E: :math:`y_k = h^{-\alpha_k}x_k - \sum_{j=1}^{k} (h^{\alpha_{k-j}}/h^{\alpha_k}) c_j(-\alpha_{k-j}) y_{k-j}`.

    A negative order gives the matching fractional sum; A(−α)∘D(α) and
    B(−α)∘E(α) are identities.

    Parameters
    ----------
    x : Tensor, shape ``(*B, N)``
        Series, time last.
    order : Tensor, broadcastable to ``(*B, N)``
        Order at each time step (a scalar for constant order).
    h : float
        Sample time.
    kind : {"A", "B", "D", "E"}

    Returns
    -------
    Tensor, shape ``(*B, N)``
    """
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {KINDS}, got {kind!r}")
    x = torch.as_tensor(x)
    order = torch.as_tensor(order, dtype=x.dtype, device=x.device)
    shape = broadcast_shapes(x.shape, order.shape)
    x = x.expand(shape)
    order = order.expand(shape)
    n = shape[-1]
    hpow = torch.as_tensor(h, dtype=x.dtype, device=x.device) ** order  # h^{α_k}
    out = torch.empty(shape, dtype=x.dtype, device=x.device)
    if kind in ("A", "B"):
        coeff = gl_coefficients(order, n - 1)  # (*B, N, N): [t, j] = c_j(α_t)
        if kind == "B":
            coeff = coeff / hpow.unsqueeze(-1)
        for k in range(n):
            past = x[..., : k + 1].flip(-1)  # x_k, x_{k-1}, …, x_0
            if kind == "A":
                out[..., k] = (coeff[..., k, : k + 1] * past).sum(-1) / hpow[..., k]
            else:
                # term j uses the order of time k - j
                rows = coeff[..., : k + 1, :].flip(-2)  # row i is time k - i
                diag = torch.diagonal(rows[..., : k + 1, : k + 1], dim1=-2, dim2=-1)
                out[..., k] = (diag * past).sum(-1)
        return out
    coeff = gl_coefficients(-order, n - 1)  # [t, j] = c_j(-α_t)
    for k in range(n):
        if kind == "D":
            mem = (coeff[..., k, 1 : k + 1] * out[..., :k].flip(-1)).sum(-1)
            out[..., k] = x[..., k] / hpow[..., k] - mem
        else:
            past_rows = coeff[..., :k, :].flip(-2)  # row i-1 is time k - i
            idx = torch.arange(1, k + 1, device=x.device)
            cj = past_rows[..., idx - 1, idx] if k > 0 else out[..., :0]
            w = hpow[..., :k].flip(-1) / hpow[..., k : k + 1]
            mem = (w * cj * out[..., :k].flip(-1)).sum(-1)
            out[..., k] = x[..., k] / hpow[..., k] - mem
    return out

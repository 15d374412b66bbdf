"""A TEA's settings as tensors (:class:`TEAParams`, :func:`make_params`): each filter's prior, drive and noise shaped
for a :class:`~.structure.Structure`, a drive's cap, several configurations stacked into one batch
(:func:`stack_params`)."""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace
from typing import NamedTuple

import torch
from torch import Tensor

from .settings import TEAConfig
from .structure import Structure

__all__ = ["TEAParams", "make_params", "stack_params", "q_cap"]


def _mat(value, size: int, like: Tensor, name: str) -> Tensor:
    t = torch.as_tensor(value, dtype=like.dtype, device=like.device)
    eye = torch.eye(size, dtype=like.dtype, device=like.device)
    if t.ndim == 0:
        return t * eye
    if t.ndim == 1:
        if t.shape[0] != size:
            raise ValueError(f"{name}: expected {size} diagonal entries, got {t.shape[0]}")
        return torch.diag(t)
    if t.shape[-2:] != (size, size):
        raise ValueError(f"{name}: expected a {size}x{size} matrix, got {tuple(t.shape)}")
    return t


def _vec(value, size: int, like: Tensor, name: str) -> Tensor:
    t = torch.as_tensor(value, dtype=like.dtype, device=like.device)
    if t.ndim == 0:
        return t.expand(size).clone()
    if t.shape[-1] != size:
        raise ValueError(f"{name}: expected {size} entries, got {tuple(t.shape)}")
    return t


class TEAParams(NamedTuple):
    """Tensor form of a :class:`TEAConfig` for one :class:`Structure`.

    Tensor fields have a leading batch shape (possibly empty) that broadcasts
    with the data; :func:`stack_params` stacks configs of e.g. three axes.
    """

    x0: Tensor  # (*B, n)
    P0: Tensor  # (*B, n, n)
    Q: Tensor  # (*B, n, n)
    R: Tensor  # (*B, p, p)
    alpha0: Tensor  # (*B, L)
    P0o: Tensor  # (*B, L, L)
    Q0o: Tensor  # (*B, L, L)
    Ro: Tensor  # (*B, p, p)
    w0: Tensor  # (*B, m)
    P0w: Tensor  # (*B, m, m)
    Q0w: Tensor  # (*B, m, m)
    Rw: Tensor  # (*B, p, p)
    Qmax_o: Tensor  # (*B,), +inf for no cap
    Qmax_w: Tensor  # (*B,)
    config: TEAConfig


def make_params(config: TEAConfig, structure: Structure, *, dtype=torch.float64, device=None) -> TEAParams:
    """Turn a config into tensors shaped for ``structure``."""
    like = torch.empty((), dtype=dtype, device=device)
    n, p, L, m = structure.n_states, structure.n_outputs, structure.n_estimated_orders, structure.n_params
    x, o, w = config.kfx, config.kfo, config.kfw
    Q0o, Q0w = _mat(o.Q0, L, like, "kfo.Q0"), _mat(w.Q0, m, like, "kfw.Q0")
    return TEAParams(
        x0=_vec(x.x0, n, like, "kfx.x0"), P0=_mat(x.P0, n, like, "kfx.P0"),
        Q=_mat(x.Q0, n, like, "kfx.Q0"), R=_mat(x.R, p, like, "kfx.R"),
        alpha0=_vec(o.x0, L, like, "kfo.x0"), P0o=_mat(o.P0, L, like, "kfo.P0"),
        Q0o=Q0o, Ro=_r(o, p, like, "kfo.R"),
        w0=_vec(w.x0, m, like, "kfw.x0"), P0w=_mat(w.P0, m, like, "kfw.P0"),
        Q0w=Q0w, Rw=_r(w, p, like, "kfw.R"),
        Qmax_o=q_cap(o.Q_max, Q0o, like),
        Qmax_w=q_cap(w.Q_max, Q0w, like),
        config=config,
    )


def _r(f, size: int, like: Tensor, name: str) -> Tensor:
    """KFo's or KFw's R (``f`` its :class:`UnscentedConfig`) as a matrix; NaN for ``"innovation"`` (the step takes
    ``Carry.S`` then, never this)."""
    if f.uses_innovation:
        return torch.full((size, size), math.nan, dtype=like.dtype, device=like.device)
    return _mat(f.R, size, like, name)


def q_cap(q_max, Q0: Tensor, like: Tensor) -> Tensor:
    if q_max == "none":
        return torch.tensor(math.inf, dtype=like.dtype, device=like.device)
    if q_max == "Q0":
        return torch.diagonal(Q0, dim1=-2, dim2=-1).amax(-1)
    return torch.tensor(float(q_max), dtype=like.dtype, device=like.device)


def stack_params(params: Sequence[TEAParams]) -> TEAParams:
    """Stack parameter sets (e.g. one per axis) along a new leading batch dimension.

    The non-tensor settings (UT constants, δ, options) must agree.
    """
    params = list(params)
    if not params:
        raise ValueError("nothing to stack")
    first = params[0].config

    def strip(c: TEAConfig):
        keep = lambda f: replace(f, x0=0, P0=0, Q0=0, R=0)  # noqa: E731
        # KFo's and KFw's: the cap's kind and whether R is "innovation" must agree, not their numbers
        cap = lambda f: replace(keep(f), Q_max=1.0 if f.Q_max != "none" else "none",  # noqa: E731
                                R=f.R if f.uses_innovation else 0)
        return replace(c, kfx=keep(c.kfx), kfo=cap(c.kfo), kfw=cap(c.kfw))

    for p in params[1:]:
        if strip(p.config) != strip(first):
            raise ValueError("stacked configs may differ only in x0, P0, Q0, R and the Q cap")
    tensors = [torch.stack([getattr(p, name) for p in params]) for name in TEAParams._fields[:-1]]
    return TEAParams(*tensors, config=first)

"""What :func:`~.tea.run_tea` does around its loop: its arguments checked and broadcast to one batch
(:func:`_batched`), the outputs stored at every ``record_every``-th step (:func:`_recorder`), the result of the steps
that completed (:func:`_result`)."""
from __future__ import annotations

import torch

from ..core.gl import broadcast_shapes
from .params import TEAParams
from .results import STEP_OUTPUTS, TEAResult
from .structure import Structure


def _batched(y, params: TEAParams, inputs, structure: Structure, record_every):
    """:func:`run_tea`'s arguments checked and broadcast to one batch: ``y`` ``(*batch, N, p)`` (float64 unless
    floating already), ``params`` on its dtype and device, ``inputs`` ``(*batch, N, d)`` or None, the batch shape and
    the recording stride; ``ValueError`` for a shape or a stride that does not fit."""
    y = torch.as_tensor(y)
    if not y.is_floating_point():
        y = y.to(torch.float64)
    dtype, device = y.dtype, y.device
    p = structure.n_outputs
    if y.ndim < 2 or y.shape[-1] != p:
        raise ValueError(f"y must have shape (*B, N, {p}), got {tuple(y.shape)}")
    if int(record_every) < 1:
        raise ValueError(f"record_every must be >= 1, got {record_every}")
    N = y.shape[-2]
    params = TEAParams(*[t.to(device=device, dtype=dtype) for t in params[:-1]], config=params.config)
    shapes = [y.shape[:-2], params.x0.shape[:-1], params.R.shape[:-2], params.Ro.shape[:-2], params.Rw.shape[:-2],
              params.alpha0.shape[:-1], params.w0.shape[:-1], params.P0.shape[:-2], params.Q.shape[:-2],
              params.Qmax_o.shape, params.Qmax_w.shape]
    if inputs is not None:
        inputs = torch.as_tensor(inputs, dtype=dtype, device=device)
        if inputs.shape[-2:] != (N, structure.n_inputs):
            raise ValueError(f"inputs must have shape (*B, {N}, {structure.n_inputs}), got {tuple(inputs.shape)}")
        shapes.append(inputs.shape[:-2])
    batch = broadcast_shapes(*shapes)
    y = y.expand(batch + (N, p))
    if inputs is not None:
        inputs = inputs.expand(batch + (N, structure.n_inputs))
    return y, params, inputs, batch, int(record_every)


def _recorder(out: dict, every: int, nb: int, device):
    """``record_block(k0, tensors, stacked)``: stores the outputs of steps k0 … (one step, or a block stacked along
    dim ``nb``) in the preallocated ``out`` at the rows of every ``every``-th step."""

    def record_block(k0: int, tensors, stacked: bool):
        if not stacked:
            if k0 % every == 0:
                for name, t in zip(STEP_OUTPUTS, tensors):
                    out[name].select(nb, k0 // every).copy_(t)
            return
        T = tensors[0].shape[nb]
        first = (-k0) % every  # offset of the first stored step in the block
        if first >= T:
            return
        rows = torch.arange(first, T, every, device=device)
        i0 = (k0 + first) // every
        for name, t in zip(STEP_OUTPUTS, tensors):
            out[name].narrow(nb, i0, rows.shape[0]).copy_(t.index_select(nb, rows))
    return record_block


def _result(out: dict, completed: int, every: int, nb: int, N: int, diverged_at, clamped, memory, device) -> TEAResult:
    """The :class:`TEAResult` of the ``completed`` steps (the stored rows cut to them; interrupted when fewer than
    ``N``)."""
    rows = (completed - 1) // every + 1
    n_out = (N - 1) // every + 1
    if rows < n_out:
        out = {name: t.narrow(nb, 0, rows) for name, t in out.items()}
    diverged = (diverged_at >= 0) & (diverged_at < completed)
    return TEAResult(**out, diverged=diverged, diverged_at=torch.where(diverged, diverged_at, -1),
                     steps=torch.arange(0, completed, every, device=device),
                     memory_clamped=clamped if memory.bounded and memory.kernel is not None else None,
                     interrupted=completed < N)

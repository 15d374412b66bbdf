"""The sensor's filters: a first-order low-pass and its digital-filter variant."""
from __future__ import annotations

import math

import torch
from torch import Tensor

from .base import FilterEffect, ParamSpec


class LowPass(FilterEffect):
    r"""First-order low-pass :math:`l_k = a l_{k-1} + (1-a) s_k`, :math:`a = e^{-2\pi f_c h}`, of the stochastic
    components before it, :math:`s_k` their sum (the sensor's digital filter), started from rest before the first
    sample. Multiplies their spectra by :math:`(1-a)^2/(1 - 2a\cos\omega + a^2)`."""

    name = "low-pass"
    params = (ParamSpec("cutoff_hz", "positive", "f_c (Hz)"),)

    def gain(self, v, omega, h):
        a = self.coefficient(v, h).unsqueeze(-1)
        return ((1.0 - a) ** 2 / (1.0 - 2.0 * a * torch.cos(omega) + a * a)) ** self.stages

    def gain_derivatives(self, v, omega, h) -> tuple[Tensor, Tensor]:
        r""":meth:`gain` ``(B, W)`` and its derivative with respect to the cut-off ``(B, 1, W)``: with
        :math:`a = e^{-2\pi f_c h}`, :math:`\partial_a \log G = m(-2/(1-a) - 2(a - \cos\omega)/(1 - 2a\cos\omega +
        a^2))` for m stages and :math:`\partial_{f_c} a = -2\pi h a`."""
        a = self.coefficient(v, h).unsqueeze(-1)
        co = torch.cos(omega)
        den = 1.0 - 2.0 * a * co + a * a
        G = ((1.0 - a) ** 2 / den) ** self.stages
        dlog_a = self.stages * (-2.0 / (1.0 - a) - 2.0 * (a - co) / den)
        return G, (G * dlog_a * (-2.0 * math.pi * h * a)).unsqueeze(1)

    def coefficient(self, v, h):
        return torch.exp(-2.0 * math.pi * v["cutoff_hz"] * h)

    def filter_block(self, v, h) -> tuple[Tensor, Tensor]:
        r"""The filter as the state space the model's assembly stacks after the components it filters:
        :math:`x_{k+1} = A x_k + b\, u_{k+1}` with ``u`` its input (the sum of what it filters) and its output the
        last state; ``A`` ``(B, m, m)``, ``b`` ``(B, m)``, ``m`` = :attr:`stages`. Stage j filters stage j − 1:
        :math:`x^{(j)}_{k+1} = a x^{(j)}_k + (1-a) x^{(j-1)}_{k+1}`, so A's row j is (1 − a) × row j − 1 plus a on
        the diagonal and :math:`b_j = (1-a)^{j+1}`."""
        a = self.coefficient(v, h)
        B, m = a.shape[0], self.stages
        eye = torch.eye(m, dtype=a.dtype)
        rows, bs = [], [1.0 - a]
        for j in range(m):  # rows built anew, not written in place, so that the assembly has derivatives
            before = (1.0 - a).unsqueeze(-1) * rows[-1] if rows else a.new_zeros(B, m)
            rows.append(before + a.unsqueeze(-1) * eye[j])
            if j:
                bs.append((1.0 - a) * bs[-1])
        return torch.stack(rows, dim=1), torch.stack(bs, dim=1)

    def typical(self, param, h, t_ref):
        return 5.0


class DigitalFilter(LowPass):
    r"""A sensor's digital low-pass of second order: two first-order stages in cascade, each
    :math:`l_k = a l_{k-1} + (1-a) u_k` with :math:`a = e^{-2\pi f_c h}` (the critically damped second-order
    filter, both poles at a), of everything before it, white noise included, started from rest before the first
    sample. MEMS parts filter in two or more stages (a decimation filter after the converter, then the
    user-selected DLPF), and a cascade falls off twice as fast above its cut-off as one stage:
    :math:`|H(\omega)|^2 = \big((1-a)^2/(1 - 2a\cos\omega + a^2)\big)^2`, −12 dB per octave well above f_c. Its
    half-power frequency is ≈ 0.64 f_c (:math:`\sqrt{\sqrt2 - 1}` f_c for the continuous-time cascade), so a DLPF
    specified as "21 Hz bandwidth" is a cut-off f_c near 33 Hz here. One filter per model: it and ``low-pass``
    exclude each other."""

    name = "digital-filter"
    stages = 2
    params = (ParamSpec("cutoff_hz", "positive", "f_c (Hz), each of the two stages"),)

    def typical(self, param, h, t_ref):
        return 8.0

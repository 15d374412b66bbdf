"""The paper's fractional-order noise (its (43)–(45)): a Grünwald–Letnikov state of order α."""
from __future__ import annotations

import math

import torch
from torch import Tensor

from ...core import forward
from ...core.gl import gl_tail_coefficients
from .base import ORDER_BOUNDS, FractionalState, ParamSpec


class Fractional(FractionalState):
    r"""The paper's (43)–(45): :math:`x_{k+1} = h^{\alpha}(f x_k + \omega_k) - \sum_{j\ge1} c_j(\alpha) x_{k+1-j}`,
    ω ~ N(0, q), zero history before ``x_0 = 0``. Spectrum (ALGORITHMS.md §5)
    :math:`S(\omega) = q h^{2\alpha} / (2\pi |(1-e^{-i\omega})^\alpha - f h^\alpha e^{-i\omega}|^2)`."""

    name = "fractional"
    order_param = "order"
    #: order 1 with its pole at 0 is a random walk, order 1 with a pole a first-order Gauss–Markov bias (at order 0
    #: it is white noise: dropping it beside a white component)

    def check_fixed(self, label, fixed):
        if f"{label}.pole" in fixed and f"{label}.order" not in fixed:
            raise ValueError(f"{label}.pole cannot be fixed while {label}.order is free: the pole is fitted as a "
                             "fraction of its stability limit −2^α/h^α, which moves with the order; fix the order "
                             "too, or leave the pole free")
    params = (ParamSpec("order", "bounded", "α (dimensionless)", ORDER_BOUNDS),
              ParamSpec("pole", "fraction", "f (1/s^α), stable for −2^α < f h^α < 0"),
              ParamSpec("q", "positive", "drive variance (units²)"))

    def spectrum(self, v, omega, h):
        alpha, f, q = v["order"].unsqueeze(-1), v["pole"].unsqueeze(-1), v["q"].unsqueeze(-1)
        a = f * h ** alpha
        # |(1 − e^{−iω})^α − a e^{−iω}|²: 1 − e^{−iω} = 2 sin(ω/2) e^{i(π−ω)/2}
        mag = (2.0 * torch.sin(omega / 2.0)) ** alpha
        phase = alpha * (math.pi - omega) / 2.0
        re = mag * torch.cos(phase) - a * torch.cos(omega)
        im = mag * torch.sin(phase) + a * torch.sin(omega)
        return q * h ** (2.0 * alpha) / (2.0 * math.pi * (re * re + im * im))

    def spectrum_derivatives(self, v, omega, h):
        r"""With :math:`D = |(1-e^{-i\omega})^\alpha - a e^{-i\omega}|^2`, :math:`a = f h^\alpha` and
        :math:`\log S = \log q + 2\alpha\log h - \log 2\pi - \log D`: :math:`\partial_q S = S/q`,
        :math:`\partial_f S = -S\,\partial_f D/D`, :math:`\partial_\alpha S = S(2\log h - \partial_\alpha D/D)`, where
        the real and imaginary parts of the difference move with α through its magnitude
        :math:`(2\sin\tfrac\omega2)^\alpha`, its phase :math:`\alpha(\pi-\omega)/2` and :math:`a`."""
        alpha, f, q = v["order"].unsqueeze(-1), v["pole"].unsqueeze(-1), v["q"].unsqueeze(-1)
        hp = h ** alpha
        a = f * hp
        base = 2.0 * torch.sin(omega / 2.0)
        mag = base ** alpha
        turn = (math.pi - omega) / 2.0
        phase = alpha * (math.pi - omega) / 2.0
        cph, sph, co, so = torch.cos(phase), torch.sin(phase), torch.cos(omega), torch.sin(omega)
        re = mag * cph - a * co
        im = mag * sph + a * so
        D = re * re + im * im
        S = q * h ** (2.0 * alpha) / (2.0 * math.pi * D)
        lh, lb = math.log(h), torch.log(base)
        dre = mag * (lb * cph - turn * sph) - a * lh * co
        dim = mag * (lb * sph + turn * cph) + a * lh * so
        d_alpha = S * (2.0 * lh - 2.0 * (re * dre + im * dim) / D)
        d_pole = -S * 2.0 * hp * (im * so - re * co) / D
        return S, torch.stack([d_alpha, d_pole, S / q], dim=1)

    def first_row(self, v: dict, alpha: Tensor, h: float, memory) -> tuple[Tensor, Tensor]:
        """The block's first row of F, ``(*S, J + M)``, and its noise loading ``h^α √q`` ``(*S,)`` for orders
        ``alpha`` ``(*S,)`` (the only part of the block that depends on the order, so a time-varying order
        changes this row alone); ``v``'s ``pole`` and ``q`` broadcast against ``alpha``."""
        f, q = v["pole"], v["q"]
        J, M = memory.lags, memory.n_modes
        hp = h ** alpha
        c = gl_tail_coefficients(alpha.reshape(-1), J).reshape(*alpha.shape, J)  # c_1 … c_J
        row = torch.cat([-c, -memory.kernel.weights(alpha)], dim=-1) if M else -c
        row[..., 0] = row[..., 0] + hp * f
        return row, hp * torch.sqrt(q)

    def typical(self, param, h, t_ref):
        a = 0.3  # the Monte Carlo studies' part: order 0.3, pole at 40 % of its stability limit, q = r / h^{2α}
        return {"order": a, "pole": -0.4 * 2 ** a / h ** a, "q": 1e-3 / h ** (2 * a)}[param]


    def run_exact(self, v: dict, alpha: Tensor, h: float, xi: Tensor, forcing: Tensor | None = None,
                  x0: Tensor | None = None) -> Tensor:
        r"""The state over the whole past (exact memory, O(k) per step, any length): for ``k = 0 … N−2``
        :math:`x_{k+1} = h^{\alpha_{k+1}}(f x_k + u_k + \sqrt{q}\,\xi_k) - \sum_{j=1}^{k+1} c_j(\alpha_{k+1}) x_{k+1-j}`,
        ``x_0 = x0`` (zero by default) — the block's recursion with its history uncut, for the simulator (the state
        space's ``exact`` memory holds the same past as states). ``alpha`` ``(S, N)`` the order of each step (a known
        trajectory, or a constant), ``xi`` ``(S, N)`` standard-normal drive, ``forcing`` ``(S, N)`` a known input
        ``u_k`` (the paper's ``B u_k``); ``v`` holds ``pole`` and ``q`` ``(S,)``. Returns x ``(S, N)``. Runs where
        its arguments are (a GPU included) and keeps their gradients."""
        S, N = alpha.shape
        a3 = alpha.unsqueeze(-1)  # (S, N, 1): one state; the layout of the paper's simulator, so its sums are the same
        f = v["pole"].to(alpha).reshape(S, 1, 1)
        omega = xi.unsqueeze(-1) * torch.sqrt(v["q"].to(alpha)).reshape(S, 1, 1)
        u = None if forcing is None else forcing.to(alpha).unsqueeze(-1)
        x = alpha.new_empty(S, N, 1)
        x[:, 0, :] = 0.0 if x0 is None else torch.as_tensor(x0).to(alpha).reshape(S, 1)
        hpow = torch.as_tensor(h, dtype=alpha.dtype, device=alpha.device) ** a3
        constant = bool(torch.all(a3 == a3[:, :1, :]))
        # past states newest first, hist[..., i] = x_{k−i}: time-reversed so that every step reads one contiguous slice
        hist = alpha.new_zeros(S, 1, N)
        hist[..., N - 1] = x[:, 0, :]
        if constant:
            coeff_all = gl_tail_coefficients(a3[:, 0, :], N)  # (S, 1, N): c_1 … c_N
        for k in range(N - 1):
            past = hist[..., N - 1 - k:]  # x_k … x_0
            c = coeff_all[..., :k + 1] if constant else gl_tail_coefficients(a3[:, k + 1, :], k + 1)
            drive = torch.bmm(f, x[:, k, :, None]).squeeze(-1)
            if u is not None:
                drive = drive + u[:, k, :]
            x[:, k + 1, :] = hpow[:, k + 1, :] * (drive + omega[:, k, :]) - (c * past).sum(-1)
            hist[..., N - 2 - k] = x[:, k + 1, :]
        return x[..., 0]

    def block_derivatives(self, v, h, memory):
        """Only the first row of F and G's one entry move: with respect to the pole, ``∂F[0, 0] = h^α``; to q,
        ``∂G[0, 0] = h^α/(2√q)``; to the order, the row's GL and kernel weights by forward-mode differentiation of
        :meth:`first_row` (n numbers) and ``∂G[0, 0] = G[0, 0] ln h``."""
        F, G = self.block(v, h, memory)
        alpha, f, q = v["order"], v["pole"], v["q"]
        B, n = F.shape[0], F.shape[-1]
        _, (d_row, d_g) = forward.jvp(lambda a: self.first_row({"pole": f, "q": q}, a, h, memory), (alpha,),
                                      (torch.ones_like(alpha),))
        dF = F.new_zeros(B, 3, n, n)
        dG = G.new_zeros(B, 3, n, 1)
        dF[:, 0, 0] = d_row
        dG[:, 0, 0, 0] = d_g
        dF[:, 1, 0, 0] = h ** alpha
        dG[:, 2, 0, 0] = h ** alpha / (2.0 * torch.sqrt(q))
        return F, G, dF, dG

    def block(self, v, h, memory):
        alpha = v["order"]
        B = alpha.shape[0]
        J, M = memory.lags, memory.n_modes
        n = J + M
        F = alpha.new_zeros(B, n, n)
        F[:, 0], g = self.first_row(v, alpha, h, memory)
        idx = torch.arange(1, J)
        F[:, idx, idx - 1] = 1.0
        if M:
            _, _, decay, inject = memory.kernel.tensors(alpha.dtype, alpha.device)
            modes = torch.arange(J, n)
            F[:, modes, modes] = decay
            F[:, modes, J - 1] = inject
        G = alpha.new_zeros(B, n, 1)
        G[:, 0, 0] = g
        return F, G

"""Integer-order stochastic states: the bias random walk, the first-order Gauss–Markov bias, a resonance."""
from __future__ import annotations

import math

import torch

from .base import ParamSpec, StateEffect


class RandomWalk(StateEffect):
    r"""Bias random walk :math:`b_{k+1} = b_k + \sigma\sqrt{h}\,\xi_k`, ``b_0 = 0`` (σ: rate random walk K, units/√s).
    Spectrum of its increments' integral: :math:`\sigma^2 h / (2\pi \cdot 4\sin^2(\omega/2))`."""

    name = "random-walk"
    diffuse = True

    params = (ParamSpec("sigma", "positive", "K (units/√s)"),)

    def spectrum(self, v, omega, h):
        s = v["sigma"].unsqueeze(-1)
        return s * s * h / (2.0 * math.pi * 4.0 * torch.sin(omega / 2.0) ** 2)

    def spectrum_derivatives(self, v, omega, h):
        r""":math:`\partial_\sigma S = 2S/\sigma`."""
        S = self.spectrum(v, omega, h)
        return S, (2.0 * S / v["sigma"].unsqueeze(-1)).unsqueeze(1)

    def typical(self, param, h, t_ref):
        return 2e-3


    def block(self, v, h, memory):
        s = v["sigma"]
        F = s.new_ones(s.shape[0], 1, 1)
        G = (s * math.sqrt(h)).reshape(-1, 1, 1)
        return F, G

    def block_derivatives(self, v, h, memory):
        """``∂G/∂σ = √h``."""
        F, G = self.block(v, h, memory)
        return F, G, F.new_zeros(F.shape[0], 1, 1, 1), G.new_full((G.shape[0], 1, 1, 1), math.sqrt(h))


class GaussMarkov(StateEffect):
    r"""First-order Gauss–Markov noise, IEEE Std 952's exponentially correlated noise (in every INS error model as a
    bias instability): :math:`b_{k+1} = a\,b_k + \sigma\sqrt{1-a^2}\,\xi_k`, :math:`a = e^{-h/\tau}`, so that
    σ is its stationary standard deviation and τ its correlation time (autocorrelation :math:`\sigma^2
    e^{-|t|/\tau}`); started at ``b_0 = 0`` like the random walk (a constant bias is the level's business).
    Spectrum of the stationary process: :math:`\sigma^2(1-a^2) / (2\pi(1 - 2a\cos\omega + a^2))`. Its Allan
    deviation peaks near τ_A ≈ 1.89 τ at ≈ 0.62 σ (the flat "bias instability" region when τ is long)."""

    name = "gauss-markov"
    params = (ParamSpec("sigma", "positive", "σ (units), stationary standard deviation"),
              ParamSpec("tau_s", "positive", "τ (s), correlation time"))

    def coefficient(self, v, h):
        return torch.exp(-h / v["tau_s"])

    def spectrum(self, v, omega, h):
        a = self.coefficient(v, h).unsqueeze(-1)
        s2 = (v["sigma"] ** 2).unsqueeze(-1)
        return s2 * (1.0 - a * a) / (2.0 * math.pi * (1.0 - 2.0 * a * torch.cos(omega) + a * a))

    def spectrum_derivatives(self, v, omega, h):
        r""":math:`\partial_\sigma S = 2S/\sigma`; through :math:`a = e^{-h/\tau}`, :math:`\partial_a \log S =
        -2a/(1-a^2) - 2(a - \cos\omega)/(1 - 2a\cos\omega + a^2)` and :math:`\partial_\tau a = a h/\tau^2`."""
        a = self.coefficient(v, h).unsqueeze(-1)
        s2 = (v["sigma"] ** 2).unsqueeze(-1)
        co = torch.cos(omega)
        den = 1.0 - 2.0 * a * co + a * a
        S = s2 * (1.0 - a * a) / (2.0 * math.pi * den)
        tau = v["tau_s"].unsqueeze(-1)
        dlog_a = -2.0 * a / (1.0 - a * a) - 2.0 * (a - co) / den
        return S, torch.stack([2.0 * S / v["sigma"].unsqueeze(-1), S * dlog_a * a * h / (tau * tau)], dim=1)

    def block(self, v, h, memory):
        a = self.coefficient(v, h)
        F = a.reshape(-1, 1, 1).clone()
        G = (v["sigma"] * torch.sqrt(1.0 - a * a)).reshape(-1, 1, 1)
        return F, G

    def block_derivatives(self, v, h, memory):
        """With ``a = e^{−h/τ}``, ``∂a/∂τ = a h/τ²``: ``∂F/∂τ = ∂a/∂τ``, ``∂G/∂σ = √(1 − a²)``,
        ``∂G/∂τ = −σ a/√(1 − a²) ∂a/∂τ``."""
        F, G = self.block(v, h, memory)
        a, s, tau = self.coefficient(v, h), v["sigma"], v["tau_s"]
        da = a * h / (tau * tau)
        root = torch.sqrt(1.0 - a * a)
        dF = torch.stack([torch.zeros_like(a), da], dim=1).reshape(-1, 2, 1, 1)
        dG = torch.stack([root, -s * a / root * da], dim=1).reshape(-1, 2, 1, 1)
        return F, G, dF, dG

    def typical(self, param, h, t_ref):
        return {"sigma": 5e-3, "tau_s": 20.0}[param]


class Resonance(StateEffect):
    r"""A vibration band: narrow-band random vibration, white noise through a damped second-order resonator — a
    mechanical mode of the board or the part, or vibration aliased into the band, whose power spreads over a band
    instead of one line (a line that wanders is not a line). The AR(2) with complex poles
    :math:`\rho e^{\pm i\theta}`, :math:`\theta = 2\pi f_r h`, :math:`\rho = e^{-\pi B h}`:
    :math:`x_{k+1} = a_1 x_k + a_2 x_{k-1} + g\,\xi_k` with :math:`a_1 = 2\rho\cos\theta`, :math:`a_2 = -\rho^2`,
    started at rest like the Gauss–Markov bias. ``frequency_hz`` is f_r, ``bandwidth_hz`` B (the resonance's
    half-power width when it is narrow, B ≪ f_r), ``sigma`` its stationary standard deviation:
    :math:`g^2 = \sigma^2 (1 + a_2)((1 - a_2)^2 - a_1^2)/(1 - a_2)`. Spectrum
    :math:`g^2 / (2\pi |1 - a_1 e^{-i\omega} - a_2 e^{-2i\omega}|^2)`.

    ``check`` screens it by the band of the innovations' periodogram with the most power against the model
    (:func:`~torchtea.checking.diagnostics.band_search`: sums of 4 to 256 adjacent ordinates, each Gamma under the
    model, Bonferroni over positions and widths — its frequency is not identified where σ vanishes, so a likelihood
    ratio's null would not be a χ² mixture), and refits it by exact likelihood from that band. By hand, its start is
    the band where the data's spectrum stands highest above its own smooth trend."""

    name = "resonance"
    params = (ParamSpec("frequency_hz", "nyquist", "f_r (Hz), centre of the band"),
              ParamSpec("bandwidth_hz", "positive", "B (Hz), half-power width"),
              ParamSpec("sigma", "positive", "σ (units), stationary standard deviation"))

    @staticmethod
    def coefficients(v, h):
        """``(a₁, a₂, g)`` of the AR(2), each ``(B,)``."""
        rho = torch.exp(-math.pi * v["bandwidth_hz"] * h)
        a1 = 2.0 * rho * torch.cos(2.0 * math.pi * v["frequency_hz"] * h)
        a2 = -rho * rho
        g2 = v["sigma"] ** 2 * (1.0 + a2) * ((1.0 - a2) ** 2 - a1 * a1) / (1.0 - a2)
        return a1, a2, torch.sqrt(torch.clamp(g2, min=0.0))

    def spectrum(self, v, omega, h):
        a1, a2, g = (c.unsqueeze(-1) for c in self.coefficients(v, h))
        re = 1.0 - a1 * torch.cos(omega) - a2 * torch.cos(2.0 * omega)
        im = a1 * torch.sin(omega) + a2 * torch.sin(2.0 * omega)
        return g * g / (2.0 * math.pi * (re * re + im * im))

    def spectrum_derivatives(self, v, omega, h):
        r"""Through the AR(2)'s coefficients: :math:`\log S = \log g^2 - \log 2\pi - \log|A|^2`, with
        :math:`\partial_{a_1}\log g^2 = -2a_1/((1-a_2)^2 - a_1^2)`, :math:`\partial_{a_2}\log g^2 = 1/(1+a_2) +
        1/(1-a_2) - 2(1-a_2)/((1-a_2)^2 - a_1^2)`, :math:`\partial_\sigma \log g^2 = 2/\sigma`, and
        :math:`a_1 = 2\rho\cos\theta`, :math:`a_2 = -\rho^2` moved by :math:`\theta = 2\pi f_r h` and
        :math:`\rho = e^{-\pi B h}`."""
        a1, a2, g = (c.unsqueeze(-1) for c in self.coefficients(v, h))
        c1, c2, s1, s2 = torch.cos(omega), torch.cos(2.0 * omega), torch.sin(omega), torch.sin(2.0 * omega)
        re = 1.0 - a1 * c1 - a2 * c2
        im = a1 * s1 + a2 * s2
        A2 = re * re + im * im
        S = g * g / (2.0 * math.pi * A2)
        det = (1.0 - a2) ** 2 - a1 * a1
        d_a1 = -2.0 * a1 / det - 2.0 * (im * s1 - re * c1) / A2
        d_a2 = 1.0 / (1.0 + a2) + 1.0 / (1.0 - a2) - 2.0 * (1.0 - a2) / det - 2.0 * (im * s2 - re * c2) / A2
        rho = torch.exp(-math.pi * v["bandwidth_hz"] * h).unsqueeze(-1)
        theta = (2.0 * math.pi * v["frequency_hz"] * h).unsqueeze(-1)
        d_freq = d_a1 * (-2.0 * rho * torch.sin(theta) * 2.0 * math.pi * h)
        d_band = d_a1 * (2.0 * torch.cos(theta) * (-math.pi * h * rho)) + d_a2 * (2.0 * math.pi * h * rho * rho)
        return S, torch.stack([S * d_freq, S * d_band, 2.0 * S / v["sigma"].unsqueeze(-1)], dim=1)

    def block(self, v, h, memory):
        a1, a2, g = self.coefficients(v, h)
        B = a1.shape[0]
        F = a1.new_zeros(B, 2, 2)
        F[:, 0, 0], F[:, 0, 1], F[:, 1, 0] = a1, a2, 1.0
        G = a1.new_zeros(B, 2, 1)
        G[:, 0, 0] = g
        return F, G

    def block_derivatives(self, v, h, memory):
        """Through ``a₁ = 2ρ cos θ``, ``a₂ = −ρ²`` (θ = 2π f_r h, ρ = e^{−πBh}) and ``g = √g²``, ``∂g = g ∂log g²/2``
        with :meth:`spectrum_derivatives`' ``∂log g²``."""
        F, G = self.block(v, h, memory)
        a1, a2, g = self.coefficients(v, h)
        rho = torch.exp(-math.pi * v["bandwidth_hz"] * h)
        theta = 2.0 * math.pi * v["frequency_hz"] * h
        zero = torch.zeros_like(rho)
        da1 = torch.stack([-2.0 * rho * torch.sin(theta) * 2.0 * math.pi * h,
                           2.0 * torch.cos(theta) * (-math.pi * h * rho), zero], dim=1)
        da2 = torch.stack([zero, 2.0 * math.pi * h * rho * rho, zero], dim=1)
        det = (1.0 - a2) ** 2 - a1 * a1
        dlog = ((-2.0 * a1 / det).unsqueeze(-1) * da1
                + (1.0 / (1.0 + a2) + 1.0 / (1.0 - a2) - 2.0 * (1.0 - a2) / det).unsqueeze(-1) * da2)
        dlog[:, 2] = 2.0 / v["sigma"]
        B = a1.shape[0]
        dF = F.new_zeros(B, 3, 2, 2)
        dF[:, :, 0, 0], dF[:, :, 0, 1] = da1, da2
        dG = G.new_zeros(B, 3, 2, 1)
        dG[:, :, 0, 0] = 0.5 * g.unsqueeze(-1) * dlog
        return F, G, dF, dG

    def typical(self, param, h, t_ref):
        return {"frequency_hz": min(30.0, 0.3 / h), "bandwidth_hz": min(3.0, 0.03 / h), "sigma": 2e-3}[param]



"""Identification of a static accelerometer's noise, paper §5.

Steps (paper §5.1): counts → m/s²; each axis's mean removed; the TEA with the
paper's MEMS settings on the three axes as one batch (no known input);
per-axis order α̂ and parameter ŵ, final and averaged over the last third.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import torch

from .io import Recording
from .model import Structure
from .presets import get_preset
from .tea import TEAConfig, TEAResult, make_params, run_tea, stack_params

__all__ = ["AXES", "Identification", "axis_configs", "identify", "summarise"]

AXES = ("x", "y", "z")


@dataclass(frozen=True)
class Identification:
    """Result of :func:`identify`. ``y`` is ``(3, N, 1)`` (mean-removed, m/s²); ``result`` has batch ``(3,)``."""

    recording: Recording
    h: float
    y: torch.Tensor
    means: np.ndarray
    configs: tuple
    result: TEAResult

    @property
    def t(self) -> np.ndarray:
        return np.arange(self.y.shape[-2]) * self.h

    def summary(self) -> dict:
        return summarise(self.result, self.configs, self.means)


def axis_configs(y: torch.Tensor, r_mode: str = "measured", overrides: dict | None = None) -> tuple:
    """The paper's §5.1 settings per axis.

    ``r_mode="paper"`` keeps the printed R, Rᵒ, Rʷ (4, 3.9, 11 ·10⁻⁴ (m/s²)²);
    ``"measured"`` sets all three to each axis's sample variance — the paper's
    rule ("adjusted according to noise measurement corresponding to each axis"),
    which its printed values follow for the MPU-9250.
    """
    if r_mode not in ("measured", "paper"):
        raise ValueError(f"r_mode must be 'measured' or 'paper', got {r_mode!r}")
    out = []
    for i, axis in enumerate(AXES):
        cfg = get_preset(f"paper-mems-{axis}")
        if r_mode == "measured":
            r = float(np.nanvar(y[i, :, 0].cpu().numpy()))
            cfg = replace(cfg, kfx=replace(cfg.kfx, R=r), kfo=replace(cfg.kfo, R=r), kfw=replace(cfg.kfw, R=r))
        if overrides:
            cfg = TEAConfig.from_dict(overrides, cfg)
        out.append(cfg)
    return tuple(out)


def identify(recording: Recording, *, n_samples: int | None = None, r_mode: str = "measured",
             overrides: dict | None = None, progress=None, compile: bool = False) -> Identification:
    """Run the TEA on the three accelerometer axes of a recording as one batch.

    Parameters
    ----------
    recording : Recording
    n_samples : int, optional
        Use the first ``n_samples`` samples (the paper used 3000 at 100 Hz); all by default.
    r_mode : {"measured", "paper"}
        See :func:`axis_configs`.
    overrides : dict, optional
        TEA settings applied on top of the presets (as in a TOML config), e.g.
        ``{"memory": {"kind": "soe"}}`` for long recordings.
    compile : bool
        Passed to :func:`torchtea.tea.run_tea`.
    """
    acc = recording.accel_ms2()
    if n_samples is not None:
        if n_samples < 2:
            raise ValueError("need at least 2 samples")
        acc = acc[:n_samples]
    means = np.nanmean(acc, axis=0)
    y = torch.as_tensor((acc - means).T.copy(), dtype=torch.float64).unsqueeze(-1)  # (3, N, 1)
    configs = axis_configs(y, r_mode, overrides)
    params = stack_params([make_params(c, Structure()) for c in configs])
    result = run_tea(y, h=recording.h, params=params, progress=progress, compile=compile)
    return Identification(recording, recording.h, y, means, configs, result)


def summarise(result: TEAResult, configs, means=None) -> dict:
    """Per-axis order and parameter: final value and mean/std over the last third."""
    axes = {}
    N = result.alpha.shape[-2]
    third = slice(N - N // 3, N)
    for i, axis in enumerate(AXES[: result.alpha.shape[0]]):
        a = result.alpha[i, :, 0]
        w = result.w[i, :, 0]
        axes[axis] = {
            "alpha": float(a[third].mean()),
            "param": float(w[third].mean()),
            "alpha_std_last_third": float(a[third].std()),
            "param_std_last_third": float(w[third].std()),
            "alpha_final": float(a[-1]),
            "param_final": float(w[-1]),
            "R": float(configs[i].kfx.R),
            "diverged": bool(result.diverged[i]),
            "innovation_nis": float((result.innovation[i, 1:, 0] ** 2 / result.innovation_cov[i, 1:, 0, 0]).mean()),
        }
        if means is not None:
            axes[axis]["mean_removed_ms2"] = float(means[i])
    return {"axes": axes}

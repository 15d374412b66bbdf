r"""Is the fractional component there at all? A likelihood-ratio test calibrated by parametric bootstrap.

The statistic is :math:`LR = 2(\hat\ell_W^{\text{full}} - \hat\ell_W^{\text{null}})` of the Whittle
likelihoods of the model and of the same model without its fractional component. Under the null the
fractional part's drive q is 0 — on the boundary of the parameter space — and its order and pole are not
identified, so LR is not χ²-distributed. The p-value comes from ``B`` series simulated from the fitted null
and fitted with both models exactly as the data were:
:math:`p = (1 + \#\{LR_b \ge LR\}) / (B + 1)`. The bootstrap calibrates whatever approximation the Whittle
likelihood makes, so the test's size holds for the procedure as run.

When the null is white noise only, the Whittle fits are scale-equivariant, so LR's null distribution
depends on N alone: one bootstrap serves every series of that length (``shared`` in the result).
"""
from __future__ import annotations

import numpy as np
import torch

from ..noise.model import parse_model
from ..noise.simulate import simulate_model
from .mle import whittle_fit

__all__ = ["fractional_test", "BOOTSTRAP_ORDERS", "BOOTSTRAP_FRACTIONS"]

#: Multi-start of the test's fits of the full model, for the data and every replicate alike (fewer starts
#: than an estimate's fit, for speed; the same for both, so the p-value calibrates the procedure as run).
BOOTSTRAP_ORDERS = (0.2, 0.6)
BOOTSTRAP_FRACTIONS = (0.5,)


def _lr(model, null, series, h):
    """LR of each series, the full model fitted from the :data:`BOOTSTRAP_ORDERS` × :data:`BOOTSTRAP_FRACTIONS`
    starts — the same for the data and every replicate, so the statistic is one procedure: under the null
    the order and pole are not identified, and more starts would give a stochastically larger maximum."""
    full = whittle_fit(model, series, h, orders=BOOTSTRAP_ORDERS, fractions=BOOTSTRAP_FRACTIONS)
    nul = whittle_fit(null, series, h)
    return (2.0 * (full.loglik - nul.loglik)).clamp(min=0.0).numpy(), nul.values


def fractional_test(model, series: list, h: float, *, n_boot: int = 99, seed: int = 0,
                    null_cache: dict | None = None) -> list[dict]:
    """Per series: ``{"lr", "p_value", "n_boot", "null", "shared", "null_lr_quantile95"}``. Series must be
    complete (the Whittle likelihood); their means are removed as in the fit. ``null_cache``: a dict that
    keeps the white-null bootstrap distributions (keyed by model, N, h and ``n_boot``) for later calls — pass
    the same dict to test more series of the same length without simulating the null again."""
    model = parse_model(model)
    if model.order_name is None:
        raise ValueError(f"model {model.spec!r} has no fractional component to test")
    null = model.without(dict(model.components)[model.order_labels[0]].name)
    series = [np.asarray(y, dtype=np.float64) - np.mean(y) for y in series]
    lr, V0 = _lr(model, null, series, h)
    gen = torch.Generator().manual_seed(seed)
    white_only = all(c.kind == "measurement" for _, c in null.components)
    out = []
    cache = {} if null_cache is None else null_cache
    for s, y in enumerate(series):
        N = len(y)
        key = (model.spec, N, h, n_boot) if white_only else None
        if key is not None and key in cache:
            boot = cache[key]
        else:
            sims = simulate_model(null, V0[s:s + 1], n_steps=N, h=h, realisations=n_boot, generator=gen)[0]
            sims = [sims[b].numpy() - float(sims[b].mean()) for b in range(n_boot)]
            boot, _ = _lr(model, null, sims, h)
            if key is not None:
                cache[key] = boot
        p = (1.0 + float(np.sum(boot >= lr[s]))) / (n_boot + 1.0)
        out.append({"lr": float(lr[s]), "p_value": p, "n_boot": n_boot, "null": null.spec,
                    "shared": key is not None, "null_lr_quantile95": float(np.quantile(boot, 0.95))})
    return out

"""What a fit says, as one dict: the ``torchtea fit --json`` document and the identify report's table.

Every number carries its meaning in ``meaning`` so that a reader of the JSON alone cannot mistake, e.g.,
a Wald interval for a profile one, or the Whittle log-likelihood for the exact one.
"""
from __future__ import annotations

import numpy as np

from .mle import FIT_MEMORY, Fit, exact_pass

__all__ = ["fit_nis", "axis_summary", "MEANING"]

MEANING = {
    "value": "maximum-likelihood estimate (natural units, see unit)",
    "se": "standard error from the observed information (delta method); null for a fixed or least-squares value",
    "ci95": "95 % interval; how it was made is in ci95_method",
    "loglik": "maximised log-likelihood of the fitting method (nats)",
    "loglik_exact": "exact log-likelihood (Kalman filter on the stacked state) at the estimate; without an offset "
                    "component the unknown level is integrated out (flat prior, the diffuse likelihood)",
    "aic": "2k − 2·loglik, k = number of free parameters",
    "bic": "k·ln N − 2·loglik",
    "fractional_p_value": "parametric-bootstrap p-value of the likelihood-ratio test 'no fractional component' "
                          "(small = the fractional part is there); null when not run",
    "nis": "mean of e²/S of the exact filter at the estimate over the observed samples: 1 when the fitted "
           "noise levels match the data",
}


def fit_nis(fit: Fit, y, h: float, inputs=None, memory=FIT_MEMORY) -> float:
    """Mean normalised innovation square of the exact filter at the fitted values."""
    p = exact_pass(fit.model, fit.values, y, h, inputs=inputs, memory=memory)
    ok = ~np.isnan(p.innovation)
    return float(np.mean(p.innovation[ok] ** 2 / p.variance[ok]))


def axis_summary(fit: Fit, *, nis: float | None = None, test: dict | None = None) -> dict:
    params = {}
    for n in fit.model.names:
        params[n] = {"value": fit.values[n], "se": fit.se[n], "ci95": fit.ci95[n], "ci95_method": fit.ci95_method[n],
                     "unit": fit.model.param_spec(n).unit, "free": n in fit.free}
    out = {"parameters": params, "loglik": fit.loglik, "loglik_exact": fit.loglik_exact, "aic": fit.aic,
           "bic": fit.bic, "n": fit.n, "method": fit.method, "converged": fit.converged,
           "fractional_p_value": None if test is None else test["p_value"], "nis": nis, "notes": list(fit.notes)}
    if test is not None:
        out["fractional_test"] = test
    if fit.profile is not None:
        out["order_profile"] = {"ci95": fit.profile["ci95"], "pieces": fit.profile["pieces"],
                                "at_edge": fit.profile["at_edge"], "likelihood": "whittle"}
    return out

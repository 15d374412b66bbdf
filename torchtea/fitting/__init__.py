"""Fitting noise models: maximum likelihood with intervals (:mod:`.mle`), the batched Newton minimiser
(:mod:`.optimize`) and the test of whether the fractional component is there at all (:mod:`.presence`)."""
from .mle import METHODS, Fit, exact_loglik, fit_series, profile_order, regress_mean, whittle_fit

__all__ = ["METHODS", "Fit", "exact_loglik", "fit_series", "profile_order", "regress_mean", "whittle_fit"]

"""Likelihoods of a :class:`~torchtea.noise.model.NoiseModel`: Whittle (:mod:`.whittle`) and the exact
Kalman filter on the stacked state (:mod:`.kalman`).

Its layer is above the models: it may import :mod:`torchtea.noise` and everything below it, never the fits or
checks."""
from .kalman import FilterResult, filter_fast, kalman_filter, loglik_fast
from .whittle import periodogram, whittle_loglik

__all__ = ["FilterResult", "filter_fast", "kalman_filter", "loglik_fast", "periodogram", "whittle_loglik"]

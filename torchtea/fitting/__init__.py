"""Fitting noise models: the Whittle and exact maximum likelihood (:mod:`.mle`; the Whittle sum as the scoring reads
it, :mod:`.whittle_objective`; the long-record path that fits by the Whittle likelihood and evaluates the exact one,
:mod:`.whittle_path`), where they start (:mod:`.starts`, each
effect's heuristics registered apart from its physics), the method of scoring both likelihoods' fits run on
(:mod:`.scoring`), a fit's result with its intervals and BIC (:mod:`.results`), the exact
likelihood and innovations at given values (:mod:`.exact`, :mod:`.innovations`), the test of whether the fractional
component is there at all (:mod:`.presence`), how long to record (:mod:`.plan`), ``fit`` on a recording's channels
(:mod:`.recording`, :mod:`.summary`).

Its layer is above the likelihoods: it may import :mod:`torchtea.likelihood`, :mod:`torchtea.noise` and everything
below, never :mod:`torchtea.checking`, the exports, reports or the command line."""
from .mle import METHODS, Fit, exact_loglik, fit_series, profile_order, regress_mean, whittle_fit

__all__ = ["METHODS", "Fit", "exact_loglik", "fit_series", "profile_order", "regress_mean", "whittle_fit"]

"""Model checking: compare a fitted noise model with the measurements, see where it fails, and find the effect
it is missing (:func:`check`; diagnostics in :mod:`.diagnostics`, Allan deviations in :mod:`.allan`)."""
from .check import CANDIDATES, CheckResult, Suggestion, check, extend
from .diagnostics import DIAGNOSTICS, Diagnostic

__all__ = ["CANDIDATES", "CheckResult", "Suggestion", "check", "extend", "DIAGNOSTICS", "Diagnostic"]

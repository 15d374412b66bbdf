"""Results in the navigation filters' own terms: Kalibr, VINS, ORB-SLAM3 and the IEEE Std 952 table
(:mod:`.terms` computes the numbers, :mod:`.formats` writes the files, :mod:`.nees` tests the cover as a filter
feels it)."""
from .terms import DEFAULT_HORIZON, UNITS, AxisTerms, axis_terms, parse_horizon

__all__ = ["AxisTerms", "axis_terms", "parse_horizon", "DEFAULT_HORIZON", "UNITS"]

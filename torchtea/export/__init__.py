"""Results in the navigation filters' own terms: Kalibr, VINS, ORB-SLAM3 and the IEEE Std 952 table
(:mod:`.terms` computes the numbers, :mod:`.formats` writes the files, :mod:`.nees` tests the cover as a filter
feels it).

Its layer is above the model checking (an export may check each axis to the end first): it may import
:mod:`torchtea.checking` and everything below it, never the reports, studies or the command line."""
from .terms import DEFAULT_HORIZON, UNITS, AxisTerms, axis_terms, parse_horizon

__all__ = ["AxisTerms", "axis_terms", "parse_horizon", "DEFAULT_HORIZON", "UNITS"]

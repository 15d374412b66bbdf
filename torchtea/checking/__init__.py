"""Model checking: compare a fitted noise model with the measurements, see where it fails, and find the effect
it is missing (:func:`check`, :mod:`.check`): the diagnostics (:mod:`.diagnostics`, Allan deviations :mod:`.allan`),
the screens of the effects (:mod:`.screens`, run by :mod:`.screening`), the refits (:mod:`.refits`), the ranking
(:mod:`.ranking`), what a check finds as data (:mod:`.results`), the loop's policy (:mod:`.loop`) with its taking away
and swapping (:mod:`.simplify`, :mod:`.models`), a recording's channels (:mod:`.channels`), the report
(:mod:`.report`), TensorBoard (:mod:`.tblog`). The studies' hidden-effect records and oracle are in :mod:`torchtea.studies`.

Its layer is above the fits: it may import :mod:`torchtea.fitting` and everything below it, never the exports,
reports, studies or the command line."""
from .check import CANDIDATES, CheckResult, Suggestion, check, extend
from .diagnostics import DIAGNOSTICS, Diagnostic

__all__ = ["CANDIDATES", "CheckResult", "Suggestion", "check", "extend", "DIAGNOSTICS", "Diagnostic"]

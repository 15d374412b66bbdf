"""Model checking: compare a fitted noise model with the measurements, see where it fails, and find the effect
it is missing (:func:`check`). The modules read in the loop's order, each using only those before it:

1. how the model fails — Allan deviations (:mod:`.allan`) and the diagnostics on its innovations (:mod:`.diagnostics`);
2. what each effect's screen computes (:mod:`.screens`, registered per effect) and the model's fit, extended by an
   effect (:mod:`.models`); the screens run against the fit (:mod:`.screening`: one
   :class:`~.screening.ScreenRow` per effect);
3. the ranking of what passed (:mod:`.ranking`) and the refits that confirm it (:mod:`.refits`);
4. what a step found, as data (:mod:`.results`);
5. the loop's moves — taking away and swapping (:mod:`.simplify`) — and its policy (:mod:`.loop`);
6. one step of it, the entry point (:mod:`.check`: :func:`check`, :class:`CheckResult` with its verbs), and the loop
   on several recordings of one sensor, by their pooled likelihood (:mod:`.pooled`);
7. the outputs: several recordings and a record's windows side by side (:mod:`.replicates`), the report
   (:mod:`.report`), TensorBoard (:mod:`.tblog`), and a recording's channels checked one by one or on a cluster
   (:mod:`.channels`).

The studies' hidden-effect records and oracle are in :mod:`torchtea.studies`. Its layer is above the fits: it may import
:mod:`torchtea.fitting` and everything below it, never the exports, reports, studies or the command line."""
from .check import CANDIDATES, CheckResult, Suggestion, check, extend
from .diagnostics import DIAGNOSTICS, Diagnostic

__all__ = ["CANDIDATES", "CheckResult", "Suggestion", "check", "extend", "DIAGNOSTICS", "Diagnostic"]

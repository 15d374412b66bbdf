"""How ``check`` screens an effect the model lacks — kept apart from the effect's physics (``noise/components``) and
attached to it by a registry (:func:`register_screen`), as ``torch.distributions`` attaches a divergence to a pair of
distributions with ``register_kl``.

A screen is a test with a known null law of "the model without the effect" against "the model with it", run at the
model's fit: ``(statistic, log p-value, the effect's start values, note)``. The built-in effects' screens are in one
module per family (:mod:`.levels`, :mod:`.lines`, :mod:`.markov`, :mod:`.outliers`, :mod:`.temperature`); a
stochastic effect without one is screened by the Whittle likelihood-ratio (in ``check``, every such effect on one
periodogram), a mean without one by :func:`mean_screen`. How ``check`` treats each effect as a candidate — its row
in the table, what it explains, whether a second one may join (:class:`Screening`) — is registered beside its
screen (the built-in effects' in :mod:`.builtin`). A user's effect may register its own of both.

Its layer is the model checking's: it may import ``torchtea.core`` (the searches and exact laws on a series) and
``torchtea.noise`` (the effects it screens), the effects' starts (``torchtea.fitting.starts``: a mean's default
screen starts where the fits do), and reads the rest through the check's context (``ctx.inn``,
``ctx.exact_loglik``, ``ctx.diagnostic``)."""
from __future__ import annotations

from . import builtin, levels, lines, markov, outliers, temperature  # noqa: F401  (the built-ins register themselves)
from .registry import (
    MEAN_SCREEN,
    REGISTRY,
    SCREENING,
    WHITTLE_SCREEN,
    WHITTLE_SCREEN_2,
    NotScreened,
    Screen,
    Screening,
    boundary_logsf,
    candidates,
    configure,
    mean_screen,
    register_screen,
    register_screening,
    run_screen,
    screen_df,
    screen_of,
    screen_test,
    screening_of,
    unregister_screen,
    unregister_screening,
    whittle_screened,
)

REGISTRY.seal()  # (the built-in entries: unregistering one a user replaced brings it back)
SCREENING.seal()

__all__ = ["Screen", "REGISTRY", "register_screen", "unregister_screen", "screen_of", "screen_df", "screen_test", "whittle_screened",
           "run_screen", "configure", "mean_screen", "boundary_logsf", "NotScreened", "WHITTLE_SCREEN",
           "WHITTLE_SCREEN_2", "MEAN_SCREEN", "Screening", "SCREENING", "register_screening", "unregister_screening",
           "screening_of", "candidates"]

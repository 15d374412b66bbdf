"""How the fits start an effect — kept apart from its physics (``noise/components``) and attached to it by a registry
(:func:`register_start`), as the screens are (:mod:`torchtea.checking.screens`).

An effect's :class:`Starts` says where a fit begins: a rough value of each parameter from the data (:meth:`Starts.start`),
its values in the Whittle fit's grid (:meth:`~Starts.grid_start`, :meth:`~Starts.scale_drive`), its part of the
least-squares start of the mean (:meth:`~Starts.regressors`, :meth:`~Starts.fit_residual`), the strengths from which
``check`` refits a model extended by it (:meth:`~Starts.strengths`, :meth:`~Starts.vanishing`), and the intervals of
the parameters every fit holds where the data put them (:meth:`~Starts.located_intervals`). The built-in effects'
starts are in one module per family (:mod:`.fractional`, :mod:`.measurement`, :mod:`.markov`, :mod:`.filters`,
:mod:`.levels`, :mod:`.lines`, :mod:`.thermal`, :mod:`.outliers`); an effect without one of its own gets the
defaults of :class:`Starts`; a user's effect may register its own.

Its layer is the fitting's: it may import ``torchtea.core`` (the searches on a series) and ``torchtea.noise`` (the
effects it starts), numpy, torch and scipy's optimisers and filters; it reads the fitting's innovations only through
what its caller gives (``innovations(values)``)."""
from __future__ import annotations

from . import filters, fractional, levels, lines, markov, measurement, outliers, thermal  # noqa: F401  (register)
from .registry import REGISTRY, StartData, Starts, initial_values, register_start, starts_of, unregister_start

REGISTRY.seal()  # (the built-in starts: unregistering one a user replaced brings it back)

__all__ = ["Starts", "StartData", "REGISTRY", "register_start", "unregister_start", "starts_of", "initial_values"]

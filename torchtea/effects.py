"""The registry of model components (effects): one class per effect, found by name everywhere.

Every part of a noise model — the built-in ones (``torchtea.noise.components.COMPONENTS``: ``fractional``, ``white``,
``random-walk``, ``gauss-markov``, ``resonance``, ``low-pass``, ``digital-filter``, ``offset``, ``ramp``, ``step``,
``spikes``, ``sinusoid``, ``drifting-line``, ``temperature-bias``, ``thermal-lag``, ``temperature-order``,
``quantisation``) and any a user writes — is a
:class:`~torchtea.noise.components.Component` that carries its own knowledge: its parameters with units
and transforms, its spectrum or state block or mean, and its typical values (``torchtea simulate``). A user's
effect derives from the base of its kind — :class:`StateEffect` (a noise with a state block),
:class:`MeasurementEffect` (white noise added to each sample) or :class:`MeanEffect` (a function of time and the
inputs) —, which declares the hooks that kind's engines call.
:func:`parse_model` finds it here by
name. A user adds an effect from their own module or notebook::

    import torch
    from torchtea.effects import MeanEffect, ParamSpec, register

    @register
    class WarmUp(MeanEffect):  # a settling transient after power-on: A·exp(−t/τ)
        name = "warm-up"
        params = (ParamSpec("amplitude", "free", "units"), ParamSpec("tau_s", "positive", "τ (s)"))

        def mean(self, v, t, inputs):
            return v["amplitude"].unsqueeze(-1) * torch.exp(-t / v["tau_s"].unsqueeze(-1))

        def typical(self, param, h, t_ref):
            return {"amplitude": 0.05, "tau_s": 20.0}[param]

and ``fractional+white+warm-up`` is then simulated, fitted (Whittle and exact), checked and reported like a built-in
model. How ``check`` screens it and how the fits start it are not the class's business: the defaults of its kind, or
a screen registered for it with :func:`torchtea.checking.screens.register_screen` and starts with
:func:`torchtea.fitting.starts.register_start`.
A package can register its effects through the entry-point group ``torchtea.effects`` (each entry a Component
subclass); they are loaded the first time a model names a component that is not registered.
"""
from __future__ import annotations

import math
from importlib import metadata

from .noise.components import (
    COMPONENTS,
    KIND_BASES,
    Component,
    MeanEffect,
    MeasurementEffect,
    ParamSpec,
    StateEffect,
)
from .noise.components.base import SCALES

__all__ = ["register", "unregister", "registered", "ENTRY_POINTS", "StateEffect", "MeasurementEffect", "MeanEffect",
           "ParamSpec"]

#: The entry-point group a package registers its effects under.
ENTRY_POINTS = "torchtea.effects"

#: The kinds of a user's effect that the filters and fits run generically; a ``filter`` (the low-pass) and a
#: ``modifier`` (the temperature-driven order) are built into the state-space assembly and cannot be added.
KINDS = ("state", "measurement", "mean")
_loaded_entry_points = False


def register(effect, *, replace: bool = False):
    """Register a :class:`~torchtea.noise.components.Component` subclass (or an instance of one) under its
    ``name``; returns what it was given, so it serves as a class decorator. Raises ``ValueError`` naming the
    effect when its name, kind or parameters are not usable, or when the name is taken (``replace=True`` replaces
    the effect of that name, a built-in one too, until :func:`unregister`)."""
    comp = effect() if isinstance(effect, type) else effect
    if not isinstance(comp, Component):
        raise TypeError(f"register() takes a Component subclass, got {effect!r}")
    name = comp.name
    where = f"effect {type(comp).__name__}"
    if not isinstance(name, str) or not name or name != name.strip().lower() or any(c in name for c in "+. "):
        raise ValueError(f"{where}: name {name!r} must be a non-empty lower-case word without '+', '.' or spaces")
    if name[-1].isdigit():
        raise ValueError(f"{where}: name {name!r} must not end in a digit (a second copy is labelled {name}2)")
    if comp.kind not in KINDS:
        raise ValueError(f"{where}: kind {comp.kind!r} must be one of {', '.join(KINDS)}: derive the effect from "
                         "StateEffect, MeasurementEffect or MeanEffect (a filter or a modifier is built into the "
                         "state-space assembly: only the built-in ones run)")
    if not comp.params or not all(isinstance(p, ParamSpec) for p in comp.params):
        raise ValueError(f"{where}: params must be a non-empty tuple of ParamSpec")
    if any(p.kind not in SCALES for p in comp.params):
        raise ValueError(f"{where}: a parameter's kind must be one of {', '.join(SCALES)} (got "
                         f"{', '.join(sorted({p.kind for p in comp.params} - set(SCALES)))})")
    if any(p.kind == "bounded" and not all(map(math.isfinite, p.bounds)) for p in comp.params):
        raise ValueError(f"{where}: a 'bounded' parameter needs finite bounds (its transform is the logit of its "
                         "share of the range); an unbounded one is 'free'")
    if any(p.kind == "fraction" for p in comp.params) and comp.order_param is None:
        raise ValueError(f"{where}: a 'fraction' parameter is a pole's fraction of the stability limit at the "
                         "effect's fractional order: the effect needs an order_param")
    if not isinstance(comp, KIND_BASES[comp.kind]):
        raise ValueError(f"{where}: an effect of kind {comp.kind!r} derives from "
                         f"torchtea.effects.{KIND_BASES[comp.kind].__name__} (the hooks its kind's engines call)")
    if comp.kind == "mean" and type(comp).mean is MeanEffect.mean:
        raise ValueError(f"{where}: a mean effect must define mean(v, t, inputs)")
    if comp.kind == "state" and type(comp).block is StateEffect.block:
        raise ValueError(f"{where}: a state effect must define block(v, h, memory) (its spectrum, unless it writes "
                         "its own, is the block's stationary one)")
    if comp.kind == "measurement" and type(comp).measurement_variance is MeasurementEffect.measurement_variance:
        raise ValueError(f"{where}: a measurement effect must define measurement_variance(v)")
    try:
        COMPONENTS.add(name, comp, replace=replace)
    except ValueError as e:
        raise ValueError(f"{where}: {e}") from None
    return effect


def unregister(name: str) -> None:
    """Remove a user's effect from the registry; where it had replaced a built-in effect of that name, the built-in
    one is back (a built-in effect itself stays: ``ValueError``)."""
    COMPONENTS.remove(name)


def registered() -> dict:
    """``{name: component}`` of every registered effect, built-in first."""
    return dict(COMPONENTS)


def load_entry_points() -> None:
    """Register the effects of installed packages (entry-point group :data:`ENTRY_POINTS`), once. A broken
    entry point is reported with its name and skipped."""
    global _loaded_entry_points
    if _loaded_entry_points:
        return
    _loaded_entry_points = True
    import warnings

    for ep in metadata.entry_points(group=ENTRY_POINTS):
        try:
            obj = ep.load()
            if getattr(obj, "name", None) not in COMPONENTS:
                register(obj)
        except Exception as exc:  # noqa: BLE001 - a third party's module: name it and go on
            warnings.warn(f"torchtea effect entry point {ep.name!r} ({ep.value}) not loaded: {exc}", stacklevel=2)


def import_effects(name: str) -> None:
    """Import a user's module of effects (what ``--effects`` names, so that its :func:`register` calls run): a ``.py``
    file by its path, else a module by name. Importing it again in the same process does nothing (a Dask worker runs it
    before every task that needs it). Raises ``ValueError`` naming the module and what went wrong."""
    import importlib
    import importlib.util
    import sys
    from pathlib import Path

    try:
        if name.endswith(".py"):
            path = Path(name)
            if not path.is_file():
                raise ValueError(f"--effects {name}: no such file")
            key = f"torchtea_user_effects_{path.stem}"
            if getattr(sys.modules.get(key), "__file__", None) == str(path.resolve()):
                return  # imported by an earlier command in this process: its effects are registered
            spec = importlib.util.spec_from_file_location(key, path.resolve())
            module = importlib.util.module_from_spec(spec)
            sys.modules[spec.name] = module
            spec.loader.exec_module(module)
        else:
            importlib.import_module(name)
    except ValueError:
        raise
    except Exception as exc:  # noqa: BLE001 - the user's module: say which one failed and why
        raise ValueError(f"--effects {name}: could not import it: {type(exc).__name__}: {exc}") from exc

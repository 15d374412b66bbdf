"""The spec grammar's part of an effect: how it is written in a model's spec (``spikes:13``), whether a model holds
one at most, which models can hold it and where a new one goes among a model's components.

Kept apart from the effects' physics and registered by the effect's class (:func:`register_grammar`, the rule of
:class:`~torchtea.core.registry.Registry`); :func:`~torchtea.noise.model.parse_model` and ``check``'s ``extend``
read it. An effect without an entry is written by its name, may appear several times, fits any model and goes at
the end."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from ..core.registry import Registry
from .components import Component, LowPass, Spikes, TemperatureOrder

__all__ = ["Grammar", "GRAMMAR", "register_grammar", "unregister_grammar", "grammar_of", "token", "configured",
           "token_for", "validate", "position"]


@dataclass(frozen=True)
class Grammar:
    """``configure(comp, argument)`` → the component the spec's ``name:argument`` writes (a spikes component of that
    count; raises ``ValueError`` for a bad argument), None: it takes no argument; ``needs_argument``: the words with
    which the bare name is refused ("" : it is not); ``token(comp)`` → how a configured component is written (None:
    its name); ``token_for(comp, label, values)`` → the token of the component ``label`` whose parameter values are
    ``values`` (a simulation's truth); ``single``: a model holds one at most; ``validate(comp, components, spec)``
    raises ``ValueError`` (naming the model ``spec``) where the model's ``(label, component)`` list cannot hold it;
    ``position(comp, model)`` → where ``extend`` inserts it among ``model``'s components (None: at the end), raising
    ``ValueError`` naming what the model lacks."""

    configure: Callable | None = None
    needs_argument: str = ""
    token: Callable | None = None
    token_for: Callable | None = None
    single: bool = False
    validate: Callable | None = None
    position: Callable | None = None


#: The effects' grammar by class (a subclass has its parent's unless it registers its own).
GRAMMAR = Registry("grammar", by_class=True)
PLAIN = Grammar()


def register_grammar(effect, *, replace: bool = False, **fields) -> None:
    """The effect class ``effect`` (or an instance's class) is written and placed as ``fields`` say
    (:class:`Grammar`'s)."""
    GRAMMAR.add(effect, Grammar(**fields), replace=replace)


def unregister_grammar(effect) -> None:
    """Remove what a user registered for the effect class ``effect`` (a built-in entry it replaced is back)."""
    GRAMMAR.remove(effect)


def grammar_of(comp) -> Grammar:
    return GRAMMAR.find(comp, PLAIN)


def token(comp) -> str:
    """How ``comp`` is written in a model's spec: its name, or ``name:argument`` for one configured by an argument."""
    g = grammar_of(comp)
    return comp.name if g.token is None else g.token(comp)


def configured(comp, argument: str) -> Component:
    """The component the spec's ``name:argument`` writes; ``ValueError`` for a component that takes no argument."""
    g = grammar_of(comp)
    if g.configure is None:
        raise ValueError(f"component {comp.name!r} takes no argument (got {comp.name}:{argument})")
    return g.configure(comp, argument)


def token_for(comp, label: str, values: dict) -> str:
    """The token of the component ``label`` whose parameter values are ``values`` (a simulation's truth)."""
    g = grammar_of(comp)
    return comp.name if g.token_for is None else g.token_for(comp, label, values)


def validate(comp, components: list, spec: str) -> None:
    """Raise ``ValueError`` where the model ``spec`` (its ``(label, component)`` list) cannot hold ``comp``."""
    g = grammar_of(comp)
    if g.validate is not None:
        g.validate(comp, components, spec)


def position(comp, model) -> int:
    """Where ``extend`` inserts ``comp`` among ``model``'s components (the end unless its grammar says otherwise)."""
    g = grammar_of(comp)
    return len(model.components) if g.position is None else g.position(comp, model)


# ---- the built-in effects' grammar --------------------------------------------------------------------------------

def _spikes(comp, argument):
    try:
        count = int(argument)
    except ValueError:
        count = 0
    if not 1 <= count <= comp.MAX_SPIKES:
        raise ValueError(f"spikes:{argument}: the count must be a whole number from 1 to {comp.MAX_SPIKES}")
    return type(comp)(count)


def _one_filter(comp, components, spec):
    filters = [c.name for _, c in components if c.kind == "filter"]
    if len(filters) > 1:
        raise ValueError(f"model {spec!r}: one sensor filter at most ({', '.join(filters)})")


def _after_the_noise(comp, model):
    """Right after the last stochastic component: a sensor's digital filter filters its whole signal, white noise
    included."""
    last = max((i for i, (_, c) in enumerate(model.components) if c.kind in ("state", "measurement")), default=None)
    if last is None:
        raise ValueError(f"a {comp.name} filters stochastic components; {model.spec!r} has none")
    return last + 1


def _one_order_driven(comp, components, spec):
    names = [c.name for _, c in components]
    if names.count(comp.name) > 1 or sum(c.order_param is not None for _, c in components) != 1:
        raise ValueError(f"model {spec!r}: temperature-order drives the order of exactly one fractional "
                         "component, and a model holds one temperature-order")
    if any(c.kind == "filter" for _, c in components):
        raise ValueError(f"model {spec!r}: temperature-order drives the order of one fractional component and "
                         "cannot be combined with a sensor filter (low-pass, digital-filter)")


def _with_an_order(comp, model):
    if model.order_name is None:
        raise ValueError(f"temperature-order drives a fractional component's order; {model.spec!r} has none")
    return len(model.components)


register_grammar(Spikes, configure=_spikes,
                 needs_argument="spikes need their count: spikes:K (check finds the spikes and their count itself)",
                 token=lambda comp: f"{comp.name}:{comp.count}",
                 token_for=lambda comp, label, values: f"{comp.name}:"
                                                       f"{sum(1 for n in values if n.startswith(f'{label}.t'))}")
register_grammar(LowPass, single=True, validate=_one_filter, position=_after_the_noise)
register_grammar(TemperatureOrder, validate=_one_order_driven, position=_with_an_order)
GRAMMAR.seal()

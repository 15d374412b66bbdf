"""How a navigation filter's noise model names each effect: its IEEE Std 952 term, the term's value where one
parameter gives it, and what a white-noise + random-walk filter misses of an effect that has no term.

Kept apart from the effects' physics, registered by the effect's class (:func:`register_nav_term`, the rule of
:class:`~torchtea.core.registry.Registry`); the plan's intervals (:mod:`torchtea.fitting.plan`) and the exports
(:mod:`torchtea.export.terms`) read it. An effect without an entry has no term: the exports name it and cover it."""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from ..core.registry import Registry
from .components import LowPass, Offset, Quantisation, Ramp, RandomWalk, White

__all__ = ["NavTerm", "NAV_TERMS", "register_nav_term", "unregister_nav_term", "nav_term_of", "nav_value",
           "nav_note"]


@dataclass(frozen=True)
class NavTerm:
    """An effect's place in a navigation filter's noise model. ``term``: the IEEE Std 952 term it is — ``"N"`` (white
    rate noise: a noise density), ``"K"`` (rate random walk: a bias random walk), ``"R"`` (rate ramp), ``"bias"`` (a
    constant level: a filter's bias state holds it) — or None. Kalibr, VINS and ORB-SLAM3 know N and K only.
    ``value(label, values, h)`` → ``(value, the parameter it follows, the power it follows it with)`` (N = √(r h)
    follows r to the power ½, K = σ to the power 1), or None: not one parameter's power. ``note(comp, label, v, h)``
    → what a white-noise + random-walk filter misses of it (``v``: its values as floats), or None for the default
    words."""

    term: str | None = None
    value: Callable | None = None
    note: Callable | None = None


#: The effects' terms by class (a subclass has its parent's unless it registers its own).
NAV_TERMS = Registry("navigation term", by_class=True)
NO_TERM = NavTerm()


def register_nav_term(effect, term: str | None = None, value: Callable | None = None, note: Callable | None = None,
                      *, replace: bool = False) -> None:
    """The effect class ``effect`` (or an instance's class) is the IEEE 952 ``term`` in a navigation filter (see
    :class:`NavTerm` for ``value`` and ``note``)."""
    NAV_TERMS.add(effect, NavTerm(term, value, note), replace=replace)


def unregister_nav_term(effect) -> None:
    """Remove what a user registered for the effect class ``effect`` (a built-in entry it replaced is back)."""
    NAV_TERMS.remove(effect)


def nav_term_of(comp) -> NavTerm:
    """The entry of ``comp``'s class or its nearest parent's (no term where none has one)."""
    return NAV_TERMS.find(comp, NO_TERM)


def nav_value(comp, label: str, values: dict, h: float) -> tuple[float, str, float] | None:
    """``comp``'s term's value at ``values`` (name → float; ``label`` its label) as ``(value, the parameter it
    follows, the power)``, for the plan's intervals; None where it has none."""
    entry = nav_term_of(comp)
    return None if entry.value is None else entry.value(label, values, h)


def nav_note(comp, label: str, v: dict, h: float) -> str:
    """What a white-noise + random-walk filter misses of ``comp`` (the exports' list); ``v``: its values (floats)."""
    entry = nav_term_of(comp)
    if entry.note is not None:
        return entry.note(comp, label, v, h)
    shown = ", ".join(f"{p.name} {v[p.name]:.4g}" for p in comp.params if p.name in v)
    return f"{label}: no term in a white-noise + random-walk model ({shown}); covered by raising N or K"


def _filter_note(comp, label, v, h):
    fc = v["cutoff_hz"]
    return (f"{label}: the sensor filters its output at {fc:.4g} Hz ({comp.stages} stage(s); Nyquist "
            f"{0.5 / h:g} Hz): above the cut-off the noise is not white, so σ_d = N/√Δt at the IMU rate "
            f"overstates the noise of one sample and ignores that neighbouring samples are correlated "
            f"(over about {1 / (2 * math.pi * fc):.3g} s); the density N holds below the cut-off")


register_nav_term(White, "N", lambda label, v, h: (math.sqrt(float(v[f"{label}.r"]) * h), f"{label}.r", 0.5))
register_nav_term(Quantisation, "N")  # (white: Δ²/12 adds to the white variance)
register_nav_term(RandomWalk, "K", lambda label, v, h: (float(v[f"{label}.sigma"]), f"{label}.sigma", 1.0))
register_nav_term(Offset, "bias")
register_nav_term(Ramp, "R")
register_nav_term(LowPass, note=_filter_note)
NAV_TERMS.seal()

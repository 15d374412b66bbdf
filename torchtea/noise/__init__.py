"""Noise models assembled from physical components (:mod:`.components`) into what every engine reads
(:mod:`.model`) and its derivatives (:mod:`.derivatives`), their simulation (:mod:`.simulate`) and the TEA's settings read from a model (:mod:`.tea`).

Its layer is the model's: it may import :mod:`torchtea.core`, :mod:`torchtea.render`, the lowest layer of
:mod:`torchtea.sensors` (its readers, and ``io.write_columns`` for a simulated recording) and :mod:`torchtea.engines` (the TEA's structures and GL kernels), never the likelihoods,
fits or checks above it, and runs no statistical test (``tests/test_layers.py``)."""
from .components import COMPONENTS, ORDER_BOUNDS, ParamSpec
from .model import NoiseModel, StateSpace, parse_model, state_memory
from .simulate import Simulation, default_values, simulate_model, simulate_states, temperature_profile

__all__ = ["COMPONENTS", "ORDER_BOUNDS", "ParamSpec", "NoiseModel", "StateSpace", "parse_model", "state_memory",
           "Simulation", "simulate_model", "simulate_states", "default_values", "temperature_profile"]

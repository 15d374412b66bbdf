"""torchtea — fractional-order noise identification with the Triple Estimation Algorithm, batched in PyTorch.

Batch convention (used everywhere)
----------------------------------
* Leading dimensions ``*B`` are batch: realisations, axes, candidate models. A
  Monte Carlo study is "just a bigger batch". Batch shapes are combined with
  :func:`torch.broadcast_shapes`, never guessed from ``ndim``.
* Inside filters time is the loop, not a dimension. Stored trajectories put
  time at dimension ``-2`` for vectors (``(*B, N, n)``) and ``-3`` for matrices
  (``(*B, N, n, n)``).
* Sigma points sit between batch and event: ``(*B, S, n)``.
* GL series functions (:mod:`torchtea.core.gl`) take time as the last dimension.
* float64 by default; dtype and device follow the inputs; randomness comes
  from an explicit :class:`torch.Generator`.
"""
from .core.gl import difference, gl_coefficients, history_sum
from .core.memory import MemoryConfig, parse_memory
from .engines.presets import PRESETS, SCENARIOS, get_preset
from .engines.settings import StateFilterConfig, TEAConfig, UnscentedConfig
from .engines.structure import (
    ConstantOrder,
    FunctionOrder,
    InputOrder,
    LinearOrder,
    OrderSchedule,
    ParabolicOrder,
    ParametricMatrix,
    Structure,
    parse_order_spec,
)
from .engines.tea import TEAParams, TEAResult, make_params, run_tea, stack_params
from .noise.simulate import Simulation, gaussian_input, simulate

__version__ = "0.1.0"

__all__ = [
    "difference", "gl_coefficients", "history_sum",
    "MemoryConfig", "parse_memory",
    "ConstantOrder", "FunctionOrder", "InputOrder", "LinearOrder", "OrderSchedule", "ParabolicOrder",
    "ParametricMatrix", "Structure", "parse_order_spec",
    "PRESETS", "SCENARIOS", "get_preset",
    "Simulation", "gaussian_input", "simulate",
    "StateFilterConfig", "TEAConfig", "TEAParams", "TEAResult", "UnscentedConfig", "make_params", "run_tea",
    "stack_params",
]

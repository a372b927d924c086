"""jaxworm: a differentiable JAX simulator of worm-inspired burrowing by crack propagation.

The model is that of "Burrowing Locomotion via Crack Propagation of a Bio-inspired Soft
Robot" (eqs. 1-25, Table 1), with the conventions of `MODEL.md`. float64 throughout.
"""

import jax as _jax

_jax.config.update("jax_enable_x64", True)

from . import _physics as physics  # noqa: E402
from . import paper, plot  # noqa: E402
from ._box import AbstractBox, SigmoidBox, SineBox  # noqa: E402
from ._control import AbstractController, TravellingWave, whole_period_horizon  # noqa: E402
from ._dynamics import (
    WormState,
    crack_condition,
    crack_jump,
    forces,  # noqa: E402
    initial_crack_tip,
    initial_state,
    stress_intensity_of,
    vector_field,
)
from ._energy import energy_residual, energy_terms  # noqa: E402
from ._files import ResultFileError  # noqa: E402
from ._history import OptimiseResult, load_optimisation  # noqa: E402
from ._identify import identify, observe  # noqa: E402
from ._numerics import PRESETS, SOLVERS, Numerics  # noqa: E402
from ._objectives import cost_of_transport  # noqa: E402
from ._optimise import DEFAULT_BOUNDS, optimise  # noqa: E402
from ._optimiser import default_optimiser, make_optimiser, rprop  # noqa: E402
from ._params import (
    FLAT_NAMES,
    Body,
    Params,
    Smoothing,
    Soil,
    params_valid,  # noqa: E402
    speed_bound,
)
from ._result import (
    STATUS,
    Result,
    Trajectory,
    mean_velocity,
    status_message,  # noqa: E402
    status_name,
)
from ._rosenbrock import ForwardOnlyError  # noqa: E402
from ._segment_gait import SegmentWave, apply_segments, segment_bounds  # noqa: E402
from ._solve import SensitivityUnavailableError, simulate  # noqa: E402
from ._sweep import SWEEP_FIELDS, SweepResult, load_sweep, sweep  # noqa: E402
from ._version import __version__  # noqa: E402

__all__ = [
    "AbstractController",
    "Body",
    "FLAT_NAMES",
    "Numerics",
    "PRESETS",
    "Params",
    "Result",
    "SOLVERS",
    "STATUS",
    "Smoothing",
    "Soil",
    "Trajectory",
    "TravellingWave",
    "WormState",
    "crack_condition",
    "crack_jump",
    "energy_residual",
    "energy_terms",
    "forces",
    "initial_crack_tip",
    "initial_state",
    "mean_velocity",
    "params_valid",
    "physics",
    "simulate",
    "status_name",
    "status_message",
    "speed_bound",
    "stress_intensity_of",
    "vector_field",
    "sweep",
    "load_sweep",
    "SWEEP_FIELDS",
    "SweepResult",
    "optimise",
    "load_optimisation",
    "OptimiseResult",
    "cost_of_transport",
    "AbstractBox",
    "SineBox",
    "SigmoidBox",
    "make_optimiser",
    "whole_period_horizon",
    "ForwardOnlyError",
    "SensitivityUnavailableError",
    "ResultFileError",
    "DEFAULT_BOUNDS",
    "default_optimiser",
    "rprop",
    "identify",
    "observe",
    "SegmentWave",
    "apply_segments",
    "segment_bounds",
    "paper",
    "plot",
    "__version__",
]

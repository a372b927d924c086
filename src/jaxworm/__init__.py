"""jaxworm: a differentiable JAX simulator of worm-inspired burrowing by crack propagation.

The model is that of "Burrowing Locomotion via Crack Propagation of a Bio-inspired Soft
Robot" (eqs. 1-25, Table 1), with the conventions of `MODEL.md`. float64 throughout.
"""

import jax as _jax

_jax.config.update("jax_enable_x64", True)

from . import _physics as physics
from . import paper, plot
from ._box import BOXES, AbstractBox, SigmoidBox, SineBox
from ._control import HORIZONS, AbstractController, TravellingWave, whole_period_horizon
from ._dynamics import (
    WormState,
    control_rate,
    crack_condition,
    crack_jump,
    forces,
    initial_crack_tip,
    initial_state,
    sensors_of,
    stress_intensity_of,
    vector_field,
)
from ._energy import energy_residual, energy_terms
from ._feedback import AbstractFeedbackController, PolicyMLP, ReflexWave
from ._files import ResultFileError
from ._history import OptimiseResult, load_optimisation
from ._identify import identify, observe
from ._numerics import PRESETS, SOLVERS, Numerics
from ._objectives import cost_of_transport
from ._optimise import DEFAULT_BOUNDS, optimise
from ._optimiser import (
    DEFAULT_OPTIMISERS,
    OPTIMISERS,
    default_optimiser,
    make_optimiser,
    rprop,
)
from ._params import (
    FLAT_NAMES,
    MODEL_OPTIONS,
    Body,
    Params,
    Smoothing,
    Soil,
    params_valid,
    speed_bound,
)
from ._result import (
    STATUS,
    Result,
    Trajectory,
    mean_velocity,
    status_message,
    status_name,
)
from ._rosenbrock import ForwardOnlyError
from ._segment_gait import SegmentWave, apply_segments, segment_bounds
from ._sensitivity import SecondDerivativeError
from ._sensors import SensorNoise, Sensors
from ._soil import AbstractProfile, Gradient, Layered, RandomField
from ._solve import SensitivityUnavailableError, simulate
from ._sweep import (
    CHUNK_COST,
    CHUNK_SECONDS,
    MAX_SCENES,
    SWEEP_FIELDS,
    SweepResult,
    default_chunk,
    load_sweep,
    sweep,
)
from ._train import TrainResult, load_training, train
from ._version import __version__

__all__ = [
    "BOXES",
    "HORIZONS",
    "DEFAULT_OPTIMISERS",
    "OPTIMISERS",
    "AbstractController",
    "Body",
    "FLAT_NAMES",
    "MODEL_OPTIONS",
    "Numerics",
    "PRESETS",
    "Params",
    "Result",
    "SOLVERS",
    "STATUS",
    "Smoothing",
    "Soil",
    "AbstractProfile",
    "Layered",
    "Gradient",
    "RandomField",
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
    "default_chunk",
    "CHUNK_SECONDS",
    "CHUNK_COST",
    "MAX_SCENES",
    "optimise",
    "load_optimisation",
    "OptimiseResult",
    "train",
    "load_training",
    "TrainResult",
    "cost_of_transport",
    "AbstractBox",
    "SineBox",
    "SigmoidBox",
    "make_optimiser",
    "whole_period_horizon",
    "ForwardOnlyError",
    "SecondDerivativeError",
    "SensitivityUnavailableError",
    "ResultFileError",
    "DEFAULT_BOUNDS",
    "default_optimiser",
    "rprop",
    "identify",
    "observe",
    "SegmentWave",
    "AbstractFeedbackController",
    "ReflexWave",
    "PolicyMLP",
    "Sensors",
    "SensorNoise",
    "sensors_of",
    "control_rate",
    "apply_segments",
    "segment_bounds",
    "paper",
    "plot",
    "__version__",
]

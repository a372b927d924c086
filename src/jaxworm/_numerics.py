"""Numerical settings: which diffrax solver, step control, error norm and bounds.

Everything here is static configuration (it shapes the compiled program), so a
`Numerics` is hashable and changing it recompiles.
"""

from __future__ import annotations

import dataclasses
from typing import Literal

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx

from ._linear_solve import FACTORS
from ._rosenbrock import Rodas4
from ._sensitivity import Rodas4Sensitivity
from ._validation import check_int, check_option_float, option_float, show, static_int

ROSENBROCK = {"Rodas4": Rodas4}

__all__ = ["Numerics", "SOLVERS", "PRESETS"]

SOLVERS = (
    "Rodas4",
    "Kvaerno3",
    "Kvaerno4",
    "Kvaerno5",
    "KenCarp3",
    "KenCarp4",
    "KenCarp5",
    "ImplicitEuler",
    "Tsit5",
)
NORMS = ("full", "positions")
ADJOINTS = ("reverse", "forward")
CRACK_SENSITIVITIES = ("schedule_held", "exact", "tips_held")


#: String options and their choices.
CHOICES = {
    "solver": SOLVERS,
    "norm": NORMS,
    "newton": ("chord", "full"),
    "linear_solve": ("structured", "structured_lanes", "dense"),
    "adjoint": ADJOINTS,
    "crack_sensitivity": CRACK_SENSITIVITIES,
    "sensitivity_frame": ("phase", "time"),
    "sensitivity_norm": ("state", "mean_position"),
    "interpolant": ("rodas", "hermite"),
}

#: Float options: (check, allowed range as text, None allowed). Every one finite.
#: Largest `event_rtol` and `event_atol`: the crack times are located to at least this.
EVENT_TOL_MAX = 1e-6

FLOAT_OPTIONS = {
    "rtol": (lambda v: (v >= 0) & (v < 1), ">= 0 and < 1", False),
    "atol": (lambda v: v > 0, "> 0", False),
    "dt": (lambda v: v > 0, "> 0", True),
    "dt_max": (lambda v: v > 0, "> 0", True),
    "newton_rtol": (lambda v: v > 0, "> 0", False),
    "newton_atol": (lambda v: v > 0, "> 0", False),
    # PID coefficients are fractions of the error exponent (Söderlind): 0.3/0.4 by
    # default, 0/1 for the integral controller; beyond 1 the steps oscillate.
    "pcoeff": (lambda v: (v >= 0) & (v <= 1), ">= 0 and <= 1", False),
    "icoeff": (lambda v: (v > 0) & (v <= 1), "> 0 and <= 1", False),
    # A crack time located to 1e-2 (s, relative) was seen 0.45 s early with status ok:
    # the bisection's tolerances are bounded so that the crack times stay exact to
    # far below a step of the solve.
    "event_rtol": (
        lambda v: (v > 0) & (v <= EVENT_TOL_MAX),
        f"> 0 and <= {EVENT_TOL_MAX:g}",
        False,
    ),
    "event_atol": (
        lambda v: (v > 0) & (v <= EVENT_TOL_MAX),
        f"> 0 and <= {EVENT_TOL_MAX:g} s",
        False,
    ),
    "energy_tol": (lambda v: v > 0, "> 0", False),
    "sensitivity_tol": (lambda v: v > 0, "> 0", True),
    "sensitivity_ramp": (lambda v: v >= 0, ">= 0 s", False),
}

#: Integer options and their largest values (the smallest is 1). `max_cracks` sizes the
#: per-crack records and the segment loop (10**9 ran XLA out of memory); a run of 2**31
#: steps would take days; a Newton iteration that has not converged in 1000 never will.
INT_OPTIONS = {"max_steps": 2**31 - 1, "max_cracks": 10_000, "newton_max_steps": 1000}

#: Values that stand in for a traced float option that fails its check (`placeholder`).
_SAFE = {"dt": 1e-4, "dt_max": 1.0}


def _state_norm(which: str):
    """RMS error norm over (x, v, l̄) ("full") or (x, l̄) ("positions").

    The work integrals never steer the step size: they are quadratures of the state.
    """

    def norm(tree):
        parts = (tree.x, tree.v, tree.lbar) if which == "full" else (tree.x, tree.lbar)
        return optx.rms_norm(parts)

    return norm


class StepController(diffrax.PIDController):
    """diffrax's PID step-size controller that ends the solve (`dt_min_reached`) when
    the next step would have no length (t + dt == t in floating point).

    Where the vector field is not finite beyond some time (a controller that returns
    NaN), every step across that time is rejected and the step size shrinks until
    t + dt rounds to t. A step of no length has no error, so the PID controller accepted
    it, and every later one, until `max_steps`, which then named the step bound as the
    cause. The solve now ends when its next step would have no length (or a NaN one).
    Nothing else changes: a step that has a length is controlled as before.
    """

    def adapt_step_size(self, t0, t1, y0, y1_candidate, args, y_error, error_order, state):
        keep, next_t0, next_t1, jump, state, result = super().adapt_step_size(
            t0, t1, y0, y1_candidate, args, y_error, error_order, state
        )
        stalled = ~(next_t1 > next_t0)  # also a NaN step (a state already NaN)
        result = diffrax.RESULTS.where(
            stalled & (result == diffrax.RESULTS.successful), diffrax.RESULTS.dt_min_reached, result
        )
        return keep, next_t0, next_t1, jump, state, result


class EventBisection(optx.Bisection):
    """Bisection for diffrax's event root find, safe under `vmap`, of one event
    condition or a tuple of them.

    Under `vmap`, diffrax root-finds every lane when any lane has an event; a lane
    without one gets g(t) = t_next − t, which decreases to its root at the step's end.
    optimistix's bracket check would throw there, so the orientation is read from the
    ends of each lane's bracket and never checked.

    With several conditions diffrax hands over one value per condition: the one that
    fired gives its own value, each other exactly 0 (where none fired, each gives
    t_next − t). The bisection follows the value of largest magnitude, which is that
    value unchanged (`_fired`).
    """

    def init(self, fn, y, args, options, f_struct, aux_struct, tags):
        fn = _fired(fn)
        f_struct = jax.ShapeDtypeStruct((), jnp.result_type(*jax.tree_util.tree_leaves(f_struct)))
        state = optx.Bisection(rtol=self.rtol, atol=self.atol, flip=False).init(
            fn, y, args, options, f_struct, aux_struct, tags
        )
        lower_val, _ = fn(state.lower, args)
        upper_val, _ = fn(state.upper, args)
        return dataclasses.replace(state, flip=lower_val > upper_val)

    def step(self, fn, y, args, options, state, tags):
        return super().step(_fired(fn), y, args, options, state, tags)

    def terminate(self, fn, y, args, options, state, tags):
        return super().terminate(_fired(fn), y, args, options, state, tags)


def _fired(fn):
    """`fn` with its values (one per event condition) reduced to the one of largest
    magnitude, the first among equals; a single value passes unchanged."""

    def one(y, args):
        values, aux = fn(y, args)
        leaves = jax.tree_util.tree_leaves(values)
        value = leaves[0]
        for v in leaves[1:]:
            value = jnp.where(jnp.abs(v) > jnp.abs(value), v, value)
        return value, aux

    return one


class Numerics(eqx.Module):
    """How to solve: solver, step-size control, error norm, bounds and checks.

    - `solver`: one of `SOLVERS`; default `"Kvaerno3"`. `"Rodas4"` (preset `fast`) is
      this package's Rosenbrock method (docs: Numerics and presets): one exact Jacobian and
      one small LU per step, no Newton iteration, cheaper per step than diffrax's
      Kvaerno solvers; `simulate` differentiates it by forward
      sensitivities (`sensitivity_tol`), never through its steps.
      The others are diffrax's; KenCarp* solve the stiff part (springs, friction)
      implicitly and the control and back pressure explicitly.
    - `linear_solve`: for Rosenbrock solvers, `"structured"` (default) solves only the
      N×N Schur complement of the Newton matrix, which is tridiagonal, with its bands
      from eight coloured directional derivatives instead of a full Jacobian, and drops
      the rows of the work integrals (`structured_factor`); `"structured_lanes"` is the
      same solve written for vmapped lanes, faster there and slower alone (`jw.sweep`
      uses it for its chunks); `"dense"` forms the Jacobian and factorises the whole
      (3N + 3)-square matrix. Same (x, v, l̄) to rounding; the work integrals, which
      feed nothing back, differ at the solver's tolerance.
    - `rtol`, `atol`: PID controller tolerances (adaptive stepping). The default,
      rtol = 0 and atol = 1e-8 m, bounds the local error of every position absolutely:
      positions grow as the worm travels, while the motion that matters is on the
      scale of the gait (A/ω ~ 1 mm).
    - `norm`: `"positions"` (default) measures the local error on (x, l̄) only, which
      lets the L-stable solvers step over the undamped elastic ringing (~1e4 rad/s)
      instead of resolving it; `"full"` measures it on (x, v, l̄) and resolves the
      ringing (tens of thousands of steps per simulated second). Both converge to the
      same mean velocity (see `benchmarks/`).
    - `pcoeff`, `icoeff`: PID coefficients (default 0.3, 0.4: fewer rejected steps than
      the integral-only controller on this problem).
    - `dt`: a fixed step [s] instead of adaptive control (`ImplicitEuler` with a fixed
      step is the paper's own method); the Newton iteration then uses `newton_rtol`,
      `newton_atol` and at most `newton_max_steps` iterations.
    - `newton`: `"chord"` (diffrax's default: the Jacobian once per step) or `"full"`
      (a fresh Jacobian every iteration, as the paper's backward Euler does; needed for
      fixed steps much longer than the friction time scale).
    - `dt_max`: largest adaptive step [s] (`None`: unbounded).
    - `max_steps`: bound on steps between two crack events (1 to 2**31 − 1).
    - `max_cracks`: bound on crack events (1 to 10,000); reaching it ends the run with status
      `"too_many_cracks"`, never a silent truncation.
    - `event_rtol`, `event_atol`: tolerances of the bisection that locates a crack time
      on the step's dense output (bisection: Newton on the cubic interpolant was seen to
      fail to converge at an event); each > 0 and ≤ 1e-6 (`EVENT_TOL_MAX`).
    - `adjoint`: how derivatives go through the solve of a diffrax solver (not
      Rodas4). `"reverse"` (default): diffrax's recursive checkpointing, for
      `jax.grad`/`jax.vjp`. `"forward"`: `diffrax.ForwardMode`, for `jax.jvp`/
      `jax.jacfwd` (`jax.grad` then raises). Both run under `vmap` through crack events.
      With Rodas4 (the `fast` preset, `simulate`'s default) both `jax.grad` and
      `jax.jacfwd` work, through forward sensitivities (`sensitivity_tol`).
    - `crack_sensitivity`: what a derivative does at the crack events.
      `"schedule_held"` (default): every crack keeps its gait phase (its time, for a gait
      without a frequency) and the new tip follows the state by eq. (13). The exact
      derivative of a long-horizon mean velocity through many cracks is that of a
      piecewise-smooth function: near-grazing events (K_I barely reaching K_Ic) make the
      tips' sensitivities grow from crack to crack, and the exact derivative then swings
      far from the slope that finite differences see (docs: Gradients). Holding the
      schedule gives that slope (`benchmarks/gradient_accuracy.py`). The derivatives of the
      per-crack records (`crack_times`, `crack_tips`, `crack_x1`, `crack_l1`) and of the
      tip after the first crack (`x_c`; the trajectory's `x_c`, `K_I`, `back_pressure`)
      are then NaN: they are not available under this surrogate. Derivatives with
      respect to K_Ic and K_Ith raise `SensitivityUnavailableError` (they act through
      the schedule the surrogate holds). `"exact"`: the exact
      derivative (jump conditions at every event; right on short horizons, tested
      against finite differences). `"tips_held"`: each new tip held constant (a cruder
      surrogate, further off the slope). Values never change. With
      a diffrax solver `"schedule_held"` is not available: differentiating raises and
      says to use Rodas4 or another mode. Both held modes raise for a feedback
      controller that reads the crack (`Sensors.stress_ratio` or `back_pressure`, as
      `ReflexWave` and `PolicyMLP` do): they drop how its u moves with the crack times
      (docs: Gradients). A run that does not end ok has NaN derivatives.
    - `sensitivity_tol`: with Rodas4, forward sensitivities S = ∂y/∂θ are integrated
      with the state (docs: Gradients) and their local error enters the step
      control with tolerance `atol · sensitivity_tol` on θ·S (lengths, as the state's
      positions). Default 10, chosen on the checks of `benchmarks/gradient_accuracy.py`
      and `benchmarks/sensitivity_tol.py` (docs: Gradients). `None` leaves them out of
      the step control: the steps are the forward solve's, but the derivative is then
      uncontrolled, and was seen far off at 60 s (docs: Gradients).
    - `sensitivity_norm`: which sensitivities' local error enters the step control with
      Rodas4. `"state"` (default): those of every position the state norm measures (x
      and l̄ of every node), so every output's derivative is controlled. `"mean_position"`:
      those of the mean node position alone, the one the mean velocity reads
      (goal-oriented control): fewer steps, the mean velocity's derivative as close to
      the finite-difference slope on the 60-s scenes of `benchmarks/gradient_accuracy.py`
      (docs: Gradients), other outputs' derivatives uncontrolled.
      `jw.optimise` takes it for its `"velocity"` objective when given no numerics.
    - `sensitivity_frame`: `"phase"` (default) integrates the sensitivities at fixed
      gait phase τ = ωt and converts them at the end (and at events, where needed):
      along ω the state at a fixed time moves with the phase, a term t·ẏ/ω that grows
      with t and carries every fast feature of ẏ, and controlling its error takes
      several times the steps; at fixed phase the response is small. `"time"`: at
      fixed time. The same for a gait without a period (`AbstractController.period`). Only with
      `"schedule_held"`, where a crack keeps its phase and nothing is converted at the
      events; the other modes convert there through the velocity at the event, which the
      positions error norm does not control (crack-time derivatives were seen off),
      so they run at fixed time.
    - `sensitivity_ramp`: seconds t_s over which the phase frame turns on from fixed
      time at the start of the run, φ(t) = t (1 − e^{−t/t_s}) in place of the phase t:
      at fixed phase the sensitivities are driven by the start-up's elastic ringing, and
      controlling their error there takes many short steps. Any value gives the same
      derivative to the solve's tolerance; 0 is the plain phase frame. Default 1,
      chosen on the steps and errors of `benchmarks/sensitivity_ramp.py` (docs:
      Gradients).
    - `sensitivity_hessian`: keep the second-derivative term of the augmented Jacobian
      in the sensitivity stages (RODAS on (y, S) exactly; default). `False` drops it (a
      W-method on the sensitivities): fewer operations per step, but d v̄/dω was seen
      several % off (scaled) at 60 s (docs: Gradients).
    - `interpolant`: a Rosenbrock solver's dense output, on which the crack events are
      located: `"rodas"` (default) the method's own third-order continuous extension,
      formed from the stages at no extra cost; `"hermite"` the cubic Hermite from the
      vector field at both ends of the step (one more evaluation of the vector field,
      and of the sensitivities' field, per step).
    - `energy_tol`: a run whose energy-balance residual, relative to the energy that
      flowed (in a gait the gross actuation work ∫|∂V/∂l̄·u|; `jaxworm.energy_residual`),
      exceeds this is flagged `"energy_balance"` (a likely false solution).

    The float options (`FLOAT_OPTIONS`: tolerances, PID coefficients, `dt`, `dt_max`,
    `sensitivity_tol`, `sensitivity_ramp`, ...) are inputs of `simulate`'s compiled
    program, as the parameters are: another value of them runs the program already
    compiled (and kept on disk). The others (solver, norm, the integer bounds, the
    choices, and whether `dt`, `dt_max` or `sensitivity_tol` is None) choose the program.
    """

    solver: str = "Kvaerno3"
    rtol: float = eqx.field(default=0.0, converter=option_float)
    atol: float = eqx.field(default=1e-8, converter=option_float)
    norm: Literal["full", "positions"] = "positions"
    dt: float | None = eqx.field(default=None, converter=option_float)
    dt_max: float | None = eqx.field(default=None, converter=option_float)
    newton_rtol: float = eqx.field(default=1e-8, converter=option_float)
    newton_atol: float = eqx.field(default=1e-12, converter=option_float)
    newton_max_steps: int = eqx.field(default=10, converter=static_int)
    newton: Literal["chord", "full"] = "chord"
    pcoeff: float = eqx.field(default=0.3, converter=option_float)
    icoeff: float = eqx.field(default=0.4, converter=option_float)
    max_steps: int = eqx.field(default=2**20, converter=static_int)
    max_cracks: int = eqx.field(default=64, converter=static_int)
    event_rtol: float = eqx.field(default=1e-10, converter=option_float)
    event_atol: float = eqx.field(default=1e-12, converter=option_float)
    energy_tol: float = eqx.field(default=0.05, converter=option_float)
    linear_solve: Literal["structured", "structured_lanes", "dense"] = "structured"
    adjoint: Literal["reverse", "forward"] = "reverse"
    crack_sensitivity: Literal["exact", "tips_held", "schedule_held"] = "schedule_held"
    sensitivity_hessian: bool = True
    sensitivity_tol: float | None = eqx.field(default=10.0, converter=option_float)
    sensitivity_frame: Literal["phase", "time"] = "phase"
    sensitivity_norm: Literal["state", "mean_position"] = "state"
    sensitivity_ramp: float = eqx.field(default=1.0, converter=option_float)
    interpolant: Literal["rodas", "hermite"] = "rodas"

    def __check_init__(self):
        for name, choices in CHOICES.items():
            value = getattr(self, name)
            if not (isinstance(value, str) and value in choices):
                raise ValueError(
                    f"option {name} = {show(value)}: need one of "
                    f"{', '.join(repr(c) for c in choices)}"
                )
        if not isinstance(self.sensitivity_hessian, bool):
            raise TypeError(
                f"option sensitivity_hessian = {show(self.sensitivity_hessian)}: need True or False"
            )
        for name, (ok, allowed, allow_none) in FLOAT_OPTIONS.items():
            check_option_float(name, getattr(self, name), ok, allowed, allow_none)
        for name, hi in INT_OPTIONS.items():
            check_int(name, getattr(self, name), 1, hi, kind="option")

    def replace(self, **kw) -> Numerics:
        return dataclasses.replace(self, **kw)

    # --- builders used by the solve ---------------------------------------------------

    @property
    def fixed_step(self) -> bool:
        return self.dt is not None

    def build_solver(self):
        """The solver (a Rosenbrock solver's stages unrolled)."""
        if self.solver in ROSENBROCK:
            factor = FACTORS[self.linear_solve]
            return ROSENBROCK[self.solver](factor=factor, interpolant=self.interpolant)
        cls = getattr(diffrax, self.solver)
        if self.solver == "Tsit5":
            return cls()
        kind = optx.Newton if self.newton == "full" else diffrax.VeryChord
        if self.fixed_step:
            root = kind(rtol=self.newton_rtol, atol=self.newton_atol, norm=_state_norm("full"))
            return cls(root_finder=root, root_find_max_steps=self.newton_max_steps)
        if self.newton == "full":
            root = optx.Newton(rtol=self.rtol, atol=self.atol, norm=_state_norm(self.norm))
            return cls(root_finder=root)
        return cls()

    def build_sensitivity_solver(self, vf):
        """The solver that carries forward sensitivities with the state (`_sensitivity`)."""
        factor = FACTORS[self.linear_solve]
        return Rodas4Sensitivity(
            vf=vf, factor=factor, hessian=self.sensitivity_hessian, interpolant=self.interpolant
        )

    def build_controller(self):
        if self.fixed_step:
            return diffrax.ConstantStepSize()
        return StepController(
            rtol=self.rtol,
            atol=self.atol,
            norm=_state_norm(self.norm),
            pcoeff=self.pcoeff,
            icoeff=self.icoeff,
            dtmax=self.dt_max,
        )

    @property
    def imex(self) -> bool:
        return self.solver.startswith("KenCarp")

    def build_adjoint(self):
        if self.adjoint == "forward":
            return diffrax.ForwardMode()
        return diffrax.RecursiveCheckpointAdjoint()

    def root_finder(self):
        return EventBisection(rtol=self.event_rtol, atol=self.event_atol)


def numerics_valid(n: Numerics):
    """The checks of the float options that hold arrays (traced under vmap), as a traced
    boolean; True when every option is a Python value (checked at construction)."""
    ok = jnp.asarray(True)
    for name, (check, _, _) in FLOAT_OPTIONS.items():
        value = getattr(n, name)
        if isinstance(value, jax.Array):
            ok = ok & jnp.isfinite(value) & check(value)
    return ok


def dynamic_floats(n: Numerics) -> Numerics:
    """`n` with every float option that holds a Python number as a float64 array: a
    program then takes the tolerances as inputs, so one compiled program serves every
    value of them (a value is not part of a compiled program's key). Options that are
    None stay None: they choose what the program does."""
    arrays = {
        name: jnp.asarray(value, jnp.float64)
        for name in FLOAT_OPTIONS
        if isinstance(value := getattr(n, name), float)
    }
    return dataclasses.replace(n, **arrays) if arrays else n


def placeholder(n: Numerics, valid) -> Numerics:
    """`n` with every array-valued float option replaced by its default where `valid` is
    False (a lane that takes no step; see `simulate`)."""
    fields = {f.name: f for f in dataclasses.fields(n)}
    safe = {}
    for name in FLOAT_OPTIONS:
        value = getattr(n, name)
        if isinstance(value, jax.Array):
            fallback = _SAFE.get(name, fields[name].default)
            # Every float option has a default; dt and dt_max (default None) are in _SAFE.
            assert fallback is not None and fallback is not dataclasses.MISSING
            safe[name] = jnp.where(valid, value, fallback)
    return dataclasses.replace(n, **safe) if safe else n


#: Named settings. `default`: Kvaerno3, local error of positions ≤ 1e-8 m (~1e-4 in the
#: 60-s mean velocity; benchmarks/results/core_timing/core_timing.md), differentiated by diffrax;
#: `fast`: Rodas4 with the same tolerance (~1e-3), `simulate`'s default, differentiated
#: by forward sensitivities; `accurate`: Kvaerno5, atol 1e-10 m;
#: `reference`: full error norm, resolves the elastic ringing (slow: for checks);
#: `paper`: the paper's fixed-step backward Euler.
PRESETS: dict[str, Numerics] = {
    "default": Numerics(),
    "accurate": Numerics(solver="Kvaerno5", atol=1e-10),
    "fast": Numerics(solver="Rodas4"),
    "reference": Numerics(
        solver="Kvaerno5",
        rtol=1e-9,
        atol=1e-12,
        norm="full",
        pcoeff=0.0,
        icoeff=1.0,
        max_steps=2**24,
    ),
    # dt = 5e-4 s fails to converge its Newton iteration at the first friction reversal
    # (~0.1 s) on the Table 1 gait; 1e-4 s is the largest power-of-ten step that runs.
    "paper": Numerics(
        solver="ImplicitEuler",
        dt=1e-4,
        newton="full",
        newton_max_steps=8,
        newton_rtol=1e-6,
        newton_atol=1e-9,
    ),
}

"""Solve the hybrid system: diffrax between cracks, eq. (13) at each crack event.

The loop over crack segments is a `lax.scan` of fixed length `max_cracks + 1`, each
step one `diffeqsolve` that terminates on the crack `Event`, or on the body's collapse
(`body_collapsed`: the run ends `body_inverted` at the first step that reaches it);
finished runs skip the remaining segments. The scan keeps reverse-mode differentiation available (a
`while_loop` would not), and `vmap` batches everything. A sweep's chunks, forward only,
run the same steps and events as one loop of steps per lane instead (`simulate_steps`,
`jaxworm._steps`), so that no lane of a batch waits at another's crack segments.
"""

from __future__ import annotations

import contextlib
import sys
from typing import Any

import diffrax
import equinox as eqx
import equinox.internal as eqxi
import jax
import jax.numpy as jnp
import optimistix as optx
from jaxtyping import Array, Float

from . import _physics as phys
from ._cache import configure_compilation_cache, exported_call, result_skeleton
from ._control import check_horizon, simulated_horizon
from ._dynamics import (
    WormState,
    body_collapsed,
    collapse_condition,
    crack_condition,
    crack_jump,
    forces,
    initial_crack_tip,
    initial_state,
    reads_crack,
    stress_intensity_of,
    vector_field,
    vector_field_nonstiff,
    vector_field_stiff,
)
from ._energy import energy_residual
from ._numerics import PRESETS, ROSENBROCK, Numerics, dynamic_floats, numerics_valid
from ._numerics import placeholder as numerics_placeholder
from ._params import Params, params_valid, speed_bound
from ._params import placeholder as params_placeholder
from ._result import STATUS_CODE, Result, Trajectory, mean_velocity_of
from ._rosenbrock import refusing
from ._sensitivity import Frame, at_fixed_time, event_jump, sensitivity_field, split_params
from ._steps import initial_carry, result_of, run_steps
from ._validation import check_t1, check_ts, concrete, ts_valid

__all__ = ["simulate", "simulate_steps", "SensitivityUnavailableError"]


def simulate(
    params: Params,
    t1: float | Float[Array, ""] = 60.0,
    numerics: Numerics | None = None,
    ts: Float[Array, " T"] | None = None,
    *,
    horizon: str = "t1",
) -> Result:
    """Simulate the worm from rest over [0, t1] [s].

    `horizon`: `"t1"` (default) simulates [0, t1]; `"whole_periods"` simulates up to
    the end of the gait's last whole period in it, K·T with K = ⌊t1/T⌋ and T the
    gait's `period()` (`whole_period_horizon`), so that the mean velocity averages over
    whole periods; a t1 shorter than one period raises `ValueError` (a traced one ends
    `"invalid_parameters"`). `Result.t1` is the end time simulated.

    `numerics` defaults to the `fast` preset (Rodas4): the fastest setting within 1 % in
    mean velocity on every scene of the presets check.

    `ts` (optional) asks for dense output at those times (`Result.trajectory`); without
    it only the summary is kept, as a sweep needs. Jit-compiled; `vmap` over batched
    parameters works as usual.

    **Derivatives.** `jax.jacfwd`, `jax.jvp`, `jax.grad` and `jax.vjp` work with respect
    to the parameters and `t1`, under `vmap`, through crack events. With Rodas4 they
    come from forward sensitivities integrated with the state (docs: Gradients):
    one solve carries ∂y/∂θ along every perturbed parameter, with its error in the step
    control, and the JVP is that sensitivity matrix applied to the tangent, so reverse
    mode transposes a contraction. At each crack event the derivative follows
    `numerics.crack_sensitivity`; the default, `"schedule_held"`, holds every crack at
    its gait phase and lets the new tip follow the state. That is not the exact
    derivative: the exact one (`"exact"`) is right on short horizons but, through tens
    of cracks, swings far from the slope that finite differences of the mean velocity
    see (near-grazing events make the tips' sensitivities grow from crack to crack).
    The default gives that slope: within 2 % (scaled) of finite differences of a tight
    solve on the 60-s scenes of `benchmarks/gradient_accuracy.py`. Under it the
    derivatives of the per-crack records (`crack_times`, `crack_tips`, ...) are NaN.
    A derivative along the body's l0, m or EA is taken with `norm="full"` (the solve that
    returns it controls the velocities' error too, many times the steps): with the positions
    norm the solve steps over the elastic ringing these parameters act through, and its
    derivative along them was seen far off finite differences of a tight solve, along m
    of the wrong sign (`benchmarks/body_gradient.py`).
    Over a fixed t1 the derivative in ω includes the gait's phase at t1 (a sawtooth);
    average over whole periods (`horizon="whole_periods"`) for a smooth objective.
    Derivatives with respect to `ts`, or with a fixed step `dt`, raise.

    **Checks.** A Python or NumPy `t1` must be a finite number > 0 (else `ValueError`);
    parameters and numerics are checked when they are built, and `ts` here (finite,
    non-decreasing, within [0, t1]). Values that arrive traced (under `vmap`, `jit`),
    `ts` among them, are checked before the solve: a lane with an invalid value
    takes no step and ends `"invalid_parameters"`, and the other lanes of its batch are
    untouched (bit-identical). A run whose mean velocity exceeds what its gait's stroke
    allows (`speed_bound`) ends `"implausible_speed"`, never `"ok"`. A run stops at
    the first step at which a segment or intrinsic length reaches zero (the body has
    collapsed; nothing past it means anything) and ends `"body_inverted"` there, so a
    collapsing lane holds up no batch.

    ```python
    import jax, jax.numpy as jnp, jaxworm as jw
    p = jw.Params()
    r = jw.simulate(p, 10.0)
    print(r.mean_velocity, r.n_cracks, r.status_name)
    dv_dA = jax.grad(lambda a: jw.simulate(p.replace(A=a), 10.0).mean_velocity)(0.02)
    ```
    """
    return _checked_simulate(params, t1, numerics, ts, horizon, "segments")


def simulate_steps(params: Params, t1, numerics: Numerics | None = None, *, horizon="t1"):
    """`simulate` without dense output, each run one loop of steps with its crack events
    inside (`jaxworm._steps`) instead of a scan of segments: what a vmapped batch of
    gaits (a sweep's chunk) runs fastest, its lanes not waiting for each other at each
    crack. The same checks, steps and statuses. With the Rosenbrock solvers (`fast`)
    only, and forward only there (a derivative raises); with diffrax's solvers, whose
    set-up is `diffeqsolve`'s own, it is `simulate`'s scan of segments, derivatives
    included."""
    return _checked_simulate(params, t1, numerics, None, horizon, "steps")


def _checked_simulate(params, t1, numerics, ts, horizon, loop) -> Result:
    numerics = PRESETS["fast"] if numerics is None else numerics
    if not isinstance(params, Params):
        raise TypeError(f"simulate: params must be a jaxworm.Params, got {type(params).__name__}")
    if not isinstance(numerics, Numerics):
        raise TypeError(
            f"simulate: numerics must be a jaxworm.Numerics or None, got {type(numerics).__name__}"
        )
    t1 = check_t1(t1)
    check_horizon(horizon, params.gait, t1)
    t1 = simulated_horizon(params.gait, t1, horizon)
    ts = check_ts(ts, t1)
    # Values all concrete were checked at construction: the solve needs no mask (and
    # compiles to the program it always was). Any traced value: check before the solve.
    traced = any(not concrete(x) for x in jax.tree_util.tree_leaves((params, numerics, t1, ts)))
    numerics = dynamic_floats(numerics)
    if traced:  # a tolerance that is differentiated raises, naming what to do instead
        numerics = _refusing_tangents(numerics)
    configure_compilation_cache()
    if not traced:
        # Values only: the program traced in an earlier process, when there is one.
        skeleton = result_skeleton(Result, WormState, Trajectory, ts is not None)
        name = "simulate" if loop == "segments" else f"simulate_{loop}"
        result = exported_call(_solve, name, (params, t1, numerics, ts, loop), skeleton)
        if result is not None:
            return result
    return _simulate(params, t1, numerics, ts, traced, loop)


@contextlib.contextmanager
def equinox_checks(setting: str):
    """Trace with equinox's run-time checks (`error_if`) set to `setting` (`"off"`,
    `"nan"` or `"raise"`): equinox reads its `EQX_ON_ERROR` setting when a check is
    traced, so this holds for the programs traced while it lasts (the setting is switched
    for the whole process meanwhile). Where that setting is not found (another equinox
    layout), the checks keep their own setting.

    `"off"` (see `_without_runtime_checks`) leaves the checks out of the program;
    `"nan"` turns a failed check into NaN values instead of an error, which the training
    and optimisation steps record as a non-finite gradient (the step is not taken).
    """
    errors = sys.modules.get("equinox._errors")  # imported with equinox
    saved = getattr(errors, _EQX_SETTING, None)
    if saved is None:  # pragma: no cover - another equinox layout: the checks stay
        yield
        return
    setattr(errors, _EQX_SETTING, setting)
    try:
        yield
    finally:
        setattr(errors, _EQX_SETTING, saved)


def _without_runtime_checks():
    """Trace with equinox's run-time checks left out of the program.

    diffrax checks `SaveAt` times at run time (increasing, within the solve's span) by a
    host callback, and a program with one can neither be exported (`jax.export`) nor
    kept in JAX's persistent compilation cache: every process traced and compiled a
    dense-output `simulate` again. `simulate` checks the times itself,
    before every solve: `check_ts` for values, `ts_valid` (status `invalid_parameters`)
    for traced ones, and each segment clips them to its own span.
    """
    return equinox_checks("off")


#: equinox's setting of what its run-time checks do, read when one is traced.
_EQX_SETTING = "EQX_ON_ERROR"

#: The span, relative to max(t1, 1 s), that a finished lane solves (and discards) while
#: other lanes of a vmapped batch still run: any non-empty span will do.
_FINISHED_SPAN = 1e-6


def _terms(numerics: Numerics):
    if numerics.imex:
        return diffrax.MultiTerm(
            diffrax.ODETerm(vector_field_nonstiff), diffrax.ODETerm(vector_field_stiff)
        )
    return diffrax.ODETerm(vector_field)


@eqx.filter_jit
def _simulate(
    params: Params, t1, numerics: Numerics, ts, traced: bool = True, loop: str = "segments"
) -> Result:
    if not traced:
        return _solve(params, t1, numerics, ts, loop)
    # Check traced values before the solve: an invalid lane runs from t = 0 to 0 (no
    # step), so it costs its batch nothing (a NaN or ω = 0 lane once ran to max_steps).
    # Its non-finite values are replaced by valid placeholders, each by a `where` on that
    # value alone: a value that is not batched stays so, and the batch's program (its
    # rounding, hence its steps) is that of a batch without the check.
    valid = params_valid(params) & numerics_valid(numerics) & jnp.isfinite(t1) & (t1 > 0)
    if ts is not None:
        valid = valid & ts_valid(ts, t1)
        ts = jnp.where(jnp.isfinite(ts), ts, 0.0)  # an invalid lane runs from 0 to 0
    run_params = jax.tree_util.tree_map(
        lambda x, d: jnp.where(jnp.isfinite(x), x, d) if eqx.is_inexact_array(x) else x,
        params,
        params_placeholder(params),
    )
    run_numerics = numerics_placeholder(numerics, valid)
    result = _solve(run_params, jnp.where(valid, t1, 0.0), run_numerics, ts, loop)
    status = jnp.where(valid, result.status, STATUS_CODE["invalid_parameters"])
    result = eqx.tree_at(lambda r: (r.t1, r.status), result, (t1, status))
    # An invalid lane's values are those of its placeholder run: their derivatives are
    # NaN, not the placeholder's (a NaN amplitude once gave d v̄/dA = 0). So are those
    # of any run that did not end ok (stopped at max_cracks, collapsed, ...): it is not
    # the run asked for (one stopped at max_cracks ends at a crack time, which the
    # derivatives would hold fixed: d v̄/dt1 came out 1.3e-3 where it is 0).
    inputs = [x for x in jax.tree_util.tree_leaves((params, t1)) if eqx.is_inexact_array(x)]
    poison = _nan_tangent_unless(status == STATUS_CODE["ok"], inputs)
    return jax.tree_util.tree_map(lambda x: x + poison if eqx.is_inexact_array(x) else x, result)


@jax.custom_jvp
def _nan_tangent_unless(valid, xs):
    """0, with a NaN derivative in `xs` where not `valid` (and 0 where valid)."""
    del xs
    return jnp.where(valid, 0.0, 0.0)  # batched as `valid` is


@_nan_tangent_unless.defjvp
def _nan_tangent_unless_jvp(primals, tangents):
    valid, xs = primals
    _, t_xs = tangents
    total = sum((jnp.sum(t) for t in t_xs), start=jnp.zeros(jnp.shape(valid)))
    return _nan_tangent_unless(valid, xs), jnp.where(valid, 0.0, jnp.nan) * total


def _solve(params: Params, t1, numerics: Numerics, ts, loop: str = "segments") -> Result:
    if loop == "steps" and numerics.solver in ROSENBROCK:
        return run_steps(params, t1, numerics, _terms(numerics), _final_status)
    if numerics.solver in SENSITIVITY_SOLVERS:
        return _simulate_sensitivities(params, t1, ts, numerics=numerics)
    return _run(params, t1, numerics, ts)[0]


#: Solvers whose derivatives come from forward sensitivities (`_sensitivity`), not from
#: differentiating the solver's steps.
SENSITIVITY_SOLVERS = ("Rodas4",)


@eqx.filter_custom_jvp
def _simulate_sensitivities(params: Params, t1, ts, *, numerics: Numerics) -> Result:
    return _run(params, t1, numerics, ts)[0]


@_simulate_sensitivities.def_jvp
def _simulate_sensitivities_jvp(primals, tangents, *, numerics: Numerics):
    """The JVP as (sensitivity matrix) @ (tangent): the matrix depends on the primals
    alone, so `jax.grad` transposes a plain contraction."""
    params, t1, ts = primals
    t_params, t_t1, t_ts = tangents
    if t_ts is not None:
        raise ValueError(
            "simulate: derivatives with respect to the output times `ts` are "
            "not available; differentiate the parameters or t1 instead"
        )
    basis, coeff = _directions(params, t_params)
    if numerics.crack_sensitivity == "schedule_held":
        _refuse_fracture_constants(t_params)
    if basis is not None and numerics.crack_sensitivity != "exact" and reads_crack(params):
        raise SensitivityUnavailableError(_held_feedback(params, numerics))
    if basis is not None and numerics.fixed_step:
        raise SensitivityUnavailableError(
            f"derivatives with a fixed step (dt = {numerics.dt!r}) are not available: the "
            "forward sensitivities of the Rosenbrock solver need adaptive steps, which their "
            "own error controls (with dt = 2e-4 s the derivative was seen 80x off). Drop dt, "
            "or differentiate a diffrax solver (e.g. PRESETS['paper'] with "
            "crack_sensitivity='tips_held')."
        )
    if basis is not None and numerics.norm == "positions" and _perturbs_elastic_body(t_params):
        numerics = numerics.replace(norm="full")
    result, sens = _run(params, t1, numerics, ts, basis)
    tangent = jax.tree_util.tree_map(
        lambda s: jnp.tensordot(coeff, s, axes=1) if coeff is not None else None, sens
    )
    if t_t1 is not None:
        d_t1 = jax.tree_util.tree_map(lambda b: b * t_t1, _end_time_sensitivity(result, params))
        tangent = (
            d_t1
            if tangent is None
            else jax.tree_util.tree_map(_add, tangent, d_t1, is_leaf=lambda x: x is None)
        )
    return result, tangent


#: The body's parameters that set its elastic ringing (and, l0, the initial state).
ELASTIC_BODY = ("l0", "m", "EA")


def _perturbs_elastic_body(t_params) -> bool:
    """Whether the tangent perturbs a parameter of `ELASTIC_BODY`. The positions error
    norm steps over the elastic ringing, and the run's dependence on these parameters
    lives in it: a derivative along them is taken with the full norm (`simulate`)."""
    return t_params is not None and any(
        jax.tree_util.tree_leaves(getattr(t_params.body, name)) for name in ELASTIC_BODY
    )


#: The soil's fracture constants: they act on a run only through its crack schedule.
FRACTURE_CONSTANTS = ("K_Ic", "K_Ith")


def _refuse_fracture_constants(t_params) -> None:
    """`SensitivityUnavailableError` when the tangent perturbs K_Ic or K_Ith under
    `crack_sensitivity="schedule_held"`: they act on a run through the crack schedule
    that the surrogate holds (K_Ic only through it: its derivative would be 0)."""
    if t_params is None:
        return
    for name in FRACTURE_CONSTANTS:
        if jax.tree_util.tree_leaves(getattr(t_params.soil, name)):
            raise SensitivityUnavailableError(
                f"derivatives with respect to {name} are not available under "
                "crack_sensitivity='schedule_held' (the default): it holds the crack "
                f"schedule, and {name} acts on a run through the crack times and tips that "
                "it holds (for K_Ic the derivative would be 0). Pass "
                "numerics=jw.PRESETS['fast'].replace(crack_sensitivity='exact') (the exact "
                "derivative: right over a few cracks, far off the finite-difference slope "
                "through tens of them; docs: Gradients)."
            )


def _add(a, b):
    """a + b where None stands for a zero."""
    return b if a is None else (a if b is None else a + b)


def _directions(params: Params, t_params):
    """Unit directions along every perturbed parameter element (leading axis P), and the
    tangent's coordinates in them (P,); (None, None) when no parameter is perturbed."""
    p_leaves, treedef = jax.tree_util.tree_flatten(params)
    t_leaves = treedef.flatten_up_to(t_params) if t_params is not None else [None] * len(p_leaves)
    sizes = [jnp.size(p) if t is not None else 0 for p, t in zip(p_leaves, t_leaves)]
    P = sum(sizes)
    if P == 0:
        return None, None
    basis, offset = [], 0
    for p, n in zip(p_leaves, sizes):
        if not n:
            basis.append(None)
            continue
        b = jnp.zeros((P, n), jnp.result_type(p)).at[offset + jnp.arange(n), jnp.arange(n)].set(1.0)
        basis.append(b.reshape((P,) + jnp.shape(p)))
        offset += n
    coeff = jnp.concatenate([jnp.ravel(t) for t in t_leaves if t is not None])
    return jax.tree_util.tree_unflatten(treedef, basis), coeff


def _run(params: Params, t1, numerics: Numerics, ts, dp=None):
    """The segment loop. With parameter directions `dp` (leading axis P) it also
    carries the forward sensitivities and returns them as a `Result` of (P, ...)
    arrays (None for integer fields); else (result, None)."""
    M = numerics.max_cracks
    y0 = initial_state(params)
    xc0 = initial_crack_tip(params, y0)
    sens = dp is not None
    dense = ts is not None
    # Two conditions: the body's collapse (boolean, first: it ends the run) and the
    # crack (the upward zero crossing of K_I/K_Ic − 1). `sol.event_mask` says which fired.
    event = diffrax.Event(
        (_collapse_condition, _event_condition) if sens else (collapse_condition, crack_condition),
        root_finder=numerics.root_finder(),
        direction=True,
    )
    controller = numerics.build_controller()
    if sens:
        P = jax.tree_util.tree_leaves(dp)[0].shape[0]
        pd, pr = split_params(params, dp)

        def with_params(fn):
            """fn of the perturbed parameters alone."""
            return lambda d_, *a: fn(eqx.combine(d_, pr), *a)

        solver = numerics.build_sensitivity_solver(vector_field)
        terms = diffrax.ODETerm(_augmented_field)
        if not numerics.fixed_step:
            scale = (
                None
                if numerics.sensitivity_tol is None
                else _direction_scale(pd, dp) / numerics.sensitivity_tol
            )
            assert isinstance(controller, diffrax.PIDController)  # adaptive steps
            controller = eqx.tree_at(
                lambda c: c.norm,
                controller,
                _augmented_norm(controller.norm, scale, numerics.sensitivity_norm),
            )
        rate = _frequency_rate(params, pd, pr, dp)
        # At fixed phase only where the events need no conversion (see `Numerics`).
        phase = (
            numerics.sensitivity_frame == "phase" and numerics.crack_sensitivity == "schedule_held"
        )
        frame = Frame(
            rate if phase else jnp.zeros_like(rate), jnp.asarray(numerics.sensitivity_ramp, float)
        )
        S_y0, S_xc0 = jax.vmap(
            lambda d: jax.jvp(
                with_params(lambda q: (initial_state(q), initial_crack_tip(q, initial_state(q)))),
                (pd,),
                (d,),
            )[1]
        )(dp)
    else:
        solver = numerics.build_solver()
        terms = _terms(numerics)

    # A tip within the critical distance cracks at t = 0 (`initial_carry`).
    at_start, carry0 = initial_carry(params, y0, xc0, M)
    if sens:
        zeros = jnp.zeros((P, M))
        s_tip0 = jnp.where(
            at_start,
            jax.vmap(
                lambda Sy, d: jax.jvp(
                    with_params(lambda q, y: crack_jump(y, q, xc0)), (pd, y0), (d, Sy)
                )[1]
            )(S_y0, dp),
            S_xc0,
        )
        carry0.update(
            {
                "S": S_y0,
                "s_c": s_tip0,
                "s_times": zeros,
                "s_tips": zeros.at[:, 0].set(jnp.where(at_start, s_tip0, 0.0)),
                "s_x1": zeros.at[:, 0].set(jnp.where(at_start, S_y0.x[:, 0], 0.0)),
                "s_l1": zeros.at[:, 0].set(jnp.where(at_start, S_y0.x[:, 0] - S_y0.x[:, 1], 0.0)),
            }
        )
    if dense:
        T = ts.shape[0]
        carry0["saved"] = jax.tree_util.tree_map(lambda a: jnp.full((T,) + a.shape, jnp.nan), y0)
        carry0["saved_xc"] = jnp.full(T, jnp.nan)
        if sens:
            carry0["saved_S"] = jax.tree_util.tree_map(lambda a: jnp.zeros((T,) + a.shape), S_y0)
            carry0["saved_sc"] = jnp.zeros((T, P))

    def segment(carry, index):
        # Under vmap, finished lanes run this too and `segment_unless_done` discards the
        # result. They run a short span ending at t1, not the empty span from t1 to t1:
        # with the empty span, reverse mode through a diffrax solver gave NaN in a batch
        # where some lanes had finished (lineax refused a non-finite cotangent), while
        # each lane alone was finite: the double-`where` rule, a discarded computation
        # must itself be finite for its zero cotangent to stay zero.
        t0 = jnp.where(carry["done"], t1 - _FINISHED_SPAN * jnp.maximum(t1, 1.0), carry["t"])
        end = diffrax.SubSaveAt(t1=True)
        saveat = (
            diffrax.SaveAt(subs=[end, diffrax.SubSaveAt(ts=jnp.clip(ts, t0, t1))])
            if dense
            else diffrax.SaveAt(subs=[end])
        )
        if sens:
            z0, args = (carry["y"], carry["S"]), (pd, pr, carry["x_c"], dp, carry["s_c"], frame)
        else:
            z0, args = carry["y"], (params, carry["x_c"])
        # Dense output: without diffrax's run-time checks of the SaveAt times, which
        # `simulate` makes itself (see `_without_runtime_checks`).
        with _without_runtime_checks() if dense else contextlib.nullcontext():
            sol = diffrax.diffeqsolve(
                terms,
                solver,
                t0,
                t1,
                numerics.dt,
                z0,
                args=args,
                saveat=saveat,
                stepsize_controller=controller,
                event=event,
                max_steps=numerics.max_steps,
                throw=False,
                adjoint=numerics.build_adjoint(),
            )
        assert sol.ts is not None and sol.ys is not None  # `saveat` saves both
        t_end = sol.ts[0][-1]
        z_end = jax.tree_util.tree_map(lambda a: a[-1], sol.ys[0])
        y_end = z_end[0] if sens else z_end
        assert sol.event_mask is not None  # `event` is set
        fired = sol.result == diffrax.RESULTS.event_occurred
        collapsed = fired & sol.event_mask[0]
        hit = fired & sol.event_mask[1]
        ok = sol.result == diffrax.RESULTS.successful
        record = hit & (carry["n"] < M)
        new = dict(carry)
        new["t"] = t_end
        new["y"] = y_end
        if sens:
            dt, Y, tip, s_tip, S_plus = event_jump(
                vector_field,
                crack_condition,
                crack_jump,
                t_end,
                y_end,
                z_end[1],
                pd,
                pr,
                carry["x_c"],
                dp,
                carry["s_c"],
                rate,
                numerics.crack_sensitivity,
                frame,
            )
            new["S"] = jax.tree_util.tree_map(lambda a, b: jnp.where(hit, a, b), S_plus, z_end[1])
            new["s_c"] = jnp.where(record, s_tip, carry["s_c"])
        else:
            tip = crack_jump(y_end, params, carry["x_c"])
            if numerics.crack_sensitivity == "tips_held":
                if reads_crack(params):
                    tip = refusing(SensitivityUnavailableError, _held_feedback(params, numerics))(
                        tip
                    )
                tip = jax.lax.stop_gradient(tip)
            elif numerics.crack_sensitivity == "schedule_held":
                tip = _no_schedule_held(tip, numerics.solver)
        # A crack past the bound (too_many_cracks) ends the run unrecorded: the tip stays
        # the last recorded one.
        new["x_c"] = jnp.where(record, tip, carry["x_c"])
        slot = jnp.minimum(carry["n"], M - 1)
        new["crack_times"] = jnp.where(
            record, carry["crack_times"].at[slot].set(t_end), carry["crack_times"]
        )
        for key, value in (
            ("crack_tips", new["x_c"]),
            ("crack_x1", y_end.x[0]),
            ("crack_l1", y_end.x[0] - y_end.x[1]),
        ):
            new[key] = jnp.where(record, carry[key].at[slot].set(value), carry[key])
        if sens:
            for key, value in (
                ("s_times", dt),
                ("s_tips", s_tip),
                ("s_x1", Y.x[:, 0]),
                ("s_l1", Y.x[:, 0] - Y.x[:, 1]),
            ):
                if numerics.crack_sensitivity != "exact":
                    value = jnp.full_like(value, jnp.nan)  # not available: see Numerics
                new[key] = jnp.where(record, carry[key].at[:, slot].set(value), carry[key])
        new["n"] = carry["n"] + record.astype(int)
        new["steps"] = carry["steps"] + sol.stats["num_steps"]
        new["rejected"] = carry["rejected"] + sol.stats["num_rejected_steps"]
        status = jnp.where(
            ok | fired,
            0,
            jnp.where(
                sol.result == diffrax.RESULTS.max_steps_reached,
                STATUS_CODE["max_steps_reached"],
                STATUS_CODE["solver_failed"],
            ),
        )
        status = jnp.where(hit & ~record, STATUS_CODE["too_many_cracks"], status)
        status = jnp.where(collapsed, STATUS_CODE["body_inverted"], status)
        new["status"] = status
        new["done"] = (~hit) | ~record | (status != 0)
        if dense:
            mask = (ts >= t0) & (ts <= t_end) & jnp.isfinite(sol.ts[1])

            def put(old, fresh, axis=0):
                m = mask.reshape((1,) * axis + (-1,) + (1,) * (old.ndim - 1 - axis))
                return jnp.where(m, fresh, old)

            saved = sol.ys[1][0] if sens else sol.ys[1]
            new["saved"] = jax.tree_util.tree_map(put, carry["saved"], saved)
            new["saved_xc"] = jnp.where(mask, carry["x_c"], carry["saved_xc"])
            if sens:
                new["saved_S"] = jax.tree_util.tree_map(put, carry["saved_S"], sol.ys[1][1])
                new["saved_sc"] = jnp.where(mask[:, None], carry["s_c"][None, :], carry["saved_sc"])
        return new

    def segment_unless_done(carry, index):
        fresh = segment(carry, index)
        return jax.tree_util.tree_map(
            lambda old, new: jnp.where(carry["done"], old, new), carry, fresh
        )

    def step(carry, index):
        # Skip the segment only when every lane is done (`unvmap_all`: the plain `done`
        # without vmap), and select per lane with `where`. A `lax.cond` on the batched
        # `done` would become a select whose reverse-mode transpose runs the segment's
        # backward pass for finished lanes on zero-filled residuals: a singular implicit
        # solve there broke `vmap(grad)` (non-finite linear solve, or a wrong gradient).
        carry = jax.lax.cond(
            eqxi.unvmap_all(carry["done"]), lambda c, i: c, segment_unless_done, carry, index
        )
        return carry, None

    carry, _ = jax.lax.scan(step, carry0, jnp.arange(M + 1))
    y = carry["y"]

    def summary(y0, y, params, saved, saved_xc):
        residual = energy_residual(y0, y, params)
        trajectory = _trajectory(ts, saved, saved_xc, params) if dense else None
        return residual, trajectory

    saved = (carry["saved"], carry["saved_xc"]) if dense else (None, None)
    residual, trajectory = summary(y0, y, params, *saved)
    velocity = mean_velocity_of(y0.x, y.x, t1, carry["t"])
    status = _final_status(
        carry["status"], y, carry["x_c"], residual, params, numerics, velocity, carry["t"]
    )
    result = result_of(carry, t1, y0, xc0, residual, status, velocity, trajectory)
    if not sens:
        return result, None

    def summary_sens(d, Sy, saved_S, saved_sc):
        args = (pd, y0, y) + ((carry["saved"], carry["saved_xc"]) if dense else (None, None))
        tangents = (d, S_y0_d(d), Sy) + ((saved_S, saved_sc) if dense else (None, None))
        return jax.jvp(with_params(lambda q, a, b, e, f: summary(a, b, q, e, f)), args, tangents)[1]

    def S_y0_d(d):
        return jax.jvp(with_params(initial_state), (pd,), (d,))[1]

    def fixed_time(S, t, y, x_c):
        return at_fixed_time(S, frame.phi(t), vector_field(t, y, (params, x_c)), frame.rate)

    S_final = fixed_time(carry["S"], carry["t"], y, carry["x_c"])
    # The tip after a crack is a per-crack record: its sensitivity is the surrogate's
    # unless the jump conditions are exact, so it is NaN (not available) from the first
    # crack on, as are K_I and the back pressure, which read the tip.
    exact = numerics.crack_sensitivity == "exact"
    s_tip_final = carry["s_c"] if exact else jnp.where(carry["n"] > 0, jnp.nan, carry["s_c"])
    saved_S = (None, None)
    if dense:
        S_ts = jax.vmap(fixed_time)(carry["saved_S"], ts, carry["saved"], carry["saved_xc"])
        after_crack = ts >= carry["crack_times"][0]  # False when no crack (NaN)
        saved_sc = (
            carry["saved_sc"]
            if exact
            else jnp.where(after_crack[:, None], jnp.nan, carry["saved_sc"])
        )
        saved_S = (
            jax.tree_util.tree_map(lambda a: jnp.moveaxis(a, 1, 0), S_ts),
            jnp.moveaxis(saved_sc, 1, 0),
        )
    residual_s, trajectory_s = jax.vmap(summary_sens)(dp, S_final, *saved_S)
    sensitivities = _tangents(
        t1=None,
        x0=S_y0.x,
        final=S_final,
        x_c0=S_xc0,
        x_c=s_tip_final,
        n_cracks=None,
        crack_times=_nan_beyond(carry["s_times"], carry["n"]),
        crack_tips=_nan_beyond(carry["s_tips"], carry["n"]),
        crack_x1=_nan_beyond(carry["s_x1"], carry["n"]),
        crack_l1=_nan_beyond(carry["s_l1"], carry["n"]),
        steps=None,
        rejected_steps=None,
        energy_residual=residual_s,
        status=None,
        # Along each parameter direction t1 and t_end stay put: the positions move.
        mean_velocity=jax.vmap(
            lambda dx0, dx1: jax.jvp(
                lambda a, b: mean_velocity_of(a, b, t1, carry["t"]), (y0.x, y.x), (dx0, dx1)
            )[1]
        )(S_y0.x, S_final.x),
        trajectory=trajectory_s,
    )
    return result, sensitivities


def _frequency_rate(params: Params, pd, pr, dp):
    """dω/ω along each direction, ω the gait's angular frequency
    (`AbstractController.frequency`); zeros for a gait without a period."""
    omega = params.gait.frequency()
    if omega is None:
        return jnp.zeros(jax.tree_util.tree_leaves(dp)[0].shape[0])
    d_omega = jax.vmap(
        lambda d: jax.jvp(lambda d_: eqx.combine(d_, pr).gait.frequency(), (pd,), (d,))[1]
    )(dp)
    return d_omega / omega


_SCHEDULE_HELD_AD = (
    "crack_sensitivity='schedule_held' (the default) is computed by forward sensitivities "
    "with the Rosenbrock solver, not by differentiating the diffrax solver {solver!r}. "
    "Use simulate's default numerics (solver='Rodas4', preset 'fast'), or pass "
    "crack_sensitivity='exact' (the exact derivative: right on short horizons, far off "
    "the finite-difference slope through tens of cracks) or 'tips_held'."
)


def _held_feedback(params: Params, numerics: Numerics) -> str:
    """Why a derivative through a held crack is refused for a controller that reads it."""
    return (
        f"derivatives are not available under crack_sensitivity={numerics.crack_sensitivity!r}"
        f" for a controller that reads the crack: this {type(params.gait).__name__}'s "
        "control uses the sensors' back_pressure or stress_ratio (K_I/K_Ic). That mode "
        "holds what happens at each crack, so it drops how such a controller's u moves with "
        "the crack times (a ReflexWave with a stress reflex was seen with the wrong sign "
        "after four cracks, in both held modes). Pass "
        "numerics=jw.PRESETS['fast'].replace(crack_sensitivity='exact'), or "
        "crack_sensitivity='exact' to jw.train or jw.optimise: the exact derivative, "
        "which matched finite differences for a reflex wave over a few cracks but is far "
        "off the finite-difference slope through tens of them, and for a sharp PolicyMLP "
        "even over a few (docs: Closed-loop control). Or leave the sensor out of the "
        "derivative with jax.lax.stop_gradient."
    )


class SensitivityUnavailableError(TypeError):
    """Raised when a derivative is asked of a solver and crack mode that cannot give it."""


_no_numerics_derivative = refusing(
    SensitivityUnavailableError,
    "simulate: derivatives with respect to the numerics' options (atol, rtol, pcoeff, "
    "sensitivity_tol, ...) are not available: the solve depends on them through its "
    "discrete steps, not smoothly. Differentiate the parameters or t1; keep the "
    "options out of the differentiated function.",
)


def _refusing_tangents(numerics: Numerics) -> Numerics:
    """`numerics` whose float options raise when differentiated."""
    return jax.tree_util.tree_map(
        lambda x: _no_numerics_derivative(x) if eqx.is_inexact_array(x) else x, numerics
    )


def _no_schedule_held(tip, solver: str):
    """`tip`, refusing to be differentiated (no silent surrogate of another kind)."""
    return refusing(SensitivityUnavailableError, _SCHEDULE_HELD_AD.format(solver=solver))(tip)


def _nan_beyond(s, n):
    """Zero sensitivities in the NaN padding beyond `n` events (its value is constant)."""
    return jnp.where(jnp.arange(s.shape[-1]) < n, s, 0.0)


def _event_condition(t, y, args, **kwargs):
    return crack_condition(t, y[0], (eqx.combine(args[0], args[1]), args[2]))


def _collapse_condition(t, y, args, **kwargs):
    return body_collapsed(y[0], eqx.combine(args[0], args[1]).body)


def _augmented_field(t, z, args):
    y, S = z
    return (
        vector_field(t, y, (eqx.combine(args[0], args[1]), args[2])),
        sensitivity_field(vector_field, t, y, S, args),
    )


def _augmented_norm(norm, scale, which: str = "state"):
    """The state's error norm; with `scale` (P,) also that of the sensitivities, each
    direction scaled by its parameter's size (so both are lengths): by the state's norm
    (`which="state"`) or, `"mean_position"`, the RMS over the directions of the mean
    node position's (`Numerics.sensitivity_norm`)."""
    if scale is None:
        return lambda tree: norm(tree[0])

    def augmented(tree):
        y, S = tree
        if which == "mean_position":
            return jnp.maximum(norm(y), optx.rms_norm(scale * jnp.mean(S.x, axis=-1)))
        S = jax.tree_util.tree_map(lambda s: s * scale.reshape((-1,) + (1,) * (s.ndim - 1)), S)
        return jnp.maximum(norm(y), norm(S))

    return augmented


def _direction_scale(pd, dp):
    """|θ| along each direction (1 where θ is 0)."""
    parts = jax.tree_util.tree_map(
        lambda p, d: jnp.sum(jnp.abs(p * d).reshape(d.shape[0], -1), axis=1), pd, dp
    )
    size = sum(jax.tree_util.tree_leaves(parts))
    return jnp.where(size > 0, size, 1.0)


def _tangents(**fields: Any) -> Result:
    """A `Result` of derivatives: None in the fields that have none (the integer counts,
    the status) or that do not move (t1 along a parameter, x0 along t1)."""
    return Result(**fields)


def _end_time_sensitivity(result: Result, params: Params):
    """∂(result)/∂t1: the final state moves with the vector field; nothing else moves
    (no event falls exactly on t1)."""
    y, x_c = result.final, result.x_c
    f = vector_field(result.t1, y, (params, x_c))
    d_res = jax.jvp(lambda yy: energy_residual(initial_state(params), yy, params), (y,), (f,))[1]
    d_v = jax.jvp(
        lambda x1, t1: mean_velocity_of(result.x0, x1, t1, result.t_end),
        (y.x, result.t1),
        (f.x, jnp.ones_like(result.t1)),
    )[1]
    return _tangents(
        t1=jnp.ones_like(result.t1),
        x0=None,
        final=f,
        x_c0=None,
        x_c=None,
        n_cracks=None,
        crack_times=None,
        crack_tips=None,
        crack_x1=None,
        crack_l1=None,
        steps=None,
        rejected_steps=None,
        energy_residual=d_res,
        status=None,
        mean_velocity=d_v,
        trajectory=None,
    )


def _final_status(
    status, y: WormState, x_c, residual, params: Params, numerics: Numerics, speed, t_end
):
    """Invalid parameters first, then a crack tip that is not finite, then the solver's
    status, then the final state's checks, last the mean velocity `speed` against what
    the gait's stroke allows (`speed_bound`). A tip that the arrest search could not
    place (NaN, `arrest_tip`) stalls the solve at that crack, whatever bound it then
    reached: the run is `nonfinite`."""
    finite = jnp.all(jnp.array([jnp.all(jnp.isfinite(a)) for a in jax.tree_util.tree_leaves(y)]))
    inverted = body_collapsed(y, params.body)
    energy_bad = ~(jnp.abs(residual) <= numerics.energy_tol)
    too_fast = ~jnp.isfinite(speed) | (speed > speed_bound(params, t_end))
    # The solver's own verdict (bounds, failures) stands; otherwise judge the state.
    judged = jnp.where(
        ~finite,
        STATUS_CODE["nonfinite"],
        jnp.where(
            inverted,
            STATUS_CODE["body_inverted"],
            jnp.where(
                energy_bad,
                STATUS_CODE["energy_balance"],
                jnp.where(too_fast, STATUS_CODE["implausible_speed"], 0),
            ),
        ),
    )
    status = jnp.where(status == 0, judged, status)
    status = jnp.where(jnp.isfinite(x_c), status, STATUS_CODE["nonfinite"])
    return jnp.where(params_valid(params), status, STATUS_CODE["invalid_parameters"])


def _trajectory(ts, saved: WormState, saved_xc, params: Params) -> Trajectory:
    b = params.body

    def at(t, y, x_c):
        f = forces(t, y, x_c, params)
        return {
            "K_I": stress_intensity_of(y, x_c, params),
            "stretching": f["stretching"],
            "friction": f["friction"],
            "back_pressure": f["back_pressure"],
            "kinetic": phys.kinetic_energy(y.v, b.node_masses),
            "stretching_energy": phys.stretching_energy(y.x, y.lbar, b.EA),
        }

    d = jax.vmap(at)(ts, saved, saved_xc)
    return Trajectory(
        ts=ts, x=saved.x, v=saved.v, lbar=saved.lbar, x_c=saved_xc, work=saved.work, **d
    )

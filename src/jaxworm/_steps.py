"""The step loop: one run as one loop of solver steps, its crack events inside it.

`simulate` solves a run as a `lax.scan` of crack segments, one `diffeqsolve` each
(`jaxworm._solve`). Under `vmap` every lane then waits, at every segment, for the lane
whose segment takes the most steps: lanes of other gaits crack at other times and other
rates, so a batch pays for the sum over segments of the slowest lane's steps. Here each
lane carries its own crack segment through one `while_loop` of steps: when a step
crosses the crack condition the lane locates the crack on the step's dense output,
applies eq. (13) and starts its next segment at once, as a fresh `diffeqsolve` would
(the step-size controller and solver initialised again at the crack), while the other
lanes go on stepping. A batch then pays for its slowest lane's steps in all.

The steps, events and jumps are those of `_solve._run` (the same solver, controller,
event root find and jump, each segment started as `diffeqsolve` starts it): a lone run
with its values as program inputs is bit-identical in both loops; vmapped, or with its
values compiled in as constants, the two round differently, and adaptive steps turn that
into differences within the solver's tolerance. Forward only: its derivative would be
that of the steps, so tangents (of the parameters and t1) are refused. Used by
`jw.sweep` for its chunks.
"""

from __future__ import annotations

from typing import Any

import diffrax
import equinox as eqx
import equinox.internal as eqxi
import jax
import jax.numpy as jnp
import optimistix as optx

from ._dynamics import (
    collapse_condition,
    crack_condition,
    crack_jump,
    initial_crack_tip,
    initial_state,
    stress_intensity_of,
)
from ._energy import energy_residual
from ._numerics import Numerics
from ._params import Params
from ._result import STATUS_CODE, Result, mean_velocity_of
from ._rosenbrock import refusing
from ._soil import value_at

__all__ = ["initial_carry", "result_of", "run_steps"]

#: The per-crack records (written only at a live lane's crack).
_RECORDS = ("crack_times", "crack_tips", "crack_x1", "crack_l1")

#: The first step [s] of each segment when `Numerics.dt` is None (see `run_steps`).
_FIRST_STEP = 0.01

_FORWARD_ONLY = (
    "the step loop of a sweep's chunks is forward only; differentiate jaxworm.simulate, "
    "whose derivatives come from forward sensitivities (docs: Gradients)"
)


def run_steps(params: Params, t1, numerics: Numerics, terms, final_status) -> Result:
    """The `Result` (no trajectory) of one run over [0, t1] [s], every crack handled in
    one loop of steps. `terms`: the diffrax terms of the vector field; `final_status`:
    `_solve._final_status`."""
    forward_only = refusing(TypeError, _FORWARD_ONLY)
    params = jax.tree_util.tree_map(
        lambda x: forward_only(x) if eqx.is_inexact_array(x) else x, params
    )
    t1 = forward_only(jnp.asarray(t1, float))
    M = numerics.max_cracks
    solver = numerics.build_solver()
    controller = numerics.build_controller()
    root_finder = numerics.root_finder()
    error_order = solver.error_order(terms)
    vf: Any = solver.func  # diffrax types its `t` wider than the solvers here do
    y0 = initial_state(params)
    xc0 = initial_crack_tip(params, y0)
    # `diffeqsolve` wraps its terms, and diffrax's PID controller picks 0.01 s as the first
    # step of wrapped terms when given none: the same first step as each segment's there.
    first_dt = _FIRST_STEP if numerics.dt is None else numerics.dt
    # The threshold at which a step's end is rounded to t1 (diffrax's: 100 ULPs below).
    t1_floor = t1
    for _ in range(100):
        t1_floor = eqxi.prevbefore(t1_floor)

    _, base = initial_carry(params, y0, xc0, M)
    t0, tip0 = base["t"], base["x_c"]

    def start(t, y, x_c):
        """A segment's start, as `diffeqsolve` makes it: first step, controller and
        solver states, and the crack condition's value there."""
        args = (params, x_c)
        tnext, ctrl = controller.init(terms, t, t1, y, first_dt, args, vf, error_order)
        tnext = jnp.minimum(tnext, t1)
        return {
            "tnext": tnext,
            "ctrl": ctrl,
            "solver": solver.init(terms, t, tnext, y, args),
            "cond": crack_condition(t, y, args),
            "seg_steps": jnp.array(0),
        }

    # `diffeqsolve` checks the collapse at a segment's start too: a body collapsed there
    # ends `body_inverted` without a step.
    collapsed0 = collapse_condition(t0, y0, (params, tip0))
    carry0 = {
        **base,
        "done": ~(t0 < t1) | collapsed0,
        "status": jnp.where(collapsed0, STATUS_CODE["body_inverted"], 0),
        **start(t0, y0, tip0),
    }

    def body(c):
        args = (params, c["x_c"])
        y1, y_err, dense, solver_state, solver_result = solver.step(
            terms, c["t"], c["tnext"], c["y"], args, c["solver"], False
        )
        y_err = jax.tree_util.tree_map(lambda e: jnp.where(jnp.isnan(e), jnp.inf, e), y_err)
        keep, tprev, tnext, _, ctrl, ctrl_result = controller.adapt_step_size(
            c["t"], c["tnext"], c["y"], y1, args, y_err, error_order, c["ctrl"]
        )
        tprev = jnp.minimum(tprev, t1)
        tnext = jnp.where(tnext > t1_floor, jnp.where(keep, t1, tprev + 0.5 * (t1 - tprev)), tnext)
        result = diffrax.RESULTS.where(keep, solver_result, diffrax.RESULTS.successful)
        result = diffrax.RESULTS.where(result == diffrax.RESULTS.successful, ctrl_result, result)
        y_new = jax.tree_util.tree_map(lambda a, b: jnp.where(keep, a, b), y1, c["y"])
        cond = crack_condition(tprev, y_new, args)
        # A finished lane (under vmap it steps on, discarded) has no events: the crack
        # records change only at a live lane's crack, and need no selecting below.
        live = ~c["done"]
        collapsed = live & keep & collapse_condition(tprev, y_new, args)
        hit = live & keep & ~collapsed & (c["cond"] <= 0) & (cond > 0)
        seg_steps = c["seg_steps"] + 1
        new = {
            **c,
            "t": tprev,
            "y": y_new,
            "tnext": tnext,
            "ctrl": ctrl,
            "solver": jax.tree_util.tree_map(
                lambda a, b: jnp.where(keep, a, b), solver_state, c["solver"]
            ),
            "cond": cond,
            "seg_steps": seg_steps,
            "steps": c["steps"] + 1,
            "rejected": c["rejected"] + jnp.where(keep, 0, 1),
        }
        failed = result != diffrax.RESULTS.successful
        stalled = (seg_steps >= numerics.max_steps) & ~(tprev >= t1) & ~hit
        status = jnp.where(
            failed,
            STATUS_CODE["solver_failed"],
            jnp.where(stalled, STATUS_CODE["max_steps_reached"], 0),
        )
        new["status"] = jnp.where(collapsed, STATUS_CODE["body_inverted"], status)
        fired = hit | collapsed

        def event():
            """The event time of the lanes whose step ended in one, as `diffeqsolve`
            ends them: its root find on the step's dense output (for a crack, the
            crossing of the crack condition; for a collapse, the step's end), the state
            there, and for a crack eq. (13) and a fresh segment from there. Only these
            few values leave the branch (not the whole carry)."""
            interp = solver.interpolation_cls(t0=c["t"], t1=c["tnext"], **dense)

            # A lane without an event brackets [0, 0] (its own step may not be finite:
            # a lane finished by a failed step), closed from the start; its result is
            # discarded.
            lower = jnp.where(fired, c["t"], 0.0)
            upper = jnp.where(fired, c["tnext"], 0.0)

            def g(t, _):
                value = crack_condition(t, interp.evaluate(t), args)
                return jnp.where(hit, value, upper - t)

            sol = optx.root_find(
                g,
                root_finder,
                y0=upper,
                options={"lower": lower, "upper": upper},
                throw=False,
            )
            y_ev = interp.evaluate(sol.value)
            x_c = crack_jump(y_ev, params, c["x_c"])
            ok = sol.result == optx.RESULTS.successful
            # The next segment's start, and whether the body has collapsed there.
            fresh = start(sol.value, y_ev, x_c)
            return sol.value, y_ev, x_c, fresh, ok, collapse_condition(sol.value, y_ev, args)

        kept = {k: new[k] for k in ("tnext", "ctrl", "solver", "cond", "seg_steps")}
        t_ev, y_ev, x_c, fresh, ok, collapsed_there = jax.lax.cond(
            eqxi.unvmap_any(fired),
            event,
            lambda: (tprev, y_new, c["x_c"], kept, jnp.array(True), jnp.array(False)),
        )
        new["t"] = jnp.where(fired, t_ev, tprev)
        new["y"] = jax.tree_util.tree_map(lambda a, b: jnp.where(fired, a, b), y_ev, y_new)
        # A crack whose time the root find failed to locate is not recorded (as in
        # `_run`): the run ends `solver_failed` there.
        record = hit & (c["n"] < M) & ok
        new["x_c"] = jnp.where(record, x_c, c["x_c"])
        new["n"] = c["n"] + record.astype(int)
        new.update(jax.tree_util.tree_map(lambda a, b: jnp.where(record, a, b), fresh, kept))
        # One element per lane: written in place, where that lane records a crack.
        slot = jnp.minimum(c["n"], M - 1)
        for key, value in (
            ("crack_times", t_ev),
            ("crack_tips", x_c),
            ("crack_x1", y_ev.x[0]),
            ("crack_l1", y_ev.x[0] - y_ev.x[1]),
        ):
            new[key] = c[key].at[slot].set(jnp.where(record, value, c[key][slot]))
        # A crack past the bound ends the run unrecorded (too_many_cracks).
        status = jnp.where(hit & ok & ~record, STATUS_CODE["too_many_cracks"], new["status"])
        status = jnp.where(fired & ~ok, STATUS_CODE["solver_failed"], status)
        # The next segment starts collapsed: it ends there, without a step.
        new["status"] = jnp.where(record & collapsed_there, STATUS_CODE["body_inverted"], status)
        new["done"] = (new["status"] != 0) | ~(new["t"] < t1)
        frozen = {
            k: jax.tree_util.tree_map(lambda old, nw: jnp.where(live, nw, old), c[k], new[k])
            for k in new
            if k not in _RECORDS
        }
        return {**new, **frozen}

    carry = jax.lax.while_loop(lambda c: ~c["done"], body, carry0)
    y = carry["y"]
    residual = energy_residual(y0, y, params)
    velocity = mean_velocity_of(y0.x, y.x, t1, carry["t"])
    status = final_status(
        carry["status"], y, carry["x_c"], residual, params, numerics, velocity, carry["t"]
    )
    return result_of(carry, t1, y0, xc0, residual, status, velocity)


def initial_carry(params: Params, y0, xc0, M: int):
    """The start of a run's loop (`_solve._run`'s and this one's): the state at rest,
    no step taken, the per-crack records (M slots) empty. A tip given within the
    critical distance (K_I(0) ≥ K_Ic, `crack_gap0`) has no upward crossing to detect:
    the crack jumps at t = 0 (eqs. 12-13), recorded as a crack at t = 0. Returns
    (whether it did, the carry)."""
    at_start = stress_intensity_of(y0, xc0, params) >= value_at(params.soil.K_Ic, xc0)
    tip0 = jnp.where(at_start, crack_jump(y0, params, xc0), xc0)
    nan = jnp.full(M, jnp.nan)

    def first(value):
        return nan.at[0].set(jnp.where(at_start, value, jnp.nan))

    return at_start, {
        "t": jnp.zeros(()),
        "y": y0,
        "x_c": tip0,
        "n": at_start.astype(int),
        "crack_times": first(0.0),
        "crack_tips": first(tip0),
        "crack_x1": first(y0.x[0]),
        "crack_l1": first(y0.x[0] - y0.x[1]),
        "steps": jnp.array(0),
        "rejected": jnp.array(0),
        "done": jnp.array(False),
        "status": jnp.array(0),
    }


def result_of(carry, t1, y0, xc0, residual, status, velocity, trajectory=None) -> Result:
    """The `Result` of a run's loop from its final carry (`initial_carry`'s fields)."""
    return Result(
        t1=t1,
        t_end=carry["t"],
        x0=y0.x,
        final=carry["y"],
        x_c0=xc0,
        x_c=carry["x_c"],
        n_cracks=carry["n"],
        crack_times=carry["crack_times"],
        crack_tips=carry["crack_tips"],
        crack_x1=carry["crack_x1"],
        crack_l1=carry["crack_l1"],
        steps=carry["steps"],
        rejected_steps=carry["rejected"],
        energy_residual=residual,
        status=status,
        mean_velocity=velocity,
        trajectory=trajectory,
    )

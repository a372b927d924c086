"""Solve the hybrid system: diffrax between cracks, eq. (13) at each crack event.

The loop over crack segments is a `lax.scan` of fixed length `max_cracks + 1`, each
step one `diffeqsolve` that terminates on the crack `Event`; finished runs skip the
remaining segments. The scan keeps reverse-mode differentiation available (a
`while_loop` would not), and `vmap` batches everything.
"""

from __future__ import annotations

import diffrax
import equinox as eqx
import equinox.internal as eqxi
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from . import _physics as phys
from ._dynamics import (WormState, crack_condition, crack_jump, forces, initial_crack_tip,
                        initial_state, stress_intensity_of, vector_field, vector_field_nonstiff,
                        vector_field_stiff)
from ._energy import energy_residual
from ._numerics import PRESETS, Numerics
from ._params import Params, params_valid
from ._physics import segment_lengths
from ._result import STATUS_CODE, Result, Trajectory

__all__ = ["simulate"]


def simulate(params: Params, t1=60.0, numerics: Numerics | None = None,
             ts: Float[Array, " T"] | None = None) -> Result:
    """Simulate the worm from rest over [0, t1] [s].

    `numerics` defaults to the `fast` preset (Rodas4): the fastest setting within 1 % in
    mean velocity on every scene of the presets check, and forward-only. To
    differentiate, pass a differentiable preset, `jw.PRESETS["default"]` (Kvaerno3) or
    `"accurate"`; differentiating the default raises a `ForwardOnlyError` that says so.

    `ts` (optional) asks for dense output at those times (`Result.trajectory`); without
    it only the summary is kept, as a sweep needs. Jit-compiled; `vmap` over batched
    parameters and `grad` through it work as usual:

    ```python
    import jax, jax.numpy as jnp, jaxworm as jw
    p = jw.Params()
    r = jw.simulate(p, 10.0)
    print(r.mean_velocity, r.n_cracks, r.status_name)
    grad_ready = jw.PRESETS["default"]
    dv_domega = jax.grad(lambda w: jw.simulate(p.replace(omega=w), 10.0, grad_ready).mean_velocity)(
        4 * jnp.pi)
    ```
    """
    numerics = PRESETS["fast"] if numerics is None else numerics
    t1 = jnp.asarray(t1, dtype=jnp.float64)
    if ts is not None:
        ts = jnp.asarray(ts, dtype=jnp.float64)
    return _simulate(params, t1, numerics, ts)


def _terms(numerics: Numerics):
    if numerics.imex:
        return diffrax.MultiTerm(diffrax.ODETerm(vector_field_nonstiff),
                                 diffrax.ODETerm(vector_field_stiff))
    return diffrax.ODETerm(vector_field)


@eqx.filter_jit
def _simulate(params: Params, t1, numerics: Numerics, ts) -> Result:
    M = numerics.max_cracks
    y0 = initial_state(params)
    xc0 = initial_crack_tip(params, y0)
    terms = _terms(numerics)
    solver = numerics.build_solver()
    controller = numerics.build_controller()
    event = diffrax.Event(crack_condition, root_finder=numerics.root_finder(), direction=True)
    dt0 = numerics.dt
    dense = ts is not None

    # A tip given within the critical distance (K_I(0) ≥ K_Ic, `crack_gap0`) has no
    # upward crossing to detect: the crack jumps at t = 0 (eqs. 12-13), recorded as a
    # crack at t = 0.
    at_start = stress_intensity_of(y0, xc0, params) >= params.soil.K_Ic
    tip0 = jnp.where(at_start, crack_jump(y0, params), xc0)
    nan = jnp.full(M, jnp.nan)

    def first(value):
        return nan.at[0].set(jnp.where(at_start, value, jnp.nan))

    carry0 = {
        "t": jnp.zeros(()), "y": y0, "x_c": tip0, "n": at_start.astype(int),
        "crack_times": first(0.0), "crack_tips": first(tip0), "crack_x1": first(y0.x[0]),
        "crack_l1": first(y0.x[0] - y0.x[1]), "steps": jnp.array(0),
        "rejected": jnp.array(0), "done": jnp.array(False), "status": jnp.array(0),
    }
    if dense:
        T = ts.shape[0]
        carry0["saved"] = jax.tree_util.tree_map(lambda a: jnp.full((T,) + a.shape, jnp.nan), y0)
        carry0["saved_xc"] = jnp.full(T, jnp.nan)

    def segment(carry, index):
        # Under vmap, finished lanes run this too, from t1 to t1: diffrax returns at
        # once and `segment_unless_done` discards the result.
        t0 = carry["t"]
        end = diffrax.SubSaveAt(t1=True)
        saveat = (diffrax.SaveAt(subs=[end, diffrax.SubSaveAt(ts=jnp.clip(ts, t0, t1))])
                  if dense else diffrax.SaveAt(subs=[end]))
        sol = diffrax.diffeqsolve(
            terms, solver, t0, t1, dt0, carry["y"], args=(params, carry["x_c"]),
            saveat=saveat, stepsize_controller=controller, event=event,
            max_steps=numerics.max_steps, throw=False, adjoint=numerics.build_adjoint())
        t_end = sol.ts[0][-1]
        y_end = jax.tree_util.tree_map(lambda a: a[-1], sol.ys[0])
        hit = sol.result == diffrax.RESULTS.event_occurred
        ok = sol.result == diffrax.RESULTS.successful
        record = hit & (carry["n"] < M)
        new = dict(carry)
        new["t"] = t_end
        new["y"] = y_end
        tip = crack_jump(y_end, params)
        if not numerics.crack_tip_gradient:
            tip = jax.lax.stop_gradient(tip)
        new["x_c"] = jnp.where(hit, tip, carry["x_c"])
        slot = jnp.minimum(carry["n"], M - 1)
        new["crack_times"] = jnp.where(record, carry["crack_times"].at[slot].set(t_end),
                                       carry["crack_times"])
        for key, value in (("crack_tips", new["x_c"]), ("crack_x1", y_end.x[0]),
                           ("crack_l1", y_end.x[0] - y_end.x[1])):
            new[key] = jnp.where(record, carry[key].at[slot].set(value), carry[key])
        new["n"] = carry["n"] + record.astype(int)
        new["steps"] = carry["steps"] + sol.stats["num_steps"]
        new["rejected"] = carry["rejected"] + sol.stats["num_rejected_steps"]
        status = jnp.where(ok | hit, 0, jnp.where(
            sol.result == diffrax.RESULTS.max_steps_reached, STATUS_CODE["max_steps_reached"],
            STATUS_CODE["solver_failed"]))
        status = jnp.where(hit & ~record, STATUS_CODE["too_many_cracks"], status)
        new["status"] = status
        new["done"] = (~hit) | ~record | (status != 0)
        if dense:
            mask = (ts >= t0) & (ts <= t_end) & jnp.isfinite(sol.ts[1])

            def put(old, fresh):
                m = mask.reshape((-1,) + (1,) * (old.ndim - 1))
                return jnp.where(m, fresh, old)

            new["saved"] = jax.tree_util.tree_map(put, carry["saved"], sol.ys[1])
            new["saved_xc"] = jnp.where(mask, carry["x_c"], carry["saved_xc"])
        return new

    def segment_unless_done(carry, index):
        fresh = segment(carry, index)
        return jax.tree_util.tree_map(lambda old, new: jnp.where(carry["done"], old, new),
                                      carry, fresh)

    def step(carry, index):
        # Skip the segment only when every lane is done (`unvmap_all`: the plain `done`
        # without vmap), and select per lane with `where`. A `lax.cond` on the batched
        # `done` would become a select whose reverse-mode transpose runs the segment's
        # backward pass for finished lanes on zero-filled residuals: a singular implicit
        # solve there broke `vmap(grad)` (non-finite linear solve, or a wrong gradient).
        carry = jax.lax.cond(eqxi.unvmap_all(carry["done"]), lambda c, i: c,
                             segment_unless_done, carry, index)
        return carry, None

    carry, _ = jax.lax.scan(step, carry0, jnp.arange(M + 1))
    y = carry["y"]
    residual = energy_residual(y0, y, params)
    status = _final_status(carry["status"], y, residual, params, numerics)
    trajectory = _trajectory(ts, carry["saved"], carry["saved_xc"], params) if dense else None
    return Result(t1=t1, x0=y0.x, final=y, x_c0=xc0, x_c=carry["x_c"], n_cracks=carry["n"],
                  crack_times=carry["crack_times"], crack_tips=carry["crack_tips"],
                  crack_x1=carry["crack_x1"], crack_l1=carry["crack_l1"],
                  steps=carry["steps"], rejected_steps=carry["rejected"],
                  energy_residual=residual, status=status, trajectory=trajectory)


def _final_status(status, y: WormState, residual, params: Params, numerics: Numerics):
    """Invalid parameters first, then the solver's status, then the final state's checks."""
    finite = jnp.all(jnp.array([jnp.all(jnp.isfinite(a)) for a in jax.tree_util.tree_leaves(y)]))
    inverted = (jnp.min(segment_lengths(y.x)) <= 0) | (jnp.min(y.lbar) <= 0)
    energy_bad = ~(jnp.abs(residual) <= numerics.energy_tol)
    # The solver's own verdict (bounds, failures) stands; otherwise judge the state.
    judged = jnp.where(~finite, STATUS_CODE["nonfinite"], jnp.where(
        inverted, STATUS_CODE["body_inverted"], jnp.where(
            energy_bad, STATUS_CODE["energy_balance"], 0)))
    status = jnp.where(status == 0, judged, status)
    return jnp.where(params_valid(params), status, STATUS_CODE["invalid_parameters"])


def _trajectory(ts, saved: WormState, saved_xc, params: Params) -> Trajectory:
    b = params.body

    def at(t, y, x_c):
        f = forces(t, y, x_c, params)
        return {
            "K_I": stress_intensity_of(y, x_c, params),
            "stretching": f["stretching"], "friction": f["friction"],
            "back_pressure": f["back_pressure"],
            "kinetic": phys.kinetic_energy(y.v, b.node_masses),
            "stretching_energy": phys.stretching_energy(y.x, y.lbar, b.EA),
        }

    d = jax.vmap(at)(ts, saved, saved_xc)
    return Trajectory(ts=ts, x=saved.x, v=saved.v, lbar=saved.lbar, x_c=saved_xc,
                      work=saved.work, **d)

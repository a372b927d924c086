"""What a simulation returns: a summary always, a dense trajectory when asked for."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from ._dynamics import WormState

__all__ = ["Result", "Trajectory", "STATUS", "STATUS_HINTS", "status_name", "status_message"]

#: Named outcomes of a run; `Result.status` holds the code.
STATUS = {
    0: "ok",
    1: "too_many_cracks",  # the bound Numerics.max_cracks was reached before t1
    2: "max_steps_reached",  # the step bound between two cracks was reached
    3: "solver_failed",  # implicit solve or step-size control failed
    4: "nonfinite",  # NaN or inf in the final state
    5: "invalid_parameters",  # a traced parameter, t1 or ts fails the checks of values
    6: "body_inverted",  # a segment or intrinsic length reached zero: the run stopped there
    7: "energy_balance",  # work-energy residual above Numerics.energy_tol
    8: "implausible_speed",  # mean velocity above what the gait's stroke allows
}

#: What to do about each status that is not ok (`status_message`).
STATUS_HINTS = {
    "too_many_cracks": "the run stopped at the crack bound before t1; raise "
    "Numerics.max_cracks (command line: --max-cracks)",
    "max_steps_reached": "the run stopped at the step bound before t1; raise "
    "Numerics.max_steps, or loosen atol",
    "solver_failed": "the solver failed before t1: an implicit solve failed, or the step "
    "size shrank to nothing, as where the vector field is not finite beyond some time (a "
    "controller or soil profile that returns NaN or inf there: check it at t_end); else "
    "try another preset (--preset accurate) or a smaller atol",
    "nonfinite": "the final state or crack tip is not finite; check the parameters' scales "
    "(a soil profile too steep for the crack-arrest search leaves the tip NaN: widen it)",
    "invalid_parameters": "a traced parameter, numerics option, t1 or ts is out of range "
    "(see Params, Numerics; t1 > 0; ts finite, non-decreasing, within [0, t1]); the run "
    "took no step",
    "body_inverted": "a segment or intrinsic length reached zero and the run stopped "
    "there: the gait shortens a segment by more than its length (a TravellingWave by up "
    "to 2A/omega; reflex gains can raise the amplitude towards 2A); lower A or the gains, "
    "or raise omega",
    "energy_balance": "the work-energy residual exceeds Numerics.energy_tol: a likely false "
    "solution; tighten atol (--atol) or use --preset accurate",
    "implausible_speed": "the mean velocity exceeds what the gait's stroke allows "
    "(jaxworm.speed_bound): a numerical or smoothing artefact, not a "
    "result",
}
STATUS_CODE = {v: k for k, v in STATUS.items()}


def status_name(code: Int[ArrayLike, "*batch"]) -> str | np.ndarray:
    """Status code(s) to name(s)."""
    a = np.asarray(code)
    if a.ndim == 0:
        return STATUS[_known_code(a)]
    return np.vectorize(lambda c: STATUS[_known_code(c)])(a)


def status_message(code: Int[ArrayLike, ""]) -> str:
    """The status name with what to do about it (`STATUS_HINTS`), for one run."""
    a = np.asarray(code)
    if a.ndim != 0:
        raise ValueError(
            f"status_message takes the status of one run, not an array of shape {a.shape}: "
            "use status_name for a batch"
        )
    name = STATUS[_known_code(a)]
    return name if name == "ok" else f"{name}: {STATUS_HINTS[name]}"


def _known_code(code) -> int:
    """`code` as a key of `STATUS`, or a ValueError naming the known codes."""
    a = np.asarray(code)
    if a.dtype.kind not in "iuf" or not float(a).is_integer() or int(a) not in STATUS:
        known = ", ".join(f"{c} ({n})" for c, n in STATUS.items())
        raise ValueError(f"unknown status code {a.item()!r}: the codes are {known}")
    return int(a)


class Trajectory(eqx.Module):
    """Dense output at the requested times (shapes: T times, N nodes, S = N−1 segments).

    Forces per node [N]: `stretching` (𝒱_s, eq. 20), `friction` (ℱ_f, eq. 21);
    `back_pressure` F_p on the head (eq. 16). `K_I` [Pa√m] by eq. (12), `x_c` the crack
    tip [m], `kinetic`/`stretching_energy` [J] (eqs. 1-2), `work` the running actuation
    work, friction dissipation, back-pressure work and gross actuation work [J]
    (`WormState.work`).

    A run that stopped before t1 (`Result.t_end`: a bound reached, a collapsed body)
    has NaN in every field at the times after it.
    """

    ts: Float[Array, " T"]
    x: Float[Array, "T N"]
    v: Float[Array, "T N"]
    lbar: Float[Array, "T S"]
    x_c: Float[Array, " T"]
    K_I: Float[Array, " T"]
    stretching: Float[Array, "T N"]
    friction: Float[Array, "T N"]
    back_pressure: Float[Array, " T"]
    kinetic: Float[Array, " T"]
    stretching_energy: Float[Array, " T"]
    work: Float[Array, "T 4"]


class Result(eqx.Module):
    """Summary of a run (every field an array, so results batch under `vmap`).

    - `t1`: the end time asked for [s]; `t_end`: the time the run reached [s], t1
      unless it stopped early (`too_many_cracks`, `max_steps_reached`, `solver_failed`,
      `body_inverted`; 0 for `invalid_parameters`); `x0`, `final`: initial node
      positions and the state at `t_end`.
    - `x_c0`, `x_c`: initial and final crack tip [m]; `n_cracks`; per crack event,
      `crack_times` [s], `crack_tips` (the new tip, eq. 13) [m], and the head position
      `crack_x1` [m] and head-segment length `crack_l1` [m] at the event; all padded with
      NaN beyond `n_cracks` (length `Numerics.max_cracks`).
    - `steps`, `rejected_steps`: solver statistics summed over the crack segments.
    - `energy_residual`: (W_act − ΔT − ΔV − D − W_bp) relative to the energy that
      flowed (`jaxworm.energy_residual`).
    - `status`: code of `STATUS` (0 = ok).
    - `mean_velocity`: (mean of node positions at t_end − at 0) / t_end [m/s]
      (`MODEL.md`): over the time simulated, which is t1 unless the run stopped early (NaN
      when it took no step). A field, not a property, so that the derivative of a whole
      `Result` (`jax.jvp`, `jax.jacfwd`) carries the mean velocity's derivative.
    - `trajectory`: a `Trajectory` when dense output was asked for, else `None`.
    """

    t1: Float[Array, ""]
    x0: Float[Array, " N"]
    final: WormState
    x_c0: Float[Array, ""]
    x_c: Float[Array, ""]
    n_cracks: Int[Array, ""]
    crack_times: Float[Array, " M"]
    crack_tips: Float[Array, " M"]
    crack_x1: Float[Array, " M"]
    crack_l1: Float[Array, " M"]
    steps: Int[Array, ""]
    rejected_steps: Int[Array, ""]
    energy_residual: Float[Array, ""]
    status: Int[Array, ""]
    mean_velocity: Float[Array, ""]
    trajectory: Trajectory | None = None
    t_end: Float[Array, ""] | None = None

    @property
    def ok(self):
        return self._status() == 0

    @property
    def status_name(self):
        return status_name(self._status())

    def _status(self):
        """`status`; TypeError for a Result of tangents, whose status is float0."""
        if getattr(self.status, "dtype", None) == jax.dtypes.float0:
            raise TypeError(
                "this Result holds derivatives (the tangents of jax.jvp or jax.jacfwd of "
                "a whole Result): it has no status; read ok, status_name and summary() "
                "from the result itself (the primal of jax.jvp)"
            )
        return self.status

    @property
    def final_head(self):
        return self.final.x[..., 0]

    def summary(self) -> dict:
        """Plain-Python summary of an unbatched result (for JSON and printing)."""
        self._status()
        if np.ndim(self.status) != 0:
            raise ValueError(
                f"summary() takes one run's result, not a batch of shape "
                f"{np.shape(self.status)}: index a run first (jax.tree_util.tree_map("
                "lambda a: a[i], result)), or read the batched fields directly"
            )
        # The derived numbers in one compiled program, the rest read as NumPy: eager JAX
        # operations would each compile a program of their own.
        velocity, t_end = _derived(self)
        n = int(self.n_cracks)
        return {
            "mean_velocity": float(velocity),
            "t1": float(self.t1),
            "t_end": float(t_end),
            "n_cracks": n,
            "crack_times": [float(t) for t in np.asarray(self.crack_times)[:n]],
            "crack_tips": [float(t) for t in np.asarray(self.crack_tips)[:n]],
            "final_head": float(np.asarray(self.final.x)[0]),
            "final_crack_tip": float(self.x_c),
            "status": str(self.status_name),
            "status_message": status_message(self.status),
            "steps": int(self.steps),
            "rejected_steps": int(self.rejected_steps),
            "energy_residual": float(self.energy_residual),
        }


def mean_velocity(result: Result, weights: str = "nodes") -> Float[Array, ""]:
    """Mean velocity over [0, t_end] [m/s], the time simulated (`Result.t_end`).

    `weights="nodes"` (default, `MODEL.md`): the plain mean of node positions;
    `"mass"`: the centre of mass (end nodes weigh half).
    """
    t_end = result.t1 if result.t_end is None else result.t_end
    return mean_velocity_of(result.x0, result.final.x, result.t1, t_end, weights)


def mean_velocity_of(x0, x1, t1, t_end, weights: str = "nodes") -> Float[Array, ""]:
    """`mean_velocity` from the node positions at 0 and at t_end, over t1 for a run that
    reached it (so that t1's derivative flows) and over t_end for one that stopped early."""
    if weights == "nodes":
        w = jnp.ones(x0.shape[-1])
    elif weights == "mass":
        w = jnp.ones(x0.shape[-1]).at[0].set(0.5).at[-1].set(0.5)
    else:
        raise ValueError(f"option weights = {weights!r}: need 'nodes' or 'mass'")
    w = w / jnp.sum(w)
    return (jnp.sum(x1 * w, axis=-1) - jnp.sum(x0 * w, axis=-1)) / _time_simulated(t1, t_end)


@jax.jit
def _derived(result: Result):
    """`mean_velocity` and the time simulated (`_horizon`)."""
    return result.mean_velocity, _horizon(result)


def _horizon(result: Result):
    """The time `result` simulated (`_time_simulated`)."""
    if result.t_end is None:
        return result.t1
    return _time_simulated(result.t1, result.t_end)


def _time_simulated(t1, t_end):
    """t1 for a run that reached it (and t1's derivative), else t_end, the time it
    stopped (0 for a run that took no step: then the mean velocity is NaN)."""
    return jnp.where(t_end == t1, t1, t_end)

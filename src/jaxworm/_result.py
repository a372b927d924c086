"""What a simulation returns: a summary always, a dense trajectory when asked for."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from ._dynamics import WormState

__all__ = ["Result", "Trajectory", "STATUS", "status_name"]

#: Named outcomes of a run; `Result.status` holds the code.
STATUS = {
    0: "ok",
    1: "too_many_cracks",       # the bound Numerics.max_cracks was reached before t1
    2: "max_steps_reached",     # the step bound between two cracks was reached
    3: "solver_failed",         # implicit solve or step-size control failed
    4: "nonfinite",             # NaN or inf in the final state
    5: "invalid_parameters",    # a traced parameter fails the construction-time checks
    6: "body_inverted",         # a segment or intrinsic length is not positive
    7: "energy_balance",        # work-energy residual above Numerics.energy_tol
}
STATUS_CODE = {v: k for k, v in STATUS.items()}


def status_name(code) -> str | np.ndarray:
    """Status code(s) to name(s)."""
    a = np.asarray(code)
    if a.ndim == 0:
        return STATUS[int(a)]
    return np.vectorize(lambda c: STATUS[int(c)])(a)


class Trajectory(eqx.Module):
    """Dense output at the requested times (shapes: T times, N nodes, S = N−1 segments).

    Forces per node [N]: `stretching` (𝒱_s, eq. 20), `friction` (ℱ_f, eq. 21);
    `back_pressure` F_p on the head (eq. 16). `K_I` [Pa√m] by eq. (12), `x_c` the crack
    tip [m], `kinetic`/`stretching_energy` [J] (eqs. 1-2), `work` the running actuation
    work, friction dissipation and back-pressure work [J].
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
    work: Float[Array, "T 3"]


class Result(eqx.Module):
    """Summary of a run (every field an array, so results batch under `vmap`).

    - `t1`: end time [s]; `x0`, `final`: initial node positions and final state.
    - `x_c0`, `x_c`: initial and final crack tip [m]; `n_cracks`; per crack event,
      `crack_times` [s], `crack_tips` (the new tip, eq. 13) [m], and the head position
      `crack_x1` [m] and head-segment length `crack_l1` [m] at the event; all padded with
      NaN beyond `n_cracks` (length `Numerics.max_cracks`).
    - `steps`, `rejected_steps`: solver statistics summed over the crack segments.
    - `energy_residual`: (W_act − ΔT − ΔV − D − W_bp) / max(D, |W_act|) (see `energy`).
    - `status`: code of `STATUS` (0 = ok).
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
    trajectory: Trajectory | None = None

    @property
    def mean_velocity(self) -> Float[Array, ""]:
        """(mean of node positions at t1 − at 0) / t1 [m/s] (`MODEL.md`)."""
        return mean_velocity(self)

    @property
    def ok(self):
        return self.status == 0

    @property
    def status_name(self):
        return status_name(self.status)

    @property
    def final_head(self):
        return self.final.x[..., 0]

    def summary(self) -> dict:
        """Plain-Python summary of an unbatched result (for JSON and printing)."""
        n = int(self.n_cracks)
        return {
            "mean_velocity": float(self.mean_velocity),
            "n_cracks": n,
            "crack_times": [float(t) for t in np.asarray(self.crack_times)[:n]],
            "crack_tips": [float(t) for t in np.asarray(self.crack_tips)[:n]],
            "final_head": float(self.final.x[0]),
            "final_crack_tip": float(self.x_c),
            "status": str(self.status_name),
            "steps": int(self.steps),
            "rejected_steps": int(self.rejected_steps),
            "energy_residual": float(self.energy_residual),
        }


def mean_velocity(result: Result, weights: str = "nodes") -> Float[Array, ""]:
    """Mean velocity over [0, t1] [m/s].

    `weights="nodes"` (default, `MODEL.md`): the plain mean of node positions;
    `"mass"`: the centre of mass (end nodes weigh half).
    """
    x0, x1 = result.x0, result.final.x
    if weights == "nodes":
        w = jnp.ones(x0.shape[-1])
    elif weights == "mass":
        w = jnp.ones(x0.shape[-1]).at[0].set(0.5).at[-1].set(0.5)
    else:
        raise ValueError(f"option weights = {weights!r}: need 'nodes' or 'mass'")
    w = w / jnp.sum(w)
    return (jnp.sum(x1 * w, axis=-1) - jnp.sum(x0 * w, axis=-1)) / result.t1



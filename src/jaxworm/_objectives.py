"""Objectives of `jaxworm.optimise`: scalar functions of a `Result`, each with its sense and unit.

- `"velocity"`: the mean velocity [m/s] (`Result.mean_velocity`), maximised.
- `"cost_of_transport"`: the actuation work per metre advanced [J/m]
  (`cost_of_transport`), minimised.

Any callable `f(result) -> scalar` is an objective too (minimised unless
`maximise=True`); an `eqx.Module` keeps its arrays as traced leaves, so objectives that
differ only in data (`identify`'s observations) share one compiled program.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._result import Result, _horizon
from ._validation import check_range, show, to_float

__all__ = [
    "cost_of_transport",
    "OBJECTIVES",
    "COT_MIN_SPEED",
    "resolve_objective",
    "objective_value",
]

#: Below this speed [m/s] the worm counts as not advancing for the cost of transport.
COT_MIN_SPEED = 1e-4


def cost_of_transport(
    result: Result, work: str = "actuation", min_speed: float = COT_MIN_SPEED
) -> Float[Array, "*batch"]:
    """Energy spent per metre advanced [J/m]: W / Δx.

    - W: the net actuation work ∫∂V/∂l̄·u dt over [0, t_end] (`work="actuation"`, default;
      t_end = t1 unless the run stopped early, `Result.t_end`),
      which by the energy balance equals the friction dissipation plus the work against
      the crack's back pressure plus the final kinetic and stretching energy; or the
      friction dissipation alone (`work="friction"`). Net work: a pump that cannot
      recover energy spends at least this much.
    - Δx = mean_velocity · t_end: the advance of the node mean [m].

    A worm that does not advance has no cost of transport. Below Δx_min = min_speed·t_end
    (`min_speed` > 0 [m/s], default 1e-4 m/s) the value continues along the tangent of
    W/Δx at Δx_min, W/Δx_min · (2 − Δx/Δx_min): finite, decreasing in Δx, and continuous
    with its slope, so a retreating start is pushed forward instead of meeting a pole.
    Such values are a penalty, not a cost of transport; `OptimiseResult` reports the
    speed alongside. The penalty is proportional to W: a run that spends no work (A = 0,
    pushed back by the crack) scores 0, the least value, so bound the gait's work away
    from zero (A > 0) when minimising this.
    """
    if work not in ("actuation", "friction"):
        raise ValueError(f"option work = {work!r}: need 'actuation' or 'friction'")
    check_range("min_speed", to_float(min_speed), lambda v: v > 0, "> 0 [m/s]", kind="option")
    W = result.final.work[..., 0 if work == "actuation" else 1]
    horizon = _horizon(result)
    d = result.mean_velocity * horizon
    d_min = min_speed * horizon
    safe = jnp.maximum(d, d_min)  # keeps the unused branch's gradient finite
    return jnp.where(d >= d_min, W / safe, W / d_min * (2.0 - d / d_min))


def _velocity(result: Result):
    return result.mean_velocity


#: Built-in objectives: name -> (function of the Result, maximise?, unit).
OBJECTIVES: dict[str, tuple[Callable, bool, str]] = {
    "velocity": (_velocity, True, "m/s"),
    "cost_of_transport": (cost_of_transport, False, "J/m"),
}


def resolve_objective(objective, maximise: bool | None) -> tuple[Callable, bool, str, str]:
    """(function, maximise?, unit, name) of an objective: a name of `OBJECTIVES` (whose
    sense `maximise`, if given, must match) or a callable of the Result (minimised
    unless `maximise`; unit "-")."""
    if maximise is not None and not isinstance(maximise, (bool, np.bool_)):
        raise TypeError(
            f"option maximise = {maximise!r} ({type(maximise).__name__}): need True, False "
            "or None (the objective's own sense)"
        )
    if isinstance(objective, str):
        if objective not in OBJECTIVES:
            raise ValueError(
                f"objective = {objective!r} is unknown: need one of "
                f"{', '.join(OBJECTIVES)} or a callable of the Result"
            )
        fn, mx, unit = OBJECTIVES[objective]
        if maximise is not None and bool(maximise) != mx:
            raise ValueError(
                f"option maximise = {maximise!r} contradicts objective "
                f"{objective!r}, which is {'maximised' if mx else 'minimised'}"
            )
        return fn, mx, unit, objective
    if callable(objective):
        return (
            objective,
            bool(maximise),
            "-",
            getattr(objective, "__name__", type(objective).__name__),
        )
    raise ValueError(
        f"objective = {objective!r}: need one of {', '.join(OBJECTIVES)} or a "
        "callable of the Result"
    )


def objective_value(fn: Callable, result: Result) -> jax.Array:
    """`fn(result)` as one float64 number; an error naming the objective when it returns
    anything else, or reads the trajectory of a run without output times."""
    name = getattr(fn, "__name__", type(fn).__name__)
    try:
        out = fn(result)
    except AttributeError as e:
        if result.trajectory is None and "NoneType" in str(e):
            raise ValueError(
                f"objective {name} reads result.trajectory, which a run has only with "
                "output times: pass ts=... (as simulate takes them)"
            ) from e
        raise
    try:
        value = jnp.asarray(out, dtype=jnp.float64)
    except (TypeError, ValueError):
        raise TypeError(
            f"objective {name} returned {show(out)} ({type(out).__name__}): need one real number"
        ) from None
    if value.shape != ():
        raise ValueError(
            f"objective {name} returned an array of shape {value.shape}: need one number"
        )
    return value

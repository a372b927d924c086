"""Gait optimisation: gradient descent with optax on a simulated objective, in a box.

Each parameter θ_i is kept in its box [lo_i, hi_i] by construction, not by clipping: the
optimiser works on an unconstrained z_i and the simulation sees (`box="sine"`, the default)

    θ_i = lo_i + (hi_i − lo_i) (1 + sin z_i) / 2,

the transformation of MINUIT (James & Roos 1975). The optimiser's steps are in units of
the box, whatever the parameter's unit, and a bound is reached at a finite z = ±π/2,
where dθ/dz = 0: an optimiser with bounded steps gets there in a few steps and settles
(Adam without momentum, the default on this box; iRprop−, `rprop`, which halves its step
each time z crosses π/2), as gait optima do lie on bounds (an amplitude at its actuator limit; the lowest frequency
allowed: `benchmarks/results/optimise_*`). `box="sigmoid"`,

    θ_i = lo_i + (hi_i − lo_i) σ(z_i),     σ(z) = 1 / (1 + e^{−z}),

keeps every evaluated point strictly inside the box (z ∈ [−3, 3] covers 5 %–95 % of
every side) and approaches a bound only asymptotically (z → ±∞); `identify` uses it, as
its optimum (the soil) lies inside its box.

Several starts run in one batch (`batch="vmap"`, the default: one vectorised program;
`batch="map"`: one after another inside one compiled program; see `_batched`).
Every step's points, values, gradients and statuses are saved as they come, so an
interrupted run loses nothing.

```python
import numpy as np, jaxworm as jw
res = jw.optimise("velocity", {"omega": (3 * np.pi, 5 * np.pi), "delta": (-np.pi / 3, -np.pi / 6)},
                  t1=10.0, starts=4, steps=30, path="opt.npz")
res.best_value, res.best_theta          # m/s, {"omega": ..., "delta": ...}
jw.load_optimisation("opt.npz")         # the same history, from the file
```
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
import time
from pathlib import Path
from typing import Callable, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax

from . import _files
from ._control import check_horizon, simulated_horizon
from ._files import ResultFileError
from ._numerics import PRESETS, Numerics
from ._params import FLAT_NAMES, Params
from ._result import STATUS, Result, _horizon
from ._solve import SENSITIVITY_SOLVERS, simulate
from ._validation import check_t1

__all__ = ["optimise", "load_optimisation", "OptimiseResult", "cost_of_transport",
           "to_box", "from_box", "box_slope", "OBJECTIVES", "DEFAULT_BOUNDS", "BOXES",
           "DEFAULT_BOX", "DEFAULT_OPTIMISERS", "default_optimiser", "default_horizon", "rprop"]

#: The paper's Fig. 3 plane (A = 0.02 m/s fixed), with δ negative: with the conventions of
#: `MODEL.md` every δ in [π/6, π/3] retreats and δ in [−π/3, −π/6] burrows forward.
DEFAULT_BOUNDS = {"omega": (3 * math.pi, 5 * math.pi), "delta": (-math.pi / 3, -math.pi / 6)}

#: Below this speed [m/s] the worm counts as not advancing for the cost of transport.
COT_MIN_SPEED = 1e-4

FORMAT = "jaxworm-optimise/1"


# --- the box -----------------------------------------------------------------------------

#: Reparametrisations of the box: θ = lo + (hi − lo)(1 + sin z)/2, or lo + (hi − lo) σ(z).
BOXES = {"sine": "theta = lo + (hi - lo) * (1 + sin(z)) / 2",
         "sigmoid": "theta = lo + (hi - lo) * sigmoid(z)"}

#: The box of `optimise` unless told otherwise.
DEFAULT_BOX = "sine"

#: The default optimiser on each box (`default_optimiser`), Adam (issue 5 asks for Adam by
#: default): its first step in z, cosine-decayed to 5 % over the steps, and its momentum
#: b1: none on the sine box, where momentum carries z past a bound and back into the box;
#: 0.9 on the sigmoid. `rprop(0.25)` (iRprop−) needed fewer simulations than the sine
#: default in 6 of 10 gait problems and start sets measured, more in 2 (README, *Gait
#: optimisation*; benchmarks/results/optimise_amplitude*, segment_gait*, optimise_vs_grid*).
DEFAULT_OPTIMISERS = {"sine": {"learning_rate": 0.5, "b1": 0.0},
                      "sigmoid": {"learning_rate": 0.2, "b1": 0.9}}


def to_box(z, lo, hi, box: str = DEFAULT_BOX):
    """An unconstrained z to a point of [lo, hi]: lo + (hi − lo) σ(z), strictly inside
    (`"sigmoid"`), or lo + (hi − lo)(1 + sin z)/2, the bounds at z = ±π/2 (`"sine"`)."""
    if box == "sine":
        return lo + (hi - lo) * 0.5 * (1.0 + jnp.sin(z))
    return lo + (hi - lo) * jax.nn.sigmoid(z)


def from_box(theta, lo, hi, box: str = DEFAULT_BOX):
    """The inverse of `to_box` for lo < θ < hi: logit(u), or arcsin(2u − 1) ∈ (−π/2, π/2),
    u = (θ − lo)/(hi − lo)."""
    u = (theta - lo) / (hi - lo)
    if box == "sine":
        return jnp.arcsin(2.0 * u - 1.0)
    return jnp.log(u) - jnp.log1p(-u)


def box_slope(z, lo, hi, box: str = DEFAULT_BOX):
    """dθ/dz of `to_box` (elementwise)."""
    if box == "sine":
        return (hi - lo) * 0.5 * jnp.cos(z)
    s = jax.nn.sigmoid(z)
    return (hi - lo) * s * (1.0 - s)


# --- objectives --------------------------------------------------------------------------

def cost_of_transport(result: Result, work: str = "actuation",
                      min_speed: float = COT_MIN_SPEED):
    """Energy spent per metre advanced [J/m]: W / Δx.

    - W: the net actuation work ∫∂V/∂l̄·u dt over [0, t_end] (`work="actuation"`, default;
      t_end = t1 unless the run stopped early, `Result.t_end`),
      which by the energy balance equals the friction dissipation plus the work against
      the crack's back pressure plus the final kinetic and stretching energy; or the
      friction dissipation alone (`work="friction"`). Net work: a pump that cannot
      recover energy spends at least this much.
    - Δx = mean_velocity · t_end: the advance of the node mean [m].

    A worm that does not advance has no cost of transport. Below Δx_min = min_speed·t_end
    (default 1e-4 m/s × t_end) the value continues along the tangent of W/Δx at Δx_min,
    W/Δx_min · (2 − Δx/Δx_min): finite, decreasing in Δx, and continuous with its slope,
    so a retreating start is pushed forward instead of meeting a pole. Such values are a
    penalty, not a cost of transport; `OptimiseResult` reports the speed alongside.
    """
    if work not in ("actuation", "friction"):
        raise ValueError(f"option work = {work!r}: need 'actuation' or 'friction'")
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


# --- the problem, as one pytree ----------------------------------------------------------

def _replace(base: Params, names: tuple, theta) -> Params:
    """The default map from θ to parameters: `base.replace(name=θ_i, ...)`."""
    return base.replace(**{n: theta[i] for i, n in enumerate(names)})


class _Simulated(eqx.Module):
    """θ ↦ (objective of the simulation at θ, diagnostics); arrays traced, the rest static."""

    base: Params
    t1: jax.Array
    ts: jax.Array | None
    names: tuple = eqx.field(static=True)
    numerics: Numerics = eqx.field(static=True)
    fn: Callable  # a function (static under filter_jit) or a Module (its arrays traced)
    apply: Callable
    horizon: str = eqx.field(static=True, default="t1")

    def __call__(self, theta):
        p = self.apply(self.base, self.names, theta)
        r = simulate(p, simulated_horizon(p.gait, self.t1, self.horizon), self.numerics,
                     ts=self.ts)
        value = jnp.asarray(self.fn(r), dtype=jnp.float64)
        return value, {"status": r.status, "n_cracks": r.n_cracks, "velocity": r.mean_velocity}


class _Box(eqx.Module):
    """The loss on the unconstrained z: sign · evaluate(to_box(z)) (sign −1 to maximise).

    `evaluate(theta) -> (value, {"status", "n_cracks", "velocity"})` is any callable (a
    simulation, or a toy function in the tests).
    """

    evaluate: Callable
    lo: jax.Array
    hi: jax.Array
    sign: float = eqx.field(static=True)
    box: str = eqx.field(static=True, default=DEFAULT_BOX)

    def loss(self, z):
        value, aux = self.evaluate(to_box(z, self.lo, self.hi, self.box))
        return self.sign * value, (value, aux)


def _batched(fn: Callable, batch: str) -> Callable:
    """Map `fn` over the leading axis (the starts).

    `"vmap"` (the default of `optimise`) runs the starts as one vectorised program;
    `"map"` runs them one after another with `jax.lax.map` (less memory; on a CPU
    with one core, no slower).
    """
    if batch == "vmap":
        return jax.vmap(fn)
    return lambda z: jax.lax.map(fn, z)


def _with_value(out):
    """(loss, aux) -> (loss, (loss, aux)): jacfwd's aux carries the value out."""
    loss, aux = out
    return loss, (loss, aux)


@eqx.filter_jit
def _step(problem: _Box, optimiser, batch: str, derivatives: str, z, z_good, opt_state):
    """One optimiser step for every start.

    A start whose run fails (status not ok, or a non-finite value or gradient) does not
    update its optimiser state; it goes back halfway towards its last good point (halfway
    towards the centre of the box, z = 0, if it has none yet).
    """
    if derivatives == "forward":
        # One forward solve carrying a tangent per parameter (a handful): cheaper than
        # reverse mode here (benchmarks/results/gradient_cost.md).
        def vg(z):
            g, (loss, rest) = jax.jacfwd(lambda z: _with_value(problem.loss(z)), has_aux=True)(z)
            return (loss, rest), g
    else:
        vg = jax.value_and_grad(problem.loss, has_aux=True)
    (_, (value, aux)), g = _batched(vg, batch)(z)
    status = aux["status"]
    ok = (status == 0) & jnp.isfinite(value) & jnp.all(jnp.isfinite(g), axis=-1)
    g = jnp.where(ok[:, None], g, 0.0)
    updates, new_state = jax.vmap(optimiser.update)(g, opt_state, z)
    keep = lambda new, old: jnp.where(ok.reshape((-1,) + (1,) * (new.ndim - 1)), new, old)
    opt_state = jax.tree_util.tree_map(keep, new_state, opt_state)
    no_good_yet = jnp.all(z == z_good, axis=-1, keepdims=True)
    back = jnp.where(no_good_yet, 0.5 * z, z_good + 0.5 * (z - z_good))
    z_next = jnp.where(ok[:, None], optax.apply_updates(z, updates), back)
    z_good = jnp.where(ok[:, None], z, z_good)
    # d(objective)/dθ = sign · d(loss)/dz / (dθ/dz)
    slope = box_slope(z, problem.lo, problem.hi, problem.box)
    grad_theta = problem.sign * g / jnp.where(slope == 0, 1.0, slope)
    grad_theta = jnp.where(ok[:, None] & (slope != 0), grad_theta, jnp.nan)
    return z_next, z_good, opt_state, {"value": value, "grad": grad_theta, **aux}


# --- the record --------------------------------------------------------------------------

@dataclasses.dataclass(frozen=True)
class OptimiseResult:
    """The history of an optimisation and its best point.

    Arrays are indexed (step, start[, parameter]), parameters in the order of `names`:

    - `theta`: the evaluated points, in the parameters' units; `value`: the objective
      there (its own sense and unit: m/s for `"velocity"`, J/m for
      `"cost_of_transport"`); `grad`: d(objective)/dθ (NaN where the run failed);
      `status` (codes of `STATUS`), `n_cracks`, `velocity` (mean velocity [m/s]).
    - `wall_time`: seconds since the start, after each step.
    - `header`: bounds, objective, t1, base parameters, numerics, optimiser, seed, version.
    - `steps_done`: steps saved so far (an interrupted run keeps what it had).

    `best_value`, `best_theta`, `best_step`, `best_start` give the best evaluated point
    whose run ended `ok`; `best_params(base)` the parameters there.
    """

    theta: np.ndarray
    value: np.ndarray
    grad: np.ndarray
    status: np.ndarray
    n_cracks: np.ndarray
    velocity: np.ndarray
    wall_time: np.ndarray
    header: dict
    steps_done: int

    @property
    def names(self) -> list[str]:
        return list(self.header["names"])

    @property
    def bounds(self) -> dict[str, tuple[float, float]]:
        return {n: tuple(b) for n, b in self.header["bounds"].items()}

    @property
    def maximise(self) -> bool:
        return bool(self.header["maximise"])

    @property
    def n_evaluations(self) -> int:
        """Value-and-gradient evaluations done (steps × starts)."""
        return int(self.steps_done * self.value.shape[1])

    def _scores(self) -> np.ndarray:
        v = self.value[: self.steps_done]
        ok = (self.status[: self.steps_done] == 0) & np.isfinite(v)
        return np.where(ok, v if self.maximise else -v, -np.inf)

    @property
    def best_index(self) -> tuple[int, int]:
        """(step, start) of the best ok evaluation; ValueError if there is none."""
        s = self._scores()
        if s.size == 0 or not np.isfinite(s.max()):
            raise ValueError("no evaluation ended with status ok: there is no best point")
        step, start = np.unravel_index(int(np.argmax(s)), s.shape)
        return int(step), int(start)

    @property
    def best_step(self) -> int:
        return self.best_index[0]

    @property
    def best_start(self) -> int:
        return self.best_index[1]

    @property
    def best_value(self) -> float:
        return float(self.value[self.best_index])

    @property
    def best_theta(self) -> dict[str, float]:
        step, start = self.best_index
        return {n: float(self.theta[step, start, i]) for i, n in enumerate(self.names)}

    def best_so_far(self) -> np.ndarray:
        """The best ok value after each step, over all starts (NaN before the first)."""
        s = self._scores().max(axis=1)
        best = np.maximum.accumulate(s)
        best = np.where(np.isfinite(best), best, np.nan)
        return best if self.maximise else -best

    def best_params(self, base: Params | None = None, apply: Callable | None = None) -> Params:
        """`base` (default: Table 1) at the best θ: set by flat name (`Params.replace`), or
        by the `apply(base, names, theta)` the optimisation used."""
        base = Params() if base is None else base
        if apply is not None:
            return apply(base, tuple(self.names), jnp.asarray(list(self.best_theta.values())))
        return base.replace(**self.best_theta)

    def summary(self) -> dict:
        """Plain-Python summary (JSON-able)."""
        out = {"objective": self.header["objective"], "unit": self.header["unit"],
               "maximise": self.maximise, "steps_done": self.steps_done,
               "starts": int(self.value.shape[1]), "evaluations": self.n_evaluations,
               "wall_time_s": float(self.wall_time[self.steps_done - 1]) if self.steps_done else 0.0}
        try:
            step, start = self.best_index
            out.update(best_value=self.best_value, best_theta=self.best_theta,
                       best_step=step, best_start=start,
                       best_velocity=float(self.velocity[step, start]),
                       best_n_cracks=int(self.n_cracks[step, start]))
        except ValueError:
            out.update(best_value=None, best_theta=None)
        return out


_HISTORY = ("theta", "value", "grad", "status", "n_cracks", "velocity", "wall_time")


def _save(path: Path, res: OptimiseResult) -> None:
    _files.save(path, res.header, {"steps_done": np.asarray(res.steps_done),
                                   **{k: getattr(res, k) for k in _HISTORY}})


def load_optimisation(path) -> OptimiseResult:
    """Read a history written by `optimise(..., path=...)`.

    Raises `ResultFileError` (a ValueError) naming the file and what is wrong with it
    when it is not a whole optimisation history (damaged, truncated, empty, a sweep).
    """
    header, arrays = _files.load(path, "optimise")
    try:
        names = header["names"]
        if not isinstance(names, list) or not names:
            raise ValueError(f"its parameter names {names!r} are not a list")
        for key in ("maximise", "objective", "unit", "bounds"):
            header[key]
        steps_done = arrays["steps_done"]
        if steps_done.shape != () or steps_done.dtype.kind not in "iu":
            raise ValueError(f"its steps_done of shape {steps_done.shape}, dtype {steps_done.dtype}")
        hist = {k: arrays[k] for k in _HISTORY}
        steps, starts = hist["value"].shape if hist["value"].ndim == 2 else (-1, -1)
        if steps < 0 or not 0 <= int(steps_done) <= steps:
            raise ValueError(f"its values of shape {hist['value'].shape} and {int(steps_done)} "
                             "steps done")
        need = {"theta": (steps, starts, len(names)), "grad": (steps, starts, len(names)),
                "wall_time": (steps,)}
        for k, a in hist.items():
            shape = need.get(k, (steps, starts))
            if a.shape != shape or a.dtype.kind not in "fiu":
                raise ValueError(f"its {k} of shape {a.shape}, dtype {a.dtype}; need {shape}")
    except KeyError as e:
        raise _files.damaged(path, f"it lacks {e.args[0]!r}") from None
    except ValueError as e:
        raise _files.damaged(path, str(e)) from None
    return OptimiseResult(header=header, steps_done=int(steps_done), **hist)


def _same_problem(old: dict, new: dict) -> list[str]:
    """The header keys in which two optimisation headers differ, the version aside."""
    keys = sorted((set(old) | set(new)) - {"version", "integrity"})
    return [k for k in keys
            if json.dumps(old.get(k), sort_keys=True) != json.dumps(new.get(k), sort_keys=True)]


def _check_existing(path: Path | None, header: dict, overwrite: bool) -> None:
    """ResultFileError unless `path` may receive this optimisation's history: absent, the
    history of the same problem (which a rerun recomputes), or `overwrite`."""
    if path is None or overwrite or not path.exists():
        return
    try:
        old = load_optimisation(path)
    except ResultFileError as e:
        raise ResultFileError(path, e.problem, _files.KEEP_REMEDY) from None
    diff = _same_problem(old.header, header)
    if diff:
        raise ResultFileError(path, "holds the history of another optimisation "
                                    f"({', '.join(diff)} differ)", _files.KEEP_REMEDY)


# --- checks ------------------------------------------------------------------------------

def _check_bounds(bounds: dict, base: Params, custom_apply: bool) -> tuple[tuple, np.ndarray, np.ndarray]:
    if not bounds:
        raise ValueError("bounds is empty: give at least one parameter and its (lo, hi)")
    names, lo, hi = [], [], []
    for name, b in bounds.items():
        if not custom_apply:
            if name == "N":
                raise ValueError("parameter N cannot be optimised: it sets array shapes")
            if name not in FLAT_NAMES:
                raise ValueError(f"bounds: unknown parameter {name!r}; known: "
                                 f"{', '.join(n for n in FLAT_NAMES if n != 'N')}")
        try:
            a, c = (float(v) for v in b)
        except (TypeError, ValueError):
            raise ValueError(f"bounds for {name} = {b!r}: need a pair (lo, hi) of numbers") from None
        if not (math.isfinite(a) and math.isfinite(c) and a < c):
            raise ValueError(f"bounds for {name} = ({a!r}, {c!r}): need finite lo < hi")
        if not custom_apply:  # the parameter's own range check names it and the value
            base.replace(**{name: a})
            base.replace(**{name: c})
        names.append(name)
        lo.append(a)
        hi.append(c)
    return tuple(names), np.array(lo), np.array(hi)


def _initial_points(starts, names, lo, hi, seed: int) -> np.ndarray:
    """(n_starts, P) start points strictly inside the box."""
    P = len(names)
    if isinstance(starts, (int, np.integer)) and not isinstance(starts, bool):
        n = int(starts)
        if n < 1:
            raise ValueError(f"option starts = {starts!r} is out of range: need an integer >= 1")
        # Latin hypercube in the unit box, kept off the edges (5 %-95 % of each side).
        rng = np.random.default_rng(seed)
        u = (np.stack([rng.permutation(n) for _ in range(P)], axis=1)
             + rng.uniform(size=(n, P))) / n
        return lo + (hi - lo) * (0.05 + 0.9 * u)
    if isinstance(starts, dict):
        missing = [n for n in names if n not in starts]
        extra = [n for n in starts if n not in names]
        if missing or extra:
            raise ValueError(f"option starts: need values for exactly {', '.join(names)}; "
                             f"missing {missing}, unknown {extra}")
        cols = [np.atleast_1d(np.asarray(starts[n], dtype=np.float64)) for n in names]
        if len({c.shape for c in cols}) != 1 or cols[0].ndim != 1:
            raise ValueError("option starts: every parameter needs a 1-D list of the same length")
        pts = np.stack(cols, axis=1)
    else:
        pts = np.atleast_2d(np.asarray(starts, dtype=np.float64))
        if pts.ndim != 2 or pts.shape[1] != P or pts.shape[0] < 1:
            raise ValueError(f"option starts of shape {np.shape(starts)}: need an integer, a "
                             f"dict of {', '.join(names)}, or an array (n, {P})")
    for k in range(pts.shape[0]):
        for i, n in enumerate(names):
            if not (lo[i] < pts[k, i] < hi[i]):
                raise ValueError(f"start {k}: {n} = {float(pts[k, i])!r} is outside its "
                                 f"bounds: need {float(lo[i])!r} < {n} < {float(hi[i])!r}")
    return pts


def _objective(objective, maximise) -> tuple[Callable, bool, str, str]:
    if isinstance(objective, str):
        if objective not in OBJECTIVES:
            raise ValueError(f"objective = {objective!r} is unknown: need one of "
                             f"{', '.join(OBJECTIVES)} or a callable of the Result")
        fn, mx, unit = OBJECTIVES[objective]
        if maximise is not None and bool(maximise) != mx:
            raise ValueError(f"option maximise = {maximise!r} contradicts objective "
                             f"{objective!r}, which is {'maximised' if mx else 'minimised'}")
        return fn, mx, unit, objective
    if callable(objective):
        return objective, bool(maximise), "-", getattr(objective, "__name__", type(objective).__name__)
    raise ValueError(f"objective = {objective!r}: need one of {', '.join(OBJECTIVES)} or a "
                     "callable of the Result")


def default_optimiser(steps: int, box: str = DEFAULT_BOX,
                      learning_rate: float | None = None) -> optax.GradientTransformation:
    """The box's default optimiser (`DEFAULT_OPTIMISERS`): Adam on z, its step decaying
    from `learning_rate` (default: the box's) to 5 % of it (cosine) over `steps`."""
    d = DEFAULT_OPTIMISERS[box]
    lr = d["learning_rate"] if learning_rate is None else learning_rate
    return optax.adam(optax.cosine_decay_schedule(lr, max(steps, 1), alpha=0.05), b1=d["b1"])


def describe_default_optimiser(box: str = DEFAULT_BOX) -> str:
    d = DEFAULT_OPTIMISERS[box]
    return (f"adam (b1 {d['b1']:g}), cosine decay {d['learning_rate']:g} -> "
            f"{0.05 * d['learning_rate']:g} over the steps")


def default_horizon(names, gait, ts) -> str:
    """`optimise`'s horizon when none is given: `"whole_periods"` when the frequency
    `omega` is optimised, the gait has one and no `ts` is asked for; else `"t1"`.

    Over a fixed [0, t1] the unfinished last period makes the mean velocity a sawtooth in
    ω (period 2π/t1) whose slopes, about the same at every t1, swamp the gait's own dv̄/dω;
    over whole periods it is smooth. With ω fixed there is no sawtooth to avoid, and `ts`
    (the times of an objective that reads the trajectory) fixes the horizon."""
    return "whole_periods" if ("omega" in names and hasattr(gait, "omega") and ts is None) else "t1"


class RpropState(NamedTuple):
    step_size: jax.Array  # Δ_i, per coordinate
    last_grad: jax.Array  # the previous gradient, zeroed where its sign flipped


def rprop(learning_rate: float = 0.25, eta_minus: float = 0.5, eta_plus: float = 1.2,
          min_step: float = 1e-6, max_step: float = 1.0) -> optax.GradientTransformation:
    """iRprop− (Igel & Hüsken 2000), for a deterministic objective: every coordinate
    steps −sign(g_i)·Δ_i; Δ_i grows by `eta_plus` while g_i keeps its sign and shrinks
    by `eta_minus` when it flips, and then that coordinate does not move for one step.
    `learning_rate` is the first Δ (in z). On the sine box a coordinate whose optimum is
    on a bound oscillates about z = ±π/2 with halving steps, and one at an interior kink
    bisects onto it.

    Written here because `optax.rprop` (0.2.8) emits each update one step late (its first
    update is zero; google-deepmind/optax#1725).
    """
    def init(params):
        return RpropState(jnp.full_like(params, learning_rate), jnp.zeros_like(params))

    def update(grad, state, params=None):
        del params
        turn = grad * state.last_grad
        step = jnp.where(turn > 0, jnp.minimum(state.step_size * eta_plus, max_step),
                         jnp.where(turn < 0, jnp.maximum(state.step_size * eta_minus, min_step),
                                   state.step_size))
        grad = jnp.where(turn < 0, 0.0, grad)
        return -step * jnp.sign(grad), RpropState(step, grad)

    return optax.GradientTransformation(init, update)


# --- the optimiser -----------------------------------------------------------------------

def optimise(objective="velocity", bounds: dict | None = None, *, base: Params | None = None,
             t1=60.0, numerics: Numerics = PRESETS["fast"], starts=4, steps: int = 30,
             optimiser: optax.GradientTransformation | None = None, maximise: bool | None = None,
             seed: int = 0, path=None, progress: bool = True, ts=None,
             apply: Callable | None = None, batch: str = "vmap",
             derivatives: str = "forward", crack_sensitivity: str | None = None,
             horizon: str | None = None, box: str = DEFAULT_BOX,
             overwrite: bool = False) -> OptimiseResult:
    """Optimise gait (or any) parameters within a box by gradients through the solve.

    - `objective`: `"velocity"` (the mean velocity [m/s], maximised), `"cost_of_transport"`
      (actuation work per metre advanced [J/m], minimised; see `cost_of_transport`), or a
      callable `f(result) -> scalar` of the `Result`, minimised unless `maximise=True`.
    - `bounds`: `{name: (lo, hi)}` over flat parameter names (default `DEFAULT_BOUNDS`:
      ω ∈ [3π, 5π] rad/s, δ ∈ [−π/3, −π/6] rad, A = 0.02 m/s fixed). Add `"A": (lo, hi)`
      to tune the amplitude.
    - `base`: the other parameters (Table 1); `t1`: horizon [s]; `numerics`: default
      `fast` (Rodas4: derivatives by forward sensitivities, see `Numerics`); the
      diffrax presets (`default`, `accurate`) are differentiated by diffrax, with
      `crack_sensitivity="tips_held"` unless given.
    - `starts`: a number of Latin-hypercube starts in the box, or the points, as an array
      (n, P) or a dict {name: values}; all run in one batch per step (`batch`, see
      `_batched`).
    - `steps`: optimiser steps; each is one value-and-gradient solve per start.
    - `optimiser`: any optax `GradientTransformation` acting on z (default, by box,
      `DEFAULT_OPTIMISERS`: Adam, its first step cosine-decayed to 5 %: without momentum
      from 0.5 on the sine box, with b1 0.9 from 0.2 on the sigmoid). `rprop(0.25)`
      (iRprop−) took fewer simulations on most gait problems measured (README).
    - `path`: save the history there (`.npz`) after every step; `load_optimisation` reads
      it. The path is checked before anything is computed (its folder exists and is
      writable, no other process writes it: a lock). A file already there is replaced
      only if it is the history of the same problem (same header but the version: a
      rerun); anything else (another optimisation's history, a sweep, a damaged or
      foreign file) is refused with a `ResultFileError` unless `overwrite=True`.
    - `ts`: dense-output times, for objectives that read `result.trajectory`.
    - `apply`: `apply(base, names, theta) -> Params`, for parameters that are not flat
      names (default: `base.replace(**dict(zip(names, theta)))`).
    - `derivatives`: `"forward"` (default; `jax.jacfwd`) or `"reverse"` (`jax.grad`).
      With Rodas4 both take the same forward sensitivities; with a diffrax preset
      `"reverse"` is diffrax's checkpointed adjoint (more memory, ~2.5× the time of
      forward mode at 60 s).
    - `crack_sensitivity`: what the derivative does at crack events
      (`Numerics.crack_sensitivity`); `None` keeps the numerics' own
      (`"schedule_held"`: within 2 % of the finite-difference slope through tens of
      cracks), or `"tips_held"` for a diffrax preset, which cannot hold the schedule.
    - `horizon`: `"t1"` simulates [0, t1]; `"whole_periods"` simulates up to the last
      whole gait period, K·2π/ω with K = ⌊ω t1/2π⌋ (`whole_period_horizon`), so the
      objective averages over whole periods. Over [0, t1] the unfinished last period
      makes the mean velocity a sawtooth in ω (period 2π/t1) whose slopes, not the
      gait's, dominate dv̄/dω; over whole periods it is smooth. Needs a gait with a
      frequency `omega` (the travelling wave). Default (`None`): whole periods when
      `omega` is optimised and no `ts` is given, else t1 (`default_horizon`); the
      header of the history records which.
    - `box`: the reparametrisation, `"sine"` (default; bounds reached at finite z, as
      gait optima on a bound need) or `"sigmoid"` (every point strictly inside). See
      the module docstring.

    Returns an `OptimiseResult` (history, best point, best value).
    """
    base = Params() if base is None else base
    bounds = dict(DEFAULT_BOUNDS if bounds is None else bounds)
    fn, mx, unit, obj_name = _objective(objective, maximise)
    names, lo, hi = _check_bounds(bounds, base, apply is not None)
    if not (isinstance(steps, (int, np.integer)) and not isinstance(steps, bool) and steps >= 1):
        raise ValueError(f"option steps = {steps!r} is out of range: need an integer >= 1")
    t1f = float(check_t1(t1))
    if numerics.solver in SENSITIVITY_SOLVERS and numerics.fixed_step:
        raise ValueError(f"numerics dt = {numerics.dt!r}: derivatives need adaptive steps with "
                         f"solver {numerics.solver!r} (its sensitivities control them); drop dt")
    if box not in BOXES:
        raise ValueError(f"option box = {box!r}: need one of {', '.join(BOXES)}")
    if horizon is None:
        horizon = default_horizon(names, base.gait, ts)
    check_horizon(horizon, base.gait)
    if batch not in ("map", "vmap"):
        raise ValueError(f"option batch = {batch!r}: need 'map' or 'vmap'")
    if derivatives not in ("forward", "reverse"):
        raise ValueError(f"option derivatives = {derivatives!r}: need 'forward' or 'reverse'")
    if crack_sensitivity is None:
        crack_sensitivity = ("tips_held" if numerics.solver not in SENSITIVITY_SOLVERS
                             and numerics.crack_sensitivity == "schedule_held"
                             else numerics.crack_sensitivity)
    numerics = numerics.replace(adjoint="forward" if derivatives == "forward" else "reverse",
                                crack_sensitivity=crack_sensitivity)
    theta0 = _initial_points(starts, names, lo, hi, seed)
    # without the memory addresses in the repr, which differ from run to run
    described = (describe_default_optimiser(box) if optimiser is None
                 else re.sub(r" at 0x[0-9a-fA-F]+", "", repr(optimiser))[:200])
    optimiser = default_optimiser(int(steps), box) if optimiser is None else optimiser
    if not isinstance(optimiser, optax.GradientTransformation):
        raise ValueError(f"option optimiser = {optimiser!r}: need an optax GradientTransformation")

    evaluate = _Simulated(base=base, t1=jnp.asarray(t1f, dtype=jnp.float64),
                          ts=None if ts is None else jnp.asarray(ts, dtype=jnp.float64),
                          names=names, numerics=numerics, fn=fn,
                          apply=_replace if apply is None else apply, horizon=horizon)
    from ._version import __version__

    header = {
        "format": FORMAT, "version": __version__, "objective": obj_name, "unit": unit,
        "maximise": mx, "names": list(names),
        "bounds": {nm: [float(a), float(b)] for nm, a, b in zip(names, lo, hi)},
        "t1": t1f, "horizon": horizon, "steps": int(steps), "starts": int(theta0.shape[0]), "seed": int(seed),
        "batch": batch, "derivatives": derivatives, "optimiser": described,
        "reparametrisation": BOXES[box], "box": box,
        "numerics": dataclasses.asdict(numerics),
        "base_parameters": {k: (v if isinstance(v, (int, str)) else np.asarray(v).tolist())
                            for k, v in base.flat().items() if v is not None},
        "status_codes": {str(k): v for k, v in STATUS.items()},
    }
    return _descend(evaluate, lo, hi, theta0, mx, int(steps), optimiser, batch, header,
                    path, progress, derivatives, box, overwrite)


def _descend(evaluate: Callable, lo, hi, theta0, maximise: bool, steps: int, optimiser,
             batch: str, header: dict, path=None, progress: bool = True,
             derivatives: str = "forward", box: str = DEFAULT_BOX,
             overwrite: bool = False) -> OptimiseResult:
    """The optimisation loop: `steps` batched steps from the points `theta0` (n, P).

    `evaluate(theta) -> (value, {"status", "n_cracks", "velocity"})` is traced under
    `jax.jacfwd` (or `jax.value_and_grad`, `derivatives="reverse"`) and batched over
    the starts by `_batched`; `header` must carry
    `names`, `maximise`, `objective` and `unit`. Saves to `path` after every step.
    """
    problem = _Box(evaluate=evaluate, lo=jnp.asarray(lo, dtype=jnp.float64),
                   hi=jnp.asarray(hi, dtype=jnp.float64), sign=-1.0 if maximise else 1.0,
                   box=box)
    n, P = theta0.shape
    shape = (steps, n)
    rec = {"theta": np.full(shape + (P,), np.nan), "value": np.full(shape, np.nan),
           "grad": np.full(shape + (P,), np.nan), "status": np.full(shape, -1, dtype=np.int64),
           "n_cracks": np.full(shape, -1, dtype=np.int64), "velocity": np.full(shape, np.nan),
           "wall_time": np.full(steps, np.nan)}
    # The output is checked and locked before anything is computed.
    with _files.claim(path) as target:
        _check_existing(target, header, overwrite)
        z = from_box(jnp.asarray(theta0, dtype=jnp.float64), problem.lo, problem.hi, box)
        z_good = z
        opt_state = jax.vmap(optimiser.init)(z)
        from tqdm import tqdm

        unit = header.get("unit", "")
        bar = tqdm(total=steps, desc=f"optimise {header.get('objective', '')}", unit="step",
                   disable=not progress)
        t0 = time.perf_counter()
        res = OptimiseResult(header=header, steps_done=0, **rec)
        for k in range(steps):
            theta = np.asarray(to_box(z, problem.lo, problem.hi, box))
            z, z_good, opt_state, out = _step(problem, optimiser, batch, derivatives, z,
                                              z_good, opt_state)
            rec["theta"][k] = theta
            for key in ("value", "grad", "status", "n_cracks", "velocity"):
                rec[key][k] = np.asarray(out[key])
            rec["wall_time"][k] = time.perf_counter() - t0
            res = OptimiseResult(header=header, steps_done=k + 1, **rec)
            if target is not None:
                _save(target, res)
            try:
                bar.set_postfix(best=f"{res.best_value:.6g} {unit}", refresh=False)
            except ValueError:
                bar.set_postfix(best="none ok", refresh=False)
            bar.update(1)
        bar.close()
        return res

"""Gait optimisation: gradient descent with optax on a simulated objective, in a box.

The pieces, one module each: the box's reparametrisation (`_box`: `SineBox`, the
default, reaches a bound at a finite z; `SigmoidBox` keeps every point strictly
inside), the objectives (`_objectives`), the optimiser (`_optimiser`: Adam by default,
`rprop`), the samples an objective is averaged over (`_samples`), and the history and
its file (`_history`). This module is the driver: each
step solves every start's value and gradient in one batch (`batch="vmap"`, the
default: one vectorised program; `batch="map"`: one after another inside one compiled
program; see `_batched`), and saves every step's points, values, gradients and
statuses as they come, so an interrupted run loses nothing.

```python
import numpy as np, jaxworm as jw
res = jw.optimise("velocity", {"omega": (3 * np.pi, 5 * np.pi), "delta": (-np.pi / 3, -np.pi / 6)},
                  t1=10.0, starts=4, steps=30, path="opt.npz")
res.best_value, res.best_theta          # m/s, {"omega": ..., "delta": ...}
jw.load_optimisation("opt.npz")         # the same history, from the file
```
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import math
import re
import sys
import time
import warnings
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import cast

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax
from jaxtyping import Array, ArrayLike, Float

from . import _distributed, _files
from ._box import DEFAULT_BOX, AbstractBox, as_box
from ._control import check_horizon
from ._fingerprint import callable_fields, scene_fingerprint
from ._history import OptimiseResult, previous_history, save_history
from ._numerics import PRESETS, Numerics
from ._objectives import objective_value, resolve_objective
from ._optimiser import default_optimiser, describe_default_optimiser
from ._params import FLAT_NAMES, Params
from ._result import STATUS, Result
from ._resume import numpy_leaves, restore, resumable
from ._samples import check_samples, describe_samples, per_sample, pool
from ._solve import (
    FRACTURE_CONSTANTS,
    SENSITIVITY_SOLVERS,
    SensitivityUnavailableError,
    equinox_checks,
    simulate,
)
from ._sweep import MAX_SCENES
from ._threads import MAX_WORKERS, default_workers
from ._validation import check_instance, check_int, check_t1, check_ts

__all__ = [
    "optimise",
    "DEFAULT_BOUNDS",
    "default_horizon",
    "derivative_numerics",
    "describe_optimiser",
    "optimiser_fingerprint",
    "value_and_grad",
]

#: The paper's Fig. 3 plane (A = 0.02 m/s fixed), with δ negative: with the conventions of
#: `MODEL.md` every δ in [π/6, π/3] retreats and δ in [−π/3, −π/6] burrows forward.
DEFAULT_BOUNDS = {"omega": (3 * math.pi, 5 * math.pi), "delta": (-math.pi / 3, -math.pi / 6)}


# --- the problem, as one pytree ----------------------------------------------------------


def _name(fn) -> str:
    """A callable's name for a header (its type's for an object without one)."""
    return getattr(fn, "__name__", type(fn).__name__)


def _replace(base: Params, names: tuple, theta) -> Params:
    """The default map from θ to parameters: `base.replace(name=θ_i, ...)`."""
    return base.replace(**{n: theta[i] for i, n in enumerate(names)})


class _Simulated(eqx.Module):
    """θ ↦ (objective of the simulation at θ, diagnostics); arrays traced, the rest static.

    With `samples` (`_samples`), the objective is the mean over the samples' scenes,
    solved as one vmapped batch, and the diagnostics are pooled (`pool`: the status of
    the first sample not ok, the cracks of all, the mean velocity); `per_sample` gives
    each sample's own.
    """

    base: Params
    t1: jax.Array
    ts: jax.Array | None
    names: tuple = eqx.field(static=True)
    numerics: Numerics = eqx.field(static=True)
    fn: Callable  # a function (static under filter_jit) or a Module (its arrays traced)
    apply: Callable
    horizon: str = eqx.field(static=True, default="t1")
    samples: dict | None = None

    def run(self, p: Params):
        """(objective, diagnostics) of the simulation of `p`."""
        r = simulate(p, self.t1, self.numerics, ts=self.ts, horizon=self.horizon)
        value = objective_value(self.fn, r)
        return value, {"status": r.status, "n_cracks": r.n_cracks, "velocity": r.mean_velocity}

    def per_sample(self, theta):
        """(objectives (S,), diagnostics (S,)) at θ, one per sample (S = 1 without)."""
        return per_sample(
            lambda scene: self.run(self.apply(scene, self.names, theta)), self.base, self.samples
        )

    def __call__(self, theta):
        if self.samples is None:
            return self.run(self.apply(self.base, self.names, theta))
        return pool(*self.per_sample(theta))


class _Problem(eqx.Module):
    """The loss on the unconstrained z: sign · evaluate(box.to_box(z)) (sign −1 to maximise).

    `evaluate(theta) -> (value, {"status", "n_cracks", "velocity"})` is any callable (a
    simulation, or a toy function in the tests).
    """

    evaluate: Callable
    lo: jax.Array
    hi: jax.Array
    sign: float = eqx.field(static=True)
    box: AbstractBox

    def loss(self, z):
        value, aux = self.evaluate(self.box.to_box(z, self.lo, self.hi))
        return self.sign * value, (value, aux)


def _batched(fn: Callable, batch: str) -> Callable:
    """Map `fn` over the leading axis (the starts).

    `"vmap"` (the default of `optimise`) runs the starts as one vectorised program;
    `"map"` runs them one after another with `jax.lax.map` (less memory; which is
    faster on a CPU depends on the problem: docs, Optimisation). A batch of one start
    is solved alone either way: a vmapped lane runs both branches of every conditional
    of the solver and has no other lane to share them with (benchmarks/optimise_batch.py
    measures both).
    """

    def batched(z):
        if batch == "vmap" and z.shape[0] > 1:
            return jax.vmap(fn)(z)
        return jax.lax.map(fn, z)

    return batched


def _with_value(out):
    """(loss, aux) -> (loss, (loss, aux)): jacfwd's aux carries the value out."""
    loss, aux = out
    return loss, (loss, aux)


def value_and_grad(loss: Callable, derivatives: str) -> Callable:
    """x ↦ ((loss, aux), d loss/dx) of `loss(x) -> (scalar, aux)`, x any pytree of arrays.

    `"forward"`: `jax.jacfwd`, one forward solve carrying a tangent per parameter (a
    handful: cheaper than reverse mode here, benchmarks/results/gradient_cost/gradient_cost.md);
    `"reverse"`: `jax.value_and_grad`.
    """
    if derivatives == "forward":

        def vg(x):
            g, (value, aux) = jax.jacfwd(lambda x: _with_value(loss(x)), has_aux=True)(x)
            return (value, aux), g

        return vg
    return jax.value_and_grad(loss, has_aux=True)


@eqx.filter_jit
def _step(problem: _Problem, optimiser, batch: str, derivatives: str, z, z_good, opt_state):
    """One optimiser step for every start.

    A start whose run fails (status not ok, or a non-finite value or gradient) does not
    update its optimiser state; it goes back halfway towards its last good point (halfway
    towards the centre of the box, z = 0, if it has none yet).
    """
    vg = value_and_grad(problem.loss, derivatives)
    (_, (value, aux)), g = _batched(vg, batch)(z)
    status = aux["status"]
    ok = (status == 0) & jnp.isfinite(value) & jnp.all(jnp.isfinite(g), axis=-1)
    g = jnp.where(ok[:, None], g, 0.0)
    updates, new_state = jax.vmap(optimiser.update)(g, opt_state, z)

    def keep(new, old):
        return jnp.where(ok.reshape((-1,) + (1,) * (new.ndim - 1)), new, old)

    opt_state = jax.tree_util.tree_map(keep, new_state, opt_state)
    no_good_yet = jnp.all(z == z_good, axis=-1, keepdims=True)
    back = jnp.where(no_good_yet, 0.5 * z, z_good + 0.5 * (z - z_good))
    stepped = cast(jax.Array, optax.apply_updates(z, updates))  # an array, as z is
    z_next = jnp.where(ok[:, None], stepped, back)
    z_good = jnp.where(ok[:, None], z, z_good)
    # d(objective)/dθ = sign · d(loss)/dz / (dθ/dz)
    slope = problem.box.slope(z, problem.lo, problem.hi)
    grad_theta = problem.sign * g / jnp.where(slope == 0, 1.0, slope)
    grad_theta = jnp.where(ok[:, None] & (slope != 0), grad_theta, jnp.nan)
    return z_next, z_good, opt_state, {"value": value, "grad": grad_theta, **aux}


def default_numerics(objective) -> Numerics:
    """`optimise`'s numerics when none are given: `fast`; for the mean velocity, with the
    sensitivities' error measured on the mean node position alone, which is all that
    objective's derivative reads (`Numerics.sensitivity_norm`)."""
    fast = PRESETS["fast"]
    velocity = isinstance(objective, str) and objective == "velocity"
    return fast.replace(sensitivity_norm="mean_position") if velocity else fast


def derivative_numerics(
    numerics: Numerics, derivatives: str, crack_sensitivity: str | None
) -> Numerics:
    """`numerics` for value-and-gradient solves by `derivatives` (`"forward"` or
    `"reverse"`), with `crack_sensitivity` (None: the numerics' own, or `"tips_held"` for
    a diffrax solver, which cannot hold the schedule); refused, by name, when the
    derivatives cannot be taken (fixed steps with a sensitivity solver)."""
    if derivatives not in ("forward", "reverse"):
        raise ValueError(f"option derivatives = {derivatives!r}: need 'forward' or 'reverse'")
    if numerics.solver in SENSITIVITY_SOLVERS and numerics.fixed_step:
        raise ValueError(
            f"numerics dt = {numerics.dt!r}: derivatives need adaptive steps with "
            f"solver {numerics.solver!r} (its sensitivities control them); drop dt"
        )
    if crack_sensitivity is None:
        crack_sensitivity = (
            "tips_held"
            if numerics.solver not in SENSITIVITY_SOLVERS
            and numerics.crack_sensitivity == "schedule_held"
            else numerics.crack_sensitivity
        )
    return numerics.replace(
        adjoint="forward" if derivatives == "forward" else "reverse",
        crack_sensitivity=crack_sensitivity,
    )


def describe_optimiser(optimiser, steps: int = 5) -> str:
    """An optax optimiser in words, for a result header: its repr without the memory
    addresses (which differ from run to run), then a fingerprint of what it does.

    An optax repr names the transformation but not its hyperparameters (`adam(0.1)` and
    `adam(0.2)` print alike), and a history is resumed only under the same header, so
    the fingerprint hashes the updates the optimiser makes from a fixed probe over the
    run's `steps` on a fixed gradient sequence: optimisers that differ in any
    hyperparameter acting within the run (a schedule's later boundaries included) get
    different headers. An optimiser that cannot take the probe (one that needs extra
    arguments) is described by its repr alone, marked `unprobed`. Refused unless a
    GradientTransformation."""
    if not isinstance(optimiser, optax.GradientTransformation):
        raise ValueError(f"option optimiser = {optimiser!r}: need an optax GradientTransformation")
    words = re.sub(r" at 0x[0-9a-fA-F]+", "", repr(optimiser))[:200]
    return f"{words} [{optimiser_fingerprint(optimiser, steps)}]"


def optimiser_fingerprint(optimiser, steps: int = 5) -> str:
    """`behaviour <12 hex digits>`: a hash of the updates `optimiser` makes over `steps`
    steps from a fixed probe (parameters and gradients of mixed signs and scales), or
    `unprobed` when it cannot take the probe."""
    probe = jnp.array([-1.5, -0.2, 0.05, 0.7, 3.0], dtype=jnp.float64)

    def step(carry, k):
        theta, state = carry
        g = jnp.cos((k + 1.0) * probe + k) * (1.0 + k) ** jnp.where(k % 2 == 0, 1.0, -1.0)
        u, state = optimiser.update(g, state, theta)
        return (optax.apply_updates(theta, u), state), u

    try:
        ks = jnp.arange(steps, dtype=jnp.float64)
        _, updates = jax.jit(lambda: jax.lax.scan(step, (probe, optimiser.init(probe)), ks))()
        updates = np.asarray(updates, dtype=np.float64).ravel()
    except Exception:  # any optimiser the probe cannot drive
        return "unprobed"
    # Rounded to 10 significant digits: the same optimiser hashes alike across machines.
    digits = np.array([float(f"{v:.10g}") for v in updates])
    return "behaviour " + hashlib.sha256(digits.tobytes()).hexdigest()[:12]


def default_horizon(names, gait, ts) -> str:
    """`optimise`'s horizon when none is given: `"whole_periods"` when the frequency
    `omega` is optimised, the gait is periodic (`AbstractController.period`) and no `ts`
    is asked for; else `"t1"`.

    Over a fixed [0, t1] the unfinished last period makes the mean velocity a sawtooth in
    ω (period 2π/t1) whose slopes, about the same at every t1, swamp the gait's own dv̄/dω;
    over whole periods it is smooth. With ω fixed there is no sawtooth to avoid, and `ts`
    (the times of an objective that reads the trajectory) fixes the horizon."""
    return (
        "whole_periods" if "omega" in names and gait.period() is not None and ts is None else "t1"
    )


# --- checks ------------------------------------------------------------------------------


def _check_bounds(
    bounds: dict, base: Params, custom_apply: bool
) -> tuple[tuple, np.ndarray, np.ndarray]:
    if not bounds:
        raise ValueError("bounds is empty: give at least one parameter and its (lo, hi)")
    names, lo, hi = [], [], []
    for name, b in bounds.items():
        if not custom_apply:
            if name == "N":
                raise ValueError("parameter N cannot be optimised: it sets array shapes")
            if name not in FLAT_NAMES:
                raise ValueError(
                    f"bounds: unknown parameter {name!r}; known: "
                    f"{', '.join(n for n in FLAT_NAMES if n != 'N')}"
                )
        try:
            a, c = (float(v) for v in b)
        except (TypeError, ValueError):
            raise ValueError(
                f"bounds for {name} = {b!r}: need a pair (lo, hi) of numbers"
            ) from None
        if not (math.isfinite(a) and math.isfinite(c) and a < c):
            raise ValueError(f"bounds for {name} = ({a!r}, {c!r}): need finite lo < hi")
        if not custom_apply:  # the parameter's own range check names it and the value
            for v in (a, c):
                try:
                    base.replace(**{name: v})
                except ValueError as e:  # a check of another parameter may name only it
                    raise ValueError(
                        f"bounds for {name} = ({a!r}, {c!r}): the scene at {name} = {v!r} "
                        f"is invalid: {str(e).splitlines()[0]}"
                    ) from None
        names.append(name)
        lo.append(a)
        hi.append(c)
    return tuple(names), np.array(lo), np.array(hi)


def _initial_points(starts, names, lo, hi, seed: int) -> np.ndarray:
    """(n_starts, P) start points strictly inside the box."""
    P = len(names)
    if isinstance(starts, (int, np.integer)) and not isinstance(starts, bool):
        n = int(starts)
        if not 1 <= n <= MAX_SCENES:
            raise ValueError(
                f"option starts = {starts!r} is out of range: need an integer 1 <= starts "
                f"<= {MAX_SCENES}"
            )
        # Latin hypercube in the unit box, kept off the edges (5 %-95 % of each side).
        rng = np.random.default_rng(seed)
        u = (
            np.stack([rng.permutation(n) for _ in range(P)], axis=1) + rng.uniform(size=(n, P))
        ) / n
        return lo + (hi - lo) * (0.05 + 0.9 * u)
    if isinstance(starts, dict):
        missing = [n for n in names if n not in starts]
        extra = [n for n in starts if n not in names]
        if missing or extra:
            raise ValueError(
                f"option starts: need values for exactly {', '.join(names)}; "
                f"missing {missing}, unknown {extra}"
            )
        cols = [np.atleast_1d(np.asarray(starts[n], dtype=np.float64)) for n in names]
        if len({c.shape for c in cols}) != 1 or cols[0].ndim != 1:
            raise ValueError("option starts: every parameter needs a 1-D list of the same length")
        pts = np.stack(cols, axis=1)
    else:
        if isinstance(starts, (float, np.floating)):
            raise TypeError(
                f"option starts = {starts!r}: need an integer count, a dict of "
                f"{', '.join(names)}, or an array (n, {P}) of points"
            )
        pts = np.atleast_2d(np.asarray(starts, dtype=np.float64))
        if pts.ndim != 2 or pts.shape[1] != P or pts.shape[0] < 1:
            raise ValueError(
                f"option starts of shape {np.shape(starts)}: need an integer, a "
                f"dict of {', '.join(names)}, or an array (n, {P})"
            )
    if pts.shape[0] > MAX_SCENES:
        raise ValueError(f"option starts: {pts.shape[0]} points; need at most {MAX_SCENES}")
    for k in range(pts.shape[0]):
        for i, n in enumerate(names):
            if not (lo[i] < pts[k, i] < hi[i]):
                raise ValueError(
                    f"start {k}: {n} = {float(pts[k, i])!r} is outside its "
                    f"bounds: need {float(lo[i])!r} < {n} < {float(hi[i])!r}"
                )
    return pts


# --- the optimiser -----------------------------------------------------------------------


def optimise(
    objective: str | Callable[[Result], Float[ArrayLike, ""]] = "velocity",
    bounds: dict | None = None,
    *,
    base: Params | None = None,
    t1: float | Float[Array, ""] = 60.0,
    numerics: Numerics | None = None,
    starts=4,
    steps: int = 30,
    optimiser: optax.GradientTransformation | None = None,
    maximise: bool | None = None,
    seed: int = 0,
    path=None,
    progress: bool = True,
    ts=None,
    apply: Callable | None = None,
    batch: str = "vmap",
    derivatives: str = "forward",
    crack_sensitivity: str | None = None,
    horizon: str | None = None,
    box: str | AbstractBox = DEFAULT_BOX,
    overwrite: bool = False,
    samples: dict | None = None,
    workers: int | None = None,
) -> OptimiseResult:
    """Optimise gait (or any) parameters within a box by gradients through the solve.

    - `objective`: `"velocity"` (the mean velocity [m/s], maximised), `"cost_of_transport"`
      (actuation work per metre advanced [J/m], minimised; see `cost_of_transport`), or a
      callable `f(result) -> scalar` of the `Result`, minimised unless `maximise=True`.
    - `bounds`: `{name: (lo, hi)}` over flat parameter names (default `DEFAULT_BOUNDS`:
      ω ∈ [3π, 5π] rad/s, δ ∈ [−π/3, −π/6] rad, A = 0.02 m/s fixed). Add `"A": (lo, hi)`
      to tune the amplitude.
    - `base`: the other parameters (Table 1); `t1`: horizon [s]; `numerics`: default
      `fast` (Rodas4: derivatives by forward sensitivities, see `Numerics`), for the
      `"velocity"` objective with `sensitivity_norm="mean_position"` (the step control
      watches the error of the mean velocity's derivative alone: fewer steps); the
      diffrax presets (`default`, `accurate`) are differentiated by diffrax, with
      `crack_sensitivity="tips_held"` unless given.
    - `starts`: a number of Latin-hypercube starts in the box, or the points, as an array
      (n, P) or a dict {name: values}; all run in one batch per step (`batch`, see
      `_batched`), or in `workers` equal groups at once, each batch from its own thread
      on the default device, all through one compiled program. `workers` defaults to
      the largest divisor of the starts (of this process's share) that is at most the
      CPU cores (`jaxworm._threads`; 1 on an accelerator); a rerun that continues a
      saved history (one process) takes the `workers` the file records. Batches of
      different sizes are different compiled programs: their values agree to the
      solver's tolerance, not bit for bit; `workers=1` keeps one batch. JAX's context managers
      (`jax.debug_nans`, ...) entered by the caller do not reach the worker threads.
    - `steps`: optimiser steps; each is one value-and-gradient solve per start.
    - `optimiser`: any optax `GradientTransformation` acting on z (default, by box,
      `DEFAULT_OPTIMISERS`: Adam, its first step cosine-decayed to 5 %: without momentum
      from 0.5 on the sine box, with b1 0.9 from 0.2 on the sigmoid); `make_optimiser`
      builds the others by name. `rprop(0.25)` (iRprop−) took fewer simulations on
      most gait problems measured.
    - `path`: save the history there (`.npz`) after every step; `load_optimisation`
      reads it. The path is checked before anything is computed (its folder exists and
      is writable, no other process writes it: a lock). With each step it keeps the
      state the next step starts from (`OptimiseResult.state`): a file that is the
      history of the same problem (same header) is resumed, the rerun continuing from
      its last step as the uninterrupted run would have (bit for bit); a finished one
      is returned as it is. One written by another jaxworm version, or without a state,
      is recomputed (a `RuntimeWarning` says so) and replaced once the rerun has as many
      steps, or at its end, so that a killed rerun leaves it whole. Anything else
      (another optimisation's history, a sweep, a damaged or foreign file) is refused
      with a `ResultFileError`. `overwrite=True` replaces any file, recomputing from
      step 0. The header identifies the whole scene
      `base` (a SHA-256 of its values and structure, beside its flat parameters), the
      start points, a callable objective or `apply` by a SHA-256 of its code and the
      values it holds (`objective_sha256`), and `ts` by theirs.
    - `ts`: dense-output times, for objectives that read `result.trajectory`.
    - `apply`: `apply(base, names, theta) -> Params`, for parameters that are not flat
      names (default: `base.replace(**dict(zip(names, theta)))`).
    - `derivatives`: `"forward"` (default; `jax.jacfwd`) or `"reverse"` (`jax.grad`).
      With Rodas4 both take the same forward sensitivities; with a diffrax preset
      `"reverse"` is diffrax's checkpointed adjoint (more memory and time than forward
      mode for a few parameters: docs, Gradients).
    - `crack_sensitivity`: what the derivative does at crack events
      (`Numerics.crack_sensitivity`); `None` keeps the numerics' own
      (`"schedule_held"`: within 2 % of the finite-difference slope through tens of
      cracks), or `"tips_held"` for a diffrax preset, which cannot hold the schedule.
      Bounds on K_Ic or K_Ith need `"exact"` (or `"tips_held"`): under the held
      schedule they are refused (`SensitivityUnavailableError`) before anything runs.
    - `horizon`: `"t1"` simulates [0, t1]; `"whole_periods"` simulates up to the last
      whole gait period, K·2π/ω with K = ⌊ω t1/2π⌋ (`simulate`'s `horizon`), so the
      objective averages over whole periods. Over [0, t1] the unfinished last period
      makes the mean velocity a sawtooth in ω (period 2π/t1) whose slopes, not the
      gait's, dominate dv̄/dω; over whole periods it is smooth. Needs a periodic gait
      (`AbstractController.period`), and t1 at least the longest period the bounds
      allow (`ValueError` otherwise). Default (`None`): whole periods when
      `omega` is optimised and no `ts` is given, else t1 (`default_horizon`); the
      header of the history records which.
    - `box`: the reparametrisation, `"sine"` (`SineBox`, default; bounds reached at
      finite z, as gait optima on a bound need), `"sigmoid"` (`SigmoidBox`, every point
      strictly inside), or any `AbstractBox`.
    - `samples`: average the objective over scenes, e.g. soil samples: a dict
      {name: values} of names `Params.replace` sets (flat names such as `K_Ic`, or a
      part: `soil`, `body`, `smoothing`), each value with a leading sample axis of one
      length S (an array, a batch of profiles or soils, or a list of S values of one
      structure). Sample i is the scene `base.replace(**{name: values[i]})`, then θ is
      applied to it (`apply`). Each start's value is the mean of the objective over the S
      scenes, solved as one vmapped batch, and its gradient that mean's. A start is
      recorded with the status of its first sample that is not ok (ok only if all are),
      its cracks summed over the samples and its velocity averaged. The header records
      the samples (number, names, SHA-256 of their values), so a rerun with other
      samples is another problem. Names set by `bounds` cannot be sampled.

    **Several processes.** Started under `jax.distributed.initialize()`, every process
    calls `optimise` with the same arguments; the starts are split between them (at
    least one each), every step's records of all starts reach every process, all of
    them return the whole history, and process 0 alone writes `path` and shows
    progress.

    Returns an `OptimiseResult` (history, best point, best value).
    """
    base = Params() if base is None else base
    check_instance("base", base, Params, "jw.Params().replace(omega=...)")
    bounds = dict(DEFAULT_BOUNDS if bounds is None else bounds)
    fn, mx, unit, obj_name = resolve_objective(objective, maximise)
    numerics = default_numerics(objective) if numerics is None else numerics
    check_instance("numerics", numerics, Numerics, "jw.PRESETS['fast']")
    names, lo, hi = _check_bounds(bounds, base, apply is not None)
    if not (isinstance(steps, (int, np.integer)) and not isinstance(steps, bool) and steps >= 1):
        raise ValueError(f"option steps = {steps!r} is out of range: need an integer >= 1")
    check_int("seed", seed, 0, None, kind="option")
    if workers is not None:
        check_int("workers", workers, 1, MAX_WORKERS, kind="option")
    t1f = float(check_t1(t1))
    numerics = derivative_numerics(numerics, derivatives, crack_sensitivity)
    fracture = [n for n in names if n in FRACTURE_CONSTANTS]
    if fracture and numerics.crack_sensitivity == "schedule_held":
        raise SensitivityUnavailableError(
            f"option bounds: {fracture[0]} cannot be optimised under crack_sensitivity="
            "'schedule_held' (the default), which holds the crack schedule that it acts "
            "through; pass crack_sensitivity='exact' (right over a few cracks, off the "
            "finite-difference slope through tens of them; docs: Gradients)"
        )
    box = as_box(box)
    if horizon is None:
        horizon = default_horizon(names, base.gait, ts)
    # t1 must hold the longest period the bounds allow
    longest = 2 * np.pi / lo[names.index("omega")] if "omega" in names else None
    check_horizon(horizon, base.gait, t1f, longest)
    if batch not in ("map", "vmap"):
        raise ValueError(f"option batch = {batch!r}: need 'map' or 'vmap'")
    samples, _ = check_samples(samples, base, () if apply is not None else names)
    theta0 = _initial_points(starts, names, lo, hi, seed)
    if optimiser is None:
        described = describe_default_optimiser(box)
    else:
        described = describe_optimiser(optimiser, int(steps))
    optimiser = default_optimiser(int(steps), box) if optimiser is None else optimiser

    evaluate = _Simulated(
        base=base,
        t1=jnp.asarray(t1f, dtype=jnp.float64),
        ts=check_ts(ts, t1f),
        names=names,
        numerics=numerics,
        fn=fn,
        apply=_replace if apply is None else apply,
        horizon=horizon,
        samples=samples,
    )
    header = _files.header(
        "optimise",
        objective=obj_name,
        **callable_fields("objective", objective),
        unit=unit,
        maximise=mx,
        names=list(names),
        bounds={nm: [float(a), float(b)] for nm, a, b in zip(names, lo, hi)},
        t1=t1f,
        horizon=horizon,
        steps=int(steps),
        starts=int(theta0.shape[0]),
        starts_sha256=_files.digest({"theta0": np.asarray(theta0, dtype=np.float64)}),
        seed=int(seed),
        batch=batch,
        derivatives=derivatives,
        optimiser=described,
        reparametrisation=box.formula,
        box=box.name,
        numerics=dataclasses.asdict(numerics),
        base_parameters=_files.plain(base.flat()),
        base_scene=scene_fingerprint(base),
        status_codes={str(k): v for k, v in STATUS.items()},
        **({} if samples is None else {"samples": describe_samples(samples)}),
        **({} if apply is None else {"apply": _name(apply), **callable_fields("apply", apply)}),
        **({} if ts is None else {"ts_sha256": _files.digest({"ts": np.asarray(evaluate.ts)})}),
    )
    return _descend(
        evaluate,
        lo,
        hi,
        theta0,
        mx,
        int(steps),
        optimiser,
        batch,
        header,
        path,
        progress,
        derivatives,
        box,
        overwrite,
        workers,
    )


def _resumed_groups(old: OptimiseResult, n: int, groups: list[slice], path) -> list[slice]:
    """The groups of the history `old` that a rerun not given `workers` continues: the
    file's `workers` when it cuts the `n` starts into equal groups, so that the rerun
    continues bit for bit whatever its cores; else `groups` (with a warning when the
    file has a record that does not fit; none when it predates the record)."""
    w = old.header.get("workers")
    if w is None:
        return groups
    if _fits(w, n):
        return _groups(n, w)
    warnings.warn(
        f"optimise: the history at {str(path)!r} records workers = {w!r}, which does not "
        f"cut its {n} starts into equal groups: resuming with {len(groups)} groups, whose "
        "steps agree with the uninterrupted run's to the solver's tolerance, not bit for bit",
        RuntimeWarning,
        stacklevel=4,
    )
    return groups


def _fits(w, n: int) -> bool:
    """Whether `w` is a number of equal groups of `n` starts."""
    return isinstance(w, int) and not isinstance(w, bool) and 1 <= w <= n and n % w == 0


def _groups(n: int, workers: int | None) -> list[slice]:
    """`n` starts cut into equal groups, one per worker (one shape: one program):
    `workers` of them (refused unless it divides n), else as many as the largest divisor
    of n that is at most `jaxworm._threads.default_workers` of the default device."""
    if workers is None:
        most = default_workers(jax.local_devices()[:1])
        workers = max(w for w in range(1, min(most, n) + 1) if n % w == 0)
    elif not _fits(workers, n):
        raise ValueError(
            f"option workers = {workers!r}: need a divisor of the {n} starts (of this "
            "process), so that every group has one shape"
        )
    m = n // int(workers)
    return [slice(i * m, (i + 1) * m) for i in range(int(workers))]


def _descend(
    evaluate: Callable,
    lo,
    hi,
    theta0,
    maximise: bool,
    steps: int,
    optimiser,
    batch: str,
    header: dict,
    path=None,
    progress: bool = True,
    derivatives: str = "forward",
    box: str | AbstractBox = DEFAULT_BOX,
    overwrite: bool = False,
    workers: int | None = None,
) -> OptimiseResult:
    """The optimisation loop: `steps` batched steps from the points `theta0` (n, P).

    `evaluate(theta) -> (value, {"status", "n_cracks", "velocity"})` is traced under
    `jax.jacfwd` (or `jax.value_and_grad`, `derivatives="reverse"`) and batched over
    the starts by `_batched`; `header` must carry
    `names`, `maximise`, `objective` and `unit`. Saves to `path` after every step.
    """
    box = as_box(box)
    problem = _Problem(
        evaluate=evaluate,
        lo=jnp.asarray(lo, dtype=jnp.float64),
        hi=jnp.asarray(hi, dtype=jnp.float64),
        sign=-1.0 if maximise else 1.0,
        box=box,
    )
    n, P = theta0.shape
    index, n_processes = _distributed.process()
    if n < n_processes:
        raise ValueError(
            f"option starts: {n} starts for {n_processes} processes; give at least one "
            "start per process"
        )
    # This process's starts; each step's records of all starts reach every process.
    mine = _distributed.share_of(n, index, n_processes)
    groups = _groups(mine.stop - mine.start, workers)  # refused before the file is claimed
    width = -(-n // n_processes)
    shares = [_distributed.share_of(n, i, n_processes) for i in range(n_processes)]
    shape = (steps, n)
    rec = {
        "theta": np.full(shape + (P,), np.nan),
        "value": np.full(shape, np.nan),
        "grad": np.full(shape + (P,), np.nan),
        "status": np.full(shape, -1, dtype=np.int64),
        "n_cracks": np.full(shape, -1, dtype=np.int64),
        "velocity": np.full(shape, np.nan),
        "wall_time": np.full(steps, np.nan),
    }
    leader = _distributed.is_leader()
    _distributed.check_same_run("optimise", [header, theta0.tolist()])
    # A run of one process records its groups (batches of another size are other
    # programs, which round differently); processes on machines of other core counts may
    # differ in them, so several record none. A rerun given `workers` is another problem
    # unless they are the file's; one not given them takes the file's (`_resumed_groups`).
    alone = n_processes == 1
    compared = {**header, "workers": len(groups)} if alone and workers is not None else header
    z_all = box.from_box(jnp.asarray(theta0, dtype=jnp.float64), problem.lo, problem.hi)
    like = _initial_state(optimiser, z_all)  # every start's state, from scratch
    # The output is checked and locked before anything is computed (by process 0 alone).
    with contextlib.ExitStack() as stack:
        target, error, kept, state = None, None, 0, None
        if leader:
            try:
                target = stack.enter_context(_files.claim(path))
                old = previous_history(target, compared, overwrite)
                if old is not None and alone and workers is None:
                    groups = _resumed_groups(old, mine.stop - mine.start, groups, target)
                kept = 0 if old is None else old.steps_done
                state = resumable("optimise", old, header, like, target, stacklevel=3)
            except Exception as e:  # noqa: BLE001 - any, so no other process waits for it
                error = e
        _distributed.leader_verdict(error)
        if alone:
            header = {**header, "workers": len(groups)}
        first = int(_distributed.from_leader(np.asarray(0 if state is None else kept)))
        leaves = None
        if first:  # continue from the saved state, on every process
            if leader:
                assert old is not None  # a state was restored from it
                for key in rec:
                    rec[key][:first] = getattr(old, key)[:first]
                leaves = numpy_leaves(state)
            else:
                leaves = [np.zeros_like(a) for a in numpy_leaves(like)]
            # copies: the arrays of a broadcast may be read-only
            rec, leaves = jax.tree_util.tree_map(np.array, _distributed.from_leader((rec, leaves)))
            like = restore(leaves, like)[0]
        z, z_good, opt_state = jax.tree_util.tree_map(lambda a: a[mine], like)  # this share
        from tqdm import tqdm

        unit = header.get("unit", "")
        if first and progress and leader:
            sys.stderr.write(f"optimise: resuming, {first}/{steps} steps already done\n")
        bar = tqdm(
            total=steps,
            initial=first,
            desc=f"optimise {header.get('objective', '')}",
            unit="step",
            disable=not (progress and leader),
        )
        t0 = time.perf_counter() - (float(rec["wall_time"][first - 1]) if first else 0.0)
        res = OptimiseResult(header=header, steps_done=first, state=leaves, **rec)
        keys = ("theta", "value", "grad", "status", "n_cracks", "velocity")
        pool = stack.enter_context(ThreadPoolExecutor(len(groups), "jaxworm-optimise"))
        # A failed check inside a solve or its derivative (a linear solve given NaN, say)
        # gives NaN, which `_step` treats as a failed run, instead of an error.
        stack.enter_context(equinox_checks("nan"))
        for k in range(first, steps):
            theta = np.asarray(box.to_box(z, problem.lo, problem.hi))

            def step(sl, z=z, z_good=z_good, opt_state=opt_state):
                part = jax.tree_util.tree_map(lambda leaf: leaf[sl], opt_state)
                return _step(problem, optimiser, batch, derivatives, z[sl], z_good[sl], part)

            # The first group's first step alone: it compiles the program the others reuse.
            parts = [step(groups[0])] if k == first else []
            parts += list(pool.map(step, groups[len(parts) :]))
            z, z_good, opt_state, out = jax.tree_util.tree_map(
                lambda *a: jnp.concatenate(a), *parts
            )
            local = {"theta": theta, **{key: np.asarray(out[key]) for key in keys[1:]}}
            local = _every_start(local, shares, width)
            for key in keys:
                rec[key][k] = local[key]
            rec["wall_time"][k] = time.perf_counter() - t0
            # The state the next step starts from, of every start (for a rerun to resume).
            state = _every_start(numpy_leaves((z, z_good, opt_state)), shares, width)
            res = OptimiseResult(header=header, steps_done=k + 1, state=state, **rec)
            # A rerun leaves the history it replaces until it has as many steps.
            if target is not None and (k + 1 >= kept or k + 1 == steps):
                save_history(target, res)
            try:
                bar.set_postfix(best=f"{res.best_value:.6g} {unit}", refresh=False)
            except ValueError:
                bar.set_postfix(best="none ok", refresh=False)
            bar.update(1)
        bar.close()
        return res


def _initial_state(optimiser, z):
    """(z, the last good points, the optimiser state) before the first step: no point
    good yet (z itself)."""
    return z, z, jax.vmap(optimiser.init)(z)


def _every_start(tree, shares: list[slice], width: int):
    """`tree`'s arrays, whose leading axis is this process's starts, with every
    process's rows in start order, on every process (`shares`: the processes' starts,
    `width`: the most of them)."""
    if len(shares) == 1:
        return tree

    def pad(a):
        return np.concatenate([a, np.repeat(a[:1], width - a.shape[0], axis=0)])

    every = _distributed.gather(jax.tree_util.tree_map(pad, tree))
    return jax.tree_util.tree_map(
        lambda e: np.concatenate([e[i, : sl.stop - sl.start] for i, sl in enumerate(shares)]),
        every,
    )

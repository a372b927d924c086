"""Training a controller by gradient through the simulator, over samples of the scene.

`train` climbs (or descends) an objective of the simulation, averaged over samples of
the scene (`_samples`: soils, say), in the array leaves of a controller (any
`AbstractController` that is an `eqx.Module`: `PolicyMLP`, `ReflexWave`, a subclass of
one's own). Each step solves every sample in one vmapped batch with its gradient
(`value_and_grad`, the one `optimise` takes), then applies an optax update. The
history (every step's value per sample, statuses, trained arrays and wall time) is
saved after every step to `path` with the file mechanism of `optimise` (`_files`:
checked and locked before anything is computed, written atomically), so an interrupted
run loses nothing; `load_training` reads it back. A step whose solves do not all end ok
(or whose value or gradient is not finite) is recorded and not taken: training stops
there, saying which sample ended with which status.
"""

from __future__ import annotations

import contextlib
import dataclasses
import sys
import time
import warnings
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax
from jaxtyping import ArrayLike, Float

from . import _files
from ._control import AbstractController, check_horizon
from ._fingerprint import callable_fields, scene_fingerprint
from ._numerics import PRESETS, Numerics
from ._objectives import resolve_objective
from ._optimise import _Simulated, derivative_numerics, describe_optimiser, value_and_grad
from ._params import Params
from ._result import STATUS, Result, status_message
from ._resume import numpy_leaves, resumable, saved_state, state_arrays
from ._samples import check_samples, describe_samples
from ._solve import equinox_checks
from ._validation import check_instance, check_t1, check_ts, show

__all__ = ["train", "TrainResult", "load_training", "DEFAULT_LEARNING_RATE", "FORMAT"]

FORMAT = _files.FORMATS["train"]

#: The learning rate of `train`'s default optimiser, `optax.adam`.
DEFAULT_LEARNING_RATE = 0.02


# --- the trained arrays ------------------------------------------------------------------


def _trained_leaves(controller, trainable: Callable | None) -> list[int]:
    """Indices (in `jax.tree_util.tree_leaves` order) of the floating-point array leaves
    to train: those inside `trainable(controller)`'s subtrees, or by default all of
    them outside a `noise` field."""
    flat = jax.tree_util.tree_flatten_with_path(controller)[0]
    if trainable is None:
        chosen = [not (path and getattr(path[0], "name", None) == "noise") for path, _ in flat]
    else:
        mask = jax.tree_util.tree_map(lambda _: False, controller)
        try:
            mask = eqx.tree_at(
                trainable,
                mask,
                replace_fn=lambda sub: jax.tree_util.tree_map(lambda _: True, sub),
            )
        except Exception as e:  # noqa: BLE001 - tree_at's errors vary: name the option
            raise ValueError(
                f"option trainable = {show(trainable)}: need a function of the controller "
                f"returning its parts to train, as eqx.tree_at's `where` ({e})"
            ) from None
        chosen = [bool(m) for m in jax.tree_util.tree_leaves(mask)]
    return [
        i for i, ((_, leaf), c) in enumerate(zip(flat, chosen)) if c and eqx.is_inexact_array(leaf)
    ]


class _Trainee(eqx.Module):
    """The controller with its trained leaves given separately: `build(leaves)`."""

    controller: AbstractController
    indices: tuple = eqx.field(static=True)

    def leaves(self) -> tuple:
        every = jax.tree_util.tree_leaves(self.controller)
        return tuple(every[i] for i in self.indices)

    def build(self, trained) -> AbstractController:
        every, treedef = jax.tree_util.tree_flatten(self.controller)
        for i, leaf in zip(self.indices, trained):
            every[i] = leaf
        return jax.tree_util.tree_unflatten(treedef, every)

    def vector(self, trained) -> np.ndarray:
        return np.concatenate([np.ravel(np.asarray(a)) for a in trained])

    def from_vector(self, theta) -> AbstractController:
        out, at = [], 0
        for leaf in self.leaves():
            out.append(jnp.asarray(theta[at : at + leaf.size], leaf.dtype).reshape(leaf.shape))
            at += leaf.size
        return self.build(out)

    def describe(self) -> list[dict]:
        flat = jax.tree_util.tree_flatten_with_path(self.controller)[0]
        return [
            {"path": jax.tree_util.keystr(flat[i][0]), "shape": list(np.shape(flat[i][1]))}
            for i in self.indices
        ]


class _Loss(eqx.Module):
    """trained leaves ↦ (sign · mean objective, (mean, per-sample values, diagnostics))."""

    simulated: _Simulated
    trainee: _Trainee
    sign: float = eqx.field(static=True)

    def __call__(self, trained):
        values, aux = self.simulated.per_sample(self.trainee.build(trained))
        value = jnp.mean(values)
        return self.sign * value, (value, values, aux)


def _with_gait(base: Params, names: tuple, controller) -> Params:
    """The scene `base` driven by `controller` (`_Simulated`'s apply)."""
    del names
    return base.replace(gait=controller)


def _norm(tree) -> jax.Array:
    """The Euclidean norm of every array in `tree` together."""
    return jnp.sqrt(sum(jnp.sum(jnp.square(x)) for x in jax.tree.leaves(tree)))


@eqx.filter_jit
def _step(loss: _Loss, optimiser, derivatives: str, trained, opt_state):
    (_, (value, values, aux)), g = value_and_grad(loss, derivatives)(trained)
    updates, new_state = optimiser.update(g, opt_state, trained)
    return (
        optax.apply_updates(trained, updates),
        new_state,
        value,
        values,
        aux,
        _norm(g),
    )


# --- the history -------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class TrainResult:
    """The history of a training and its best controller.

    Arrays are indexed by step (and sample): `value` the mean objective over the samples
    of the controller the step started from (its own sense and unit: m/s for
    `"velocity"`); `sample_value`, `status` (codes of `STATUS`), `n_cracks` and
    `velocity` (mean velocity [m/s]) per sample; `grad_norm` the gradient's global
    norm; `theta` the trained arrays, flattened in the order of the header's `trained`;
    `wall_time` seconds since the start, after each step. `steps_done`: steps saved so
    far; `stopped`: why training stopped early ("" if it did not); `state`: the arrays
    the next step starts from (the trained arrays, the optimiser state's leaves), from
    which a rerun of the same training continues (None in a history written by an older
    jaxworm).

    `best_step`, `best_value`: the best step whose every sample ended ok;
    `best_controller`, `controller_at(step)`: the controller then (a result read by
    `load_training` needs the starting controller for that, `load_training(path, like)`).
    """

    value: np.ndarray
    sample_value: np.ndarray
    status: np.ndarray
    n_cracks: np.ndarray
    velocity: np.ndarray
    grad_norm: np.ndarray
    theta: np.ndarray
    wall_time: np.ndarray
    header: dict
    steps_done: int
    stopped: str = ""
    controller: AbstractController | None = None
    state: list[np.ndarray] | None = dataclasses.field(default=None, repr=False, compare=False)

    @property
    def maximise(self) -> bool:
        return bool(self.header["maximise"])

    @property
    def ok(self) -> np.ndarray:
        """Per step done: every sample ended ok, with a finite value."""
        n = self.steps_done
        return np.all(self.status[:n] == 0, axis=1) & np.isfinite(self.value[:n])

    @property
    def best_step(self) -> int:
        """The step of the best ok value; ValueError if there is none."""
        v = self.value[: self.steps_done]
        score = np.where(self.ok, v if self.maximise else -v, -np.inf)
        if score.size == 0 or not np.isfinite(score.max()):
            raise ValueError("no step ended with every sample ok: there is no best controller")
        return int(np.argmax(score))

    @property
    def best_value(self) -> float:
        return float(self.value[self.best_step])

    def controller_at(self, step: int) -> AbstractController:
        """The controller at the start of `step`."""
        if self.controller is None:
            raise ValueError(
                "this result has no starting controller to rebuild from: read it with "
                "load_training(path, like=<the controller training started from>)"
            )
        if not 0 <= step < self.steps_done:
            raise ValueError(f"step = {step!r}: need 0 <= step < {self.steps_done} (steps done)")
        trainee = _Trainee(self.controller, _indices(self.controller, self.header))
        return trainee.from_vector(self.theta[step])

    @property
    def best_controller(self) -> AbstractController:
        return self.controller_at(self.best_step)

    def summary(self) -> dict:
        """Plain-Python summary (JSON-able)."""
        out = {
            "objective": self.header["objective"],
            "unit": self.header["unit"],
            "maximise": self.maximise,
            "steps_done": self.steps_done,
            "samples": int(self.status.shape[1]),
            "parameters": int(self.theta.shape[1]),
            "stopped": self.stopped,
            "wall_time_s": float(self.wall_time[self.steps_done - 1]) if self.steps_done else 0.0,
            "values": [float(v) for v in self.value[: self.steps_done]],
        }
        try:
            out.update(best_step=self.best_step, best_value=self.best_value)
        except ValueError:
            out.update(best_step=None, best_value=None)
        return out


_HISTORY = (
    "value",
    "sample_value",
    "status",
    "n_cracks",
    "velocity",
    "grad_norm",
    "theta",
    "wall_time",
)


def _indices(controller, header: dict) -> tuple:
    """The leaf indices of `controller` that the header's `trained` arrays name, checked."""
    flat = jax.tree_util.tree_flatten_with_path(controller)[0]
    where = {jax.tree_util.keystr(p): (i, list(np.shape(leaf))) for i, (p, leaf) in enumerate(flat)}
    out = []
    for entry in header["trained"]:
        i, shape = where.get(entry["path"], (None, None))
        if i is None or shape != entry["shape"]:
            raise ValueError(
                f"controller {type(controller).__name__} has no array {entry['path']} of shape "
                f"{entry['shape']}: need the controller this training started from "
                f"(a {header['controller']})"
            )
        out.append(i)
    return tuple(out)


def _arrays_digest(controller) -> str:
    """SHA-256 of a controller's arrays (PRNG keys aside), by path: the header's
    `start_sha256` of the controller a training started from."""
    return _files.digest(
        {
            jax.tree_util.keystr(p): np.asarray(leaf)
            for p, leaf in jax.tree_util.tree_flatten_with_path(controller)[0]
            if eqx.is_array(leaf) and not jnp.issubdtype(leaf.dtype, jax.dtypes.prng_key)
        }
    )


def _save(path, res: TrainResult) -> None:
    _files.save(
        path,
        res.header,
        {
            "steps_done": np.asarray(res.steps_done),
            "stopped": np.asarray(res.stopped),
            **{k: getattr(res, k) for k in _HISTORY},
            **({} if res.state is None else state_arrays(res.state)),
        },
    )


def load_training(path, like: AbstractController | None = None) -> TrainResult:
    """Read a history written by `train(..., path=...)`; `like`, the controller the
    training started from (or one of its structure), lets the result rebuild its
    controllers (`best_controller`).

    Raises `ResultFileError` (a ValueError) naming the file and what is wrong with it
    when it is not a whole training history, and ValueError when `like` does not have
    the trained arrays."""
    header, arrays = _files.load(path, "train")
    try:
        for key in ("maximise", "objective", "unit", "trained", "controller"):
            header[key]
        steps_done = arrays["steps_done"]
        if steps_done.shape != () or steps_done.dtype.kind not in "iu":
            raise ValueError(f"its steps_done of shape {steps_done.shape}")
        hist = {k: arrays[k] for k in _HISTORY}
        steps, samples = hist["status"].shape if hist["status"].ndim == 2 else (-1, -1)
        if steps < 0 or not 0 <= int(steps_done) <= steps:
            raise ValueError(f"its statuses of shape {hist['status'].shape}")
        size = sum(int(np.prod(e["shape"])) for e in header["trained"])
        need = {"theta": (steps, size), "value": (steps,), "grad_norm": (steps,)}
        need["wall_time"] = (steps,)
        for k, a in hist.items():
            shape = need.get(k, (steps, samples))
            if a.shape != shape or a.dtype.kind not in "fiu":
                raise ValueError(f"its {k} of shape {a.shape}, dtype {a.dtype}; need {shape}")
        stopped = str(arrays["stopped"])
        state = saved_state(arrays)
    except KeyError as e:
        raise _files.damaged(path, f"it lacks {e.args[0]!r}") from None
    except ValueError as e:
        raise _files.damaged(path, str(e)) from None
    if like is not None:
        indices = _indices(like, header)
        start = _Trainee(like, indices).from_vector(hist["theta"][0]) if steps_done else like
        if steps_done and _arrays_digest(start) != header.get("start_sha256"):
            warnings.warn(
                f"load_training: like (a {type(like).__name__}) holds other values than the "
                f"controller {str(path)!r} started from in arrays it did not train: the "
                "controllers rebuilt from it (best_controller, controller_at) carry like's "
                "values there",
                RuntimeWarning,
                stacklevel=2,
            )
    return TrainResult(
        header=header,
        steps_done=int(steps_done),
        stopped=stopped,
        controller=like,
        state=state,
        **hist,
    )


# --- the driver --------------------------------------------------------------------------


def train(
    controller: AbstractController,
    objective: str | Callable[[Result], Float[ArrayLike, ""]] = "velocity",
    *,
    base: Params | None = None,
    samples: dict | None = None,
    t1: float = 10.0,
    steps: int = 25,
    optimiser: optax.GradientTransformation | None = None,
    numerics: Numerics = PRESETS["fast"],
    derivatives: str = "forward",
    crack_sensitivity: str | None = None,
    horizon: str | None = None,
    trainable: Callable | None = None,
    maximise: bool | None = None,
    ts=None,
    path=None,
    progress: bool = True,
    overwrite: bool = False,
) -> TrainResult:
    """Train the array leaves of `controller` by gradient through the simulator.

    Each step solves the scene `base` driven by the current controller on every sample
    (`samples`, as `optimise` takes them: e.g. `{"soil": [soil_1, soil_2]}`), as one
    vmapped batch with its gradient, and updates the trained arrays by `optimiser`
    along the mean objective's gradient.

    - `controller`: an `AbstractController` that is an `eqx.Module` (`PolicyMLP`,
      `ReflexWave`, one's own), its trained numbers floating-point array leaves.
    - `objective`: `"velocity"` (maximised), `"cost_of_transport"` (minimised) or a
      callable of the `Result` (minimised unless `maximise=True`), as `optimise`.
    - `base`: the scene (default Table 1); its gait is replaced by the controller.
    - `samples`: the scenes averaged over (`optimise`'s `samples`); None: `base` alone.
    - `t1` [s], `horizon` (default: `"whole_periods"` for a periodic controller and no
      `ts`, else `"t1"`), `ts`: as `optimise`.
    - `steps`: gradient steps (each one batch of value-and-gradient solves).
    - `optimiser`: an optax `GradientTransformation` on the trained arrays (default
      `optax.adam(DEFAULT_LEARNING_RATE)`); compose `optax.chain` for clipping or
      schedules.
    - `numerics`, `derivatives`, `crack_sensitivity`: as `optimise` (`fast`, forward
      sensitivities). The cost of forward sensitivities grows with the number of trained
      numbers: for a network take `derivatives="reverse"` with a diffrax solver,
      `Numerics(solver="Kvaerno3", atol=1e-10)` (`crack_sensitivity` then `"tips_held"`
      unless given). A controller that reads the crack (K_I/K_Ic or F_p, as
      `ReflexWave` and `PolicyMLP` do) needs `crack_sensitivity="exact"`: the held modes
      raise for it (`Numerics.crack_sensitivity`).
    - `trainable`: a function of the controller returning the parts to train (as
      `eqx.tree_at`'s `where`, e.g. `lambda p: (p.mlp, p.b)`); default: every
      floating-point array outside its `noise` field. Hold a rate bound (`A_max`,
      `A`) out of it when controllers are compared at one bound.
    - `path`: save the history there (`.npz`) after every step, as `optimise` does:
      checked and locked first, resumed from its last step if it is the history of the
      same training (same header; a finished one, or one that stopped, is returned as
      it is), recomputed with a `RuntimeWarning` if written by another jaxworm version
      or without a state (and replaced once the rerun has as many steps, or at its end
      or stop, so that a killed rerun leaves it whole), refused otherwise unless
      `overwrite=True`. The
      header identifies the scene trained in (`base` driven by `controller`, every leaf
      and static field: a SHA-256), and a callable objective by a SHA-256 of its code
      and the values it holds.

    A step whose solves do not all end ok, or whose value or gradient is not finite, is
    recorded and not taken: training stops there, and `stopped` (and a warning) says
    which sample ended with which status.

    ```python
    import jax, optax, jaxworm as jw
    soils = [jw.Soil(K_Ic=jw.Layered([x], [250.0, 500.0]), K_Ith=jw.Layered([x], [200.0, 400.0]))
             for x in (0.02, 0.05)]
    policy = jw.PolicyMLP.init(jax.random.key(0), 7, omega=4.0, delta=-0.2, b=3.0)
    res = jw.train(policy, samples={"soil": soils}, t1=4.0, steps=10,
                   optimiser=optax.adam(0.02), trainable=lambda p: (p.mlp, p.b),
                   numerics=jw.Numerics(solver="Kvaerno3", atol=1e-10),
                   derivatives="reverse", crack_sensitivity="exact", path="policy.npz")
    res.value                      # mean velocity over the soils, per step [m/s]
    better = res.best_controller   # a PolicyMLP
    jw.load_training("policy.npz", like=policy).best_controller   # the same, from the file
    ```
    """
    if not (isinstance(controller, AbstractController) and isinstance(controller, eqx.Module)):
        raise ValueError(
            f"controller = {show(controller)}: need an AbstractController that is an "
            "eqx.Module (PolicyMLP, ReflexWave, ...)"
        )
    base = Params() if base is None else base
    check_instance("base", base, Params, "jw.Params().replace(soil=...)")
    check_instance("numerics", numerics, Numerics, "jw.PRESETS['fast']")
    fn, mx, unit, obj_name = resolve_objective(objective, maximise)
    if not (isinstance(steps, (int, np.integer)) and not isinstance(steps, bool) and steps >= 1):
        raise ValueError(f"option steps = {steps!r} is out of range: need an integer >= 1")
    t1f = float(check_t1(t1))
    numerics = derivative_numerics(numerics, derivatives, crack_sensitivity)
    if horizon is None:
        horizon = "whole_periods" if controller.period() is not None and ts is None else "t1"
    check_horizon(horizon, controller, t1f)
    samples, n_samples = check_samples(samples, base)
    if trainable is not None and not callable(trainable):
        raise ValueError(
            f"option trainable = {show(trainable)}: need a function of the controller "
            "returning its parts to train"
        )
    trainee = _Trainee(controller, tuple(_trained_leaves(controller, trainable)))
    if not trainee.indices:
        raise ValueError(
            f"controller {type(controller).__name__}: nothing to train (no floating-point "
            "array among the parts chosen by trainable)"
        )
    if optimiser is None:
        optimiser, described = (
            optax.adam(DEFAULT_LEARNING_RATE),
            f"adam({DEFAULT_LEARNING_RATE:g})",
        )
    else:
        described = describe_optimiser(optimiser, int(steps))
    simulated = _Simulated(
        base=base,
        t1=jnp.asarray(t1f, dtype=jnp.float64),
        ts=check_ts(ts, t1f),
        names=(),
        numerics=numerics,
        fn=fn,
        apply=_with_gait,
        horizon=horizon,
        samples=samples,
    )
    loss = _Loss(simulated=simulated, trainee=trainee, sign=-1.0 if mx else 1.0)
    start = _arrays_digest(controller)
    header = _files.header(
        "train",
        objective=obj_name,
        **callable_fields("objective", objective),
        unit=unit,
        maximise=mx,
        controller=type(controller).__name__,
        trained=trainee.describe(),
        start_sha256=start,
        t1=t1f,
        horizon=horizon,
        steps=int(steps),
        samples=describe_samples(samples),
        derivatives=derivatives,
        optimiser=described,
        numerics=dataclasses.asdict(numerics),
        base_parameters=_files.plain(base.flat()),
        base_scene=scene_fingerprint(base.replace(gait=controller)),
        status_codes={str(k): v for k, v in STATUS.items()},
        **({} if ts is None else {"ts_sha256": _files.digest({"ts": np.asarray(simulated.ts)})}),
    )
    size = int(sum(np.size(a) for a in trainee.leaves()))
    rec = {
        "value": np.full(steps, np.nan),
        "sample_value": np.full((steps, n_samples), np.nan),
        "status": np.full((steps, n_samples), -1, dtype=np.int64),
        "n_cracks": np.full((steps, n_samples), -1, dtype=np.int64),
        "velocity": np.full((steps, n_samples), np.nan),
        "grad_norm": np.full(steps, np.nan),
        "theta": np.full((steps, size), np.nan),
        "wall_time": np.full(steps, np.nan),
    }
    with contextlib.ExitStack() as stack:
        target = stack.enter_context(_files.claim(path))
        old = _files.previous(
            target,
            overwrite,
            load_training,
            lambda old: _files.differences(
                old.header,
                header,
                sorted((set(old.header) | set(header)) - {"version", "integrity"}),
            ),
            "the history of another training",
        )
        kept = 0 if old is None else old.steps_done
        trained = trainee.leaves()
        opt_state = optimiser.init(trained)
        state = resumable("train", old, header, (trained, opt_state), target, stacklevel=2)
        first = 0
        if state is not None:
            assert old is not None  # a state was restored from it
            if old.stopped:  # the same step would be refused again
                warnings.warn(f"train: {old.stopped}", RuntimeWarning, stacklevel=2)
                return dataclasses.replace(old, controller=controller)
            first = old.steps_done
            for key in rec:
                rec[key][:first] = getattr(old, key)[:first]
            trained, opt_state = state
        from tqdm import tqdm

        if first and progress:
            sys.stderr.write(f"train: resuming, {first}/{steps} steps already done\n")
        bar = tqdm(
            total=steps, initial=first, desc=f"train {obj_name}", unit="step", disable=not progress
        )
        res = TrainResult(
            header=header,
            steps_done=first,
            controller=controller,
            state=None if state is None else numpy_leaves(state),
            **rec,
        )
        t0 = time.perf_counter() - (float(rec["wall_time"][first - 1]) if first else 0.0)
        # A failed check inside a solve or its derivative (a linear solve given NaN, say)
        # gives NaN, recorded as a non-finite value or gradient, instead of an error.
        stack.enter_context(equinox_checks("nan"))
        for k in range(first, steps):
            new, new_state, value, values, aux, gnorm = _step(
                loss, optimiser, derivatives, trained, opt_state
            )
            rec["theta"][k] = trainee.vector(trained)
            rec["value"][k] = float(value)
            rec["sample_value"][k] = np.asarray(values)
            rec["status"][k] = np.asarray(aux["status"])
            rec["n_cracks"][k] = np.asarray(aux["n_cracks"])
            rec["velocity"][k] = np.asarray(aux["velocity"])
            rec["grad_norm"][k] = float(gnorm)
            rec["wall_time"][k] = time.perf_counter() - t0
            stopped = _refusal(k, rec)
            if not stopped:
                trained, opt_state = new, new_state
            # The state the next step starts from (for a rerun to resume).
            leaves = numpy_leaves((trained, opt_state))
            res = TrainResult(
                header=header,
                steps_done=k + 1,
                stopped=stopped,
                controller=controller,
                state=leaves,
                **rec,
            )
            # A rerun leaves the history it replaces until it has as many steps.
            if target is not None and (k + 1 >= kept or k + 1 == steps or stopped):
                _save(target, res)
            bar.set_postfix(value=f"{rec['value'][k]:.6g} {unit}", refresh=False)
            bar.update(1)
            if stopped:
                warnings.warn(f"train: {stopped}", RuntimeWarning, stacklevel=2)
                break
        bar.close()
        return res


def _refusal(k: int, rec: dict) -> str:
    """Why step k may not be taken ("" if it may): the first sample not ok, or a value or
    gradient that is not finite."""
    bad = np.flatnonzero(rec["status"][k] != 0)
    if bad.size:
        i = int(bad[0])
        return (
            f"step {k}: sample {i} ended {status_message(rec['status'][k, i])} "
            f"({bad.size} of {rec['status'].shape[1]} samples not ok); the step is not taken"
        )
    if not np.isfinite(rec["value"][k]):
        return f"step {k}: the value is {rec['value'][k]}; the step is not taken"
    if not np.isfinite(rec["grad_norm"][k]):
        return f"step {k}: the gradient is not finite; the step is not taken"
    return ""

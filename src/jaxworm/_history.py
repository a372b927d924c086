"""The history of an optimisation: every step's points, values and gradients, and its file.

`optimise` saves an `OptimiseResult` after every step (`save_history`, atomically, with
the header of `_files`), so an interrupted run loses nothing; `load_optimisation` reads
it back, checked.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from . import _files
from ._fingerprint import scene_fingerprint
from ._params import Params
from ._resume import saved_state, state_arrays

__all__ = ["OptimiseResult", "load_optimisation", "save_history", "previous_history", "FORMAT"]

FORMAT = _files.FORMATS["optimise"]


@dataclasses.dataclass(frozen=True)
class OptimiseResult:
    """The history of an optimisation and its best point.

    Arrays are indexed (step, start[, parameter]), parameters in the order of `names`:

    - `theta`: the evaluated points, in the parameters' units; `value`: the objective
      there (its own sense and unit: m/s for `"velocity"`, J/m for
      `"cost_of_transport"`); `grad`: d(objective)/dθ (NaN where the run failed, and
      along a parameter at a bound of the box, which has no slope there); `status`
      (codes of `STATUS`), `n_cracks`, `velocity` (mean velocity [m/s]); `accepted`:
      the evaluations the optimiser took a step from.
    - `wall_time`: seconds since the start, after each step.
    - `header`: bounds, objective (and, for a callable, a SHA-256 of its code), t1, base
      parameters, base scene (its parts' classes and a SHA-256 of the whole `Params`),
      numerics, optimiser, seed, version.
    - `steps_done`: steps saved so far (an interrupted run keeps what it had).
    - `state`: the arrays the next step starts from (the points z, the last good points,
      the optimiser state's leaves, of every start), from which a rerun of the same
      problem continues; None in a history written by an older jaxworm.

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
    state: list[np.ndarray] | None = dataclasses.field(default=None, repr=False, compare=False)

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
            raise ValueError(
                "no evaluation ended with status ok and a finite value: there is no best point"
            )
        step, start = np.unravel_index(int(np.argmax(s)), s.shape)
        return int(step), int(start)

    @property
    def accepted(self) -> np.ndarray:
        """(step, start): the evaluations the optimiser took, those whose run ended ok
        with a finite value and a finite gradient (along a parameter at its bound the
        box has no slope, and the gradient there is NaN). A start whose evaluation was
        not accepted took no optimiser step: it went back towards its last good point."""
        n = self.steps_done
        theta, grad = self.theta[:n], self.grad[:n]
        lo, hi = (np.array([b[i] for b in self.bounds.values()]) for i in (0, 1))
        at_bound = (theta <= lo) | (theta >= hi)
        finite_grad = np.all(np.isfinite(grad) | at_bound, axis=-1)
        return (self.status[:n] == 0) & np.isfinite(self.value[:n]) & finite_grad

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
        by the `apply(base, names, theta)` the optimisation used. ValueError when `base`
        is not the scene the optimisation ran on (the header's `base_scene`): θ applied
        to another scene is not the optimum found (`base.replace(**best_theta)` does
        that on purpose)."""
        given = base is not None
        base = Params() if base is None else base
        recorded = self.header.get("base_scene", {}).get("sha256")
        if recorded is not None and scene_fingerprint(base)["sha256"] != recorded:
            raise ValueError(
                "best_params: "
                + ("base is not" if given else "this optimisation did not run on Table 1 but")
                + " the scene the optimisation ran on (its header's base_scene): pass "
                "base=<the Params given to optimise>"
            )
        if apply is not None:
            return apply(base, tuple(self.names), jnp.asarray(list(self.best_theta.values())))
        return base.replace(**self.best_theta)

    def summary(self) -> dict:
        """Plain-Python summary (JSON-able)."""
        out = {
            "objective": self.header["objective"],
            "unit": self.header["unit"],
            "maximise": self.maximise,
            "steps_done": self.steps_done,
            "starts": int(self.value.shape[1]),
            "evaluations": self.n_evaluations,
            "wall_time_s": float(self.wall_time[self.steps_done - 1]) if self.steps_done else 0.0,
        }
        try:
            step, start = self.best_index
            out.update(
                best_value=self.best_value,
                best_theta=self.best_theta,
                best_step=step,
                best_start=start,
                best_velocity=float(self.velocity[step, start]),
                best_n_cracks=int(self.n_cracks[step, start]),
            )
        except ValueError:
            out.update(best_value=None, best_theta=None)
        return out


_HISTORY = ("theta", "value", "grad", "status", "n_cracks", "velocity", "wall_time")


def save_history(path: Path, res: OptimiseResult) -> None:
    """Write `res` to `path` (atomically; `load_optimisation` reads it)."""
    _files.save(
        path,
        res.header,
        {
            "steps_done": np.asarray(res.steps_done),
            **{k: getattr(res, k) for k in _HISTORY},
            **({} if res.state is None else state_arrays(res.state)),
        },
    )


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
            raise ValueError(
                f"its steps_done of shape {steps_done.shape}, dtype {steps_done.dtype}"
            )
        hist = {k: arrays[k] for k in _HISTORY}
        steps, starts = hist["value"].shape if hist["value"].ndim == 2 else (-1, -1)
        if steps < 0 or not 0 <= int(steps_done) <= steps:
            raise ValueError(
                f"its values of shape {hist['value'].shape} and {int(steps_done)} steps done"
            )
        need = {
            "theta": (steps, starts, len(names)),
            "grad": (steps, starts, len(names)),
            "wall_time": (steps,),
        }
        for k, a in hist.items():
            shape = need.get(k, (steps, starts))
            if a.shape != shape or a.dtype.kind not in "fiu":
                raise ValueError(f"its {k} of shape {a.shape}, dtype {a.dtype}; need {shape}")
        state = saved_state(arrays)
    except KeyError as e:
        raise _files.damaged(path, f"it lacks {e.args[0]!r}") from None
    except ValueError as e:
        raise _files.damaged(path, str(e)) from None
    return OptimiseResult(header=header, steps_done=int(steps_done), state=state, **hist)


def _same_problem(old: dict, new: dict) -> list[str]:
    """The header keys in which two optimisation headers differ, the version aside (and
    `workers` where either has no record of it: a history written before it was
    recorded, a run of several processes, or a rerun not given `workers`, which takes
    the file's)."""
    keys = (set(old) | set(new)) - {"version", "integrity"}
    if "workers" not in old or "workers" not in new:
        keys -= {"workers"}
    return _files.differences(old, new, sorted(keys))


def previous_history(path: Path | None, header: dict, overwrite: bool) -> OptimiseResult | None:
    """The history at `path` that this optimisation (`header`) resumes or replaces, or
    None; ResultFileError unless `path` may receive it: absent, the history of the same
    problem (which a rerun continues), or `overwrite`."""
    return _files.previous(
        path,
        overwrite,
        load_optimisation,
        lambda old: _same_problem(old.header, header),
        "the history of another optimisation",
    )

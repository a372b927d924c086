"""Sweeps: a grid of scenes, vmapped in chunks, each finished chunk saved at once.

A sweep keeps one summary per scene (mean velocity, crack count, status, ...), never
trajectories. Results go to a self-describing `.npz` file: the grid's coordinates, the
summary arrays shaped like the grid, a per-scene `done` mask, and a JSON header with
units, the base parameters (and a SHA-256 of the whole base scene), t1, the numerics,
model conventions and the package version. Running the same sweep again with the same
file (and the same package version) resumes where it stopped: only the chunks not yet
done are solved.

```python
import numpy as np, jaxworm as jw
grid = {"omega": np.linspace(3 * np.pi, 5 * np.pi, 21),
        "delta": np.linspace(np.pi / 6, np.pi / 3, 21)}
s = jw.sweep(grid, t1=60.0, path="fig3.npz")      # interrupt it and run again: it resumes
s.mean_velocity.shape                              # (21, 21), axes in the grid's order
jw.load_sweep("fig3.npz")                          # the same SweepResult, from the file
```
"""

from __future__ import annotations

import contextlib
import dataclasses
import itertools
import queue
import sys
import threading
import time
from collections.abc import Iterator, Mapping
from concurrent.futures import ThreadPoolExecutor, as_completed, wait
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from . import _distributed, _files
from ._cache import configure_compilation_cache, exported_call
from ._control import check_horizon
from ._files import ResultFileError
from ._fingerprint import scene_fingerprint
from ._numerics import PRESETS, Numerics
from ._params import FLAT_NAMES, MODEL_OPTIONS, PARAMETER_INFO, Params, ascii_unit
from ._result import STATUS
from ._solve import simulate_steps
from ._threads import MAX_WORKERS, default_workers
from ._validation import check_instance, check_int, check_t1

__all__ = [
    "sweep",
    "load_sweep",
    "SweepResult",
    "SWEEP_FIELDS",
    "ResultFileError",
    "default_chunk",
    "CHUNK_SECONDS",
    "CHUNK_COST",
    "MAX_SCENES",
]

#: What a sweep keeps per scene, with units.
SWEEP_FIELDS = {
    "mean_velocity": "m/s",
    "n_cracks": "-",
    "status": "code (see STATUS)",
    "steps": "-",
    "final_head": "m",
    "final_crack_tip": "m",
    "energy_residual": "-",
}

#: Units of the parameters, as the file header writes them (`PARAMETER_INFO`, in ASCII).
UNITS = {name: ascii_unit(info.unit) for name, info in PARAMETER_INFO.items()}


#: Most scenes in one sweep: its arrays (the `SWEEP_FIELDS`, the done mask, the table of
#: every scene's values), allocated before any solve, take a few hundred bytes a scene.
MAX_SCENES = 10**6


def _check_size(grid: Mapping[str, np.ndarray]) -> None:
    """`ValueError` naming the grid, its size and `MAX_SCENES` when the grid (its axes
    checked) holds more scenes than that."""
    total = 1
    for values in grid.values():
        total *= len(values)
    if total > MAX_SCENES:
        sizes = " x ".join(f"{name} {len(values)}" for name, values in grid.items())
        raise ValueError(
            f"grid ({sizes}) has {total} scenes, more than the limit of {MAX_SCENES} "
            "scenes in one sweep: give fewer values, or split it into several sweeps"
        )


def _check_grid(grid: dict, base: Params | None = None) -> dict[str, np.ndarray]:
    """The grid as float64 axes; `ValueError` naming the axis for an unknown name, a
    value that is not a finite number, a repeated value (identical scenes), or a value
    that `base.replace` refuses (the parameter's own range); `ValueError` for a grid of
    more than `MAX_SCENES` scenes (`_check_size`), before anything is allocated for them."""
    if not grid:
        raise ValueError("grid is empty: give at least one parameter and its values")
    out = {}
    for name, values in grid.items():
        if name == "N":
            raise ValueError(
                "grid parameter N cannot be swept: it sets array shapes (run one sweep per N)"
            )
        if name not in FLAT_NAMES:
            raise ValueError(
                f"grid parameter {name!r} is unknown: need one of "
                f"{', '.join(n for n in FLAT_NAMES if n != 'N')}"
            )
        try:
            raw = np.atleast_1d(np.asarray(values))
            # Booleans are not numbers here (Params.replace refuses them too).
            arr = None if raw.dtype.kind in "bOUS" else raw.astype(np.float64)
        except (TypeError, ValueError, OverflowError):
            arr = None
        if arr is None or arr.ndim != 1 or arr.size == 0 or not np.all(np.isfinite(arr)):
            raise ValueError(
                f"grid parameter {name} = {values!r}: need a non-empty 1-D list of finite numbers"
            )
        if np.unique(arr).size != arr.size:
            raise ValueError(
                f"grid parameter {name} repeats a value ({arr.size} values, "
                f"{np.unique(arr).size} distinct): the scenes would be identical"
            )
        out[name] = arr
    _check_size(out)
    if base is not None:
        for name, arr in out.items():
            for v in arr:
                try:
                    base.replace(**{name: float(v)})
                except (TypeError, ValueError) as e:
                    raise ValueError(f"grid parameter {name}: {e}") from None
    return out


def _header(grid, base: Params, t1, numerics: Numerics, horizon: str = "t1") -> dict:
    return _files.header(
        "sweep",
        **{
            "axes": list(grid),
            "units": {**{n: UNITS.get(n, "-") for n in grid}, **SWEEP_FIELDS, "t1": "s"},
            "t1": float(t1),
            "horizon": horizon,
            "base_parameters": _files.plain(base.flat()),
            "base_scene": scene_fingerprint(base),
            "model_options": base.options(),
            "numerics": dataclasses.asdict(numerics),
            "status_codes": {str(k): v for k, v in STATUS.items()},
            "conventions": "docs/MODEL.md: nodes head first, one gait input per segment, rest "
            "start, x_c(0) by eq. 13, mean velocity of the node mean",
        },
    )


#: What makes a sweep file another run's. The package version and the model conventions
#: are among them: a resumed sweep's scenes all come from one version.
_RUN_KEYS = (
    "version",
    "conventions",
    "axes",
    "t1",
    "horizon",
    "base_parameters",
    "base_scene",
    "model_options",
    "numerics",
)


def _differences(old: dict, new: dict, old_coords: dict, grid: dict) -> list[str]:
    """What makes the sweep in a file (`old` header and coordinates) another run than
    `new`: the header keys of the run, then the grid's values; [] for the same run."""
    # files written before `horizon` existed simulated [0, t1]
    old, new = ({"horizon": "t1", **h} for h in (old, new))
    # files written before a model option existed ran its default (or lacked it)
    if isinstance(old.get("model_options"), dict):
        defaults = {n: (None, info.choices[0]) for n, info in MODEL_OPTIONS.items()}
        missing = {
            n: v
            for n, v in new.get("model_options", {}).items()
            if n not in old["model_options"] and v in defaults.get(n, ())
        }
        old = {**old, "model_options": {**old["model_options"], **missing}}
    diff = _files.differences(old, new, _RUN_KEYS)
    if "axes" not in diff and any(not np.array_equal(old_coords[n], grid[n]) for n in grid):
        diff.append("grid values")
    return diff


def _save(path: Path, header, grid, results, done):
    _files.save(
        path,
        header,
        {
            "done": done,
            **{f"coord_{n}": v for n, v in grid.items()},
            **{f"result_{n}": v for n, v in results.items()},
        },
    )


@dataclasses.dataclass(frozen=True, eq=False)
class SweepResult(Mapping):
    """The results of a sweep (`sweep`, `load_sweep`), one array per field of
    `SWEEP_FIELDS`, each shaped like the grid (axes in the grid's order).

    - `header`: axes, units, t1, horizon, base parameters, base scene (its parts'
      classes and a SHA-256 of the whole `Params`), model options, numerics, status
      codes, chunk, version.
    - `coords`: {axis name: its values}; `done`: which scenes are solved (a sweep
      interrupted and read from its file has some not done: NaN there).
    - `mean_velocity` [m/s], `n_cracks`, `status` (codes of `STATUS`), `steps`,
      `final_head` [m], `final_crack_tip` [m], `energy_residual`: per scene.

    It is also a read-only mapping of these names (`result["mean_velocity"]`,
    `result["header"]`, `.keys()`, `.items()`, `in`, `dict(result)`).
    """

    header: dict
    done: np.ndarray
    coords: dict
    mean_velocity: np.ndarray
    n_cracks: np.ndarray
    status: np.ndarray
    steps: np.ndarray
    final_head: np.ndarray
    final_crack_tip: np.ndarray
    energy_residual: np.ndarray

    @property
    def axes(self) -> list[str]:
        """The grid's parameter names, in the order of the arrays' axes."""
        return list(self.header["axes"])

    @property
    def shape(self) -> tuple[int, ...]:
        return self.done.shape

    def __getitem__(self, key: str):
        if key not in _KEYS:
            raise KeyError(key)
        return getattr(self, key)

    def __iter__(self) -> Iterator[str]:
        return iter(_KEYS)

    def __len__(self) -> int:
        return len(_KEYS)


_KEYS = tuple(f.name for f in dataclasses.fields(SweepResult))


def load_sweep(path) -> SweepResult:
    """Read a sweep file as the `SweepResult` that `sweep` returned.

    Raises `ResultFileError` (a ValueError) naming the file and what is wrong with it
    when it is not a whole sweep file (damaged, truncated, empty, another kind of file).
    """
    header, arrays = _files.load(path, "sweep")
    try:
        axes = header["axes"]
        if (
            not isinstance(axes, list)
            or not axes
            or len(set(axes)) != len(axes)
            or not all(isinstance(a, str) for a in axes)
        ):
            raise ValueError(f"its axes {axes!r} are not a list of parameter names")
        if not isinstance(header.get("t1"), (int, float)):
            raise ValueError("its header has no t1")
        coords = {n: arrays[f"coord_{n}"] for n in axes}
        for n, c in coords.items():
            if c.ndim != 1 or c.size == 0 or c.dtype.kind != "f":
                raise ValueError(f"coordinate {n} of shape {c.shape}, dtype {c.dtype}")
        shape = tuple(c.size for c in coords.values())
        done = arrays["done"]
        if done.shape != shape or done.dtype != bool:
            raise ValueError(
                f"its done mask of shape {done.shape}, dtype {done.dtype}: need shape "
                f"{shape}, dtype bool"
            )
        fields = {}
        for n in SWEEP_FIELDS:
            fields[n] = arrays[f"result_{n}"]
            if fields[n].shape != shape or fields[n].dtype.kind not in "fiu":
                raise ValueError(
                    f"its {n} of shape {fields[n].shape}, dtype {fields[n].dtype}; need {shape}"
                )
    except KeyError as e:
        raise _files.damaged(path, f"it lacks {e.args[0]!r}") from None
    except ValueError as e:
        raise _files.damaged(path, str(e)) from None
    return SweepResult(header=header, done=done, coords=coords, **fields)


def _existing(path: Path | None, header: dict, grid: dict, overwrite: bool) -> SweepResult | None:
    """The sweep already at `path` to resume, or None; ResultFileError (naming the path
    and what to do) for a file that is not this run's, unless `overwrite`."""
    return _files.previous(
        path,
        overwrite,
        load_sweep,
        lambda old: _differences(old.header, header, old.coords, grid),
        "a different sweep",
    )


def check_output(
    path, grid: dict, base: Params, t1, numerics: Numerics, overwrite: bool, horizon: str = "t1"
) -> None:
    """The checks `sweep(grid, base, t1, numerics, path=path, overwrite=overwrite,
    horizon=horizon)` makes of its output before solving (the grid, the path, its lock,
    a file there that is not this sweep), for a caller that must know before it computes
    anything else; ValueError or OSError naming the problem."""
    checked = _check_grid(grid, base)
    header = _header(checked, base, float(t1), numerics, horizon)
    with _files.claim(path) as target:
        _existing(target, header, checked, overwrite)


CHUNK_SECONDS = 8.0
"""Target compute of one default chunk on one core [s] (`default_chunk`): a killed sweep
loses at most the chunks in flight, one per worker, so at most ~10 s of work each; 8 s
leaves room for gaits costlier than those measured and a slower machine."""

CHUNK_COST = {"fast": (0.0076, 0.0035), "default": (0.0057, 0.062), "accurate": (1.04, 0.82)}
"""The cost model of a chunk of c scenes over t1 seconds, T ≈ t1 (a + b c) [CPU s on one
core], per preset name: (a, b), a [s per simulated s] the per-step work the lanes of a
`vmap` share, b [s per simulated s per lane] each lane's own. `default_chunk` reads it;
numerics that are not a preset get the costliest model. Fitted by
`benchmarks/sweep_chunks.py` on a 2-core AMD EPYC (chunks of 1, 8 and 32 gaits of the
Fig. 3 grid, ω = 5π first, over 20 s with `fast`, 5 s with `default`, 1 s with
`accurate`)."""


def default_chunk(total: int, n_workers: int, t1: float, numerics: Numerics) -> int:
    """Scenes per chunk of a sweep of `total` scenes over `t1` [s] by `n_workers` (the
    workers of every device of every process), as `sweep` cuts them unless told: the
    most that keep a chunk within `CHUNK_SECONDS` by `CHUNK_COST` (at least 1, at most
    64), then as few rounds of one chunk per worker as that allows, the scenes split
    evenly between them (no lane padded for nothing). A function of the sweep alone, so
    a resumed sweep cuts the same chunks.

    ```python
    import jaxworm as jw
    jw.default_chunk(21 * 21, 2, 60.0, jw.PRESETS["fast"])   # the Fig. 3 sweep on 2 cores
    ```
    """
    costs = [c for name, c in CHUNK_COST.items() if PRESETS.get(name) == numerics]
    a, b = costs[0] if costs else max(CHUNK_COST.values(), key=lambda ab: ab[0] + 8 * ab[1])
    most = int(np.clip(np.floor((CHUNK_SECONDS / t1 - a) / b), 1, 64))
    rounds = -(-max(total, 1) // (most * n_workers))
    return -(-max(total, 1) // (rounds * n_workers))


def _solve_chunk(base: Params, names, values, t1, numerics, horizon="t1"):
    if numerics.linear_solve == "structured":  # the same solve, written for lanes
        numerics = numerics.replace(linear_solve="structured_lanes")

    def one(vals):
        p = base.replace(**dict(zip(names, vals)))
        # Each lane its own loop of steps: no lane waits at another's cracks.
        r = simulate_steps(p, t1, numerics, horizon=horizon)
        return {
            "mean_velocity": r.mean_velocity,
            "n_cracks": r.n_cracks,
            "status": r.status,
            "steps": r.steps,
            "final_head": r.final.x[0],
            "final_crack_tip": r.x_c,
            "energy_residual": r.energy_residual,
        }

    return jax.vmap(one)(values)


# `jax.jit`, not `eqx.filter_jit`: the latter waits for its result, and the first dispatch
# of each device holds a lock (`_solve_chunks`) that should cover the compilation alone.
_traced_chunk = jax.jit(_solve_chunk, static_argnums=(1, 4, 5))


def _run_chunk(base: Params, names, values, t1, numerics, horizon="t1"):
    """One chunk's results (dispatched, not waited for): through the program exported by
    an earlier process when there is one (`jaxworm._cache`), else traced. `t1` is an
    input of the program (one program for every horizon), not a constant in it."""
    t1 = jnp.asarray(t1, jnp.float64)
    skeleton = dict.fromkeys(SWEEP_FIELDS, 0)
    out = exported_call(
        _solve_chunk, "sweep_chunk", (base, names, values, t1, numerics, horizon), skeleton
    )
    return _traced_chunk(base, names, values, t1, numerics, horizon) if out is None else out


class _Progress:
    """One line on stderr: scenes done, rate, time left."""

    def __init__(self, total, done, enabled):
        self.total, self.start_done, self.enabled = total, done, enabled
        self.t0 = time.perf_counter()
        if enabled and done:
            sys.stderr.write(f"sweep: resuming, {done}/{total} scenes already done\n")

    def update(self, done):
        if not self.enabled:
            return
        dt = time.perf_counter() - self.t0
        new = done - self.start_done
        rate = new / dt if dt > 0 else 0.0
        left = (self.total - done) / rate if rate > 0 else float("nan")
        sys.stderr.write(f"\rsweep: {done}/{self.total} scenes, {rate:.2f}/s, {left:.0f} s left   ")
        sys.stderr.flush()
        if done == self.total:
            sys.stderr.write("\n")


def sweep(
    grid: dict,
    base: Params | None = None,
    t1=60.0,
    numerics: Numerics = PRESETS["fast"],
    chunk: int | None = None,
    path=None,
    progress: bool = True,
    devices=None,
    horizon: str = "t1",
    overwrite: bool = False,
    workers: int | None = None,
) -> SweepResult:
    """Solve every scene of the Cartesian grid `grid` ({flat name: values}) from `base`.

    The grid's scenes, in order, are cut into chunks of `chunk` scenes (at most the
    grid's), each solved under one `vmap`. `workers` chunks run at once on each of
    `devices` (default `jax.local_devices()`), each from its own thread, one compiled
    program for all of them; a worker takes the next chunk as soon as its last one is
    done. `workers` defaults to the cores this process may use shared among the CPU
    devices (one XLA CPU solve runs on one core), and to 1 on an accelerator. `chunk`
    defaults to `default_chunk`: as many scenes as keep a chunk within ~`CHUNK_SECONDS`
    of compute (at most 64), split evenly over rounds of one chunk per worker; a resumed
    sweep keeps its file's chunks.

    With `path`, the output is checked before anything is computed (its folder exists
    and is writable, it is not a folder, no other process writes it: a lock) and every
    finished chunk is saved at once, atomically, so a killed sweep loses at most the
    chunks in flight (one per worker). A rerun with the same file, grid, t1, horizon,
    scene (the whole `base`, by a SHA-256 of its values and structure), numerics and
    package version resumes: only the chunks not yet done are solved, cut as before, so
    the result is bit-identical to an uninterrupted run. A file that holds anything else (a
    different sweep, another kind of file, a damaged one) is refused with a
    `ResultFileError`, never overwritten, unless `overwrite=True` (then the sweep
    starts afresh and replaces it). Returns a `SweepResult` (as `load_sweep` reads it).

    `numerics` defaults to the `fast` preset. `horizon`: `"t1"` simulates [0, t1];
    `"whole_periods"` up to the last whole gait period in it (`simulate`'s `horizon`),
    as `jaxworm.optimise(horizon=...)`; t1 must hold one period of the grid's slowest
    gait (`ValueError` otherwise).

    On a CPU, JAX shows one device however many cores there are, and one solve uses
    one core: the default workers put every core to work on that one device.

    **Several processes.** Started under `jax.distributed.initialize()` (several hosts,
    or several processes on one), every process calls `sweep` with the same arguments;
    each solves its share of every round of chunks on its own devices, and all of them
    return the whole result. Process 0 alone reads and writes `path` (on its file
    system) and shows progress. The chunks are those of one process with as many
    workers in all, so the results are bit-identical to that run's; after a process is
    killed, rerun them all and the sweep resumes from the file.

    The workers are threads: JAX's context managers (`jax.debug_nans`,
    `jax.log_compiles`, ...) entered by the caller do not reach them; set such options
    with `jax.config.update`.
    """
    base = Params() if base is None else base
    check_instance("base", base, Params, "jw.Params().replace(omega=...)")
    check_instance("numerics", numerics, Numerics, "jw.PRESETS['fast']")
    grid = _check_grid(grid, base)
    if chunk is not None:
        check_int("chunk", chunk, 1, None, kind="option")
        chunk = int(chunk)
    t1 = float(check_t1(t1))
    omega = grid.get("omega")  # t1 must hold the longest period on the grid
    check_horizon(horizon, base.gait, t1, None if omega is None else 2 * np.pi / np.min(omega))
    if workers is not None:
        check_int("workers", workers, 1, MAX_WORKERS, kind="option")
    header = _header(grid, base, t1, numerics, horizon)
    shape = tuple(v.size for v in grid.values())
    total = int(np.prod(shape))
    devices = jax.local_devices() if devices is None else list(devices)
    _check_devices(devices)
    per_device = default_workers(devices) if workers is None else int(workers)
    slots = [d for d in devices for _ in range(per_device)]
    configure_compilation_cache()
    leader = _distributed.is_leader()
    _distributed.check_same_run("sweep", [header, {n: v.tolist() for n, v in grid.items()}, chunk])
    with contextlib.ExitStack() as stack:
        # The leader alone claims, reads and writes the file; the others learn from it
        # what is done already, or why the run is refused.
        results = {n: np.full(total, np.nan) for n in SWEEP_FIELDS}
        done = np.zeros(total, dtype=bool)
        target, old, error = None, None, None
        if leader:
            try:
                target = stack.enter_context(_files.claim(path))
                old = _existing(target, header, grid, overwrite)
            except (ValueError, OSError) as e:
                error = e
        _distributed.leader_verdict(error)
        if old is not None:
            done = old.done.ravel().copy()
            for n in SWEEP_FIELDS:
                results[n] = old[n].ravel().astype(np.float64).copy()
            if chunk is None and isinstance(old.header.get("chunk"), int):
                chunk = max(1, old.header["chunk"])
        resumed = np.array([chunk or 0], np.int64)
        done, resumed, stacked = _distributed.from_leader(
            (done, resumed, np.stack([results[n] for n in SWEEP_FIELDS]))
        )
        results = {n: stacked[i].copy() for i, n in enumerate(SWEEP_FIELDS)}
        done = done.copy()
        chunk = int(resumed[0]) or None
        # Every process's worker count: the chunks of a round, one per worker.
        counts = _distributed.gather(np.array(len(slots), np.int64))
        if chunk is None:
            chunk = default_chunk(total, int(counts.sum()), t1, numerics)
        # Every chunk is padded to this size (one program): never beyond the grid.
        chunk = min(chunk, total)
        header["chunk"] = chunk
        _solve_chunks(
            grid,
            base,
            t1,
            numerics,
            horizon,
            chunk,
            slots,
            counts,
            results,
            done,
            lambda: (
                _save(
                    target,
                    header,
                    grid,
                    {n: v.reshape(shape) for n, v in results.items()},
                    done.reshape(shape),
                )
                if target is not None
                else None
            ),
            _Progress(total, int(done.sum()), progress and leader),
        )
    return SweepResult(
        header=header,
        done=done.reshape(shape),
        coords=grid,
        **{n: v.reshape(shape) for n, v in results.items()},
    )


def _check_devices(devices) -> None:
    """`ValueError` for no device, or a device of another process (`jax.distributed`)."""
    if not devices:
        raise ValueError("option devices is empty: need at least one device")
    foreign = [d for d in devices if d.process_index != jax.process_index()]
    if foreign:
        raise ValueError(
            f"option devices: {foreign[0]} belongs to process {foreign[0].process_index}; "
            "each process computes on its own devices (jax.local_devices())"
        )


def _solve_chunks(
    grid, base, t1, numerics, horizon, chunk, slots, counts, results, done, save, bar
) -> None:
    """Solve the chunks of the grid (scenes [k chunk, (k + 1) chunk)) that are not done,
    filling `results` and `done` (flat) and calling `save()` as chunks finish.

    `slots`: a device per worker (a device appears once per worker on it). Each worker
    is a thread that dispatches a chunk to its device and waits for it; the first
    dispatch of each device is made by one thread alone, so the program is traced and
    compiled once and the others reuse it. With one process a worker takes the next
    chunk as soon as it is free. With several, the chunks go in rounds of one per
    worker of every process (`counts`, workers per process, in process order); a
    process solves its share of each round, and every round's results then reach every
    process (`jaxworm._distributed.gather`) before the leader saves them."""
    points = np.array(list(itertools.product(*grid.values())))  # (total, n_axes)
    names = tuple(grid)
    cuts = [np.arange(i, min(i + chunk, done.size)) for i in range(0, done.size, chunk)]
    todo = [idx[~done[idx]] for idx in cuts if not done[idx].all()]
    index, n_processes = _distributed.process()
    offsets = np.concatenate([[0], np.cumsum(counts)])
    per_round = int(offsets[-1])
    free: queue.SimpleQueue = queue.SimpleQueue()
    for device in slots:
        free.put(device)
    first_dispatch = threading.Lock()
    compiled: set = set()

    def solve(idx):
        """One chunk on a free worker's device: (its scenes, their values)."""
        device = free.get()
        try:
            # Pad a short chunk to full size (repeat its first scene): one compiled shape.
            padded = np.concatenate([idx, np.full(chunk - idx.size, idx[0])])
            args = (base, names, jax.device_put(points[padded], device), t1, numerics, horizon)
            if device in compiled:
                out = _run_chunk(*args)
            else:
                # Dispatch returns once the program is compiled (JAX runs it
                # asynchronously), so the lock is held for the compilation alone.
                with first_dispatch:
                    out = _run_chunk(*args)
                    compiled.add(device)
            return idx, np.stack([np.asarray(out[n])[: idx.size] for n in SWEEP_FIELDS])
        finally:
            free.put(device)

    def record(idx, values):
        for i, n in enumerate(SWEEP_FIELDS):
            results[n][idx] = values[i]
        done[idx] = True
        if save is not None:
            save()
        bar.update(int(done.sum()))

    pool = ThreadPoolExecutor(max(1, min(len(slots), len(todo))), "jaxworm-sweep")
    try:
        if n_processes == 1:
            futures = [pool.submit(solve, idx) for idx in todo]
            try:
                for future in as_completed(futures):
                    record(*future.result())
            except BaseException as error:
                # Keep what finishes all the same: after a failed chunk the chunks in
                # flight end first (those not started never start); after an interrupt
                # only what has already ended is kept.
                if not isinstance(error, KeyboardInterrupt):
                    for future in futures:
                        future.cancel()
                    wait(futures)
                for future in futures:
                    if future.done() and not future.cancelled() and future.exception() is None:
                        idx, values = future.result()
                        if not done[idx].all():
                            record(idx, values)
                raise
            return
        for first in range(0, len(todo), per_round):
            group = todo[first + offsets[index] : first + offsets[index + 1]]
            mine = np.full((int(counts.max()), chunk), -1, np.int64)
            values = np.full((int(counts.max()), len(SWEEP_FIELDS), chunk), np.nan)
            for j, (idx, v) in enumerate(pool.map(solve, group)):
                mine[j, : idx.size] = idx
                values[j, :, : idx.size] = v
            all_idx, all_values = _distributed.gather((mine, values))
            taken = all_idx >= 0
            record(all_idx[taken], np.moveaxis(all_values, 2, -1)[taken].T)
    finally:
        # An error or an interrupt: chunks not yet started never start; those in flight
        # finish in their threads, unrecorded.
        pool.shutdown(wait=False, cancel_futures=True)

"""Sweeps: a grid of scenes, vmapped in chunks, each finished chunk saved at once.

A sweep keeps one summary per scene (mean velocity, crack count, status, ...), never
trajectories. Results go to a self-describing `.npz` file: the grid's coordinates, the
summary arrays shaped like the grid, a per-scene `done` mask, and a JSON header with
units, the base parameters, t1, the numerics, model conventions and the package version.
Running the same sweep again with the same file resumes where it stopped: only the
chunks not yet done are solved.

```python
import numpy as np, jaxworm as jw
grid = {"omega": np.linspace(3 * np.pi, 5 * np.pi, 21), "delta": np.linspace(np.pi / 6, np.pi / 3, 21)}
s = jw.sweep(grid, t1=60.0, path="fig3.npz")      # interrupt it and run again: it resumes
s["mean_velocity"].shape                           # (21, 21), axes in the grid's order
```
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import json
import os
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from ._control import check_horizon, simulated_horizon
from ._numerics import PRESETS, Numerics
from ._params import FLAT_NAMES, Params
from ._result import STATUS
from ._solve import simulate

__all__ = ["sweep", "load_sweep", "SWEEP_FIELDS"]

#: What a sweep keeps per scene, with units.
SWEEP_FIELDS = {
    "mean_velocity": "m/s", "n_cracks": "-", "status": "code (see STATUS)", "steps": "-",
    "final_head": "m", "final_crack_tip": "m", "energy_residual": "-",
}

UNITS = {"N": "-", "E_s": "Pa", "K_Ic": "Pa m^0.5", "K_Ith": "Pa m^0.5", "nu": "-", "w_c": "m",
         "Wg": "-", "EA": "N", "w0": "m", "l0": "m", "h": "m", "m": "kg", "mu_s": "-",
         "lam": "-", "A": "m/s", "omega": "rad/s", "delta": "rad", "eps_v": "m/s",
         "eps_N": "N", "crack_gap0": "m"}


def _check_grid(grid: dict, base: Params | None = None) -> dict[str, np.ndarray]:
    """The grid as float64 axes; `ValueError` naming the axis for an unknown name, a
    value that is not a finite number, a repeated value (identical scenes), or a value
    that `base.replace` refuses (the parameter's own range)."""
    if not grid:
        raise ValueError("grid is empty: give at least one parameter and its values")
    out = {}
    for name, values in grid.items():
        if name == "N":
            raise ValueError("grid parameter N cannot be swept: it sets array shapes "
                             "(run one sweep per N)")
        if name not in FLAT_NAMES:
            raise ValueError(f"grid parameter {name!r} is unknown: need one of "
                             f"{', '.join(n for n in FLAT_NAMES if n != 'N')}")
        try:
            arr = np.atleast_1d(np.asarray(values, dtype=np.float64))
        except (TypeError, ValueError, OverflowError):
            arr = None
        if arr is None or arr.ndim != 1 or arr.size == 0 or not np.all(np.isfinite(arr)):
            raise ValueError(f"grid parameter {name} = {values!r}: need a non-empty 1-D "
                             "list of finite numbers")
        if np.unique(arr).size != arr.size:
            raise ValueError(f"grid parameter {name} repeats a value ({arr.size} values, "
                             f"{np.unique(arr).size} distinct): the scenes would be identical")
        if base is not None:
            for v in arr:
                try:
                    base.replace(**{name: float(v)})
                except (TypeError, ValueError) as e:
                    raise ValueError(f"grid parameter {name}: {e}") from None
        out[name] = arr
    return out


def _header(grid, base: Params, t1, numerics: Numerics, horizon: str = "t1") -> dict:
    from . import __version__

    return {
        "format": "jaxworm-sweep/1",
        "version": __version__,
        "axes": list(grid),
        "units": {**{n: UNITS.get(n, "-") for n in grid}, **SWEEP_FIELDS, "t1": "s"},
        "t1": float(t1),
        "horizon": horizon,
        "base_parameters": {k: (v if isinstance(v, (int, str)) else float(v))
                            for k, v in base.flat().items() if v is not None},
        "model_options": {"wedge": base.soil.wedge, "offset": getattr(base.gait, "offset", None),
                          "exact": base.smoothing.exact},
        "numerics": dataclasses.asdict(numerics),
        "status_codes": {str(k): v for k, v in STATUS.items()},
        "conventions": "docs/MODEL.md: nodes head first, one gait input per segment, rest "
                       "start, x_c(0) by eq. 13, mean velocity of the node mean",
    }


def _same_run(a: dict, b: dict) -> bool:
    keys = ("axes", "t1", "horizon", "base_parameters", "model_options", "numerics")
    # files written before `horizon` existed simulated [0, t1]
    a, b = ({"horizon": "t1", **h} for h in (a, b))
    return all(json.dumps(a[k], sort_keys=True) == json.dumps(b[k], sort_keys=True) for k in keys)


def _save(path: Path, header, grid, results, done):
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez(tmp, header=json.dumps(header), done=done,
             **{f"coord_{n}": v for n, v in grid.items()},
             **{f"result_{n}": v for n, v in results.items()})
    os.replace(tmp, path)  # atomic: an interrupted save never corrupts the file


def load_sweep(path) -> dict:
    """Read a sweep file: `{"header", "coords", "done", <fields>}`, fields shaped like the grid."""
    with np.load(path, allow_pickle=False) as f:
        header = json.loads(str(f["header"]))
        out = {"header": header, "done": f["done"],
               "coords": {n: f[f"coord_{n}"] for n in header["axes"]}}
        for n in SWEEP_FIELDS:
            out[n] = f[f"result_{n}"]
    return out


# `jax.jit`, not `eqx.filter_jit`: the latter waits for its result, which would run the
# chunks given to several devices one after another instead of at once.
@functools.partial(jax.jit, static_argnums=(1, 3, 4, 5))
def _run_chunk(base: Params, names, values, t1, numerics, horizon="t1"):
    def one(vals):
        p = base.replace(**dict(zip(names, vals)))
        r = simulate(p, simulated_horizon(p.gait, t1, horizon), numerics)
        return {"mean_velocity": r.mean_velocity, "n_cracks": r.n_cracks, "status": r.status,
                "steps": r.steps, "final_head": r.final.x[0], "final_crack_tip": r.x_c,
                "energy_residual": r.energy_residual}
    return jax.vmap(one)(values)


class _Progress:
    """One line on stderr: scenes done, rate, time left."""

    def __init__(self, total, done, enabled):
        self.total, self.start_done, self.enabled = total, done, enabled
        self.t0 = time.perf_counter()

    def update(self, done):
        if not self.enabled:
            return
        dt = time.perf_counter() - self.t0
        new = done - self.start_done
        rate = new / dt if dt > 0 else 0.0
        left = (self.total - done) / rate if rate > 0 else float("nan")
        sys.stderr.write(f"\rsweep: {done}/{self.total} scenes, {rate:.2f}/s, "
                         f"{left:.0f} s left   ")
        sys.stderr.flush()
        if done == self.total:
            sys.stderr.write("\n")


def sweep(grid: dict, base: Params | None = None, t1=60.0,
          numerics: Numerics = PRESETS["fast"], chunk: int | None = None, path=None,
          progress: bool = True, devices=None, horizon: str = "t1") -> dict:
    """Solve every scene of the Cartesian grid `grid` ({flat name: values}) from `base`.

    Scenes run `chunk` at a time under one `vmap`, one chunk per device at once
    (`devices`, default `jax.devices()`; `chunk` default: at most 64, the scenes left
    split evenly into a multiple of the device count, so no lanes are padded for
    nothing); with `path`, each finished round of chunks is
    saved at once and a rerun with the same file, grid, t1 and numerics resumes (a file
    from a different sweep is an error, never overwritten). Returns the dict of
    `load_sweep`. `numerics` defaults to the `fast` preset. `horizon`:
    `"t1"` simulates [0, t1]; `"whole_periods"` up to the last whole gait period in it
    (`whole_period_horizon`), as `jaxworm.optimise(horizon=...)`.

    On a CPU, JAX shows one device however many cores there are, and one solve uses
    one core. Set `XLA_FLAGS=--xla_force_host_platform_device_count=<cores>` before JAX
    starts (the `jaxworm` command does) and the chunks run on all cores.
    """
    base = Params() if base is None else base
    grid = _check_grid(grid, base)
    if not (chunk is None or (isinstance(chunk, int) and chunk >= 1)):
        raise ValueError(f"option chunk = {chunk!r} is out of range: need an integer >= 1")
    t1 = float(t1)
    if not (np.isfinite(t1) and t1 > 0):
        raise ValueError(f"parameter t1 = {t1!r} is out of range: need t1 > 0")
    check_horizon(horizon, base.gait)
    header = _header(grid, base, t1, numerics, horizon)
    shape = tuple(v.size for v in grid.values())
    total = int(np.prod(shape))
    points = np.array(list(itertools.product(*grid.values())))  # (total, n_axes)
    results = {n: np.full(total, np.nan) for n in SWEEP_FIELDS}
    done = np.zeros(total, dtype=bool)
    path = None if path is None else Path(path)
    if path is not None and path.exists():
        old = load_sweep(path)
        if not _same_run(old["header"], header) or any(
                not np.array_equal(old["coords"][n], grid[n]) for n in grid):
            raise ValueError(f"sweep file {str(path)!r} holds a different sweep: "
                             "give another path or delete it")
        done = old["done"].ravel().copy()
        for n in SWEEP_FIELDS:
            results[n] = old[n].ravel().astype(np.float64).copy()
    names = tuple(grid)
    bar = _Progress(total, int(done.sum()), progress)
    todo = np.flatnonzero(~done)
    devices = jax.devices() if devices is None else list(devices)
    if chunk is None:
        rounds = -(-max(todo.size, 1) // (64 * len(devices)))
        chunk = -(-max(todo.size, 1) // (rounds * len(devices)))
    chunks = [todo[i:i + chunk] for i in range(0, todo.size, chunk)]
    for first in range(0, len(chunks), len(devices)):
        group = chunks[first:first + len(devices)]
        outs = []
        for idx, device in zip(group, devices):  # dispatched at once, run concurrently
            # Pad the last chunk to full size (repeat its first scene): one compiled shape.
            padded = np.concatenate([idx, np.full(chunk - idx.size, idx[0])])
            outs.append(_run_chunk(base, names, jax.device_put(points[padded], device), t1,
                                   numerics, horizon))
        for idx, out in zip(group, outs):
            for n in SWEEP_FIELDS:
                results[n][idx] = np.asarray(out[n])[: idx.size]
            done[idx] = True
        if path is not None:
            _save(path, header, grid, {n: v.reshape(shape) for n, v in results.items()},
                  done.reshape(shape))
        bar.update(int(done.sum()))
    out = {"header": header, "done": done.reshape(shape), "coords": grid}
    out.update({n: v.reshape(shape) for n, v in results.items()})
    return out

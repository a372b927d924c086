"""Shared helpers of the benchmarks: compile once, time after compilation, peak memory,
errors, and where results go.

Timing protocol (every JAX method): `jax.jit(lambda p, t1: simulate(p, t1, numerics))`
is lowered and compiled ahead of time (the compile time), then the compiled executable
is called `repeats` times and the fastest wall time is kept (as `timeit` advises: on a shared
machine the others only add noise; all of them are recorded). Parameters and `t1` are
arguments, so one compilation serves every scene with the same static structure.

Peak memory: the increase of the process's peak resident set over its level before the
solve (the kernel's high-water mark is reset through `/proc/self/clear_refs`), the same
measure for JAX and SciPy; for JAX also XLA's own buffer plan of the compiled program
(temporaries + arguments + outputs).
"""

from __future__ import annotations

import os

# Single-threaded OpenBLAS (read when the library loads, so before numpy and jax): the
# LU of an implicit step is tiny, and threaded OpenBLAS was seen to take 260 ms instead of
# 1 ms for a 152-square LU (N = 50 nodes) on a busy 2-core machine. Recorded in the
# machine info; set OPENBLAS_NUM_THREADS yourself to override.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
# Compile times must be real: no programs from the jaxworm cache folder either.
os.environ["JAXWORM_CACHE_DIR"] = ""

import inspect
import math
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

jax.config.update("jax_enable_compilation_cache", False)  # compile times must be real

from _results import (  # noqa: F401  (re-exported: the scripts use them as _bench.X)
    RESULTS,
    cores,
    machine_info,
    machine_line,
    quick_suffix,
    results_dir,
    run_record,
    write_json,
)

import jaxworm as jw  # noqa: E402

#: `jaxworm.optimise`'s keyword defaults (box, t1, starts, steps, numerics, ...).
OPTIMISE_DEFAULTS = {
    k: v.default
    for k, v in inspect.signature(jw.optimise).parameters.items()
    if v.default is not inspect.Parameter.empty
}

#: |v| floor [m/s] of the relative error: scenes whose mean velocity is near zero are
#: judged on the scale of the gaits' speeds (~1e-2 m/s), not on round-off.
V_FLOOR = 1e-4


# --- machine and memory -------------------------------------------------------------


def _status_kb(key: str) -> int | None:
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(key):
                return int(line.split()[1])
    except OSError:
        return None
    return None


def reset_peak_rss() -> int | None:
    """Reset the kernel's peak-RSS mark to the current RSS; return the current RSS [kB]."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        return None
    return _status_kb("VmRSS")


def peak_rss_mb() -> float | None:
    """The process's peak RSS since the last `reset_peak_rss` [MB] (None where unsupported)."""
    peak = _status_kb("VmHWM")
    return None if peak is None else peak / 1024.0


def peak_rss_increase_mb(before_kb: int | None) -> float | None:
    """Peak RSS since `reset_peak_rss` minus the RSS then [MB] (None where unsupported)."""
    peak = _status_kb("VmHWM")
    if before_kb is None or peak is None:
        return None
    return max(peak - before_kb, 0) / 1024.0


# --- JAX: compile once, time after -------------------------------------------------

_COMPILED: dict = {}


def compiled_simulate(numerics: jw.Numerics, params: jw.Params, dense: int = 0):
    """AOT-compiled `(params, t1[, ts]) -> Result` for this numerics and params structure.

    Returns `(fn, compile_s, xla_bytes)`; cached, so a second scene with the same static
    structure reuses it (compile_s is then the first compilation's).
    """
    key = (numerics, jax.tree_util.tree_structure(params), dense)
    if key not in _COMPILED:
        t1 = jnp.float64(1.0)
        if dense:
            fn = jax.jit(lambda p, t, ts: jw.simulate(p, t, numerics, ts=ts))
            args = (params, t1, jnp.zeros(dense))
        else:
            fn = jax.jit(lambda p, t: jw.simulate(p, t, numerics))
            args = (params, t1)
        start = time.perf_counter()
        compiled = fn.lower(*args).compile()
        compile_s = time.perf_counter() - start
        try:
            m = compiled.memory_analysis()
            xla_bytes = int(
                m.temp_size_in_bytes + m.argument_size_in_bytes + m.output_size_in_bytes
            )
        except Exception:  # not every backend reports it
            xla_bytes = None
        _COMPILED[key] = (compiled, compile_s, xla_bytes)
    return _COMPILED[key]


def timed_runs(fn, args, repeats: int = 3, long_s: float = 5.0):
    """Call `fn(*args)` up to `repeats` times (once if the first takes > `long_s`).

    Returns `(last_result, min_wall_s, all_walls, peak_rss_increase_mb_of_first)`.
    """
    walls = []
    result = None
    peak = None
    for i in range(max(repeats, 1)):
        before = reset_peak_rss()
        start = time.perf_counter()
        result = fn(*args)
        jax.block_until_ready(result)
        walls.append(time.perf_counter() - start)
        if i == 0:
            peak = peak_rss_increase_mb(before)
            if walls[0] > long_s:
                break
    return result, min(walls), walls, peak


def first_call_and_runs(fn, args, repeats: int):
    """`jax.jit(fn)(*args)` once (compile + run), then `repeats` more times.

    Returns `(result, first_call_s, [run_s, ...])`."""
    fn = jax.jit(fn)
    start = time.perf_counter()
    result = jax.block_until_ready(fn(*args))
    first = time.perf_counter() - start
    runs = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn(*args))
        runs.append(time.perf_counter() - start)
    return result, first, runs


def params_of(overrides: dict) -> jw.Params:
    """`jw.Params()` with flat overrides (`N` goes through the constructor as an int)."""
    over = dict(overrides)
    p = jw.Params()
    if "N" in over:
        p = p.replace(N=int(over.pop("N")))
    return p.replace(**over)


def run_jax(numerics: jw.Numerics, overrides: dict, t1: float, repeats: int = 3) -> dict:
    """One timed solve: the row of a results table (no error yet)."""
    p = params_of(overrides)
    fn, compile_s, xla_bytes = compiled_simulate(numerics, p)
    r, wall, walls, peak = timed_runs(fn, (p, jnp.float64(t1)), repeats)
    return summary_row(r) | {
        "t1": t1,
        "wall_s": wall,
        "walls_s": walls,
        "compile_s": compile_s,
        "xla_bytes": xla_bytes,
        "peak_rss_mb": peak,
    }


def summary_row(r) -> dict:
    """Plain-Python summary of an unbatched `Result`, with the runaway indicators."""
    v = np.asarray(r.final.v)
    return {
        "mean_velocity": float(r.mean_velocity),
        "n_cracks": int(r.n_cracks),
        "steps": int(r.steps),
        "rejected": int(r.rejected_steps),
        "energy_residual": float(r.energy_residual),
        "status": str(r.status_name),
        "max_abs_v_final": float(np.max(np.abs(v))) if v.size else math.nan,
        "finite": bool(np.all(np.isfinite(np.asarray(r.final.x))) and np.all(np.isfinite(v))),
        "x_final": np.asarray(r.final.x).tolist(),
    }


# --- SciPy anchors ------------------------------------------------------------------


def run_scipy(method: str, rtol: float, overrides: dict, t1: float) -> dict:
    """`reference_model.simulate_reference` (solve_ivp, terminal crack events and
    restart, analytic Jacobian), timed once; atol = 1e-3·rtol m on positions (×1e3 on
    velocities, as that module scales them)."""
    from reference_model import simulate_reference  # late: loads SciPy

    before = reset_peak_rss()
    start = time.perf_counter()
    try:
        out = simulate_reference(t1, rtol=rtol, atol=1e-3 * rtol, method=method, **overrides)
        status = "ok"
    except RuntimeError as err:  # solve_ivp failure or too many cracks
        out, status = None, f"failed: {err}"
    wall = time.perf_counter() - start
    peak = peak_rss_increase_mb(before)
    row = {
        "t1": t1,
        "wall_s": wall,
        "walls_s": [wall],
        "compile_s": 0.0,
        "xla_bytes": None,
        "peak_rss_mb": peak,
        "status": status,
    }
    if out is None:
        return row | {
            "mean_velocity": math.nan,
            "n_cracks": -1,
            "steps": -1,
            "rejected": -1,
            "energy_residual": math.nan,
            "max_abs_v_final": math.nan,
            "finite": False,
        }
    return row | {
        "mean_velocity": out["mean_velocity"],
        "n_cracks": out["n_cracks"],
        "steps": out["nsteps"],
        "rejected": -1,
        "energy_residual": math.nan,
        "max_abs_v_final": float(np.max(np.abs(out["v_final"]))),
        "finite": bool(np.all(np.isfinite(out["x_final"]))),
    }


# --- errors and equal-error comparisons ---------------------------------------------


def rel_error(v: float, v_ref: float) -> float:
    """|v − v_ref| / max(|v_ref|, V_FLOOR): relative error in mean velocity."""
    if not (math.isfinite(v) and math.isfinite(v_ref)):
        return math.inf
    return abs(v - v_ref) / max(abs(v_ref), V_FLOOR)


def pareto(points: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """The (error, time) points no other point beats in both; sorted by error."""
    pts = sorted((e, t) for e, t in points if math.isfinite(e) and math.isfinite(t))
    front = []
    for e, t in pts:
        if not front or t < front[-1][1]:
            front.append((e, t))
    return front


def time_at_error(points: list[tuple[float, float]], error: float) -> tuple[float | None, str]:
    """Wall time a method needs to reach `error`, from its (error, time) points.

    Log-log interpolation along the method's Pareto front where it brackets `error`
    ("interpolated"). Where even its cheapest run is more accurate than `error`, that
    run's time ("upper bound": the method was never run as loosely, it might be faster).
    Where no run is as accurate, the time of its most accurate run ("lower bound": the
    method never reached `error`, it would take longer).
    """
    front = pareto(points)
    if not front:
        return None, "no successful run"
    if error < front[0][0]:
        return front[0][1], f"lower bound (never reached; best error {front[0][0]:.1e})"
    if error >= front[-1][0]:
        return front[-1][1], "upper bound (its loosest run is more accurate)"
    for (e0, t0), (e1, t1) in zip(front, front[1:]):
        if e0 <= error <= e1:
            if e0 <= 0 or e1 == e0:
                return t0, "interpolated"
            a = (math.log(error) - math.log(e0)) / (math.log(e1) - math.log(e0))
            return math.exp(math.log(t0) + a * (math.log(t1) - math.log(t0))), "interpolated"
    return None, "no successful run"


def slope_fit(dx, y) -> tuple[float, float]:
    """The least-squares line through (dx, y): its slope and the slope's standard error
    (the reference slope of a derivative check, dx the parameter's offsets)."""
    dx, y = np.asarray(dx, float), np.asarray(y, float)
    coef, res, *_ = np.linalg.lstsq(np.stack([dx, np.ones_like(dx)], axis=1), y, rcond=None)
    sigma2 = float(res[0]) / (dx.size - 2) if res.size else 0.0
    return float(coef[0]), math.sqrt(sigma2 / np.sum(dx**2))


# --- output -------------------------------------------------------------------------


def batched_velocity(
    numerics: jw.Numerics,
    t1: float,
    names,
    base: jw.Params | None = None,
    apply=None,
    horizon: str = "t1",
    workers: int | None = None,
):
    """`theta (n, P) -> (mean velocity, status)`, the n points solved as `workers` equal
    vmapped batches at once, each from its own thread (default: one per core), all
    through one program, compiled at the first call (before the threads start). One
    XLA CPU solve runs on one core, so this is the fastest batched forward solve of a
    population on a CPU. The last batch is padded with copies of its last point, whose
    results are dropped.
    `apply(base, names, th) -> Params` (default: `base.replace` by the flat names);
    `horizon` as in `jaxworm.optimise` ("t1" or "whole_periods")."""
    base = jw.Params() if base is None else base
    apply = apply or (lambda b, ns, th: b.replace(**dict(zip(ns, th))))
    workers = cores() if workers is None else workers

    def one(th):
        p = apply(base, names, th)
        return jw.simulate(p, t1, numerics, horizon=horizon)

    @jax.jit
    def run(theta):
        r = jax.vmap(one)(theta)
        return r.mean_velocity, r.status

    compiled = {}

    def batched(theta):
        theta = np.asarray(theta, dtype=np.float64)
        n = theta.shape[0]
        groups = max(1, min(workers, n))
        m = -(-n // groups)  # points per batch
        padded = np.concatenate([theta, np.repeat(theta[-1:], groups * m - n, axis=0)])
        parts = [jnp.asarray(padded[g * m : (g + 1) * m]) for g in range(groups)]
        if m not in compiled:  # once per batch shape, not once per thread
            compiled[m] = run.lower(parts[0]).compile()
        with ThreadPoolExecutor(groups) as pool:
            out = list(pool.map(compiled[m], parts))
        v, status = (np.concatenate([np.asarray(o[k]) for o in out])[:n] for k in (0, 1))
        return v, status

    return batched


def add_gradient_options(ap, horizon: str) -> None:
    """`--horizon`, `--box`, `--optimiser`, `--b1` and `--lr` of the optimisation
    benchmarks, defaulting to `jaxworm.optimise`'s own choices: its box, and Adam on z
    with that box's first step and momentum, cosine-decayed to 5 %. `horizon` is the
    library's default for the benchmark's parameters (whole periods when ω is optimised,
    else t1). Any other choice adds a suffix to the file names (`gradient_tag`)."""
    box = OPTIMISE_DEFAULTS["box"]
    lr, b1 = jw.DEFAULT_OPTIMISERS[box]["learning_rate"], jw.DEFAULT_OPTIMISERS[box]["b1"]
    ap.add_argument(
        "--horizon",
        choices=jw.HORIZONS,
        default=horizon,
        help="every method: mean velocity over [0, t1] or over whole gait periods "
        f"(default {horizon}, jaxworm.optimise's for these parameters)",
    )
    ap.add_argument(
        "--box",
        choices=tuple(jw.BOXES),
        default=box,
        help=f"the reparametrisation (default {box}, jaxworm.optimise's; "
        "--lr and --b1 keep their defaults whatever the box)",
    )
    ap.add_argument(
        "--optimiser",
        choices=("adam", "rprop"),
        default="adam",
        help="adam (default, jaxworm.optimise's): cosine-decayed from --lr to 5 %%; "
        "rprop: jaxworm's iRprop−, first step --lr (--b1 unused)",
    )
    ap.add_argument(
        "--b1",
        type=float,
        default=b1,
        help=f"Adam's momentum (default {b1:g}, jaxworm.optimise's on the {box} box)",
    )
    ap.add_argument(
        "--lr",
        type=float,
        default=lr,
        help=f"first step in z (default {lr:g}, jaxworm.optimise's on the {box} box)",
    )


def gradient_optimiser(args, steps: int):
    """The optax transformation `add_gradient_options` (and `--lr`) describe
    (`jaxworm.make_optimiser`; `--b1` is Adam's alone)."""
    return jw.make_optimiser(
        args.optimiser,
        steps,
        box=args.box,
        learning_rate=args.lr,
        b1=args.b1 if args.optimiser == "adam" else None,
    )


def gradient_label(o: dict) -> str:
    """'Adam b1 0' or 'iRprop−' from a benchmark's saved options."""
    if o.get("optimiser") == "rprop":
        return "iRprop−"
    return f"Adam b1 {o.get('b1', 0.9):g}"


def gradient_tag(args, ap) -> str:
    """File-name suffix of the `add_gradient_options` choices that differ from the
    defaults of the parser `ap`: `_horizon_<h>`, `_<box>`, `_rprop`, `_b1_<b1>` (Adam
    only), `_lr_<lr>`, in that order ('' for the defaults)."""
    d = ap.get_default
    return (
        ("" if args.horizon == d("horizon") else f"_horizon_{args.horizon}")
        + ("" if args.box == d("box") else f"_{args.box}")
        + ("" if args.optimiser == d("optimiser") else f"_{args.optimiser}")
        + ("" if args.b1 == d("b1") or args.optimiser != "adam" else f"_b1_{args.b1:g}")
        + ("" if args.lr == d("lr") else f"_lr_{args.lr:g}")
    )


def evals_to(best_so_far, evals, walls, target: float):
    """First (evaluations, wall time) at which the best so far reaches `target`;
    (None, None) if it never does."""
    hit = np.flatnonzero(np.asarray(best_so_far) >= target)
    if hit.size == 0:
        return None, None
    return int(np.asarray(evals)[hit[0]]), float(np.asarray(walls)[hit[0]])


def first_call_excess(call_ends) -> float:
    """What the first of a sequence of like calls took beyond the median of the others
    (compilation, mostly), from the cumulative wall times at which the calls ended; 0
    with fewer than three calls. Subtracted from a wall time, it gives that wall time
    with the compilation excluded."""
    ends = np.unique(np.asarray(call_ends, float))
    if ends.size < 3:
        return 0.0
    return max(0.0, float(ends[0] - np.median(np.diff(ends))))


def cma_maximise(fn, lo, hi, x0, sigma0: float, seed: int, budget: int) -> dict:
    """CMA-ES (the `cma` package) maximising `fn` over the box [lo, hi], scaled to the
    unit cube (cma's own bound handling). `fn(theta (P, n)) -> (values, statuses)` takes
    a whole generation at once; a status other than 0 counts as −inf. Returns the best
    so far after each evaluation (in the order CMA asked), the wall time since the start
    (compilation included on a first call), the population size and the best point."""
    import cma

    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    es = cma.CMAEvolutionStrategy(
        list(x0), sigma0, {"bounds": [0.0, 1.0], "seed": seed, "verbose": -9, "maxfevals": budget}
    )
    best, best_theta, trace, walls = -np.inf, None, [], []
    t = time.perf_counter()
    while not es.stop():
        us = es.ask()
        theta = lo + (hi - lo) * np.clip(np.array(us), 0.0, 1.0)
        v, status = fn(theta)
        v = np.where(np.asarray(status) == 0, np.asarray(v), -np.inf)
        es.tell(us, list(-v))
        now = time.perf_counter() - t
        for k in range(len(us)):
            if v[k] > best:
                best, best_theta = float(v[k]), theta[k]
            trace.append(best)
            walls.append(now)
    return {
        "seed": seed,
        "popsize": es.popsize,
        "evaluations": len(trace),
        "best_so_far": np.array(trace),
        "walls": np.array(walls),
        "evals": np.arange(1, len(trace) + 1),
        "best_theta": best_theta,
        "best_fast": best,
    }


def fmt(x, spec: str = ".3g") -> str:
    """Number for a Markdown cell ('—' for None/NaN)."""
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "—"
    return format(x, spec)


def md_table(header: list[str], rows: list[list]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return lines


def log(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)

"""How `jw.optimise` should batch its starts on a CPU: `vmap` against `map`.

Each configuration runs in a fresh Python process with the jaxworm caches off
(`JAXWORM_CACHE_DIR=""`), as a user's first run: its first step includes tracing and
compiling. Two problems at t1 = 10 s (`--t1`): the 12 per-segment amplitudes and phases
(`apply_segments`, from the wave A = 0.02 m/s, ω = 3π, δ = −0.2333π; the bounds of
`segment_gait.py`) and the travelling wave's (A, ω, δ) (`DEFAULT_BOUNDS` plus A in
[0.01, 0.03] m/s, over whole periods).

- 4 starts: `jw.optimise` with `batch="vmap"` against `batch="map"` (default workers,
  `--steps` steps of the default optimiser): the first step's wall time and the median
  of the later steps, from the step times the history records.
- 1 start: one value and `jax.jacfwd` at the box's centre, alone (as `jw.optimise`
  solves a batch of one) against vmapped over a batch of one: the first call and the
  fastest of `--steps` later calls.

Each configuration runs `--repeats` times, the two modes alternated, and the fastest is
kept. Also reported: the largest difference in value and gradient between the two
modes at the first step (the same points: rounding, and the adaptive steps it moves).

    python benchmarks/optimise_batch.py            # ~7 min on 2 cores
    python benchmarks/optimise_batch.py --t1 60

Writes results/optimise_batch/optimise_batch[_t1_X].{json,md}.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import _bench as B  # (first: sets the BLAS threads and turns the jaxworm caches off)
import jax
import jax.numpy as jnp
import numpy as np

import jaxworm as jw
from jaxworm import SegmentWave, apply_segments


def _problem(name: str):
    if name == "wave":
        bounds = {**jw.DEFAULT_BOUNDS, "A": (0.01, 0.03)}
        return jw.Params(), bounds, None, 3
    wave = jw.TravellingWave(A=0.02, omega=3.0 * math.pi, delta=-0.2333 * math.pi)
    n_seg = jw.Body().N - 1
    seg = SegmentWave.from_wave(wave, n_seg + 1)
    phases = np.asarray(seg.phase)
    bounds = {f"A_{k}": (0.01, 0.03) for k in range(1, n_seg + 1)}
    bounds.update(
        {
            f"phase_{k}": (phases[k - 1] - math.pi / 4, phases[k - 1] + math.pi / 4)
            for k in range(1, n_seg + 1)
        }
    )
    return jw.Params(gait=seg), bounds, apply_segments, len(bounds)


def lane(problem: str, mode: str, t1: float, steps: int) -> dict:
    """One start's value and `jax.jacfwd` at the centre of the box, alone or vmapped as a
    batch of one (`mode` "alone" or "vmap"): the first call (compiling) and the fastest
    of `steps` later ones."""
    base, bounds, apply, n_params = _problem(problem)
    names = tuple(bounds)
    horizon = "whole_periods" if "omega" in names else "t1"

    def velocity(theta):
        p = apply(base, names, theta) if apply else base.replace(**dict(zip(names, theta)))
        r = jw.simulate(p, t1, horizon=horizon)
        return r.mean_velocity, (r.mean_velocity, r.status)

    def value_and_jac(theta):  # one solve, as `jw.optimise` takes it (jacfwd's aux)
        grad, (value, status) = jax.jacfwd(velocity, has_aux=True)(theta)
        return value, grad, status

    fn = value_and_jac if mode == "alone" else lambda th: jax.vmap(value_and_jac)(th[None])
    fn = jax.jit(fn)
    theta = jnp.asarray([(lo + hi) / 2 for lo, hi in bounds.values()])
    start = time.perf_counter()
    value, grad, status = jax.block_until_ready(fn(theta))
    first = time.perf_counter() - start
    later = []
    for _ in range(steps):
        start = time.perf_counter()
        jax.block_until_ready(fn(theta))
        later.append(time.perf_counter() - start)
    return {
        "problem": problem,
        "parameters": n_params,
        "starts": 1,
        "batch": mode,
        "first_step_s": first,
        "later_step_s": min(later),
        "value0": np.ravel(value).tolist(),
        "grad0": np.ravel(grad).tolist(),
        "ok0": bool(np.all(np.asarray(status) == 0)),
    }


def child(problem: str, starts: int, batch: str, t1: float, steps: int) -> dict:
    if starts == 1:
        return lane(problem, batch, t1, steps)
    base, bounds, apply, n_params = _problem(problem)
    with tempfile.TemporaryDirectory() as tmp:
        res = jw.optimise(
            "velocity",
            bounds,
            base=base,
            apply=apply,
            t1=t1,
            starts=starts,
            steps=steps,
            batch=batch,
            path=Path(tmp) / "h.npz",
            progress=False,
        )
        h = np.load(Path(tmp) / "h.npz")
        wall = h["wall_time"]
    return {
        "problem": problem,
        "parameters": n_params,
        "starts": starts,
        "batch": batch,
        "first_step_s": float(wall[0]),
        "later_step_s": float(np.median(np.diff(wall))),
        "value0": np.asarray(res.value[0]).tolist(),
        "grad0": np.asarray(res.grad[0]).tolist(),
        "ok0": bool(np.all(np.asarray(res.status[0]) == 0)),
    }


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--t1", type=float, default=10.0, help="horizon [s] (default 10)")
    ap.add_argument("--steps", type=int, default=4, help="optimiser steps (default 4)")
    ap.add_argument(
        "--repeats", type=int, default=2, help="processes per configuration, alternated (default 2)"
    )
    ap.add_argument(
        "--child", nargs=3, metavar=("PROBLEM", "STARTS", "BATCH"), help=argparse.SUPPRESS
    )
    args = ap.parse_args(argv)
    if args.child:
        problem, starts, batch = args.child
        print(json.dumps(child(problem, int(starts), batch, args.t1, args.steps)))
        return

    env = {**os.environ, "JAXWORM_CACHE_DIR": ""}
    rows = []
    cmd = [sys.executable, __file__, "--t1", str(args.t1), "--steps", str(args.steps)]
    for problem in ("segments", "wave"):
        for starts in (1, 4):
            runs: dict[str, list] = {"vmap": [], "map" if starts > 1 else "alone": []}
            for _ in range(args.repeats):
                for batch in runs:
                    out = subprocess.run(
                        [*cmd, "--child", problem, str(starts), batch],
                        env=env,
                        capture_output=True,
                        text=True,
                        check=True,
                    )
                    runs[batch].append(json.loads(out.stdout.strip().splitlines()[-1]))
                    B.log(str({k: v for k, v in runs[batch][-1].items() if "0" not in k}))
            for rs in runs.values():  # the fastest process of each (timeit's rule)
                row = dict(rs[0])
                for key in ("first_step_s", "later_step_s"):
                    row[key] = min(r[key] for r in rs)
                    row[key.replace("_s", "_all_s")] = [r[key] for r in rs]
                rows.append(row)
    pairs = []
    for v, m in zip(rows[::2], rows[1::2]):
        dv = np.max(np.abs(np.subtract(v["value0"], m["value0"])) / np.abs(m["value0"]))
        g_v, g_m = np.asarray(v["grad0"]), np.asarray(m["grad0"])
        dg = np.max(np.abs(g_v - g_m)) / np.max(np.abs(g_m))
        pairs.append({"value_rel_diff": float(dv), "grad_rel_diff": float(dg)})
    suffix = "" if args.t1 == 10.0 else f"_t1_{args.t1:g}"
    folder = B.results_dir("optimise_batch")
    out = {
        "machine": B.machine_info(),
        "t1": args.t1,
        "steps": args.steps,
        "rows": rows,
        "pairs": pairs,
    }
    B.write_json(folder / f"optimise_batch{suffix}.json", out)
    table = []
    for (v, m), d in zip(zip(rows[::2], rows[1::2]), pairs):
        table.append(
            [
                f"{v['problem']} ({v['parameters']} parameters)",
                v["starts"],
                f"{v['first_step_s']:.1f} / {m['first_step_s']:.1f}",
                f"{v['later_step_s']:.2f} / {m['later_step_s']:.2f}",
                f"{v['later_step_s'] / m['later_step_s']:.2f}",
                f"{d['value_rel_diff']:.1e} / {d['grad_rel_diff']:.1e}",
                "yes" if v["ok0"] and m["ok0"] else "no",
            ]
        )
    lines = [
        f"# `jw.optimise` on a CPU: starts vmapped or mapped (t1 = {args.t1:g} s)",
        "",
        B.machine_line(out["machine"]),
        "",
        f"Command: `python benchmarks/optimise_batch.py{suffix and f' --t1 {args.t1:g}'}`. "
        f"{args.repeats} fresh processes per configuration (the modes alternated), the "
        "fastest kept; jaxworm caches off. 4 starts: `jw.optimise`, default workers, "
        f"{args.steps} steps of the default optimiser; first step: wall time to its end, "
        "tracing and compiling included; later: the median step after it. 1 start: one "
        "value and `jax.jacfwd` at the box's centre, vmapped over a batch of one or alone "
        f"(as `jw.optimise` solves a batch of one); first call, and the fastest of "
        f"{args.steps} later ones. Difference: the largest relative difference between "
        "the modes at the first step (same points) in value, and in gradient relative to "
        "its largest component.",
        "",
        *B.md_table(
            [
                "problem",
                "starts",
                "first step s, vmap / map (1 start: alone)",
                "later step s, vmap / map (alone)",
                "vmap ÷ map (alone)",
                "difference value / gradient",
                "all ok",
            ],
            table,
        ),
    ]
    (folder / f"optimise_batch{suffix}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()

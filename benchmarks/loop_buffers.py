"""Why every array of a solver step must stay at or under 512 bytes on a CPU.

XLA's CPU runtime runs the thunks (fused kernels, library calls) of a loop body one
after another in the calling thread only while every buffer they use holds at most
512 bytes (64 float64); past that it executes the body as a dataflow graph on its
thread pool. For a step made of a hundred kernels of a few hundred nanoseconds each,
handing them between threads costs more than it gains.

This measures one `fast` Rodas4 step of the Table 1 scene (open-loop wave), repeated
1000 times in a `fori_loop`, with one more array carried and updated in the loop body,
of 0 (none), 48, 64, 65 and 128 float64. Wall time and the process's CPU time per step,
fastest of `--rounds` interleaved rounds: at 65 elements the wall time jumps and the
CPU time exceeds it (a second thread busy). `jaxworm`'s closed-loop linear solve keeps
its arrays in blocks under the threshold for this reason (`_linear_solve._gauss_jordan`).

Then what it costs a user today: `jw.simulate(p, 10.0, ts=ts)` (δ = −π/4, `fast`)
with 0, 8, 64 and 600 output times (diffrax keeps the saved states in the solve's
loop, (len(ts), N) arrays, past the threshold from 10 times on), and the same solve
without output times for bodies of N = 7 … 14 nodes (the structured solve forms its
N×N tridiagonal inverse and its directional derivatives in blocks under the threshold;
as one (N, N) and one (8, N) array they passed it from N = 9 on).

    python benchmarks/loop_buffers.py [--rounds 7]

Writes results/loop_buffers/loop_buffers.{json,md}.
"""

from __future__ import annotations

import os

os.environ["XLA_FLAGS"] = "--xla_force_host_platform_device_count=1"

import argparse  # noqa: E402
import time  # noqa: E402

import _bench as B  # noqa: E402
import _results as R  # noqa: E402
import diffrax  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

import jaxworm as jw  # noqa: E402

STEPS = 1000
H = 1e-4  # one step of 0.1 ms from t = 0.1 s, repeated
SIZES = (0, 48, 64, 65, 128)
OUTPUT_TIMES = (0, 8, 64, 600)
NODES = (7, 8, 9, 10, 14)
TRAJECTORY_T1 = 10.0


def _program(extra: int):
    """A jitted loop of STEPS Rodas4 steps carrying one more array of `extra` float64
    (none for 0), and its input."""
    p = jw.Params()
    y0 = jw.initial_state(p)
    args = (p, jw.initial_crack_tip(p, y0))
    solver = jw.PRESETS["fast"].build_solver()
    terms = diffrax.ODETerm(jw.vector_field)

    def body(_, z):
        y, more = z
        y1, err, _, _, _ = solver.step(terms, 0.1, 0.1 + H, y, args, None, False)
        # The step's result enters the carry at 1e-30: the same step every time.
        y = jax.tree_util.tree_map(lambda a, b, e: a + 1e-30 * (b + e), y, y1, err)
        if extra:
            more = 0.999 * more + 1e-30 * y.x[0]
        return y, more

    z0 = (y0, jnp.ones(max(extra, 1)))
    return jax.jit(lambda z: jax.lax.fori_loop(0, STEPS, body, z)), z0


def _trajectory_program(count: int):
    """The jitted mean velocity of `simulate` over TRAJECTORY_T1 with `count` output
    times (none for 0), and its input."""
    ts = jnp.linspace(0.0, TRAJECTORY_T1, count) if count else None
    fn = jax.jit(lambda p: jw.simulate(p, TRAJECTORY_T1, ts=ts).mean_velocity)
    return fn, jw.Params().replace(delta=-jnp.pi / 4)


def _nodes_program(N: int):
    """The jitted `simulate` over TRAJECTORY_T1 of a body of N nodes, and its input."""
    fn = jax.jit(lambda p: jw.simulate(p, TRAJECTORY_T1))
    return fn, jw.Params().replace(delta=-jnp.pi / 4, N=N)


def _fastest(programs: dict, rounds: int, per: int = 1):
    """Fastest wall and CPU seconds (divided by `per`) of each program, interleaved."""
    wall = {k: float("inf") for k in programs}
    cpu = {k: float("inf") for k in programs}
    for _ in range(rounds):
        for k, (fn, z0) in programs.items():
            w, c = time.perf_counter(), time.process_time()
            jax.block_until_ready(fn(z0))
            wall[k] = min(wall[k], (time.perf_counter() - w) / per)
            cpu[k] = min(cpu[k], (time.process_time() - c) / per)
    return wall, cpu


def main(argv=None):
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--rounds", type=int, default=7, help="interleaved timing rounds")
    args = ap.parse_args(argv)
    programs = {}
    for extra in SIZES:
        fn, z0 = _program(extra)
        jax.block_until_ready(fn(z0))
        programs[extra] = (fn, z0)
    wall, cpu = _fastest(programs, args.rounds, STEPS)
    trajectories = {}
    for count in OUTPUT_TIMES:
        fn, p = _trajectory_program(count)
        jax.block_until_ready(fn(p))
        trajectories[count] = (fn, p)
    t_wall, t_cpu = _fastest(trajectories, args.rounds)
    simulate_rows = [
        {"output_times": n, "wall_s": t_wall[n], "cpu_s": t_cpu[n]} for n in OUTPUT_TIMES
    ]
    bodies, steps = {}, {}
    for N in NODES:
        fn, p = _nodes_program(N)
        steps[N] = int(jax.block_until_ready(fn(p)).steps)
        bodies[N] = (fn, p)
    n_wall, n_cpu = _fastest(bodies, args.rounds)
    nodes_rows = [
        {"N": N, "steps": steps[N], "wall_s": n_wall[N], "cpu_s": n_cpu[N]} for N in NODES
    ]
    rows = [
        {
            "extra_float64": e,
            "extra_bytes": 8 * e,
            "wall_us_per_step": 1e6 * wall[e],
            "cpu_us_per_step": 1e6 * cpu[e],
        }
        for e in SIZES
    ]
    out = {
        "machine": B.machine_info(),
        "steps": STEPS,
        "rounds": args.rounds,
        "rows": rows,
        "simulate_t1": TRAJECTORY_T1,
        "simulate_rows": simulate_rows,
        "nodes_rows": nodes_rows,
    }
    folder = R.results_dir("loop_buffers")
    R.write_json(folder / "loop_buffers.json", out)
    base = rows[0]["wall_us_per_step"]
    lines = [
        "# One Rodas4 step with one more array in the loop body: XLA's 512-byte threshold",
        "",
        B.machine_line(out["machine"]),
        "",
        f"Command: `python benchmarks/loop_buffers.py --rounds {args.rounds}`. "
        f"{STEPS} `fast` Rodas4 steps of Table 1 in a `fori_loop`, one more array of the "
        f"given size carried and updated; fastest of {args.rounds} interleaved rounds. "
        "CPU time above wall time means a second thread was busy.",
        "",
        *B.md_table(
            ["extra array", "bytes", "wall µs per step", "× none", "CPU µs per step"],
            [
                [
                    f"{r['extra_float64']} float64" if r["extra_float64"] else "none",
                    str(r["extra_bytes"]),
                    f"{r['wall_us_per_step']:.2f}",
                    f"{r['wall_us_per_step'] / base:.2f}",
                    f"{r['cpu_us_per_step']:.2f}",
                ]
                for r in rows
            ],
        ),
    ]
    base_s = simulate_rows[0]["wall_s"]
    lines += [
        "",
        f"`jw.simulate(p, {TRAJECTORY_T1:g}, ts=ts)`, δ = −π/4, `fast`, with evenly spaced "
        "output times: diffrax keeps the saved states in the solve's loop.",
        "",
        *B.md_table(
            ["output times", "wall ms", "× none", "CPU ms"],
            [
                [
                    str(r["output_times"]) if r["output_times"] else "none",
                    f"{1e3 * r['wall_s']:.1f}",
                    f"{r['wall_s'] / base_s:.2f}",
                    f"{1e3 * r['cpu_s']:.1f}",
                ]
                for r in simulate_rows
            ],
        ),
    ]
    lines += [
        "",
        f"`jw.simulate(p, {TRAJECTORY_T1:g})`, δ = −π/4, `fast`, bodies of N nodes:",
        "",
        *B.md_table(
            ["N", "steps", "wall ms", "µs per step", "CPU ms"],
            [
                [
                    str(r["N"]),
                    str(r["steps"]),
                    f"{1e3 * r['wall_s']:.1f}",
                    f"{1e6 * r['wall_s'] / r['steps']:.1f}",
                    f"{1e3 * r['cpu_s']:.1f}",
                ]
                for r in nodes_rows
            ],
        ),
    ]
    (folder / "loop_buffers.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

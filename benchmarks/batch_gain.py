"""What a vmapped batch buys on one CPU core, and where its lanes wait.

Four measurements in one process, on one JAX CPU device:

1. **The ceiling.** Table 1 stepped in lockstep: a fixed step (1000 Rodas4 steps over
   2 s, no events, no rejected steps), as one lone solve and as vmapped batches of B
   gaits. Every lane takes the same steps, so the batch gain here is what vmap can give
   at best: the per-lane cost of one step in a batch of B against a lone step.
2. **Real chunks.** `jw.sweep` of an 8 × 8 Fig. 3 grid (one chunk of 64, `fast`, t1)
   against the same 64 gaits solved one by one with `jw.simulate`: the gain a sweep
   delivers. Both readings of the window: as printed (no cracks) and mirrored
   (δ → −δ, cracks every ~2 s).
3. **Where the lanes wait.** In a chunk every lane steps until the slowest is done.
   Step imbalance is the chunk's mean steps per lane over its most; what is left
   between the ceiling times that and the real gain is the adaptive loop's share. The
   chunk runs each lane as one loop of steps with its cracks inside; the same gaits as
   one vmapped `jw.simulate` (a scan of crack segments, each waiting for the lane with
   the longest) show what that loop saves.
4. **The whole sweep, as a user runs it.** `jw.sweep` of the 21 × 21 Fig. 3 grid over
   60 s with its defaults (every core, default chunks), warm, against lone `jw.simulate`
   of every `--every`-th gait of the same grid (compiled once, one at a time), scaled to
   the grid: the per-core gain is the lone solves' time over the cores times the
   sweep's wall time, and (by CPU time) the lone solves' CPU time over the sweep's.
   With the chunks as the sweep cuts them (grid order), the step imbalance of the whole
   sweep, and what chunks sorted by their steps (known only after the run) would have.

A chunk alone on an otherwise idle machine (2.) may take a second core: XLA's CPU
runtime hands a loop body past 512-byte buffers to its thread pool
(`loop_buffers.py`); its CPU time is reported beside the wall time. In the whole
sweep every core is busy with its own chunk.

    python benchmarks/batch_gain.py             # t1 = 20 s
    python benchmarks/batch_gain.py --t1 60

Writes results/batch_gain/batch_gain[_t1_X].{json,md}.
"""

from __future__ import annotations

import os

os.environ["XLA_FLAGS"] = "--xla_force_host_platform_device_count=1"

import argparse  # noqa: E402
import time  # noqa: E402

import _bench as B  # noqa: E402
import diffrax  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import jaxworm as jw  # noqa: E402
from jaxworm.paper import paper_grid  # noqa: E402

STEPS = 1000
SPAN = 2.0


def _best(fn, *args, repeats=15):
    """The fastest of `repeats` warm calls (a lockstep solve takes milliseconds, and one
    call's time on a shared virtual machine varies by half)."""
    jax.block_until_ready(fn(*args))
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - start)
    return min(times)


def lockstep(params_of, num):
    """run(ω): x_1 after `STEPS` fixed Rodas4 steps over `SPAN` s of `params_of(ω)`, no
    events (the ceiling's solve; vmap it for a batch)."""

    def run(omega):
        p = params_of(omega)
        y0 = jw.initial_state(p)
        sol = diffrax.diffeqsolve(
            diffrax.ODETerm(jw.vector_field),
            num.build_solver(),
            0.0,
            SPAN,
            SPAN / STEPS,
            y0,
            args=(p, jw.initial_crack_tip(p, y0)),
            stepsize_controller=diffrax.ConstantStepSize(),
            max_steps=STEPS + 1,
            throw=False,
            saveat=diffrax.SaveAt(t1=True),
        )
        assert sol.ys is not None
        return sol.ys.x[-1, 0]

    return run


def ceiling(batches) -> list[dict]:
    num = jw.PRESETS["fast"]
    p0 = jw.Params()
    run = lockstep(lambda omega: p0.replace(omega=omega), num)
    lone = _best(jax.jit(run), jnp.array(4 * np.pi))
    # Batches solve as `jw.sweep`'s chunks do: the linear solve written for lanes.
    lanes = num.replace(linear_solve="structured_lanes")
    rows = []
    for b in batches:
        omegas = jnp.linspace(3 * np.pi, 5 * np.pi, b)
        run_lanes = lockstep(lambda omega: p0.replace(omega=omega), lanes)
        batch = _best(jax.jit(jax.vmap(run_lanes)), omegas)
        rows.append(
            {
                "batch": b,
                "lone_us_per_step": lone / STEPS * 1e6,
                "lane_us_per_step": batch / b / STEPS * 1e6,
                "gain": lone * b / batch,
            }
        )
        B.log(str(rows[-1]))
    return rows


def chunk(t1: float, sign: float) -> dict:
    grid = paper_grid(8, delta_sign=sign)
    dev = jax.devices()[:1]

    def swept():
        return jw.sweep(grid, t1=t1, chunk=64, progress=False, devices=dev)

    swept()
    start, cpu = time.perf_counter(), time.process_time()
    s = swept()
    batch, batch_cpu = time.perf_counter() - start, time.process_time() - cpu
    p = jw.Params()
    om, de = np.meshgrid(grid["omega"], grid["delta"], indexing="ij")
    jax.block_until_ready(jw.simulate(p.replace(omega=om.flat[0], delta=de.flat[0]), t1))
    start = time.perf_counter()
    for o, d in zip(om.ravel(), de.ravel()):
        jax.block_until_ready(jw.simulate(p.replace(omega=o, delta=d), t1))
    lone = time.perf_counter() - start
    # The same 64 gaits as one vmapped `jw.simulate`: its scan of crack segments, where
    # every lane waits at each segment for the lane with the longest (same linear solve
    # as the sweep's chunks, so that only the loop differs).
    lanes = jw.PRESETS["fast"].replace(linear_solve="structured_lanes")
    scan = jax.jit(
        jax.vmap(lambda o, d: jw.simulate(p.replace(omega=o, delta=d), t1, lanes).mean_velocity)
    )
    o64, d64 = jnp.asarray(om.ravel()), jnp.asarray(de.ravel())
    jax.block_until_ready(scan(o64, d64))
    start, cpu = time.perf_counter(), time.process_time()
    v_scan = np.asarray(jax.block_until_ready(scan(o64, d64)))
    segments, segments_cpu = time.perf_counter() - start, time.process_time() - cpu
    steps = np.asarray(s["steps"]).ravel()
    cracks = np.asarray(s["n_cracks"]).ravel()
    v = np.asarray(s["mean_velocity"]).ravel()
    return {
        "segments_s": segments,
        "segments_cpu_s": segments_cpu,
        "loop_gain": segments / batch,
        "loop_max_rel_diff_v": float(np.max(np.abs(v / v_scan - 1))),
        "reading": "as printed" if sign > 0 else "mirrored",
        "batch_s": batch,
        "batch_cpu_s": batch_cpu,
        "lone_s": lone,
        "gain": lone / batch,
        "steps_mean": steps.mean(),
        "steps_max": int(steps.max()),
        "imbalance": steps.mean() / steps.max(),
        "cracks_min": int(cracks.min()),
        "cracks_max": int(cracks.max()),
        "all_ok": bool(np.all(np.asarray(s["status"]) == 0)),
    }


def whole_sweep(every: int) -> dict:
    """Section 4: the Fig. 3 sweep with `jw.sweep`'s defaults against lone solves."""
    grid = paper_grid(21)
    t1 = 60.0
    jw.sweep(grid, t1=t1, progress=False)  # compiles
    start, cpu = time.perf_counter(), time.process_time()
    s = jw.sweep(grid, t1=t1, progress=False)
    wall, sweep_cpu = time.perf_counter() - start, time.process_time() - cpu
    om, de = np.meshgrid(grid["omega"], grid["delta"], indexing="ij")
    points = list(zip(om.ravel(), de.ravel()))[::every]
    solve = jax.jit(lambda o, d: jw.simulate(jw.Params().replace(omega=o, delta=d), t1))
    jax.block_until_ready(solve(*points[0]))
    lone = lone_cpu = 0.0
    for o, d in points:
        start, cpu = time.perf_counter(), time.process_time()
        jax.block_until_ready(solve(o, d))
        lone += time.perf_counter() - start
        lone_cpu += time.process_time() - cpu
    scale = om.size / len(points)
    cores = B.cores()
    steps = np.asarray(s["steps"]).ravel().astype(float)
    # One CPU device (XLA_FLAGS above): the sweep's default workers are the cores.
    size = jw.default_chunk(om.size, cores, t1, jw.PRESETS["fast"])

    def imbalance(order):
        chunks = [order[i : i + size] for i in range(0, order.size, size)]
        return order.sum() / sum(c.size * c.max() for c in chunks)

    return {
        "gaits": om.size,
        "t1": t1,
        "cores": cores,
        "chunk": size,
        "sweep_s": wall,
        "sweep_cpu_s": sweep_cpu,
        "lone_gaits": len(points),
        "lone_s": lone,
        "lone_cpu_s": lone_cpu,
        "lone_all_s": lone * scale,
        "gain_per_core": lone * scale / (cores * wall),
        "gain_per_core_cpu": lone_cpu * scale / sweep_cpu,
        "imbalance": imbalance(steps),
        "imbalance_sorted": imbalance(np.sort(steps)),
        "all_ok": bool(np.all(np.asarray(s["status"]) == 0)),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--t1", type=float, default=20.0, help="horizon of the chunks [s]")
    ap.add_argument("--every", type=int, default=4, help="lone solves of every k-th gait")
    args = ap.parse_args()
    rows = ceiling((1, 8, 64, 256))
    chunks = [chunk(args.t1, 1.0), chunk(args.t1, -1.0)]
    for c in chunks:
        B.log(str(c))
    at64 = next(r["gain"] for r in rows if r["batch"] == 64)
    for c in chunks:
        c["ceiling_x_imbalance"] = at64 * c["imbalance"]
    whole = whole_sweep(args.every)
    B.log(str(whole))
    out = {"t1": args.t1, "ceiling": rows, "chunks": chunks, "sweep": whole}
    stem = "batch_gain" + ("" if args.t1 == 20.0 else f"_t1_{args.t1:g}")
    folder = B.results_dir("batch_gain")
    B.write_json(folder / f"{stem}.json", out)
    run = B.run_record()
    lines = [
        f"# What a vmapped batch buys on one core (t1 = {args.t1:g} s)",
        "",
        f"`{run['command']}` on {run['machine']}, one JAX CPU device, {run['date']}, "
        f"load {run['load'][0]:.1f} at start.",
        "",
        "## The ceiling: lockstep fixed steps (no events, no rejections)",
        "",
    ]
    lines += B.md_table(
        ["batch B", "lone µs/step", "per-lane µs/step in the batch", "gain"],
        [
            [
                r["batch"],
                f"{r['lone_us_per_step']:.2f}",
                f"{r['lane_us_per_step']:.2f}",
                f"{r['gain']:.2f}",
            ]
            for r in rows
        ],
    )
    lines += [
        "",
        "## Real chunks: one `jw.sweep` chunk of 64 against 64 lone `jw.simulate`",
        "",
        "The chunk runs each lane as one loop of steps, its cracks inside it. The scan of "
        "segments is the same 64 gaits as one vmapped `jw.simulate` (same linear solve), "
        "whose lanes wait at every crack segment for the longest: step loop gain is its "
        "time over the chunk's; max Δv̄/v̄ the largest relative difference of their mean "
        "velocities (rounding: a lone run is bit-identical in both loops).",
        "",
    ]
    lines += B.md_table(
        [
            "reading",
            "cracks",
            "chunk s (CPU s)",
            "64 lone s",
            "gain",
            "steps mean/max",
            "ceiling(64) × imbalance",
            "scan of segments s (CPU s)",
            "step loop gain",
            "max Δv̄/v̄",
            "all ok",
        ],
        [
            [
                c["reading"],
                f"{c['cracks_min']}–{c['cracks_max']}",
                f"{c['batch_s']:.2f} ({c['batch_cpu_s']:.2f})",
                f"{c['lone_s']:.2f}",
                f"{c['gain']:.2f}",
                f"{c['imbalance']:.2f}",
                f"{c['ceiling_x_imbalance']:.2f}",
                f"{c['segments_s']:.2f} ({c['segments_cpu_s']:.2f})",
                f"{c['loop_gain']:.2f}",
                f"{c['loop_max_rel_diff_v']:.1e}",
                c["all_ok"],
            ]
            for c in chunks
        ],
    )
    w = whole
    lines += [
        "",
        f"## The whole sweep: `jw.sweep` of the 21 × 21 Fig. 3 grid over 60 s, defaults, warm, "
        f"on {w['cores']} cores",
        "",
        f"Lone `jw.simulate` of every {args.every}th gait ({w['lone_gaits']}), scaled to "
        f"{w['gaits']}. Target (issue 20): a per-core gain of 3.",
        "",
    ]
    lines += B.md_table(
        ["sweep s (CPU s)", "lone s, all gaits (est.)", "per-core gain", "by CPU time",
         f"imbalance, chunks of {w['chunk']} in grid order", "sorted by steps", "all ok"],
        [[f"{w['sweep_s']:.2f} ({w['sweep_cpu_s']:.2f})", f"{w['lone_all_s']:.1f}",
          f"{w['gain_per_core']:.2f}", f"{w['gain_per_core_cpu']:.2f}",
          f"{w['imbalance']:.3f}", f"{w['imbalance_sorted']:.3f}", w["all_ok"]]],
    )  # fmt: skip
    (folder / f"{stem}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()

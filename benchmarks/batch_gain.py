"""What a vmapped batch buys on one CPU core, and where its lanes wait.

Three measurements in one process, on one JAX CPU device (one core):

1. **The ceiling.** Table 1 stepped in lockstep: a fixed step (1000 Rodas4 steps over
   2 s, no events, no rejected steps), as one lone solve and as vmapped batches of B
   gaits. Every lane takes the same steps, so the batch gain here is what vmap can give
   at best: the per-lane cost of one step in a batch of B against a lone step.
2. **Real chunks.** `jw.sweep` of an 8 × 8 Fig. 3 grid (one chunk of 64, `fast`, t1)
   against the same 64 gaits solved one by one with `jw.simulate`: the gain a sweep
   delivers. Both readings of the window: as printed (no cracks) and mirrored
   (δ → −δ, cracks every ~2 s).
3. **Where the lanes wait.** In a chunk every lane steps until the slowest is done, and
   each crack segment waits for the lane with the longest one. Step imbalance is the
   chunk's mean steps per lane over its most; what is left between the ceiling times
   that and the real gain is the segments' and the adaptive loop's share.

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


def _best(fn, *args, repeats=3):
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
    start = time.perf_counter()
    s = swept()
    batch = time.perf_counter() - start
    p = jw.Params()
    om, de = np.meshgrid(grid["omega"], grid["delta"], indexing="ij")
    jax.block_until_ready(jw.simulate(p.replace(omega=om.flat[0], delta=de.flat[0]), t1))
    start = time.perf_counter()
    for o, d in zip(om.ravel(), de.ravel()):
        jax.block_until_ready(jw.simulate(p.replace(omega=o, delta=d), t1))
    lone = time.perf_counter() - start
    steps = np.asarray(s["steps"]).ravel()
    cracks = np.asarray(s["n_cracks"]).ravel()
    return {
        "reading": "as printed" if sign > 0 else "mirrored",
        "batch_s": batch,
        "lone_s": lone,
        "gain": lone / batch,
        "steps_mean": steps.mean(),
        "steps_max": int(steps.max()),
        "imbalance": steps.mean() / steps.max(),
        "cracks_min": int(cracks.min()),
        "cracks_max": int(cracks.max()),
        "all_ok": bool(np.all(np.asarray(s["status"]) == 0)),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--t1", type=float, default=20.0, help="horizon of the chunks [s]")
    args = ap.parse_args()
    rows = ceiling((1, 8, 64, 256))
    chunks = [chunk(args.t1, 1.0), chunk(args.t1, -1.0)]
    for c in chunks:
        B.log(str(c))
    at64 = next(r["gain"] for r in rows if r["batch"] == 64)
    for c in chunks:
        c["ceiling_x_imbalance"] = at64 * c["imbalance"]
    out = {"t1": args.t1, "ceiling": rows, "chunks": chunks}
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
    lines += ["", "## Real chunks: one `jw.sweep` chunk of 64 against 64 lone `jw.simulate`", ""]
    lines += B.md_table(
        [
            "reading",
            "cracks",
            "chunk s",
            "64 lone s",
            "gain",
            "steps mean/max",
            "ceiling(64) × imbalance",
            "all ok",
        ],
        [
            [
                c["reading"],
                f"{c['cracks_min']}–{c['cracks_max']}",
                f"{c['batch_s']:.2f}",
                f"{c['lone_s']:.2f}",
                f"{c['gain']:.2f}",
                f"{c['imbalance']:.2f}",
                f"{c['ceiling_x_imbalance']:.2f}",
                c["all_ok"],
            ]
            for c in chunks
        ],
    )
    (folder / f"{stem}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()

"""Issue 15, point 7: one invalid lane must cost its batch nothing.

    python benchmarks/bad_lane.py [--lanes 256] [--t1 0.5] [--repeats 3]

A batch of `--lanes` gaits (ω over [3π, 5π], δ = π/4, preset `fast` with max_steps =
2**14, as the issue measured) is solved clean, then with lane 0 set to ω = NaN, ω = 0
and (traced) t1 = −1. Each batch is one compiled `vmap`; the fastest of `--repeats`
calls is kept. Checks: the bad lane ends `invalid_parameters` after 0 steps, every other
lane is bit-identical to the clean batch, and the bad batch's time is within 1.2x the
clean one's. Writes `results/bad_lane/bad_lane.{json,md}`.
"""

from __future__ import annotations

import argparse
import sys
import time

import _bench as B  # (first: sets the BLAS threads before numpy loads)
import equinox as eqx  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

jw = B.jw


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lanes", type=int, default=256)
    ap.add_argument("--t1", type=float, default=0.5)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args(argv)
    numerics = jw.PRESETS["fast"].replace(max_steps=2**14)
    base = jw.Params()

    def one(omega, t1):
        return jw.simulate(base.replace(omega=omega), t1, numerics)

    fn = eqx.filter_jit(jax.vmap(one))
    omegas = jnp.linspace(3 * np.pi, 5 * np.pi, args.lanes)
    t1s = jnp.full(args.lanes, args.t1)
    start = time.perf_counter()
    clean = jax.block_until_ready(fn(omegas, t1s))
    compile_s = time.perf_counter() - start

    def timed(o, t):
        walls = []
        for _ in range(args.repeats):
            start = time.perf_counter()
            r = jax.block_until_ready(fn(o, t))
            walls.append(time.perf_counter() - start)
        return r, walls

    def timed_once(o, t):
        start = time.perf_counter()
        r = jax.block_until_ready(fn(o, t))
        return r, time.perf_counter() - start

    clean, clean_walls = timed(omegas, t1s)
    rows = []
    others = np.arange(args.lanes) != 0
    for label, o, t in (
        ("omega = NaN", omegas.at[0].set(jnp.nan), t1s),
        ("omega = 0", omegas.at[0].set(0.0), t1s),
        ("t1 = -1 (traced)", omegas, t1s.at[0].set(-1.0)),
    ):
        # clean and bad calls alternate, so that a shared machine's load hits both alike
        walls, clean_here = [], []
        for _ in range(args.repeats):
            r, w = timed_once(o, t)
            walls.append(w)
            clean_here.append(timed_once(omegas, t1s)[1])
        clean_walls += clean_here
        identical = all(
            np.array_equal(np.asarray(a)[others], np.asarray(b)[others], equal_nan=True)
            for a, b in zip(jax.tree_util.tree_leaves(r), jax.tree_util.tree_leaves(clean))
        )
        ratio = min(walls) / min(clean_here)
        rows.append(
            {
                "bad lane": label,
                "status": str(jw.status_name(r.status[0])),
                "steps": int(r.steps[0]),
                "others_bit_identical": bool(identical),
                "wall_s": min(walls),
                "walls_s": walls,
                "clean_wall_s": min(clean_here),
                "clean_walls_s": clean_here,
                "ratio_to_clean": ratio,
                "within_1.2x": bool(ratio <= 1.2),
            }
        )
    out = {
        "machine": B.machine_info(),
        "lanes": args.lanes,
        "t1": args.t1,
        "max_steps": numerics.max_steps,
        "compile_and_first_call_s": compile_s,
        "clean_wall_s": min(clean_walls),
        "clean_walls_s": clean_walls,
        "clean_statuses": {
            str(k): int(v)
            for k, v in zip(
                *np.unique(np.asarray(jw.status_name(clean.status)), return_counts=True)
            )
        },
        "rows": rows,
    }
    folder = B.results_dir("bad_lane")
    B.write_json(folder / "bad_lane.json", out)
    m = out["machine"]
    lines = [
        f"# One bad lane in a batch of {args.lanes} (t1 = {args.t1:g} s, fast, max_steps = 2**14)",
        "",
        B.machine_line(m),
        "",
        f"Command: `python benchmarks/bad_lane.py --lanes {args.lanes} --t1 {args.t1:g} "
        f"--repeats {args.repeats}`. Fastest of {args.repeats} calls after compilation.",
        "",
        f"Clean batch: {out['clean_wall_s']:.3f} s (statuses {out['clean_statuses']}).",
        "",
        "Each bad batch alternates with a clean one; the ratio is of the fastest of each.",
        "",
        "| bad lane | its status | its steps | other lanes bit-identical | wall s | clean wall s "
        "| ratio to clean |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['bad lane']} | {r['status']} | {r['steps']} | "
            f"{r['others_bit_identical']} | {r['wall_s']:.3f} | {r['clean_wall_s']:.3f} | "
            f"{r['ratio_to_clean']:.3f} |"
        )
    (folder / "bad_lane.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return (
        0
        if all(r["within_1.2x"] and r["others_bit_identical"] and r["steps"] == 0 for r in rows)
        else 1
    )


if __name__ == "__main__":
    sys.exit(main())

"""Core targets of issue 2: a 60-s nominal simulation after compilation, and the first
compilation, with the error of the timed run against a tight solve of the same scene.

    python benchmarks/core_timing.py [--t1 60] [--reference accurate|reference] [--repeats 3]

Writes benchmarks/results/core_timing/core_timing.{json,md}. Timings are wall-clock on whatever
machine runs it (recorded in the output); the persistent compilation cache is off so
that "first compilation" is real.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
import statistics
import time
from datetime import UTC, datetime

import jax

jax.config.update("jax_enable_compilation_cache", False)

from _results import results_dir, write_json  # noqa: E402

import jaxworm as jw  # noqa: E402


def _timed(params, t1, numerics):
    t = time.perf_counter()
    r = jw.simulate(params, t1, numerics)
    jax.block_until_ready(r.final.x)
    return r, time.perf_counter() - t


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--t1", type=float, default=60.0)
    ap.add_argument("--reference", default="accurate", choices=sorted(jw.PRESETS))
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args(argv)

    rows = []
    for scene, delta in (("nominal (δ = π/4)", math.pi / 4), ("forward (δ = −π/4)", -math.pi / 4)):
        p = jw.Params().replace(delta=delta)
        scene_rows = []
        for name in ("default", "fast", "accurate"):
            num = jw.PRESETS[name]
            first, t_first = _timed(p, args.t1, num)
            runs = [_timed(p, args.t1, num)[1] for _ in range(args.repeats)]
            scene_rows.append(
                {
                    "scene": scene,
                    "preset": name,
                    "first_call_s": t_first,
                    "run_s": statistics.median(runs),
                    "runs_s": runs,
                    "mean_velocity": float(first.mean_velocity),
                    "n_cracks": int(first.n_cracks),
                    "steps": int(first.steps),
                    "energy_residual": float(first.energy_residual),
                    "status": str(first.status_name),
                }
            )
        ref = next((r for r in scene_rows if r["preset"] == args.reference), None)
        if ref is None:
            r, t = _timed(p, args.t1, jw.PRESETS[args.reference])
            ref = {"mean_velocity": float(r.mean_velocity)}
        for row in scene_rows:
            row["error_vs_reference"] = abs(row["mean_velocity"] / ref["mean_velocity"] - 1.0)
        rows += scene_rows

    out = {
        "scene": f"Table 1, t1 = {args.t1} s",
        "reference": args.reference,
        "machine": {
            "platform": platform.platform(),
            "processor": platform.processor(),
            "cpus": os.cpu_count(),
            "jax": jax.__version__,
            "device": str(jax.devices()[0]),
        },
        "date": datetime.now(UTC).isoformat(timespec="seconds"),
        "rows": rows,
    }
    folder = results_dir("core_timing")
    write_json(folder / "core_timing.json", out, indent=2)
    lines = [
        f"# Core timing: {out['scene']}",
        "",
        f"Machine: {out['machine']['platform']}, {out['machine']['cpus']} CPUs, "
        f"jax {out['machine']['jax']}; {out['date']}. Reference: `{args.reference}` preset.",
        "",
        "| scene | preset | first call (compile + run) s | run after compile s | mean velocity m/s "
        "| error vs reference | cracks | steps | energy residual | status |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['scene']} | {r['preset']} | {r['first_call_s']:.1f} | {r['run_s']:.2f} | "
            f"{r['mean_velocity']:.6g} | {r['error_vs_reference']:.1e} | {r['n_cracks']} | "
            f"{r['steps']} | {r['energy_residual']:.1e} | {r['status']} |"
        )
    (folder / "core_timing.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()

"""Fig. 3 at 21 × 21 gaits × 60 s on this machine's CPU cores: wall time, memory, error.

Issue 3's target is ≤ 30 s on the 2-core machine. The sweep runs as `jaxworm paper`
runs it: `jw.sweep` with the `fast` preset on JAX's one CPU device, one worker (a
thread solving one vmapped chunk at a time) per core. Measured in the same run:

- the anchor: the same grid with ONE worker (one core), so the gain from the cores is
  a ratio measured side by side;
- the error: a sample of the grid's gaits solved again with the `accurate` preset
  (Kvaerno5, atol 1e-10 m), one at a time; the sweep's error is the largest relative
  difference in mean velocity (|v| floor 1e-4 m/s, as in the work-precision study);
- peak memory: the process's peak resident set during the timed sweep (the kernel's
  high-water mark reset just before it), JAX and Python included.

    python benchmarks/sweep_throughput.py            # 21 × 21 × 60 s (a few minutes)
    python benchmarks/sweep_throughput.py --quick    # 7 × 7 × 10 s

Writes benchmarks/results/sweep_throughput/sweep_throughput[_quick].{json,md}.
"""

from __future__ import annotations

import argparse
import time

import _bench as B
import jax
import numpy as np

import jaxworm as jw
from jaxworm.paper import paper_grid

_CORES = B.cores()


def _timed_sweep(grid, t1, workers):
    """Compile (a throw-away run on a 1-s horizon would not share the program: t1 is
    static in the chunk), then time a second, identical sweep."""
    start = time.perf_counter()
    jw.sweep(grid, t1=t1, progress=False, workers=workers)
    first = time.perf_counter() - start
    B.reset_peak_rss()
    start = time.perf_counter()
    s = jw.sweep(grid, t1=t1, progress=False, workers=workers)
    wall = time.perf_counter() - start
    return s, wall, first - wall, B.peak_rss_mb()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    size, t1, n_check = (7, 10.0, 4) if args.quick else (21, 60.0, 8)
    folder = B.results_dir("sweep_throughput")
    quick = B.quick_suffix(args.quick)
    info = B.machine_info()
    info["devices"] = [str(d) for d in jax.devices()]
    grid = paper_grid(size)
    n = size * size

    s_all, wall_all, compile_all, mem_all = _timed_sweep(grid, t1, None)
    s_one, wall_one, compile_one, mem_one = _timed_sweep(grid, t1, 1)
    assert np.array_equal(s_all["n_cracks"], s_one["n_cracks"])

    # Error: a spread sample of the grid, solved one at a time with `accurate`.
    rng = np.random.default_rng(0)
    picks = rng.choice(n, size=n_check, replace=False)
    errors = []
    for k in picks:
        i, j = np.unravel_index(k, (size, size))
        p = jw.Params().replace(omega=float(grid["omega"][i]), delta=float(grid["delta"][j]))
        ref = jw.simulate(p, t1, jw.PRESETS["accurate"])
        v, v_ref = float(s_all["mean_velocity"][i, j]), float(ref.mean_velocity)
        errors.append(
            {
                "omega": float(grid["omega"][i]),
                "delta": float(grid["delta"][j]),
                "mean_velocity": v,
                "accurate": v_ref,
                "status": ref.status_name,
                "error": B.rel_error(v, v_ref),
            }
        )
    worst = max(e["error"] for e in errors)
    ok = int((s_all["status"] == 0).sum())
    row = {
        "grid": f"{size} x {size}",
        "t1_s": t1,
        "preset": "fast",
        "scenes_ok": ok,
        "devices": len(jax.devices()),
        "workers": _CORES,
        "wall_s_all_workers": wall_all,
        "compile_s_all_workers": compile_all,
        "wall_s_one_worker": wall_one,
        "compile_s_one_worker": compile_one,
        "speedup_cores": wall_one / wall_all,
        "simulated_s_per_wall_s": n * t1 / wall_all,
        "peak_rss_mb": mem_all,
        "peak_rss_mb_one_worker": mem_one,
        "max_error_vs_accurate": worst,
        "error_sample": errors,
        "target_s": 30.0 if not args.quick else None,
    }
    B.write_json(folder / f"sweep_throughput{quick}.json", {"machine": info, **row}, indent=2)
    lines = [
        f"# Fig. 3 sweep throughput ({size} × {size} gaits × {t1:g} s)",
        "",
        f"Machine: {info['cpu']}, {info['cpus']} CPUs, jax {info['jax']}; {info['date']}; "
        f"load at start {info['load_average_at_start']}. Preset `fast` (Rodas4), "
        f"`jw.sweep` default chunks, one JAX device.",
        "",
        "| workers (cores) | wall s | compile s | simulated s / wall s | peak RSS MB | scenes ok |",
        "|---|---|---|---|---|---|",
        f"| {_CORES} | {wall_all:.1f} | {compile_all:.1f} | "
        f"{n * t1 / wall_all:.0f} | {mem_all:.0f} | {ok}/{n} |",
        f"| 1 | {wall_one:.1f} | {compile_one:.1f} | {n * t1 / wall_one:.0f} | {mem_one:.0f} | |",
        "",
        f"Cores: {wall_one / wall_all:.2f}× faster than one. Error against `accurate` on "
        f"{n_check} gaits of the grid: max {worst:.1e} (relative, mean velocity).",
    ]
    if not args.quick:
        lines.append(f"Target ≤ 30 s: {'MET' if wall_all <= 30 else 'MISSED'} ({wall_all:.1f} s).")
    (folder / f"sweep_throughput{quick}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()

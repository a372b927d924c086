"""The cost of a sweep chunk, for `jaxworm.sweep`'s default chunk size (`jw.default_chunk`).

A killed sweep loses the chunks in flight, so a default chunk must stay within ~10 s of
compute (`jw.CHUNK_SECONDS`). A chunk of c scenes over t1 seconds costs about

    T(c, t1) ≈ t1 (a + b c)      [s, one core]

(a: the per-step work the lanes of a `vmap` share; b: each lane's own; `jw.CHUNK_COST`).
This script measures T as users meet it: `jw.sweep` of a grid of exactly c scenes with
`chunk=c` on one device and no file, for c = 1, 8, 32 gaits of the Fig. 3 grid (ω = 3π …
5π, 5π in every chunk: the 5π lanes take the most steps), per preset, as the process's
CPU time (on a shared machine wall times measure the neighbours too; the chunk runs on
one core), fastest of 2 runs after a first that compiles, and fits a and b (least
squares on T/t1). It then checks the model where it matters: the default Fig. 3 sweep
(21 × 21 × 60 s, `fast`, one chunk per core, default chunk), timed without a file and
with one (`path`: every finished chunk saved at once); the difference is the cost of
the saves.

    python benchmarks/sweep_chunks.py            # all presets, then the Fig. 3 check
    python benchmarks/sweep_chunks.py --quick    # fast only, 7 x 7 x 10 s check

Writes benchmarks/results/sweep_chunks/sweep_chunks[_quick].{json,md}.
"""

from __future__ import annotations

import os

import _results as R

_CORES = R.cores()
os.environ.setdefault("XLA_FLAGS", f"--xla_force_host_platform_device_count={_CORES}")

import argparse  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import _bench as B  # noqa: E402
import jax  # noqa: E402
import numpy as np  # noqa: E402

import jaxworm as jw  # noqa: E402
from jaxworm.paper import paper_grid  # noqa: E402

#: Horizon [s] of the fit, per preset: long enough that the start is not all of it.
FIT_T1 = {"fast": 20.0, "default": 5.0, "accurate": 1.0}
SIZES = (1, 8, 32)


def _grid(c: int) -> dict[str, np.ndarray]:
    """A grid of c gaits of the Fig. 3 grid, n_ω × n_δ (n_δ the largest divisor of c with
    n_δ² ≤ c): ω spread from 5π (the most steps) down, δ spread over its range (the
    middle δ when n_δ = 1)."""
    g = paper_grid(21)
    n_d = max(d for d in range(1, c + 1) if c % d == 0 and d * d <= c)
    omega = g["omega"][::-1][np.linspace(0, 20, c // n_d).round().astype(int)]
    delta = g["delta"][np.linspace(0, 20, n_d).round().astype(int) if n_d > 1 else [10]]
    return {"omega": omega, "delta": delta}


def _timed_sweep(grid, **kw) -> tuple[jw.SweepResult, float, float]:
    """`jw.sweep(grid, **kw)` without progress: (result, wall s, process CPU s)."""
    start, cpu = time.perf_counter(), time.process_time()
    s = jw.sweep(grid, progress=False, **kw)
    return s, time.perf_counter() - start, time.process_time() - cpu


def fit(preset: str) -> dict:
    t1 = FIT_T1[preset]
    numerics = jw.PRESETS[preset]
    one = jax.devices()[:1]
    rows = []
    for c in SIZES:
        grid = _grid(c)
        kw = {"t1": t1, "numerics": numerics, "chunk": c, "devices": one}
        _timed_sweep(grid, **kw)  # compile
        runs = [_timed_sweep(grid, **kw) for _ in range(2)]
        rows.append(
            {
                "chunk": c,
                "grid": {k: v.tolist() for k, v in grid.items()},
                "t1_s": t1,
                "cpu_s": min(r[2] for r in runs),
                "wall_s": min(r[1] for r in runs),
                "cpus_s": [r[2] for r in runs],
                "walls_s": [r[1] for r in runs],
                "scenes_ok": int((runs[-1][0].status == 0).sum()),
            }
        )
        print(preset, rows[-1], flush=True)
    A = np.array([[1.0, r["chunk"]] for r in rows])
    y = np.array([r["cpu_s"] / r["t1_s"] for r in rows])
    (a, b), *_ = np.linalg.lstsq(A, y, rcond=None)
    if a < 0:  # no shared work to speak of: through the origin
        c = A[:, 1]
        a, b = 0.0, float((c * y).sum() / (c * c).sum())
    return {"preset": preset, "a": float(a), "b": float(b), "runs": rows}


def check(size: int, t1: float, repeats: int) -> dict:
    """The default sweep of a size x size Fig. 3 grid on every device, without a file and
    with one (`path`), `repeats` times each in turn after a first that compiles: wall and
    CPU times; the saves' cost is the difference of the fastest runs."""
    grid = paper_grid(size)
    d = len(jax.devices())
    with tempfile.TemporaryDirectory() as tmp:
        _timed_sweep(grid, t1=t1)  # compile
        plain, saved = [], []
        for k in range(repeats):
            plain.append(_timed_sweep(grid, t1=t1))
            saved.append(_timed_sweep(grid, t1=t1, path=Path(tmp) / f"s{k}.npz"))
    s = saved[-1][0]
    chunk = s.header["chunk"]
    chunks = -(-grid["omega"].size * grid["delta"].size // chunk)
    rounds = -(-chunks // d)
    wall, cpu = min(r[1] for r in plain), min(r[2] for r in plain)
    wall_saved, cpu_saved = min(r[1] for r in saved), min(r[2] for r in saved)
    return {
        "grid": f"{size} x {size}",
        "t1_s": t1,
        "devices": d,
        "chunk": chunk,
        "default_chunk": jw.default_chunk(size * size, d, t1, jw.PRESETS["fast"]),
        "chunks": chunks,
        "rounds": rounds,
        "walls_s": [r[1] for r in plain],
        "cpus_s": [r[2] for r in plain],
        "walls_with_path_s": [r[1] for r in saved],
        "cpus_with_path_s": [r[2] for r in saved],
        "wall_s": wall,
        "cpu_s": cpu,
        "wall_with_path_s": wall_saved,
        "cpu_with_path_s": cpu_saved,
        "chunk_cpu_s": cpu / chunks,
        "round_wall_s": wall / rounds,
        "save_wall_s": wall_saved - wall,
        "save_wall_per_chunk_s": (wall_saved - wall) / chunks,
        "scenes_ok": int((s.status == 0).sum()),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    folder = B.results_dir("sweep_chunks")
    quick = B.quick_suffix(args.quick)
    info = B.machine_info()
    presets = ("fast",) if args.quick else ("fast", "default", "accurate")
    fits = [fit(p) for p in presets]
    c = check(7, 10.0, repeats=3) if args.quick else check(21, 60.0, repeats=2)
    print(c, flush=True)
    B.write_json(
        folder / f"sweep_chunks{quick}.json",
        {
            "machine": info,
            "chunk_seconds": jw.CHUNK_SECONDS,
            "chunk_cost": jw.CHUNK_COST,
            "fits": fits,
            "check": c,
        },
        indent=2,
    )
    lines = [
        "# Sweep chunks: cost model and chunk times",
        "",
        f"Machine: {info['cpu']}, {info['cpus']} CPUs, jax {info['jax']}; {info['date']}; "
        f"load at start {info['load_average_at_start']}. One core per chunk.",
        "",
        "T(c, t1) ≈ t1 (a + b c) [s], fitted on c = "
        + ", ".join(map(str, SIZES))
        + " gaits of the Fig. 3 grid (5π in each), T the CPU time of `jw.sweep` of those c "
        "scenes with `chunk=c` on one device:",
        "",
        "| preset | t1 s | CPU s at c = " + " / ".join(map(str, SIZES)) + " | wall s | a [s/s] | "
        "b [s/s/lane] |",
        "|---|---|---|---|---|---|",
    ]
    for f in fits:
        lines.append(
            f"| {f['preset']} | {f['runs'][0]['t1_s']:g} | "
            + " / ".join(f"{r['cpu_s']:.2f}" for r in f["runs"])
            + " | "
            + " / ".join(f"{r['wall_s']:.2f}" for r in f["runs"])
            + f" | {f['a']:.3g} | {f['b']:.3g} |"
        )
    fast = next(f for f in fits if f["preset"] == "fast")
    a, b = jw.CHUNK_COST["fast"]
    lines += [
        "",
        "`jw.CHUNK_COST` (the model `jw.default_chunk` uses, from an earlier run of this "
        "script): "
        + ", ".join(f"{k} a = {a:.3g}, b = {b:.3g}" for k, (a, b) in jw.CHUNK_COST.items())
        + f"; target `jw.CHUNK_SECONDS` = {jw.CHUNK_SECONDS:g} s.",
        "",
        f"Check, the default sweep of {c['grid']} gaits × {c['t1_s']:g} s (`fast`, "
        f"{c['devices']} devices, default chunk {c['chunk']}, {c['chunks']} chunks in "
        f"{c['rounds']} rounds, {c['scenes_ok']} ok), fastest of {len(c['walls_s'])}: "
        f"without a file {c['wall_s']:.1f} s wall, {c['cpu_s']:.1f} CPU s, so "
        f"{c['chunk_cpu_s']:.1f} CPU s per chunk on average (the model, for a chunk of "
        f"{c['chunk']} with a 5π lane: {c['t1_s'] * (a + b * c['chunk']):.1f} s by "
        f"`jw.CHUNK_COST`, {c['t1_s'] * (fast['a'] + fast['b'] * c['chunk']):.1f} s by this "
        f"run's fit; target ≤ {jw.CHUNK_SECONDS:g} s) and {c['round_wall_s']:.1f} s "
        f"wall per round; with a file (`path`) {c['wall_with_path_s']:.1f} s wall, "
        f"{c['cpu_with_path_s']:.1f} CPU s: the saves cost {c['save_wall_s']:+.2f} s in all, "
        f"{c['save_wall_per_chunk_s']:+.3f} s per chunk (a difference of two noisy totals).",
    ]
    (folder / f"sweep_chunks{quick}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()

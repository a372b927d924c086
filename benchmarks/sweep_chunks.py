"""The cost of a sweep chunk, for `jaxworm.sweep`'s default chunk size (issue 15).

A killed sweep loses the chunks in flight, so a default chunk must stay within ~10 s of
compute (`_sweep.CHUNK_SECONDS`). A chunk of c scenes over t1 seconds costs about

    T(c, t1) ≈ t1 (a + b c)      [s, one core]

(a: the per-step work the lanes of a `vmap` share; b: each lane's own). This script
measures T, as the process's CPU time (on the shared 2-core machine wall times measure
the neighbours too; the chunk runs on one core), for c = 1, 8, 32 on gaits of the Fig. 3
grid (ω = 3π … 5π: the 5π lanes take the most steps), per preset, fits a and b (least
squares on T/t1), and then checks the model where it matters: the default Fig. 3 sweep
(21 × 21 × 60 s, `fast`, one chunk per core) with a file, timing every chunk from the
start of its round to its save.

    python benchmarks/sweep_chunks.py            # all presets, then the Fig. 3 check
    python benchmarks/sweep_chunks.py --quick    # fast only, 7 x 7 x 10 s check

Writes benchmarks/results/sweep_chunks/sweep_chunks[_quick].{json,md}.
"""

from __future__ import annotations

import os

_CORES = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
os.environ.setdefault("XLA_FLAGS", f"--xla_force_host_platform_device_count={_CORES}")

import argparse  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import _bench as B  # noqa: E402
import jax  # noqa: E402
import numpy as np  # noqa: E402

import jaxworm as jw  # noqa: E402

# private: this benchmark times one sweep chunk (`_run_chunk`) and checks the chunk-size
# model's constants (CHUNK_SECONDS, CHUNK_COST), which `jw.sweep` does not expose
from jaxworm import _sweep  # noqa: E402
from jaxworm.paper import paper_grid  # noqa: E402

#: Horizon [s] of the fit, per preset: long enough that the start is not all of it.
FIT_T1 = {"fast": 20.0, "default": 5.0, "accurate": 1.0}
SIZES = (1, 8, 32)


def _points(c: int) -> np.ndarray:
    """c gaits of the Fig. 3 grid spread over ω from 5π (the most steps) down, δ mixed."""
    g = paper_grid(21)
    k = np.linspace(0, 20, c).round().astype(int)
    return np.stack([g["omega"][::-1][k], g["delta"][(7 * k + 10) % 21]], axis=1)


def fit(preset: str) -> dict:
    t1 = FIT_T1[preset]
    numerics = jw.PRESETS[preset]
    dev = jax.devices()[0]
    rows = []
    for c in SIZES:
        pts = jax.device_put(_points(c), dev)
        jax.block_until_ready(
            _sweep._run_chunk(jw.Params(), ("omega", "delta"), pts, t1, numerics, "t1")
        )  # compile
        walls, cpus = [], []
        for _ in range(2):
            start, cpu = time.perf_counter(), time.process_time()
            jax.block_until_ready(
                _sweep._run_chunk(jw.Params(), ("omega", "delta"), pts, t1, numerics, "t1")
            )
            walls.append(time.perf_counter() - start)
            cpus.append(time.process_time() - cpu)
        rows.append(
            {
                "chunk": c,
                "t1_s": t1,
                "cpu_s": min(cpus),
                "wall_s": min(walls),
                "cpus_s": cpus,
                "walls_s": walls,
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


def chunk_times(size: int, t1: float) -> dict:
    """The default sweep of a size x size Fig. 3 grid with a file: each chunk's wall time
    (its round's dispatch to its save), compile excluded (a first, identical sweep)."""
    grid = paper_grid(size)
    with tempfile.TemporaryDirectory() as tmp:
        jw.sweep(grid, t1=t1, progress=False, path=Path(tmp) / "warm.npz")
        stamps = []
        original = _sweep._files.save

        def timed_save(*args, **kw):
            original(*args, **kw)
            stamps.append((time.perf_counter(), time.process_time()))

        _sweep._files.save = timed_save
        try:
            start = (time.perf_counter(), time.process_time())
            s = jw.sweep(grid, t1=t1, progress=False, path=Path(tmp) / "s.npz")
        finally:
            _sweep._files.save = original
    chunk = s["header"]["chunk"]
    d = len(jax.devices())
    # The chunks of a round run at once, one per device (core): each one's wall time runs
    # from its round's start to its save; the round's CPU time, over the devices, is the
    # compute of one chunk (on a busy machine wall times also measure the neighbours).
    rounds = [stamps[i : i + d] for i in range(0, len(stamps), d)]
    walls, cpus, t0 = [], [], start
    for r in rounds:
        walls += [w - t0[0] for w, _ in r]
        cpus.append((r[-1][1] - t0[1]) / len(r))
        t0 = r[-1]
    return {
        "grid": f"{size} x {size}",
        "t1_s": t1,
        "devices": d,
        "chunk": chunk,
        "chunks": len(stamps),
        "chunk_wall_s": walls,
        "max_chunk_wall_s": max(walls),
        "chunk_cpu_s": cpus,
        "max_chunk_cpu_s": max(cpus),
        "total_wall_s": stamps[-1][0] - start[0],
        "scenes_ok": int((s["status"] == 0).sum()),
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
    check = chunk_times(7, 10.0) if args.quick else chunk_times(21, 60.0)
    B.write_json(
        folder / f"sweep_chunks{quick}.json",
        {"machine": info, "chunk_seconds": _sweep.CHUNK_SECONDS, "fits": fits, "check": check},
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
        + " gaits of the Fig. 3 grid (5π first), T the CPU time of one chunk:",
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
    c = check
    lines += [
        "",
        "In `jaxworm._sweep.CHUNK_COST` (from an earlier run of this script): "
        + ", ".join(f"{k} a = {a:.3g}, b = {b:.3g}" for k, (a, b) in _sweep.CHUNK_COST.items())
        + f"; target CHUNK_SECONDS = {_sweep.CHUNK_SECONDS:g} s.",
    ]
    lines += [
        "",
        f"Check, the default sweep of {c['grid']} gaits × {c['t1_s']:g} s (`fast`, "
        f"{c['devices']} devices, default chunk {c['chunk']}, {c['chunks']} chunks, "
        f"{c['scenes_ok']} ok): compute per chunk (a round's CPU time over the devices) "
        f"{min(c['chunk_cpu_s']):.1f}–{c['max_chunk_cpu_s']:.1f} s (target ≤ "
        f"{_sweep.CHUNK_SECONDS:g} s); wall time per chunk {min(c['chunk_wall_s']):.1f}–"
        f"{c['max_chunk_wall_s']:.1f} s; total {c['total_wall_s']:.1f} s.",
    ]
    (folder / f"sweep_chunks{quick}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()

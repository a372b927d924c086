"""A sweep over several processes (`jax.distributed`) against one process with as many
devices, as a user runs them: whole `jaxworm sweep` commands.

Configurations, each with D devices in all (one JAX CPU device per core of this machine):

- `1 process x 1 device`: the baseline of one core;
- `1 process x D devices`: the one-process path (`jw.sweep` puts a chunk on each device);
- `D processes x 1 device`: the multi-controller path, the coordinator on localhost.

Each runs the paper's Fig. 3 grid (21 × 21 × 60 s; 7 × 7 × 10 s with `--quick`) twice to
fresh output files, sharing one program cache folder: the first run compiles (cold), the
second loads the compiled programs (warm). Reported: wall time of the whole command (the
slowest process), scenes and simulated seconds per second, and whether the results are
bit-identical to those of `1 process x D devices` (the same chunks).

    python benchmarks/distributed.py [--quick]

Writes results/distributed/distributed[_quick].{json,md}.
"""

from __future__ import annotations

import argparse
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import _results as R
import numpy as np

JAXWORM = [sys.executable, "-m", "jaxworm", "sweep", "--quiet"]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _run(processes: int, devices: int, out: Path, cache: Path, grid: list[str]) -> float:
    """Wall time of one sweep command per process, all started at once."""
    env = dict(os.environ)
    env["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={devices}"
    env["JAXWORM_CACHE_DIR"] = str(cache)
    port = _free_port()
    cmds = []
    for k in range(processes):
        # One worker per device: D devices in all are D workers whatever the split.
        cmd = [*JAXWORM, *grid, "--out", str(out), "--workers", "1"]
        if processes > 1:
            cmd += ["--coordinator", f"127.0.0.1:{port}", "--num-processes", str(processes)]
            cmd += ["--process-id", str(k)]
        cmds.append(cmd)
    t0 = time.perf_counter()
    procs = [
        subprocess.Popen(c, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        for c in cmds
    ]
    for p in procs:
        _, err = p.communicate()
        if p.returncode not in (0, 1):
            raise RuntimeError(f"{p.args} failed ({p.returncode}):\n{err[-2000:]}")
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="7 x 7 x 10 s instead of 21 x 21 x 60 s")
    args = ap.parse_args()
    import jaxworm as jw

    run = R.run_record()
    D = max(2, R.cores())
    n, t1 = (7, 10.0) if args.quick else (21, 60.0)
    grid = ["--grid", f"omega=3*pi:5*pi:{n}", "--grid", f"delta=pi/6:pi/3:{n}"]
    grid += ["--set", f"t1={t1}"]
    configs = [(1, 1), (1, D), (D, 1)]
    work = Path(tempfile.mkdtemp(prefix="jaxworm-distributed-"))
    rows, files = [], {}
    try:
        for processes, devices in configs:
            cache = work / f"cache-{processes}x{devices}"
            times = []
            for k in range(2):
                out = work / f"{processes}x{devices}-{k}.npz"
                times.append(_run(processes, devices, out, cache, grid))
            files[(processes, devices)] = jw.load_sweep(out)
            rows.append({"processes": processes, "devices": devices, "cold_s": times[0],
                         "warm_s": times[1]})  # fmt: skip
    finally:
        reference = files.get((1, D))
        for r in rows:
            s = files[(r["processes"], r["devices"])]
            r["bit_identical"] = reference is not None and all(
                np.array_equal(s[f], reference[f], equal_nan=True) for f in jw.SWEEP_FIELDS
            )
            r["all_ok"] = bool((s.status == 0).all())
        shutil.rmtree(work, ignore_errors=True)
    scenes = n * n
    for r in rows:
        r["scenes_per_s_warm"] = scenes / r["warm_s"]
        r["simulated_s_per_s_warm"] = scenes * t1 / r["warm_s"]
    result = {"grid": f"{n} x {n} x {t1:g} s", "devices_in_all": D, "rows": rows}
    stem = "distributed" + R.quick_suffix(args.quick)
    folder = R.results_dir("distributed")
    R.write_json(folder / f"{stem}.json", result)
    base = rows[0]["warm_s"]
    lines = [
        f"# One sweep, one or several processes: Fig. 3, {result['grid']}",
        "",
        f"`{run['command']}` on {run['machine']} ({run['cores']} cores), {run['date']}, "
        f"load {run['load'][0]:.1f} at start. Whole `jaxworm sweep` commands (the slowest "
        "process); cold: empty program cache; warm: the second run with that cache. "
        "1 × 1 cuts its own chunks (one device), so its bits may differ.",
        "",
        "| processes × devices | cold s | warm s | warm speed-up over 1 × 1 | scenes/s (warm) "
        "| simulated s/s (warm) | bit-identical to 1 × D | all ok |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['processes']} × {r['devices']} | {r['cold_s']:.1f} | {r['warm_s']:.1f} | "
            f"{base / r['warm_s']:.2f} | {r['scenes_per_s_warm']:.1f} | "
            f"{r['simulated_s_per_s_warm']:.0f} | {'yes' if r['bit_identical'] else 'no'} | "
            f"{'yes' if r['all_ok'] else 'no'} |"
        )
    (folder / f"{stem}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()

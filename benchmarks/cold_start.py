"""Latency as a user meets it: whole processes, from a cold and from a warm cache.

Each figure is the wall time of a fresh process (`subprocess`), so imports, tracing,
loading compiled programs and the solve are all in it:

- `simulate`: `jaxworm simulate` on Table 1 over 60 s, once with an empty jaxworm cache
  folder (cold) and then `--repeats` times with the folder it left (warm);
- `first solve`: a fresh Python process that imports jaxworm and calls
  `jw.simulate(jw.Params(), 60.0)`, warm cache: the import and the first call, each
  timed inside the process;
- `sweep` (with `--sweep`): `jaxworm sweep` of the paper's Fig. 3 grid (21 × 21 × 60 s;
  7 × 7 × 10 s with `--quick`), cold and warm, each to a fresh output file; and `jw.sweep`
  in a fresh Python process (its defaults: a worker per core), its first and second run, with an
  empty and with a warm cache;
- `paper` (with `--paper`): the quick start's `jaxworm paper --out DIR`, cold and warm.

The anchor, measured in the same run, is the solve alone: the second call of
`jw.simulate` in one process (compiled, warm). The error beside it is that solve's mean
velocity against the `accurate` preset's.

    python benchmarks/cold_start.py                  # simulate and first solve
    python benchmarks/cold_start.py --sweep --quick  # and a 7 x 7 x 10-s sweep
    python benchmarks/cold_start.py --paper          # and `jaxworm paper`

Writes results/cold_start/cold_start[_quick][_paper][_sweep].{json,md}.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import _results as R

JAXWORM = [sys.executable, "-m", "jaxworm"]

FIRST_SOLVE = """
import time; t0 = time.perf_counter()
import jax, jaxworm as jw
t1 = time.perf_counter()
r = jw.simulate(jw.Params(), 60.0); jax.block_until_ready(r)
t2 = time.perf_counter()
r = jw.simulate(jw.Params(), 60.0); jax.block_until_ready(r)
t3 = time.perf_counter()
import json; print(json.dumps({"import_s": t1 - t0, "first_s": t2 - t1, "solve_s": t3 - t2,
       "velocity": float(r.mean_velocity), "status": str(r.status_name)}))
"""

SWEEP_IN_PROCESS = """
import os, time, sys; t0 = time.perf_counter()
import jax, jaxworm as jw
from jaxworm.paper import paper_grid
size, t1 = int(sys.argv[1]), float(sys.argv[2])
t1_ = time.perf_counter()
jw.sweep(paper_grid(size), t1=t1, progress=False)
t2 = time.perf_counter()
s = jw.sweep(paper_grid(size), t1=t1, progress=False)
t3 = time.perf_counter()
import json; print(json.dumps({"import_s": t1_ - t0, "first_s": t2 - t1_, "second_s": t3 - t2,
       "devices": len(jax.devices())}))
"""

ACCURATE = """
import jaxworm as jw
r = jw.simulate(jw.Params(), 60.0, jw.PRESETS["accurate"])
import json; print(json.dumps({"velocity": float(r.mean_velocity), "status": str(r.status_name)}))
"""


def _process(cmd, cache: Path | None, **kw) -> tuple[float, str]:
    env = {**os.environ, "JAXWORM_CACHE_DIR": "" if cache is None else str(cache)}
    start = time.perf_counter()
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, **kw)
    wall = time.perf_counter() - start
    if out.returncode not in (0, 1):
        raise RuntimeError(f"{cmd} failed ({out.returncode}):\n{out.stderr[-2000:]}")
    return wall, out.stdout


def _python(code: str, cache: Path | None, *argv: str) -> dict:
    _, out = _process([sys.executable, "-c", code, *argv], cache)
    return json.loads(out.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3, help="warm runs of each command")
    ap.add_argument("--sweep", action="store_true", help="also time `jaxworm sweep`")
    ap.add_argument("--quick", action="store_true", help="a 7 x 7 x 10-s sweep grid")
    ap.add_argument(
        "--paper", action="store_true", help="also time the quick start's `jaxworm paper`"
    )
    args = ap.parse_args()
    run = R.run_record()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        cache = Path(tmp) / "cache"
        sim = [*JAXWORM, "simulate", "--set", "t1=60", "--json"]
        cold, out = _process(sim, cache)
        report = json.loads(out)
        warm = [_process(sim, cache)[0] for _ in range(args.repeats)]
        rows.append(
            {
                "what": "jaxworm simulate, Table 1, 60 s",
                "cold_s": cold,
                "warm_s": min(warm),
                "warm_runs_s": warm,
            }
        )
        first = [_python(FIRST_SOLVE, cache) for _ in range(args.repeats)]
        best = min(first, key=lambda r: r["first_s"])
        rows.append(
            {
                "what": "fresh Python process: jw.simulate(jw.Params(), 60.0)",
                "import_s": best["import_s"],
                "warm_s": best["first_s"],
                "warm_runs_s": [r["first_s"] for r in first],
            }
        )
        anchor = min(r["solve_s"] for r in first)
        accurate = _python(ACCURATE, None)
        error = abs(best["velocity"] - accurate["velocity"]) / max(abs(accurate["velocity"]), 1e-4)
        if args.paper:
            shutil.rmtree(cache)
            times = [
                _process([*JAXWORM, "paper", "--out", str(Path(tmp) / f"paper{i}")], cache)[0]
                for i in range(1 + args.repeats)
            ]
            rows.append(
                {
                    "what": "jaxworm paper --out DIR (the quick start's main job)",
                    "cold_s": times[0],
                    "warm_s": min(times[1:]),
                    "warm_runs_s": times[1:],
                }
            )
        if args.sweep:
            grid = (
                ["--grid", "omega=3*pi:5*pi:7", "--grid", "delta=pi/6:pi/3:7", "--set", "t1=10"]
                if args.quick
                else []
            )
            shutil.rmtree(cache)
            times = []
            for i in range(1 + args.repeats):
                out_file = Path(tmp) / f"sweep{i}.npz"
                times.append(
                    _process([*JAXWORM, "sweep", "--quiet", "--out", str(out_file), *grid], cache)[
                        0
                    ]
                )
            size, t1 = ("7", "10") if args.quick else ("21", "60")
            for label, c in (("empty", Path(tmp) / "cache_in_process"), ("warm", cache)):
                r = _python(SWEEP_IN_PROCESS, c, size, t1)
                rows.append(
                    {
                        "what": f"fresh Python process, {label} cache: jw.sweep twice "
                        f"({size} x {size} x {t1} s, {r['devices']} device(s))",
                        "import_s": r["import_s"],
                        "cold_s": r["first_s"],
                        "warm_s": r["second_s"],
                        "warm_runs_s": [r["second_s"]],
                    }
                )
            rows.append(
                {
                    "what": "jaxworm sweep, Fig. 3 "
                    + ("7 x 7 x 10 s" if args.quick else "21 x 21 x 60 s"),
                    "cold_s": times[0],
                    "warm_s": min(times[1:]),
                    "warm_runs_s": times[1:],
                }
            )
    result = {
        "run": run,
        "anchor_solve_s": anchor,
        "velocity": best["velocity"],
        "velocity_accurate": accurate["velocity"],
        "error": error,
        "status": report["status"],
        "rows": rows,
    }
    stem = (
        "cold_start"
        + R.quick_suffix(args.quick)
        + ("_paper" if args.paper else "")
        + ("_sweep" if args.sweep else "")
    )
    folder = R.results_dir("cold_start")
    R.write_json(folder / f"{stem}.json", result)
    lines = [
        f"# Latency from a cold and a warm cache: {stem}",
        "",
        f"`{run['command']}` on {run['machine']} ({run['cores']} cores), {run['date']}, "
        f"load {run['load'][0]:.1f} at start.",
        "",
        f"Anchor (the 60-s solve alone, compiled, in-process): {anchor:.3f} s; its error "
        f"against `accurate`: {error:.1e} (v = {best['velocity']:.6g} m/s).",
        "",
        "| what | import s | cold s | warm s (best) | warm ÷ anchor | warm runs s |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['what']} | {r.get('import_s', float('nan')):.2f} | "
            f"{r.get('cold_s', float('nan')):.1f} | {r['warm_s']:.2f} | "
            f"{r['warm_s'] / anchor:.1f} | "
            + ", ".join(f"{t:.2f}" for t in r["warm_runs_s"])
            + " |"
        )
    (folder / f"{stem}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()

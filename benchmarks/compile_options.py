"""XLA's older CPU loop emitters (`--xla_cpu_use_fusion_emitters=false`) against its
defaults for jaxworm's programs: compile and run time, and the error on the same work.

The library keeps XLA's defaults: this records an option measured and not taken (the
programs compile faster with it, and run slower).

Each configuration runs in a fresh Python process with the caches off, the two
alternated `--rounds` times (which goes first swaps every round); the fastest of each is
kept.

- `sweep`: the program of `jw.sweep(paper_grid(n), t1)` (Fig. 3, `fast`, its default
  chunk) traced and compiled on a tiny sweep of 16 scenes (t1 is the program's
  argument), then the whole grid twice: the first run and the faster of the two.
- `lone`: `jw.simulate` of Table 1 with δ = −π/4 over t1 (`fast`): compilation and the
  fastest of 3 runs.

Each with `XLA_FLAGS=--xla_cpu_use_fusion_emitters=false` (`options`) and without
(`defaults`).

Error on the same work: both sweeps' v̄ against `accurate` at `--check` grid points
(relative, floor 1e-4 m/s), and the largest difference between the two grids.

    python benchmarks/compile_options.py
    python benchmarks/compile_options.py --n 5 --t1 10 --rounds 1

Writes results/compile_options/compile_options[_t1_X].{json,md}.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

OPTION = "--xla_cpu_use_fusion_emitters=false"


def _child(kind: str, n: int, t1: float) -> dict:
    import _bench  # noqa: F401  (first: caches off, BLAS threads)
    import jax
    import jax.numpy as jnp
    import numpy as np

    import jaxworm as jw
    from jaxworm.paper import paper_grid

    if kind == "sweep":
        # The grid's program (its chunk size) compiled on a tiny sweep of 16 scenes:
        # t1 is an argument of the program, so the full sweeps below reuse it.
        chunk = jw.default_chunk(n * n, os.cpu_count() or 1, t1, jw.PRESETS["fast"])
        start = time.perf_counter()
        jw.sweep(paper_grid(4), t1=0.05, progress=False, chunk=chunk)
        compile_s = time.perf_counter() - start
        times, v = [], None
        for _ in range(2):
            start = time.perf_counter()
            r = jw.sweep(paper_grid(n), t1=t1, progress=False, chunk=chunk)
            times.append(time.perf_counter() - start)
            v = np.asarray(r.mean_velocity)
        status_ok = bool(np.all(np.asarray(r.status) == 0))
        return {
            "compile_s": compile_s,
            "first_run_s": times[0],
            "run_s": min(times),
            "runs_s": times,
            "v": v.tolist(),
            "all_ok": status_ok,
        }
    p = jw.Params(gait=jw.TravellingWave(delta=-jnp.pi / 4))
    fn = jax.jit(lambda p, t: jw.simulate(p, t).mean_velocity)
    start = time.perf_counter()
    compiled = fn.lower(p, jnp.float64(t1)).compile()
    compile_s = time.perf_counter() - start
    runs = []
    for _ in range(4):
        start = time.perf_counter()
        v = jax.block_until_ready(compiled(p, jnp.float64(t1)))
        runs.append(time.perf_counter() - start)
    return {"compile_s": compile_s, "run_s": min(runs[1:]), "v": float(v)}


def _spawn(kind: str, variant: str, n: int, t1: float) -> dict:
    env = dict(os.environ)
    env.pop("XLA_FLAGS", None)
    if variant == "options":
        env["XLA_FLAGS"] = OPTION
    cmd = [sys.executable, __file__, "--child", kind, "--n", str(n), "--t1", str(t1)]
    done = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if done.returncode != 0:
        raise RuntimeError(f"{kind} {variant} failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=21, help="grid points per axis")
    ap.add_argument("--t1", type=float, default=60.0)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--check", type=int, default=5, help="grid points checked on accurate")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        print(json.dumps(_child(args.child, args.n, args.t1)))
        return

    import _bench as B
    import numpy as np

    import jaxworm as jw
    from jaxworm.paper import paper_grid

    runs = {(k, v): [] for k in ("sweep", "lone") for v in ("options", "defaults")}
    for k in range(args.rounds):
        for kind in ("sweep", "lone"):
            order = ("options", "defaults") if k % 2 == 0 else ("defaults", "options")
            for variant in order:
                got = _spawn(kind, variant, args.n, args.t1)
                runs[(kind, variant)].append(got)
                print(kind, variant, {k: v for k, v in got.items() if k != "v"}, flush=True)

    def best(kind, variant, key):
        return min(r[key] for r in runs[(kind, variant)])

    grid = paper_grid(args.n)
    points = [(w, d) for w in grid["omega"] for d in grid["delta"]]
    v_opt = np.asarray(runs[("sweep", "options")][0]["v"]).ravel()
    v_def = np.asarray(runs[("sweep", "defaults")][0]["v"]).ravel()
    pick = np.linspace(0, len(points) - 1, args.check).round().astype(int)
    checks = []
    for i in pick:
        w, d = points[i]
        ref = float(
            jw.simulate(
                jw.Params().replace(omega=w, delta=d), args.t1, jw.PRESETS["accurate"]
            ).mean_velocity
        )
        scale = max(abs(ref), B.V_FLOOR)
        checks.append(
            {
                "omega": float(w),
                "delta": float(d),
                "accurate": ref,
                "err_options": abs(v_opt[i] - ref) / scale,
                "err_defaults": abs(v_def[i] - ref) / scale,
            }
        )
    floor = np.maximum(np.abs(v_def), B.V_FLOOR)
    rows = {
        "sweep": {
            "compile_s": {v: best("sweep", v, "compile_s") for v in ("options", "defaults")},
            "first_run_s": {v: best("sweep", v, "first_run_s") for v in ("options", "defaults")},
            "run_s": {v: best("sweep", v, "run_s") for v in ("options", "defaults")},
            "all_ok": all(r["all_ok"] for k in runs if k[0] == "sweep" for r in runs[k]),
            "max_rel_diff_between": float(np.max(np.abs(v_opt - v_def) / floor)),
        },
        "lone": {
            "compile_s": {v: best("lone", v, "compile_s") for v in ("options", "defaults")},
            "run_s": {v: best("lone", v, "run_s") for v in ("options", "defaults")},
            "v": {v: runs[("lone", v)][0]["v"] for v in ("options", "defaults")},
        },
    }
    suffix = "" if args.t1 == 60 and args.n == 21 else f"_n_{args.n}_t1_{args.t1:g}"
    out = {
        "machine": B.machine_info(),
        "n": args.n,
        "t1": args.t1,
        "rounds": args.rounds,
        "option": OPTION,
        "rows": rows,
        "checks": checks,
        "runs": {f"{k}/{v}": [dict(r, v=None) for r in rs] for (k, v), rs in runs.items()},
    }
    folder = B.results_dir("compile_options")
    B.write_json(folder / f"compile_options{suffix}.json", out, indent=1)
    s, lo = rows["sweep"], rows["lone"]
    lines = [
        f"# XLA CPU emitters: `{OPTION}` against XLA's defaults",
        "",
        B.machine_line(out["machine"]),
        f"Command: `python benchmarks/compile_options.py --n {args.n} --t1 {args.t1:g} "
        f"--rounds {args.rounds}`; fresh processes, caches off, fastest of {args.rounds}.",
        "",
    ]
    table = []
    for label, key, group in (
        ("jw.sweep first call: 16 scenes over 0.05 s (trace, compile, run) s", "compile_s", s),
        (f"jw.sweep {args.n}×{args.n}×{args.t1:g} s, first run s", "first_run_s", s),
        (f"jw.sweep {args.n}×{args.n}×{args.t1:g} s, fastest run (2 per process) s", "run_s", s),
        (f"lone simulate {args.t1:g} s, trace and compile s", "compile_s", lo),
        (f"lone simulate {args.t1:g} s, run s", "run_s", lo),
    ):
        o, d = group[key]["options"], group[key]["defaults"]
        table.append([label, f"{o:.3f}", f"{d:.3f}", f"{o / d:.2f}"])
    lines += B.md_table(["work", "options", "XLA defaults", "ratio"], table)
    lines += [
        "",
        f"Sweeps all ok: {s['all_ok']}. Largest relative difference between the two grids' "
        f"v̄: {s['max_rel_diff_between']:.1e}.",
        "",
    ]
    lines += B.md_table(
        ["ω", "δ", "v̄ accurate", "error, options", "error, defaults"],
        [
            [f"{c['omega']:.4f}", f"{c['delta']:.4f}", f"{c['accurate']:.6g}"]
            + [f"{c['err_options']:.1e}", f"{c['err_defaults']:.1e}"]
            for c in checks
        ],
    )
    (folder / f"compile_options{suffix}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()

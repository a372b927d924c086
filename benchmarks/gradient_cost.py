"""Cost of a gradient (issue 5): value-and-gradient of a 60-s objective against the
forward solve with the same preset, and the peak memory of each, for both derivative
modes: reverse (`jax.value_and_grad`, diffrax's checkpointed adjoint) and forward
(`jax.jacfwd` with `Numerics(adjoint="forward", crack_tip_gradient=False)`, what
`jaxworm.optimise` uses).

    python benchmarks/gradient_cost.py [--t1 60] [--presets default,accurate] [--repeats 2]

Each measurement runs in its own subprocess (so its peak resident memory, `ru_maxrss`,
is its own): the forward solve `simulate(...).mean_velocity` and `jax.value_and_grad`
of it with respect to (A, ω, δ), jitted, on the forward scene δ = −π/4 (27 cracks in
60 s). Reported: first call (compile + run), run after compilation (median of
`--repeats`), the ratio of the two runs, the process's peak RSS, and XLA's memory
analysis of the compiled program (temporaries and arguments) where the backend gives it.
Writes benchmarks/results/gradient_cost.{json,md}. The persistent compilation cache is
off, so "first call" is real. Timings need a quiet machine: the load average is recorded.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

RESULTS = Path(__file__).parent / "results"
MODES = ("forward", "value_and_jacfwd", "value_and_grad")


def _child(mode: str, t1: float, preset: str, repeats: int) -> dict:
    """One measurement, in this (fresh) process."""
    import resource

    import equinox as eqx
    import jax
    import jax.numpy as jnp

    jax.config.update("jax_enable_compilation_cache", False)
    import jaxworm as jw

    num = jw.PRESETS[preset]
    if mode == "value_and_jacfwd":
        num = num.replace(adjoint="forward", crack_tip_gradient=False)
    base = jw.Params()

    def velocity(z):
        r = jw.simulate(base.replace(A=z[0], omega=z[1], delta=z[2]), t1, num)
        return r.mean_velocity

    def value_and_jacfwd(z):
        g, v = jax.jacfwd(lambda z: (velocity(z), velocity(z)), has_aux=True)(z)
        return v, g

    fn = {"forward": velocity, "value_and_grad": jax.value_and_grad(velocity),
          "value_and_jacfwd": value_and_jacfwd}[mode]
    z = jnp.array([0.02, 4 * jnp.pi, -jnp.pi / 4])
    jitted = eqx.filter_jit(fn)
    t = time.perf_counter()
    out = jax.block_until_ready(jitted(z))
    first = time.perf_counter() - t
    runs = []
    for _ in range(repeats):
        t = time.perf_counter()
        jax.block_until_ready(jitted(z))
        runs.append(time.perf_counter() - t)
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # before the analysis compiles again
    memory = None
    try:
        compiled = jax.jit(fn).lower(z).compile()
        m = compiled.memory_analysis()
        if m is not None:
            memory = {k: int(getattr(m, k)) for k in (
                "temp_size_in_bytes", "argument_size_in_bytes", "output_size_in_bytes",
                "generated_code_size_in_bytes") if hasattr(m, k)}
    except Exception as e:  # noqa: BLE001 - the analysis is optional
        memory = {"error": repr(e)[:200]}
    value = out if mode == "forward" else out[0]
    grad = None if mode == "forward" else [float(g) for g in out[1]]
    return {"mode": mode, "preset": preset, "t1": t1, "first_call_s": first,
            "run_s": statistics.median(runs), "runs_s": runs, "value": float(value),
            "grad": grad, "max_rss_MiB": rss,
            "xla_memory": memory}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--t1", type=float, default=60.0)
    ap.add_argument("--presets", default="default,accurate")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--child", choices=MODES, help=argparse.SUPPRESS)
    ap.add_argument("--preset", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        print(json.dumps(_child(args.child, args.t1, args.preset, args.repeats)))
        return

    rows = []
    for preset in args.presets.split(","):
        pair = {}
        for mode in MODES:
            cmd = [sys.executable, __file__, "--child", mode, "--preset", preset,
                   "--t1", str(args.t1), "--repeats", str(args.repeats)]
            done = subprocess.run(cmd, capture_output=True, text=True, check=True)
            pair[mode] = json.loads(done.stdout.strip().splitlines()[-1])
            print(f"{preset} {mode}: {pair[mode]['run_s']:.2f} s after compile, "
                  f"first {pair[mode]['first_call_s']:.1f} s, "
                  f"peak RSS {pair[mode]['max_rss_MiB']:.0f} MiB", file=sys.stderr)
        f = pair["forward"]
        for mode in MODES[1:]:
            g = pair[mode]
            rows.append({"preset": preset, "mode": mode, "forward": f, "value_and_grad": g,
                         "ratio_run": g["run_s"] / f["run_s"],
                         "ratio_first_call": g["first_call_s"] / f["first_call_s"],
                         "rss_ratio": g["max_rss_MiB"] / f["max_rss_MiB"]})

    import jax

    out = {
        "scene": f"Table 1 with delta = -pi/4, t1 = {args.t1} s; d(mean velocity)/d(A, omega, delta)",
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                    "jax": jax.__version__, "load_average": os.getloadavg()},
        "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "target": "value-and-gradient <= 3x the forward solve (issue 5)",
        "rows": rows,
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "gradient_cost.json").write_text(json.dumps(out, indent=2))
    lines = [f"# Gradient cost: {out['scene']}", "",
             f"Machine: {out['machine']['platform']}, {out['machine']['cpus']} CPUs, jax "
             f"{out['machine']['jax']}, load average {', '.join(f'{x:.1f}' for x in out['machine']['load_average'])}"
             f" at the end; {out['date']}. Target: {out['target']}.", "",
             "| preset | derivative | forward run s | value+grad run s | ratio | forward first call s | "
             "value+grad first call s | forward peak RSS MiB | value+grad peak RSS MiB | "
             "value+grad XLA temporaries MiB |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        f, g = r["forward"], r["value_and_grad"]
        temp = (g["xla_memory"] or {}).get("temp_size_in_bytes")
        lines.append(
            f"| {r['preset']} | {r['mode']} | {f['run_s']:.2f} | {g['run_s']:.2f} | {r['ratio_run']:.1f} | "
            f"{f['first_call_s']:.1f} | {g['first_call_s']:.1f} | {f['max_rss_MiB']:.0f} | "
            f"{g['max_rss_MiB']:.0f} | {'-' if temp is None else f'{temp / 2**20:.0f}'} |")
    (RESULTS / "gradient_cost.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()

"""Cost of the default derivative: value-and-gradient against the fastest forward solve
of the same run, with peak memory, for the travelling wave's (A, ω, δ) and for the
12-parameter per-segment gait.

    python benchmarks/gradient_cost.py [--t1 60] [--repeats 3] [--sensitivity-ramp S]
        [--sensitivity-norm mean_position]

Scene: Table 1 with δ = −π/4 (27 cracks in 60 s), the mean velocity over the whole gait
periods within t1. Problems: `wave`, d v̄/d(A, ω, δ); `segments`, d v̄/d(A_1..A_6,
φ_1..φ_6) of the same gait as a `SegmentWave`. Modes: `forward` (`jw.simulate` with its
defaults, the `fast` preset: the fastest forward solve within 1 %), `jacfwd`
(value and `jax.jacfwd`, default numerics) and `grad` (`jax.value_and_grad`, default
numerics: reverse mode through the same forward sensitivities).

Each measurement runs in its own subprocess, so its peak resident memory (`ru_maxrss`)
is its own; all of them run from this one command, one after the other. Reported:
first call (compile + run), the fastest of `--repeats` runs after compilation, their
ratio to the forward solve of the same problem, and peak RSS. The persistent
compilation cache is off, so "first call" is real. `--sensitivity-ramp`: the
derivatives with `Numerics.sensitivity_ramp` S instead of the default (a baseline on
the same machine). `--sensitivity-norm mean_position`: the derivatives with the
goal-oriented step control that `jw.optimise` takes for its velocity objective
(`Numerics.sensitivity_norm`). Writes
benchmarks/results/gradient_cost/gradient_cost.{json,md} (`_ramp_S` and `_mean_position`
added to the name with those options).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

MODES = ("forward", "jacfwd", "grad")
PROBLEMS = ("wave", "segments")


def _child(problem: str, mode: str, t1: float, repeats: int, ramp: float | None, norm: str) -> dict:
    """One measurement, in this (fresh) process."""
    import resource

    import _bench  # compilation cache off: first calls are real
    import jax
    import jax.numpy as jnp

    import jaxworm as jw

    wave = jw.TravellingWave(delta=-jnp.pi / 4)
    if problem == "wave":
        base = jw.Params(gait=wave)
        z = jnp.array([0.02, 4 * jnp.pi, -jnp.pi / 4])

        def params(z):
            return base.replace(A=z[0], omega=z[1], delta=z[2])
    else:
        base = jw.Params(gait=jw.SegmentWave.from_wave(wave, N=7))
        z = jnp.concatenate([base.gait.A, base.gait.phase])

        def params(z):
            return jw.Params(gait=jw.SegmentWave(A=z[:6], phase=z[6:], omega=base.gait.omega))

    horizon = jw.whole_period_horizon(4 * jnp.pi, t1)

    options = {"sensitivity_ramp": ramp} if ramp is not None else {}
    if norm != "state":
        options["sensitivity_norm"] = norm
    numerics = jw.PRESETS["fast"].replace(**options) if options else None

    def velocity(z):
        return jw.simulate(params(z), horizon, numerics).mean_velocity

    def value_and_jacfwd(z):
        def with_value(q):
            v = velocity(q)
            return v, v

        g, v = jax.jacfwd(with_value, has_aux=True)(z)
        return v, g

    fn = {"forward": velocity, "grad": jax.value_and_grad(velocity), "jacfwd": value_and_jacfwd}[
        mode
    ]
    out, first, runs = _bench.first_call_and_runs(fn, (z,), repeats)
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    value = out if mode == "forward" else out[0]
    grad = None if mode == "forward" else [float(g) for g in out[1]]
    return {
        "problem": problem,
        "mode": mode,
        "t1": float(horizon),
        "first_call_s": first,
        "run_s": min(runs),
        "runs_s": runs,
        "value": float(value),
        "grad": grad,
        "max_rss_MiB": rss,
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--t1", type=float, default=60.0)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--sensitivity-ramp", type=float, default=None)
    ap.add_argument("--sensitivity-norm", choices=("state", "mean_position"), default="state")
    ap.add_argument("--child", nargs=2, metavar=("PROBLEM", "MODE"), help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    ramp = args.sensitivity_ramp
    if args.child:
        print(json.dumps(_child(*args.child, args.t1, args.repeats, ramp, args.sensitivity_norm)))
        return
    tag = "" if ramp is None else f"_ramp_{ramp:g}"
    flag = "" if ramp is None else f" --sensitivity-ramp {ramp:g}"
    if args.sensitivity_norm != "state":
        tag += f"_{args.sensitivity_norm}"
        flag += f" --sensitivity-norm {args.sensitivity_norm}"

    import _results

    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    rows = []
    for problem in PROBLEMS:
        got = {}
        for mode in MODES:
            cmd = [
                sys.executable,
                __file__,
                "--child",
                problem,
                mode,
                "--t1",
                str(args.t1),
                "--repeats",
                str(args.repeats),
            ] + ([] if ramp is None else ["--sensitivity-ramp", str(ramp)])
            cmd += ["--sensitivity-norm", args.sensitivity_norm]
            done = subprocess.run(cmd, capture_output=True, text=True, check=True, env=env)
            got[mode] = json.loads(done.stdout.strip().splitlines()[-1])
            print(
                f"{problem} {mode}: {got[mode]['run_s']:.3f} s, first "
                f"{got[mode]['first_call_s']:.1f} s, {got[mode]['max_rss_MiB']:.0f} MiB",
                file=sys.stderr,
                flush=True,
            )
        f = got["forward"]
        for mode in MODES[1:]:
            g = got[mode]
            rows.append(
                {
                    "problem": problem,
                    "mode": mode,
                    "forward": f,
                    "derivative": g,
                    "ratio_run": g["run_s"] / f["run_s"],
                    "ratio_first_call": g["first_call_s"] / f["first_call_s"],
                    "rss_ratio": g["max_rss_MiB"] / f["max_rss_MiB"],
                }
            )
    out = {
        "scene": f"Table 1 with delta = -pi/4, whole periods within {args.t1:g} s",
        "machine": _results.machine_info(),
        "targets": {"wave": "<= 3x the forward solve", "segments": "<= 6x"},
        "command": f"python benchmarks/gradient_cost.py --t1 {args.t1:g}{flag}",
        "rows": rows,
    }
    folder = _results.results_dir("gradient_cost")
    _results.write_json(folder / f"gradient_cost{tag}.json", out, indent=2)
    m = out["machine"]
    note = (
        ""
        if args.sensitivity_norm == "state"
        else f" with sensitivity_norm {args.sensitivity_norm!r} (jw.optimise's for v̄)"
    )
    lines = [
        f"# Cost of the default derivative{note}: {out['scene']}",
        "",
        f"`{out['command']}` on {m['cpu']} ({m['cpus']} CPUs), jax {m['jax']}, "
        f"{m['date']}, load {m['load_average_at_start'][0]:.1f} at start. Targets "
        "(issue 14): wave ≤ 3×, segments ≤ 6× the forward solve.",
        "",
        "| problem | derivative | forward s | derivative s | ratio | forward first call s "
        "| derivative first call s | first-call ratio | forward peak MiB | derivative peak MiB |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        f, g = r["forward"], r["derivative"]
        lines.append(
            f"| {r['problem']} | {r['mode']} | {f['run_s']:.3f} | {g['run_s']:.3f} | "
            f"{r['ratio_run']:.1f} | {f['first_call_s']:.1f} | {g['first_call_s']:.1f} | "
            f"{r['ratio_first_call']:.1f} | {f['max_rss_MiB']:.0f} | {g['max_rss_MiB']:.0f} |"
        )
    (folder / f"gradient_cost{tag}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()

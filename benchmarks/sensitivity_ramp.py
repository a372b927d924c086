"""The phase frame's start-up ramp (`Numerics.sensitivity_ramp`): steps, time and error.

    python benchmarks/sensitivity_ramp.py [--ramps 0,1] [--scenes mirror,N10]

At fixed gait phase the forward sensitivities are driven by the start-up's elastic
ringing, and their error control then takes many short steps; the ramp turns the frame
on from fixed time over its first seconds (docs: Gradients). For each ramp and each
scene of `gradient_accuracy.py`, the default derivative d v̄/d(A, ω, δ) (`jax.jacfwd`,
`fast` with the ramp changed): the sensitivity solve's steps (accepted and rejected)
over 10 s and over 60 s, the value-and-Jacobian wall time (fastest of 2 calls after
compilation), and over 60 s its scaled error against `gradient_accuracy.py`'s cached
reference slopes for both objectives (max_i |θ_i (g_i − ref_i)| / max_j |θ_j ref_j|).
Writes results/sensitivity_ramp/sensitivity_ramp.{json,md}.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import _bench as B  # (first: sets the BLAS threads before numpy loads)
import _results as R  # noqa: E402
import gradient_accuracy as G  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import jaxworm as jw  # noqa: E402

REFERENCES = R.results_dir("gradient_accuracy") / "gradient_accuracy_reference.json"


def _fastest(fn, z, repeats=2):
    jax.block_until_ready(fn(z))
    best = np.inf
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn(z))
        best = min(best, time.perf_counter() - start)
    return best


def measure(scene: dict, objective: str, t1: float, ramp: float) -> dict:
    num = jw.PRESETS["fast"].replace(max_cracks=G.MAX_CRACKS, sensitivity_ramp=ramp)
    v = G._velocity(scene, objective, t1, num)
    z = jnp.asarray(G._point(scene))

    def value_and_jac(q):
        def with_value(u):
            val, aux = v(u)
            return val, (val, aux)

        jac, (val, (status, cracks, _)) = jax.jacfwd(with_value, has_aux=True)(q)
        return val, jac, status, cracks

    def steps(q):  # the sensitivity solve's, through a JVP along all three
        base = jw.Params().replace(**scene)

        def run(u):
            horizon = jw.whole_period_horizon(u[1], t1) if objective == "whole_periods" else t1
            return jw.simulate(base.replace(**dict(zip(G.NAMES, u))), horizon, num)

        r = jax.jvp(run, (q,), (jnp.ones(3),))[0]
        return r.steps + r.rejected_steps

    fn = jax.jit(value_and_jac)
    val, jac, status, cracks = fn(z)
    return {
        "value": float(val),
        "grad": [float(g) for g in jac],
        "status": str(jw.status_name(status)),
        "cracks": int(cracks),
        "steps": int(jax.jit(steps)(z)),
        "value_and_jacfwd_s": _fastest(fn, z),
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--ramps", default="0,1", help="ramps [s], comma-separated")
    ap.add_argument("--scenes", default=",".join(G.SCENES))
    args = ap.parse_args(argv)
    ramps = [float(r) for r in args.ramps.split(",")]
    scenes = args.scenes.split(",")
    refs = json.loads(REFERENCES.read_text())
    run, machine = R.run_record(), R.machine_info()  # before the load the run adds
    rows = []
    for name in scenes:
        scene = G.SCENES[name]
        z = G._point(scene)
        for ramp in ramps:
            row = {"scene": name, "ramp": ramp}
            row["t10"] = measure(scene, "t1", 10.0, ramp)
            for objective in G.OBJECTIVES:
                m = measure(scene, objective, 60.0, ramp)
                slope = np.asarray(refs[f"{name}/{objective}/60.0"]["slope"])
                err = np.abs(z * (np.asarray(m["grad"]) - slope)) / np.max(np.abs(z * slope))
                m["scaled_error"] = float(err.max())
                row[objective] = m
            rows.append(row)
            B.log(f"{name} ramp {ramp}: {row['t10']['steps']} / {row['t1']['steps']} steps")
    out = {"run": run, "machine": machine, "ramps": ramps, "rows": rows}
    folder = R.results_dir("sensitivity_ramp")
    R.write_json(folder / "sensitivity_ramp.json", out)

    def total(key, field, ramp):
        return sum(r[key][field] for r in rows if r["ramp"] == ramp)

    def errors(r):
        fixed, whole = (100 * r[k]["scaled_error"] for k in G.OBJECTIVES)
        return f"{fixed:.2f} / {whole:.2f} %"

    def largest(ramp):
        mine = [r for r in rows if r["ramp"] == ramp]
        return max(max(r["t1"]["scaled_error"], r["whole_periods"]["scaled_error"]) for r in mine)

    table = [
        [
            r["scene"],
            f"{r['ramp']:g}",
            f"{r['t10']['steps']}",
            f"{r['t10']['value_and_jacfwd_s']:.2f}",
            f"{r['t1']['steps']}",
            f"{r['t1']['value_and_jacfwd_s']:.2f}",
            f"{r['t1']['cracks']}",
            errors(r),
        ]
        for r in rows
    ]
    table += [
        [
            "**all**",
            f"{ramp:g}",
            f"{total('t10', 'steps', ramp)}",
            f"{total('t10', 'value_and_jacfwd_s', ramp):.2f}",
            f"{total('t1', 'steps', ramp)}",
            f"{total('t1', 'value_and_jacfwd_s', ramp):.2f}",
            "",
            f"{100 * largest(ramp):.2f} % (largest)",
        ]
        for ramp in ramps
    ]
    lines = [
        "# The phase frame's start-up ramp: the default derivative's steps, time and error",
        "",
        R.machine_line(out["machine"]),
        "",
        f"Command: `{run['command']}`. "
        "`jax.jacfwd` of the mean velocity w.r.t. (A, ω, δ), `fast` with "
        "`sensitivity_ramp` as the ramp column says (0: the plain phase frame). Steps: the "
        "sensitivity solve's, accepted and rejected; time: value and Jacobian, fastest of "
        "2 calls after compilation; error: scaled, against the cached reference slopes of "
        "`gradient_accuracy.py`, over a fixed 60 s / whole periods within 60 s.",
        "",
        *B.md_table(
            [
                "scene",
                "ramp s",
                "10 s: steps",
                "10 s: value+jac s",
                "60 s: steps",
                "60 s: value+jac s",
                "cracks in 60 s",
                "60-s error (t1 / whole periods)",
            ],
            table,
        ),
    ]
    (folder / "sensitivity_ramp.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Is the default derivative right? d v̄/d(A, ω, δ) of `jw.simulate(p, t1)` with its
default numerics against finite differences of a tightly solved model, on long horizons
through many cracks.

    python benchmarks/gradient_accuracy.py [--quick] [--scenes mirror,N10] [--recompute]
        [--batched] [--sensitivity-norm mean_position]

Scenes (`SCENES`): the Table-1 gait (it retreats and never cracks), its mirror
δ = −π/4, and five others with 24-108 cracks in 60 s (N = 10; another soil and ω = 5π;
more friction and anisotropy; a larger amplitude; many cracks at ω = 3π). Objectives:
the mean velocity over t1 = 60 s and over the whole gait periods within 60 s
(`jw.whole_period_horizon`).

Reference: the `fast` solver tightened to atol 1e-10 m (forward error ~1e-7 relative),
21 runs per parameter at θ(1 + k·5e-4), k = −10..10, batched. The reference slope is
the least-squares line through them (±0.5 %), with its standard error; the 1 % central
difference is reported beside it. For ω over a fixed t1 the steps are 1e-5 (±1e-4):
there the mean velocity is a sawtooth in ω (the gait's phase at t1), and its local
slope, which is the derivative, is ~100× the slope averaged over whole periods that
wider differences see. Why a fit: the mean velocity is piecewise smooth in
the parameters (each crack that appears or vanishes, or moves to another gait cycle,
steps it slightly), so single differences scatter with the step (at 120 periods, d v̄/dδ
by central differences: 0.0129 at 0.5 %, 0.0142 at 1 %, 0.0147 at 2 %).

Comparison, as the issue asks, in scaled terms: e_i = |θ_i (g_i − g_ref,i)| / max_j
|θ_j g_ref,j|. The references are cached in
results/gradient_accuracy/gradient_accuracy_reference[_quick].json (`--recompute` to
redo them). Also timed: the forward solve and the value-and-Jacobian
(`jax.jacfwd`) with the default numerics, after compilation, in this process.
Writes results/gradient_accuracy/gradient_accuracy.{json,md} (`--quick`: 10 s, files
suffixed `_quick`). `--batched`: the derivative taken under `jax.vmap` over a batch of
one, as `jw.optimise` (`batch="vmap"`, its default) solves its starts; the program
differs from the lone one, so its rounding, and with it the adaptive steps, may too
(files suffixed `_batched`). `--sensitivity-norm mean_position`: the derivative with
`Numerics.sensitivity_norm="mean_position"`, `jw.optimise`'s for its velocity objective
(files suffixed `_mean_position`).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

import _bench  # (first: sets OPENBLAS_NUM_THREADS before jax loads)
import jax
import jax.numpy as jnp
import numpy as np

import jaxworm as jw

PI = math.pi
SCENES = {
    "table1": {},
    "mirror": {"delta": -PI / 4},
    "N10": {"N": 10, "delta": -PI / 4},
    "soil": {"E_s": 1.6e5, "K_Ic": 260.0, "K_Ith": 245.0, "delta": -PI / 4, "omega": 5 * PI},
    "friction": {"mu_s": 0.5, "lam": 2.0, "delta": -PI / 4},
    "amplitude": {"A": 0.03, "delta": -PI / 3},
    "many_cracks": {"omega": 3 * PI, "delta": -PI / 6, "K_Ith": 235.0},
}
NAMES = ("A", "omega", "delta")
OBJECTIVES = ("t1", "whole_periods")
MAX_CRACKS = 256
REL_STEP, HALF_WIDTH = 5e-4, 10  # the fit's points: θ(1 + k·REL_STEP), |k| ≤ HALF_WIDTH
#: Over a fixed t1 the mean velocity carries the gait's phase at t1, a sawtooth in ω of
#: period 2π/t1 (0.8 % of ω at 60 s): its local slope, which the derivative is, needs
#: steps well inside that period.
REL_STEP_OMEGA_T1 = 1e-5
TIGHT = jw.PRESETS["fast"].replace(atol=1e-10, max_cracks=MAX_CRACKS)


def _velocity(scene: dict, objective: str, t1: float, numerics):
    base = jw.Params().replace(**scene)

    def v(z):
        p = base.replace(**dict(zip(NAMES, z)))
        horizon = jw.whole_period_horizon(z[1], t1) if objective == "whole_periods" else t1
        r = jw.simulate(p, horizon, numerics)
        return r.mean_velocity, (r.status, r.n_cracks, r.steps)

    return v


def _point(scene: dict) -> np.ndarray:
    flat = jw.Params().replace(**scene).flat()
    return np.array([float(flat[n]) for n in NAMES])


def reference(scene: dict, objective: str, t1: float) -> dict:
    """Least-squares slopes and 1 % central differences of the tight solve."""
    z = _point(scene)
    k = np.arange(-HALF_WIDTH, HALF_WIDTH + 1)
    rows = []
    for i in range(len(NAMES)):
        step = REL_STEP_OMEGA_T1 if (NAMES[i], objective) == ("omega", "t1") else REL_STEP
        for rel in np.concatenate([k * step, [-1e-2, 1e-2]]):
            zz = z.copy()
            zz[i] *= 1 + rel
            rows.append(zz)
    Z = np.array(rows)
    v = jax.jit(jax.vmap(_velocity(scene, objective, t1, TIGHT)))
    t = time.perf_counter()
    vals, status = jax.block_until_ready(v(jnp.asarray(Z)))
    wall = time.perf_counter() - t
    vals, status = np.asarray(vals).reshape(len(NAMES), -1), np.asarray(status[0])
    out = {
        "slope": [],
        "stderr": [],
        "central_1pc": [],
        "all_ok": bool(np.all(status == 0)),
        "wall_s": wall,
    }
    for i in range(len(NAMES)):
        x = Z[i * (len(k) + 2) : i * (len(k) + 2) + len(k), i]
        y = vals[i, : len(k)]
        slope, se = _bench.slope_fit(x - z[i], y)
        out["slope"].append(slope)
        out["stderr"].append(se)
        out["central_1pc"].append(float((vals[i, -1] - vals[i, -2]) / (2e-2 * z[i])))
    return out


def _timed(fn, z, repeats: int):
    out, first, runs = _bench.first_call_and_runs(fn, (z,), repeats)
    return out, first, min(runs)


def default_derivative(
    scene: dict,
    objective: str,
    t1: float,
    repeats: int,
    batched: bool = False,
    norm: str = "state",
) -> dict:
    """The default numerics' value, derivative (jacfwd) and timings; `batched`: under
    `jax.vmap` over a batch of one; `norm`: the numerics' `sensitivity_norm`."""
    num = jw.PRESETS["fast"].replace(max_cracks=MAX_CRACKS, sensitivity_norm=norm)
    v = _velocity(scene, objective, t1, num)
    z = jnp.asarray(_point(scene))
    (val, (status, cracks, _)), first_f, run_f = _timed(v, z, repeats)

    def value_and_jac(z):
        def with_value(q):
            val, aux = v(q)
            return val, (val, aux)

        jac, (val, aux) = jax.jacfwd(with_value, has_aux=True)(z)
        return val, jac, aux

    if batched:
        lone = value_and_jac

        def value_and_jac(z):
            return jax.tree_util.tree_map(lambda a: a[0], jax.vmap(lone)(z[None]))

    (val2, jac, _), first_g, run_g = _timed(value_and_jac, z, repeats)
    return {
        "value": float(val),
        "status": str(jw.status_name(status)),
        "cracks": int(cracks),
        "grad": [float(g) for g in jac],
        "forward_s": run_f,
        "forward_first_s": first_f,
        "value_and_jacfwd_s": run_g,
        "value_and_jacfwd_first_s": first_g,
        "ratio": run_g / run_f,
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="t1 = 10 s, files suffixed _quick")
    ap.add_argument("--scenes", default=",".join(SCENES))
    ap.add_argument("--recompute", action="store_true", help="redo the cached references")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--reference-only", action="store_true", help="only fill the cache")
    ap.add_argument(
        "--batched", action="store_true", help="the derivative under vmap (a batch of one)"
    )
    ap.add_argument(
        "--sensitivity-norm",
        choices=("state", "mean_position"),
        default="state",
        help="Numerics.sensitivity_norm of the derivative (not 'state': files suffixed "
        "with it; 'mean_position' is jw.optimise's for the velocity objective)",
    )
    args = ap.parse_args(argv)
    goal = args.sensitivity_norm != "state"
    t1 = 10.0 if args.quick else 60.0
    folder = _bench.results_dir("gradient_accuracy")
    quick = _bench.quick_suffix(args.quick)
    cache_path = folder / f"gradient_accuracy_reference{quick}.json"
    cache = json.loads(cache_path.read_text()) if cache_path.exists() else {}
    rows = []
    for name in args.scenes.split(","):
        scene = SCENES[name]
        for objective in OBJECTIVES:
            key = f"{name}/{objective}/{t1}"
            if args.recompute or key not in cache:
                cache[key] = reference(scene, objective, t1)
                cache_path.write_text(json.dumps(cache, indent=1))
            ref = cache[key]
            if args.reference_only:
                continue
            got = default_derivative(
                scene, objective, t1, args.repeats, args.batched, args.sensitivity_norm
            )
            z = _point(scene)
            g, r = np.array(got["grad"]), np.array(ref["slope"])
            scale = np.max(np.abs(z * r))
            err = np.abs(z * (g - r)) / scale
            row = {
                "scene": name,
                "objective": objective,
                "t1": t1,
                "reference": ref,
                "default": got,
                "scaled_error": err.tolist(),
                "max_scaled_error": float(err.max()),
                "reference_scaled_stderr": (np.abs(z * np.array(ref["stderr"])) / scale).tolist(),
            }
            rows.append(row)
            print(
                f"{name:12s} {objective:13s} err {err.max():.4f} ratio {got['ratio']:.1f} "
                f"grad {g} ref {r}",
                file=sys.stderr,
                flush=True,
            )
    out = {
        "machine": _bench.machine_info(),
        "t1": t1,
        "reference_numerics": repr(TIGHT),
        "fit": {"rel_step": REL_STEP, "half_width": HALF_WIDTH},
        "rows": rows,
        "command": "python benchmarks/gradient_accuracy.py"
        + (" --quick" if args.quick else "")
        + (" --batched" if args.batched else "")
        + (f" --sensitivity-norm {args.sensitivity_norm}" if goal else ""),
        "batched": args.batched,
        "sensitivity_norm": args.sensitivity_norm,
    }
    tag = (
        quick + ("_batched" if args.batched else "") + (f"_{args.sensitivity_norm}" if goal else "")
    )
    _bench.write_json(folder / f"gradient_accuracy{tag}.json", out)
    m = out["machine"]
    lines = [
        f"# Default derivative against finite differences ({t1:g} s"
        + (", under `jax.vmap`, a batch of one" if args.batched else "")
        + (f", sensitivity_norm {args.sensitivity_norm!r}" if goal else "")
        + ")",
        "",
        f"`{out['command']}` on {m['cpu']} ({m['cpus']} CPUs), jax {m['jax']}, {m['date']}, "
        f"load {m['load_average_at_start'][0]:.1f} at start.",
        "",
        "Scaled error: max_i |θ_i (g_i − ref_i)| / max_j |θ_j ref_j|, the reference the "
        "least-squares slope of 21 tight solves over ±0.5 % (its scaled standard error "
        "beside it). Ratio: value-and-jacfwd time over the forward solve, default "
        "numerics, after compilation.",
        "",
        "| scene | objective | status, cracks | d v̄/dA | ref | d v̄/dω | ref | d v̄/dδ | ref | "
        "scaled error | ref stderr | 1 % central (A, ω, δ) | ratio |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        g, r = row["default"]["grad"], row["reference"]["slope"]
        c = row["reference"]["central_1pc"]
        lines.append(
            f"| {row['scene']} | {row['objective']} | {row['default']['status']}, "
            f"{row['default']['cracks']} | "
            + " | ".join(f"{a:.5g} | {b:.5g}" for a, b in zip(g, r))
            + f" | {row['max_scaled_error']:.4f} | {max(row['reference_scaled_stderr']):.4f} | "
            + ", ".join(f"{x:.4g}" for x in c)
            + f" | {row['default']['ratio']:.1f} |"
        )
    (folder / f"gradient_accuracy{tag}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()

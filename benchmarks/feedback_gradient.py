"""Is there a right derivative for a controller that reads the crack? The exact jump
conditions (`crack_sensitivity="exact"`, the only mode such a controller is allowed)
against the finite-difference slope of a tight solve, over horizons of a few to tens of
cracks.

    python benchmarks/feedback_gradient.py [--horizons 1,2,5,10]

Two controllers that read K_I/K_Ic:

- `reflex`: a `ReflexWave` with a stress reflex (A = 0.02 m/s, ω = 4π, δ = −π/4,
  g_K = 1, g_v = 0.5, g_δ = 0.3) on the Table-1 soil (δ = −π/4), over t1; parameters
  (A, g_K, g_δ);
- `policy`: the trained `PolicyMLP` of `results/closed_loop/` on its first training
  soil, over the whole periods within t1; parameters (b, δ, ω).

Reference: 21 tight solves (`fast` at atol 1e-10) per parameter at θ(1 + k·5e-4),
k = −10..10, in one batch; the slope is their least-squares line, with its standard
error. Scaled error as in `gradient_accuracy.py`: |θ_i (g_i − ref_i)| / max_j
|θ_j ref_j|. Writes results/feedback_gradient/feedback_gradient.{json,md}.
"""

from __future__ import annotations

import argparse
import json
import math
import time

import _bench  # (first: sets OPENBLAS_NUM_THREADS before jax loads)
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from _results import machine_info, machine_line, results_dir, write_json
from closed_loop import A_MAX, TRAIN, layered_soil
from gradient_accuracy import HALF_WIDTH, REL_STEP  # the same reference as there

import jaxworm as jw

TIGHT = jw.PRESETS["fast"].replace(atol=1e-10, max_cracks=512)
EXACT = jw.PRESETS["fast"].replace(crack_sensitivity="exact", max_cracks=512)


def reflex_scene():
    base = jw.Params().replace(delta=-math.pi / 4)
    reflex = jw.ReflexWave(
        A=0.02, omega=4 * math.pi, delta=-math.pi / 4, gain_stress=1.0, gain_speed=0.5,
        gain_phase=0.3,
    )  # fmt: skip

    def params(z):
        g = eqx.tree_at(lambda c: (c.A, c.gain_stress, c.gain_phase), reflex, tuple(z))
        return eqx.tree_at(lambda p: p.gait, base, g)

    return params, np.array([0.02, 1.0, 0.3]), ("A", "gain_stress", "gain_phase"), "t1"


def policy_scene():
    folder = results_dir("closed_loop")
    wave = json.loads((folder / "closed_loop.json").read_text())["wave"]
    start = jw.PolicyMLP.init(
        jax.random.key(0), 7, omega=wave["omega"], delta=wave["delta"], b=3.0, A_max=A_MAX
    )
    policy = eqx.tree_deserialise_leaves(folder / "closed_loop_policy.eqx", start)
    soil = layered_soil(TRAIN[0])

    def params(z):
        g = eqx.tree_at(lambda c: (c.b, c.delta, c.omega), policy, tuple(z))
        return jw.Params(soil=soil, gait=g)

    z = np.array([float(policy.b), float(policy.delta), float(policy.omega)])
    return params, z, ("b", "delta", "omega"), "whole_periods"


SCENES = {"reflex": reflex_scene, "policy": policy_scene}


def check(scene: str, t1: float) -> dict:
    params, z, names, horizon = SCENES[scene]()

    def v(zz, numerics):
        r = jw.simulate(params(zz), t1, numerics, horizon=horizon)
        return r.mean_velocity, (r.n_cracks, r.status)

    t = time.perf_counter()
    grad, (cracks, status) = jax.jit(jax.jacfwd(v, has_aux=True), static_argnums=1)(
        jnp.asarray(z), EXACT
    )
    exact_s = time.perf_counter() - t
    k = np.arange(-HALF_WIDTH, HALF_WIDTH + 1)
    Z = np.repeat(z[None], 3 * k.size, axis=0)
    for i in range(3):
        Z[i * k.size : (i + 1) * k.size, i] *= 1 + k * REL_STEP
    vals, (_, ref_status) = jax.jit(jax.vmap(lambda zz: v(zz, TIGHT)))(jnp.asarray(Z))
    vals = np.asarray(vals).reshape(3, k.size)
    fits = [_bench.slope_fit(z[i] * k * REL_STEP, vals[i]) for i in range(3)]
    slope, stderr = [f[0] for f in fits], [f[1] for f in fits]
    g, s = np.asarray(grad), np.array(slope)
    scale = np.max(np.abs(z * s))
    err = np.abs(z * (g - s)) / scale
    return {
        "scene": scene,
        "t1": t1,
        "names": names,
        "theta": z.tolist(),
        "cracks": int(cracks),
        "status": str(jw.status_name(status)),
        "reference_all_ok": bool(np.all(np.asarray(ref_status) == 0)),
        "exact": g.tolist(),
        "slope": slope,
        "stderr": stderr,
        "scaled_error": err.tolist(),
        "max_scaled_error": float(err.max()),
        "reference_scaled_stderr": float(np.max(np.abs(z * np.array(stderr))) / scale),
        "exact_s": exact_s,
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--horizons", default="1,2,5,10", help="t1 values [s], comma-separated")
    ap.add_argument("--scenes", default=",".join(SCENES))
    args = ap.parse_args(argv)
    rows = []
    for scene in args.scenes.split(","):
        for t1 in (float(h) for h in args.horizons.split(",")):
            row = check(scene, t1)
            rows.append(row)
            _bench.log(
                f"{scene} t1 {t1:g}: {row['cracks']} cracks, exact {row['exact']} "
                f"slope {row['slope']} scaled error {row['max_scaled_error']:.3f}"
            )
    folder = results_dir("feedback_gradient")
    out = {"machine": machine_info(), "rows": rows}
    write_json(folder / "feedback_gradient.json", out)
    lines = [
        "# The exact derivative of a controller that reads the crack, against finite differences",
        "",
        f"`python benchmarks/feedback_gradient.py --horizons {args.horizons}`. "
        + machine_line(out["machine"]),
        "",
        "Reference: least-squares slope of 21 tight solves (atol 1e-10) over ±0.5 % per "
        "parameter, its scaled standard error beside it. Scaled error: "
        "max_i |θ_i (g_i − ref_i)| / max_j |θ_j ref_j|.",
        "",
    ]
    lines += _bench.md_table(
        ["scene", "t1 s", "cracks", "parameters", "exact", "slope", "scaled error", "ref stderr"],
        [
            [
                r["scene"],
                f"{r['t1']:g}",
                r["cracks"],
                ", ".join(r["names"]),
                ", ".join(f"{x:.4g}" for x in r["exact"]),
                ", ".join(f"{x:.4g}" for x in r["slope"]),
                f"{r['max_scaled_error']:.3f}",
                f"{r['reference_scaled_stderr']:.3f}",
            ]
            for r in rows
        ],
    )
    (folder / "feedback_gradient.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()

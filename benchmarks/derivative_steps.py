"""How many steps does a right derivative need? d v̄/d(A, ω, δ) under several step
controls, against the tight slopes of `gradient_accuracy.py`.

The default derivative (forward sensitivities of the Rodas4 solve) puts the
sensitivities' local error into the step control (`Numerics.sensitivity_tol`). Left out
(`sensitivity_tol=None`), the steps are the forward solve's own, and so is the
derivative of any method that differentiates that discrete solve (forward sensitivities,
a discrete adjoint, automatic differentiation of its steps). This measures what that
costs in accuracy, and what tighter state tolerances buy back.

    python benchmarks/derivative_steps.py [--scenes mirror,friction]

Scenes and reference slopes: `gradient_accuracy.py` (its cached references, whole
periods within 60 s). Scaled error as there: max_i |θ_i (g_i − ref_i)| / max_j |θ_j ref_j|.
Writes results/derivative_steps/derivative_steps.{json,md}.
"""

from __future__ import annotations

import argparse
import json
import time

import _bench  # noqa: F401  (first: sets OPENBLAS_NUM_THREADS before jax loads)
import _results as R
import jax
import jax.numpy as jnp
import numpy as np
from gradient_accuracy import NAMES, SCENES

import jaxworm as jw

FAST = jw.PRESETS["fast"].replace(max_cracks=256)
VARIANTS = {
    "default (sensitivity_tol 10)": FAST,
    "state's steps (sensitivity_tol None)": FAST.replace(sensitivity_tol=None),
    "state's steps, no Hessian term": FAST.replace(sensitivity_tol=None, sensitivity_hessian=False),
    "state's steps, atol 1e-9": FAST.replace(sensitivity_tol=None, atol=1e-9),
    "state's steps, atol 1e-9, no Hessian term": FAST.replace(
        sensitivity_tol=None, atol=1e-9, sensitivity_hessian=False
    ),
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="mirror,friction")
    args = ap.parse_args()
    folder = R.results_dir("gradient_accuracy")
    refs = json.loads((folder / "gradient_accuracy_reference.json").read_text())
    rows = []
    for scene in args.scenes.split(","):
        base = jw.Params().replace(**SCENES[scene])
        z0 = jnp.array([base.gait.A, base.gait.omega, base.gait.delta])
        ref = np.array(refs[f"{scene}/whole_periods/60.0"]["slope"])
        forward = jax.jit(
            lambda z, base=base: (
                jw.simulate(
                    base.replace(**dict(zip(NAMES, z))), jw.whole_period_horizon(z[1], 60.0)
                ).steps
            )
        )
        forward_steps = int(forward(z0))
        for label, numerics in VARIANTS.items():

            def v(z, numerics=numerics, base=base):
                p = base.replace(**dict(zip(NAMES, z)))
                r = jw.simulate(p, jw.whole_period_horizon(z[1], 60.0), numerics)
                return r.mean_velocity, r.steps

            f = jax.jit(jax.jacfwd(v, has_aux=True))
            g, steps = f(z0)
            walls = []
            for _ in range(3):  # the first warm calls still warm up: keep the fastest
                t0 = time.perf_counter()
                jax.block_until_ready(f(z0))
                walls.append(time.perf_counter() - t0)
            wall = min(walls)
            g = np.asarray(g)
            scale = np.max(np.abs(np.asarray(z0) * ref))
            err = float(np.max(np.abs(np.asarray(z0) * (g - ref))) / scale)
            rows.append({"scene": scene, "control": label, "derivative": g.tolist(),
                         "reference": ref.tolist(), "scaled_error": err, "steps": int(steps),
                         "forward_steps": forward_steps, "wall_s": wall})  # fmt: skip
            print(rows[-1], flush=True)
    R.write_json(R.results_dir("derivative_steps") / "derivative_steps.json", {"rows": rows})
    run = R.run_record()
    lines = [
        "# How many steps a right derivative needs (whole periods within 60 s)",
        "",
        f"`{run['command']}` on {run['machine']} ({run['cores']} cores), {run['date']}, "
        f"load {run['load'][0]:.1f} at start. Steps: the derivative's solve; forward: the "
        "`fast` forward solve of the same scene. References: `gradient_accuracy`'s slopes.",
        "",
        "| scene | step control | steps | × forward steps | d v̄/dA | d v̄/dω | d v̄/dδ "
        "| scaled error | s (fastest of 3 warm) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        d = r["derivative"]
        lines.append(
            f"| {r['scene']} | {r['control']} | {r['steps']} | "
            f"{r['steps'] / r['forward_steps']:.2f} | {d[0]:.5g} | {d[1]:.4g} | {d[2]:.5g} | "
            f"{100 * r['scaled_error']:.2f} % | {r['wall_s']:.2f} |"
        )
    for scene in args.scenes.split(","):
        ref = next(r["reference"] for r in rows if r["scene"] == scene)
        lines.append(
            f"| {scene} | reference (tight slope) | | | {ref[0]:.5g} | {ref[1]:.4g} "
            f"| {ref[2]:.5g} | | |"
        )
    path = R.results_dir("derivative_steps") / "derivative_steps.md"
    path.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()

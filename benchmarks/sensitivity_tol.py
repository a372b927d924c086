"""The default derivative's step control, looser: d v̄/d(A, ω, δ) over 60 s at several
`Numerics.sensitivity_tol`, on every scene of `gradient_accuracy.py` and both of its
objectives (a fixed 60 s, and the whole gait periods within it), against its tight slopes.

    python benchmarks/sensitivity_tol.py [--tols 10,30,50]

The sensitivities' local error enters the step control with tolerance
`atol · sensitivity_tol`; a looser one takes fewer steps. This measures how many, and
what it costs in accuracy (issue 14's bar: every scene within 2 %, scaled error as in
`gradient_accuracy.py`: max_i |θ_i (g_i − ref_i)| / max_j |θ_j ref_j|). Steps only, no
timings (a step's cost does not depend on the tolerance: `sensitivity_steps.py`).
Writes results/sensitivity_tol/sensitivity_tol.{json,md}.
"""

from __future__ import annotations

import argparse
import json

import _bench  # first: sets OPENBLAS_NUM_THREADS before jax loads
import _results as R
import jax
import jax.numpy as jnp
import numpy as np
from gradient_accuracy import MAX_CRACKS, OBJECTIVES, SCENES, _point, _velocity

import jaxworm as jw

T1 = 60.0


def _derivative(scene: dict, objective: str, numerics):
    """(θ, d v̄/dθ, steps, cracks) of the scene's 60-s objective, θ = (A, ω, δ)."""
    z0 = jnp.asarray(_point(scene))
    jac = jax.jacfwd(_velocity(scene, objective, T1, numerics), has_aux=True)
    g, (_, cracks, steps) = jax.jit(jac)(z0)
    return np.asarray(z0), np.asarray(g), int(steps), int(cracks)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tols", default="10,30,50")
    args = ap.parse_args(argv)
    refs = json.loads(
        (R.results_dir("gradient_accuracy") / "gradient_accuracy_reference.json").read_text()
    )
    run = R.run_record()
    rows = []
    for tol in [float(t) for t in args.tols.split(",")]:
        numerics = jw.PRESETS["fast"].replace(sensitivity_tol=tol, max_cracks=MAX_CRACKS)
        for objective in OBJECTIVES:
            for name, scene in SCENES.items():
                ref = np.asarray(refs[f"{name}/{objective}/{T1}"]["slope"])
                z0, g, steps, cracks = _derivative(scene, objective, numerics)
                err = float(np.max(np.abs(z0 * (g - ref))) / np.max(np.abs(z0 * ref)))
                rows.append({"sensitivity_tol": tol, "objective": objective, "scene": name,
                             "steps": steps, "n_cracks": cracks, "derivative": g.tolist(),
                             "reference": ref.tolist(), "scaled_error": err})  # fmt: skip
                print(rows[-1], flush=True)
    folder = R.results_dir("sensitivity_tol")
    R.write_json(folder / "sensitivity_tol.json", {"run": run, "rows": rows})
    lines = [
        "# The default derivative at looser sensitivity tolerances (60 s)",
        "",
        f"`{run['command']}` on {run['machine']} ({run['cores']} cores), {run['date']}, "
        f"load {run['load'][0]:.1f} at start. `fast` with `sensitivity_tol` as the column "
        "says (default 10); scaled error against `gradient_accuracy`'s tight slopes "
        "(the bar: 2 %).",
        "",
    ]
    tols = sorted({r["sensitivity_tol"] for r in rows})
    header = ["objective", "scene", f"cracks (tol {tols[0]:g})"]
    header += [f"tol {t:g}: steps / error" for t in tols]
    table = []
    for objective in OBJECTIVES:
        for name in SCENES:
            cells = [objective, name]
            mine = [r for r in rows if r["objective"] == objective and r["scene"] == name]
            cells.append(str(mine[0]["n_cracks"]))
            for t in tols:
                r = next(r for r in mine if r["sensitivity_tol"] == t)
                cells.append(f"{r['steps']} / {100 * r['scaled_error']:.2f} %")
            table.append(cells)
    worst = ["largest error", "", ""]
    for t in tols:
        errs = [r["scaled_error"] for r in rows if r["sensitivity_tol"] == t]
        worst.append(f"{100 * max(errs):.2f} %")
    lines += _bench.md_table(header, [*table, worst])
    (folder / "sensitivity_tol.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()

"""Which differentiable setting is the fastest within 1 % on every scene, and what do
its gradients cost in accuracy? (issue 3, defaults)

    python benchmarks/differentiable_defaults.py [--atols 1e-6,1e-7]

`fast` (Rodas4) is the fastest setting within 1 % on every scene but is forward-only, so
`jax.grad`, `jw.optimise` and `jw.simulate`'s Python default need a Kvaerno solver. This
runs Kvaerno3 on the positions norm at looser tolerances than `default` (atol 1e-8 m):

1. on every scene and horizon of the presets check, against the references stored in
   `benchmarks/results/work_precision/presets.json` (same scenes, same error measure);
2. d(mean velocity)/dω of the nominal gait at the 8 frequencies of
   `gradient_presets.py`, against `accurate`'s forward-mode values stored in
   `benchmarks/results/gradient_presets/gradient_presets.json`.

Writes benchmarks/results/differentiable_defaults/differentiable_defaults.{json,md}.
"""

from __future__ import annotations

import argparse
import json
import time

import _bench as B  # (first: sets the BLAS threads before numpy loads)
import equinox as eqx  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

jw = B.jw


def candidates(atols) -> dict[str, jw.Numerics]:
    out = {"default (atol 1e-08)": jw.PRESETS["default"]}
    out.update({f"Kvaerno3 atol {a:g}": jw.PRESETS["default"].replace(atol=a) for a in atols})
    return out


def scene_errors(num: jw.Numerics, presets: dict) -> list[dict]:
    rows = []
    for (name, t1), (params, v_ref) in presets.items():
        res = B.run_jax(num, params, t1, repeats=1)
        rows.append(
            {
                "scene": name,
                "t1": t1,
                "error": B.rel_error(res["mean_velocity"], v_ref),
                "wall_s": res["wall_s"],
                "status": res["status"],
            }
        )
    return rows


def omega_gradients(num: jw.Numerics, omegas, t1: float) -> tuple[np.ndarray, float]:
    p = jw.Params()
    f = eqx.filter_jit(
        jax.vmap(
            jax.jacfwd(
                lambda w: (
                    jw.simulate(
                        p.replace(omega=w),
                        t1,
                        num.replace(adjoint="forward", crack_sensitivity="exact"),
                    ).mean_velocity
                )
            )
        )
    )
    t = time.perf_counter()
    g = np.asarray(f(jnp.asarray(omegas)))
    return g, time.perf_counter() - t


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--atols", default="1e-6,1e-7")
    args = ap.parse_args(argv)
    stored = json.loads((B.RESULTS / "work_precision" / "presets.json").read_text())
    scenes = {
        (r["scene"], r["t1"]): (r["params"], r["reference_velocity"])
        for r in stored["rows"]
        if r["preset"] == "default"
    }
    grads = json.loads((B.RESULTS / "gradient_presets" / "gradient_presets.json").read_text())
    ref_grad = np.asarray(grads["accurate_jacfwd_vmap"])
    out = {"machine": B.machine_info(), "scenes": len(scenes), "rows": {}, "verdict": {}}
    for label, num in candidates([float(a) for a in args.atols.split(",")]).items():
        B.log(f"[defaults] {label}")
        rows = scene_errors(num, scenes)
        g, g_wall = omega_gradients(num, grads["omega"], grads["t1"])
        worst = max(rows, key=lambda r: r["error"])
        out["rows"][label] = rows
        out["verdict"][label] = {
            "max_error": worst["error"],
            "worst_scene": worst["scene"],
            "worst_t1": worst["t1"],
            "all_ok": all(r["status"] == "ok" for r in rows),
            "within_1pct": worst["error"] <= 1e-2,
            "total_wall_s": sum(r["wall_s"] for r in rows),
            "domega_max_abs_error": float(np.max(np.abs(g - ref_grad))),
            "domega": g.tolist(),
            "domega_wall_s_with_compile": g_wall,
        }
    out["domega_accurate"] = ref_grad.tolist()
    folder = B.results_dir("differentiable_defaults")
    B.write_json(folder / "differentiable_defaults.json", out)
    m = out["machine"]
    lines = [
        "# Differentiable defaults: Kvaerno3 at looser tolerances",
        "",
        f"Machine: {m['cpu']}, {m['cpus']} CPUs, jax {m['jax']}, commit {m['git_commit']}; "
        f"{m['date']}. {len(scenes)} scene-horizons of the presets check (references from "
        "presets.json); d v̄/dω at 8 frequencies, t1 = 10 s, against `accurate` "
        f"(values {np.min(np.abs(ref_grad)):.1e} to {np.max(np.abs(ref_grad)):.1e}).",
        "",
    ]
    lines += B.md_table(
        [
            "setting",
            "max error in v̄",
            "worst scene",
            "all ok",
            "within 1 %",
            "total wall s",
            "max |d v̄/dω − accurate|",
        ],
        [
            [
                k,
                f"{v['max_error']:.2e}",
                f"{v['worst_scene']} {v['worst_t1']:g} s",
                v["all_ok"],
                v["within_1pct"],
                f"{v['total_wall_s']:.1f}",
                f"{v['domega_max_abs_error']:.2e}",
            ]
            for k, v in out["verdict"].items()
        ],
    )
    (folder / "differentiable_defaults.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()

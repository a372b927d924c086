"""Derivatives with respect to the body's parameters (l0, m, EA) against finite
differences: where the `fast` preset's positions error norm falls short.

    python benchmarks/body_gradient.py [--t1 0.3,2]

The gait: Table 1 with δ = −π/4. For each body parameter θ and horizon t1:
d v̄/dθ by `jax.grad` of `jw.simulate` with the default numerics (`fast`), with
`sensitivity_tol=1`, and with `norm="full"` (the error of the velocities controlled
too); central differences (1 % steps) of each of those solves' own values, and of a
tight solve (Rodas4, atol 1e-11), the reference. The body's parameters set
the initial state and its elastic ringing, which the positions norm steps over: the
`fast` solve's own dependence on them then differs from the tight one's, so no control
of the sensitivities alone can make its derivative right. Each derivative is shown
scaled, θ·d v̄/dθ, beside θ_A·d v̄/dA of the same run (the largest component of the
gait's derivatives), so that an error can be read both ways: relative to its own
component and to the gradient's largest.

Since `jw.simulate` takes the full norm itself for a derivative along l0, m or EA, the
`fast (default)` rows of a run now repeat the `norm full` ones; the committed run (code
2fcc7d9, before that switch) shows the positions norm's derivative, which it replaced.

Writes results/body_gradient/body_gradient.{json,md}.
"""

from __future__ import annotations

import argparse
import sys
import time

import _bench as B  # (first: sets the BLAS threads before numpy loads)
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

jw = B.jw

BASE = jw.Params(gait=jw.TravellingWave(delta=-jnp.pi / 4))
FAST = jw.PRESETS["fast"]
NUMERICS = {
    "fast (default)": FAST,
    "fast, sensitivity_tol 1": FAST.replace(sensitivity_tol=1.0),
    "fast, norm full": FAST.replace(norm="full"),
}
TIGHT = jw.Numerics(solver="Rodas4", atol=1e-11)
PARAMETERS = ("l0", "m", "EA")
STEP = 0.01  # relative step of the central differences


def velocity(name, value, t1, numerics):
    return jw.simulate(BASE.replace(**{name: value}), t1, numerics).mean_velocity


def central(name, t1, numerics):
    theta = float(BASE.flat()[name])
    h = STEP * theta
    up, down = (float(velocity(name, theta + s, t1, numerics)) for s in (h, -h))
    return (up - down) / (2 * h)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--t1", default="0.3,2", help="horizons [s], comma-separated")
    args = ap.parse_args()
    horizons = [float(t) for t in args.t1.split(",")]
    rows = []
    for t1 in horizons:
        a = float(BASE.flat()["A"])
        scale_A = a * float(jax.grad(lambda x, t=t1: velocity("A", x, t, FAST))(a))
        for name in PARAMETERS:
            theta = float(BASE.flat()[name])
            reference = central(name, t1, TIGHT)
            for label, numerics in NUMERICS.items():
                start = time.perf_counter()
                g = float(jax.grad(lambda x, n=name, q=numerics, t=t1: velocity(n, x, t, q))(theta))
                wall = time.perf_counter() - start
                own = central(name, t1, numerics)
                r = jw.simulate(BASE, t1, numerics)
                rows.append(
                    {
                        "t1": t1,
                        "parameter": name,
                        "numerics": label,
                        "derivative": g,
                        "own_difference": own,
                        "reference": reference,
                        "scaled_error": theta * (g - reference) / abs(scale_A),
                        "relative_error": (g - reference) / abs(reference),
                        "scaled_A": scale_A,
                        "steps": int(r.steps),
                        "grad_wall_s": wall,
                    }
                )
                B.log(
                    f"{t1:g} s, {name}, {label}: {g:.5g} (own FD {own:.5g}, tight {reference:.5g})"
                )
    out = {"run": B.run_record(), "machine": B.machine_info(), "rows": rows}
    folder = B.results_dir("body_gradient")
    B.write_json(folder / "body_gradient.json", out)
    lines = [
        "# Derivatives with respect to the body's parameters against finite differences",
        "",
        B.machine_line(out["machine"]),
        "",
        f"Command: `{out['run']['command']}`. Table 1, δ = −π/4. Reference: central "
        "differences (1 % steps) of Rodas4 at atol 1e-11. Own FD: the same "
        "differences of the row's own numerics. Scaled error: θ (derivative − reference) "
        "over |θ_A d v̄/dA| (`fast`), the gradient's largest component. Steps: the "
        "forward solve's. Grad s: one call; the first horizon's include compilation (t1 "
        "is an argument of the compiled program).",
        "",
        *B.md_table(
            [
                "t1 s",
                "θ",
                "numerics",
                "d v̄/dθ",
                "own FD",
                "reference",
                "relative error",
                "scaled error",
                "steps",
                "grad s",
            ],
            [
                [
                    f"{r['t1']:g}",
                    r["parameter"],
                    r["numerics"],
                    f"{r['derivative']:.4g}",
                    f"{r['own_difference']:.4g}",
                    f"{r['reference']:.4g}",
                    f"{r['relative_error']:+.1%}",
                    f"{r['scaled_error']:+.1%}",
                    r["steps"],
                    f"{r['grad_wall_s']:.1f}",
                ]
                for r in rows
            ],
        ),
    ]
    (folder / "body_gradient.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Which parameter directions drive the derivative's steps, and what a step costs: the
forward solve against `jax.jacfwd` of `jw.simulate` with respect to one gait parameter at
a time and to all three, on a crack-free scene (Table 1, 20 s: no crack), default
numerics (`fast`, sensitivity_tol 10, phase frame), through the public API only; then,
for A alone and for all three, two variants that split a step's cost: without the
second-derivative term of the augmented Jacobian (`sensitivity_hessian=False`) and on the
state's own steps (`sensitivity_tol=None`). Last, the same forward solve and derivative
in all three on models whose sign of the friction is smoothed more (`Smoothing.eps_v`
1e-4 m/s, the default, 3e-4 and 1e-3): where the steps of the δ and ω directions go.
Each eps_v is another model (its own mean velocity and derivative, in the table).

    python benchmarks/sensitivity_steps.py

With Rodas4, `jax.jacfwd` of `jw.simulate` integrates the state with its sensitivities
along the differentiated parameters in one solve, under one error control; the primal
`Result` returned beside the derivative (`has_aux`) counts that solve's steps. Each row
is a jit-compiled function of (A, ω, δ) (the same traced inputs in every row),
differentiated with respect to the row's parameters only; the first row is the forward
solve alone.

Writes benchmarks/results/sensitivity_steps/sensitivity_steps.{json,md}. Fastest of 5 runs
after compilation (`_bench.first_call_and_runs`).
"""

from __future__ import annotations

import argparse

import _bench  # sets OPENBLAS_NUM_THREADS before jax loads
import jax

import jaxworm as jw

T1 = 20.0
GAIT = ("A", "omega", "delta")
#: The smoothing scales of the friction's sign compared [m/s] (the first: the default).
EPS_V = (1e-4, 3e-4, 1e-3)


#: The rows' numerics beside the default (label -> options of the `fast` preset).
VARIANTS = {
    "default": {},
    "no Hessian term": {"sensitivity_hessian": False},
    "state's steps": {"sensitivity_tol": None},
    "state's steps, no Hessian term": {"sensitivity_tol": None, "sensitivity_hessian": False},
}


def _velocity(p: jw.Params, names: tuple[str, ...], variant: str = "default"):
    """(values of `names`, values of the rest of (A, ω, δ)) -> (mean velocity, Result)
    of the scene `p` with that gait, solved with the numerics of `variant`."""
    rest = tuple(n for n in GAIT if n not in names)
    numerics = jw.PRESETS["fast"].replace(**VARIANTS[variant])

    def run(theta, others):
        r = jw.simulate(p.replace(**dict(zip(names + rest, theta + others))), T1, numerics)
        return r.mean_velocity, r

    return run, rest


def _row(names: tuple[str, ...], p: jw.Params, variant: str = "default") -> dict:
    """Steps, status and fastest run, jit-compiled, of the forward solve (`names` empty)
    or of `jax.jacfwd` with respect to the gait parameters `names`; the rest of
    (A, ω, δ) are arguments too, so every row traces the same inputs."""
    run, rest = _velocity(p, names, variant)
    fn = jax.jacfwd(run, has_aux=True) if names else run
    args = tuple(tuple(getattr(p.gait, n) for n in group) for group in (names, rest))
    (value, r), _, runs = _bench.first_call_and_runs(fn, args, 5)  # value: v̄ or its derivative
    steps = int(r.steps)
    derivative = [float(d) for d in value] if names else None
    return {
        "directions": ", ".join(names) or "none (state alone)",
        "numerics": variant,
        "steps": steps,
        "mean_velocity": float(r.mean_velocity),
        "derivative": derivative,
        "ok": jw.status_name(r.status) == "ok",
        "n_cracks": int(r.n_cracks),
        "run_s": min(runs),
        "us_per_step": min(runs) / steps * 1e6,
    }


def main(argv=None):
    argparse.ArgumentParser(description=__doc__.splitlines()[0]).parse_args(argv)
    p = jw.Params()
    rows = []
    plan = [(names, "default") for names in ((), ("A",), ("omega",), ("delta",), GAIT)]
    plan += [(names, v) for v in list(VARIANTS)[1:] for names in (("A",), GAIT)]
    for names, variant in plan:
        rows.append(_row(names, p, variant))
        print(rows[-1], flush=True)
    base = rows[0]
    smoothing = []
    for eps_v in EPS_V:
        ps = p.replace(smoothing=jw.Smoothing(eps_v=eps_v))
        for names in ((), GAIT):
            smoothing.append({"eps_v": eps_v, **_row(names, ps)})
            print(smoothing[-1], flush=True)
    out = {
        "machine": _bench.machine_info(),
        "scene": f"Table 1, {T1:g} s, no cracks",
        "command": "python benchmarks/sensitivity_steps.py",
        "rows": rows,
        "smoothing": smoothing,
    }
    folder = _bench.results_dir("sensitivity_steps")
    _bench.write_json(folder / "sensitivity_steps.json", out)
    m = out["machine"]
    lines = [
        f"# Forward-sensitivity steps by direction: {out['scene']}",
        "",
        f"`{out['command']}` on {m['cpu']} ({m['cpus']} CPUs), jax {m['jax']}, {m['date']}, "
        f"load {m['load_average_at_start'][0]:.1f} at start. Numerics `fast` (sensitivity_tol "
        "10, phase frame), changed as the numerics column says (`VARIANTS`); `jax.jacfwd` "
        "of `jw.simulate` with respect to the row's parameters, steps from the primal "
        "`Result`.",
        "",
    ]
    lines += _bench.md_table(
        [
            "sensitivities of",
            "numerics",
            "steps",
            "× state's steps",
            "run s",
            "µs per step",
            "× state's µs per step",
        ],
        [
            [
                r["directions"],
                r["numerics"],
                r["steps"],
                f"{r['steps'] / base['steps']:.2f}",
                f"{r['run_s']:.3f}",
                f"{r['us_per_step']:.1f}",
                f"{r['us_per_step'] / base['us_per_step']:.2f}",
            ]
            for r in rows
        ],
    )
    lines += [
        "",
        "## The friction sign's smoothing",
        "",
        "The same forward solve and derivative in (A, ω, δ), default numerics, on models "
        "whose sign of the node velocity is smoothed over eps_v (tanh(v/eps_v); default "
        "1e-4 m/s): each row pair is another model, with its own mean velocity and "
        "derivative.",
        "",
    ]
    state_steps = {r["eps_v"]: r["steps"] for r in smoothing if r["derivative"] is None}
    lines += _bench.md_table(
        ["eps_v m/s", "solve", "steps", "× its state's steps", "run s", "v̄ m/s", "d v̄/d(A, ω, δ)"],
        [
            [
                f"{r['eps_v']:g}",
                r["directions"],
                r["steps"],
                f"{r['steps'] / state_steps[r['eps_v']]:.2f}",
                f"{r['run_s']:.3f}",
                f"{r['mean_velocity']:.6f}",
                ", ".join(f"{d:.4g}" for d in r["derivative"]) if r["derivative"] else "",
            ]
            for r in smoothing
        ],
    )
    (folder / "sensitivity_steps.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()

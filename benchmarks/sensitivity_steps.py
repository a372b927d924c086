"""Which parameter directions drive the forward-sensitivity solve's steps, and what a
step costs: the state alone against the state with the sensitivities of one direction
at a time and of all three, on a crack-free scene (Table 1, 20 s), by diffeqsolve
directly (no crack events), default numerics (`fast`, sensitivity_tol 10, phase frame).

    python benchmarks/sensitivity_steps.py

Writes benchmarks/results/sensitivity_steps/sensitivity_steps.{json,md}. Fastest of 5 runs after
compilation (`_bench.first_call_and_runs`).
"""

from __future__ import annotations

import argparse

import _bench  # sets OPENBLAS_NUM_THREADS before jax loads
import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp

import jaxworm as jw
from jaxworm import crack_condition, initial_crack_tip, initial_state, vector_field

# private: this benchmark times the solver's internals (the augmented state-and-sensitivity
# field, its norm and direction scaling), which `jw.simulate` does not expose
from jaxworm._sensitivity import split_params
from jaxworm._solve import (
    _augmented_field,
    _augmented_norm,
    _direction_scale,
    _directions,
    _event_condition,
    _frequency_rate,
)

T1 = 20.0


def _solve(terms, solver, z0, args, controller, condition):
    event = diffrax.Event(condition, root_finder=jw.PRESETS["fast"].root_finder(), direction=True)

    def run():
        sol = diffrax.diffeqsolve(
            terms,
            solver,
            0.0,
            T1,
            None,
            z0,
            args=args,
            stepsize_controller=controller,
            event=event,
            max_steps=2**20,
            throw=False,
            saveat=diffrax.SaveAt(t1=True),
        )
        return sol.stats["num_steps"], sol.result == diffrax.RESULTS.successful

    (steps, ok), _, runs = _bench.first_call_and_runs(run, (), 5)
    return {
        "steps": int(steps),
        "ok": bool(ok),
        "run_s": min(runs),
        "us_per_step": min(runs) / int(steps) * 1e6,
    }


def main(argv=None):
    argparse.ArgumentParser(description=__doc__.splitlines()[0]).parse_args(argv)
    num = jw.PRESETS["fast"]
    p = jw.Params()
    y0 = initial_state(p)
    xc = initial_crack_tip(p, y0)
    ctrl = num.build_controller()
    rows = [
        {
            "directions": "none (state alone)",
            **_solve(
                diffrax.ODETerm(vector_field),
                num.build_solver(),
                y0,
                (p, xc),
                ctrl,
                crack_condition,
            ),
        }
    ]
    solver = num.build_sensitivity_solver(vector_field)
    for names in (("A",), ("omega",), ("delta",), ("A", "omega", "delta")):
        tp = jax.tree_util.tree_map(lambda a: None, p)
        tp = eqx.tree_at(
            lambda q, names=names: tuple(getattr(q.gait, n) for n in names),
            tp,
            tuple(1.0 for _ in names),
            is_leaf=lambda x: x is None,
        )
        dp, _ = _directions(p, tp)
        pd, pr = split_params(p, dp)
        P = len(names)
        S0 = jax.tree_util.tree_map(lambda a, P=P: jnp.zeros((P,) + a.shape), y0)
        args = (pd, pr, xc, dp, jnp.zeros(P), _frequency_rate(p, dp))  # phase frame
        actrl = eqx.tree_at(
            lambda c: c.norm,
            ctrl,
            _augmented_norm(ctrl.norm, _direction_scale(pd, dp) / num.sensitivity_tol),
        )
        rows.append(
            {
                "directions": ", ".join(names),
                **_solve(
                    diffrax.ODETerm(_augmented_field),
                    solver,
                    (y0, S0),
                    args,
                    actrl,
                    _event_condition,
                ),
            }
        )
        print(rows[-1], flush=True)
    base = rows[0]
    out = {
        "machine": _bench.machine_info(),
        "scene": f"Table 1, {T1:g} s, no cracks",
        "command": "python benchmarks/sensitivity_steps.py",
        "rows": rows,
    }
    folder = _bench.results_dir("sensitivity_steps")
    _bench.write_json(folder / "sensitivity_steps.json", out)
    m = out["machine"]
    lines = [
        f"# Forward-sensitivity steps by direction: {out['scene']}",
        "",
        f"`{out['command']}` on {m['cpu']} ({m['cpus']} CPUs), jax {m['jax']}, {m['date']}, "
        f"load {m['load_average_at_start'][0]:.1f} at start. Default numerics (`fast`, "
        "sensitivity_tol 10, phase frame).",
        "",
    ]
    lines += _bench.md_table(
        [
            "sensitivities of",
            "steps",
            "× state's steps",
            "run s",
            "µs per step",
            "× state's µs per step",
        ],
        [
            [
                r["directions"],
                r["steps"],
                f"{r['steps'] / base['steps']:.2f}",
                f"{r['run_s']:.3f}",
                f"{r['us_per_step']:.1f}",
                f"{r['us_per_step'] / base['us_per_step']:.2f}",
            ]
            for r in rows
        ],
    )
    (folder / "sensitivity_steps.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()

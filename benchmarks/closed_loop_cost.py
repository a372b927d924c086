"""Issue 19, point 6: what a closed-loop controller's solve costs, and why.

    python benchmarks/closed_loop_cost.py [--t1 10] [--rounds 7]

One `fast` solve of the Table 1 soil over `--t1` seconds for each of seven controllers:

- `wave`: the best travelling wave of `results/closed_loop/closed_loop.json` (A = 0.03 m/s;
  ω and δ read from that file), open loop;
- `wave, as feedback`: an `AbstractFeedbackController` that returns the same wave's rate
  and reads no sensor. Its u is the wave's, but the solver takes it for closed loop and
  keeps the controller's rows in every step's Newton matrix;
- `wave, as feedback, open_loop = True`: the same class declared open loop, so the
  solver drops those rows again;
- `policy`: the trained `PolicyMLP` of `results/closed_loop/closed_loop_policy.eqx`;
- `policy, network by equinox's call`: the same weights in an `equinox.nn.MLP` subclass
  with a call of its own, which the policy then calls (a library matrix product per
  layer) instead of writing each layer as a product and a sum;
- `reflex, zero gains`: `ReflexWave` on the same wave with its gains at 0: the wave's
  rates and steps, with every sensor read (K_I/K_Ic, the head's velocity);
- `stress reflex`: the same with an amplitude reflex to K_I/K_Ic (g_K = 1): other
  dynamics, so other steps. (With g_v = 0.5 and g_δ = 0.3 added, as in
  `feedback_gradient.py`, this wave chatters and no tolerance converges its mean
  velocity: docs, known issues.)

Each solve is compiled once, then the controllers are timed in `--rounds` interleaved
rounds, so that a shared machine's load hits them alike. The median and fastest per
simulated second and per solver step (accepted and rejected) are reported. Each mean
velocity's error comes from a tight Rodas4 solve (atol 1e-11), beside that reference's
own spread (its difference from atol 1e-10: a controller that reads K_I changes its crack
count with the steps, so a reference can be less converged than it looks). Writes
`results/closed_loop_cost/closed_loop_cost.{json,md}`.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import _bench as B  # (first: sets the BLAS threads before numpy loads)
import equinox as eqx  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

jw = B.jw

CLOSED_LOOP = Path(__file__).parent / "results" / "closed_loop"
TIGHT = jw.Numerics(solver="Rodas4", atol=1e-11)
LESS_TIGHT = jw.Numerics(solver="Rodas4", atol=1e-10)


class LibraryMLP(eqx.nn.MLP):
    """`equinox.nn.MLP` with a `__call__` of its own (equinox's): `PolicyMLP` calls it."""

    def __call__(self, x, *, key=None):
        return super().__call__(x, key=key)


def with_library_network(policy: jw.PolicyMLP) -> jw.PolicyMLP:
    """The same policy, its network's weights in a `LibraryMLP`."""
    m = policy.mlp
    shape = LibraryMLP(
        m.in_size, m.out_size, m.width_size, m.depth, activation=jnp.tanh,
        key=jax.random.key(0), dtype=float,
    )  # fmt: skip
    leaves = jax.tree_util.tree_leaves(m)
    library = jax.tree_util.tree_unflatten(jax.tree_util.tree_structure(shape), leaves)
    return eqx.tree_at(lambda c: c.mlp, policy, library)


class WaveAsFeedback(jw.AbstractFeedbackController):
    """The travelling wave's rate, as a feedback controller that reads no sensor."""

    wave: jw.TravellingWave

    def control(self, sensors, body):
        return self.wave(sensors.t, None, None, None, body)


class WaveAsFeedbackOpenLoop(WaveAsFeedback):
    """The same, declared open loop: u depends on t alone."""

    open_loop = True


def controllers() -> dict:
    """The seven controllers, from the committed closed-loop run (its wave and policy)."""
    w = json.loads((CLOSED_LOOP / "closed_loop.json").read_text())["wave"]
    wave = jw.TravellingWave(A=w["A"], omega=w["omega"], delta=w["delta"])
    template = jw.PolicyMLP.init(
        jax.random.key(0), 7, omega=w["omega"], delta=w["delta"], b=3.0, A_max=w["A"]
    )
    policy = eqx.tree_deserialise_leaves(CLOSED_LOOP / "closed_loop_policy.eqx", template)
    return {
        "wave": wave,
        "wave, as feedback": WaveAsFeedback(wave),
        "wave, as feedback, open_loop = True": WaveAsFeedbackOpenLoop(wave),
        "policy": policy,
        "policy, network by equinox's call": with_library_network(policy),
        "reflex, zero gains": jw.ReflexWave(A=wave.A, omega=wave.omega, delta=wave.delta),
        "stress reflex": jw.ReflexWave(
            A=wave.A, omega=wave.omega, delta=wave.delta, gain_stress=1.0
        ),
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--t1", type=float, default=10.0, help="simulated seconds (default 10)")
    ap.add_argument("--rounds", type=int, default=7, help="interleaved timing rounds")
    args = ap.parse_args(argv)
    gaits = controllers()
    fns, results, compile_s = {}, {}, {}
    for name, gait in gaits.items():
        fns[name] = eqx.filter_jit(lambda p: jw.simulate(p, args.t1, jw.PRESETS["fast"]))
        start = time.perf_counter()
        results[name] = jax.block_until_ready(fns[name](jw.Params(gait=gait)))
        compile_s[name] = time.perf_counter() - start
        B.log(f"{name}: compiled and ran in {compile_s[name]:.1f} s")
    walls = {name: [] for name in gaits}
    for _ in range(args.rounds):
        for name, gait in gaits.items():
            p = jw.Params(gait=gait)
            start = time.perf_counter()
            jax.block_until_ready(fns[name](p).mean_velocity)
            walls[name].append(time.perf_counter() - start)
    rows = []
    for name, gait in gaits.items():
        r = results[name]
        tight = jw.simulate(jw.Params(gait=gait), args.t1, TIGHT)
        less = jw.simulate(jw.Params(gait=gait), args.t1, LESS_TIGHT)
        steps = int(r.steps) + int(r.rejected_steps)
        median, fastest = float(np.median(walls[name])), float(np.min(walls[name]))
        rows.append(
            {
                "controller": name,
                "ms_per_simulated_s_median": 1e3 * median / args.t1,
                "ms_per_simulated_s_fastest": 1e3 * fastest / args.t1,
                "us_per_step_median": 1e6 * median / steps,
                "steps": int(r.steps),
                "rejected_steps": int(r.rejected_steps),
                "mean_velocity": float(r.mean_velocity),
                "error_vs_tight": B.rel_error(float(r.mean_velocity), float(tight.mean_velocity)),
                "reference_spread": B.rel_error(
                    float(less.mean_velocity), float(tight.mean_velocity)
                ),
                "status": str(r.status_name),
                "walls_s": walls[name],
                "compile_and_first_call_s": compile_s[name],
            }
        )
    base = rows[0]["ms_per_simulated_s_median"]
    base_step = rows[0]["us_per_step_median"]
    out = {"machine": B.machine_info(), "t1": args.t1, "rounds": args.rounds, "rows": rows}
    folder = B.results_dir("closed_loop_cost")
    B.write_json(folder / "closed_loop_cost.json", out)
    m = out["machine"]
    lines = [
        f"# Closed-loop solver cost against the open-loop wave (t1 = {args.t1:g} s, `fast`)",
        "",
        B.machine_line(m),
        "",
        f"Command: `python benchmarks/closed_loop_cost.py --t1 {args.t1:g} --rounds "
        f"{args.rounds}`. Median (and fastest) of {args.rounds} interleaved warm calls; "
        "per step counts accepted and rejected steps. Error: the mean velocity against "
        "Rodas4 at atol 1e-11; reference spread: Rodas4 at 1e-10 against it.",
        "",
        *B.md_table(
            [
                "controller",
                "ms per simulated s (fastest)",
                "× wave",
                "µs per step (× wave)",
                "steps (rejected)",
                "mean velocity m/s",
                "error",
                "reference spread",
                "status",
            ],
            [
                [
                    r["controller"],
                    f"{r['ms_per_simulated_s_median']:.2f} ({r['ms_per_simulated_s_fastest']:.2f})",
                    f"{r['ms_per_simulated_s_median'] / base:.2f}",
                    f"{r['us_per_step_median']:.1f} ({r['us_per_step_median'] / base_step:.2f})",
                    f"{r['steps']} ({r['rejected_steps']})",
                    f"{r['mean_velocity']:.6f}",
                    f"{r['error_vs_tight']:.1e}",
                    f"{r['reference_spread']:.1e}",
                    r["status"],
                ]
                for r in rows
            ],
        ),
    ]
    (folder / "closed_loop_cost.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())

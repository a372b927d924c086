"""What XLA's CPU elementwise functions cost in float64, and what computing the wave's
sines by angle addition buys.

Two measurements in one process, on one JAX CPU device:

1. **Per element.** Each function applied 2000 times in a loop to a (6, 64) array (six
   segments, 64 lanes): nanoseconds per element. On a CPU XLA vectorises `tanh`, `exp`,
   products and quotients, while a float64 sine, cosine or logarithm is a scalar
   library call.
2. **The wave.** `jw.TravellingWave` computes sin(ωt + δk) by angle addition
   (`sine_of_sum`: sin δk and cos δk stay fixed during a solve, so XLA computes them once),
   against the same wave with one sine per segment and evaluation (`DirectSineWave`,
   the code before): the 60-s Table 1 solve (`fast`) and a lockstep batch of 64 lanes
   (1000 fixed Rodas4 steps over 2 s, the ceiling of `batch_gain.py`), alternated over
   `--rounds` rounds, fastest of each. The mean velocities of both are reported: the two
   waves are the same function to rounding, and adaptive steps turn rounding into
   differences within their tolerance.

    python benchmarks/elementwise_cost.py [--rounds 5]

Writes results/elementwise_cost/elementwise_cost.{json,md}.
"""

from __future__ import annotations

import os

os.environ["XLA_FLAGS"] = "--xla_force_host_platform_device_count=1"

import argparse  # noqa: E402

import _bench as B  # noqa: E402
import _results as R  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from batch_gain import SPAN, STEPS, _best, lockstep  # noqa: E402

import jaxworm as jw  # noqa: E402

LOOP = 2000
SHAPE = (6, 64)
FUNCTIONS = {
    "x·a + b": lambda z: z * 1.0000001 + 1e-9,
    "1/(1 + x²)": lambda z: 1.0 / (1.0 + z * z),
    "sqrt": lambda z: jnp.sqrt(1.0 + z * z),
    "tanh": jnp.tanh,
    "exp": lambda z: jnp.exp(-jnp.abs(z)),
    "log": lambda z: jnp.log(1.5 + z),
    "log1p": lambda z: jnp.log1p(jnp.abs(z)),
    "softplus": jax.nn.softplus,
    "sin": jnp.sin,
    "cos": jnp.cos,
}
LANES = 64


class DirectSineWave(jw.TravellingWave):
    """The travelling wave with one library sine per segment and evaluation."""

    def __call__(self, t, x, v, lbar, body):
        return self.A * jnp.sin(self.phase(t, body.N - 1))


def per_element() -> list[dict]:
    x = jnp.asarray(np.random.default_rng(0).uniform(-1.0, 1.0, SHAPE))
    rows = []
    for name, op in FUNCTIONS.items():
        fn = jax.jit(lambda z, op=op: jax.lax.fori_loop(0, LOOP, lambda i, y: op(y) * 0.5 + 0.1, z))
        wall = min(_best(fn, x, repeats=1) for _ in range(5))
        rows.append({"function": name, "ns_per_element": 1e9 * wall / LOOP / x.size})
        B.log(f"{name}: {rows[-1]['ns_per_element']:.2f} ns per element")
    return rows


def _solve_60(wave_cls):
    def run(delta):
        return jw.simulate(jw.Params(gait=wave_cls(delta=delta)), 60.0).mean_velocity

    return jax.jit(run)


def _lockstep(wave_cls):
    # As `jw.sweep`'s chunks solve: the linear solve written for lanes.
    num = jw.PRESETS["fast"].replace(linear_solve="structured_lanes")
    return jax.jit(jax.vmap(lockstep(lambda omega: jw.Params(gait=wave_cls(omega=omega)), num)))


def wave(rounds: int) -> list[dict]:
    waves = {
        "angle addition (jw.TravellingWave)": jw.TravellingWave,
        "one sine per segment": DirectSineWave,
    }
    omegas = jnp.linspace(3 * jnp.pi, 5 * jnp.pi, LANES)
    delta = jnp.asarray(-jnp.pi / 4)  # 27 cracks in 60 s
    solve = {name: _solve_60(cls) for name, cls in waves.items()}
    lock = {name: _lockstep(cls) for name, cls in waves.items()}
    velocity = {name: float(f(delta)) for name, f in solve.items()}  # compiles
    for f in lock.values():
        jax.block_until_ready(f(omegas))
    walls = {name: {"solve": [], "lanes": []} for name in waves}
    for r in range(rounds):
        for name in waves:
            walls[name]["solve"].append(_best(solve[name], delta, repeats=1))
            walls[name]["lanes"].append(_best(lock[name], omegas, repeats=1))
        B.log(f"round {r + 1}/{rounds}")
    rows = []
    for name in waves:
        rows.append(
            {
                "wave": name,
                "solve_60s_s": min(walls[name]["solve"]),
                "lane_step_us": 1e6 * min(walls[name]["lanes"]) / (STEPS * LANES),
                "mean_velocity": velocity[name],
                "walls": walls[name],
            }
        )
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--rounds", type=int, default=5, help="alternated timing rounds")
    args = ap.parse_args(argv)
    elements = per_element()
    waves = wave(args.rounds)
    out = {"machine": B.machine_info(), "per_element": elements, "wave": waves}
    folder = R.results_dir("elementwise_cost")
    R.write_json(folder / "elementwise_cost.json", out)
    new, old = waves
    lines = [
        "# float64 elementwise functions on a CPU, and the wave's sines",
        "",
        B.machine_line(out["machine"]),
        "",
        f"Command: `python benchmarks/elementwise_cost.py --rounds {args.rounds}`. One JAX "
        "CPU device. Per element: each function applied "
        f"{LOOP} times in a loop to a {SHAPE} array, fastest of 5.",
        "",
        *B.md_table(
            ["function", "ns per element"],
            [[e["function"], f"{e['ns_per_element']:.2f}"] for e in elements],
        ),
        "",
        "The wave: the 60-s Table 1 solve (δ = −π/4, `fast`) and a lockstep batch of "
        f"{LANES} lanes ({STEPS} fixed Rodas4 steps over {SPAN:g} s), fastest of "
        f"{args.rounds} alternated rounds.",
        "",
        *B.md_table(
            ["wave", "60-s solve s", "µs per lane and step", "mean velocity m/s (60 s)"],
            [
                [
                    w["wave"],
                    f"{w['solve_60s_s']:.4f}",
                    f"{w['lane_step_us']:.3f}",
                    f"{w['mean_velocity']:.8g}",
                ]
                for w in waves
            ],
        ),
        "",
        f"Angle addition against one sine per segment: the 60-s solve "
        f"{new['solve_60s_s'] / old['solve_60s_s']:.3f}×, a lane-step "
        f"{new['lane_step_us'] / old['lane_step_us']:.3f}× the time; mean velocities "
        f"{abs(new['mean_velocity'] / old['mean_velocity'] - 1):.1e} apart (relative).",
    ]
    (folder / "elementwise_cost.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()

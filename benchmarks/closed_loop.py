"""Closed-loop burrowing in layered soil: a neural policy trained by gradient through
the simulator against the best open-loop travelling wave, on held-out soils.

    python benchmarks/closed_loop.py [--quick] [--reuse-wave]

Soil distribution (`layered_soil`): six layers from the start of the burrow, each
0.04–0.14 m thick (uniform), alternately weak (E_s = 1.4e5 Pa, K_Ic = 250 Pa√m,
K_Ith = 200 Pa√m: Table 1) and stiff (E_s, K_Ic, K_Ith doubled), the first one weak or
stiff at random; μ_s = 0.3 throughout. Sharp interfaces. Seeds 0..3 train, 100..107 are
held out.

Every controller has the same rate bound |u_k| ≤ A_max = 0.03 m/s (the amplitude bound
of `jaxworm.optimise`'s default box):
- **wave**: `TravellingWave(A = 0.03, ω, δ)`, (ω, δ) tuned on the mean velocity over
  the training soils in the box ω ∈ [2π, 6π], δ ∈ [−π/2, 0]: the centres of a 13 × 13
  grid of the box, then `jaxworm.optimise` (`samples`: the soils) from its 4 best
  points, 20 steps of the default optimiser (`fast` preset, forward sensitivities,
  whole periods); the best ok point wins. (The landscape is a sawtooth of narrow
  ridges, sharp in δ near 0; from Latin-hypercube starts the gradient steps stayed on
  poor ridges.)
- **policy**: `PolicyMLP` (width 8, depth 1, 115 weights) from that wave's ω and δ
  (b = 8: nearly a square wave, the gain picked on the training soils by
  benchmarks/policy_gain.py; `--b` sets another), trained by `jaxworm.train` (Adam,
  its rate decaying from 0.02 to 0 over the steps by a cosine: at a constant 0.02 the
  training value peaked at step 14 of 25 and fell after) on the mean velocity over the
  training soils over 2 s (whole periods; 1.5 s with --quick) by reverse-mode
  gradients through Kvaerno3 steps (the forward sensitivities' cost grows with the 115
  parameters) with the exact jump conditions (`crack_sensitivity = "exact"`: the policy
  reads K_I/K_Ic, which the held modes refuse) at atol 1e-10 (at 1e-8 Kvaerno3's exact
  derivative was seen 18 % off); the network, b, δ and ω move, A_max and the leak stay.
  The training horizon is short because that exact derivative points along the
  finite-difference slope over short horizons only: off it by tens of per cent over
  1–2 s, by factors from 5 s on (benchmarks/feedback_gradient.py);
- **policy, open loop**: the same network with its sensor inputs zeroed
  (`feedback=False`), trained the same way: what the waveform alone buys.

Evaluation (`fast` preset, t1 = 10 s whole periods) on the held-out soils: mean
velocity, cost of transport, the policy under sensor noise, and the solver cost per
simulated second of each controller (fastest of 3 warm calls, same process).
The error of `fast` is its largest relative difference in mean velocity from a tight
Rodas4 solve (atol = 1e-10) on two held-out soils. Writes
benchmarks/results/closed_loop/closed_loop[_quick].{json,md} and the trained policies
(`equinox.tree_serialise_leaves`) as closed_loop[_quick]_<name>.eqx, with the histories
of the wave's optimisation (closed_loop[_quick]_wave.npz, `jaxworm.load_optimisation`)
and of the trainings (closed_loop[_quick]_<name>_training.npz, `jaxworm.load_training`).
"""

from __future__ import annotations

import argparse
import json
import math
import time
from datetime import UTC, datetime

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax
from _results import machine_info, quick_suffix, results_dir, write_json

import jaxworm as jw

A_MAX = 0.03
WEAK = {"E_s": 1.4e5, "K_Ic": 250.0, "K_Ith": 200.0}
LAYERS = 6
TRAIN = (0, 1, 2, 3)
HELD_OUT = tuple(range(100, 108))
#: The policies' training horizon [s]: where their exact derivative follows the slope.
TRAIN_T1 = 2.0
#: The policies' starting gain b of A_max tanh(b sin(ω t + δ k)).
B0 = 8.0
TRAINING = jw.Numerics(solver="Kvaerno3", atol=1e-10, crack_sensitivity="exact")
EVALUATION = jw.PRESETS["fast"]
#: The wave's box: the grid of earlier runs.
WAVE_BOUNDS = {"omega": (2 * math.pi, 6 * math.pi), "delta": (-math.pi / 2, 0.0)}


def layered_soil(seed: int) -> jw.Soil:
    """Six layers, 0.04–0.14 m thick, alternately weak and stiff (2×), first at random."""
    rng = np.random.default_rng(seed)
    thickness = rng.uniform(0.04, 0.14, LAYERS - 1)
    interfaces = np.cumsum(thickness) - thickness[0] * rng.uniform()
    factor = np.where((np.arange(LAYERS) + rng.integers(2)) % 2 == 0, 1.0, 2.0)

    def layered(name):
        return jw.Layered(list(interfaces), list(WEAK[name] * factor))

    return jw.Soil(E_s=layered("E_s"), K_Ic=layered("K_Ic"), K_Ith=layered("K_Ith"))


def stack(trees):
    return jax.tree_util.tree_map(lambda *a: jnp.stack(a), *trees)


def speeds(gait, soils, t1, numerics):
    """Mean velocities and costs of transport of one gait over a batch of soils."""

    def one(soil):
        r = jw.simulate(jw.Params(soil=soil, gait=gait), t1, numerics, horizon="whole_periods")
        return r.mean_velocity, jw.cost_of_transport(r), r.status

    return jax.vmap(one)(soils)


def grid_points(n: int):
    """The centres of an n × n grid of cells of WAVE_BOUNDS (strictly inside the box):
    (ω values, δ values)."""
    centres = (np.arange(n) + 0.5) / n
    (wlo, whi), (dlo, dhi) = WAVE_BOUNDS["omega"], WAVE_BOUNDS["delta"]
    return wlo + centres * (whi - wlo), dlo + centres * (dhi - dlo)


def wave_grid(soils, t1, n):
    """Mean velocity over `soils` (stacked) of TravellingWave(A_MAX, ω, δ) at the
    `grid_points(n)` (`fast`): (ω values, δ values, v̄ [n, n])."""
    omegas, deltas = grid_points(n)

    @jax.jit
    def row(omega):
        def mean_v(delta):
            gait = jw.TravellingWave(A=A_MAX, omega=omega, delta=delta)
            v, _, status = speeds(gait, soils, t1, EVALUATION)
            return jnp.where(jnp.all(status == 0), jnp.mean(v), jnp.nan)

        return jax.vmap(mean_v)(jnp.asarray(deltas))

    return omegas, deltas, np.stack([np.asarray(row(w)) for w in omegas])


def best_wave(soils, t1, grid, starts, steps, path, log):
    """The (ω, δ) of the fastest TravellingWave(A_MAX) on average over `soils` (a list),
    and its mean velocity there: the `starts` best points of a `grid` × `grid` scan of
    the box, refined by `jaxworm.optimise` over the soils as samples (its steps are
    gradient steps, so each start stays near its own ridge of the sawtooth landscape)."""
    omegas, deltas, v = wave_grid(stack(soils), t1, grid)
    order = np.argsort(np.where(np.isfinite(v), -v, np.inf), axis=None)[:starts]
    i, j = np.unravel_index(order, v.shape)
    log(
        f"wave grid {grid}x{grid}: best v {v[i[0], j[0]]:.5f} at omega {omegas[i[0]]:.3f}, "
        f"delta {deltas[j[0]]:.3f}"
    )
    res = jw.optimise(
        "velocity",
        WAVE_BOUNDS,
        base=jw.Params(gait=jw.TravellingWave(A=A_MAX)),
        samples={"soil": soils},
        t1=t1,
        numerics=EVALUATION,
        starts={"omega": omegas[i], "delta": deltas[j]},
        steps=steps,
        path=path,
        overwrite=True,
        progress=False,
    )
    for k, best in enumerate(res.best_so_far()):
        log(f"wave step {k:3d}: best training v {best:.5f}  ({res.wall_time[k]:.0f} s)")
    theta = res.best_theta
    log(
        f"wave: best v {res.best_value:.5f} at omega {theta['omega']:.3f}, delta "
        f"{theta['delta']:.3f} (step {res.best_step}, start {res.best_start})"
    )
    grid_best = {
        "omega": float(omegas[i[0]]),
        "delta": float(deltas[j[0]]),
        "v": float(v[i[0], j[0]]),
    }
    return theta["omega"], theta["delta"], res.best_value, grid_best


def train(policy, soils, t1, steps, lr, path, log):
    """`jaxworm.train` on the mean velocity over `soils` (a list) by reverse mode through
    Kvaerno3 steps. Only the network, b, δ and ω move; A_max (the rate bound) and the
    leak stay. A step whose solves do not all end ok stops the training."""
    res = jw.train(
        policy,
        "velocity",
        samples={"soil": soils},
        t1=t1,
        steps=steps,
        optimiser=optax.adam(optax.cosine_decay_schedule(lr, steps)),
        numerics=TRAINING,
        derivatives="reverse",
        trainable=lambda p: (p.mlp, p.b, p.delta, p.omega),
        path=path,
        overwrite=True,
        progress=False,
    )
    n = res.steps_done
    for k in range(n):
        log(f"  step {k:3d}: training v {res.value[k]:.5f}  ({res.wall_time[k]:.0f} s)")
    if res.stopped:
        log(f"  {res.stopped}; training stops")
    history = [float(v) for v, ok in zip(res.value[:n], res.ok) if ok]
    return res.best_controller, history, float(res.wall_time[n - 1])


def policy_file(folder, tag, name):
    """Where a trained policy is saved (`equinox.tree_serialise_leaves`)."""
    return folder / f"closed_loop{tag}_{name.replace(', ', '_').replace(' ', '_')}.eqx"


def training_file(folder, tag, name):
    """Where a policy's training history is saved (`jaxworm.load_training`)."""
    policy = policy_file(folder, tag, name)
    return policy.with_name(policy.stem + "_training.npz")


def solve_error(gait, soils, t1):
    """Largest relative difference of the `fast` mean velocity from a tight Rodas4
    solve (atol = 1e-10) over `soils`: the evaluation's own error."""
    fast, _, _ = speeds(gait, soils, t1, EVALUATION)
    tight, _, _ = speeds(gait, soils, t1, jw.Numerics(solver="Rodas4", atol=1e-10))
    return float(np.max(np.abs(np.asarray(fast) / np.asarray(tight) - 1.0)))


def cost_per_second(gait, t1, repeats=3):
    """Fastest of `repeats` warm calls of one `fast` solve over t1 (Table 1 soil), per
    simulated second, and the solver steps."""
    p = jw.Params(gait=gait)
    f = eqx.filter_jit(lambda p: jw.simulate(p, t1, EVALUATION))
    r = f(p)
    jax.block_until_ready(r.mean_velocity)
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        jax.block_until_ready(f(p).mean_velocity)
        times.append(time.perf_counter() - t)
    return min(times) / t1, int(r.steps), float(r.mean_velocity)


def main(argv=None):
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument(
        "--quick",
        action="store_true",
        help="t1 = 3 s (training 1.5 s), 2 + 2 soils, 3 × 3 wave grid, 3 steps",
    )
    ap.add_argument("--steps", type=int, help="Adam steps (default 25; 3 with --quick)")
    ap.add_argument(
        "--lr",
        type=float,
        default=0.02,
        help="Adam's first learning rate (default 0.02), decaying to 0 by a cosine",
    )
    ap.add_argument(
        "--wave-steps", type=int, help="optimiser steps of the wave (default 20; 3 with --quick)"
    )
    ap.add_argument(
        "--evaluate",
        action="store_true",
        help="train nothing: evaluate the policies and wave of the last run's files again",
    )
    ap.add_argument(
        "--reuse-wave",
        action="store_true",
        help="take the wave of the last run's results instead of tuning it again, and train",
    )
    ap.add_argument(
        "--b",
        type=float,
        default=B0,
        help=f"the policies' starting gain b (default {B0:g})",
    )
    args = ap.parse_args(argv)
    tag = quick_suffix(args.quick)
    folder = results_dir("closed_loop")
    t1 = 3.0 if args.quick else 10.0
    train_t1 = 1.5 if args.quick else TRAIN_T1
    steps = args.steps if args.steps is not None else (3 if args.quick else 25)
    train_seeds = TRAIN[:2] if args.quick else TRAIN
    test_seeds = HELD_OUT[:2] if args.quick else HELD_OUT
    train_list = [layered_soil(s) for s in train_seeds]
    train_soils = stack(train_list)
    test_soils = stack([layered_soil(s) for s in test_seeds])
    lines: list[str] = []

    def log(msg):
        print(msg, flush=True)
        lines.append(msg)

    t_start = time.perf_counter()
    previous = None
    if args.evaluate or args.reuse_wave:
        last = json.loads((folder / f"closed_loop{tag}.json").read_text())
        omega, delta, wave_train_v = (last["wave"][k] for k in ("omega", "delta", "train_v"))
        wave_grid_best = last["wave"].get("grid_best")
        if args.evaluate:
            previous = last
            log(f"wave and policies of the run of {last['date']}; evaluated again")
        else:
            log(f"wave of the run of {last['date']} (not tuned again)")
    else:
        wave_steps = args.wave_steps or (3 if args.quick else 20)
        omega, delta, wave_train_v, wave_grid_best = best_wave(
            train_list,
            t1,
            3 if args.quick else 13,
            2 if args.quick else 4,
            wave_steps,
            folder / f"closed_loop{tag}_wave.npz",
            log,
        )
    wave = jw.TravellingWave(A=A_MAX, omega=omega, delta=delta)
    controllers = {"wave": wave}
    training = {} if previous is None else previous["training"]
    # The starting gain of the policies evaluated: this run's, or the run's that trained
    # them (runs before `--b` existed started from 3).
    b0 = args.b if previous is None else previous.get("b0", 3.0)
    for name, feedback in (("policy", True), ("policy, open loop", False)):
        start = jw.PolicyMLP.init(
            jax.random.key(0), 7, omega=omega, delta=delta, b=args.b, A_max=A_MAX, feedback=feedback
        )
        if previous is not None:
            controllers[name] = eqx.tree_deserialise_leaves(policy_file(folder, tag, name), start)
            continue
        log(f"training {name}")
        trained, history, seconds = train(
            start, train_list, train_t1, steps, args.lr, training_file(folder, tag, name), log
        )
        controllers[name] = trained
        training[name] = {"history": history, "seconds": seconds}
        eqx.tree_serialise_leaves(policy_file(folder, tag, name), trained)

    rows = {}
    for name, gait in controllers.items():
        v, cot, status = speeds(gait, test_soils, t1, EVALUATION)
        v_train, _, _ = speeds(gait, train_soils, t1, EVALUATION)
        rows[name] = {
            "held_out_v": np.asarray(v).tolist(),
            "held_out_cot": np.asarray(cot).tolist(),
            "held_out_ok": bool(np.all(np.asarray(status) == 0)),
            "train_v_mean": float(np.mean(v_train)),
        }
        log(f"{name}: held-out v {np.mean(v):.5f} ± {np.std(v):.5f}, CoT {np.mean(cot):.3g} J/m")
    noise_rows = []
    for sigma in (0.0, 0.05, 0.1, 0.2):
        noisy = eqx.tree_at(
            lambda p: p.noise,
            controllers["policy"],
            jw.SensorNoise(
                jax.random.key(7), velocity=sigma * A_MAX, stress_ratio=sigma, length=sigma * 1e-3
            ),
            is_leaf=lambda x: x is None,
        )
        v, _, status = speeds(noisy, test_soils, t1, EVALUATION)
        noise_rows.append(
            {"sigma": sigma, "v": float(np.mean(v)), "ok": bool(np.all(np.asarray(status) == 0))}
        )
        log(f"policy, noise {sigma}: held-out v {np.mean(v):.5f}")
    errors = {
        name: solve_error(g, stack([layered_soil(s) for s in test_seeds[:2]]), t1)
        for name, g in controllers.items()
    }
    for name, e in errors.items():
        log(f"evaluation error {name}: {e:.2e} (fast against Rodas4 atol 1e-10, 2 held-out soils)")
    cost = {name: cost_per_second(g, t1) for name, g in controllers.items()}
    for name, (sec, n_steps, _) in cost.items():
        log(f"cost {name}: {sec * 1e3:.2f} ms per simulated s, {n_steps} steps")

    v_wave = float(np.mean(rows["wave"]["held_out_v"]))
    out = {
        "benchmark": "closed_loop",
        "quick": args.quick,
        "date": datetime.now(UTC).isoformat(timespec="seconds"),
        "trained": previous["date"] if previous is not None else None,
        "machine": machine_info(),
        "t1": t1,
        "train_t1": train_t1,
        "b0": b0,
        "train_seeds": list(train_seeds),
        "held_out_seeds": list(test_seeds),
        "wave": {
            "omega": omega,
            "delta": delta,
            "A": A_MAX,
            "train_v": wave_train_v,
            "grid_best": wave_grid_best,
        },
        "rows": rows,
        "training": training,
        "noise": noise_rows,
        "cost_per_simulated_second": {k: list(v) for k, v in cost.items()},
        "evaluation_error": errors,
        "seconds": time.perf_counter() - t_start,
        "log": lines,
    }
    write_json(folder / f"closed_loop{tag}.json", out, indent=2)
    m = machine_info()
    md = [
        f"# Closed-loop policy against the best open-loop wave, layered soil{tag and ' (quick)'}",
        "",
        f"`python benchmarks/closed_loop.py{' --quick' if args.quick else ''}"
        f"{' --reuse-wave' if args.reuse_wave else ''}"
        f"{f' --b {args.b:g}' if args.b != B0 else ''}` on "
        f"{m.get('cpu', m.get('processor', '?'))}, {out['date']}; t1 = {t1:g} s (whole "
        f"periods; policies trained over {train_t1:g} s from the gain b = {b0:g}); "
        f"{len(train_seeds)} training "
        f"soils, {len(test_seeds)} held out; rate "
        f"bound |u| ≤ {A_MAX} m/s for every controller."
        + (
            ""
            if previous is None
            else f" Wave and policies (and training s) from the run of {previous['date']}, "
            "evaluated again (`--evaluate`)."
        ),
        "",
        "| controller | held-out v̄ [m/s] (mean ± sd) | × wave | held-out CoT [J/m] | "
        "training v̄ | all ok | error of `fast` | training s |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, r in rows.items():
        v = np.asarray(r["held_out_v"])
        secs = training.get(name, {}).get("seconds")
        md.append(
            f"| {name} | {v.mean():.5f} ± {v.std():.5f} | {v.mean() / v_wave:.3f} | "
            f"{np.mean(r['held_out_cot']):.3g} | {r['train_v_mean']:.5f} | {r['held_out_ok']} | "
            f"{errors[name]:.1e} | {'-' if secs is None else f'{secs:.0f}'} |"
        )
    md += [
        "",
        f"Wave: ω = {omega:.4f} rad/s, δ = {delta:.4f} rad, A = {A_MAX} m/s"
        + (
            ""
            if wave_grid_best is None
            else f" (the grid's best: training v̄ {wave_grid_best['v']:.5f} at ω = "
            f"{wave_grid_best['omega']:.4f}, δ = {wave_grid_best['delta']:.4f}; refined: "
            f"{wave_train_v:.5f})"
        )
        + ".",
        "",
        "Policy under sensor noise (σ relative: velocity σ·A_max, K_I/K_Ic σ, "
        "lengths σ·1 mm; held-out mean v̄):",
        "",
        "| σ | v̄ [m/s] | all ok |",
        "|---|---|---|",
    ]
    md += [f"| {r['sigma']} | {r['v']:.5f} | {r['ok']} |" for r in noise_rows]
    md += [
        "",
        "Solver cost, Table 1 soil, `fast` preset, fastest of 3 warm calls:",
        "",
        "| controller | ms per simulated s | × wave | steps |",
        "|---|---|---|---|",
    ]
    base_cost = cost["wave"][0]
    md += [f"| {k} | {c[0] * 1e3:.2f} | {c[0] / base_cost:.2f} | {c[1]} |" for k, c in cost.items()]
    (folder / f"closed_loop{tag}.md").write_text("\n".join(md) + "\n")
    print("\n".join(md))


if __name__ == "__main__":
    main()

"""Gait tuning over (A, ω, δ), the amplitude free: gradients against CMA-ES (issue 5).

    python benchmarks/optimise_amplitude.py [--t1 10] [--steps 12] [--no-decay]
        [--horizon whole_periods] [--box sine] [--optimiser adam] [--b1 0] [--lr 0.5]

The box: ω ∈ [3π, 5π] rad/s, δ ∈ [−π/3, −π/6] rad (`jaxworm.DEFAULT_BOUNDS`) and
A ∈ [0.01, 0.03] m/s. CMA-ES (3 seeds, pop 7, `fast`, each generation as vmapped batches
on all cores at once) and `jaxworm.optimise` (its default numerics, forward mode) with 1,
2 and 4 Latin-hypercube starts, and one start at the box's centre (CMA-ES's own x0). For each:
simulations until the best so far is within 1 % of the best known (every best re-solved
with `default`; CMA's trace rescaled by its best point's default/fast ratio, as in
`optimise_vs_grid.py`).

The gradient options default to `jaxworm.optimise`'s: the mean velocity over whole gait
periods (ω is optimised), the sine box, Adam with first step 0.5 and no momentum,
cosine-decayed. Deliberately not the library's: t1 = 10 s (library 60 s) and 12 steps
(library 30), a small budget in which to count simulations. Writes
benchmarks/results/optimise_amplitude/optimise_amplitude<suffix>.{json,md}, the suffix
naming each option that differs from these defaults (`_horizon_t1`, `_sigmoid`,
`_rprop`, `_b1_0.9`, `_lr_1`, then `_constant`, `_t1_60`).
"""

from __future__ import annotations

import argparse

import _bench as B  # (first: sets the BLAS threads before numpy loads)
import numpy as np
import optax

import jaxworm as jw

BOUNDS = {**jw.DEFAULT_BOUNDS, "A": (0.01, 0.03)}
NAMES = list(BOUNDS)
LO = np.array([BOUNDS[n][0] for n in NAMES])
HI = np.array([BOUNDS[n][1] for n in NAMES])


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--t1", type=float, default=10.0, help="horizon [s] (default 10; jaxworm.optimise's is 60)"
    )
    ap.add_argument(
        "--steps",
        type=int,
        default=12,
        help="steps per start (default 12; jaxworm.optimise's is 30)",
    )
    ap.add_argument("--no-decay", action="store_true", help="constant Adam step (no cosine decay)")
    B.add_gradient_options(ap, horizon="whole_periods")
    args = ap.parse_args(argv)
    tag = (
        B.gradient_tag(args, ap)
        + ("_constant" if args.no_decay else "")
        + ("" if args.t1 == ap.get_default("t1") else f"_t1_{args.t1:g}")
    )
    fast, default = (
        B.batched_velocity(jw.PRESETS[k], args.t1, NAMES, horizon=args.horizon)
        for k in ("fast", "default")
    )
    cmas = [B.cma_maximise(fast, LO, HI, [0.5] * len(NAMES), 0.25, seed, 300) for seed in (1, 2, 3)]
    v_def, _ = default([c["best_theta"] for c in cmas])
    grads = []
    # 1, 2, 4 Latin-hypercube starts, and one start at the box's centre: CMA-ES's x0.
    centre = {n: [0.5 * (a + b)] for n, (a, b) in BOUNDS.items()}
    for label, starts in (("1", 1), ("2", 2), ("4", 4), ("centre", centre)):
        res = jw.optimise(
            "velocity",
            BOUNDS,
            t1=args.t1,
            starts=starts,
            steps=args.steps,
            optimiser=(
                optax.adam(args.lr, b1=args.b1)
                if args.no_decay
                else B.gradient_optimiser(args, args.steps)
            ),
            progress=False,
            horizon=args.horizon,
            box=args.box,
        )
        grads.append(
            {
                "starts": res.value.shape[1],
                "label": label,
                "best": res.best_value,
                "best_theta": res.best_theta,
                "best_so_far": res.best_so_far().tolist(),
                "walls": res.wall_time.tolist(),
            }
        )
    best_known = max([g["best"] for g in grads] + [float(v) for v in np.asarray(v_def)])
    target = 0.99 * best_known
    for g in grads:
        steps = np.arange(1, len(g["best_so_far"]) + 1)
        g["simulations_to_1pct"], g["wall_to_1pct"] = B.evals_to(
            g["best_so_far"], steps * g["starts"], g["walls"], target
        )
    cma_rows = []
    for c, v in zip(cmas, np.asarray(v_def)):
        cma_rows.append(
            {
                "seed": c["seed"],
                "popsize": c["popsize"],
                "best": float(v),
                "best_theta": dict(zip(NAMES, c["best_theta"].tolist())),
                **dict(
                    zip(
                        ("simulations_to_1pct", "wall_to_1pct"),
                        B.evals_to(
                            c["best_so_far"] * float(v) / c["best_fast"],
                            c["evals"],
                            c["walls"],
                            target,
                        ),
                    )
                ),
            }
        )
    out = {
        "t1": args.t1,
        "horizon": args.horizon,
        "box": args.box,
        "optimiser": args.optimiser,
        "decay": not args.no_decay,
        "b1": args.b1,
        "bounds": {n: list(b) for n, b in BOUNDS.items()},
        "steps": args.steps,
        "lr": args.lr,
        "best_known": best_known,
        "target": target,
        "gradient": grads,
        "cma": cma_rows,
        "machine": B.machine_info(),
    }
    folder = B.results_dir("optimise_amplitude")
    B.write_json(folder / f"optimise_amplitude{tag}.json", out)
    m = out["machine"]

    def wall(w):
        return "-" if w is None else f"{w:.0f}"

    rows = [
        [
            "gradient, "
            + ("1 start at the centre" if g["label"] == "centre" else g["label"] + " start(s)")
            + f" × {args.steps} steps",
            f"{g['best']:.6g}",
            g["simulations_to_1pct"]
            if g["simulations_to_1pct"] is not None
            else f"not in {g['starts'] * args.steps}",
            wall(g["wall_to_1pct"]),
            ", ".join(f"{n} {g['best_theta'][n]:.4g}" for n in NAMES),
        ]
        for g in grads
    ]
    rows += [
        [
            f"CMA-ES seed {r['seed']} (pop {r['popsize']}, fast)",
            f"{r['best']:.6g}",
            r["simulations_to_1pct"] if r["simulations_to_1pct"] is not None else "not in 300",
            wall(r["wall_to_1pct"]),
            ", ".join(f"{n} {r['best_theta'][n]:.4g}" for n in NAMES),
        ]
        for r in cma_rows
    ]
    what = (
        ("" if args.horizon == "t1" else ", mean velocity over whole gait periods")
        + f"; {B.gradient_label(out)} on the {args.box} box, first step {args.lr:g}"
        + ("" if args.optimiser == "rprop" else ", constant" if args.no_decay else ", cosine decay")
    )
    lines = [
        f"# Tuning (A, ω, δ), t1 = {args.t1:g} s{what}",
        "",
        f"Machine: {m['cpu']}, {m['cpus']} CPUs, jax {m['jax']}, commit {m['git_commit']}; "
        f"{m['date']}. Best known {best_known:.6g} m/s; within 1 %: ≥ {target:.6g} m/s.",
        "",
    ]
    lines += B.md_table(
        [
            "method",
            "best m/s",
            "simulations to 1 %",
            "wall to 1 % [s, compilation included]",
            "best point",
        ],
        rows,
    )
    (folder / f"optimise_amplitude{tag}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()

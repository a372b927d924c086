"""Per-segment gaits against the best travelling wave (issue 5, beyond the paper).

    python benchmarks/segment_gait.py --quick --cma-seeds 3   # t1 = 10 s, ~5 min
    python benchmarks/segment_gait.py [--t1 60] [--steps 30] [--cma-seeds 3]
        [--box sine] [--optimiser adam] [--b1 0] [--lr 0.5] [--wave-from FILE]

Starts from the best uniform travelling wave found by `optimise_vs_grid.py` (the
gradient's best in its results file at its default options, quick or not like this run,
or `--wave-from`; else ω = 3π, δ = −0.2333π), writes it as a `SegmentWave` (A_k = A,
φ_k = δk) and optimises the 2(N − 1) amplitudes and phases (A_k ∈ [0.01, 0.03] m/s,
φ_k within ±π/4 of the wave's δk) with the common ω fixed, by `jaxworm.optimise` with
`apply=apply_segments`. Reports the gain in mean velocity over the uniform wave. The
gradient options default to `jaxworm.optimise`'s (over [0, t1], as ω is fixed; the sine
box; Adam with first step 0.5, no momentum, cosine-decayed; 30 steps; t1 = 60 s). Writes
benchmarks/results/segment_gait/segment_gait[_quick]<suffix>.{json,md,npz}, the suffix
naming each gradient option that differs from its default (`_sigmoid`, `_rprop`,
`_b1_0.9`, `_lr_0.25`).

With `--cma-seeds K`, CMA-ES (the `cma` package) runs K times on the same 12-D box and
objective, from the same start (the box scaled to [0, 1]^12, step 0.25), each generation
solved as vmapped batches on all cores at once (`_bench.batched_velocity`) with the
forward-only `fast` preset, and the table reports the simulations and wall time each
method needs to come within 1 % of the best known value (the best of all runs, re-solved
with `default`), as `optimise_vs_grid.py` does in the 2-D gait plane.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
from datetime import UTC, datetime
from pathlib import Path

import _bench as B  # (first: sets the BLAS threads before numpy loads)
import jax
import numpy as np
from _bench import (
    add_gradient_options,
    batched_velocity,
    cma_maximise,
    evals_to,
    first_call_excess,
    gradient_label,
    gradient_optimiser,
    gradient_tag,
)
from _results import cpu_model

import jaxworm as jw
from jaxworm import SegmentWave, apply_segments


def _best_wave(path: Path) -> dict:
    """The gradient's best (ω, δ) in an `optimise_vs_grid.py` results file, else the
    fallback wave."""
    if path.exists():
        g = json.loads(path.read_text())["gradient"]["best_theta"]
        return {"omega": g["omega"], "delta": g["delta"]}
    return {"omega": 3 * math.pi, "delta": -0.2333 * math.pi}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="t1 = 10 s")
    ap.add_argument(
        "--t1", type=float, help="horizon [s] (default 60, jaxworm.optimise's; 10 with --quick)"
    )
    ap.add_argument(
        "--steps", type=int, default=30, help="gradient steps (default 30, jaxworm.optimise's)"
    )
    ap.add_argument("--cma-seeds", type=int, default=0)
    ap.add_argument("--cma-evals", type=int, default=1000, help="evaluation budget per CMA run")
    ap.add_argument(
        "--wave-from",
        type=Path,
        help="optimise_vs_grid results JSON whose gradient best is the start "
        "(default: results/optimise_vs_grid/optimise_vs_grid[_quick].json)",
    )
    add_gradient_options(ap, horizon="t1")
    args = ap.parse_args(argv)
    if args.horizon != "t1":
        ap.error("--horizon: ω is fixed here, so only t1 applies")
    tag = B.quick_suffix(args.quick)
    run_tag = tag + gradient_tag(args, ap)
    t1 = args.t1 if args.t1 is not None else (10.0 if args.quick else 60.0)
    steps = args.steps
    folder = B.results_dir("segment_gait")

    wave = _best_wave(
        args.wave_from or B.RESULTS / "optimise_vs_grid" / f"optimise_vs_grid{tag}.json"
    )
    N = jw.Body().N
    seg = SegmentWave.from_wave(jw.TravellingWave(A=0.02, **wave), N)
    base = jw.Params(gait=seg)
    uniform = float(
        jw.simulate(jw.Params().replace(A=0.02, **wave), t1, jw.PRESETS["default"]).mean_velocity
    )
    phases = np.asarray(seg.phase)
    bounds = {f"A_{k}": (0.01, 0.03) for k in range(1, N)}
    bounds.update(
        {
            f"phase_{k}": (phases[k - 1] - math.pi / 4, phases[k - 1] + math.pi / 4)
            for k in range(1, N)
        }
    )
    start = {
        **{f"A_{k}": [0.02] for k in range(1, N)},
        **{f"phase_{k}": [phases[k - 1]] for k in range(1, N)},
    }
    res = jw.optimise(
        "velocity",
        bounds,
        base=base,
        apply=apply_segments,
        t1=t1,
        starts=start,
        steps=steps,
        optimiser=gradient_optimiser(args, steps),
        path=folder / f"segment_gait{run_tag}.npz",
        box=args.box,
        overwrite=True,
    )  # this benchmark's own history, written afresh
    out = {
        "t1": t1,
        "steps": steps,
        "box": args.box,
        "b1": args.b1,
        "optimiser": args.optimiser,
        "lr": args.lr,
        "uniform_wave": {"A": 0.02, **wave, "mean_velocity": uniform},
        "per_segment_best": res.best_value,
        "gain": res.best_value / uniform - 1.0,
        "best_theta": res.best_theta,
        "evaluations": res.n_evaluations,
        "wall_s": float(res.wall_time[res.steps_done - 1]),
        "machine": {
            "cpu": cpu_model(),
            "platform": platform.platform(),
            "cpus": os.cpu_count(),
            "jax": jax.__version__,
            "load_average_end": os.getloadavg(),
        },
        "date": datetime.now(UTC).isoformat(timespec="seconds"),
    }
    _equal_amplitude(out, N)
    if args.cma_seeds:
        out["cma"] = _against_cma(res, bounds, start, base, t1, args.cma_seeds, args.cma_evals)
    _write(out, run_tag, N, args.quick)


def _against_cma(res, bounds: dict, start: dict, base, t1: float, seeds: int, budget: int) -> dict:
    """CMA-ES on the same box and objective; simulations and wall time to 1 %. CMA's
    trace (`fast` values) is rescaled by its best point's default/fast ratio before the
    threshold test, as in `optimise_vs_grid.py`."""
    names = list(bounds)
    lo = np.array([bounds[n][0] for n in names])
    hi = np.array([bounds[n][1] for n in names])
    fast, default = (
        batched_velocity(jw.PRESETS[k], t1, names, base, apply_segments)
        for k in ("fast", "default")
    )
    x0 = (np.array([start[n][0] for n in names]) - lo) / (hi - lo)
    runs = []
    for seed in range(1, seeds + 1):
        r = cma_maximise(fast, lo, hi, x0, 0.25, seed, budget)
        runs.append(
            {
                "seed": seed,
                "popsize": r["popsize"],
                "evaluations": r["evaluations"],
                "best_fast": r["best_fast"],
                "best_theta": r["best_theta"].tolist(),
                "trace": r["best_so_far"].tolist(),
                "walls": r["walls"].tolist(),
            }
        )
        print(
            f"CMA-ES seed {seed}: {r['best_fast']:.6g} m/s after {r['evaluations']} evaluations",
            flush=True,
        )
    v_def, _ = default([r["best_theta"] for r in runs])
    for r, v in zip(runs, np.asarray(v_def)):
        r["best_default"] = float(v)
    grad_trace = res.best_so_far()
    best_known = max([float(np.max(grad_trace))] + [r["best_default"] for r in runs])
    target = 0.99 * best_known
    g_evals, g_wall = evals_to(
        grad_trace, np.arange(1, res.steps_done + 1), res.wall_time[: res.steps_done], target
    )
    for r in runs:
        r["evals_to_1pc"], r["wall_to_1pc"] = evals_to(
            np.asarray(r["trace"]) * r["best_default"] / r["best_fast"],
            np.arange(1, r["evaluations"] + 1),
            r["walls"],
            target,
        )
        r["wall_to_1pc_warm"] = (
            None if r["wall_to_1pc"] is None else r["wall_to_1pc"] - first_call_excess(r["walls"])
        )
    reached = [r["evals_to_1pc"] for r in runs if r["evals_to_1pc"] is not None]
    g_warm = None if g_wall is None else g_wall - first_call_excess(res.wall_time[: res.steps_done])
    return {
        "best_known": best_known,
        "target": target,
        "gradient_evals_to_1pc": g_evals,
        "gradient_wall_to_1pc": g_wall,
        "gradient_wall_to_1pc_warm": g_warm,
        "runs": runs,
        "cma_reached": f"{len(reached)}/{len(runs)}",
        "cma_median_evals_to_1pc": float(np.median(reached)) if reached else None,
        "budget": budget,
    }


def _equal_amplitude(out: dict, N: int) -> None:
    """The uniform wave at the per-segment gait's mean amplitude: the velocity rises
    with A, so this separates the gain of the phase pattern from that of amplitude."""
    w = out["uniform_wave"]
    A = float(np.mean([out["best_theta"][f"A_{k}"] for k in range(1, N)]))
    v = float(
        jw.simulate(
            jw.Params().replace(A=A, omega=w["omega"], delta=w["delta"]),
            out["t1"],
            jw.PRESETS["default"],
        ).mean_velocity
    )
    out["uniform_equal_amplitude"] = {
        "A": A,
        "mean_velocity": v,
        "gain": out["per_segment_best"] / v - 1.0,
    }


def _write(out: dict, tag: str, N: int, quick: bool) -> None:
    t1, steps, wave, uniform = (
        out["t1"],
        out["steps"],
        out["uniform_wave"],
        out["uniform_wave"]["mean_velocity"],
    )
    eq = out["uniform_equal_amplitude"]
    folder = B.results_dir("segment_gait")
    B.write_json(folder / f"segment_gait{tag}.json", out, indent=2)
    A = [out["best_theta"][f"A_{k}"] for k in range(1, N)]
    ph = [out["best_theta"][f"phase_{k}"] / math.pi for k in range(1, N)]
    md = (
        "\n".join(
            [
                "# Per-segment gait against the best travelling wave "
                f"(t1 = {t1:g} s{', quick' if quick else ''}"
                f"; {gradient_label(out)} on the {out.get('box', 'sigmoid')} box)",
                "",
                f"Uniform wave A = 0.02 m/s, ω = {wave['omega'] / math.pi:.4f}π, δ = "
                f"{wave['delta'] / math.pi:.4f}π: **{uniform:.6g} m/s**. "
                "Per-segment (12 parameters, "
                f"{steps} {gradient_label(out)} steps from the wave, "
                f"{out['evaluations']} value-and-gradient solves, "
                f"{out['wall_s']:.0f} s): **{out['per_segment_best']:.6g} m/s**, gain "
                f"{100 * out['gain']:+.2f} %; against the uniform wave at the same mean amplitude "
                f"(A = {eq['A']:.5f} m/s: {eq['mean_velocity']:.6g} m/s) the gain is "
                f"**{100 * eq['gain']:+.2f} %** (the phase pattern's share).",
                "",
                "| segment | " + " | ".join(str(k) for k in range(1, N)) + " |",
                "|---|" + "---|" * (N - 1),
                "| A_k [m/s] | " + " | ".join(f"{a:.4f}" for a in A) + " |",
                "| φ_k [π] | " + " | ".join(f"{p:.3f}" for p in ph) + " |",
                "",
                f"Machine: {out['machine'].get('cpu', out['machine']['platform'])}, "
                f"{out['machine']['cpus']} CPUs, "
                "load average "
                f"{', '.join(f'{x:.1f}' for x in out['machine']['load_average_end'])}; "
                f"{out['date']}.",
            ]
            + _cma_lines(out.get("cma"), gradient_label(out))
        )
        + "\n"
    )
    (folder / f"segment_gait{tag}.md").write_text(md)
    print(md)


def _rounded(wall):
    """A wall time to 0.1 s, None as it is."""
    return wall if wall is None else round(wall, 1)


def _evals_to_1pc(run):
    """A CMA-ES run's evaluations to within 1 %, or how many it ran without getting there."""
    if run["evals_to_1pc"] is not None:
        return run["evals_to_1pc"]
    return "not in " + str(run["evaluations"])


def _wall_ratio(c, key: str) -> str:
    """CMA-ES's wall time to 1 % over the gradient's: with compilation (`key` ''), its
    first run's (the one that compiled); without (`key` '_warm'), the median run's."""
    runs = c["runs"] if key else c["runs"][:1]
    walls = [r.get(f"wall_to_1pc{key}") for r in runs]
    walls = [w for w in walls if w is not None]
    g = c.get(f"gradient_wall_to_1pc{key}")
    return "-" if not walls or not g else f"**{float(np.median(walls)) / g:.2f}×**"


def _cma_lines(c, label: str) -> list[str]:
    if not c:
        return []

    def wall(x):
        return "-" if x is None else _rounded(x)

    rows = [
        f"| gradient ({label}, `jax.jacfwd`, `fast`: forward sensitivities) | "
        f"{c['gradient_evals_to_1pc']} | {wall(c['gradient_wall_to_1pc'])} | "
        f"{wall(c.get('gradient_wall_to_1pc_warm'))} |"
    ]
    rows += [
        f"| CMA-ES seed {r['seed']} (pop {r['popsize']}, `fast`; best {r['best_default']:.6g}) | "
        f"{_evals_to_1pc(r)} | {wall(r['wall_to_1pc'])} | {wall(r.get('wall_to_1pc_warm'))} |"
        for r in c["runs"]
    ]
    ratio = (
        "-"
        if c["cma_median_evals_to_1pc"] is None or not c["gradient_evals_to_1pc"]
        else f"{c['cma_median_evals_to_1pc'] / c['gradient_evals_to_1pc']:.1f}×"
    )
    return (
        [
            "",
            "## Against CMA-ES on the same 12-D box",
            "",
            f"Best known {c['best_known']:.6g} m/s; within 1 %: ≥ {c['target']:.6g} m/s. A "
            "value-and-gradient solve counts as one simulation.",
            "",
            "| method | simulations to 1 % | wall to 1 % s | without compilation s |",
            "|---|---|---|---|",
        ]
        + rows
        + [
            "",
            f"CMA-ES reached 1 % in {c['cma_reached']} runs (budget {c['budget']} each); "
            f"simulations, CMA-ES median / gradient: **{ratio}**; wall time to 1 %, "
            f"CMA-ES / gradient: {_wall_ratio(c, '')} with compilation (CMA-ES's first run, "
            f"which compiled), {_wall_ratio(c, '_warm')} without (median run; the first "
            "call's excess over the median call subtracted; CMA-ES runs after the first "
            "reuse its compiled solve).",
        ]
    )


if __name__ == "__main__":
    main()

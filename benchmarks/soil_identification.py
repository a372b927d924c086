"""Soil identification (issue 5, beyond the paper): recover E_s, K_Ic and μ_s from a
noisy head trajectory of a simulated worm by gradient-based least squares.

    python benchmarks/soil_identification.py [--quick]

The "observation" is the head position x_1 of the forward gait δ = −π/4 (Table 1 soil:
E_s = 1.4e5 Pa, K_Ic = 250 Pa√m, μ_s = 0.3) at 50 times over (0, t1], plus Gaussian
noise of 0, 10 µm and 100 µm; `jaxworm.identify` fits the three parameters
within E_s ∈ [1e5, 2e5] Pa, K_Ic ∈ [215, 320] Pa√m, μ_s ∈ [0.2, 0.45] with its own
defaults (Adam, 3 starts, 30 steps, `default` preset; 12 steps with `--quick`).
K_Ith = 200 Pa√m and the rest of Table 1 are known. Reports the recovered values and
their relative errors per noise level. Writes
benchmarks/results/soil_identification/soil_identification[_quick].{json,md} and the
histories `soil_identification[_quick]_noise<k>.npz`.
"""

from __future__ import annotations

import argparse
import math
import os
import platform
from datetime import UTC, datetime

import jax
import numpy as np
from _results import quick_suffix, results_dir, write_json

import jaxworm as jw
from jaxworm import identify, observe

TRUE = {"E_s": 1.4e5, "K_Ic": 250.0, "mu_s": 0.3}
BOUNDS = {"E_s": (1.0e5, 2.0e5), "K_Ic": (215.0, 320.0), "mu_s": (0.2, 0.45)}
NOISE = (0.0, 1e-5, 1e-4)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="t1 = 3 s, 3 starts x 12 steps")
    ap.add_argument("--t1", type=float)
    ap.add_argument(
        "--steps",
        type=int,
        help="steps per start (default 30, jaxworm.identify's; 12 with --quick)",
    )
    ap.add_argument("--starts", type=int, default=3, help="default 3, jaxworm.identify's")
    args = ap.parse_args(argv)
    tag = quick_suffix(args.quick)
    folder = results_dir("soil_identification")
    t1 = args.t1 if args.t1 is not None else (3.0 if args.quick else 6.0)
    steps = args.steps if args.steps is not None else (12 if args.quick else 30)
    base = jw.Params().replace(delta=-math.pi / 4)
    ts = np.linspace(t1 / 50, t1, 50)
    truth = base.replace(**TRUE)
    rows = []
    for k, noise in enumerate(NOISE):
        x1 = observe(truth, ts, noise=noise, seed=k)
        res = identify(
            ts,
            x1,
            BOUNDS,
            base=base,
            starts=args.starts,
            steps=steps,
            seed=0,
            path=folder / f"soil_identification{tag}_noise{k}.npz",
            overwrite=True,
        )  # this benchmark's own history, written afresh
        best = res.best_theta
        rows.append(
            {
                "noise_m": noise,
                "recovered": best,
                "relative_error": {n: best[n] / TRUE[n] - 1.0 for n in TRUE},
                "misfit": res.best_value,
                "evaluations": res.n_evaluations,
                "wall_s": float(res.wall_time[res.steps_done - 1]),
            }
        )
        print(rows[-1])
    out = {
        "t1": t1,
        "observations": len(ts),
        "true": TRUE,
        "bounds": BOUNDS,
        "steps": steps,
        "starts": args.starts,
        "rows": rows,
        "machine": {
            "platform": platform.platform(),
            "cpus": os.cpu_count(),
            "jax": jax.__version__,
            "load_average_end": os.getloadavg(),
        },
        "date": datetime.now(UTC).isoformat(timespec="seconds"),
    }
    write_json(folder / f"soil_identification{tag}.json", out, indent=2)
    lines = [
        f"# Soil identification from the head trajectory (t1 = {t1:g} s, {len(ts)} "
        f"observations{', quick' if args.quick else ''})",
        "",
        f"True: E_s = 1.4e5 Pa, K_Ic = 250 Pa√m, μ_s = 0.3. {args.starts} starts × "
        f"{steps} Adam steps per noise level.",
        "",
        "| noise [m] | E_s [Pa] | K_Ic [Pa√m] | μ_s | errors (E_s, K_Ic, μ_s) "
        "| misfit [(1e-4 m)²] | wall s |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        b, e = r["recovered"], r["relative_error"]
        lines.append(
            f"| {r['noise_m']:g} | {b['E_s']:.4g} | {b['K_Ic']:.4g} | {b['mu_s']:.4g} | "
            f"{100 * e['E_s']:+.2f} %, {100 * e['K_Ic']:+.2f} %, {100 * e['mu_s']:+.2f} % | "
            f"{r['misfit']:.3g} | {r['wall_s']:.0f} |"
        )
    lines += [
        "",
        f"Machine: {out['machine']['platform']}, {out['machine']['cpus']} CPUs, load "
        f"average {', '.join(f'{x:.1f}' for x in out['machine']['load_average_end'])}; "
        f"{out['date']}.",
    ]
    (folder / f"soil_identification{tag}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()

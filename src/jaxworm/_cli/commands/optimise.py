"""`jaxworm optimise`: gradient-based tuning of parameters within bounds
(`jaxworm.optimise`), its history saved after every step."""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

import jaxworm as jw

from ..._box import BOXES, DEFAULT_BOX
from ..._control import HORIZONS
from ..._optimise import DEFAULT_BOUNDS
from ..._optimiser import DEFAULT_OPTIMISERS, OPTIMISERS, make_optimiser
from ..._plot import optimisation_axes
from ..outputs import check_distinct, figure_file
from ..runtime import add_process_options, configure_cache, start_processes
from ..scenes import add_scene_options, scene
from ..values import (
    UsageError,
    file_path,
    fraction,
    parse_assignments,
    parse_bounds,
    positive_float,
    positive_int,
)

#: Most starts and steps of one optimisation (its history, starts x steps evaluations,
#: is allocated up front).
MAX_STARTS = 4096
MAX_STEPS = 10_000


def add_parser(sub) -> None:
    D = DEFAULT_OPTIMISERS
    op = sub.add_parser(
        "optimise",
        help="tune gait parameters within bounds by gradients through the solve",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "Optimise parameters within bounds with optax (Adam by default), by "
            "gradients through the simulation and its crack events. Parameters "
            "are kept inside their bounds by a box, theta = lo + (hi - lo)(1 + sin z)/2 "
            "by default (--box). "
            "Several starts run per step; the history is saved after every step. "
            "Default: mean velocity over omega in [3pi, 5pi] x delta in "
            "[-pi/3, -pi/6] (A = 0.02 m/s), t1 = 60 s, preset fast."
        ),
        epilog=(
            "--bound NAME=LO:HI (repeatable) replaces the default bounds; add "
            "--bound A=0.01:0.03 to tune the amplitude. --set fixes the other "
            "parameters (and t1). Presets: fast (forward sensitivities), or default or "
            "accurate (differentiated by diffrax, crack tips held)."
            "\n\nexit codes: 0 every evaluation ok, 1 some evaluation ended with "
            "another status or was not accepted (a non-finite value or gradient), "
            "2 usage error or unusable file (--out another run's or locked, a damaged "
            "--heatmap, an unwritable folder)."
        ),
    )
    op.add_argument(
        "--objective",
        choices=("velocity", "cost_of_transport"),
        default="velocity",
        help="maximise the mean velocity [m/s] or minimise the actuation work "
        "per metre advanced [J/m] (default: velocity)",
    )
    op.add_argument(
        "--bound",
        action="append",
        default=[],
        metavar="NAME=LO:HI",
        help="a parameter to optimise and its bounds (repeatable)",
    )
    op.add_argument(
        "--starts",
        type=positive_int("starts", high=MAX_STARTS),
        default=4,
        help="Latin-hypercube starts in the box, run together (default: 4)",
    )
    op.add_argument(
        "--steps",
        type=positive_int("steps", high=MAX_STEPS),
        default=30,
        help="optimiser steps, one value-and-gradient solve per start each (default: 30)",
    )
    op.add_argument(
        "--optimiser",
        choices=OPTIMISERS,
        default="adam",
        help="an optax optimiser, or rprop (jaxworm's iRprop-) (default: adam)",
    )
    op.add_argument(
        "--lr",
        type=positive_float("lr"),
        default=None,
        help="first step in the unconstrained z; optax optimisers cosine-decay it "
        "to 5 %% (default: "
        + ", ".join(f"{d['learning_rate']:g} on the {b} box" for b, d in D.items())
        + ")",
    )
    op.add_argument(
        "--b1",
        type=fraction("b1"),
        default=None,
        help="momentum of adam and adabelief (default: "
        + ", ".join(f"{d['b1']:g} on the {b} box" for b, d in D.items())
        + ")",
    )
    op.add_argument("--seed", type=int, default=0, help="seed of the starts (default: 0)")
    op.add_argument(
        "--horizon",
        choices=HORIZONS,
        default=None,
        help="simulate [0, t1], or up to the last whole gait period in it, so "
        "that the objective averages over whole periods (default: "
        "whole_periods when omega is optimised, else t1)",
    )
    op.add_argument(
        "--crack-sensitivity",
        choices=("schedule_held", "tips_held", "exact"),
        default=None,
        help="what the derivative does at the crack events (Numerics.crack_sensitivity; "
        "default: the preset's, schedule_held for fast, tips_held for the diffrax "
        "presets); K_Ic and K_Ith need exact under fast",
    )
    op.add_argument(
        "--box",
        choices=tuple(BOXES),
        default=DEFAULT_BOX,
        help="reparametrisation of the bounds: theta = lo + (hi - lo)(1 + sin z)/2, "
        "which reaches a bound in a few steps, or lo + (hi - lo) sigmoid(z), "
        f"strictly inside (default: {DEFAULT_BOX})",
    )
    add_scene_options(op)
    op.set_defaults(preset="fast")
    oo = op.add_argument_group("output")
    oo.add_argument(
        "--out",
        type=file_path("out"),
        default=Path("optimise.npz"),
        help="history file (.npz, saved after every step; default: optimise.npz)",
    )
    oo.add_argument(
        "--overwrite",
        action="store_true",
        help="replace a file at --out that is not the history of this same "
        "optimisation (default: refuse it)",
    )
    oo.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    oo.add_argument("--quiet", action="store_true", help="no progress bar")
    add_process_options(op)
    oo.add_argument(
        "--plot",
        metavar="FILE",
        type=file_path("plot"),
        help="also draw the optimisation paths to FILE",
    )
    oo.add_argument(
        "--heatmap",
        metavar="SWEEP",
        type=Path,
        help="a `jaxworm sweep` file over two of the optimised parameters, "
        "drawn under the paths of --plot",
    )


def optimiser(name: str, lr: float | None, b1: float | None, steps: int, box: str):
    """The optimiser --optimiser, --lr, --b1 and --steps ask for, on the `box`
    reparametrisation (`jaxworm.make_optimiser`; the box's `DEFAULT_OPTIMISERS` fill what
    is not given), and its first learning rate; `UsageError` for a b1 the optimiser has no
    use for."""
    try:
        opt = make_optimiser(name, steps, box=box, learning_rate=lr, b1=b1)
    except ValueError as e:
        raise UsageError(str(e).replace("option b1", "--b1")) from None
    return opt, DEFAULT_OPTIMISERS[box]["learning_rate"] if lr is None else lr


def run(args) -> int:
    bounds = parse_bounds(args.bound)
    params, t1, numerics = scene(args)
    fixed = {n for n in parse_assignments(args.assignments)}
    clash = sorted(fixed & set(bounds or {}))
    if clash:
        raise UsageError(f"parameter {clash[0]} is both fixed (--set) and optimised (--bound)")
    sweep = None
    if args.heatmap is not None:
        if args.plot is None:
            raise UsageError("--heatmap needs --plot FILE (the figure it is drawn in)")
        if not args.heatmap.exists():
            raise UsageError(f"sweep file {str(args.heatmap)!r} does not exist")
        try:
            sweep = jw.load_sweep(args.heatmap)
        except jw.ResultFileError as e:
            raise UsageError(f"--heatmap: {e}") from None
        try:  # the heatmap's axes are the paths': checked before the optimisation runs
            optimisation_axes(list(bounds or DEFAULT_BOUNDS), sweep)
        except ValueError as e:
            raise UsageError(f"--heatmap: {e}") from None
    plot = None if args.plot is None else figure_file("--plot", args.plot, "paths.png")
    check_distinct({"--out": args.out, "--plot": plot, "--heatmap": args.heatmap})
    reports = start_processes(args)
    configure_cache()
    opt, lr = optimiser(args.optimiser, args.lr, args.b1, args.steps, args.box)
    try:
        res = jw.optimise(
            args.objective,
            bounds,
            base=params,
            t1=t1,
            # the fast preset as it stands: jw.optimise's own default for the objective
            numerics=None if numerics == jw.PRESETS["fast"] else numerics,
            starts=args.starts,
            steps=args.steps,
            optimiser=opt,
            seed=args.seed,
            path=args.out,
            progress=not args.quiet,
            horizon=args.horizon,
            box=args.box,
            overwrite=args.overwrite,
            crack_sensitivity=args.crack_sensitivity,
        )
    except jw.SensitivityUnavailableError as e:
        message = str(e).replace("option bounds: ", "--bound ").replace("pass ", "add ")
        message = re.sub(r"crack_sensitivity='(\w+)'", r"--crack-sensitivity \1", message)
        raise UsageError(message) from None
    except ValueError as e:
        raise UsageError(str(e).splitlines()[0]) from None
    if not reports:  # another process of a multi-process run: process 0 reports
        return 0 if bool(res.accepted.all()) else 1
    figure = None
    if plot is not None:
        try:
            figure = jw.plot.plot_optimisation(res, plot, sweep=sweep)
        except (ValueError, KeyError) as e:
            raise UsageError(f"--plot: {e}") from None
    report = res.summary()
    report.update(
        history=str(args.out),
        t1=float(t1),
        preset=args.preset,
        optimiser=args.optimiser,
        lr=lr,
        figure=None if figure is None else str(figure),
    )
    all_ok = bool(res.accepted.all())
    if args.json:
        print(json.dumps(report, allow_nan=False, default=float))
    else:
        unit = report["unit"]
        print(
            f"jaxworm optimise: {report['objective']} over {', '.join(res.names)}; "
            f"{report['starts']} starts x {report['steps_done']} steps, t1 = {t1:g} s, "
            f"preset {args.preset}; history in {args.out}"
        )
        if report["best_value"] is not None:
            at = ", ".join(f"{n} = {v:.6g}" for n, v in report["best_theta"].items())
            print(
                f"  best           {report['best_value']:.6g} {unit} at {at} "
                f"(start {report['best_start']}, step {report['best_step']}; "
                f"mean velocity {report['best_velocity']:.6g} m/s, "
                f"{report['best_n_cracks']} cracks)"
            )
        else:
            print("  best           none: no evaluation ended ok with a finite value")
        bad = int((~res.accepted).sum())
        print(
            f"  evaluations    {report['evaluations']} value-and-gradient solves "
            f"({bad} not ok or not accepted), {report['wall_time_s']:.1f} s"
        )
        if figure is not None:
            print(f"  figure         {figure}")
    return 0 if all_ok else 1

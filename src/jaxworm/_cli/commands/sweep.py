"""`jaxworm sweep`: a grid of scenes in vmapped chunks, each chunk saved when done."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import jaxworm as jw

from ..._control import HORIZONS
from ..._result import STATUS_HINTS
from ..outputs import check_distinct, figure_file
from ..runtime import add_process_options, configure_cache, start_processes
from ..scenes import add_scene_options, scene
from ..values import UsageError, file_path, parse_assignments, parse_grid, positive_int


def add_parser(sub) -> None:
    sw = sub.add_parser(
        "sweep",
        help="solve a grid of scenes in vmapped chunks, saving each chunk",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "Solve every scene of a grid (by default the paper's Fig. 3: omega in "
            "[3pi, 5pi] x delta in [pi/6, pi/3], 21 x 21, t1 = 60 s), a vmapped "
            "chunk at a time. Each finished chunk is saved to --out; running the "
            "same command again resumes where it stopped."
        ),
        epilog=(
            "--grid NAME=START:STOP:NUM (NUM evenly spaced values) or NAME=V1,V2,...; "
            "repeat it for more axes. --set fixes the other parameters (and t1).\n\n"
            "exit codes: 0 every scene ok, 1 some scene ended with another status, "
            "2 usage error or unusable file (damaged, another run's, locked by "
            "another process, unwritable)."
        ),
    )
    sw.add_argument(
        "--grid",
        action="append",
        default=[],
        metavar="NAME=SPEC",
        help="a grid axis (repeatable); default: the paper's omega x delta",
    )
    sw.add_argument(
        "--horizon",
        choices=HORIZONS,
        default="t1",
        help="simulate [0, t1], or each scene up to its last whole gait period "
        "in it, the objective `jaxworm optimise` climbs when it tunes "
        "omega (default: t1)",
    )
    add_scene_options(sw)
    swo = sw.add_argument_group("output")
    swo.add_argument(
        "--out",
        type=file_path("out"),
        default=Path("sweep.npz"),
        help="results file (.npz, self-describing; default: sweep.npz)",
    )
    swo.add_argument(
        "--chunk",
        type=positive_int("chunk"),
        default=None,
        help="scenes per vmapped chunk, each saved when done (default: as "
        "many as ~8 s of compute allows, at most 64, split evenly over "
        "the workers; a resumed sweep keeps its file's)",
    )
    swo.add_argument(
        "--workers",
        type=positive_int("workers"),
        default=None,
        help="chunks solved at once on each device, each from its own thread (default: "
        "one per CPU core on a CPU, 1 on a GPU); processes sharing a host share its "
        "cores: give each its share",
    )
    swo.add_argument(
        "--overwrite",
        action="store_true",
        help="start afresh, discarding whatever the file at --out holds, this same "
        "sweep's finished chunks included (default: resume this same sweep, refuse "
        "any other file)",
    )
    swo.add_argument("--quiet", action="store_true", help="no progress line")
    add_process_options(sw)
    swo.add_argument(
        "--plot",
        metavar="FILE",
        type=file_path("plot"),
        help="also draw the Fig.-3-like heatmap (2-axis sweeps) to FILE",
    )


def run(args) -> int:
    reports = start_processes(args)
    configure_cache()
    params, t1, numerics = scene(args)
    grid = parse_grid(args.grid)
    clash = [name for name in parse_assignments(args.assignments) if name in grid]
    if clash:
        raise UsageError(
            f"parameter {clash[0]} is both fixed (--set) and swept (--grid): drop one "
            "(the grid's values would replace the --set value)"
        )
    figure = None if args.plot is None else figure_file("--plot", args.plot, "fig3.png")
    check_distinct({"--out": args.out, "--plot": figure})
    if figure is not None and len(grid) != 2:
        raise UsageError(f"--plot draws a sweep over 2 parameters; this grid has {len(grid)}")
    try:
        s = jw.sweep(
            grid,
            params,
            t1,
            numerics,
            chunk=args.chunk,
            path=args.out,
            progress=not args.quiet,
            horizon=args.horizon,
            overwrite=args.overwrite,
            workers=args.workers,
        )
    except ValueError as e:  # the library's options are this command's
        message = str(e).splitlines()[0]
        for option in ("workers", "chunk"):
            message = message.replace(f"option {option} = ", f"--{option} ")
        raise UsageError(message) from None
    ok = s["status"] == 0
    if not reports:  # another process of a multi-process run: process 0 reports
        return 0 if ok.all() else 1
    if figure is not None:
        try:
            figure = jw.plot.plot_fig3(s, figure)
        except ValueError as e:
            raise UsageError(str(e)) from None
    v = s["mean_velocity"]
    ok = s["status"] == 0
    axes = " x ".join(f"{n} {len(x)}" for n, x in grid.items())
    print(
        f"jaxworm sweep: {v.size} scenes ({axes}), t1 = {t1:g} s, {int(ok.sum())} ok; "
        f"results in {args.out}"
    )
    if np.any(ok):
        best = np.unravel_index(np.nanargmax(np.where(ok, v, -np.inf)), v.shape)
        at = ", ".join(f"{n} = {grid[n][i]:.6g}" for n, i in zip(grid, best))
        print(f"  highest mean velocity: {v[best]:.6g} m/s at {at}")
    if not ok.all():
        print(f"  not ok: {_not_ok(s['status'][~ok])}")
    if figure is not None:
        print(f"  figure: {figure}")
    return 0 if ok.all() else 1


def _not_ok(codes) -> str:
    """How many scenes ended with each status other than ok, most frequent first, and
    what to do about the most frequent (`STATUS_HINTS`)."""
    values, counts = np.unique(np.asarray(codes, dtype=np.int64), return_counts=True)
    order = np.argsort(-counts, kind="stable")
    names = [jw.STATUS[int(values[i])] for i in order]
    text = ", ".join(f"{int(counts[i])} {name}" for i, name in zip(order, names))
    hint = STATUS_HINTS.get(names[0])
    return f"{text} ({names[0]}: {hint})" if hint else text

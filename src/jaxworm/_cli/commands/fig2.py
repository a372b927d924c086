"""`jaxworm fig2`: the paper's Fig. 2 for one scene."""

from __future__ import annotations

import argparse

import jaxworm as jw

from ..outputs import figure_file, figure_path
from ..report import one_line
from ..runtime import configure_cache
from ..scenes import add_scene_options, dense_run, scene
from ..values import file_path, positive_int

#: Dense output points of `jaxworm fig2` and `jaxworm paper`: 50 per second of the 60-s
#: window, ~25 per gait period at ω = 4π.
FIG2_POINTS = 3000
#: Most dense output times of `jaxworm fig2` (the trajectory is held in memory).
MAX_POINTS = 100_000


def add_parser(sub) -> None:
    f2 = sub.add_parser(
        "fig2",
        help="the paper's Fig. 2 for one scene (the nominal gait unless --set)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "Simulate one scene (Table 1: omega = 4pi, delta = pi/4) with dense "
            "output and draw the paper's Fig. 2: crack tip, head and body nodes "
            "with K_I against K_Ic and K_Ith (left), the forces on the head (upper "
            "right), kinetic and stretching energy (lower right). t1 is 60 s unless "
            "--set: the paper's Fig. 2 is the run marked in its Fig. 3, whose mean "
            "velocity is taken over 60 s."
        ),
        epilog=(
            "exit codes: 0 status ok, 1 another status (the figure is written all the "
            "same), 2 usage error."
        ),
    )
    add_scene_options(f2)
    o = f2.add_argument_group("output")
    o.add_argument(
        "--out",
        type=file_path("out"),
        help="figure file (default: fig2.png, or fig2.pdf with --format pdf)",
    )
    o.add_argument(
        "--format",
        choices=("png", "pdf"),
        help="figure format (default: the suffix of --out, else png)",
    )
    o.add_argument(
        "--points",
        type=positive_int("points", low=2, high=MAX_POINTS),
        default=FIG2_POINTS,
        help=f"dense output times, 2 to {MAX_POINTS} (default: {FIG2_POINTS})",
    )


def run(args) -> int:
    params, t1, numerics = scene(args)
    path = figure_file("--out", figure_path(args.out, args.format, "fig2"), "fig2.png")
    configure_cache()
    result, wall = dense_run(params, t1, numerics, args.points)
    jw.plot.plot_fig2(result, params, path)
    print(f"jaxworm fig2: {path}\n  {one_line(result, t1, wall)}")
    return 0 if str(result.status_name) == "ok" else 1

"""`jaxworm paper`: the nominal scene's Fig. 2, a reduced Fig. 3, and the paper's numbers
beside ours."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jaxworm as jw

from ..report import one_line
from ..runtime import configure_cache
from ..scenes import add_scene_options, dense_run, scene
from ..values import UsageError, positive_int
from .fig2 import FIG2_POINTS


def add_parser(sub) -> None:
    pa = sub.add_parser(
        "paper",
        help="the paper's Fig. 2 and a reduced Fig. 3, with its numbers beside ours",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "Run the nominal scene (Table 1, t1 = 60 s unless --set) to OUT/fig2, "
            "then a reduced Fig. 3 grid (SIZE x SIZE over omega in [3pi, 5pi] x "
            "delta in [pi/6, pi/3], same t1, options and preset) saved to "
            "OUT/fig3_SIZExSIZE.npz (a rerun resumes it) and drawn to OUT/fig3; "
            "prints the nominal mean velocity and crack count and the paper's "
            "numbers beside ours."
        ),
        epilog="exit codes: 0 every scene ok, 1 some scene not ok, 2 usage error.",
    )
    add_scene_options(pa)
    o = pa.add_argument_group("output")
    o.add_argument(
        "--out",
        type=Path,
        default=Path("out"),
        help="folder for the figures and the sweep file (default: out)",
    )
    o.add_argument(
        "--size",
        type=positive_int("size"),
        default=7,
        help="grid points per axis of the reduced Fig. 3 (default: 7; paper: 21)",
    )
    o.add_argument(
        "--format", choices=("png", "pdf"), default="png", help="figure format (default: png)"
    )
    o.add_argument("--quiet", action="store_true", help="no progress line")
    pa.add_argument(
        "--mirror",
        action="store_true",
        help="the mirrored reading: the wave run from head to tail, delta -> "
        "-delta for the nominal scene and the grid (files *_mirrored.*)",
    )


def run(args) -> int:
    if args.size < 2:
        raise UsageError(f"--size {args.size} is out of range: need >= 2")
    params, t1, numerics = scene(args)
    assert isinstance(params.gait, jw.TravellingWave)  # as `scene` builds it
    tag = "_mirrored" if args.mirror else ""
    if args.mirror:
        params = params.replace(delta=-params.gait.delta)
    configure_cache()
    args.out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    result, wall = dense_run(params, t1, numerics, FIG2_POINTS)
    fig2 = jw.plot.plot_fig2(result, params, args.out / f"fig2{tag}.{args.format}")
    print(
        f"jaxworm paper: nominal scene{' (mirrored)' if args.mirror else ''} -> {fig2}\n"
        f"  {one_line(result, t1, wall)}",
        flush=True,
    )
    grid = jw.paper.paper_grid(args.size, delta_sign=-1 if args.mirror else 1)
    data = args.out / f"fig3_{args.size}x{args.size}{tag}.npz"
    try:
        s = jw.sweep(grid, params, t1, numerics, path=data, progress=not args.quiet)
    except ValueError as e:
        raise UsageError(str(e).splitlines()[0]) from None
    gait = params.gait
    assert isinstance(gait, jw.TravellingWave)
    mark = {"omega": float(gait.omega), "delta": float(gait.delta)}
    fig3 = jw.plot.plot_fig3(s, args.out / f"fig3{tag}.{args.format}", mark=mark)
    ok = s["status"] == 0
    summary = result.summary()
    rows = jw.paper.compare_with_paper(
        jw.paper.mirror_sweep(s) if args.mirror else s,
        summary["mean_velocity"],
        summary["n_cracks"],
    )
    note = "  mirrored: jaxworm's delta is minus the paper's, compared at |delta|\n"
    print(
        f"jaxworm paper: reduced Fig. 3 ({args.size} x {args.size}, t1 = {t1:g} s, "
        f"{int(ok.sum())} of {ok.size} ok) -> {fig3}, data {data}\n"
        f"{jw.paper.format_comparison(rows)}\n{note if args.mirror else ''}"
        f"  total {time.perf_counter() - start:.1f} s; docs/reproduction.md explains "
        "the differences"
    )
    return 0 if (ok.all() and summary["status"] == "ok") else 1

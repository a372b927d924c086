"""`jaxworm paper`: the nominal scene's Fig. 2 and a reduced Fig. 3, for the MODEL.md
reading and the mirrored one (the wave run the other way along the body), and the paper's
numbers beside both."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jaxworm as jw

from ... import _sweep
from ..outputs import file_in_folder, output_folder
from ..report import one_line
from ..runtime import configure_cache
from ..scenes import add_scene_options, dense_run, scene
from ..values import UsageError, positive_int
from .fig2 import FIG2_POINTS

#: Largest --size: a size x size grid within `jaxworm.sweep`'s most scenes.
MAX_SIZE = 1000

#: The readings `jaxworm paper` runs: name, sign of δ, file tag, heading.
READINGS = {
    "model": (1, "", "MODEL.md reading (δ as printed)"),
    "mirrored": (-1, "_mirrored", "mirrored reading (δ → −δ)"),
}


def add_parser(sub) -> None:
    pa = sub.add_parser(
        "paper",
        help="the paper's Fig. 2 and a reduced Fig. 3 in both readings, with its numbers",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "Run the nominal scene (Table 1, t1 = 60 s unless --set) and a reduced "
            "Fig. 3 grid (SIZE x SIZE over omega in [3pi, 5pi] x delta in [pi/6, pi/3], "
            "same t1, options and preset) in two readings of the paper: MODEL.md's "
            "(delta as printed; the worm retreats) and the mirrored one (delta -> "
            "-delta, the wave run from head to tail; the worm burrows). Writes "
            "OUT/fig2 (the two nominal scenes, one above the other), OUT/fig3 (the two "
            "grids side by side, one colour scale) and the grids' data "
            "OUT/fig3_SIZExSIZE.npz and OUT/fig3_SIZExSIZE_mirrored.npz (a rerun "
            "resumes them); prints each nominal scene's mean velocity and crack count "
            "and the paper's numbers beside both readings'. --reading model or "
            "mirrored runs one reading alone (files fig2, fig3 and fig2_mirrored, "
            "fig3_mirrored)."
        ),
        epilog=(
            "exit codes: 0 every scene ok, 1 some scene not ok, 2 usage error or "
            "unusable output (--out a file, a grid file of another sweep, damaged or "
            "locked), reported before anything is computed."
        ),
    )
    add_scene_options(pa)
    o = pa.add_argument_group("output")
    o.add_argument(
        "--out",
        type=Path,
        default=Path("out"),
        help="folder for the figures and the sweep files (default: out)",
    )
    o.add_argument(
        "--size",
        type=positive_int("size", low=2, high=MAX_SIZE),
        default=7,
        help="grid points per axis of the reduced Fig. 3 (default: 7; paper: 21)",
    )
    o.add_argument(
        "--format", choices=("png", "pdf"), default="png", help="figure format (default: png)"
    )
    o.add_argument(
        "--overwrite",
        action="store_true",
        help="start the grids afresh, discarding whatever their files in OUT hold, "
        "another sweep's results or this same one's finished scenes (default: resume "
        "this same sweep, refuse any other file)",
    )
    o.add_argument("--quiet", action="store_true", help="no progress line")
    pa.add_argument(
        "--reading",
        choices=("both", *READINGS),
        default="both",
        help="both (default): MODEL.md's and the mirrored one side by side; model: "
        "MODEL.md's alone; mirrored: the mirrored one alone (files *_mirrored.*)",
    )
    pa.add_argument(
        "--mirror",
        action="store_true",
        help="the same as --reading mirrored",
    )


def check_sweep_file(path: Path, grid, params, t1, numerics, overwrite: bool) -> None:
    """`UsageError` unless `jw.sweep(grid, params, t1, numerics, path=path,
    overwrite=overwrite)` may write `path`: the checks it makes itself before solving
    (the path, its lock, a file there that is not this sweep), made before anything of
    `paper` is computed."""
    try:
        _sweep.check_output(path, grid, params, t1, numerics, overwrite)
    except ValueError as e:
        raise UsageError(str(e).splitlines()[0]) from None


def run(args) -> int:
    if args.mirror and args.reading == "model":
        raise UsageError("--mirror and --reading model contradict each other")
    names = (
        ["mirrored"]
        if args.mirror
        else list(READINGS)
        if args.reading == "both"
        else [args.reading]
    )
    params, t1, numerics = scene(args)
    assert isinstance(params.gait, jw.TravellingWave)  # as `scene` builds it
    delta = params.gait.delta
    one = len(names) == 1
    tag = READINGS[names[0]][1] if one else ""
    folder = output_folder("--out", args.out)
    fig2 = file_in_folder("--out", folder, f"fig2{tag}.{args.format}")
    fig3 = file_in_folder("--out", folder, f"fig3{tag}.{args.format}")
    grids = {name: jw.paper.paper_grid(args.size, delta_sign=READINGS[name][0]) for name in names}
    data = {
        name: file_in_folder(
            "--out", folder, f"fig3_{args.size}x{args.size}{READINGS[name][1]}.npz"
        )
        for name in names
    }
    for name in names:
        check_sweep_file(data[name], grids[name], params, t1, numerics, args.overwrite)
    configure_cache()
    start = time.perf_counter()
    scenes = {}
    for name in names:
        sign, _, heading = READINGS[name]
        p = params.replace(delta=sign * delta)
        result, wall = dense_run(p, t1, numerics, FIG2_POINTS)
        scenes[name] = (p, result)
        print(
            f"jaxworm paper: nominal scene, {heading}\n  {one_line(result, t1, wall)}", flush=True
        )
    if one:
        p, result = scenes[names[0]]
        jw.plot.plot_fig2(result, p, fig2)
    else:
        runs = [(r, p, READINGS[n][2]) for n, (p, r) in scenes.items()]
        jw.plot.plot_fig2_rows(runs, fig2)
    sweeps = {}
    for name in names:
        heading = READINGS[name][2]
        if not args.quiet and not one:
            print(f"jaxworm paper: reduced Fig. 3, {heading} -> {data[name]}", flush=True)
        try:
            sweeps[name] = jw.sweep(
                grids[name],
                params,
                t1,
                numerics,
                path=data[name],
                progress=not args.quiet,
                overwrite=args.overwrite,
            )
        except ValueError as e:
            raise UsageError(str(e).splitlines()[0]) from None
    marks = []
    for name in names:
        gait = scenes[name][0].gait
        assert isinstance(gait, jw.TravellingWave)
        marks.append({"omega": float(gait.omega), "delta": float(gait.delta)})
    if one:
        jw.plot.plot_fig3(sweeps[names[0]], fig3, mark=marks[0])
    else:
        jw.plot.plot_fig3_panels(
            list(sweeps.values()), fig3, titles=[READINGS[n][2] for n in names], marks=marks
        )
    rows = {}
    ok_all = True
    counts = []
    for name in names:
        s = sweeps[name]
        ok = s["status"] == 0
        summary = scenes[name][1].summary()
        ok_all = ok_all and bool(ok.all()) and summary["status"] == "ok"
        counts.append(f"{int(ok.sum())} of {ok.size} ok")
        rows["MODEL.md" if name == "model" else "mirrored"] = jw.paper.compare_with_paper(
            jw.paper.mirror_sweep(s) if READINGS[name][0] < 0 else s,
            summary["mean_velocity"],
            summary["n_cracks"],
        )
    note = (
        "  mirrored: jaxworm's delta is minus the paper's, compared at |delta|\n"
        if "mirrored" in names
        else ""
    )
    print(
        f"jaxworm paper: Fig. 2 -> {fig2}; reduced Fig. 3 ({args.size} x {args.size}, "
        f"t1 = {t1:g} s, {', '.join(counts)}) -> {fig3}\n"
        f"{jw.paper.format_readings(rows)}\n{note}"
        f"  total {time.perf_counter() - start:.1f} s; docs/reproduction.md explains "
        "the differences"
    )
    return 0 if ok_all else 1

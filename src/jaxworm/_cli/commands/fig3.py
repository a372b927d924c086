"""`jaxworm fig3`: the Fig.-3-like heatmap of a 2-axis sweep file."""

from __future__ import annotations

from pathlib import Path

import numpy as np

import jaxworm as jw

from ..._plot import solved_note
from ..outputs import check_distinct, figure_file
from ..values import UsageError, file_path


def add_parser(sub) -> None:
    f3 = sub.add_parser(
        "fig3",
        help="heatmap of mean velocity from a 2-axis sweep file",
        description="Draw the Fig.-3-like heatmap of a `jaxworm sweep` file.",
    )
    f3.add_argument("sweep_file", type=Path, help="a file written by `jaxworm sweep`")
    f3.add_argument(
        "--out",
        type=file_path("out"),
        default=Path("fig3.png"),
        help="figure file; the suffix sets the format, .png if none (default: fig3.png)",
    )


def run(args) -> int:
    if not args.sweep_file.exists():
        raise UsageError(f"sweep file {str(args.sweep_file)!r} does not exist")
    out = figure_file("--out", args.out, "fig3.png")
    check_distinct({"sweep file": args.sweep_file, "--out": out})
    try:
        s = jw.load_sweep(args.sweep_file)
    except jw.ResultFileError as e:
        raise UsageError(str(e)) from None
    try:
        path = jw.plot.plot_fig3(s, out)
    except ValueError as e:
        raise UsageError(f"{str(args.sweep_file)!r}: {e}") from None
    print(f"jaxworm fig3: {path}")
    unfinished = solved_note(s)
    if unfinished:
        print(
            f"  the sweep is unfinished{unfinished}: the others are blank; rerun its "
            "sweep command to finish it"
        )
    failed = int(np.sum(np.asarray(s.done) & (np.asarray(s.status) != 0)))
    if failed:
        print(f"  {failed} scene(s) did not end ok: their cells are marked, not coloured")
    # As every command: 0 only when every scene of the figure was solved and ended ok.
    return 1 if unfinished or failed else 0

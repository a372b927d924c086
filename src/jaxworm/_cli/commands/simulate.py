"""`jaxworm simulate`: one scene, its summary as text or JSON, optionally a Fig.-2-like
figure (the only file it writes)."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp

import jaxworm as jw

from ..outputs import file_in_folder, output_folder
from ..report import print_text, run_report
from ..runtime import configure_cache
from ..scenes import add_scene_options, scene
from ..values import PARAMETERS

#: Dense output times of --plot.
DENSE_POINTS = 2000


def add_parser(sub) -> None:
    names = "\n".join(f"  {n:<10} [{u}] {d} (default {v})" for n, (u, v, d) in PARAMETERS.items())
    sim = sub.add_parser(
        "simulate",
        help="simulate one scene and print its summary",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Simulate the worm from rest over [0, t1] (Table 1 unless --set).",
        epilog=(
            "parameters for --set NAME=VALUE (VALUE: a number or an expression in pi,"
            " e.g. 4*pi, pi/4, -pi/3):\n"
            + names
            + "\n\nexit codes: 0 status ok, 1 another status, 2 usage error."
        ),
    )
    add_scene_options(sim)
    out = sim.add_argument_group("output")
    out.add_argument(
        "--json",
        action="store_true",
        help="print one JSON object on stdout instead of the text summary",
    )
    out.add_argument(
        "--plot",
        metavar="DIR",
        type=Path,
        help=f"also draw a Fig.-2-like figure of the run, from dense output at "
        f"{DENSE_POINTS} times, to DIR/fig2.png (or .pdf, --format); DIR is created "
        "if missing",
    )
    out.add_argument(
        "--format", choices=("png", "pdf"), default="png", help="figure format (default: png)"
    )


def run(args) -> int:
    params, t1, numerics = scene(args)
    figure_out = None
    if args.plot is not None:
        folder = output_folder("--plot", args.plot)
        figure_out = file_in_folder("--plot", folder, f"fig2.{args.format}")
    configure_cache()
    ts = jnp.linspace(0.0, t1, DENSE_POINTS) if args.plot is not None else None

    start = time.perf_counter()
    result = jw.simulate(params, t1, numerics, ts=ts)
    jax.block_until_ready(result)
    wall = time.perf_counter() - start

    report = run_report(result, params, t1, numerics, wall)
    figure = None
    if figure_out is not None:
        figure = jw.plot.plot_fig2(result, params, figure_out)
        report["figure"] = str(figure)
    if args.json:
        print(json.dumps(report, allow_nan=False))
    else:
        print_text(report, args.preset, figure)
    return 0 if report["status"] == "ok" else 1

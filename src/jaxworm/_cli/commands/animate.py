"""`jaxworm animate`: a GIF (MP4 with ffmpeg) of one run, the worm in its crack."""

from __future__ import annotations

import argparse
from pathlib import Path

from ... import _animate
from ..outputs import output_file
from ..report import one_line
from ..runtime import configure_cache
from ..scenes import add_scene_options, dense_run, scene
from ..values import UsageError, file_path, positive_int

#: Most frames of one animation (each is a drawn figure).
MAX_FRAMES = 10_000

#: Default horizon of `jaxworm animate` [s]: a few gait periods, a few seconds of GIF.
ANIMATE_T1 = 5.0


def add_parser(sub) -> None:
    an = sub.add_parser(
        "animate",
        help="a GIF (MP4 with ffmpeg) of the worm in its crack",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "Simulate one scene and animate it: segments at their eq.-6 widths "
            "(orange where wider than the crack, which they open), the crack of "
            "width w_c and its tip. t1 is "
            f"{ANIMATE_T1:g} s unless --set."
        ),
        epilog="exit codes: 0 status ok, 1 another status (written all the same), 2 usage error.",
    )
    add_scene_options(an)
    o = an.add_argument_group("output")
    o.add_argument(
        "--out",
        type=file_path("out"),
        default=Path("worm.gif"),
        help="animation file: .gif (Pillow) or .mp4 (needs ffmpeg) (default: worm.gif)",
    )
    o.add_argument(
        "--frames",
        type=positive_int("frames", high=MAX_FRAMES),
        default=100,
        help=f"frames, evenly spaced over [0, t1], at most {MAX_FRAMES} (default: 100)",
    )
    o.add_argument(
        "--fps",
        type=positive_int("fps", high=1000),
        default=20,
        help="frames per second of the animation (default: 20)",
    )


def run(args) -> int:
    params, t1, numerics = scene(args, default_t1=ANIMATE_T1)
    suffix = args.out.suffix.lower()
    if suffix not in (".gif", ".mp4"):
        raise UsageError(f"--out {args.out}: the animation suffix must be .gif or .mp4")
    if suffix == ".mp4" and not _animate.ffmpeg_available():
        raise UsageError(f"--out {args.out}: MP4 needs ffmpeg on the PATH; write a .gif")
    if suffix == ".gif" and args.fps > _animate.GIF_MAX_FPS:
        raise UsageError(_animate.gif_fps_problem(args.fps).replace("option fps", "--fps"))
    output_file("--out", args.out, "worm.gif")
    configure_cache()
    result, wall = dense_run(params, t1, numerics, args.frames)
    _animate.animate(result, params, args.out, fps=args.fps, max_frames=args.frames)
    print(
        f"jaxworm animate: {args.out} ({args.frames} frames at {args.fps} fps)\n"
        f"  {one_line(result, t1, wall)}"
    )
    return 0 if str(result.status_name) == "ok" else 1

"""The scene a command solves: the options every solving command shares (--set, model
options, numerics), the (params, t1, numerics) they give, and a solve with dense output."""

from __future__ import annotations

import dataclasses
import time

import jax
import jax.numpy as jnp

import jaxworm as jw

from .._numerics import INT_OPTIONS
from .._params import MODEL_OPTIONS
from .._validation import check_t1
from .values import (
    DEFAULT_T1,
    UsageError,
    fraction,
    parse_assignments,
    positive_float,
    positive_int,
)

#: Model options that are readings of the paper's equations, each a `--name` choice.
READINGS = ("normal_stress", "friction_forward", "entries", "numbering")


def add_scene_options(cmd) -> None:
    """--set, model options and numerics options, on the subcommand parser `cmd`."""
    cmd.add_argument(
        "--set",
        dest="assignments",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="set a parameter (repeatable; a name set twice takes its last value)",
    )
    model = cmd.add_argument_group("model options")
    model.add_argument(
        "--wedge",
        choices=("given", "eq5"),
        default="given",
        help="Wg as given (Table 1) or derived from eq. 5 (default: given)",
    )
    model.add_argument(
        "--offset",
        choices=("rest", "centred"),
        default="rest",
        help="travelling-wave offset of the intrinsic lengths (default: rest)",
    )
    model.add_argument(
        "--exact", action="store_true", help="exact sgn and max instead of the smoothed ones"
    )
    for name in READINGS:
        info = MODEL_OPTIONS[name]
        model.add_argument(
            f"--{name.replace('_', '-')}",
            choices=info.choices,
            default=None,
            help=f"{info.doc} (default: {info.choices[0]})",
        )
    num = cmd.add_argument_group("numerics")
    num.add_argument(
        "--preset",
        choices=tuple(jw.PRESETS),
        default="fast",
        help="numerics preset (default: %(default)s, the Rosenbrock solver, "
        "differentiated by forward sensitivities)",
    )
    num.add_argument("--solver", choices=jw.SOLVERS, help="diffrax solver")
    num.add_argument("--rtol", type=fraction("rtol"), help="relative tolerance (0 <= rtol < 1)")
    num.add_argument("--atol", type=positive_float("atol"), help="absolute tolerance")
    num.add_argument("--norm", choices=("full", "positions"), help="error norm")
    num.add_argument("--dt", type=positive_float("dt"), help="fixed step [s] (no adaptivity)")
    num.add_argument(
        "--max-cracks",
        type=positive_int("max-cracks", high=INT_OPTIONS["max_cracks"]),
        help="bound on crack events",
    )


def scene(args, default_t1: float = DEFAULT_T1):
    """(params, t1, numerics) from the parsed arguments (t1 [s] is `default_t1` unless
    --set); `UsageError` on bad values."""
    values = parse_assignments(args.assignments)
    t1 = values.pop("t1", default_t1)
    try:
        check_t1(t1)
        p = jw.Params()
        p = dataclasses.replace(
            p,
            soil=dataclasses.replace(p.soil, wedge=args.wedge),
            gait=dataclasses.replace(p.gait, offset=args.offset),
            smoothing=dataclasses.replace(p.smoothing, exact=args.exact),
        )
        p = p.replace(**values)
        chosen = {n: getattr(args, n) for n in READINGS if getattr(args, n) is not None}
        if chosen:
            p = p.replace(**chosen)
    except ValueError as e:
        raise UsageError(str(e).splitlines()[0]) from None

    overrides = {
        k: v
        for k, v in {
            "solver": args.solver,
            "rtol": args.rtol,
            "atol": args.atol,
            "norm": args.norm,
            "dt": args.dt,
            "max_cracks": args.max_cracks,
        }.items()
        if v is not None
    }
    try:
        numerics = jw.PRESETS[args.preset].replace(**overrides)
    except ValueError as e:
        raise UsageError(str(e).splitlines()[0]) from None
    return p, t1, numerics


def dense_run(params, t1, numerics, points: int):
    """One solve with dense output at `points` times over [0, t1]; (result, wall time [s])."""
    start = time.perf_counter()
    result = jw.simulate(params, t1, numerics, ts=jnp.linspace(0.0, t1, points))
    jax.block_until_ready(result)
    return result, time.perf_counter() - start

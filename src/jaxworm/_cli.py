"""The `jaxworm` command line: `jaxworm simulate` runs one scene and reports it;
`jaxworm sweep` solves a grid of scenes, saving as it goes; `jaxworm optimise` tunes
parameters within bounds by gradients through the solve; `jaxworm paper`, `fig2` and
`animate` reproduce the paper's figures and animate a run.

```
jaxworm simulate                                  # Table 1, 60 s, summary on stdout
jaxworm simulate --set omega=3*pi --set delta=pi/3 --json
jaxworm simulate --set t1=10 --preset accurate --plot out/
jaxworm sweep --grid omega=3*pi:5*pi:5 --grid delta=pi/6,pi/3 --set t1=10 --out s.npz
jaxworm optimise --set t1=10 --steps 20 --plot paths.png --heatmap s.npz
jaxworm paper --out out/                          # Fig. 2 + a 7 x 7 Fig. 3 + the paper's numbers
```

Exit codes: 0 the run finished with status "ok"; 1 it finished with another status
(the summary or JSON is printed all the same); 2 a usage error (unknown parameter,
malformed or out-of-range value, bad option) or a file that cannot be used (a damaged
or foreign result file, another run's file at --out, an output another jaxworm process
is writing, a folder that does not exist or cannot be written), reported as one line on
stderr before anything is computed.

Result files (`sweep`, `optimise`) are only ever replaced by the same run: a sweep's
--out resumes the same sweep, an optimisation's --out is rewritten by the same problem;
any other file there is refused unless --overwrite.

Compiled programs are kept in JAX's persistent compilation cache, so a second run of the
same scene shape does not compile again: `~/.cache/jaxworm/jax` by default, or the
folder `JAXWORM_CACHE_DIR` names (set it empty to switch the cache off).
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import json
import math
import operator
import os
import sys
import time
from pathlib import Path

__all__ = ["main", "parse_value"]

#: Flat parameter names the CLI accepts, with units and defaults (Table 1 and MODEL.md).
PARAMETERS: dict[str, tuple[str, str, str]] = {
    # name: (unit, default as shown, description)
    "N": ("-", "7", "number of nodes (integer >= 2)"),
    "E_s": ("Pa", "1.4e5", "soil elasticity"),
    "K_Ic": ("Pa·√m", "250", "critical stress intensity factor"),
    "K_Ith": ("Pa·√m", "200", "threshold stress intensity factor (< K_Ic)"),
    "nu": ("-", "0.3", "Poisson's ratio, in [0, 0.5)"),
    "w_c": ("m", "1e-3", "crack width"),
    "Wg": ("-", "4.59e-4", "wedge number"),
    "EA": ("N", "13", "stretching stiffness (Table 1 writes Pa·m²)"),
    "w0": ("m", "1e-3", "unstretched segment width"),
    "l0": ("m", "1e-2", "unstretched segment length"),
    "h": ("m", "1e-3", "planar thickness"),
    "m": ("kg", "1e-5", "mass per segment"),
    "mu_s": ("-", "0.3", "sliding friction coefficient"),
    "lam": ("-", "1.5", "friction anisotropy multiplier (>= 1)"),
    "A": ("m/s", "0.02", "gait amplitude"),
    "omega": ("rad/s", "4*pi", "gait angular frequency (> 0)"),
    "delta": ("rad", "pi/4", "gait phase offset between segments"),
    "t1": ("s", "60", "simulated horizon (not a model parameter)"),
    "eps_v": ("m/s", "1e-4", "smoothing scale of sgn: tanh(v/eps_v)"),
    "eps_N": ("N", "1e-8", "smoothing scale of max in the normal force"),
    "crack_gap0": ("m", "eq. 13", "initial crack tip distance ahead of the head"),
}

DEFAULT_T1 = 60.0
#: Most values on one --grid axis.
MAX_AXIS = 10_000
DENSE_POINTS = 2000


# --- values: numbers and expressions in pi ------------------------------------------------

_BINARY = {ast.Add: operator.add, ast.Sub: operator.sub, ast.Mult: operator.mul,
           ast.Div: operator.truediv, ast.Pow: operator.pow}
_UNARY = {ast.USub: operator.neg, ast.UAdd: operator.pos}
_NAMES = {"pi": math.pi}


def parse_value(text: str) -> float:
    """A number, or an arithmetic expression in numbers and `pi` (`4*pi`, `-pi/3`, `2**-3`).

    Only numeric literals, the name `pi`, `+ - * / **` and parentheses are accepted; the
    expression is walked, never `eval`-ed. Raises `ValueError` on anything else or on a
    non-finite result.
    """

    def walk(node):
        if isinstance(node, ast.Expression):
            return walk(node.body)
        if isinstance(node, ast.Constant) and type(node.value) in (int, float):
            return float(node.value)
        if isinstance(node, ast.Name) and node.id in _NAMES:
            return _NAMES[node.id]
        if isinstance(node, ast.BinOp) and type(node.op) in _BINARY:
            return _BINARY[type(node.op)](walk(node.left), walk(node.right))
        if isinstance(node, ast.UnaryOp) and type(node.op) in _UNARY:
            return _UNARY[type(node.op)](walk(node.operand))
        raise ValueError("only numbers, pi, + - * / ** and parentheses are allowed")

    text = text.strip()
    if not text or len(text) > 200:
        raise ValueError("need a number or an expression such as 4*pi")
    try:
        value = walk(ast.parse(text, mode="eval"))
    except SyntaxError:
        raise ValueError("not a number or an arithmetic expression") from None
    except (ZeroDivisionError, OverflowError) as e:
        raise ValueError(f"cannot evaluate it ({e})") from None
    if isinstance(value, complex) or not math.isfinite(value):
        raise ValueError("the value is not a finite real number")
    return value


def _parse_assignments(items: list[str]) -> dict[str, float | int]:
    """`["NAME=VALUE", ...]` to `{name: value}`; the last of repeated names wins."""
    values: dict[str, float | int] = {}
    for item in items:
        name, sep, text = item.partition("=")
        name = name.strip()
        if not sep or not name:
            raise _UsageError(f"--set {item!r} is malformed: need NAME=VALUE, e.g. omega=3*pi")
        if name not in PARAMETERS:
            raise _UsageError(f"unknown parameter {name!r} in --set {item}; "
                              f"known: {', '.join(PARAMETERS)}")
        try:
            value = parse_value(text)
        except ValueError as e:
            raise _UsageError(f"--set {name}={text}: bad value {text!r}: {e}") from None
        if name == "N":
            if value != int(value):
                raise _UsageError(f"parameter N = {text} is not an integer: need an integer N >= 2")
            value = int(value)
        values[name] = value
    return values


# --- argument parsing ----------------------------------------------------------------------

class _UsageError(Exception):
    """A user error: reported as one line on stderr, exit code 2."""


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (no usage dump) and exit code 2."""

    def error(self, message):
        raise _UsageError(message)


def _build_parser() -> argparse.ArgumentParser:
    import jaxworm as jw
    from ._control import HORIZONS

    parser = _Parser(prog="jaxworm", description=(
        "Differentiable simulator of worm-inspired burrowing by crack propagation."))
    parser.add_argument("--version", action="version", version=f"jaxworm {jw.__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

    names = "\n".join(f"  {n:<10} [{u}] {d} (default {v})" for n, (u, v, d) in PARAMETERS.items())
    sim = sub.add_parser(
        "simulate", help="simulate one scene and print its summary",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Simulate the worm from rest over [0, t1] (Table 1 unless --set).",
        epilog=("parameters for --set NAME=VALUE (VALUE: a number or an expression in pi,"
                " e.g. 4*pi, pi/4, -pi/3):\n" + names +
                "\n\nexit codes: 0 status ok, 1 another status, 2 usage error."))
    _add_scene_options(sim)
    out = sim.add_argument_group("output")
    out.add_argument("--json", action="store_true",
                     help="print one JSON object on stdout instead of the text summary")
    out.add_argument("--plot", metavar="DIR", type=Path,
                     help=f"also save dense output ({DENSE_POINTS} times) and a Fig.-2-like "
                          "figure in DIR")
    out.add_argument("--format", choices=("png", "pdf"), default="png",
                     help="figure format (default: png)")
    sw = sub.add_parser(
        "sweep", help="solve a grid of scenes in vmapped chunks, saving each chunk",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=("Solve every scene of a grid (by default the paper's Fig. 3: omega in "
                     "[3pi, 5pi] x delta in [pi/6, pi/3], 21 x 21, t1 = 60 s), a vmapped "
                     "chunk at a time. Each finished chunk is saved to --out; running the "
                     "same command again resumes where it stopped."),
        epilog=("--grid NAME=START:STOP:NUM (NUM evenly spaced values) or NAME=V1,V2,...; "
                "repeat it for more axes. --set fixes the other parameters (and t1).\n\n"
                "exit codes: 0 every scene ok, 1 some scene ended with another status, "
                "2 usage error or unusable file (damaged, another run's, locked by "
                "another process, unwritable)."))
    sw.add_argument("--grid", action="append", default=[], metavar="NAME=SPEC",
                    help="a grid axis (repeatable); default: the paper's omega x delta")
    sw.add_argument("--horizon", choices=HORIZONS, default="t1",
                    help="simulate [0, t1], or each scene up to its last whole gait period "
                         "in it, the objective `jaxworm optimise` climbs when it tunes "
                         "omega (default: t1)")
    _add_scene_options(sw)
    swo = sw.add_argument_group("output")
    swo.add_argument("--out", type=Path, default=Path("sweep.npz"),
                     help="results file (.npz, self-describing; default: sweep.npz)")
    swo.add_argument("--chunk", type=_positive_int("chunk"), default=None,
                     help="scenes per vmapped chunk, each saved when done (default: as "
                          "many as ~8 s of compute allows, at most 64, split evenly over "
                          "the CPU cores or devices; a resumed sweep keeps its file's)")
    swo.add_argument("--overwrite", action="store_true",
                     help="replace a file at --out that holds anything but this sweep "
                          "(default: refuse it)")
    swo.add_argument("--quiet", action="store_true", help="no progress line")
    swo.add_argument("--plot", metavar="FILE", type=Path,
                     help="also draw the Fig.-3-like heatmap (2-axis sweeps) to FILE")
    f3 = sub.add_parser("fig3", help="heatmap of mean velocity from a 2-axis sweep file",
                        description="Draw the Fig.-3-like heatmap of a `jaxworm sweep` file.")
    f3.add_argument("sweep_file", type=Path, help="a file written by `jaxworm sweep`")
    f3.add_argument("--out", type=Path, default=Path("fig3.png"),
                    help="figure file; the suffix sets the format, .png if none "
                         "(default: fig3.png)")
    _add_optimise_command(sub)
    _add_reproduction_commands(sub)
    return parser


def _add_optimise_command(sub) -> None:
    """`jaxworm optimise`: gradient-based gait tuning within bounds (`jaxworm.optimise`)."""
    from ._control import HORIZONS
    from ._optimise import BOXES, DEFAULT_BOX, DEFAULT_OPTIMISERS as D

    op = sub.add_parser(
        "optimise", help="tune gait parameters within bounds by gradients through the solve",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=("Optimise parameters within bounds with optax (Adam by default), by "
                     "gradients through the simulation and its crack events. Parameters "
                     "are kept inside their bounds by theta = lo + (hi - lo) sigmoid(z). "
                     "Several starts run per step; the history is saved after every step. "
                     "Default: mean velocity over omega in [3pi, 5pi] x delta in "
                     "[-pi/3, -pi/6] (A = 0.02 m/s), t1 = 60 s, preset fast."),
        epilog=("--bound NAME=LO:HI (repeatable) replaces the default bounds; add "
                "--bound A=0.01:0.03 to tune the amplitude. --set fixes the other "
                "parameters (and t1). Presets: fast (forward sensitivities), or default or "
                "accurate (differentiated by diffrax, crack tips held)."
                "\n\nexit codes: 0 every evaluation ok, 1 some evaluation ended with "
                "another status, 2 usage error or unusable file (--out another run's or "
                "locked, a damaged --heatmap, an unwritable folder)."))
    op.add_argument("--objective", choices=("velocity", "cost_of_transport"),
                    default="velocity",
                    help="maximise the mean velocity [m/s] or minimise the actuation work "
                         "per metre advanced [J/m] (default: velocity)")
    op.add_argument("--bound", action="append", default=[], metavar="NAME=LO:HI",
                    help="a parameter to optimise and its bounds (repeatable)")
    op.add_argument("--starts", type=_positive_int("starts"), default=4,
                    help="Latin-hypercube starts in the box, run together (default: 4)")
    op.add_argument("--steps", type=_positive_int("steps"), default=30,
                    help="optimiser steps, one value-and-gradient solve per start each "
                         "(default: 30)")
    op.add_argument("--optimiser", choices=tuple(_OPTIMISERS), default="adam",
                    help="an optax optimiser, or rprop (jaxworm's iRprop-) (default: adam)")
    op.add_argument("--lr", type=_positive_float("lr"), default=None,
                    help="first step in the unconstrained z; optax optimisers cosine-decay it "
                         "to 5 %% (default: " + ", ".join(
                             f"{d['learning_rate']:g} on the {b} box" for b, d in D.items()) + ")")
    op.add_argument("--b1", type=_fraction("b1"), default=None,
                    help="momentum of adam and adabelief (default: " + ", ".join(
                        f"{d['b1']:g} on the {b} box" for b, d in D.items()) + ")")
    op.add_argument("--seed", type=int, default=0, help="seed of the starts (default: 0)")
    op.add_argument("--horizon", choices=HORIZONS, default=None,
                    help="simulate [0, t1], or up to the last whole gait period in it, so "
                         "that the objective averages over whole periods (default: "
                         "whole_periods when omega is optimised, else t1)")
    op.add_argument("--box", choices=tuple(BOXES), default=DEFAULT_BOX,
                    help="reparametrisation of the bounds: theta = lo + (hi - lo)(1 + sin z)/2, "
                         "which reaches a bound in a few steps, or lo + (hi - lo) sigmoid(z), "
                         f"strictly inside (default: {DEFAULT_BOX})")
    _add_scene_options(op)
    op.set_defaults(preset="fast")
    oo = op.add_argument_group("output")
    oo.add_argument("--out", type=Path, default=Path("optimise.npz"),
                    help="history file (.npz, saved after every step; default: optimise.npz)")
    oo.add_argument("--overwrite", action="store_true",
                    help="replace a file at --out that is not the history of this same "
                         "optimisation (default: refuse it)")
    oo.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    oo.add_argument("--quiet", action="store_true", help="no progress bar")
    oo.add_argument("--plot", metavar="FILE", type=Path,
                    help="also draw the optimisation paths to FILE")
    oo.add_argument("--heatmap", metavar="SWEEP", type=Path,
                    help="a `jaxworm sweep` file over two of the optimised parameters, "
                         "drawn under the paths of --plot")


#: `--optimiser` names: optax transformations of one learning rate (sgd with momentum 0.9),
#: cosine-decayed, and jaxworm's iRprop− (`_optimise.rprop`, --lr its first step).
_OPTIMISERS = ("adam", "adabelief", "rmsprop", "sgd", "rprop")


def _add_scene_options(cmd) -> None:
    """--set, model options and numerics options, shared by `simulate` and `sweep`."""
    import jaxworm as jw

    cmd.add_argument("--set", dest="assignments", action="append", default=[],
                     metavar="NAME=VALUE", help="set a parameter (repeatable)")
    model = cmd.add_argument_group("model options")
    model.add_argument("--wedge", choices=("given", "eq5"), default="given",
                       help="Wg as given (Table 1) or derived from eq. 5 (default: given)")
    model.add_argument("--offset", choices=("rest", "centred"), default="rest",
                       help="travelling-wave offset of the intrinsic lengths (default: rest)")
    model.add_argument("--exact", action="store_true",
                       help="exact sgn and max instead of the smoothed ones")
    num = cmd.add_argument_group("numerics")
    num.add_argument("--preset", choices=tuple(jw.PRESETS), default="fast",
                     help="numerics preset (default: %(default)s, the Rosenbrock solver, "
                          "differentiated by forward sensitivities)")
    num.add_argument("--solver", choices=jw.SOLVERS, help="diffrax solver")
    num.add_argument("--rtol", type=_positive_float("rtol", allow_zero=True),
                     help="relative tolerance")
    num.add_argument("--atol", type=_positive_float("atol"), help="absolute tolerance")
    num.add_argument("--norm", choices=("full", "positions"), help="error norm")
    num.add_argument("--dt", type=_positive_float("dt"), help="fixed step [s] (no adaptivity)")
    num.add_argument("--max-cracks", type=_positive_int("max-cracks"),
                     help="bound on crack events")


def _positive_float(name, allow_zero=False):
    def convert(text):
        try:
            value = parse_value(text)
        except ValueError as e:
            raise argparse.ArgumentTypeError(f"--{name} {text}: {e}") from None
        if not (value >= 0 if allow_zero else value > 0):
            raise argparse.ArgumentTypeError(
                f"--{name} {text} is out of range: need {name} {'>=' if allow_zero else '>'} 0")
        return value
    return convert


def _fraction(name):
    """A number in [0, 1) (a momentum)."""
    def convert(text):
        try:
            value = parse_value(text)
        except ValueError as e:
            raise argparse.ArgumentTypeError(f"--{name} {text}: {e}") from None
        if not 0 <= value < 1:
            raise argparse.ArgumentTypeError(
                f"--{name} {text} is out of range: need 0 <= {name} < 1")
        return value
    return convert


def _positive_int(name):
    def convert(text):
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"--{name} {text!r} is not an integer") from None
        if value < 1:
            raise argparse.ArgumentTypeError(f"--{name} {text} is out of range: need >= 1")
        return value
    return convert


# --- building the scene ------------------------------------------------------------------

def _scene(args, default_t1: float = DEFAULT_T1):
    """(params, t1, numerics) from the parsed arguments (t1 [s] is `default_t1` unless
    --set); `_UsageError` on bad values."""
    import jaxworm as jw
    from ._validation import check_t1

    values = _parse_assignments(args.assignments)
    t1 = values.pop("t1", default_t1)
    try:
        check_t1(t1)
        p = jw.Params()
        p = dataclasses.replace(
            p, soil=dataclasses.replace(p.soil, wedge=args.wedge),
            gait=dataclasses.replace(p.gait, offset=args.offset),
            smoothing=dataclasses.replace(p.smoothing, exact=args.exact))
        p = p.replace(**values)
    except ValueError as e:
        raise _UsageError(str(e).splitlines()[0]) from None

    overrides = {k: v for k, v in {
        "solver": args.solver, "rtol": args.rtol, "atol": args.atol, "norm": args.norm,
        "dt": args.dt, "max_cracks": args.max_cracks}.items() if v is not None}
    try:
        numerics = jw.PRESETS[args.preset].replace(**overrides)
    except ValueError as e:
        raise _UsageError(str(e).splitlines()[0]) from None
    return p, t1, numerics


def _configure_cache() -> str | None:
    """Point JAX's persistent compilation cache at the jaxworm cache folder."""
    import jax

    path = os.environ.get("JAXWORM_CACHE_DIR")
    if path is None:
        path = os.path.join(os.path.expanduser("~"), ".cache", "jaxworm", "jax")
    if not path:
        return None
    if jax.config.jax_compilation_cache_dir != path:
        # JAX opens its persistent cache once per process, at the first compilation: a
        # folder set after that (an earlier compile in a notebook, or another command
        # with another folder) only takes effect once the cache is reset.
        from jax.experimental.compilation_cache import compilation_cache

        jax.config.update("jax_compilation_cache_dir", path)
        compilation_cache.reset_cache()
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)
    return path


def _finite_or_none(x):
    return x if isinstance(x, (int, str)) or x is None or math.isfinite(x) else None


def _report(result, params, t1, numerics, wall) -> dict:
    """The JSON-able summary of a run, with the parameters and numerics used."""
    import numpy as np

    out = result.summary()
    out = {k: ([_finite_or_none(v) for v in val] if isinstance(val, list) else _finite_or_none(val))
           for k, val in out.items()}
    out["wall_time_s"] = wall
    used = {}
    for name, value in params.flat().items():
        if name == "N":
            used[name] = int(value)
        elif value is None:
            used[name] = None
        else:
            used[name] = float(np.asarray(value))
    used["t1"] = float(t1)
    out["parameters"] = used
    out["options"] = {"wedge": params.soil.wedge, "offset": getattr(params.gait, "offset", None),
                      "exact_smoothing": params.smoothing.exact}
    out["numerics"] = {f.name: getattr(numerics, f.name) for f in dataclasses.fields(numerics)}
    return out


def _print_text(report: dict, preset: str, figure: Path | None) -> None:
    n = report["numerics"]
    p = report["parameters"]
    times = report["crack_times"]
    cracks = f"{report['n_cracks']}"
    if times:
        cracks += f" (first at {times[0]:.3g} s, last at {times[-1]:.3g} s)"
    mv = report["mean_velocity"]
    lines = [
        f"jaxworm: t1 = {p['t1']:g} s, omega = {p['omega']:.4g} rad/s, delta = {p['delta']:.4g} "
        f"rad, A = {p['A']:g} m/s; preset {preset} ({n['solver']}, rtol {n['rtol']:g}, "
        f"atol {n['atol']:g}{', dt ' + format(n['dt'], 'g') if n['dt'] else ''})",
        f"  mean velocity  {mv:.6g} m/s" if mv is not None else "  mean velocity  nan",
        f"  cracks         {cracks}",
        f"  status         {report['status_message']}",
        f"  steps          {report['steps']} (rejected {report['rejected_steps']})",
        f"  wall time      {report['wall_time_s']:.2f} s (compile included)",
    ]
    if report["t_end"] is not None and report["t_end"] < p["t1"]:
        lines.insert(2, f"  simulated      {report['t_end']:.6g} s of t1 = {p['t1']:g} s "
                        "(stopped early; the mean velocity is over the time simulated)")
    if figure is not None:
        lines.append(f"  figure         {figure}")
    print("\n".join(lines))


def _simulate(args) -> int:
    import jax
    import jax.numpy as jnp

    import jaxworm as jw

    params, t1, numerics = _scene(args)
    _configure_cache()
    ts = jnp.linspace(0.0, t1, DENSE_POINTS) if args.plot is not None else None

    start = time.perf_counter()
    result = jw.simulate(params, t1, numerics, ts=ts)
    jax.block_until_ready(result)
    wall = time.perf_counter() - start

    report = _report(result, params, t1, numerics, wall)
    figure = None
    if args.plot is not None:
        from ._plot import plot_fig2

        args.plot.mkdir(parents=True, exist_ok=True)
        figure = plot_fig2(result, params, args.plot / f"fig2.{args.format}")
        report["figure"] = str(figure)
    if args.json:
        print(json.dumps(report, allow_nan=False))
    else:
        _print_text(report, args.preset, figure)
    return 0 if report["status"] == "ok" else 1


def _parse_grid(items: list[str]) -> dict[str, list[float]]:
    """`["NAME=START:STOP:NUM" | "NAME=V1,V2,...", ...]` to `{name: values}`."""
    if not items:  # the paper's Fig. 3
        return {"omega": [3 * math.pi + 2 * math.pi * i / 20 for i in range(21)],
                "delta": [math.pi / 6 + (math.pi / 6) * i / 20 for i in range(21)]}
    grid: dict[str, list[float]] = {}
    for item in items:
        name, sep, spec = item.partition("=")
        name = name.strip()
        if not sep or not name or not spec:
            raise _UsageError(f"--grid {item!r} is malformed: need NAME=START:STOP:NUM or "
                              "NAME=V1,V2,...")
        if name in grid:
            raise _UsageError(f"--grid {item}: parameter {name} is given twice; give each "
                              "axis once (NAME=V1,V2,... lists several values)")
        try:
            if ":" in spec:
                parts = spec.split(":")
                if len(parts) != 3:
                    raise ValueError("need START:STOP:NUM")
                start, stop = parse_value(parts[0]), parse_value(parts[1])
                try:
                    num = int(parts[2])
                except ValueError:
                    raise ValueError(f"NUM = {parts[2]!r} is not an integer") from None
                if not 1 <= num <= MAX_AXIS:
                    raise ValueError(f"NUM = {num} is out of range: need 1 <= NUM <= {MAX_AXIS}")
                if (num > 1) == (start == stop):
                    raise ValueError("a degenerate range: START = STOP needs NUM = 1, and NUM = "
                                     "1 needs START = STOP (or give the value alone)")
                values = [start + (stop - start) * i / max(num - 1, 1) for i in range(num)]
            else:
                values = [parse_value(v) for v in spec.split(",")]
        except ValueError as e:
            raise _UsageError(f"--grid {item}: {e}") from None
        grid[name] = values
    return grid


def _sweep(args) -> int:
    import numpy as np

    import jaxworm as jw

    _configure_cache()
    params, t1, numerics = _scene(args)
    grid = _parse_grid(args.grid)
    figure = None if args.plot is None else _figure_file("--plot", args.plot, "fig3.png")
    if figure is not None and len(grid) != 2:
        raise _UsageError(f"--plot draws a sweep over 2 parameters; this grid has {len(grid)}")
    try:
        s = jw.sweep(grid, params, t1, numerics, chunk=args.chunk, path=args.out,
                     progress=not args.quiet, horizon=args.horizon, overwrite=args.overwrite)
    except ValueError as e:
        raise _UsageError(str(e).splitlines()[0]) from None
    if figure is not None:
        from ._plot import plot_fig3
        try:
            figure = plot_fig3(s, figure)
        except ValueError as e:
            raise _UsageError(str(e)) from None
    v = s["mean_velocity"]
    ok = s["status"] == 0
    print(f"jaxworm sweep: {v.size} scenes ({' x '.join(f'{n} {len(x)}' for n, x in grid.items())}),"
          f" t1 = {t1:g} s, {int(ok.sum())} ok; results in {args.out}")
    if np.any(ok):
        best = np.unravel_index(np.nanargmax(np.where(ok, v, -np.inf)), v.shape)
        at = ", ".join(f"{n} = {grid[n][i]:.6g}" for n, i in zip(grid, best))
        print(f"  highest mean velocity: {v[best]:.6g} m/s at {at}")
    if figure is not None:
        print(f"  figure: {figure}")
    return 0 if ok.all() else 1


def _fig3(args) -> int:
    import jaxworm as jw

    from ._plot import plot_fig3

    if not args.sweep_file.exists():
        raise _UsageError(f"sweep file {str(args.sweep_file)!r} does not exist")
    out = _figure_file("--out", args.out, "fig3.png")
    try:
        s = jw.load_sweep(args.sweep_file)
    except jw.ResultFileError as e:
        raise _UsageError(str(e)) from None
    try:
        path = plot_fig3(s, out)
    except ValueError as e:
        raise _UsageError(f"{str(args.sweep_file)!r}: {e}") from None
    print(f"jaxworm fig3: {path}")
    return 0


def _figure_file(option: str, out: Path, default_name: str) -> Path:
    """The figure file `out` names (`.png` added when it has no suffix), checked before
    anything is computed: a format matplotlib writes, not a folder, in a folder that
    exists and is writable (none is created)."""
    from matplotlib.backend_bases import FigureCanvasBase

    if out.is_dir():
        raise _UsageError(f"{option} {str(out)!r} is a folder: give a file such as "
                          f"{str(out / default_name)!r}")
    if not out.suffix:
        out = out.with_suffix(".png")
    formats = FigureCanvasBase.get_supported_filetypes()
    if out.suffix.lower().lstrip(".") not in formats:
        raise _UsageError(f"{option} {str(out)!r}: unknown figure format {out.suffix!r}; "
                          f"need one of {', '.join('.' + f for f in sorted(formats))}")
    folder = out.parent
    if not folder.is_dir():
        raise _UsageError(f"{option} {str(out)!r}: folder {str(folder)!r} does not exist; "
                          "create it first")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise _UsageError(f"{option} {str(out)!r}: no permission to write in folder "
                          f"{str(folder)!r}")
    return out


def _parse_bounds(items: list[str]) -> dict[str, tuple[float, float]] | None:
    """`["NAME=LO:HI", ...]` to `{name: (lo, hi)}`; `None` (the defaults) when empty."""
    if not items:
        return None
    bounds: dict[str, tuple[float, float]] = {}
    for item in items:
        name, sep, spec = item.partition("=")
        name = name.strip()
        parts = spec.split(":")
        if not sep or not name or len(parts) != 2:
            raise _UsageError(f"--bound {item!r} is malformed: need NAME=LO:HI, e.g. "
                              "delta=-pi/3:-pi/6")
        try:
            lo, hi = parse_value(parts[0]), parse_value(parts[1])
        except ValueError as e:
            raise _UsageError(f"--bound {item}: {e}") from None
        bounds[name] = (lo, hi)
    return bounds


def _optimise(args) -> int:
    import optax

    import jaxworm as jw
    from ._optimise import DEFAULT_OPTIMISERS, rprop

    bounds = _parse_bounds(args.bound)
    params, t1, numerics = _scene(args)
    fixed = {n for n in _parse_assignments(args.assignments)}
    clash = sorted(fixed & set(bounds or {}))
    if clash:
        raise _UsageError(f"parameter {clash[0]} is both fixed (--set) and optimised (--bound)")
    sweep = None
    if args.heatmap is not None:
        if args.plot is None:
            raise _UsageError("--heatmap needs --plot FILE (the figure it is drawn in)")
        if not args.heatmap.exists():
            raise _UsageError(f"sweep file {str(args.heatmap)!r} does not exist")
        try:
            sweep = jw.load_sweep(args.heatmap)
        except jw.ResultFileError as e:
            raise _UsageError(f"--heatmap: {e}") from None
    plot = None if args.plot is None else _figure_file("--plot", args.plot, "paths.png")
    _configure_cache()
    defaults = DEFAULT_OPTIMISERS[args.box]
    name = args.optimiser
    lr = defaults["learning_rate"] if args.lr is None else args.lr
    if args.b1 is not None and name not in ("adam", "adabelief"):
        raise _UsageError(f"--b1 = {args.b1!r}: only adam and adabelief have a momentum b1, "
                          f"not {name}")
    schedule = optax.cosine_decay_schedule(lr, args.steps, alpha=0.05)
    b1 = defaults["b1"] if args.b1 is None else args.b1
    opt = (optax.sgd(schedule, momentum=0.9) if name == "sgd"
           else rprop(lr) if name == "rprop"  # its own step control: no schedule
           else optax.rmsprop(schedule) if name == "rmsprop"
           else getattr(optax, name)(schedule, b1=b1))
    try:
        res = jw.optimise(args.objective, bounds, base=params, t1=t1, numerics=numerics,
                          starts=args.starts, steps=args.steps, optimiser=opt,
                          seed=args.seed, path=args.out, progress=not args.quiet,
                          horizon=args.horizon, box=args.box, overwrite=args.overwrite)
    except ValueError as e:
        raise _UsageError(str(e).splitlines()[0]) from None
    figure = None
    if plot is not None:
        from ._plot import plot_optimisation
        try:
            figure = plot_optimisation(res, plot, sweep=sweep)
        except (ValueError, KeyError) as e:
            raise _UsageError(f"--plot: {e}") from None
    report = res.summary()
    report.update(history=str(args.out), t1=float(t1), preset=args.preset,
                  optimiser=name, lr=lr,
                  figure=None if figure is None else str(figure))
    all_ok = bool((res.status[: res.steps_done] == 0).all())
    if args.json:
        print(json.dumps(report, allow_nan=False, default=float))
    else:
        unit = report["unit"]
        print(f"jaxworm optimise: {report['objective']} over {', '.join(res.names)}; "
              f"{report['starts']} starts x {report['steps_done']} steps, t1 = {t1:g} s, "
              f"preset {args.preset}; history in {args.out}")
        if report["best_value"] is not None:
            at = ", ".join(f"{n} = {v:.6g}" for n, v in report["best_theta"].items())
            print(f"  best           {report['best_value']:.6g} {unit} at {at} "
                  f"(start {report['best_start']}, step {report['best_step']}; "
                  f"mean velocity {report['best_velocity']:.6g} m/s, "
                  f"{report['best_n_cracks']} cracks)")
        else:
            print("  best           none: no evaluation ended with status ok")
        bad = int((res.status[: res.steps_done] != 0).sum())
        print(f"  evaluations    {report['evaluations']} value-and-gradient solves "
              f"({bad} not ok), {report['wall_time_s']:.1f} s")
        if figure is not None:
            print(f"  figure         {figure}")
    return 0 if all_ok else 1


# --- reproducing the paper: fig2, animate, paper -------------------------------------------

#: Dense output points of `jaxworm fig2` and `jaxworm paper`: 50 per second of the 60-s
#: window, ~25 per gait period at ω = 4π.
FIG2_POINTS = 3000
#: Default horizon of `jaxworm animate` [s]: a few gait periods, a few seconds of GIF.
ANIMATE_T1 = 5.0


def _add_reproduction_commands(sub) -> None:
    """`jaxworm fig2`, `jaxworm animate` and `jaxworm paper`."""
    f2 = sub.add_parser(
        "fig2", help="the paper's Fig. 2 for one scene (the nominal gait unless --set)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=("Simulate one scene (Table 1: omega = 4pi, delta = pi/4) with dense "
                     "output and draw the paper's Fig. 2: crack tip, head and body nodes "
                     "with K_I against K_Ic and K_Ith (left), the forces on the head (upper "
                     "right), kinetic and stretching energy (lower right). t1 is 60 s unless "
                     "--set: the paper's Fig. 2 is the run marked in its Fig. 3, whose mean "
                     "velocity is taken over 60 s."),
        epilog=("exit codes: 0 status ok, 1 another status (the figure is written all the "
                "same), 2 usage error."))
    _add_scene_options(f2)
    o = f2.add_argument_group("output")
    o.add_argument("--out", type=Path, help="figure file (default: fig2.png, or fig2.pdf "
                                            "with --format pdf)")
    o.add_argument("--format", choices=("png", "pdf"),
                   help="figure format (default: the suffix of --out, else png)")
    o.add_argument("--points", type=_positive_int("points"), default=FIG2_POINTS,
                   help=f"dense output times (default: {FIG2_POINTS})")

    an = sub.add_parser(
        "animate", help="a GIF (MP4 with ffmpeg) of the worm in its crack",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=("Simulate one scene and animate it: segments at their eq.-6 widths "
                     "(orange where wider than the crack, which they open), the crack of "
                     "width w_c and its tip. t1 is "
                     f"{ANIMATE_T1:g} s unless --set."),
        epilog="exit codes: 0 status ok, 1 another status (written all the same), 2 usage error.")
    _add_scene_options(an)
    o = an.add_argument_group("output")
    o.add_argument("--out", type=Path, default=Path("worm.gif"),
                   help="animation file: .gif (Pillow) or .mp4 (needs ffmpeg) "
                        "(default: worm.gif)")
    o.add_argument("--frames", type=_positive_int("frames"), default=100,
                   help="frames, evenly spaced over [0, t1] (default: 100)")
    o.add_argument("--fps", type=_positive_int("fps"), default=20,
                   help="frames per second of the animation (default: 20)")

    pa = sub.add_parser(
        "paper", help="the paper's Fig. 2 and a reduced Fig. 3, with its numbers beside ours",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=("Run the nominal scene (Table 1, t1 = 60 s unless --set) to OUT/fig2, "
                     "then a reduced Fig. 3 grid (SIZE x SIZE over omega in [3pi, 5pi] x "
                     "delta in [pi/6, pi/3], same t1, options and preset) saved to "
                     "OUT/fig3_SIZExSIZE.npz (a rerun resumes it) and drawn to OUT/fig3; "
                     "prints the nominal mean velocity and crack count and the paper's "
                     "numbers beside ours."),
        epilog="exit codes: 0 every scene ok, 1 some scene not ok, 2 usage error.")
    _add_scene_options(pa)
    o = pa.add_argument_group("output")
    o.add_argument("--out", type=Path, default=Path("out"),
                   help="folder for the figures and the sweep file (default: out)")
    o.add_argument("--size", type=_positive_int("size"), default=7,
                   help="grid points per axis of the reduced Fig. 3 (default: 7; paper: 21)")
    o.add_argument("--format", choices=("png", "pdf"), default="png",
                   help="figure format (default: png)")
    o.add_argument("--quiet", action="store_true", help="no progress line")
    pa.add_argument("--mirror", action="store_true",
                    help="the mirrored reading: the wave run from head to tail, delta -> "
                         "-delta for the nominal scene and the grid (files *_mirrored.*)")


def _figure_path(out: Path | None, fmt: str | None, stem: str) -> Path:
    """The figure file from --out and --format; `_UsageError` when they disagree."""
    if out is None:
        return Path(f"{stem}.{fmt or 'png'}")
    suffix = out.suffix.lower().lstrip(".")
    if not suffix:
        return out.with_suffix(f".{fmt or 'png'}")
    if suffix not in ("png", "pdf"):
        raise _UsageError(f"--out {out}: the figure suffix must be .png or .pdf")
    if fmt is not None and suffix != fmt:
        raise _UsageError(f"--out {out} does not match --format {fmt}")
    return out


def _dense_run(params, t1, numerics, points: int):
    """One solve with dense output at `points` times over [0, t1]; (result, wall time [s])."""
    import jax
    import jax.numpy as jnp

    import jaxworm as jw

    start = time.perf_counter()
    result = jw.simulate(params, t1, numerics, ts=jnp.linspace(0.0, t1, points))
    jax.block_until_ready(result)
    return result, time.perf_counter() - start


def _one_line(result, t1, wall) -> str:
    s = result.summary()
    return (f"mean velocity {s['mean_velocity']:.6g} m/s, {s['n_cracks']} cracks, status "
            f"{s['status']}, t1 = {float(t1):g} s, solve {wall:.1f} s (compile included)")


def _fig2(args) -> int:
    from ._plot import plot_fig2

    params, t1, numerics = _scene(args)
    path = _figure_path(args.out, args.format, "fig2")
    _configure_cache()
    result, wall = _dense_run(params, t1, numerics, args.points)
    path.parent.mkdir(parents=True, exist_ok=True)
    plot_fig2(result, params, path)
    print(f"jaxworm fig2: {path}\n  {_one_line(result, t1, wall)}")
    return 0 if str(result.status_name) == "ok" else 1


def _animate(args) -> int:
    from ._animate import animate, ffmpeg_available

    params, t1, numerics = _scene(args, default_t1=ANIMATE_T1)
    suffix = args.out.suffix.lower()
    if suffix not in (".gif", ".mp4"):
        raise _UsageError(f"--out {args.out}: the animation suffix must be .gif or .mp4")
    if suffix == ".mp4" and not ffmpeg_available():
        raise _UsageError(f"--out {args.out}: MP4 needs ffmpeg on the PATH; write a .gif")
    _configure_cache()
    result, wall = _dense_run(params, t1, numerics, args.frames)
    animate(result, params, args.out, fps=args.fps, max_frames=args.frames)
    print(f"jaxworm animate: {args.out} ({args.frames} frames at {args.fps} fps)\n"
          f"  {_one_line(result, t1, wall)}")
    return 0 if str(result.status_name) == "ok" else 1


def _paper(args) -> int:
    import jaxworm as jw

    from ._plot import plot_fig2, plot_fig3
    from ._reproduction import compare_with_paper, format_comparison, mirror_sweep, paper_grid

    if args.size < 2:
        raise _UsageError(f"--size {args.size} is out of range: need >= 2")
    params, t1, numerics = _scene(args)
    tag = "_mirrored" if args.mirror else ""
    if args.mirror:
        params = params.replace(delta=-params.gait.delta)
    _configure_cache()
    args.out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    result, wall = _dense_run(params, t1, numerics, FIG2_POINTS)
    fig2 = plot_fig2(result, params, args.out / f"fig2{tag}.{args.format}")
    print(f"jaxworm paper: nominal scene{' (mirrored)' if args.mirror else ''} -> {fig2}\n"
          f"  {_one_line(result, t1, wall)}", flush=True)
    grid = paper_grid(args.size, delta_sign=-1 if args.mirror else 1)
    data = args.out / f"fig3_{args.size}x{args.size}{tag}.npz"
    try:
        s = jw.sweep(grid, params, t1, numerics, path=data,
                     progress=not args.quiet)
    except ValueError as e:
        raise _UsageError(str(e).splitlines()[0]) from None
    mark = {"omega": float(params.gait.omega), "delta": float(params.gait.delta)}
    fig3 = plot_fig3(s, args.out / f"fig3{tag}.{args.format}", mark=mark)
    ok = s["status"] == 0
    summary = result.summary()
    rows = compare_with_paper(mirror_sweep(s) if args.mirror else s,
                              summary["mean_velocity"], summary["n_cracks"])
    note = "  mirrored: jaxworm's delta is minus the paper's, compared at |delta|\n"
    print(f"jaxworm paper: reduced Fig. 3 ({args.size} x {args.size}, t1 = {t1:g} s, "
          f"{int(ok.sum())} of {ok.size} ok) -> {fig3}, data {data}\n"
          f"{format_comparison(rows)}\n{note if args.mirror else ''}"
          f"  total {time.perf_counter() - start:.1f} s; docs/reproduction.md explains "
          "the differences")
    return 0 if (ok.all() and summary["status"] == "ok") else 1


_REPRODUCTION_COMMANDS = {"fig2": _fig2, "animate": _animate, "paper": _paper}


def _use_all_cores() -> None:
    """One JAX CPU device per core, so that sweeps run a chunk on each (`jw.sweep`).
    Only before JAX's backend starts, and never over a user's own device count."""
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_force_host_platform_device_count" not in flags:
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
        os.environ["XLA_FLAGS"] = f"{flags} --xla_force_host_platform_device_count={cores or 1}".strip()


def main(argv: list[str] | None = None) -> int:
    """Entry point of the `jaxworm` console script; returns (and exits with) the exit code."""
    _use_all_cores()
    try:
        args = _build_parser().parse_args(argv)
        if args.command == "simulate":
            code = _simulate(args)
        elif args.command == "sweep":
            code = _sweep(args)
        elif args.command == "fig3":
            code = _fig3(args)
        elif args.command == "optimise":
            code = _optimise(args)
        elif args.command in _REPRODUCTION_COMMANDS:
            code = _REPRODUCTION_COMMANDS[args.command](args)
        else:  # pragma: no cover - argparse rejects unknown commands
            raise _UsageError(f"unknown command {args.command!r}")
    except _UsageError as e:
        print(f"jaxworm: error: {' '.join(str(e).split())}", file=sys.stderr)
        code = 2
    except OSError as e:
        print(f"jaxworm: error: {e}", file=sys.stderr)
        code = 2
    if argv is None:
        sys.exit(code)
    return code


if __name__ == "__main__":  # pragma: no cover
    main()

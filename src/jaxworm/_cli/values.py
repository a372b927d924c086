"""Values on the command line: numbers and expressions in pi (`parse_value`), and the
NAME=VALUE forms of --set, --grid and --bound; `UsageError` for anything malformed."""

from __future__ import annotations

import argparse
import ast
import math
import operator
import os
from pathlib import Path

import numpy as np

from .._params import PARAMETER_INFO
from .._reproduction import paper_grid

#: Horizon [s] of a run whose t1 is not set.
DEFAULT_T1 = 60.0
#: Most values on one --grid axis.
MAX_AXIS = 10_000


class UsageError(Exception):
    """A user error: reported as one line on stderr, exit code 2."""


def _parameters() -> dict[str, tuple[str, str, str]]:
    table = {}
    for name, info in PARAMETER_INFO.items():
        table[name] = (info.unit, info.default, info.doc)
        if name == "delta":  # the horizon is listed after the gait
            table["t1"] = ("s", f"{DEFAULT_T1:g}", "simulated horizon (not a model parameter)")
    return table


#: The names --set takes, with (unit, default as shown, description): the model's
#: parameters (`PARAMETER_INFO`) and the horizon t1.
PARAMETERS: dict[str, tuple[str, str, str]] = _parameters()

_BINARY = {
    ast.Add: operator.add,
    ast.Sub: operator.sub,
    ast.Mult: operator.mul,
    ast.Div: operator.truediv,
    ast.Pow: operator.pow,
}
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
        if (
            isinstance(node, ast.Constant)
            and isinstance(node.value, (int, float))
            and not isinstance(node.value, bool)  # True parses as a Constant too
        ):
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


def parse_assignments(items: list[str]) -> dict[str, float | int]:
    """`["NAME=VALUE", ...]` (--set) to `{name: value}`; the last of repeated names wins."""
    values: dict[str, float | int] = {}
    for item in items:
        name, sep, text = item.partition("=")
        name = name.strip()
        if not sep or not name:
            raise UsageError(f"--set {item!r} is malformed: need NAME=VALUE, e.g. omega=3*pi")
        if name not in PARAMETERS:
            raise UsageError(
                f"unknown parameter {name!r} in --set {item}; known: {', '.join(PARAMETERS)}"
            )
        try:
            value = parse_value(text)
        except ValueError as e:
            raise UsageError(f"--set {name}={text}: bad value {text!r}: {e}") from None
        if name == "N":
            if value != int(value):
                raise UsageError(f"parameter N = {text} is not an integer: need an integer N >= 2")
            value = int(value)
        values[name] = value
    return values


def parse_grid(items: list[str]) -> dict[str, list[float]]:
    """`["NAME=START:STOP:NUM" | "NAME=V1,V2,...", ...]` (--grid) to `{name: values}`;
    the paper's Fig. 3 grid when empty; `UsageError` for a name given twice."""
    if not items:
        return {name: values.tolist() for name, values in paper_grid(21).items()}
    grid: dict[str, list[float]] = {}
    for item in items:
        name, sep, spec = item.partition("=")
        name = name.strip()
        if not sep or not name or not spec:
            raise UsageError(
                f"--grid {item!r} is malformed: need NAME=START:STOP:NUM or NAME=V1,V2,..."
            )
        if name in grid:
            raise UsageError(
                f"--grid {item}: parameter {name} is given twice; give each "
                "axis once (NAME=V1,V2,... lists several values)"
            )
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
                    raise ValueError(
                        "a degenerate range: START = STOP needs NUM = 1, and NUM = "
                        "1 needs START = STOP (or give the value alone)"
                    )
                # np.linspace's values: the Python API's grids, so a sweep file of
                # either is resumed by the other.
                values = np.linspace(start, stop, num).tolist()
            else:
                texts = spec.split(",")
                if len(texts) > MAX_AXIS:
                    raise ValueError(
                        f"{len(texts)} values are too many: need at most {MAX_AXIS} per axis"
                    )
                values = [parse_value(v) for v in texts]
        except ValueError as e:
            raise UsageError(f"--grid {item}: {e}") from None
        grid[name] = values
    return grid


def parse_bounds(items: list[str]) -> dict[str, tuple[float, float]] | None:
    """`["NAME=LO:HI", ...]` (--bound) to `{name: (lo, hi)}`; `None` (the defaults) when
    empty; `UsageError` for a name given twice."""
    if not items:
        return None
    bounds: dict[str, tuple[float, float]] = {}
    for item in items:
        name, sep, spec = item.partition("=")
        name = name.strip()
        parts = spec.split(":")
        if not sep or not name or len(parts) != 2:
            raise UsageError(
                f"--bound {item!r} is malformed: need NAME=LO:HI, e.g. delta=-pi/3:-pi/6"
            )
        if name in bounds:
            raise UsageError(
                f"--bound {item}: parameter {name} is given twice; give each "
                "parameter's bounds once"
            )
        try:
            lo, hi = parse_value(parts[0]), parse_value(parts[1])
        except ValueError as e:
            raise UsageError(f"--bound {item}: {e}") from None
        bounds[name] = (lo, hi)
    return bounds


# --- argparse types: an option's value, checked as it is parsed ----------------------------


def positive_float(name: str, allow_zero: bool = False):
    """A number or expression > 0 (>= 0 with `allow_zero`) for option --`name`."""

    def convert(text):
        try:
            value = parse_value(text)
        except ValueError as e:
            raise argparse.ArgumentTypeError(f"--{name} {text}: {e}") from None
        if not (value >= 0 if allow_zero else value > 0):
            raise argparse.ArgumentTypeError(
                f"--{name} {text} is out of range: need {name} {'>=' if allow_zero else '>'} 0"
            )
        return value

    return convert


def fraction(name: str):
    """A number in [0, 1) (a momentum, a relative tolerance) for option --`name`."""

    def convert(text):
        try:
            value = parse_value(text)
        except ValueError as e:
            raise argparse.ArgumentTypeError(f"--{name} {text}: {e}") from None
        if not 0 <= value < 1:
            raise argparse.ArgumentTypeError(
                f"--{name} {text} is out of range: need 0 <= {name} < 1"
            )
        return value

    return convert


def positive_int(name: str, low: int = 1, high: int | None = None):
    """An integer >= `low` (1 unless given) and, with `high`, <= `high` for option
    --`name`."""

    def convert(text):
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"--{name} {text!r} is not an integer") from None
        if value < low or (high is not None and value > high):
            need = f">= {low}" if high is None else f"{low} <= {name} <= {high}"
            raise argparse.ArgumentTypeError(f"--{name} {text} is out of range: need {need}")
        return value

    return convert


def file_path(name: str):
    """The path of an output file for option --`name`: refused when it ends with a path
    separator (a folder's name; `Path` would drop the separator and write a file of
    that name)."""

    def convert(text):
        if text.endswith(("/", os.sep)):
            raise argparse.ArgumentTypeError(
                f"--{name} {text!r} ends with {text[-1]!r}, so it names a folder: give a file path"
            )
        return Path(text)

    return convert


def host_port(name: str):
    """An address HOST:PORT (a host name or IP address, a port in 1..65535) for option
    --`name`."""

    def convert(text):
        host, sep, port = text.strip().rpartition(":")
        if not sep or not host or not port.isdigit() or not 1 <= int(port) <= 65535:
            raise argparse.ArgumentTypeError(
                f"--{name} {text!r} is not HOST:PORT: need a host name or IP address and "
                "a port in 1..65535, e.g. 10.0.0.1:1234 or localhost:12345"
            )
        return f"{host}:{int(port)}"

    return convert

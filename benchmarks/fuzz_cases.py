"""Hostile inputs for the API and the command line (issue 15), shared by
`tests/test_fuzz.py` (a small sample in CI, importing it as `benchmarks.fuzz_cases`) and
`benchmarks/fuzz.py` (≥ 1,000 cases).

Every case must end in one of two ways: refused (API: `TypeError`/`ValueError` naming
the parameter; CLI: exit 2 and one line naming it and what is allowed), or run to a named
status. Never a traceback, never `ok` with a non-finite value or a mean velocity above
`jaxworm.speed_bound`. `check_*` return the outcome's label and raise `AssertionError`
on a violation.
"""

from __future__ import annotations

import contextlib
import io
import json
import math

import numpy as np
from hypothesis import strategies as st

import jaxworm as jw
from jaxworm.cli import main as cli_main

FLOAT_NAMES = tuple(n for n in jw.FLAT_NAMES if n != "N")
NUMERIC_FLOATS = (
    "rtol",
    "atol",
    "dt",
    "dt_max",
    "newton_rtol",
    "newton_atol",
    "pcoeff",
    "icoeff",
    "event_rtol",
    "event_atol",
    "energy_tol",
    "sensitivity_tol",
)
NUMERIC_INTS = ("max_steps", "max_cracks", "newton_max_steps")
NUMERIC_CHOICES = (
    "solver",
    "norm",
    "newton",
    "linear_solve",
    "adjoint",
    "crack_sensitivity",
    "sensitivity_frame",
)

HOSTILE_FLOATS = [
    math.nan,
    math.inf,
    -math.inf,
    0.0,
    -0.0,
    -1.0,
    1e300,
    -1e300,
    1e-300,
    5e-324,
    1.0,
    0.5,
    2.0,
    1e6,
    -1e-12,
]
#: Values of other types, each refused: strings, None, bools, lists, complex numbers.
WRONG_TYPES = [
    "abc",
    "1e5",
    "",
    None,
    True,
    False,
    [1.0, 2.0],
    (0.1,),
    {},
    1 + 2j,
    np.array([1.0, 2.0]),
    np.array("x"),
    object(),
]


def hostile_float(default: float):
    """A float near the default, or a hostile one (NaN, ±inf, 0, negative, huge, tiny)."""
    near = st.floats(0.1, 10.0).map(lambda f: default * f)
    return st.one_of(
        st.sampled_from(HOSTILE_FLOATS),
        near,
        st.just(default),
        st.floats(allow_nan=True, allow_infinity=True),
    )


def api_value(name: str):
    """Any value for parameter `name`: hostile floats, huge ints, wrong types, NumPy
    scalars of another precision."""
    default = float(jw.Params().flat().get(name) or 0.1)
    return st.one_of(
        hostile_float(default),
        st.sampled_from(WRONG_TYPES),
        st.sampled_from([10**300, -(10**400), 7, 0, -3]),
        hostile_float(default).map(np.float32),
    )


def n_value(valid: tuple[int, ...] = (7,)):
    """N: the valid values given (each new N compiles anew), or a refused one."""
    return st.one_of(
        st.sampled_from(valid),
        st.sampled_from([1, 0, -1, 10**300, 2.5, 7.0, "7", None, True, math.nan, 1001]),
    )


def _names_parameter(exc: BaseException, name: str) -> None:
    msg = str(exc)
    assert name in msg, f"message does not name {name!r}: {msg}"
    assert "\n" not in msg.strip(), f"message is not one line: {msg!r}"


def check_outcome(result, params, t1) -> str:
    """A finished run: a named status; `ok` only when finite and within the speed bound."""
    name = str(result.status_name)
    assert name in jw.STATUS.values(), name
    if name == "ok":
        v = float(result.mean_velocity)
        assert math.isfinite(v), f"ok with v = {v}"
        leaves = [np.asarray(x) for x in (result.final.x, result.final.v, result.final.lbar)]
        assert all(np.all(np.isfinite(x)) for x in leaves), "ok with a non-finite state"
        assert v <= float(jw.speed_bound(params, t1)), f"ok at an impossible speed {v}"
    return name


def check_api(values: dict, numerics_kw: dict, t1, run: bool = True) -> str:
    """Build Params/Numerics from hostile values and simulate when they are accepted."""
    try:
        p = jw.Params().replace(**values)
    except (TypeError, ValueError) as e:
        assert any(n in str(e) for n in values), f"names none of {list(values)}: {e}"
        _names_parameter(e, next(n for n in values if n in str(e)))
        return "refused"
    try:
        num = jw.PRESETS["fast"].replace(**numerics_kw)
    except (TypeError, ValueError) as e:
        assert any(n in str(e) for n in numerics_kw), f"names none of {list(numerics_kw)}: {e}"
        _names_parameter(e, next(n for n in numerics_kw if n in str(e)))
        return "refused"
    try:
        t1 = float(t1) if isinstance(t1, float) else t1
        result = jw.simulate(p, t1, num) if run else None
    except (TypeError, ValueError) as e:
        _names_parameter(e, "t1")
        return "refused"
    if not run:
        return "accepted"
    return check_outcome(result, p, t1)


def check_traced(run_batch, rows: list[dict], t1s: list[float]) -> list[str]:
    """Traced values in one batch: each lane a named status, `ok` only when plausible;
    a lane that fails the checks takes no step."""
    r = run_batch(rows, t1s)
    names = []
    defaults = {n: float(v) for n, v in jw.Params().flat().items() if n != "N" and v is not None}
    for i, row in enumerate(rows):
        name = str(jw.status_name(r.status[i]))
        assert name in jw.STATUS.values()
        if name == "invalid_parameters":
            assert int(r.steps[i]) == 0, f"an invalid lane took {int(r.steps[i])} steps"
        if name == "ok":
            v = float(r.mean_velocity[i])
            assert math.isfinite(v)
            try:
                p = jw.Params().replace(**{**defaults, **row})
            except ValueError as e:  # pragma: no cover - a violation
                raise AssertionError(f"ok for values refused concretely: {e}") from None
            assert v <= float(jw.speed_bound(p, t1s[i])), f"ok at an impossible speed {v}"
        names.append(name)
    return names


# --- the command line ----------------------------------------------------------------

CLI_TEXTS = [
    "nan",
    "inf",
    "-inf",
    "1e300",
    "1e400",
    "10**400",
    "2**1000",
    "-1",
    "0",
    "abc",
    "",
    "(",
    "pi/0",
    "1e-320",
    "1e-300",
    "4*pi",
    "__import__('os')",
    "1" * 400,
    "0.5",
    "2",
    "1e6",
    "-0",
    "True",
    "None",
    "[1,2]",
    "1,2",
    "=1",
]


def cli_text(default: str):
    return st.one_of(
        st.sampled_from(CLI_TEXTS),
        st.just(default),
        st.floats(allow_nan=True, allow_infinity=True).map(repr),
        st.text(max_size=12),
    )


def run_cli(argv: list[str]) -> tuple[int, str, str]:
    """In-process `jaxworm` call: (exit code, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = cli_main(argv)
    return code, out.getvalue(), err.getvalue()


def check_cli(argv: list[str], named: str) -> str:
    """Exit 2 with one line naming `named` and what is allowed, or a run whose JSON
    reports a named status (ok only when finite and within the speed bound)."""
    code, out, err = run_cli(argv)
    if code == 2:
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("jaxworm: error: "), err
        assert named in lines[0], f"{named!r} not named: {lines[0]}"
        assert any(
            w in lines[0]
            for w in (
                "need",
                "allowed",
                "invalid choice",
                "expected",
                "not a number",
                "not an integer",
                "malformed",
                "cannot evaluate",
                "not a finite",
            )
        ), lines[0]
        return "refused"
    assert code in (0, 1), (code, err)
    assert "Traceback" not in err, err
    report = json.loads(out)
    status = report["status"]
    assert status in jw.STATUS.values()
    assert (code == 0) == (status == "ok")
    if status == "ok":
        v = report["mean_velocity"]
        assert v is not None and math.isfinite(v)
        values = {k: v_ for k, v_ in report["parameters"].items() if k != "t1" and v_ is not None}
        p = jw.Params().replace(**values)
        assert v <= float(jw.speed_bound(p, report["parameters"]["t1"]))
    return status

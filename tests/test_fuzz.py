"""Property-based fuzz of the API and the command line: a small, derandomised
sample in CI; `benchmarks/fuzz.py` runs ≥ 1,000 cases. See `fuzz_cases.py`.

Runs stay cheap: t1 ≤ 0.1 s, N and the numerics take only values that are refused or
that reuse one compiled program (each new N or numerics compiles anew).
"""

import math

import pytest
from conftest import FLAT_BATCH_DEFAULTS, FLAT_BATCH_SIZE
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import jaxworm as jw
from benchmarks.fuzz_cases import (
    FLOAT_NAMES,
    HOSTILE_FLOATS,
    NUMERIC_CHOICES,
    NUMERIC_FLOATS,
    NUMERIC_INTS,
    WRONG_TYPES,
    api_value,
    check_api,
    check_cli,
    check_traced,
    cli_text,
    hostile_float,
    n_value,
)

CI = settings(
    max_examples=25,
    derandomize=True,
    deadline=None,
    database=None,
    suppress_health_check=list(HealthCheck),
)
SHORT_T1 = 0.05
#: t1 values: refused ones, or short.
T1S = [math.nan, math.inf, -math.inf, 0.0, -1.0, -1e300, 5e-324, 0.02, SHORT_T1]


@pytest.fixture(autouse=True)
def _no_cli_cache(monkeypatch):
    monkeypatch.setenv("JAXWORM_CACHE_DIR", "")  # the CLI must not move JAX's cache


@CI
@given(data=st.data())
def test_api_parameters(data):
    name = data.draw(st.sampled_from(FLOAT_NAMES + ("N",)))
    value = data.draw(n_value() if name == "N" else api_value(name))
    values = {name: value}
    if data.draw(st.booleans()):
        other = data.draw(st.sampled_from(FLOAT_NAMES))
        values.setdefault(other, data.draw(api_value(other)))
    check_api(values, {}, SHORT_T1)


@CI
@given(data=st.data())
def test_api_numerics_and_t1(data):
    kind = data.draw(st.sampled_from(["float", "int", "choice", "t1"]))
    if kind == "t1":
        t1 = data.draw(st.one_of(st.sampled_from(T1S), st.sampled_from(WRONG_TYPES)))
        check_api({}, {}, t1)
        return
    if kind == "float":
        name = data.draw(st.sampled_from(NUMERIC_FLOATS))
        value = data.draw(st.one_of(st.sampled_from(HOSTILE_FLOATS), st.sampled_from(WRONG_TYPES)))
    elif kind == "int":
        name = data.draw(st.sampled_from(NUMERIC_INTS))
        value = data.draw(
            st.sampled_from([0, -1, 10**9, 2**70, 2.5, "64", None, True, math.nan, 1, 64])
        )
    else:
        name = data.draw(st.sampled_from(NUMERIC_CHOICES))
        value = data.draw(st.sampled_from(["foo", "", None, 1, "Dense", "rodas4"]))
    # construction only: each accepted numerics would compile anew (the benchmark runs them)
    check_api({}, {name: value}, SHORT_T1, run=False)


def _refused(name, value) -> bool:
    try:
        jw.Params().replace(**{name: value})
    except ValueError:
        return True
    return False


def _ci_traced_value(name):
    """A hostile value that the checks refuse, or one within 2x of the default: valid
    extremes (E_s = 1e300, ...) may take 2**20 steps, which only the benchmark affords."""
    default = FLAT_BATCH_DEFAULTS[name]
    return hostile_float(default).filter(lambda v: _refused(name, v) or 0.5 <= v / default <= 2)


@CI
@given(data=st.data())
def test_traced_values_in_a_batch(data, run_flat_batch):
    rows, t1s = [], []
    for _ in range(FLAT_BATCH_SIZE):
        names = data.draw(st.lists(st.sampled_from(tuple(FLAT_BATCH_DEFAULTS)), max_size=3))
        rows.append({n: data.draw(_ci_traced_value(n)) for n in names})
        t1s.append(data.draw(st.sampled_from([math.nan, math.inf, 0.0, -1.0, 0.02, SHORT_T1])))
    check_traced(run_flat_batch, rows, t1s)


@CI
@given(data=st.data())
def test_cli(data):
    argv = ["simulate", "--json", "--set", f"t1={SHORT_T1}"]
    kind = data.draw(st.sampled_from(["set", "t1", "option"]))
    if kind == "option":
        option = data.draw(st.sampled_from(["atol", "rtol", "dt", "max-cracks"]))
        text = data.draw(
            st.sampled_from(
                ["nan", "inf", "-1", "abc", "", "1e400", "(", "-inf", "10**9", "2.5", "0x"]
            )
        )
        argv += [f"--{option}", text]
        named = option
    else:
        name = "t1" if kind == "t1" else data.draw(st.sampled_from(tuple(jw.FLAT_NAMES)))
        default = "7" if name == "N" else "0.1"
        text = data.draw(cli_text(default))
        if name == "N":  # each valid N compiles anew
            text = data.draw(st.sampled_from(["7", "1", "0", "1e300", "2.5", "1001", "nan", "x"]))
        if name == "t1":  # only short horizons run
            text = data.draw(st.sampled_from(["0", "-1", "nan", "inf", "1e-320", "abc", "0.05"]))
        argv += ["--set", f"{name}={text}"]
        named = name
    check_cli(argv, named)

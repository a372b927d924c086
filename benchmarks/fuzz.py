"""Issue 15: the property-based fuzz at scale (≥ 1,000 cases), with counts.

    python benchmarks/fuzz.py [--examples 300]

Four families of `fuzz_cases.py`, `--examples` cases each: Params (every float
parameter and N, hostile floats, huge ints, wrong types, float32) through the API;
Numerics options (built, and run from a small menu of valid values); traced values in
batches of 4 lanes (every float parameter and t1, valid extremes included); and the
command line in-process (`--set` every parameter and t1, numerics options). A violation
(a traceback, an unnamed refusal, ok with a non-finite or impossible speed, an invalid
lane that took a step) stops the run with hypothesis' minimal example. Writes
`results/fuzz/fuzz.{md,json}` with the outcome counts.
"""

from __future__ import annotations

import argparse
import collections
import math
import os
import sys
import time

os.environ["JAXWORM_CACHE_DIR"] = ""

import _bench as B  # noqa: E402
import equinox as eqx  # noqa: E402
import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
from fuzz_cases import (
    FLOAT_NAMES,
    HOSTILE_FLOATS,
    NUMERIC_CHOICES,
    NUMERIC_FLOATS,  # noqa: E402
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
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

jw = B.jw
T1 = 0.05
#: Accepted numerics values that may run (each distinct one compiles once).
VALID_MENU = {
    "atol": [1e-8, 1e-6],
    "rtol": [0.0, 1e-3],
    "pcoeff": [0.0, 0.3],
    "icoeff": [0.4, 1.0],
    "max_cracks": [64, 2],
    "linear_solve": ["dense"],
}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--examples", type=int, default=300)
    args = ap.parse_args(argv)
    counts = {
        k: collections.Counter()
        for k in ("API parameters", "API numerics and t1", "traced batches (lanes)", "CLI")
    }
    walls = {}
    cfg = settings(
        max_examples=args.examples,
        deadline=None,
        database=None,
        suppress_health_check=list(HealthCheck),
    )

    @cfg
    @given(data=st.data())
    def api_parameters(data):
        name = data.draw(st.sampled_from(FLOAT_NAMES + ("N",)))
        value = data.draw(n_value((7, 3)) if name == "N" else api_value(name))
        values = {name: value}
        if data.draw(st.booleans()):
            other = data.draw(st.sampled_from(FLOAT_NAMES))
            values.setdefault(other, data.draw(api_value(other)))
        counts["API parameters"][check_api(values, {}, T1)] += 1

    @cfg
    @given(data=st.data())
    def api_numerics(data):
        kind = data.draw(st.sampled_from(["float", "int", "choice", "t1", "menu"]))
        if kind == "t1":
            t1 = data.draw(
                st.one_of(
                    st.sampled_from(
                        [math.nan, math.inf, -math.inf, 0.0, -1.0, -1e300, 5e-324, 0.02, T1]
                    ),
                    st.sampled_from(WRONG_TYPES),
                )
            )
            counts["API numerics and t1"][check_api({}, {}, t1)] += 1
            return
        run = kind == "menu"
        if kind == "menu":
            name = data.draw(st.sampled_from(tuple(VALID_MENU)))
            value = data.draw(st.sampled_from(VALID_MENU[name]))
        elif kind == "float":
            name = data.draw(st.sampled_from(NUMERIC_FLOATS))
            value = data.draw(
                st.one_of(
                    st.sampled_from(HOSTILE_FLOATS),
                    st.sampled_from(WRONG_TYPES),
                    st.floats(allow_nan=True, allow_infinity=True),
                )
            )
        elif kind == "int":
            name = data.draw(st.sampled_from(NUMERIC_INTS))
            value = data.draw(
                st.one_of(
                    st.integers(-(10**30), 10**30),
                    st.sampled_from([2**70, 2.5, "64", None, True, math.nan]),
                )
            )
        else:
            name = data.draw(st.sampled_from(NUMERIC_CHOICES))
            value = data.draw(st.one_of(st.text(max_size=8), st.sampled_from([None, 1])))
        label = check_api({}, {name: value}, T1, run=run)
        counts["API numerics and t1"][
            label if run or label == "refused" else "accepted (built)"
        ] += 1

    names = tuple(n for n, v in jw.Params().flat().items() if n != "N" and v is not None)
    defaults = {n: float(v) for n, v in jw.Params().flat().items() if n in names}
    numerics = jw.PRESETS["fast"].replace(max_steps=2**14)

    @eqx.filter_jit
    def batch(values, t1s):
        return jax.vmap(
            lambda v, t: jw.simulate(jw.Params().replace(**dict(zip(names, v))), t, numerics)
        )(values, t1s)

    def run_batch(rows, t1s):
        values = jnp.array([[r.get(n, defaults[n]) for n in names] for r in rows])
        return batch(values, jnp.asarray(t1s, dtype=jnp.float64))

    @cfg
    @given(data=st.data())
    def traced(data):
        rows, t1s = [], []
        for _ in range(4):
            chosen = data.draw(st.lists(st.sampled_from(names), max_size=3))
            rows.append({n: data.draw(hostile_float(defaults[n])) for n in chosen})
            t1s.append(
                data.draw(
                    st.sampled_from([math.nan, math.inf, -math.inf, 0.0, -1.0, 1e-300, 0.02, T1])
                )
            )
        for label in check_traced(run_batch, rows, t1s):
            counts["traced batches (lanes)"][label] += 1

    @cfg
    @given(data=st.data())
    def cli(data):
        argv = ["simulate", "--json", "--set", f"t1={T1}"]
        kind = data.draw(st.sampled_from(["set", "set", "t1", "option"]))
        if kind == "option":
            named = data.draw(st.sampled_from(["atol", "rtol", "dt", "max-cracks"]))
            text = data.draw(
                st.one_of(
                    st.sampled_from(
                        ["nan", "inf", "-1", "abc", "", "1e400", "(", "10**9", "2.5", "1e-8", "0"]
                    ),
                    st.text(max_size=8),
                )
            )
            argv += [f"--{named}", text]
        else:
            named = "t1" if kind == "t1" else data.draw(st.sampled_from(tuple(jw.FLAT_NAMES)))
            text = data.draw(cli_text("0.1"))
            if named == "N":
                text = data.draw(
                    st.sampled_from(["7", "3", "1", "0", "1e300", "2.5", "1001", "nan", "x"])
                )
            if named == "t1":
                text = data.draw(
                    st.one_of(
                        st.sampled_from(["0", "-1", "nan", "inf", "1e-320", "0.02"]),
                        st.text(max_size=6),
                    )
                )
            argv += ["--set", f"{named}={text}"]
        counts["CLI"][check_cli(argv, named)] += 1

    for key, fn in zip(counts, (api_parameters, api_numerics, traced, cli)):
        start = time.perf_counter()
        fn()
        walls[key] = time.perf_counter() - start
        print(key, dict(counts[key]), f"{walls[key]:.0f} s", flush=True)

    total = sum(sum(c.values()) for c in counts.values())
    m = B.machine_info()
    lines = [
        "# Fuzz of the API and the command line (issue 15)",
        "",
        f"Command: `python benchmarks/fuzz.py --examples {args.examples}` "
        f"(hypothesis, random seed; cases from `benchmarks/fuzz_cases.py`).",
        "",
        f"Machine: {m['cpu']}, {m['cpus']} CPUs, jax {m['jax']}; {m['date']}; commit "
        f"{m['git_commit']}.",
        "",
        f"{total} cases (traced batches count each of their 4 lanes), no violation: every "
        "case was refused with a message naming the parameter (API: TypeError/ValueError; "
        "CLI: exit 2 and one line) or ended in a named status; no ok with a non-finite "
        "value or above `speed_bound`; every invalid lane took 0 steps.",
        "",
        "| family | cases | outcomes | wall s |",
        "|---|---|---|---|",
    ]
    for key, c in counts.items():
        outcome = ", ".join(f"{k} {v}" for k, v in sorted(c.items(), key=lambda kv: -kv[1]))
        lines.append(f"| {key} | {sum(c.values())} | {outcome} | {walls[key]:.0f} |")
    folder = B.results_dir("fuzz")
    B.write_json(
        folder / "fuzz.json",
        {
            "machine": m,
            "examples": args.examples,
            "counts": {k: dict(c) for k, c in counts.items()},
            "wall_s": walls,
        },
    )
    (folder / "fuzz.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())

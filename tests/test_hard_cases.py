"""The hard-case suite, cheap versions (short horizons); the full version is
`benchmarks/hard_cases.py`.

Cases (`benchmarks/scenes.py`, all on the forward gait δ = −π/4): EA × 100; m × 0.01; an
amplitude at which a segment's l̄ falls to 0.2 l0; ε_v = 1e-6; ω = 20π;
K_Ith = 0.99 K_Ic; N = 50; μ_s = 0; the head 1 mm from the crack tip; eq. 7 read as a
strain (model option `normal_stress = "strain"`: normal forces 1000× larger) (the 600-s
horizon is benchmark-only).

Property checked for the `default` and `fast` presets: a run either ends `ok` with a
finite, non-runaway state whose node positions agree with a tight reference of the same
case (Tsit5, full error norm, rtol 1e-8) to `scenes.position_tolerance` (5 % of the
gait's stroke 2A/ω, at least 0.2 mm) and the same crack count, or
it ends with a named non-ok status. A NaN or a runaway (mean speed > 0.1 m/s, a node
faster than 1 m/s) reported `ok` fails. Over horizons this short the relative error of
the mean velocity is not the measure: a bounded position error of ~0.1 mm is ~1 % of
the ~8 mm the worm travels in 0.5 s (see tests/test_reference.py).

Run with `-s` to see the numbers.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

import jaxworm as jw
from benchmarks.scenes import classify, hard_cases, position_tolerance

CASES = {name: case for name, case in hard_cases().items() if case["t1_test"] is not None}
PRESETS = ("default", "fast")
TIGHT = jw.Numerics(
    solver="Tsit5", rtol=1e-8, atol=1e-11, norm="full", pcoeff=0.0, icoeff=1.0, max_steps=2**24
)


def _openblas_thread_controls():
    """(get, set) of every loaded OpenBLAS that exposes them (scipy's wheels prefix the
    names with `scipy_`); JAX's CPU LAPACK calls scipy's OpenBLAS."""
    import ctypes

    import scipy.linalg  # noqa: F401  (loads scipy's OpenBLAS, which JAX's LAPACK calls)

    paths = set()
    with open("/proc/self/maps") as maps:
        for line in maps:
            if "openblas" in line.lower() and line.rstrip().endswith(".so"):
                paths.add(line.split()[-1])
    controls = []
    for path in sorted(paths):
        lib = ctypes.CDLL(path)
        for prefix in ("scipy_openblas", "openblas"):
            get, put = f"{prefix}_get_num_threads", f"{prefix}_set_num_threads"
            if hasattr(lib, get) and hasattr(lib, put):
                controls.append((getattr(lib, get), getattr(lib, put)))
                break
    return controls


@pytest.fixture(autouse=True, scope="module")
def _single_threaded_lapack():
    """One OpenBLAS thread while this module runs, restored after.

    N = 50 makes Kvaerno's Newton matrix 152-square, where OpenBLAS's dgetrf goes
    multi-threaded; on a busy 2-core machine that took 260 ms instead of 1 ms per LU
    (the N = 50 default case: ~100 s instead of ~15 s). Best effort: where the controls
    are not found (another BLAS, another OS) nothing changes.
    """
    try:
        controls = _openblas_thread_controls()
    except OSError:
        controls = []
    before = [get() for get, _ in controls]
    for _, put in controls:
        put(1)
    yield
    for (_, put), n in zip(controls, before):
        put(n)


def _params(overrides: dict) -> jw.Params:
    over = dict(overrides)
    p = jw.Params()
    if "N" in over:
        p = p.replace(N=int(over.pop("N")))
    return p.replace(**over)


@functools.cache
def _solve(name: str, which: str) -> dict:
    case = CASES[name]
    num = TIGHT if which == "tight" else jw.PRESETS[which]
    r = jw.simulate(_params(case["params"]), case["t1_test"], num)
    x = np.asarray(r.final.x)
    v = np.asarray(r.final.v)
    return dict(
        status=str(r.status_name),
        x=x,
        mean_velocity=float(r.mean_velocity),
        n_cracks=int(r.n_cracks),
        finite=bool(np.all(np.isfinite(x)) and np.all(np.isfinite(v))),
        max_abs_v=float(np.max(np.abs(v))),
        energy=float(r.energy_residual),
        steps=int(r.steps),
    )


def test_hard_case_references_are_ok():
    """The tight solves themselves end ok, finite and slow (else the suite judges nothing)."""
    for name in CASES:
        ref = _solve(name, "tight")
        outcome = classify(
            ref["status"], ref["finite"], ref["mean_velocity"], ref["max_abs_v"], None, 0.0
        )
        print(
            f"\n{name:22s} tight: v={ref['mean_velocity']:+.6f} cracks={ref['n_cracks']} "
            f"steps={ref['steps']} energy={ref['energy']:+.1e} {ref['status']}"
        )
        assert outcome == "ok (no reference)", (name, outcome)


@pytest.mark.parametrize("preset", PRESETS)
@pytest.mark.parametrize("name", list(CASES))
def test_hard_case_is_accurate_or_names_its_status(name, preset):
    run, ref = _solve(name, preset), _solve(name, "tight")
    dx = float(np.max(np.abs(run["x"] - ref["x"]))) if run["finite"] else float("inf")
    tol = position_tolerance(CASES[name]["params"])
    error = dx if run["n_cracks"] == ref["n_cracks"] else float("inf")
    outcome = classify(
        run["status"], run["finite"], run["mean_velocity"], run["max_abs_v"], error, tol
    )
    print(
        f"\n{name:22s} {preset:8s} v={run['mean_velocity']:+.6f} (tight "
        f"{ref['mean_velocity']:+.6f}) max|dx|={dx:.1e} m (tol {tol:.1e}) cracks={run['n_cracks']}/"
        f"{ref['n_cracks']} energy={run['energy']:+.1e} {run['status']}: {outcome}"
    )
    assert not outcome.startswith("BUG"), (name, preset, outcome)
    assert outcome != "ok but error above tolerance", (name, preset, dx, run["n_cracks"])

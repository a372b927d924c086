"""Scenes of the work-precision study and the hard-case suite (issue 3).

A scene is a name, a dict of flat parameter overrides (`jaxworm.FLAT_NAMES`, the same
names `tests/reference_model.py` takes) and a horizon. Only plain Python here, so the
tests and the benchmarks share the definitions without importing each other.
"""

from __future__ import annotations

import math

import numpy as np

PI = math.pi

#: The paper's nominal gait (Table 1: ω = 4π, δ = π/4). In this model it retreats.
NOMINAL = {}
#: δ = −π/4: burrows forward and cracks (27 cracks in 60 s).
FORWARD = {"delta": -PI / 4}


def fig3_corners() -> dict[str, dict]:
    """The corners of Fig. 3, ω ∈ {3π, 5π} × δ ∈ {π/6, π/3}, with both signs of δ."""
    out = {}
    for w_name, w in (("3pi", 3 * PI), ("5pi", 5 * PI)):
        for d_name, d in (("pi/6", PI / 6), ("pi/3", PI / 3)):
            for sign, s_name in ((1.0, "+"), (-1.0, "-")):
                out[f"corner w={w_name} d={s_name}{d_name}"] = {"omega": w, "delta": sign * d}
    return out


def random_gaits(n: int = 12, seed: int = 3) -> dict[str, dict]:
    """`n` gaits drawn uniformly: ω ∈ [3π, 5π], |δ| ∈ [π/6, π/3], sign of δ ±1 at random."""
    rng = np.random.default_rng(seed)
    omega = rng.uniform(3 * PI, 5 * PI, n)
    delta = rng.uniform(PI / 6, PI / 3, n) * rng.choice([-1.0, 1.0], n)
    return {
        f"random {i:02d}": {"omega": float(w), "delta": float(d)}
        for i, (w, d) in enumerate(zip(omega, delta))
    }


def gait_scenes(n_random: int = 12) -> dict[str, dict]:
    """Nominal, the eight Fig.-3 corners and `n_random` random gaits, in that order."""
    return {"nominal": dict(NOMINAL), **fig3_corners(), **random_gaits(n_random)}


def amplitude_for_min_lbar(
    fraction: float, omega: float, delta: float, n_nodes: int = 7, l0: float = 1e-2
) -> float:
    """Gait amplitude A [m/s] at which the shortest l̄ reaches `fraction`·l0.

    With l̄^k(t) = l0 + (A/ω)(cos δk − cos(ωt + δk)) (MODEL.md), the minimum over t of
    segment k is l0 − (A/ω)(1 − cos δk); the first segment to reach `fraction`·l0 is the
    one with the largest 1 − cos δk, k = 1..N−1.
    """
    depth = max(1.0 - math.cos(delta * k) for k in range(1, n_nodes))
    return (1.0 - fraction) * l0 * omega / depth


def hard_cases() -> dict[str, dict]:
    """The hard-case suite of issue 3 on the forward gait (δ = −π/4, which cracks).

    Each entry: `params` (flat overrides and model options, as `jaxworm.Params.replace`
    takes them), `t1` [s] of the full benchmark version,
    `t1_test` of the cheap CI version (`tests/test_hard_cases.py`), and `what`.
    """
    fwd = dict(FORWARD)
    big_a = amplitude_for_min_lbar(0.2, 4 * PI, fwd["delta"])
    return {
        "EA x100": dict(
            params={**fwd, "EA": 1300.0},
            t1=10.0,
            t1_test=0.25,
            what="elastic mode 10x faster (~1e5 rad/s)",
        ),
        "m x0.01": dict(
            params={**fwd, "m": 1e-7},
            t1=10.0,
            t1_test=0.25,
            what="elastic mode 10x faster through the mass",
        ),
        "A: lbar_min = 0.2 l0": dict(
            params={**fwd, "A": big_a},
            t1=10.0,
            t1_test=0.5,
            what=f"A = {big_a:.4g} m/s: a segment shrinks to 0.2 l0",
        ),
        "eps_v = 1e-6": dict(
            params={**fwd, "eps_v": 1e-6}, t1=10.0, t1_test=0.25, what="friction 100x sharper"
        ),
        "omega = 20pi": dict(
            params={**fwd, "omega": 20 * PI}, t1=10.0, t1_test=0.5, what="gait 5x faster"
        ),
        "K_Ith = 0.99 K_Ic": dict(
            params={**fwd, "K_Ith": 0.99 * 250.0},
            t1=10.0,
            t1_test=0.5,
            what="tiny crack jumps, many cracks",
        ),
        "N = 50": dict(
            params={**fwd, "N": 50},
            t1=2.0,
            t1_test=0.1,
            what="50 nodes (49 segments); t1 = 2 s: Kvaerno's dense 152-square "
            "Newton matrix costs ~1.5 ms a step",
        ),
        "mu_s = 0": dict(
            params={**fwd, "mu_s": 0.0},
            t1=10.0,
            t1_test=0.5,
            what="no friction: nothing dissipates the elastic ringing",
        ),
        "near tip (1 mm)": dict(
            params={**fwd, "crack_gap0": 1e-3},
            t1=10.0,
            t1_test=0.5,
            what="head 1 mm from the tip: K_I(0) ~ 8 K_Ic > K_Ic with no upward "
            "crossing to detect: the crack jumps at t = 0 (eq. 13)",
        ),
        "eq. 7 as a strain": dict(
            params={**fwd, "normal_stress": "strain"},
            t1=10.0,
            t1_test=0.1,
            what="normal force 1/w_c = 1000x larger (model option normal_stress = "
            "'strain'): friction ~0.1 N competes with the springs, stiff stick-slip",
        ),
        "t1 = 600 s": dict(
            params=dict(fwd), t1=600.0, t1_test=None, what="long horizon (benchmark only)"
        ),
    }


# --- judging a hard case --------------------------------------------------------------


def position_tolerance(overrides: dict) -> float:
    """Final-position tolerance [m] of a short (CI-horizon) hard case.

    The cheap presets' error is a bounded position error that scales with the motion:
    5 % of the gait's stroke 2A/ω (the peak-to-peak of l̄), at least 0.2 mm (2 % of l0).
    """
    a = overrides.get("A", 0.02)
    omega = overrides.get("omega", 4 * PI)
    return max(2e-4, 0.05 * 2 * a / omega)


#: A mean speed [m/s] no gait of the suite comes near (they move ~1e-2 m/s): above it an
#: "ok" run is a runaway, a false solution.
RUNAWAY_MEAN_SPEED = 0.1
#: A final node speed [m/s] above which an "ok" run is a runaway.
RUNAWAY_NODE_SPEED = 1.0


def classify(
    status: str,
    finite: bool,
    mean_velocity: float,
    max_abs_v: float,
    error: float | None,
    tolerance: float,
) -> str:
    """Outcome of one hard-case run.

    - `"BUG: nonfinite reported ok"`, `"BUG: runaway reported ok"`: the failures the
      suite exists to catch (a status must name them).
    - `"ok within tolerance"`, `"ok but error above tolerance"` (a silent inaccuracy).
    - `"named status: <name>"`: the run ended with a non-ok status, which is allowed.
    """
    if status != "ok":
        return f"named status: {status}"
    if not finite or not math.isfinite(mean_velocity):
        return "BUG: nonfinite reported ok"
    if abs(mean_velocity) > RUNAWAY_MEAN_SPEED or max_abs_v > RUNAWAY_NODE_SPEED:
        return "BUG: runaway reported ok"
    if error is None:
        return "ok (no reference)"
    return "ok within tolerance" if error <= tolerance else "ok but error above tolerance"

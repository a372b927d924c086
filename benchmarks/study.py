"""The work-precision study's numerics and plans, shared by its parts
(`work_precision.py`, `smoothing.py`, `hard_cases.py`), and the command line of a part
run alone (`run_part`).

`FULL` is the study; `QUICK` a tiny ladder on short horizons, whose files get `_quick`.
"""

from __future__ import annotations

import argparse
import dataclasses

import _bench as B

jw = B.jw

# --- numerics of the study ------------------------------------------------------------

#: The study's reference: an explicit Runge-Kutta method on the full norm resolves the
#: elastic ringing (~1e4 rad/s) at ~5e4-1.5e5 steps per simulated second and a few µs a
#: step; on Table 1's scenes friction (ε_v = 1e-4 m/s) is not stiff enough to hurt it.
#: (The `reference` preset, Kvaerno5 at the same tolerances, agrees to ~5e-8 but took
#: ~9× the steps at ~30× the cost per step.)
REFERENCE = jw.PRESETS["reference"].replace(solver="Tsit5", max_cracks=256)
#: Its convergence check: ten times tighter.
REFERENCE_TIGHT = REFERENCE.replace(rtol=1e-10, atol=1e-13)
#: Reference of the preset check on every scene (60-s horizons) and of the hard cases:
#: 100 times looser than REFERENCE (~2.5× cheaper); its agreement with REFERENCE on the
#: diagram's scene is in the convergence table (it must stay ≪ 1e-3, the finest target).
SCENE_REFERENCE = REFERENCE.replace(rtol=1e-7, atol=1e-10)


@dataclasses.dataclass(frozen=True)
class Plan:
    """What one invocation runs; `FULL` and `QUICK` below."""

    name: str
    wp_scene: str  # scene of the work-precision diagram (scenes.py)
    t_short: float  # horizon shared with the SciPy anchors [s]
    t_long: float  # horizon of the second diagram [s]
    t_refcheck: float  # horizon of `reference` preset vs REFERENCE [s]
    positions_solvers: tuple
    positions_atols: tuple  # rtol = 0 on the positions norm
    full_solvers: tuple
    full_rtols: tuple  # atol = 1e-3·rtol on the full norm (Tsit5)
    full_rtols_implicit: tuple  # the same for the implicit solvers
    ie_dts: tuple  # the paper's fixed-step implicit Euler
    scipy_methods: tuple
    scipy_rtols: tuple
    n_random: int  # random gaits of the preset check
    scene_t1s: tuple  # horizons of the preset check [s]
    scene_names: tuple | None  # None: nominal + corners + random gaits
    eps_vs: tuple
    eps_Ns: tuple
    smoothing_t1: float
    hard_full: bool  # full hard cases (t1 of scenes.py) or CI versions
    repeats: int = 3
    max_run_s: float = 30.0  # skip tighter rungs / the long horizon beyond this
    max_scipy_s: float = 60.0


#: Assumed growth of a run's cost from one rung of a ladder to the next, tighter one: a
#: line stops when its last run took more than max_run_s / GROWTH.
GROWTH = 3.0

SOLVERS_IMPLICIT = (
    "Kvaerno3",
    "Kvaerno4",
    "Kvaerno5",
    "KenCarp3",
    "KenCarp4",
    "KenCarp5",
    "Rodas4",
    "ImplicitEuler",
)

FULL = Plan(
    name="full",
    wp_scene="forward",
    t_short=2.5,
    t_long=10.0,
    t_refcheck=0.1,
    positions_solvers=SOLVERS_IMPLICIT,
    positions_atols=(1e-6, 1e-7, 1e-8, 1e-9, 1e-10),
    # Implicit solvers on the full norm resolve the ringing with expensive steps: the
    # GROWTH rule cuts their lines early; Tsit5's goes further.
    full_solvers=("Tsit5",) + SOLVERS_IMPLICIT,
    full_rtols=(1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8),
    full_rtols_implicit=(1e-3, 1e-4, 1e-5),
    ie_dts=(2e-4, 1e-4, 5e-5, 2e-5, 1e-5, 5e-6),
    scipy_methods=("LSODA", "BDF", "Radau"),
    scipy_rtols=(1e-3, 1e-4, 1e-5, 1e-6),
    n_random=12,
    scene_t1s=(10.0, 60.0),
    scene_names=None,
    eps_vs=(1e-3, 3e-4, 1e-4, 3e-5, 1e-5, 3e-6, 1e-6),
    eps_Ns=(1e-6, 1e-7, 1e-8, 1e-9, 1e-10),
    smoothing_t1=10.0,
    hard_full=True,
    max_run_s=60.0,
    max_scipy_s=60.0,
)

QUICK = Plan(
    name="quick",
    wp_scene="forward",
    t_short=0.5,
    t_long=2.0,
    t_refcheck=0.05,
    positions_solvers=("Kvaerno3", "Kvaerno5", "KenCarp4", "Rodas4"),
    positions_atols=(1e-7, 1e-9),
    full_solvers=("Tsit5", "Kvaerno5"),
    full_rtols=(1e-4, 1e-6),
    full_rtols_implicit=(1e-4,),
    ie_dts=(1e-4, 5e-5),
    scipy_methods=("LSODA", "BDF", "Radau"),
    scipy_rtols=(1e-4, 1e-6),
    n_random=1,
    scene_t1s=(2.0,),
    scene_names=("nominal", "corner w=3pi d=-pi/3", "corner w=5pi d=+pi/6", "random 00"),
    eps_vs=(1e-3, 1e-4, 1e-5, 1e-6),
    eps_Ns=(1e-6, 1e-8, 1e-10),
    smoothing_t1=2.0,
    hard_full=False,
    repeats=2,
    max_run_s=20.0,
    max_scipy_s=40.0,
)


def plan_of(quick: bool) -> Plan:
    """`QUICK` or `FULL`."""
    return QUICK if quick else FULL


def run_part(study, doc: str) -> None:
    """Command line of one part of the study run alone: `--quick` picks the small plan
    (files suffixed `_quick`); `study(plan, root, machine_info())` does the work and
    writes under `root/<part>/`."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="tiny plan, short horizons")
    quick = ap.parse_args().quick
    study(plan_of(quick), B.RESULTS, B.machine_info())


def output(root, benchmark: str, stem: str, plan: Plan, ext: str):
    """`root/<benchmark>/<stem>[_quick].<ext>`, the folder created."""
    return B.results_dir(benchmark, root) / f"{stem}{B.quick_suffix(plan is QUICK)}.{ext}"

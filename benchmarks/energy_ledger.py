"""The energy ledger at δ = 0 and ±π, where the soil takes almost no energy, by solver.

    python benchmarks/energy_ledger.py [--t1 2]

At δ = 0, π and −π (and π/4 for comparison), Table 1 otherwise, each term of the
work-energy balance (`jaxworm.energy_terms`), the gross actuation work ∫|∂V/∂l̄·u| (the
residual's scale there) and the residual, with `fast`, `accurate`
and a tight full-norm solve (Tsit5, rtol 1e-7: `study.SCENE_REFERENCE`). Writes
`results/energy_ledger/energy_ledger.json`; `readings.py --readme-only` adds it to the README.
"""

from __future__ import annotations

import argparse
import math
import time

import _bench as B  # (first: sets the BLAS threads before numpy loads)
import study

jw = B.jw
PI = math.pi


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--t1", type=float, default=2.0)
    args = ap.parse_args()
    numerics = {
        "fast": jw.PRESETS["fast"],
        "accurate": jw.PRESETS["accurate"],
        "Tsit5 full rtol 1e-7": study.SCENE_REFERENCE,
    }
    rows = []
    for delta in (0.0, PI, -PI, PI / 4):
        p = jw.Params().replace(delta=delta)
        for label, num in numerics.items():
            B.log(f"[ledger] delta={delta / PI:g}pi {label}")
            start = time.perf_counter()
            r = jw.simulate(p, t1=args.t1, numerics=num)
            wall = time.perf_counter() - start
            terms = jw.energy_terms(jw.initial_state(p), r.final, p)
            rows.append(
                {
                    "delta": delta,
                    "numerics": label,
                    "t1": args.t1,
                    "mean_velocity": float(r.mean_velocity),
                    "status": str(r.status_name),
                    "energy_residual": float(r.energy_residual),
                    "steps": int(r.steps),
                    "n_cracks": int(r.n_cracks),
                    "wall_s_with_compile": wall,
                    "terms_J": {k: float(v) for k, v in terms.items()},
                    "actuation_gross_J": float(r.final.work[3]),
                }
            )
    B.write_json(B.results_dir("energy_ledger") / "energy_ledger.json", {"rows": rows})


if __name__ == "__main__":
    main()

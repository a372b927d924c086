"""Reading 2 (eq. 7 as a strain): convergence of the `default` preset, checked.

    python benchmarks/readings_strain_check.py

At the two ends of the ω ratio at δ = π/6 (ω = 3π and 5π): `default` at 60 s and 10 s,
`accurate` at 10 s (a tighter solve), and `fast` at 60 s (it reaches its step bound).
Writes `results/readings_strain_check/readings_strain_check.json`;
`readings.py --readme-only` shows it in `results/readings/README.md`.
"""

from __future__ import annotations

import math
import time

import _bench as B  # (first: sets the BLAS threads before numpy loads)

jw = B.jw
PI = math.pi

RUNS = [
    ("default", 60.0),
    ("accurate", 10.0),
    ("default", 10.0),
    ("fast", 60.0),
]


def main() -> None:
    rows = []
    for omega in (3 * PI, 5 * PI):
        p = jw.Params().replace(normal_stress="strain", omega=omega, delta=PI / 6)
        for preset, t1 in RUNS:
            B.log(f"[strain] omega={omega / PI:g}pi {preset} t1={t1}")
            start = time.perf_counter()
            r = jw.simulate(p, t1=t1, numerics=jw.PRESETS[preset])
            wall = time.perf_counter() - start
            rows.append(
                {
                    "omega": omega,
                    "delta": PI / 6,
                    "preset": preset,
                    "t1": t1,
                    "wall_s_with_compile": wall,
                }
                | {
                    k: v
                    for k, v in B.summary_row(r).items()
                    if k not in ("x_final", "max_abs_v_final", "finite")
                }
            )
            B.log(f"[strain]   {rows[-1]}")
    B.write_json(
        B.results_dir("readings_strain_check") / "readings_strain_check.json", {"rows": rows}
    )


if __name__ == "__main__":
    main()

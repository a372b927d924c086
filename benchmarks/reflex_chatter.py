"""A reflex that chatters: status `ok`, and no tolerance converges its mean velocity.

    python benchmarks/reflex_chatter.py

The open-loop wave ω = 25π/6 ≈ 13.09 rad/s, δ = −π/16, A = 0.03 m/s (the best wave of
an earlier run of `closed_loop.py`, on a grid) under `ReflexWave` with the gains of
`feedback_gradient.py` (g_K = 1, g_v = 0.5, g_δ = 0.3), on the Table 1 soil. Each gain
alone settles as atol shrinks. Together they chatter: the mean velocity moves by per
cents from one tolerance to the next (and with rounding-level changes of the
controller), and the steps at a tight atol are several times those of any one gain.
The table gives, for each controller, horizon and numerics, the mean velocity, its
relative difference from the tightest solve (atol 1e-11) of the same run, its cracks,
status and steps. Writes
`results/reflex_chatter/reflex_chatter.{json,md}`.
"""

from __future__ import annotations

import math
import sys
import time

import _bench as B  # (first: sets the BLAS threads before numpy loads)

jw = B.jw

GAINS = {
    "zero gains": {},
    "g_K = 1": {"gain_stress": 1.0},
    "g_v = 0.5": {"gain_speed": 0.5},
    "g_δ = 0.3": {"gain_phase": 0.3},
    "all three": {"gain_stress": 1.0, "gain_speed": 0.5, "gain_phase": 0.3},
}
TIGHTEST = "Rodas4, atol 1e-11"
NUMERICS = {
    "fast": jw.PRESETS["fast"],
    **{f"Rodas4, atol {a:g}": jw.Numerics(solver="Rodas4", atol=a) for a in (1e-9, 1e-10, 1e-11)},
}


#: The wave the chatter was found on (see the module's docstring).
WAVE = {"A": 0.03, "omega": 25 * math.pi / 6, "delta": -math.pi / 16}


def main() -> int:
    rows = []
    for label, gains in GAINS.items():
        gait = jw.ReflexWave(**WAVE, **gains)
        for t1 in (2.0, 10.0) if label == "all three" else (2.0,):
            for name, numerics in NUMERICS.items():
                start = time.perf_counter()
                r = jw.simulate(jw.Params(gait=gait), t1, numerics)
                rows.append(
                    {
                        "controller": label,
                        "t1": t1,
                        "numerics": name,
                        "mean_velocity": float(r.mean_velocity),
                        "cracks": int(r.n_cracks),
                        "status": str(r.status_name),
                        "steps": int(r.steps),
                        "wall_s": time.perf_counter() - start,
                    }
                )
                B.log(f"{label}, {t1:g} s, {name}: {rows[-1]['mean_velocity']:.6f}")
    for r in rows:
        tight = next(
            q["mean_velocity"]
            for q in rows
            if (q["controller"], q["t1"]) == (r["controller"], r["t1"])
            and q["numerics"] == TIGHTEST
        )
        r["vs_tightest"] = B.rel_error(r["mean_velocity"], tight)
    out = {"machine": B.machine_info(), "wave": WAVE, "rows": rows}
    folder = B.results_dir("reflex_chatter")
    B.write_json(folder / "reflex_chatter.json", out)
    lines = [
        "# A reflex that chatters: the mean velocity against the tolerance",
        "",
        B.machine_line(out["machine"]),
        "",
        "Command: `python benchmarks/reflex_chatter.py`. `ReflexWave` on the wave "
        f"ω = {WAVE['omega']:.4f} rad/s, δ = {WAVE['delta']:.4f} rad, A = {WAVE['A']:g} m/s, "
        "Table 1 soil. Difference: relative, from the same run at atol 1e-11.",
        "",
        *B.md_table(
            [
                "reflex gains",
                "t1 s",
                "numerics",
                "mean velocity m/s",
                "difference",
                "cracks",
                "status",
                "steps",
            ],
            [
                [
                    r["controller"],
                    f"{r['t1']:g}",
                    r["numerics"],
                    f"{r['mean_velocity']:.6f}",
                    f"{r['vs_tightest']:.1e}",
                    r["cracks"],
                    r["status"],
                    r["steps"],
                ]
                for r in rows
            ],
        ),
    ]
    (folder / "reflex_chatter.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Per-segment gaits against the best travelling wave (issue 5, beyond the paper).

    python benchmarks/segment_gait.py [--quick] [--t1 60] [--steps 30]

Starts from the best uniform travelling wave found by `optimise_vs_grid.py` (read from
its results file, else ω = 3π, δ = −0.2333π), writes it as a `SegmentWave` (A_k = A,
φ_k = δk) and optimises the 2(N − 1) amplitudes and phases (A_k ∈ [0.01, 0.03] m/s,
φ_k within ±π/4 of the wave's δk) with the common ω fixed, by `jaxworm.optimise` with
`apply=apply_segments`. Reports the gain in mean velocity over the uniform wave. Writes
benchmarks/results/segment_gait{,_quick}.{json,md} and the history `.npz`.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
from datetime import datetime, timezone
from pathlib import Path

import jax
import numpy as np

import jaxworm as jw
from jaxworm._segment_gait import SegmentWave, apply_segments

RESULTS = Path(__file__).parent / "results"


def _best_wave(tag: str) -> dict:
    path = RESULTS / f"optimise_vs_grid{tag}.json"
    if path.exists():
        g = json.loads(path.read_text())["gradient"]["best_theta"]
        return {"omega": g["omega"], "delta": g["delta"]}
    return {"omega": 3 * math.pi, "delta": -0.2333 * math.pi}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="t1 = 10 s, 10 steps")
    ap.add_argument("--t1", type=float)
    ap.add_argument("--steps", type=int)
    ap.add_argument("--lr", type=float, default=0.1)
    args = ap.parse_args(argv)
    tag = "_quick" if args.quick else ""
    t1 = args.t1 if args.t1 is not None else (10.0 if args.quick else 60.0)
    steps = args.steps if args.steps is not None else (10 if args.quick else 30)

    wave = _best_wave(tag)
    N = jw.Body().N
    seg = SegmentWave.from_wave(jw.TravellingWave(A=0.02, **wave), N)
    base = jw.Params(gait=seg)
    uniform = float(jw.simulate(jw.Params().replace(A=0.02, **wave), t1).mean_velocity)
    phases = np.asarray(seg.phase)
    bounds = {f"A_{k}": (0.01, 0.03) for k in range(1, N)}
    bounds.update({f"phase_{k}": (phases[k - 1] - math.pi / 4, phases[k - 1] + math.pi / 4)
                   for k in range(1, N)})
    start = {**{f"A_{k}": [0.02] for k in range(1, N)},
             **{f"phase_{k}": [phases[k - 1]] for k in range(1, N)}}
    import optax

    res = jw.optimise("velocity", bounds, base=base, apply=apply_segments, t1=t1,
                      starts=start, steps=steps,
                      optimiser=optax.adam(optax.cosine_decay_schedule(args.lr, steps, 0.05)),
                      path=RESULTS / f"segment_gait{tag}.npz")
    out = {
        "t1": t1, "steps": steps, "uniform_wave": {"A": 0.02, **wave, "mean_velocity": uniform},
        "per_segment_best": res.best_value, "gain": res.best_value / uniform - 1.0,
        "best_theta": res.best_theta, "evaluations": res.n_evaluations,
        "wall_s": float(res.wall_time[res.steps_done - 1]),
        "machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                    "jax": jax.__version__, "load_average_end": os.getloadavg()},
        "date": datetime.now(timezone.utc).isoformat(timespec="seconds"),
    }
    _equal_amplitude(out, N)
    _write(out, tag, N, args.quick)


def _equal_amplitude(out: dict, N: int) -> None:
    """The uniform wave at the per-segment gait's mean amplitude: the velocity rises
    with A, so this separates the gain of the phase pattern from that of amplitude."""
    w = out["uniform_wave"]
    A = float(np.mean([out["best_theta"][f"A_{k}"] for k in range(1, N)]))
    v = float(jw.simulate(jw.Params().replace(A=A, omega=w["omega"], delta=w["delta"]),
                          out["t1"]).mean_velocity)
    out["uniform_equal_amplitude"] = {"A": A, "mean_velocity": v,
                                      "gain": out["per_segment_best"] / v - 1.0}


def _write(out: dict, tag: str, N: int, quick: bool) -> None:
    t1, steps, wave, uniform = out["t1"], out["steps"], out["uniform_wave"], out["uniform_wave"]["mean_velocity"]
    eq = out["uniform_equal_amplitude"]
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / f"segment_gait{tag}.json").write_text(json.dumps(out, indent=2))
    A = [out["best_theta"][f"A_{k}"] for k in range(1, N)]
    ph = [out["best_theta"][f"phase_{k}"] / math.pi for k in range(1, N)]
    md = "\n".join([
        f"# Per-segment gait against the best travelling wave (t1 = {t1:g} s{', quick' if quick else ''})",
        "",
        f"Uniform wave A = 0.02 m/s, ω = {wave['omega'] / math.pi:.4f}π, δ = "
        f"{wave['delta'] / math.pi:.4f}π: **{uniform:.6g} m/s**. Per-segment (12 parameters, "
        f"{steps} Adam steps from the wave, {out['evaluations']} value-and-gradient solves, "
        f"{out['wall_s']:.0f} s): **{out['per_segment_best']:.6g} m/s**, gain "
        f"{100 * out['gain']:+.2f} %; against the uniform wave at the same mean amplitude "
        f"(A = {eq['A']:.5f} m/s: {eq['mean_velocity']:.6g} m/s) the gain is "
        f"**{100 * eq['gain']:+.2f} %** (the phase pattern's share).",
        "",
        "| segment | " + " | ".join(str(k) for k in range(1, N)) + " |",
        "|---|" + "---|" * (N - 1),
        "| A_k [m/s] | " + " | ".join(f"{a:.4f}" for a in A) + " |",
        "| φ_k [π] | " + " | ".join(f"{p:.3f}" for p in ph) + " |",
        "",
        f"Machine: {out['machine']['platform']}, {out['machine']['cpus']} CPUs, load average "
        f"{', '.join(f'{x:.1f}' for x in out['machine']['load_average_end'])}; {out['date']}.",
    ]) + "\n"
    (RESULTS / f"segment_gait{tag}.md").write_text(md)
    print(md)


if __name__ == "__main__":
    main()

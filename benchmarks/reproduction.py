"""The numbers of docs/reproduction.md that are not in a sweep the CLI writes directly.

- both readings' Fig. 3 grids (the paper's window, MODEL.md δ ∈ [π/6, π/3] and the
  mirrored δ ∈ [−π/3, −π/6]), 21 × 21 × 60 s, `fast` (`--size` for fewer points):
  saved as `fig3_<size>x<size>[_mirrored].npz`;
- each reading's behaviour along δ at fixed ω: where each ω row has its minimum and
  maximum, and whether it is monotone in δ (the paper: the velocity "increases with
  increasing offset δ");
- single scenes at the paper's two extreme points (3π, π/3) and (3π, π/6), both readings,
  60 s, `fast`;
- the nominal and mirrored nominal gait over 10 s with `fast` and `accurate`, the values
  `tests/test_reproduction_numbers.py` pins, and their relative difference.

Mirrored values are listed at the paper's |δ|.

    python benchmarks/reproduction.py             # 21 x 21 grids
    python benchmarks/reproduction.py --size 5    # 5 x 5 grids

Writes results/reproduction/reproduction[_size_N].{json,md} and the two grids.
"""

from __future__ import annotations

import argparse
import math
import time

import _results as R
import numpy as np

import jaxworm as jw
from jaxworm.paper import PAPER, mirror_sweep, paper_grid

PI = math.pi


def _row_shape(delta: np.ndarray, v: np.ndarray) -> dict:
    """Where one ω row of a sweep has its extremes along δ, and whether it is monotone."""
    dv = np.diff(v)
    return {
        "delta_min_pi": float(delta[np.argmin(v)] / PI),
        "v_min": float(np.min(v)),
        "delta_max_pi": float(delta[np.argmax(v)] / PI),
        "v_max": float(np.max(v)),
        "increasing": bool(np.all(dv > 0)),
        "decreasing": bool(np.all(dv < 0)),
    }


def _scene(omega: float, delta: float, t1: float, preset: str) -> dict:
    p = jw.Params().replace(omega=omega, delta=delta)
    start = time.perf_counter()
    r = jw.simulate(p, t1, jw.PRESETS[preset])
    s = r.summary()
    return {
        "omega_pi": omega / PI,
        "delta_pi": delta / PI,
        "t1": t1,
        "preset": preset,
        "mean_velocity": s["mean_velocity"],
        "n_cracks": s["n_cracks"],
        "status": s["status"],
        "wall_s": time.perf_counter() - start,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--size", type=int, default=21, help="grid points per axis (paper: 21)")
    args = ap.parse_args()
    folder = R.results_dir("reproduction")
    suffix = "" if args.size == 21 else f"_size_{args.size}"
    fast = jw.PRESETS["fast"]
    t1 = PAPER["t1"]

    readings = {}
    for name, sign, tag in (("MODEL.md", 1, ""), ("mirrored", -1, "_mirrored")):
        path = folder / f"fig3_{args.size}x{args.size}{tag}.npz"
        start = time.perf_counter()
        s = jw.sweep(paper_grid(args.size, delta_sign=sign), t1=t1, numerics=fast, path=path)
        wall = time.perf_counter() - start
        seen = mirror_sweep(s) if sign < 0 else s  # at the paper's |δ|, increasing
        d = np.asarray(seen["coords"]["delta"])
        v = np.asarray(seen["mean_velocity"])
        ok = np.asarray(seen["status"]) == 0
        rows = [
            {"omega_pi": float(w / PI), **_row_shape(d, v[i])}
            for i, w in enumerate(seen["coords"]["omega"])
        ]
        readings[name] = {
            "file": path.name,
            "ok": int(ok.sum()),
            "scenes": int(ok.size),
            "wall_s": wall,
            "v_min": float(v.min()),
            "v_max": float(v.max()),
            "rows": rows,
        }

    points = [
        _scene(3 * PI, PI / 3, t1, "fast"),
        _scene(3 * PI, PI / 6, t1, "fast"),
        _scene(3 * PI, -PI / 3, t1, "fast"),
        _scene(3 * PI, -PI / 6, t1, "fast"),
    ]
    pins = [
        _scene(4 * PI, sign * PI / 4, 10.0, preset)
        for sign in (1, -1)
        for preset in ("fast", "accurate")
    ]
    for a, b in ((pins[0], pins[1]), (pins[2], pins[3])):
        b["relative_to_fast"] = abs(b["mean_velocity"] - a["mean_velocity"]) / abs(
            b["mean_velocity"]
        )

    result = {"size": args.size, "t1": t1, "readings": readings, "points": points, "pins": pins}
    R.write_json(folder / f"reproduction{suffix}.json", result)
    run = R.run_record()
    lines = [
        "# The reproduction report's numbers",
        "",
        f"`{run['command']}` on {run['machine']} ({run['cores']} cores), {run['date']}, "
        f"load {run['load'][0]:.1f}.",
        "",
        f"## Fig. 3 grids, {args.size} x {args.size} x {t1:g} s, `fast` (mirrored at |δ|)",
        "",
    ]
    for name, r in readings.items():
        lines += [
            f"**{name}** (`{r['file']}`): {r['ok']} of {r['scenes']} ok, "
            f"{r['v_min']:+.4f} … {r['v_max']:+.4f} m/s, {r['wall_s']:.0f} s.",
            "",
            "| ω [π] | min v [m/s] at δ [π] | max v [m/s] at δ [π] | monotone in δ |",
            "|---|---|---|---|",
        ]
        for row in r["rows"]:
            mono = (
                "increasing" if row["increasing"] else "decreasing" if row["decreasing"] else "no"
            )
            lines.append(
                f"| {row['omega_pi']:.2f} | {row['v_min']:+.5f} at {row['delta_min_pi']:.3f} | "
                f"{row['v_max']:+.5f} at {row['delta_max_pi']:.3f} | {mono} |"
            )
        lines.append("")
    lines += [
        "## Scenes",
        "",
        "| ω [π] | δ [π] | t1 s | preset | mean velocity [m/s] | cracks | status | wall s |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for s in points + pins:
        lines.append(
            f"| {s['omega_pi']:.3g} | {s['delta_pi']:+.4g} | {s['t1']:g} | {s['preset']} | "
            f"{s['mean_velocity']:+.7f} | {s['n_cracks']} | {s['status']} | {s['wall_s']:.1f} |"
        )
    lines += ["", "`fast` against `accurate` at 10 s (relative):"]
    lines += [
        f"- δ = {s['delta_pi']:+.2f}π: {s['relative_to_fast']:.1e}"
        for s in pins
        if "relative_to_fast" in s
    ]
    (folder / f"reproduction{suffix}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()

"""Readings of the paper not pinned by default: each on the Fig.-3 window, beside the default.

    python benchmarks/readings.py [--readings default,mirror,...] [--line] [--size 5]
                                  [--t1 60] [--preset fast] [--max-steps N]

Each reading is a set of model options (`jaxworm.MODEL_OPTIONS`) and a direction of the
travelling wave: `+` runs the paper's ψ_k = ωt + δk with δ ∈ [π/6, π/3]; `-` the mirrored
wave, ψ_k = ωt − δk, shown at |δ| (`jaxworm.paper.mirror_sweep`). Every reading is swept
on the `--size`² window ω ∈ [3π, 5π] × δ ∈ [π/6, π/3] at `--t1` s, and with `--line`
on the δ line 0.05π, 0.10π, …, 0.5π at ω = 4π. Per point: mean velocity, status,
energy residual, cracks and steps; per reading: the ω ratio (mean |v̄| over the ok points
at 3π over that at 5π), the zero crossing of each ω row and of the line
(`jaxworm.paper.zero_crossing`). Writes `results/readings/readings_<reading>.json` (one per
reading run, with its command and machine) and rebuilds `results/readings/README.md`
from every JSON there, `notes.md` there, and the results of `readings_strain_check.py`
and `energy_ledger.py`.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import _bench as B  # (first: sets the BLAS threads before numpy loads)
import numpy as np

from jaxworm.paper import PAPER, mirror_sweep, paper_grid, zero_crossing

jw = B.jw
PI = math.pi
OUT = B.results_dir("readings")
#: The results of `readings_strain_check.py` and `energy_ledger.py`, which README.md shows.
STRAIN_CHECK = B.RESULTS / "readings_strain_check" / "readings_strain_check.json"
LEDGER = B.RESULTS / "energy_ledger" / "energy_ledger.json"

#: name: (model options, wave direction, what it reads).
READINGS: dict[str, tuple[dict, int, str]] = {
    "default": ({}, +1, "MODEL.md: the pinned reading"),
    "mirror": ({}, -1, "the wave run tail to head (δ → −δ)"),
    "tail": (
        {"friction_forward": "tail"},
        +1,
        "reading 1, anisotropy alone: eq. 10's forward points tail-ward",
    ),
    "tail+mirror": (
        {"friction_forward": "tail"},
        -1,
        "reading 1: eq. 10's forward and the wave (eq. 25) both point tail-ward",
    ),
    "tail_numbered": (
        {"numbering": "tail"},
        +1,
        "eq. 25's k counted from the tail: ψ_k = ωt + δ(N − k), the wave of the body seen "
        "from its tail",
    ),
    "tail+tail_numbered": (
        {"friction_forward": "tail", "numbering": "tail"},
        +1,
        "reading 1, exact mirror image: eq. 10's forward tail-ward and eq. 25's k counted "
        "from the tail",
    ),
    "strain": ({"normal_stress": "strain"}, +1, "reading 2: eq. 7 as a strain, E_s (w − w_c)/w_c"),
    "strain+mirror": ({"normal_stress": "strain"}, -1, "reading 2 with the mirrored wave"),
    "node_difference": (
        {"entries": "node_difference"},
        +1,
        "reading 3a: eq. 24's N node entries, u_k = a_k − a_{k+1}",
    ),
    "node_difference+mirror": (
        {"entries": "node_difference"},
        -1,
        "reading 3a with the mirrored wave",
    ),
    "node_mean": ({"entries": "node_mean"}, +1, "reading 3b: u_k = (a_k + a_{k+1})/2"),
    "node_mean+mirror": ({"entries": "node_mean"}, -1, "reading 3b with the mirrored wave"),
}

#: The δ line at ω = 4π [rad]: 0.05π … 0.5π.
LINE_DELTA = np.round(np.arange(1, 11) * 0.05, 2) * PI


def status_names(codes) -> list:
    """Status names of an array of codes, in its shape (nested lists)."""
    return np.vectorize(lambda c: jw.STATUS[int(c)], otypes=[object])(np.asarray(codes)).tolist()


def run_grid(
    grid: dict, base: jw.Params, t1: float, numerics: jw.Numerics, sign: int, chunk=None
) -> dict:
    """One sweep, seen at |δ| in increasing order when `sign` is −1."""
    start = time.perf_counter()
    s = jw.sweep(grid, base=base, t1=t1, numerics=numerics, progress=False, chunk=chunk)
    wall = time.perf_counter() - start
    s = dict(s)
    if sign < 0:
        s = mirror_sweep(s)
    return {
        "omega": np.asarray(s["coords"]["omega"]).tolist(),
        "delta": np.asarray(s["coords"]["delta"]).tolist(),
        "mean_velocity": np.asarray(s["mean_velocity"]).tolist(),
        "status": status_names(s["status"]),
        "energy_residual": np.asarray(s["energy_residual"]).tolist(),
        "n_cracks": np.asarray(s["n_cracks"]).tolist(),
        "steps": np.asarray(s["steps"]).tolist(),
        "wall_s": wall,
    }


def ok_velocity(g: dict) -> np.ndarray:
    """Mean velocities with the non-ok points NaN."""
    v = np.asarray(g["mean_velocity"], float)
    return np.where(np.asarray(g["status"]) == "ok", v, np.nan)


def sign_changes(delta, velocity) -> list[str]:
    """Every sign change of `velocity` along increasing `delta` (ok points), linearly
    interpolated: "0.39 rad (to advance)" or "… (to retreat)"."""
    d, v = np.asarray(delta, float), np.asarray(velocity, float)
    keep = np.isfinite(v)
    d, v = d[keep], v[keep]
    out = []
    for i in range(d.size - 1):
        a, b = v[i], v[i + 1]
        if (a < 0 <= b) or (a >= 0 > b):
            z = d[i] + (d[i + 1] - d[i]) * (-a) / (b - a)
            out.append(f"{z:.3f} rad ({'to advance' if b >= 0 else 'to retreat'})")
    return out


def omega_ratio(g: dict) -> float:
    """Mean |v̄| over the ok points of the lowest ω row over that of the highest."""
    v = np.abs(ok_velocity(g))
    lo, hi = np.nanmean(v[0]), np.nanmean(v[-1])
    return float(lo / hi) if np.isfinite(lo) and np.isfinite(hi) and hi > 0 else math.nan


def run_reading(name: str, args) -> dict:
    options, sign, what = READINGS[name]
    base = jw.Params().replace(**options)
    numerics = jw.PRESETS[args.preset]
    if args.max_steps:
        numerics = numerics.replace(max_steps=args.max_steps)
    B.log(f"[readings] {name}: window")
    grid = paper_grid(args.size, delta_sign=sign)
    window = run_grid(grid, base, args.t1, numerics, sign, args.chunk)
    v = ok_velocity(window)
    out = {
        "reading": name,
        "what": what,
        "options": options,
        "wave": "+delta" if sign > 0 else "-delta (shown at |delta|)",
        "t1": args.t1,
        "preset": args.preset,
        "numerics": {k: str(val) for k, val in vars(numerics).items()},
        "window": window,
        "omega_ratio": omega_ratio(window),
        "row_zero_crossings": [zero_crossing(window["delta"], row) for row in v],
    }
    if args.line:
        B.log(f"[readings] {name}: delta line")
        line_grid = {"omega": np.array([4 * PI]), "delta": sign * LINE_DELTA}
        if sign < 0:
            line_grid["delta"] = line_grid["delta"][::-1]
        line = run_grid(line_grid, base, args.t1, numerics, sign, args.chunk)
        out["line"] = line
        out["line_zero_crossing"] = zero_crossing(line["delta"], ok_velocity(line)[0])
    return out


# --- the README -------------------------------------------------------------------------


def _v(x, status) -> str:
    return f"{x:+.4f}" if status == "ok" else f"{x:+.4f} ({status})"


def _pi(x: float) -> str:
    return f"{x / PI:.3g}π"


def reading_markdown(r: dict) -> list[str]:
    w = r["window"]
    run = r["run"]
    L = [
        f"## {r['reading']}{' (' + r['tag'].lstrip('_') + ')' if r.get('tag') else ''}",
        "",
        f"{r['what']}. Options: `{json.dumps(r['options'])}`; wave {r['wave']}; "
        f"t1 = {r['t1']:g} s; preset `{r['preset']}`"
        + (
            f" (max_steps {r['numerics']['max_steps']})"
            if r["numerics"]["max_steps"] != str(jw.PRESETS[r["preset"]].max_steps)
            else ""
        )
        + ".",
        "",
        f"Command: `{run['command']}`. Machine: {run['machine']}, {run['cores']} cores, "
        f"load {', '.join(f'{x:.2f}' for x in run['load'])}; {run['date']}; "
        f"sweep wall {w['wall_s']:.0f} s.",
        "",
        "Mean velocity v̄ [m/s] (status when not ok), rows ω, columns |δ|:",
        "",
    ]
    L += B.md_table(
        ["ω \\ δ"] + [_pi(d) for d in w["delta"]],
        [
            [_pi(om)] + [_v(x, s) for x, s in zip(vrow, srow)]
            for om, vrow, srow in zip(w["omega"], w["mean_velocity"], w["status"])
        ],
    )
    L += ["", "Energy residual (cracks):", ""]
    L += B.md_table(
        ["ω \\ δ"] + [_pi(d) for d in w["delta"]],
        [
            [_pi(om)] + [f"{e:.1e} ({int(c)})" for e, c in zip(erow, crow)]
            for om, erow, crow in zip(w["omega"], w["energy_residual"], w["n_cracks"])
        ],
    )
    zc = "; ".join(
        f"{_pi(om)}: {', '.join(sign_changes(w['delta'], row)) or 'none'}"
        for om, row in zip(w["omega"], ok_velocity(w))
    )
    L += [
        "",
        f"ω ratio (mean |v̄| at 3π over 5π, ok points): {r['omega_ratio']:.3g} "
        f"(paper: ~{PAPER['slowdown_3pi_to_5pi']:g}). Sign changes with increasing δ per "
        f"ω row: {zc} (paper: retreat to advance at δ ≈ {PAPER['retreat_below_delta']} rad).",
        "",
    ]
    if "line" in r:
        ln = r["line"]
        changes = sign_changes(ln["delta"], ok_velocity(ln)[0]) or ["none"]
        L += [f"δ line at ω = 4π; sign changes with increasing δ: {', '.join(changes)}:", ""]
        L += B.md_table(
            ["δ", "v̄ m/s", "status", "energy res.", "cracks"],
            [
                [_pi(d), f"{v:+.4f}", s, f"{e:.1e}", int(c)]
                for d, v, s, e, c in zip(
                    ln["delta"],
                    ln["mean_velocity"][0],
                    ln["status"][0],
                    ln["energy_residual"][0],
                    ln["n_cracks"][0],
                )
            ],
        )
        L += [""]
    return L


def strain_check_markdown(c: dict) -> list[str]:
    run = c["run"]
    L = [
        "### strain: convergence check",
        "",
        f"Command: `{run['command']}`. Machine: {run['machine']}, {run['cores']} cores, "
        f"load {', '.join(f'{x:.2f}' for x in run['load'])}; {run['date']}. Wall includes "
        "compilation.",
        "",
    ]
    L += B.md_table(
        ["ω", "δ", "preset", "t1 s", "v̄ m/s", "status", "energy res.", "steps", "wall s"],
        [
            [
                _pi(r["omega"]),
                _pi(r["delta"]),
                r["preset"],
                f"{r['t1']:g}",
                f"{r['mean_velocity']:+.6f}",
                r["status"],
                f"{r['energy_residual']:.1e}",
                r["steps"],
                f"{r['wall_s_with_compile']:.0f}",
            ]
            for r in c["rows"]
        ],
    )
    return L + [""]


def ledger_markdown(c: dict) -> list[str]:
    run = c["run"]
    L = [
        "## Energy ledger at δ = 0 and ±π",
        "",
        f"Command: `{run['command']}`. Machine: {run['machine']}, {run['cores']} cores, "
        f"load {', '.join(f'{x:.2f}' for x in run['load'])}; {run['date']}. Terms [J] of "
        "W_act = ΔT + ΔV + D + W_bp; residual relative to the energy that flowed (the "
        "largest of |ΔT|, |ΔV|, |D|, |W_bp| and the gross actuation work ∫|∂V/∂l̄·u|; "
        "older runs, without the gross work, relative to the largest term).",
        "",
    ]
    L += B.md_table(
        [
            "δ",
            "numerics",
            "t1 s",
            "v̄ m/s",
            "status",
            "residual",
            "W_act",
            "ΔT",
            "ΔV",
            "D",
            "W_bp",
            "gross W_act",
            "steps",
        ],
        [
            [
                _pi(r["delta"]),
                r["numerics"],
                f"{r['t1']:g}",
                f"{r['mean_velocity']:+.6g}",
                r["status"],
                f"{r['energy_residual']:.2g}",
                *(
                    f"{r['terms_J'][k]:.3g}"
                    for k in (
                        "actuation",
                        "kinetic_change",
                        "stretching_change",
                        "friction_dissipation",
                        "back_pressure_work",
                    )
                ),
                f"{r['actuation_gross_J']:.3g}" if "actuation_gross_J" in r else "",
                r["steps"],
            ]
            for r in c["rows"]
        ],
    )
    return L + [""]


def readme(folder: Path) -> str:
    L = [
        "# Readings of the paper",
        "",
        "Command: `python benchmarks/readings.py --readme-only` (rebuilds this page from the "
        "results below; each section names the command that made it).",
        "",
        "Mean velocity "
        "v̄ is head-ward positive (toward the crack), of the node mean (`docs/MODEL.md`). "
        "A mirrored reading runs δ < 0 and is shown at |δ|.",
        "",
    ]
    extra = folder / "notes.md"
    if extra.exists():
        L += [extra.read_text().strip(), ""]
    results = {}
    for path in sorted(folder.glob("readings_*.json")):
        r = json.loads(path.read_text())
        if "reading" in r:
            results[(r["reading"], r.get("tag", ""))] = r
    for name in READINGS:
        for key in sorted(k for k in results if k[0] == name):
            L += reading_markdown(results[key])
        if name == "strain" and STRAIN_CHECK.exists():
            L += strain_check_markdown(json.loads(STRAIN_CHECK.read_text()))
    if LEDGER.exists():
        L += ledger_markdown(json.loads(LEDGER.read_text()))
    return "\n".join(L) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--readings", default=",".join(READINGS), help="comma-separated names")
    ap.add_argument("--line", action="store_true", help="also the δ line at 4π")
    ap.add_argument("--size", type=int, default=5)
    ap.add_argument("--t1", type=float, default=PAPER["t1"])
    ap.add_argument("--preset", default="fast", choices=tuple(jw.PRESETS))
    ap.add_argument("--max-steps", type=int, default=None)
    ap.add_argument(
        "--chunk", type=int, default=None, help="scenes per vmap (jw.sweep's default when unset)"
    )
    ap.add_argument("--tag", default="", help="suffix of the result file's name")
    ap.add_argument("--readme-only", action="store_true", help="rebuild README.md only")
    args = ap.parse_args()
    if not args.readme_only:
        for name in args.readings.split(","):
            if name not in READINGS:
                raise SystemExit(f"unknown reading {name!r}; known: {', '.join(READINGS)}")
            out = run_reading(name, args)
            out["tag"] = args.tag
            B.write_json(OUT / f"readings_{name.replace('+', '_')}{args.tag}.json", out)
    (OUT / "README.md").write_text(readme(OUT))


if __name__ == "__main__":
    main()

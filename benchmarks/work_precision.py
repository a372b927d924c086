"""Work-precision study of issue 3: every solver against a tight reference, side by side
with SciPy's solve_ivp and the paper's fixed-step implicit Euler; the presets on every
gait scene; the smoothing study and the hard-case suite.

    python benchmarks/work_precision.py            # the full study (est. ~45 min, quiet 2-core)
    python benchmarks/work_precision.py --quick    # tiny ladder, short horizons (~6 min)
    python benchmarks/work_precision.py --parts wp,presets   # a subset

Writes `benchmarks/results/work_precision/`: `work_precision.{json,md,png}`,
`presets.{json,md}` and `run_info.json`; the other parts write
`results/smoothing/smoothing.{json,md,png}` and `results/hard_cases/hard_cases.{json,md}`;
`--quick` adds `_quick` to every name. Each file records the machine and the date.
The numerics and plans are in `study.py`; `benchmarks/README.md` explains the figures.

Error: relative error in mean velocity, |v − v_ref| / max(|v_ref|, 1e-4 m/s), against a
reference of the *same smoothed model* that resolves the elastic ringing: Tsit5 on the
full error norm (x, v, l̄), rtol 1e-9 (`REFERENCE`). Its convergence is shown against
rtol 1e-10 and against the package's `reference` preset (Kvaerno5, same norm and
tolerance; ~250× slower here, so compared on a short horizon only).
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import _bench as B  # (first: sets the BLAS threads before numpy loads)
import hard_cases
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
import scenes as S
import smoothing
import study
from study import FULL, GROWTH, QUICK, REFERENCE, REFERENCE_TIGHT, SCENE_REFERENCE, Plan  # noqa: F401

jw = B.jw


def all_scenes(n_random: int) -> dict[str, dict]:
    """Every gait scene by name, `forward` included."""
    return {"forward": dict(S.FORWARD), **S.gait_scenes(n_random)}


def paper_ie(dt: float) -> jw.Numerics:
    """The `paper` preset (fixed-step implicit Euler, full Newton) at step `dt`."""
    return jw.PRESETS["paper"].replace(dt=dt)


def ladder(plan: Plan) -> list[tuple[str, str, jw.Numerics]]:
    """(line, point label, numerics) of every method of the diagram, loose to tight."""
    out = []
    for solver in plan.positions_solvers:
        for atol in plan.positions_atols:
            out.append(
                (
                    f"{solver} / positions",
                    f"atol {atol:g}",
                    jw.Numerics(solver=solver, rtol=0.0, atol=atol, max_cracks=256),
                )
            )
    for solver in plan.full_solvers:
        rtols = plan.full_rtols if solver == "Tsit5" else plan.full_rtols_implicit
        for rtol in rtols:
            out.append(
                (
                    f"{solver} / full",
                    f"rtol {rtol:g}",
                    jw.Numerics(
                        solver=solver,
                        rtol=rtol,
                        atol=1e-3 * rtol,
                        norm="full",
                        max_cracks=256,
                        max_steps=2**22,
                    ),
                )
            )
    for dt in sorted(plan.ie_dts, reverse=True):
        out.append(("paper IE (fixed dt)", f"dt {dt:g}", paper_ie(dt)))
    return out


# --- the work-precision diagram ---------------------------------------------------------


def reference_rows(plan: Plan, scene: dict) -> dict:
    """REFERENCE at both horizons, its convergence, and the `reference` preset check."""
    out = {}
    for label, num in (
        ("REFERENCE (Tsit5 full rtol 1e-9)", REFERENCE),
        ("REFERENCE_TIGHT (Tsit5 full rtol 1e-10)", REFERENCE_TIGHT),
        ("SCENE_REFERENCE (Tsit5 full rtol 1e-7)", SCENE_REFERENCE),
    ):
        for t1 in (plan.t_short, plan.t_long):
            B.log(f"[reference] {label} t1={t1}")
            out[(label, t1)] = B.run_jax(num, scene, t1, repeats=1)
    for label, num in (
        ("REFERENCE (Tsit5 full rtol 1e-9)", REFERENCE),
        ("`reference` preset (Kvaerno5 full rtol 1e-9)", jw.PRESETS["reference"]),
    ):
        B.log(f"[reference] {label} t1={plan.t_refcheck}")
        out[(label, plan.t_refcheck)] = B.run_jax(num, scene, plan.t_refcheck, repeats=1)
    return out


def convergence_table(refs: dict, plan: Plan) -> list[dict]:
    """Pairwise agreement of the reference solves at each horizon."""
    rows = []
    base = "REFERENCE (Tsit5 full rtol 1e-9)"
    for (label, t1), r in refs.items():
        if label == base:
            continue
        v0 = refs[(base, t1)]["mean_velocity"]
        rows.append(
            {
                "t1": t1,
                "solve": label,
                "versus": base,
                "mean_velocity": r["mean_velocity"],
                "reference_velocity": v0,
                "rel_difference": B.rel_error(r["mean_velocity"], v0),
                "wall_s": r["wall_s"],
                "steps": r["steps"],
                "status": r["status"],
            }
        )
    return rows


def run_ladder(plan: Plan, scene: dict, v_ref: dict) -> list[dict]:
    """Every ladder point at t_short and (when affordable) t_long, with its error."""
    rows = []
    skip_lines = set()
    failures: dict[str, int] = {}
    for line, point, num in ladder(plan):
        if line in skip_lines:
            rows.append(
                {
                    "line": line,
                    "point": point,
                    "t1": plan.t_short,
                    "status": "skipped (a looser rung was too slow or two failed)",
                }
            )
            continue
        for t1 in (plan.t_short, plan.t_long):
            B.log(f"[ladder] {line} {point} t1={t1}")
            row = {"line": line, "point": point, "numerics": _numerics_dict(num)}
            if t1 == plan.t_long:
                short = rows[-1]
                predicted = short["wall_s"] * plan.t_long / plan.t_short
                if predicted > plan.max_run_s or short["status"] != "ok":
                    rows.append(
                        row
                        | {
                            "t1": t1,
                            "status": f"skipped (predicted {predicted:.0f} s > max_run_s)"
                            if short["status"] == "ok"
                            else "skipped (failed short)",
                        }
                    )
                    continue
            res = B.run_jax(num, scene, t1, repeats=plan.repeats)
            res["error"] = B.rel_error(res["mean_velocity"], v_ref[t1])
            rows.append(row | res)
            if t1 == plan.t_short and res["wall_s"] > plan.max_run_s / GROWTH:
                skip_lines.add(line)  # the next, tighter rung would likely exceed it
            if t1 == plan.t_short:
                failures[line] = failures.get(line, 0) + 1 if res["status"] != "ok" else 0
                if failures[line] >= 2:
                    skip_lines.add(line)  # two failures in a row: the line says no more
    return rows


def run_presets_wp(plan: Plan, scene: dict, v_ref: dict) -> list[dict]:
    """The named presets at both horizons, as rows of the diagram."""
    rows = []
    for name in ("default", "fast", "accurate", "paper"):
        for t1 in (plan.t_short, plan.t_long):
            B.log(f"[preset] {name} t1={t1}")
            res = B.run_jax(jw.PRESETS[name], scene, t1, repeats=plan.repeats)
            res["error"] = B.rel_error(res["mean_velocity"], v_ref[t1])
            rows.append(
                {
                    "line": f"preset {name}",
                    "point": name,
                    "numerics": _numerics_dict(jw.PRESETS[name]),
                }
                | res
            )
    return rows


def run_scipy_anchors(plan: Plan, scene: dict, v_ref: dict) -> list[dict]:
    """solve_ivp LSODA/BDF/Radau over the rtol ladder at t_short, loose to tight."""
    rows = []
    for method in plan.scipy_methods:
        for rtol in sorted(plan.scipy_rtols, reverse=True):
            if (
                rows
                and rows[-1]["line"] == f"SciPy {method}"
                and rows[-1].get("wall_s", 0) > plan.max_scipy_s / GROWTH
            ):
                rows.append(
                    {
                        "line": f"SciPy {method}",
                        "point": f"rtol {rtol:g}",
                        "t1": plan.t_short,
                        "status": "skipped (> max_scipy_s)",
                    }
                )
                continue
            B.log(f"[scipy] {method} rtol={rtol} t1={plan.t_short}")
            res = B.run_scipy(method, rtol, scene, plan.t_short)
            res["error"] = B.rel_error(res["mean_velocity"], v_ref[plan.t_short])
            rows.append({"line": f"SciPy {method}", "point": f"rtol {rtol:g}"} | res)
    return rows


def _numerics_dict(num: jw.Numerics) -> dict:
    return {f.name: getattr(num, f.name) for f in dataclasses.fields(num)}


def _points(rows, line_prefix: str, t1: float) -> list[tuple[float, float]]:
    return [
        (r["error"], r["wall_s"])
        for r in rows
        if r["line"].startswith(line_prefix)
        and r.get("t1") == t1
        and r.get("status") == "ok"
        and "error" in r
    ]


def equal_error_ratios(rows: list[dict], plan: Plan) -> list[dict]:
    """default (and fast) against the best SciPy method and the paper's IE, at equal error.

    For the competitor, the wall time to reach the preset's error is read off its
    work-precision line (`_bench.time_at_error`); ratio = that time / the preset's time.
    """
    out = []
    for preset in ("default", "fast"):
        for t1 in (plan.t_short, plan.t_long):
            me = next((r for r in rows if r["line"] == f"preset {preset}" and r["t1"] == t1), None)
            if me is None or me.get("status") != "ok":
                continue
            rivals = [f"SciPy {m}" for m in plan.scipy_methods] if t1 == plan.t_short else []
            rivals.append("paper IE (fixed dt)")
            for rival in rivals:
                t_rival, how = B.time_at_error(_points(rows, rival, t1), me["error"])
                ratio = (t_rival / me["wall_s"]) if t_rival else None
                bound = "≥ " if how.startswith("lower") else "≤ " if how.startswith("upper") else ""
                target = RATIO_TARGETS.get((preset, rival.split()[0]))
                out.append(
                    {
                        "preset": preset,
                        "t1": t1,
                        "versus": rival,
                        "preset_error": me["error"],
                        "preset_wall_s": me["wall_s"],
                        "rival_wall_s_at_equal_error": t_rival,
                        "how": how,
                        "ratio": ratio,
                        "ratio_bound": bound,
                        "target": target,
                    }
                )
    best = {}
    for r in out:
        if r["versus"].startswith("SciPy") and r["ratio"] is not None:
            key = (r["preset"], r["t1"])
            if key not in best or r["ratio"] < best[key]["ratio"]:
                best[key] = r
    for r in best.values():
        r["best_scipy"] = True
    return out


SCIPY_COLORS = {"SciPy LSODA": "#006400", "SciPy BDF": "#32cd32", "SciPy Radau": "#8b4513"}


def plot_work_precision(rows: list[dict], plan: Plan, path: Path, title: str) -> None:
    """Two log-log panels (t_short with SciPy, t_long): error against wall time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(14, 6.2))
    lines = list(dict.fromkeys(r["line"] for r in rows))
    cmap = plt.get_cmap("tab20")
    for ax, t1 in zip(axes, (plan.t_short, plan.t_long)):
        for i, line in enumerate(lines):
            pts = [
                (r["wall_s"], max(r["error"], 1e-12))
                for r in rows  # ladder order
                if r["line"] == line
                and r.get("t1") == t1
                and "error" in r
                and r.get("status") == "ok"
            ]
            if not pts:
                continue
            x, y = zip(*pts)
            if line.startswith("preset"):
                ax.plot(x, y, "*", ms=16, mec="k", color=cmap(i % 20), label=line, zorder=5)
            elif line.startswith("SciPy"):
                ax.plot(x, y, "s--", lw=2, color=SCIPY_COLORS.get(line, "0.5"), label=line)
            elif line.startswith("paper"):
                ax.plot(x, y, "D-", lw=2.5, color="k", label=line)
            else:
                ax.plot(x, y, "o-" if "positions" in line else "^:", color=cmap(i % 20), label=line)
        ax.axhline(1e-2, color="r", lw=0.8, ls="--")
        ax.axhline(1e-3, color="g", lw=0.8, ls="--")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("wall time after compilation [s]")
        ax.set_ylabel("relative error in mean velocity")
        ax.set_title(f"t1 = {t1:g} s")
        ax.grid(True, which="both", alpha=0.3)
    handles = {}
    for ax in axes:
        for h, label in zip(*ax.get_legend_handles_labels()):
            handles.setdefault(label, h)
    fig.legend(handles.values(), handles.keys(), fontsize=7, loc="center right")
    fig.suptitle(title, fontsize=10)
    fig.tight_layout(rect=(0, 0, 0.87, 1))
    fig.savefig(path, dpi=120)
    plt.close(fig)


def wp_markdown(out: dict) -> str:
    plan = out["plan"]
    m = out["machine"]
    L = [
        f"# Work-precision study ({plan['name']})",
        "",
        f"Machine: {m['cpu']}, {m['cpus']} CPUs, {m['platform']}, jax {m['jax']}, "
        f"diffrax {m['diffrax']}, scipy {m['scipy']}; load average at start "
        f"{m['load_average_at_start']}; {m['date']}; commit {m['git_commit']}.",
        "",
        f"Scene `{plan['wp_scene']}` ({out['scene']}). Error = |v − v_ref| / max(|v_ref|, "
        f"1e-4 m/s), v = mean velocity; v_ref from REFERENCE (Tsit5, full norm, rtol 1e-9). "
        f"Wall time: fastest of up to {plan['repeats']} runs after compilation. Memory: "
        "peak RSS increase during the solve [MB] / XLA buffer plan [kB].",
        "",
        "## Reference convergence",
        "",
    ]
    L += B.md_table(
        [
            "t1 s",
            "solve",
            "mean velocity m/s",
            "rel. difference to REFERENCE",
            "wall s",
            "steps",
            "status",
        ],
        [
            [
                c["t1"],
                c["solve"],
                B.fmt(c["mean_velocity"], ".10g"),
                B.fmt(c["rel_difference"], ".1e"),
                B.fmt(c["wall_s"], ".3g"),
                c["steps"],
                c["status"],
            ]
            for c in out["convergence"]
        ],
    )
    L += ["", "## Equal-error ratios", ""]
    L += B.md_table(
        [
            "preset",
            "t1 s",
            "versus",
            "preset error",
            "preset wall s",
            "rival wall s at equal error",
            "how",
            "ratio",
            "target",
        ],
        [
            [
                r["preset"],
                r["t1"],
                r["versus"] + (" (best SciPy)" if r.get("best_scipy") else ""),
                B.fmt(r["preset_error"], ".1e"),
                B.fmt(r["preset_wall_s"], ".3g"),
                B.fmt(r["rival_wall_s_at_equal_error"], ".3g"),
                r["how"],
                r["ratio_bound"] + B.fmt(r["ratio"], ".3g"),
                "—" if r["target"] is None else f"≥ {r['target']:g}",
            ]
            for r in out["ratios"]
        ],
    )
    L += ["", "## All runs", ""]
    L += B.md_table(
        [
            "method",
            "point",
            "t1 s",
            "error",
            "wall s",
            "compile s",
            "steps",
            "rejected",
            "cracks",
            "peak MB",
            "XLA kB",
            "energy res.",
            "status",
        ],
        [
            [
                r["line"],
                r["point"],
                r.get("t1"),
                B.fmt(r.get("error"), ".1e"),
                B.fmt(r.get("wall_s"), ".3g"),
                B.fmt(r.get("compile_s"), ".3g"),
                r.get("steps", "—"),
                r.get("rejected", "—"),
                r.get("n_cracks", "—"),
                B.fmt(r.get("peak_rss_mb"), ".3g"),
                B.fmt(None if r.get("xla_bytes") is None else r["xla_bytes"] / 1024, ".3g"),
                B.fmt(r.get("energy_residual"), ".1e"),
                r.get("status"),
            ]
            for r in out["rows"]
        ],
    )
    return "\n".join(L) + "\n"


def _path(root: Path, stem: str, plan: Plan, ext: str) -> Path:
    """This benchmark's file `root/work_precision/<stem>[_quick].<ext>`."""
    return study.output(root, "work_precision", stem, plan, ext)


def work_precision(plan: Plan, root: Path, machine: dict) -> dict:
    """The diagram, its table and the equal-error ratios, under `root/work_precision/`."""
    scene = all_scenes(plan.n_random)[plan.wp_scene]
    refs = reference_rows(plan, scene)
    base = "REFERENCE (Tsit5 full rtol 1e-9)"
    v_ref = {t1: refs[(base, t1)]["mean_velocity"] for t1 in (plan.t_short, plan.t_long)}
    rows = run_presets_wp(plan, scene, v_ref)
    rows += run_scipy_anchors(plan, scene, v_ref)
    rows += run_ladder(plan, scene, v_ref)
    out = {
        "plan": dataclasses.asdict(plan),
        "machine": machine,
        "scene": scene,
        "reference_velocity": v_ref,
        "convergence": convergence_table(refs, plan),
        "rows": rows,
    }
    out["ratios"] = equal_error_ratios(rows, plan)
    B.write_json(_path(root, "work_precision", plan, "json"), out)
    _path(root, "work_precision", plan, "md").write_text(wp_markdown(out))
    plot_work_precision(
        rows,
        plan,
        _path(root, "work_precision", plan, "png"),
        f"scene {plan.wp_scene} {scene}; {machine['cpu']} "
        f"({machine['cpus']} CPUs), {machine['date']}",
    )
    return out


# --- the preset check on every gait scene -------------------------------------------

#: Issue 3's targets for (preset, rival family): speed-up at equal error.
RATIO_TARGETS = {("default", "SciPy"): 100.0, ("default", "paper"): 5.0}

PRESET_TARGETS = {"default": 1e-2, "fast": 1e-2, "accurate": 1e-3}


def reference_velocities(scene: dict, t1s: tuple) -> tuple[dict, dict]:
    """SCENE_REFERENCE run once to max(t1s) with dense output at every t1."""
    t_end = max(t1s)
    p = B.params_of(scene)
    fn, compile_s, _ = B.compiled_simulate(SCENE_REFERENCE, p, dense=len(t1s))
    r, wall, _, _ = B.timed_runs(fn, (p, jnp.float64(t_end), jnp.asarray(t1s, float)), 1)
    x = np.asarray(r.trajectory.x)
    x0 = np.asarray(r.x0)
    v = {t1: float((x[i].mean() - x0.mean()) / t1) for i, t1 in enumerate(t1s)}
    info = B.summary_row(r) | {"wall_s": wall, "compile_s": compile_s, "t1": t_end}
    return v, info


def preset_check(plan: Plan, root: Path, machine: dict) -> dict:
    """default, fast and accurate against SCENE_REFERENCE on every scene and horizon."""
    scenes = S.gait_scenes(plan.n_random)
    if plan.scene_names is not None:
        pool = all_scenes(max(plan.n_random, 1))
        scenes = {k: pool[k] for k in plan.scene_names}
    rows, refs = [], {}
    for name, scene in scenes.items():
        B.log(f"[presets] reference {name}")
        v_ref, info = reference_velocities(scene, plan.scene_t1s)
        refs[name] = {"velocities": v_ref} | info
        for preset in ("default", "fast", "accurate"):
            for t1 in plan.scene_t1s:
                B.log(f"[presets] {preset} {name} t1={t1}")
                res = B.run_jax(jw.PRESETS[preset], scene, t1, repeats=1)
                res["error"] = B.rel_error(res["mean_velocity"], v_ref[t1])
                rows.append(
                    {
                        "scene": name,
                        "params": scene,
                        "preset": preset,
                        "reference_velocity": v_ref[t1],
                    }
                    | res
                )
    verdict = {}
    for preset, target in PRESET_TARGETS.items():
        mine = [r for r in rows if r["preset"] == preset]
        worst = max(mine, key=lambda r: r["error"])
        verdict[preset] = {
            "target": target,
            "max_error": worst["error"],
            "worst_scene": worst["scene"],
            "worst_t1": worst["t1"],
            "all_ok": all(r["status"] == "ok" for r in mine),
            "meets_target": worst["error"] <= target,
            "total_wall_s": sum(r["wall_s"] for r in mine),
        }
    out = {
        "plan": dataclasses.asdict(plan),
        "machine": machine,
        "references": refs,
        "rows": rows,
        "verdict": verdict,
    }
    B.write_json(_path(root, "presets", plan, "json"), out)
    _path(root, "presets", plan, "md").write_text(presets_markdown(out))
    return out


def presets_markdown(out: dict) -> str:
    m = out["machine"]
    L = [
        "# Presets on every gait scene",
        "",
        f"Machine: {m['cpu']}, {m['cpus']} CPUs, jax {m['jax']}; {m['date']}. Reference: "
        f"SCENE_REFERENCE (Tsit5, full norm, rtol {SCENE_REFERENCE.rtol:g}; its agreement "
        "with rtol 1e-9 is in work_precision.md), one run to the longest horizon with dense "
        "output at each horizon. Error: |v − v_ref| / max(|v_ref|, 1e-4 m/s). Targets: "
        "default ≤ 1 %, accurate ≤ 0.1 % on every scene (fast: 1 %, informative). Wall: one "
        "run after compilation.",
        "",
        "## Verdict",
        "",
    ]
    L += B.md_table(
        [
            "preset",
            "target",
            "max error",
            "worst scene",
            "t1",
            "all ok",
            "meets target",
            "total wall s",
        ],
        [
            [
                p,
                B.fmt(v["target"], ".0e"),
                B.fmt(v["max_error"], ".2e"),
                v["worst_scene"],
                v["worst_t1"],
                v["all_ok"],
                v["meets_target"],
                B.fmt(v["total_wall_s"], ".3g"),
            ]
            for p, v in out["verdict"].items()
        ],
    )
    L += ["", "## Every run", ""]
    L += B.md_table(
        [
            "scene",
            "t1 s",
            "preset",
            "mean velocity m/s",
            "reference m/s",
            "error",
            "wall s",
            "steps",
            "cracks",
            "energy res.",
            "status",
        ],
        [
            [
                r["scene"],
                r["t1"],
                r["preset"],
                B.fmt(r["mean_velocity"], ".6g"),
                B.fmt(r["reference_velocity"], ".6g"),
                B.fmt(r["error"], ".1e"),
                B.fmt(r["wall_s"], ".3g"),
                r["steps"],
                r["n_cracks"],
                B.fmt(r["energy_residual"], ".1e"),
                r["status"],
            ]
            for r in out["rows"]
        ],
    )
    L += ["", "## References", ""]
    L += B.md_table(
        ["scene", "t1 s", "wall s", "steps", "cracks", "status"],
        [
            [k, v["t1"], B.fmt(v["wall_s"], ".3g"), v["steps"], v["n_cracks"], v["status"]]
            for k, v in out["references"].items()
        ],
    )
    return "\n".join(L) + "\n"


# --- main ---------------------------------------------------------------------------

PARTS = ("wp", "presets", "smoothing", "hard")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="tiny ladder, short horizons")
    ap.add_argument(
        "--parts", default=",".join(PARTS), help=f"comma-separated subset of {', '.join(PARTS)}"
    )
    ap.add_argument(
        "--out",
        type=Path,
        default=B.RESULTS,
        help="results root; each part writes its own folder under it (default benchmarks/results)",
    )
    args = ap.parse_args(argv)
    plan = study.plan_of(args.quick)
    parts = [p.strip() for p in args.parts.split(",") if p.strip()]
    unknown = set(parts) - set(PARTS)
    if unknown:
        ap.error(f"unknown parts {sorted(unknown)}")
    root = args.out
    machine = B.machine_info()
    start = time.perf_counter()
    timings = {}
    for part in parts:
        t = time.perf_counter()
        if part == "wp":
            work_precision(plan, root, machine)
        elif part == "presets":
            preset_check(plan, root, machine)
        elif part == "smoothing":
            smoothing.smoothing_study(plan, root, machine)
        elif part == "hard":
            hard_cases.hard_case_study(plan, root, machine)
        timings[part] = time.perf_counter() - t
        B.log(f"== {part} done in {timings[part]:.0f} s")
    B.write_json(
        _path(root, "run_info", plan, "json"),
        {
            "plan": dataclasses.asdict(plan),
            "machine": machine,
            "parts": parts,
            "part_wall_s": timings,
            "total_wall_s": time.perf_counter() - start,
        },
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

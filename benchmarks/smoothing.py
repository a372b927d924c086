"""Model error apart from solver error: what the smoothing of sgn and max costs.

    python benchmarks/smoothing.py [--quick]      # or as part of work_precision.py

For the nominal and the forward gait, the mean velocity against ε_v (sgn(v) ≈
tanh(v/ε_v)) from 1e-3 to 1e-6 m/s, and against ε_N (max(z, 0) ≈ ε_N softplus(z/ε_N)),
each solved with `accurate` (the converged value) and with `default` (whose difference
to it is the solver error at that ε); `Smoothing(exact=True)` (exact sgn and max) is the
limit. Model error of an ε = |v(ε) − v(smallest ε)| / |v(smallest ε)|. Writes
`results/smoothing/smoothing[_quick].{json,md,png}`.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import _bench as B  # (first: sets the BLAS threads before numpy loads)
import scenes as S
import study

jw = B.jw

SMOOTHING_SCENES = {"nominal": dict(S.NOMINAL), "forward": dict(S.FORWARD)}


#: Step bound of the exact (non-smooth) runs: the adaptive solvers chatter at each
#: friction reversal and were seen to exhaust 2**20 steps within 2 s, so the exact
#: limit is recorded with a small bound (its status says how it ended).
EXACT_MAX_STEPS = 2**15


def run_smoothed(scene: dict, t1: float, preset: str, exact: bool = False, **eps) -> dict:
    """One solve of `scene` with smoothing scales `eps` (eps_v, eps_N) or exact.

    `preset` names a preset or `"reference"`, the Tsit5 full-norm SCENE_REFERENCE.
    """
    if preset == "reference":
        num = study.SCENE_REFERENCE
    else:
        num = jw.PRESETS[preset]
    if exact:
        num = num.replace(max_steps=EXACT_MAX_STEPS)
        p = B.params_of(scene)
        p = dataclasses.replace(p, smoothing=jw.Smoothing(exact=True))
        fn, compile_s, xla = B.compiled_simulate(num, p)
        import jax.numpy as jnp

        r, wall, walls, peak = B.timed_runs(fn, (p, jnp.float64(t1)), 1)
        return B.summary_row(r) | {"t1": t1, "wall_s": wall, "compile_s": compile_s}
    return B.run_jax(num, scene | eps, t1, repeats=1)


def sweep_one(scene: dict, t1: float, name: str, values: tuple) -> list[dict]:
    """`name` (eps_v or eps_N) over `values`, accurate and default at each."""
    rows = []
    for value in values:
        for preset in ("accurate", "default"):
            B.log(f"[smoothing] {name}={value:g} {preset}")
            res = run_smoothed(scene, t1, preset, **{name: value})
            rows.append({"knob": name, "value": value, "preset": preset} | res)
    return rows


def reference_check(scene: dict, t1: float, values: tuple) -> list[dict]:
    """SCENE_REFERENCE at the default ε_v and the smallest: how good `accurate` is there."""
    rows = []
    for value in sorted({1e-4, min(values)}):
        B.log(f"[smoothing] eps_v={value:g} reference")
        rows.append(
            {"knob": "eps_v", "value": value, "preset": "reference"}
            | run_smoothed(scene, t1, "reference", eps_v=value)
        )
    return rows


def add_errors(rows: list[dict]) -> None:
    """Model error vs the smallest ε (accurate), solver error of default vs accurate."""
    for knob in {r["knob"] for r in rows}:
        acc = {
            r["value"]: r["mean_velocity"]
            for r in rows
            if r["knob"] == knob and r["preset"] == "accurate"
        }
        limit = acc[min(acc)]
        for r in rows:
            if r["knob"] != knob:
                continue
            if r["preset"] == "accurate":
                r["model_error_vs_smallest"] = B.rel_error(r["mean_velocity"], limit)
            elif r["preset"] == "default":
                r["solver_error_default"] = B.rel_error(r["mean_velocity"], acc[r["value"]])
            else:  # the reference: the error of accurate itself at this ε
                r["accurate_error"] = B.rel_error(acc[r["value"]], r["mean_velocity"])


def smoothing_study(plan, root: Path, machine: dict) -> dict:
    """Both sweeps on both scenes, the exact limit, table and figure, written under
    `root/smoothing/`."""
    out = {"machine": machine, "t1": plan.smoothing_t1, "scenes": {}}
    for name, scene in SMOOTHING_SCENES.items():
        rows = sweep_one(scene, plan.smoothing_t1, "eps_v", plan.eps_vs)
        rows += sweep_one(scene, plan.smoothing_t1, "eps_N", plan.eps_Ns)
        rows += reference_check(scene, plan.smoothing_t1, plan.eps_vs)
        add_errors(rows)
        B.log(f"[smoothing] exact {name}")
        exact = run_smoothed(scene, plan.smoothing_t1, "accurate", exact=True)
        out["scenes"][name] = {"params": scene, "rows": rows, "exact_accurate": exact}
    B.write_json(study.output(root, "smoothing", "smoothing", plan, "json"), out)
    study.output(root, "smoothing", "smoothing", plan, "md").write_text(smoothing_markdown(out))
    plot_smoothing(out, study.output(root, "smoothing", "smoothing", plan, "png"))
    return out


def smoothing_markdown(out: dict) -> str:
    m = out["machine"]
    L = [
        f"# Smoothing: model error against solver error (t1 = {out['t1']:g} s)",
        "",
        f"Machine: {m['cpu']}, {m['cpus']} CPUs, jax {m['jax']}; {m['date']}.",
        "",
        "Model error: |v(ε) − v(smallest ε)| / |v(smallest ε)|, both `accurate`. Solver "
        "error: |v_default(ε) − v_accurate(ε)| / |v_accurate(ε)|.",
        "",
    ]
    for name, sc in out["scenes"].items():
        L += [f"## {name} {sc['params']}", ""]
        accurate = [r for r in sc["rows"] if r["preset"] == "accurate"]
        default = {(r["knob"], r["value"]): r for r in sc["rows"] if r["preset"] == "default"}
        L += B.md_table(
            [
                "knob",
                "value",
                "mean velocity (accurate) m/s",
                "model error",
                "default m/s",
                "solver error (default)",
                "accurate wall s",
                "default wall s",
                "statuses",
            ],
            [
                [
                    r["knob"],
                    f"{r['value']:g}",
                    B.fmt(r["mean_velocity"], ".7g"),
                    B.fmt(r["model_error_vs_smallest"], ".1e"),
                    B.fmt(default[(r["knob"], r["value"])]["mean_velocity"], ".7g"),
                    B.fmt(default[(r["knob"], r["value"])]["solver_error_default"], ".1e"),
                    B.fmt(r["wall_s"], ".3g"),
                    B.fmt(default[(r["knob"], r["value"])]["wall_s"], ".3g"),
                    f"{r['status']} / {default[(r['knob'], r['value'])]['status']}",
                ]
                for r in accurate
            ],
        )
        L += ["", "Solver error of `accurate` itself (against SCENE_REFERENCE, Tsit5 full norm):"]
        L += [
            f"- ε_v = {r['value']:g}: {B.fmt(r['accurate_error'], '.1e')} (reference "
            f"{B.fmt(r['mean_velocity'], '.7g')} m/s, {r['steps']} steps, "
            f"{B.fmt(r['wall_s'], '.3g')} s, {r['status']})"
            for r in sc["rows"]
            if r["preset"] == "reference"
        ]
        e = sc["exact_accurate"]
        L += [
            "",
            f"Exact sgn and max (`Smoothing(exact=True)`, accurate, max_steps "
            f"{EXACT_MAX_STEPS}): status {e['status']} after {e['steps']} steps and "
            f"{B.fmt(e['wall_s'], '.3g')} s (mean velocity when it stopped "
            f"{B.fmt(e['mean_velocity'], '.4g')} m/s, meaningless unless ok).",
            "",
        ]
    return "\n".join(L) + "\n"


def plot_smoothing(out: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
    for ax, knob, unit in zip(axes, ("eps_v", "eps_N"), ("m/s", "N")):
        for i, (name, sc) in enumerate(out["scenes"].items()):
            rows = [r for r in sc["rows"] if r["knob"] == knob]
            acc = sorted(
                (r["value"], max(r["model_error_vs_smallest"], 1e-12))
                for r in rows
                if r["preset"] == "accurate"
            )
            dflt = sorted(
                (r["value"], max(r["solver_error_default"], 1e-12))
                for r in rows
                if r["preset"] == "default"
            )
            color = f"C{i}"
            ax.plot(*zip(*acc), "o-", color=color, label=f"{name}: model error (vs smallest ε)")
            ax.plot(*zip(*dflt), "x--", color=color, label=f"{name}: solver error of default")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel(f"{knob} [{unit}]")
        ax.set_ylabel("relative change in mean velocity")
        ax.axhline(1e-2, color="r", lw=0.8, ls=":")
        ax.grid(True, which="both", alpha=0.3)
        ax.set_title(f"{knob}, t1 = {out['t1']:g} s")
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


if __name__ == "__main__":
    study.run_part(smoothing_study, __doc__)

"""What a run prints: its summary as one JSON-able dict, as text, or as one line."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np


def _finite_or_none(x):
    return x if isinstance(x, (int, str)) or x is None or math.isfinite(x) else None


def run_report(result, params, t1, numerics, wall) -> dict:
    """The JSON-able summary of a run, with the parameters and numerics used (non-finite
    numbers as None)."""
    out = result.summary()
    out = {
        k: ([_finite_or_none(v) for v in val] if isinstance(val, list) else _finite_or_none(val))
        for k, val in out.items()
    }
    out["wall_time_s"] = wall
    used = {}
    for name, value in params.flat().items():
        if name == "N":
            used[name] = int(value)
        elif value is None:
            used[name] = None
        else:
            used[name] = float(np.asarray(value))
    used["t1"] = float(t1)
    out["parameters"] = used
    out["options"] = params.options()
    out["numerics"] = {f.name: getattr(numerics, f.name) for f in dataclasses.fields(numerics)}
    return out


def print_text(report: dict, preset: str, figure: Path | None) -> None:
    """`run_report`'s summary as the text `jaxworm simulate` prints."""
    n = report["numerics"]
    p = report["parameters"]
    times = report["crack_times"]
    cracks = f"{report['n_cracks']}"
    if times:
        cracks += f" (first at {times[0]:.3g} s, last at {times[-1]:.3g} s)"
    mv = report["mean_velocity"]
    lines = [
        f"jaxworm: t1 = {p['t1']:g} s, omega = {p['omega']:.4g} rad/s, delta = {p['delta']:.4g} "
        f"rad, A = {p['A']:g} m/s; preset {preset} ({n['solver']}, rtol {n['rtol']:g}, "
        f"atol {n['atol']:g}{', dt ' + format(n['dt'], 'g') if n['dt'] else ''})",
        f"  mean velocity  {mv:.6g} m/s" if mv is not None else "  mean velocity  nan",
        f"  cracks         {cracks}",
        f"  status         {report['status_message']}",
        f"  steps          {report['steps']} (rejected {report['rejected_steps']})",
        f"  wall time      {report['wall_time_s']:.2f} s (compile included)",
    ]
    if report["t_end"] is not None and report["t_end"] < p["t1"]:
        lines.insert(
            2,
            f"  simulated      {report['t_end']:.6g} s of t1 = {p['t1']:g} s "
            "(stopped early; the mean velocity is over the time simulated)",
        )
    if figure is not None:
        lines.append(f"  figure         {figure}")
    print("\n".join(lines))


def one_line(result, t1, wall) -> str:
    """Mean velocity, cracks, status, t1 and solve time of a run, on one line."""
    s = result.summary()
    return (
        f"mean velocity {s['mean_velocity']:.6g} m/s, {s['n_cracks']} cracks, status "
        f"{s['status']}, t1 = {float(t1):g} s, solve {wall:.1f} s (compile included)"
    )

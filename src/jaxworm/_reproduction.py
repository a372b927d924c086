"""The paper's reported numbers (§4.1, Figs. 2-3) and their comparison with a sweep.

Pure functions of a sweep dict (`jaxworm.sweep` / `load_sweep`) over ω and δ: used by
`jaxworm paper`, the reproduction notebook and `docs/reproduction.md`, so the three
print the same comparison.

```python
s = jw.sweep(paper_grid(7), t1=60.0)
for row in compare_with_paper(s, nominal_velocity=-0.0098):
    print(row["what"], row["paper"], row["ours"])
```
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
from jaxtyping import ArrayLike, Float

__all__ = [
    "PAPER",
    "paper_grid",
    "mirror_sweep",
    "zero_crossing",
    "compare_with_paper",
    "format_comparison",
    "format_readings",
]

#: What the paper reports (§4.1 and the captions of Figs. 2-3). Velocities [m/s],
#: ω [rad/s], δ [rad]; the grid is ω ∈ [3π, 5π] × δ ∈ [π/6, π/3], A = 0.02 m/s, 60 s.
PAPER: dict[str, Any] = {
    "nominal": {"omega": 4 * math.pi, "delta": math.pi / 4, "mean_velocity": 0.0022},
    "fastest_forward": {"omega": 3 * math.pi, "delta": math.pi / 3, "mean_velocity": 0.0108},
    "fastest_retreat": {"omega": 3 * math.pi, "delta": math.pi / 6, "mean_velocity": -0.0137},
    "retreat_below_delta": 0.74,  # "values of δ below approximately δ = 0.74" retreat
    "bound_at_5pi": 0.005,  # at ω = 5π "constrained between −0.005 and 0.005 m/s"
    "slowdown_3pi_to_5pi": 2.0,  # "a factor of two slower than ω = 3π" (agree: ≥ 1.5)
    "t1": 60.0,
    "omega_range": (3 * math.pi, 5 * math.pi),
    "delta_range": (math.pi / 6, math.pi / 3),
}


def paper_grid(size: int = 21, delta_sign: float = 1.0) -> dict[str, Float[np.ndarray, " size"]]:
    """The Fig. 3 grid: `size` evenly spaced ω ∈ [3π, 5π] [rad/s] × δ ∈ [π/6, π/3] [rad]
    (the paper: 21 × 21). `delta_sign = -1` mirrors δ to [−π/3, −π/6] in increasing
    order (the travelling wave run the other way along the body)."""
    if not (isinstance(size, int) and size >= 2):
        raise ValueError(f"option size = {size!r} is out of range: need an integer >= 2")
    if delta_sign not in (1, -1):
        raise ValueError(f"option delta_sign = {delta_sign!r}: need 1 or -1")
    (w_lo, w_hi), (d_lo, d_hi) = PAPER["omega_range"], PAPER["delta_range"]
    delta = np.linspace(d_lo, d_hi, size)
    return {
        "omega": np.linspace(w_lo, w_hi, size),
        "delta": delta if delta_sign > 0 else -delta[::-1],
    }


def mirror_sweep(sweep: Mapping[str, Any]) -> dict[str, Any]:
    """A sweep over (ω, δ ≤ 0) seen at |δ|: δ → −δ, in increasing order, with its fields,
    so that a mirrored grid compares with the paper's δ > 0 (`compare_with_paper`)."""
    delta = sweep["coords"]["delta"]
    if np.any(np.asarray(delta) > 0):
        raise ValueError("mirror_sweep needs a sweep over delta <= 0 (the mirrored grid)")
    out = {**sweep, "coords": {**sweep["coords"], "delta": -np.asarray(delta)[::-1]}}
    for name, value in sweep.items():
        if name not in ("header", "coords") and np.ndim(value) == 2:
            out[name] = np.asarray(value)[:, ::-1]
    return out


def zero_crossing(delta: Float[ArrayLike, " D"], velocity: Float[ArrayLike, " D"]) -> float:
    """The first δ [rad] where `velocity` [m/s] turns from < 0 to ≥ 0 along increasing
    `delta`, linearly interpolated; NaN when it never does."""
    d, v = np.asarray(delta, float), np.asarray(velocity, float)
    for i in range(d.size - 1):
        a, b = v[i], v[i + 1]
        if np.isfinite(a) and np.isfinite(b) and a < 0 <= b:
            return float(d[i] + (d[i + 1] - d[i]) * (-a) / (b - a))
    return float("nan")


def _at(sweep: Mapping[str, Any], i: int | np.integer, j: int | np.integer) -> str:
    w, d = sweep["coords"]["omega"][i], sweep["coords"]["delta"][j]
    return f"(ω, δ) = ({w / math.pi:.3g}π, {d / math.pi:.3g}π)"


def compare_with_paper(
    sweep: Mapping[str, Any],
    nominal_velocity: float | None = None,
    nominal_cracks: int | None = None,
) -> list[dict]:
    """Rows `{"what", "paper", "ours", "agree"}` (texts, and a bool or None when the row
    is not a yes/no question) comparing a sweep over ("omega", "delta") with §4.1.
    A velocity agrees when it has the paper's sign and is within a factor 2 of it
    (nominal), an extreme when it lies at the paper's grid point, the sign change when
    every ω row crosses within 0.1 rad of δ = 0.74, the ω trend when the lowest ω is at
    least 1.5× faster (mean |v|) than the highest.
    Only scenes with status ok count. `nominal_velocity` [m/s] is the nominal scene's
    (from its own run, since the grid need not hold ω = 4π, δ = π/4)."""
    if list(sweep["header"]["axes"]) != ["omega", "delta"]:
        raise ValueError(
            f"compare_with_paper needs a sweep over (omega, delta), got axes "
            f"{sweep['header']['axes']}"
        )
    w, d = sweep["coords"]["omega"], sweep["coords"]["delta"]
    v = np.where(sweep["status"] == 0, sweep["mean_velocity"], np.nan)
    rows = []
    if nominal_velocity is not None:
        p = PAPER["nominal"]["mean_velocity"]
        cracks = "" if nominal_cracks is None else f", {nominal_cracks} cracks"
        rows.append(
            {
                "what": "nominal gait (4π, π/4)",
                "paper": f"{p:+.4f} m/s",
                "ours": f"{nominal_velocity:+.4f} m/s{cracks}",
                "agree": bool(0.5 <= nominal_velocity / p <= 2.0),
            }
        )  # same sign, ≤ 2×
    if np.isfinite(v).any():
        i, j = np.unravel_index(np.nanargmax(v), v.shape)
        p = PAPER["fastest_forward"]
        rows.append(
            {
                "what": "fastest forward",
                "paper": f"{p['mean_velocity']:+.4f} m/s at (3π, π/3)",
                "ours": (
                    f"{v[i, j]:+.4f} m/s at {_at(sweep, i, j)}"
                    if v[i, j] > 0
                    else f"none: the fastest is {v[i, j]:+.4f} m/s at {_at(sweep, i, j)}"
                ),
                "agree": bool(
                    v[i, j] > 0 and np.isclose(w[i], p["omega"]) and np.isclose(d[j], p["delta"])
                ),
            }
        )
        i, j = np.unravel_index(np.nanargmin(v), v.shape)
        p = PAPER["fastest_retreat"]
        rows.append(
            {
                "what": "fastest retreat",
                "paper": f"{p['mean_velocity']:+.4f} m/s at (3π, π/6)",
                "ours": (
                    f"{v[i, j]:+.4f} m/s at {_at(sweep, i, j)}"
                    if v[i, j] < 0
                    else f"none: the slowest is {v[i, j]:+.4f} m/s at {_at(sweep, i, j)}"
                ),
                "agree": bool(
                    v[i, j] < 0 and np.isclose(w[i], p["omega"]) and np.isclose(d[j], p["delta"])
                ),
            }
        )
        crossings = np.array([zero_crossing(d, row) for row in v])
        found = crossings[np.isfinite(crossings)]
        if np.all(v[np.isfinite(v)] < 0):
            ours = "all retreat"
        elif np.all(v[np.isfinite(v)] >= 0):
            ours = "all advance"
        elif found.size:
            ours = f"δ ≈ {found.min():.3g}–{found.max():.3g} ({found.size} of {len(w)} ω rows)"
        else:
            ours = "no sign change from retreat to advance along δ"
        rows.append(
            {
                "what": "retreat for δ below",
                "paper": f"≈ {PAPER['retreat_below_delta']}",
                "ours": ours,
                "agree": bool(found.size and np.all(np.abs(found - 0.74) < 0.1)),
            }
        )
        at5 = np.isclose(w, 5 * math.pi)
        if at5.any():
            row = v[np.flatnonzero(at5)[0]]
            ok = row[np.isfinite(row)]
            rows.append(
                {
                    "what": "speeds at ω = 5π",
                    "paper": "within ±0.005 m/s",
                    "ours": f"{ok.min():+.4f} … {ok.max():+.4f} m/s" if ok.size else "none ok",
                    "agree": bool(ok.size and np.all(np.abs(ok) <= 0.005)),
                }
            )
        lo, hi = np.nanmean(np.abs(v[np.argmin(w)])), np.nanmean(np.abs(v[np.argmax(w)]))
        rows.append(
            {
                "what": "lower ω faster (mean |v| at lowest / highest ω)",
                "paper": "yes, about 2×",
                "ours": f"{lo / hi:.2f}×",
                "agree": bool(lo / hi >= 0.75 * PAPER["slowdown_3pi_to_5pi"]),
            }
        )
    return rows


def format_comparison(rows: list[dict], markdown: bool = False) -> str:
    """The rows of `compare_with_paper` as an aligned text table, or a Markdown one."""
    mark = {True: "yes", False: "no", None: "–"}
    if markdown:

        def cell(text):
            return text.replace("|", "\\|")

        lines = ["| | paper | jaxworm | agree |", "|---|---|---|---|"]
        lines += [
            f"| {cell(r['what'])} | {cell(r['paper'])} | {cell(r['ours'])} | {mark[r['agree']]} |"
            for r in rows
        ]
        return "\n".join(lines)
    a = max([len(r["what"]) for r in rows] + [4])
    b = max([len(r["paper"]) for r in rows] + [5])
    c = max([len(r["ours"]) for r in rows] + [7])
    lines = [f"  {'':<{a}}  {'paper':<{b}}  {'jaxworm':<{c}}  agree"]
    lines += [
        f"  {r['what']:<{a}}  {r['paper']:<{b}}  {r['ours']:<{c}}  {mark[r['agree']]}" for r in rows
    ]
    return "\n".join(lines)


def format_readings(readings: Mapping[str, list[dict]], markdown: bool = False) -> str:
    """Several readings' `compare_with_paper` rows side by side, matched by their "what",
    in the order of the reading with the most rows (a row a reading lacks shows "–").
    Markdown: one table, the paper's column and then, per reading (the mapping's keys
    head the columns), our value and whether it agrees. Text: per row the paper's
    value, then one indented line per reading."""
    if not readings:
        raise ValueError("format_readings needs at least one reading")
    mark = {True: "yes", False: "no", None: "–"}
    names = list(readings)
    paper: dict[str, str] = {}
    for rows in sorted(readings.values(), key=len, reverse=True):  # the fullest's order
        for r in rows:
            paper.setdefault(r["what"], r["paper"])
    by_name = {n: {r["what"]: r for r in readings[n]} for n in names}

    def ours(name: str, what: str) -> tuple[str, str]:
        r = by_name[name].get(what)
        return ("–", "–") if r is None else (r["ours"], mark[r["agree"]])

    if markdown:

        def cell(text):
            return text.replace("|", "\\|")

        lines = [
            "| | paper | " + " | ".join(f"{cell(n)} | agree" for n in names) + " |",
            "|---|---|" + "---|---|" * len(names),
        ]
        for what, value in paper.items():
            cells = [c for n in names for c in ours(n, what)]
            lines.append(f"| {cell(what)} | {cell(value)} | " + " | ".join(map(cell, cells)) + " |")
        return "\n".join(lines)
    a = max(len(n) for n in names)
    b = max([len(ours(n, w)[0]) for n in names for w in paper] + [7])
    lines = []
    for what, value in paper.items():
        lines.append(f"  {what}: paper {value}")
        lines += [
            f"    {n:<{a}}  {ours(n, what)[0]:<{b}}  agree: {ours(n, what)[1]}" for n in names
        ]
    return "\n".join(lines)

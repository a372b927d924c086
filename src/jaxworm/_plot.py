"""Figures from results (kept out of the physics): the Fig.-2-like overview of one run,
and the Fig.-3-like map of mean velocity over a 2-D sweep.

Drawn on a bare `matplotlib.figure.Figure` with the Agg canvas, so it neither needs a
display nor changes the pyplot backend of the caller.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from jaxtyping import ArrayLike, Float

from ._soil import AbstractProfile, value_at
from ._validation import check_instance, check_range, show, to_float

if TYPE_CHECKING:
    from ._history import OptimiseResult
    from ._params import Params
    from ._result import Result

__all__ = [
    "period_average",
    "period_envelope",
    "plot_fig2",
    "plot_fig2_rows",
    "plot_fig3",
    "plot_fig3_panels",
    "plot_optimisation",
]

# Colours of the paper's Fig. 2.
_TIP, _HEAD, _BODY, _KI = "magenta", "tab:blue", "c", "tab:orange"


def _figure_path(path) -> Path:
    """The file a figure is written to: `path`, with `.png` added when it has no suffix
    (as matplotlib then writes), its folder made; a folder is refused by name."""
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"figure file {str(path)!r} is a folder: name a file, e.g. fig.png")
    if not path.suffix:
        path = path.with_suffix(".png")
    path.parent.mkdir(parents=True, exist_ok=True)
    return path


def plot_fig2(
    result: Result,
    params: Params,
    path: str | Path,
    *,
    title: str | None = None,
    average: bool = True,
    dpi: int = 150,
) -> Path:
    """Save a figure like the paper's Fig. 2 for one (unbatched) run with dense output.

    - Left: crack tip x_c (magenta), head x_1 (blue) and the other nodes (cyan) against
      time; on a twin axis the stress intensity factor K_I (orange, eq. 12) with the
      critical K_Ic and threshold K_Ith as black dashed lines.
    - Upper right: forces on the head node: stretching 𝒱_s (blue, eq. 20), friction ℱ_f
      (magenta, eq. 21) and back pressure F_p (red, eq. 16), signed as in eq. (17),
      m a = ℱ_f − 𝒱_s − F_p.
    - Lower right: kinetic energy (blue) and stretching energy (orange).

    With `average=True` (the default) and a periodic gait (`period()` not None, e.g.
    `TravellingWave`: T = 2π/ω), the right-hand panels draw each quantity's moving
    average over one gait period T (`period_average`, solid), over a faint band from
    its least to its greatest sample in each period (`period_envelope`). The elastic
    ringing (~1e4 rad/s) is far faster than the dense output samples it, so drawn raw
    it fills the panel with aliased spikes; its period average is what moves the body.
    With `average=False`, or when the horizon holds fewer than two periods, a period
    fewer than 4 samples or the output times are not evenly spaced, they draw the raw
    samples. The y ranges fit the 1-99 %
    quantiles of what is drawn as a line, so the start's jolt and the moments after a
    crack do not flatten the rest.

    `result` must come from `simulate(..., ts=...)` (it reads `result.trajectory`);
    `params` gives K_Ic, K_Ith and the gait's period. The format follows the suffix of
    `path` (png, pdf, ...). Returns the path written.

    ```python
    r = jw.simulate(p, 10.0, ts=jnp.linspace(0, 10.0, 2000))
    plot_fig2(r, p, "fig2.png")
    ```
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    _check_fig2_run(result, params, "plot_fig2")
    fig = Figure(figsize=(12, 6), layout="constrained")
    FigureCanvasAgg(fig)
    _draw_fig2(fig, result, params, title, average)
    path = _figure_path(path)
    fig.savefig(path, dpi=dpi)
    return path


def plot_fig2_rows(
    runs: Sequence[tuple[Result, Params, str]],
    path: str | Path,
    *,
    average: bool = True,
    dpi: int = 120,
) -> Path:
    """Save several Fig.-2 figures (`plot_fig2`) one above the other in one image, e.g. the
    same gait read two ways. `runs` holds `(result, params, heading)` per row; each row's
    title is its heading followed by the gait, mean velocity and crack count. Returns the
    path written.

    ```python
    plot_fig2_rows([(r, p, "MODEL.md"), (r_m, p_m, "mirrored")], "fig2.png")
    ```
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    if not runs:
        raise ValueError("plot_fig2_rows needs at least one run")
    for result, params, _ in runs:
        _check_fig2_run(result, params, "plot_fig2_rows")
    fig = Figure(figsize=(12, 6 * len(runs)), layout="constrained")
    FigureCanvasAgg(fig)
    rows = list(np.ravel(fig.subfigures(len(runs), 1, squeeze=False)))
    for row, (result, params, heading) in zip(rows, runs, strict=True):
        _draw_fig2(row, result, params, f"{heading}: {_fig2_title(result, params)}", average)
    path = _figure_path(path)
    fig.savefig(path, dpi=dpi)
    return path


def _check_fig2_run(result: Result, params: Params, who: str) -> None:
    tr = result.trajectory
    if tr is None:
        raise ValueError(f"{who} needs dense output: call simulate(..., ts=...)")
    shape = np.shape(tr.x)
    if len(shape) != 2:
        raise ValueError(f"{who} draws one run per figure; got positions of shape {shape}")
    if shape[1] != params.body.N:
        raise ValueError(
            f"{who}: the result has {shape[1]} nodes and params N = {params.body.N}: pass "
            "the parameters the result was simulated with"
        )


def _fig2_title(result: Result, params: Params) -> str:
    """The gait's A, ω and δ, the mean velocity, the crack count and a status not ok."""
    g = params.gait
    parts = []
    for name, unit in (("A", "m/s"), ("omega", "rad/s"), ("delta", "rad")):
        if hasattr(g, name):
            parts.append(f"{name} = {float(np.asarray(getattr(g, name))):.4g} {unit}")
    v = float(np.asarray(result.mean_velocity))
    title = ", ".join(
        parts + [f"mean velocity {v:.3g} m/s", f"{int(np.asarray(result.n_cracks))} cracks"]
    )
    status = str(result.status_name)
    return title if status == "ok" else f"{title}, status {status}"


def _draw_fig2(fig, result: Result, params: Params, title: str | None, average: bool) -> None:
    """The three panels of `plot_fig2` on `fig` (a Figure or a SubFigure)."""
    tr = result.trajectory
    assert tr is not None
    t = np.asarray(tr.ts)
    x = np.asarray(tr.x)

    grid = fig.add_gridspec(2, 2, width_ratios=(1.3, 1))
    ax = fig.add_subplot(grid[:, 0])
    ax_f = fig.add_subplot(grid[0, 1])
    ax_e = fig.add_subplot(grid[1, 1], sharex=ax_f)

    # Left: positions and K_I.
    ax.plot(t, x[:, 1:], color=_BODY, lw=0.7)
    ax.plot([], [], color=_BODY, lw=0.7, label="body nodes $x_k$")
    ax.plot(t, x[:, 0], color=_HEAD, lw=1.2, label="head $x_1$")
    ax.plot(t, np.asarray(tr.x_c), color=_TIP, lw=1.5, label="crack tip $x_c$")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("position [m]")
    ax.set_xlim(t[0], t[-1])  # the full horizon, so a run that stopped early shows it
    ax_k = ax.twinx()
    ax_k.plot(t, np.asarray(tr.K_I), color=_KI, lw=0.8, label="$K_I$")
    soil = params.soil
    if isinstance(soil.K_Ic, AbstractProfile) or isinstance(soil.K_Ith, AbstractProfile):
        # Soil that varies: the constants at the crack tip, a step at each crack.
        xc = np.asarray(tr.x_c)
        kc = np.broadcast_to(np.asarray(value_at(soil.K_Ic, xc)), xc.shape)
        kth = np.broadcast_to(np.asarray(value_at(soil.K_Ith, xc)), xc.shape)
        ax_k.plot(t, kc, color="k", ls="--", lw=0.8, label="$K_{Ic}(x_c)$")
        ax_k.plot(t, kth, color="k", ls=":", lw=0.8, label="$K_{Ith}(x_c)$")
        K_Ic = float(np.nanmax(kc))
    else:
        K_Ic = float(np.asarray(soil.K_Ic))
        K_Ith = float(np.asarray(soil.K_Ith))
        ax_k.axhline(K_Ic, color="k", ls="--", lw=0.8, label=f"$K_{{Ic}}$ = {K_Ic:g}")
        ax_k.axhline(K_Ith, color="k", ls=":", lw=0.8, label=f"$K_{{Ith}}$ = {K_Ith:g}")
    ax_k.set_ylabel(r"stress intensity factor $K_I$ [Pa$\sqrt{\mathrm{m}}$]", color=_KI)
    ax_k.tick_params(axis="y", colors=_KI)
    k = np.asarray(tr.K_I)
    k = k[np.isfinite(k)]
    top = max(K_Ic, float(k.max()) if k.size else K_Ic)
    ax_k.set_ylim(0.0, 1.15 * top)
    lines = ax.get_legend_handles_labels()
    lines_k = ax_k.get_legend_handles_labels()
    ax.legend(lines[0] + lines_k[0], lines[1] + lines_k[1], loc="best", fontsize=8)

    # Right: forces on the head node and energies, period-averaged (or raw).
    if not isinstance(average, bool):
        raise ValueError(f"option average = {average!r}: need True or False")
    period = params.gait.period() if average else None
    period = None if period is None else float(np.asarray(period))
    if period is not None and not _fits_periods(t, period):
        period = None
    forces = (
        (np.asarray(tr.stretching)[:, 0], "tab:blue", r"stretching $\mathcal{V}_s$"),
        (np.asarray(tr.friction)[:, 0], "magenta", r"friction $\mathcal{F}_f$"),
        (np.asarray(tr.back_pressure), "red", "back pressure $F_p$"),
    )
    energies = (
        (np.asarray(tr.kinetic), "tab:blue", "kinetic"),
        (np.asarray(tr.stretching_energy), "tab:orange", "stretching"),
    )
    for axis, series in ((ax_f, forces), (ax_e, energies)):
        if period is None:
            for y, colour, label in series:
                axis.plot(t, y, color=colour, lw=0.8, label=label)
        else:
            for y, colour, label in series:
                edges, low, high = period_envelope(t, y, period)
                axis.stairs(high, edges, baseline=low, fill=True, color=colour, alpha=0.1, lw=0)
                tm, ym = period_average(t, y, period)
                axis.plot(tm, ym, color=colour, lw=1.2, label=label)
    if period is None:
        _robust_ylim(ax_f, *(y for y, _, _ in forces))
    else:
        _robust_ylim(ax_f, *(period_average(t, y, period)[1] for y, _, _ in forces))
        _robust_ylim(ax_e, *(period_average(t, y, period)[1] for y, _, _ in energies))
        ax_f.set_title(
            f"means over one gait period (T = {period:.3g} s); bands: range per period",
            fontsize=8,
            loc="right",
        )
    ax_f.set_ylabel("force on head [N]")
    ax_f.set_xlim(t[0], t[-1])
    ax_f.legend(
        loc="center right",
        fontsize=8,
        title=r"$m\ddot{x}_1 = \mathcal{F}_f - \mathcal{V}_s - F_p$",
        title_fontsize=8,
    )
    ax_f.tick_params(labelbottom=False)
    ax_e.set_ylabel("energy [J]")
    ax_e.set_xlabel("time [s]")
    ax_e.legend(loc="upper right", fontsize=8)

    fig.suptitle(_fig2_title(result, params) if title is None else title, fontsize=10)


def _evenly_spaced(t) -> bool:
    """Whether the increasing times `t` are evenly spaced (to 1e-6 of their step)."""
    steps = np.diff(np.asarray(t, float))
    return bool(steps.size and steps.min() > 0 and np.ptp(steps) <= 1e-6 * steps.mean())


def _check_period(period) -> None:
    check_range("period", to_float(period), lambda v: v > 0, "> 0 [s]", kind="option")


def _fits_periods(t, period: float) -> bool:
    """Whether the times `t`, evenly spaced, span at least two periods with at least 4
    samples in each (so that a moving average over one period means something)."""
    if not (np.isfinite(period) and period > 0) or t.size < 2 or not _evenly_spaced(t):
        return False
    span = float(t[-1] - t[0])
    return span >= 2 * period and t.size * period / span >= 4


def period_average(
    t: Float[ArrayLike, " T"], y: Float[ArrayLike, " T"], period: float
) -> tuple[Float[np.ndarray, " M"], Float[np.ndarray, " M"]]:
    """The moving average of samples `y` at evenly spaced times `t` over a window of one
    `period` [s], centred: `(tm, ym)`, with `tm` the window centres, i.e. `t` less half a
    period at each end (none when the samples span less than one period). A window
    holding a non-finite sample is NaN."""
    t, y = np.asarray(t, float), np.asarray(y, float)
    _check_period(period)
    if t.ndim != 1 or t.shape != y.shape or t.size < 2 or not _evenly_spaced(t):
        raise ValueError(
            "period_average needs samples y at evenly spaced, increasing times t (two or "
            f"more, one per sample); got t of shape {t.shape}, y of shape {y.shape}"
        )
    dt = (t[-1] - t[0]) / (t.size - 1)
    n = max(1, int(round(period / dt)))
    if n > t.size:  # no whole window (it was cut to the samples: a part-period mean)
        return np.empty(0), np.empty(0)
    kernel = np.full(n, 1.0 / n)
    ym = np.convolve(y, kernel, mode="valid")
    tm = np.convolve(t, kernel, mode="valid")
    return tm, ym


def period_envelope(
    t: Float[ArrayLike, " T"], y: Float[ArrayLike, " T"], period: float
) -> tuple[Float[np.ndarray, " P+1"], Float[np.ndarray, " P"], Float[np.ndarray, " P"]]:
    """The least and greatest sample of `y` in each whole period [t0 + iT, t0 + (i+1)T)
    of the times `t`: `(edges, low, high)`, with the P + 1 period edges [s]; non-finite
    samples are left out (a period with none finite is NaN)."""
    t, y = np.asarray(t, float), np.asarray(y, float)
    _check_period(period)
    if t.ndim != 1 or t.shape != y.shape or t.size < 1:
        raise ValueError(
            f"period_envelope needs one time per sample; got t of shape {t.shape}, y of "
            f"shape {y.shape}"
        )
    count = int(np.floor((t[-1] - t[0]) / period + 1e-9))
    edges = t[0] + period * np.arange(count + 1)
    index = np.clip(np.floor((t - t[0]) / period + 1e-9).astype(int), 0, None)
    low, high = np.full(count, np.nan), np.full(count, np.nan)
    for i in range(count):
        part = y[(index == i) & np.isfinite(y)]
        if part.size:
            low[i], high[i] = part.min(), part.max()
    return edges, low, high


def _robust_ylim(ax, *series, lo: float = 1.0, hi: float = 99.0) -> None:
    """Fit the y range to the 1-99 % quantiles, so that brief elastic ringing (at the
    start or after a crack) does not flatten the friction and back-pressure curves."""
    values = np.concatenate([np.ravel(s) for s in series])
    values = values[np.isfinite(values)]
    if values.size == 0:
        return
    a, b = np.percentile(values, [lo, hi])
    a, b = min(a, 0.0), max(b, 0.0)
    if b > a:
        pad = 0.1 * (b - a)
        ax.set_ylim(a - pad, b + pad)


def _check_sweep(function: str, sweep, two: bool = True) -> None:
    """Refuse anything but a sweep (`jaxworm.sweep` / `load_sweep`), over two parameters
    unless `two` is False, naming `function`."""
    keys = ("header", "coords", "mean_velocity", "status")
    if not (
        isinstance(sweep, Mapping)
        and all(k in sweep for k in keys)
        and isinstance(sweep["header"], Mapping)
        and "axes" in sweep["header"]
    ):
        raise TypeError(
            f"{function}: {show(sweep)} ({type(sweep).__name__}) is not a sweep: need the "
            "result of jaxworm.sweep or jaxworm.load_sweep"
        )
    axes = sweep["header"]["axes"]
    if two and len(axes) != 2:
        raise ValueError(f"{function} needs a sweep over 2 parameters, got {len(axes)}: {axes}")


def plot_fig3(
    sweep: Mapping[str, Any],
    path: str | Path,
    *,
    mark: dict[str, float] | None = None,
    dpi: int = 150,
) -> Path:
    """Save a heatmap of mean velocity over a two-axis sweep (`jaxworm.sweep` /
    `load_sweep`), like the paper's Fig. 3: a diverging map centred on zero, the
    zero-velocity contour in black, scenes that did not end `ok` grey with a cross, and
    `mark` (default: the nominal gait ω = 4π, δ = π/4, when both axes are ω and δ) as a
    white star. Scenes an interrupted sweep has not solved yet are left blank, and the
    title says how many it holds. Returns the path written.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    _check_sweep("plot_fig3", sweep)
    fig = Figure(figsize=(6.0, 4.6))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    _draw_velocity_map(fig, ax, sweep, mark)
    ax.set_title(f"mean velocity, t1 = {sweep['header']['t1']:g} s{solved_note(sweep)}")
    path = _figure_path(path)
    fig.savefig(path, dpi=dpi, bbox_inches="tight")
    return path


def plot_fig3_panels(
    sweeps: Sequence[Mapping[str, Any]],
    path: str | Path,
    *,
    titles: Sequence[str] | None = None,
    marks: Sequence[dict[str, float] | None] | None = None,
    dpi: int = 150,
) -> Path:
    """Save the Fig.-3 heatmaps (`plot_fig3`) of several two-axis sweeps side by side,
    on one diverging colour scale (± the greatest |mean velocity| of all of them), e.g.
    the paper's window read two ways. `titles` (default: none) heads each panel; `marks`
    gives each panel's white star (`plot_fig3`'s `mark`; default: its own default).
    Returns the path written.

    ```python
    s, m = jw.sweep(paper_grid(7)), jw.sweep(paper_grid(7, delta_sign=-1))
    plot_fig3_panels([s, m], "fig3.png", titles=["MODEL.md", "mirrored"])
    ```
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    n = len(sweeps)
    if n == 0:
        raise ValueError("plot_fig3_panels needs at least one sweep")
    for option, values in (("titles", titles), ("marks", marks)):
        if values is not None and len(values) != n:
            raise ValueError(f"option {option} has {len(values)} entries: need one per sweep ({n})")
    for sweep in sweeps:
        _check_sweep("plot_fig3_panels", sweep)
    speeds = [
        np.abs(np.where(_done(s) & (s["status"] == 0), s["mean_velocity"], np.nan)).ravel()
        for s in sweeps
    ]
    speeds = np.concatenate(speeds)
    speeds = speeds[np.isfinite(speeds)]
    lim = float(speeds.max()) if speeds.size and speeds.max() > 0 else None
    fig = Figure(figsize=(6.0 * n, 4.6), layout="constrained")
    FigureCanvasAgg(fig)
    for k, (ax, sweep) in enumerate(zip(fig.subplots(1, n, squeeze=False)[0], sweeps, strict=True)):
        _draw_velocity_map(fig, ax, sweep, None if marks is None else marks[k], lim=lim)
        head = f"mean velocity, t1 = {sweep['header']['t1']:g} s{solved_note(sweep)}"
        ax.set_title(head if titles is None else f"{titles[k]}\n{head}", fontsize=10)
    path = _figure_path(path)
    fig.savefig(path, dpi=dpi)
    return path


#: Parameters drawn in units of π.
_IN_PI = ("omega", "delta")


def _shown(name, values, unit=""):
    """Values on a plot axis (ω and δ in units of π) and the axis label."""
    f, label = (np.pi, "π ") if name in _IN_PI else (1.0, "")
    text = f"{label}{unit}".strip()
    return np.asarray(values, dtype=float) / f, f"{name} [{text}]" if text else name


def _increasing(x, y, *grids) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
    """The axes `x` and `y` of a two-axis sweep sorted increasing, and each of `grids`
    (shaped (x, y), the sweep's order) reordered to match and transposed to (y, x), as
    `pcolormesh(x, y, grid)` takes it."""
    ix, iy = np.argsort(np.asarray(x), kind="stable"), np.argsort(np.asarray(y), kind="stable")
    return (
        np.asarray(x)[ix],
        np.asarray(y)[iy],
        [np.asarray(g)[np.ix_(ix, iy)].T for g in grids],
    )


def _cell_edges(c) -> np.ndarray:
    """Edges of the cells centred on the increasing values `c`: halfway between
    neighbours, the outer ones as far out as the inner; ±5 % of a lone value (±0.5 at 0)."""
    c = np.asarray(c, dtype=float)
    if c.size == 1:
        h = 0.05 * abs(c[0]) or 0.5
        return np.array([c[0] - h, c[0] + h])
    mid = 0.5 * (c[1:] + c[:-1])
    return np.concatenate([[2 * c[0] - mid[0]], mid, [2 * c[-1] - mid[-1]]])


def _done(sweep: Mapping[str, Any]) -> np.ndarray:
    """The mask of the sweep's solved scenes (all of them for a sweep without one)."""
    done = sweep.get("done")
    return np.ones(np.shape(sweep["status"]), bool) if done is None else np.asarray(done, bool)


def solved_note(sweep: Mapping[str, Any]) -> str:
    """'' for a finished sweep; for an interrupted one, how many scenes it holds."""
    done = _done(sweep)
    return "" if done.all() else f" ({int(done.sum())} of {done.size} scenes solved)"


def _draw_velocity_map(
    fig,
    ax,
    sweep: Mapping[str, Any],
    mark: dict | None,
    diverging: bool = True,
    lim: float | None = None,
) -> None:
    """The Fig.-3 heatmap of a two-axis sweep on `ax` (see `plot_fig3`); with
    `diverging=False`, a sequential map over the sweep's own range (for a region where
    the velocity keeps one sign). `lim` [m/s]: the diverging map's ±range (default: the
    sweep's greatest |v|)."""
    from matplotlib.colors import ListedColormap, TwoSlopeNorm

    xname, yname = sweep["header"]["axes"]
    # pcolormesh and contour need increasing coordinates: a grid given in any order is
    # drawn with each axis sorted and the cells reordered with it.
    done = _done(sweep)
    x, y, (v, bad) = _increasing(
        sweep["coords"][xname],
        sweep["coords"][yname],
        np.where(done & (sweep["status"] == 0), sweep["mean_velocity"], np.nan),
        done & (np.asarray(sweep["status"]) != 0),  # a scene not solved yet stays blank
    )
    units = sweep["header"]["units"]
    xs, xl = _shown(xname, x, units.get(xname, ""))
    ys, yl = _shown(yname, y, units.get(yname, ""))
    finite = v[np.isfinite(v)]
    if lim is None:
        lim = float(np.max(np.abs(finite))) if finite.size else 1.0
    if diverging or not finite.size:
        norm, cmap = TwoSlopeNorm(vcenter=0.0, vmin=-lim or -1.0, vmax=lim or 1.0), "RdBu_r"
    else:
        from matplotlib.colors import Normalize

        norm, cmap = Normalize(vmin=float(finite.min()), vmax=float(finite.max())), "viridis"
    # Cell edges halfway between the values (an axis of one value: ±5 % around it, which
    # "nearest" shading would draw as an empty cell).
    xe, ye = _cell_edges(xs), _cell_edges(ys)
    mesh = ax.pcolormesh(xe, ye, v, cmap=cmap, norm=norm, shading="flat")
    fig.colorbar(mesh, ax=ax, label="mean velocity [m/s]")
    if finite.size and finite.min() < 0 < finite.max() and min(v.shape) > 1:
        ax.contour(xs, ys, v, levels=[0.0], colors="k", linewidths=1.2)
    if bad.any():  # grey with a cross, so a failed scene never reads as zero velocity
        ax.pcolormesh(
            xe,
            ye,
            np.ma.masked_where(~bad, np.ones(bad.shape)),
            shading="flat",
            cmap=ListedColormap(["0.6"]),
        )
        yy, xx = np.nonzero(bad)
        ax.plot(xs[xx], ys[yy], "kx", ms=6, ls="none")
    if mark is None and {xname, yname} == {"omega", "delta"}:
        mark = {"omega": 4 * np.pi, "delta": np.pi / 4}
        inside = all(min(sweep["coords"][n]) <= mark[n] <= max(sweep["coords"][n]) for n in mark)
        mark = mark if inside else None  # e.g. a mirrored grid, delta < 0
    if mark:
        if not isinstance(mark, Mapping) or not {xname, yname} <= set(mark):
            raise ValueError(
                f"option mark = {mark!r}: need a value for each axis of the sweep, "
                f"{xname!r} and {yname!r}"
            )
        mx, _ = _shown(xname, [mark[xname]])
        my, _ = _shown(yname, [mark[yname]])
        ax.plot(mx, my, marker="*", ms=14, color="white", mec="k")
    ax.set_xlabel(xl)
    ax.set_ylabel(yl)


def optimisation_axes(
    names: Sequence[str],
    sweep: Mapping[str, Any] | None = None,
    axes: Sequence[str] | None = None,
) -> tuple[str, str | None]:
    """The two parameters `plot_optimisation` draws an optimisation of `names` in
    (`axes`, default the first two; the second None for one parameter, drawn against
    the step); `ValueError` when an axis is not optimised or `sweep`'s axes are not
    those two. Known before the optimisation runs (the command line checks it then)."""
    xname: str
    yname: str | None
    if axes is not None:
        xname, yname = axes
    elif len(names) >= 2:
        xname, yname = names[0], names[1]
    else:
        xname, yname = names[0], None
    for n in (xname, yname):
        if n is not None and n not in names:
            raise ValueError(
                f"plot_optimisation: axis {n!r} is not an optimised parameter ({', '.join(names)})"
            )
    if sweep is not None:
        _check_sweep("plot_optimisation", sweep, two=False)  # the axes' own check below
        if yname is None or list(sweep["header"]["axes"]) not in ([xname, yname], [yname, xname]):
            raise ValueError(
                f"plot_optimisation: the sweep's axes {sweep['header']['axes']} "
                f"are not the plotted parameters ({xname}, {yname})"
            )
    return xname, yname


def heatmap_differences(history: Mapping[str, Any], sweep: Mapping[str, Any]) -> list[str]:
    """What makes a sweep (its header `sweep`) another scene than the optimisation (its
    header `history`) drawn over it: its horizon, or a fixed parameter (one neither
    optimised nor swept) of another value; each as "name (sweep ..., optimisation ...)".
    Keys a header lacks are not compared."""
    out = []
    for key in ("t1", "horizon"):
        a, b = sweep.get(key), history.get(key)
        if a is not None and b is not None and a != b:
            out.append(f"{key} (sweep {a}, optimisation {b})")
    a, b = sweep.get("base_parameters") or {}, history.get("base_parameters") or {}
    free = set(sweep.get("axes", ())) | set(history.get("names", ()))
    for name in sorted((set(a) & set(b)) - free):
        if a[name] != b[name]:
            out.append(f"{name} (sweep {a[name]}, optimisation {b[name]})")
    return out


def plot_optimisation(
    history: OptimiseResult,
    path: str | Path,
    *,
    sweep: Mapping[str, Any] | None = None,
    axes: Sequence[str] | None = None,
    dpi: int = 150,
) -> Path:
    """Save the paths of an optimisation (`jaxworm.optimise` / `load_optimisation`).

    - Left: each start's path through two of its parameters (`axes`, default the first
      two; ω and δ in units of π), a circle at its start and a cross at its last point,
      the best point as a white star; over the Fig.-3-like heatmap of `sweep` (a
      `jaxworm.sweep` / `load_sweep` dict over the same two parameters) when given,
      otherwise over the bounds' box. A sweep of another scene than the optimisation's
      (`heatmap_differences`: another t1, horizon or fixed parameter) is drawn with a
      `RuntimeWarning` and the title says so: its map is not the landscape the paths
      climbed.
    - Right: the best objective value so far against the number of value-and-gradient
      evaluations (all starts counted), and each start's value per step.

    Returns the path written.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from ._history import OptimiseResult

    check_instance("history", history, OptimiseResult, "jaxworm.load_optimisation(path)")
    names = history.names
    xname, yname = optimisation_axes(names, sweep, axes)
    done = history.steps_done
    theta = history.theta[:done]
    fig = Figure(figsize=(11.0, 4.6), layout="constrained")
    FigureCanvasAgg(fig)
    ax, ax_v = fig.subplots(1, 2, width_ratios=(1.25, 1))
    other = []
    if sweep is not None:
        if yname is not None and list(sweep["header"]["axes"]) == [yname, xname]:
            xname, yname = yname, xname
        _draw_velocity_map(fig, ax, sweep, mark={}, diverging=False)
        other = heatmap_differences(history.header, sweep["header"])
        if other:
            warnings.warn(
                f"plot_optimisation: the heatmap's sweep is another scene than the "
                f"optimisation's ({'; '.join(other)} differ): it is not the landscape "
                "the paths climbed",
                RuntimeWarning,
                stacklevel=2,
            )
    b = history.bounds
    ix = names.index(xname)
    xs = _shown(xname, theta[:, :, ix])[0]
    if yname is None:  # one parameter: its value against the step
        ys, ylabel = np.broadcast_to(np.arange(done)[:, None], xs.shape), "step"
    else:
        iy = names.index(yname)
        ys, ylabel = _shown(yname, theta[:, :, iy])
    colours = [f"C{k % 10}" for k in range(theta.shape[1])]
    for k, c in enumerate(colours):
        ax.plot(xs[:, k], ys[:, k], "-", color=c, lw=1.2, marker=".", ms=3)
        ax.plot(xs[0, k], ys[0, k], "o", color=c, mec="k", ms=6)
        ax.plot(xs[-1, k], ys[-1, k], "x", color="k", ms=6)
    try:
        step, start = history.best_index
        ax.plot(
            xs[step, start],
            ys[step, start],
            marker="*",
            ms=15,
            color="white",
            mec="k",
            label=f"best {history.best_value:.5g} {history.header['unit']}",
        )
        ax.legend(loc="best", fontsize=8)
    except ValueError:
        pass
    if sweep is None:
        ax.set_xlim(*_shown(xname, b[xname])[0])
        if yname is not None:
            ax.set_ylim(*_shown(yname, b[yname])[0])
        ax.set_xlabel(_shown(xname, [], "")[1])
        ax.set_ylabel(ylabel if yname is None else _shown(yname, [], "")[1])
    ax.set_title(
        f"{theta.shape[1]} starts, {done} steps ({history.header['objective']}, "
        f"t1 = {history.header.get('t1', float('nan')):g} s)"
        + ("" if not other else f"\nheatmap of another scene: {', '.join(other)}"),
        fontsize=9,
    )

    n = theta.shape[1]
    evals = n * (np.arange(done) + 1)
    for k, c in enumerate(colours):
        v = np.where(history.status[:done, k] == 0, history.value[:done, k], np.nan)
        ax_v.plot(evals, v, ".", color=c, ms=4)
    ax_v.plot(evals, history.best_so_far(), "k-", lw=1.5, label="best so far")
    ax_v.set_xlabel("value-and-gradient evaluations (all starts)")
    ax_v.set_ylabel(f"{history.header['objective']} [{history.header['unit']}]")
    ax_v.legend(loc="best", fontsize=8)
    path = _figure_path(path)
    fig.savefig(path, dpi=dpi)
    return path

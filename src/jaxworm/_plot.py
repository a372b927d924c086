"""Figures from results (kept out of the physics): the Fig.-2-like overview of one run,
and the Fig.-3-like map of mean velocity over a 2-D sweep.

Drawn on a bare `matplotlib.figure.Figure` with the Agg canvas, so it neither needs a
display nor changes the pyplot backend of the caller.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from ._history import OptimiseResult
    from ._params import Params
    from ._result import Result

__all__ = ["plot_fig2", "plot_fig3", "plot_optimisation"]

# Colours of the paper's Fig. 2.
_TIP, _HEAD, _BODY, _KI = "magenta", "tab:blue", "c", "tab:orange"


def plot_fig2(
    result: Result,
    params: Params,
    path: str | Path,
    *,
    title: str | None = None,
    dpi: int = 150,
) -> Path:
    """Save a figure like the paper's Fig. 2 for one (unbatched) run with dense output.

    - Left: crack tip x_c (magenta), head x_1 (blue) and the other nodes (cyan) against
      time; on a twin axis the stress intensity factor K_I (orange, eq. 12) with the
      critical K_Ic and threshold K_Ith as black dashed lines.
    - Upper right: forces on the head node: stretching (blue), friction (magenta) and
      back pressure (red, eq. 16); the y range fits the 1-99 % quantiles, so brief
      elastic ringing does not flatten the other curves.
    - Lower right: kinetic energy (blue) and stretching energy (orange).

    `result` must come from `simulate(..., ts=...)` (it reads `result.trajectory`);
    `params` gives K_Ic and K_Ith. The format follows the suffix of `path` (png, pdf, ...).
    Returns the path written.

    ```python
    r = jw.simulate(p, 10.0, ts=jnp.linspace(0, 10.0, 2000))
    plot_fig2(r, p, "fig2.png")
    ```
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    tr = result.trajectory
    if tr is None:
        raise ValueError("plot_fig2 needs dense output: call simulate(..., ts=...)")
    t = np.asarray(tr.ts)
    x = np.asarray(tr.x)
    if x.ndim != 2:
        raise ValueError(f"plot_fig2 draws one run; got positions of shape {x.shape}")

    fig = Figure(figsize=(12, 6), layout="constrained")
    FigureCanvasAgg(fig)
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
    K_Ic = float(np.asarray(params.soil.K_Ic))
    K_Ith = float(np.asarray(params.soil.K_Ith))
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

    # Upper right: forces on the head node.
    ax_f.plot(t, np.asarray(tr.stretching)[:, 0], color="tab:blue", lw=0.8, label="stretching")
    ax_f.plot(t, np.asarray(tr.friction)[:, 0], color="magenta", lw=0.8, label="friction")
    ax_f.plot(t, np.asarray(tr.back_pressure), color="red", lw=0.8, label="back pressure")
    _robust_ylim(
        ax_f,
        np.asarray(tr.stretching)[:, 0],
        np.asarray(tr.friction)[:, 0],
        np.asarray(tr.back_pressure),
    )
    ax_f.set_ylabel("force on head [N]")
    ax_f.set_xlim(t[0], t[-1])
    ax_f.legend(loc="upper right", fontsize=8)
    ax_f.tick_params(labelbottom=False)

    # Lower right: energies.
    ax_e.plot(t, np.asarray(tr.kinetic), color="tab:blue", lw=0.8, label="kinetic")
    ax_e.plot(t, np.asarray(tr.stretching_energy), color="tab:orange", lw=0.8, label="stretching")
    ax_e.set_xlabel("time [s]")
    ax_e.set_ylabel("energy [J]")
    ax_e.legend(loc="upper right", fontsize=8)

    if title is None:
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
        if status != "ok":
            title += f", status {status}"
    fig.suptitle(title, fontsize=10)

    path = Path(path)
    fig.savefig(path, dpi=dpi)
    return path


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
    white star. Returns the path written.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    axes = sweep["header"]["axes"]
    if len(axes) != 2:
        raise ValueError(f"plot_fig3 needs a sweep over 2 parameters, got {len(axes)}: {axes}")
    fig = Figure(figsize=(6.0, 4.6))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    _draw_velocity_map(fig, ax, sweep, mark)
    ax.set_title(f"mean velocity, t1 = {sweep['header']['t1']:g} s")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi, bbox_inches="tight")
    return path


#: Parameters drawn in units of π.
_IN_PI = ("omega", "delta")


def _shown(name, values, unit=""):
    """Values on a plot axis (ω and δ in units of π) and the axis label."""
    f, label = (np.pi, "π ") if name in _IN_PI else (1.0, "")
    text = f"{label}{unit}".strip()
    return np.asarray(values, dtype=float) / f, f"{name} [{text}]" if text else name


def _draw_velocity_map(
    fig, ax, sweep: Mapping[str, Any], mark: dict | None, diverging: bool = True
) -> None:
    """The Fig.-3 heatmap of a two-axis sweep on `ax` (see `plot_fig3`); with
    `diverging=False`, a sequential map over the sweep's own range (for a region where
    the velocity keeps one sign)."""
    from matplotlib.colors import ListedColormap, TwoSlopeNorm

    xname, yname = sweep["header"]["axes"]
    x, y = sweep["coords"][xname], sweep["coords"][yname]
    v = np.where(sweep["status"] == 0, sweep["mean_velocity"], np.nan).T  # (y, x)
    units = sweep["header"]["units"]
    xs, xl = _shown(xname, x, units.get(xname, ""))
    ys, yl = _shown(yname, y, units.get(yname, ""))
    finite = v[np.isfinite(v)]
    lim = float(np.max(np.abs(finite))) if finite.size else 1.0
    if diverging or not finite.size:
        norm, cmap = TwoSlopeNorm(vcenter=0.0, vmin=-lim or -1.0, vmax=lim or 1.0), "RdBu_r"
    else:
        from matplotlib.colors import Normalize

        norm, cmap = Normalize(vmin=float(finite.min()), vmax=float(finite.max())), "viridis"
    mesh = ax.pcolormesh(xs, ys, v, cmap=cmap, norm=norm, shading="nearest")
    fig.colorbar(mesh, ax=ax, label="mean velocity [m/s]")
    if finite.size and finite.min() < 0 < finite.max() and min(v.shape) > 1:
        ax.contour(xs, ys, v, levels=[0.0], colors="k", linewidths=1.2)
    bad = sweep["status"].T != 0
    if bad.any():  # grey with a cross, so a failed scene never reads as zero velocity
        ax.pcolormesh(
            xs,
            ys,
            np.ma.masked_where(~bad, np.ones(bad.shape)),
            shading="nearest",
            cmap=ListedColormap(["0.6"]),
        )
        yy, xx = np.nonzero(bad)
        ax.plot(xs[xx], ys[yy], "kx", ms=6, ls="none")
    if mark is None and {xname, yname} == {"omega", "delta"}:
        mark = {"omega": 4 * np.pi, "delta": np.pi / 4}
        inside = all(min(sweep["coords"][n]) <= mark[n] <= max(sweep["coords"][n]) for n in mark)
        mark = mark if inside else None  # e.g. a mirrored grid, delta < 0
    if mark:
        mx, _ = _shown(xname, [mark[xname]])
        my, _ = _shown(yname, [mark[yname]])
        ax.plot(mx, my, marker="*", ms=14, color="white", mec="k")
    ax.set_xlabel(xl)
    ax.set_ylabel(yl)


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
      otherwise over the bounds' box.
    - Right: the best objective value so far against the number of value-and-gradient
      evaluations (all starts counted), and each start's value per step.

    Returns the path written.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    names = history.names
    xname: str
    yname: str | None  # None: one parameter, drawn against the step
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
    done = history.steps_done
    theta = history.theta[:done]
    fig = Figure(figsize=(11.0, 4.6), layout="constrained")
    FigureCanvasAgg(fig)
    ax, ax_v = fig.subplots(1, 2, width_ratios=(1.25, 1))
    if sweep is not None:
        if yname is None or list(sweep["header"]["axes"]) not in ([xname, yname], [yname, xname]):
            raise ValueError(
                f"plot_optimisation: the sweep's axes {sweep['header']['axes']} "
                f"are not the plotted parameters ({xname}, {yname})"
            )
        if list(sweep["header"]["axes"]) == [yname, xname]:
            xname, yname = yname, xname
        _draw_velocity_map(fig, ax, sweep, mark={}, diverging=False)
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
        f"t1 = {history.header.get('t1', float('nan')):g} s)",
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
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    return path

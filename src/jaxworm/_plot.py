"""Figures from results (kept out of the physics): the Fig.-2-like overview of one run,
and the Fig.-3-like map of mean velocity over a 2-D sweep.

Drawn on a bare `matplotlib.figure.Figure` with the Agg canvas, so it neither needs a
display nor changes the pyplot backend of the caller.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["plot_fig2", "plot_fig3"]

# Colours of the paper's Fig. 2.
_TIP, _HEAD, _BODY, _KI = "magenta", "tab:blue", "c", "tab:orange"


def plot_fig2(result, params, path, *, title: str | None = None, dpi: int = 150) -> Path:
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
    _robust_ylim(ax_f, np.asarray(tr.stretching)[:, 0], np.asarray(tr.friction)[:, 0],
                 np.asarray(tr.back_pressure))
    ax_f.set_ylabel("force on head [N]")
    ax_f.set_xlim(t[0], t[-1])
    ax_f.legend(loc="upper right", fontsize=8)
    ax_f.tick_params(labelbottom=False)

    # Lower right: energies.
    ax_e.plot(t, np.asarray(tr.kinetic), color="tab:blue", lw=0.8, label="kinetic")
    ax_e.plot(t, np.asarray(tr.stretching_energy), color="tab:orange", lw=0.8,
              label="stretching")
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
        title = ", ".join(parts + [f"mean velocity {v:.3g} m/s",
                                   f"{int(np.asarray(result.n_cracks))} cracks"])
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


def plot_fig3(sweep: dict, path, *, mark: dict | None = None, dpi: int = 150) -> Path:
    """Save a heatmap of mean velocity over a two-axis sweep (`jaxworm.sweep` /
    `load_sweep`), like the paper's Fig. 3: a diverging map centred on zero, the
    zero-velocity contour in black, scenes that did not end `ok` grey with a cross, and
    `mark` (default: the nominal gait ω = 4π, δ = π/4, when both axes are ω and δ) as a
    white star. Returns the path written.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.colors import ListedColormap, TwoSlopeNorm
    from matplotlib.figure import Figure

    axes = sweep["header"]["axes"]
    if len(axes) != 2:
        raise ValueError(f"plot_fig3 needs a sweep over 2 parameters, got {len(axes)}: {axes}")
    xname, yname = axes[0], axes[1]
    x, y = sweep["coords"][xname], sweep["coords"][yname]
    v = np.where(sweep["status"] == 0, sweep["mean_velocity"], np.nan).T  # (y, x)
    units = sweep["header"]["units"]
    scale = {"omega": (np.pi, "π"), "delta": (np.pi, "π")}

    def shown(name, values):
        f, label = scale.get(name, (1.0, ""))
        return np.asarray(values) / f, f"{name} [{label + ' ' if label else ''}{units.get(name, '')}]"

    xs, xl = shown(xname, x)
    ys, yl = shown(yname, y)
    fig = Figure(figsize=(6.0, 4.6))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    finite = v[np.isfinite(v)]
    lim = float(np.max(np.abs(finite))) if finite.size else 1.0
    norm = TwoSlopeNorm(vcenter=0.0, vmin=-lim or -1.0, vmax=lim or 1.0)
    mesh = ax.pcolormesh(xs, ys, v, cmap="RdBu_r", norm=norm, shading="nearest")
    fig.colorbar(mesh, ax=ax, label="mean velocity [m/s]")
    if finite.size and finite.min() < 0 < finite.max() and min(v.shape) > 1:
        ax.contour(xs, ys, v, levels=[0.0], colors="k", linewidths=1.2)
    bad = sweep["status"].T != 0
    if bad.any():  # grey with a cross, so a failed scene never reads as zero velocity
        ax.pcolormesh(xs, ys, np.ma.masked_where(~bad, np.ones(bad.shape)), shading="nearest",
                      cmap=ListedColormap(["0.6"]))
        yy, xx = np.nonzero(bad)
        ax.plot(xs[xx], ys[yy], "kx", ms=6, ls="none")
    if mark is None and {xname, yname} == {"omega", "delta"}:
        mark = {"omega": 4 * np.pi, "delta": np.pi / 4}
    if mark:
        mx, _ = shown(xname, [mark[xname]])
        my, _ = shown(yname, [mark[yname]])
        ax.plot(mx, my, marker="*", ms=14, color="white", mec="k")
    ax.set_xlabel(xl)
    ax.set_ylabel(yl)
    ax.set_title(f"mean velocity, t1 = {sweep['header']['t1']:g} s")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi, bbox_inches="tight")
    return path

"""Animation of one run: the worm in its crack, drawn from dense output.

Each frame shows the N − 1 segments as rectangles of their current length
l^k = x_k − x_{k+1} and constant-volume width w^k = w_0 l_0 / l^k (eq. 6, computed by
`physics.segment_widths`), the crack as a channel of width w_c (§3.1) behind the
head, opened to w^k wherever a segment is wider than w_c (there the soil is displaced
and pushes back, eq. 8), and the crack tip x_c as a magenta triangle. Ahead of the
head, where the head acts as the wedge of eq. (4), the crack is drawn closing from the
head's opening to zero at the tip as √(x_c − x), the near-tip profile of linear elastic
fracture mechanics: an illustration only, since the model itself needs nothing of the
crack but x_c and w_c. The window follows the worm; widths are drawn on their own
(exaggerated) scale, in mm, against positions in cm.

Drawn on a bare `matplotlib.figure.Figure` (Agg canvas): no display is needed and the
caller's pyplot backend is left alone. GIFs use Pillow's writer (Pillow comes with
matplotlib); MP4 needs ffmpeg on the PATH.

```python
r = jw.simulate(p, 5.0, ts=jnp.linspace(0.0, 5.0, 101))
animate(r, p, "worm.gif", fps=20)
```
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike, Float

from . import _physics as physics
from ._validation import check_int

if TYPE_CHECKING:
    from ._params import Params
    from ._result import Result

__all__ = ["animate", "frame_geometry", "ffmpeg_available"]

_BODY, _OPEN, _TIP, _SOIL = "tab:blue", "tab:orange", "magenta", "0.85"
#: Fractions of the head-to-tip distance, 1 at the head to 0 at the tip, for the crack
#: profile ahead of the head: opening ∝ √(x_c − x), LEFM's near-tip shape.
_TAPER = np.linspace(1.0, 0.0, 25) ** 2


def ffmpeg_available() -> bool:
    """Whether an MP4 can be written (ffmpeg on the PATH)."""
    return shutil.which("ffmpeg") is not None


def frame_geometry(
    x: Float[ArrayLike, " N"],
    x_c: physics.Scalar,
    w0: physics.Scalar,
    l0: physics.Scalar,
    w_c: physics.Scalar,
) -> dict[str, Any]:
    """What one frame draws, from node positions `x` [m] (N,), the crack tip `x_c` [m],
    the unstretched segment width `w0` and length `l0` [m] and the crack width `w_c` [m]:

    - `left`, `length`, `width`: per segment (N − 1,), the tail-side end x_{k+1},
      the length l^k and the width w^k of eq. (6) [m];
    - `opening`: per segment, max(w^k, w_c) [m], the local crack width (the soil is
      displaced where w^k > w_c);
    - `compressed`: per segment, w^k > w_c (the segment touches the walls and feels
      friction, eqs. 8-10).
    """
    x = np.asarray(x, dtype=np.float64)
    length = physics.segment_lengths(jnp.asarray(x))
    width = np.asarray(physics.segment_widths(length, float(w0), float(l0)))
    length = np.asarray(length)
    return {
        "left": x[1:],
        "length": length,
        "width": width,
        "opening": np.maximum(width, float(w_c)),
        "compressed": width > float(w_c),
        "x_c": float(x_c),
    }


def _window(x, x_c, margin) -> float:
    """Width [m] of the view that keeps tail, head and tip in sight in every frame."""
    span = float(np.nanmax(np.maximum(x_c, x[:, 0]) - x[:, -1]))
    return span + 2 * margin


#: The highest frame rate a GIF plays at: its frame times are whole hundredths of a
#: second, and viewers slow frames shorter than 20 ms.
GIF_MAX_FPS = 50


def gif_fps_problem(fps: int) -> str:
    """Why a GIF cannot play at `fps` frames per second."""
    return (
        f"option fps = {fps}: a GIF plays at most {GIF_MAX_FPS} frames per second (its "
        "frame times are whole hundredths of a second, and viewers slow frames under "
        "20 ms); lower fps or write an .mp4"
    )


def animate(
    result: Result,
    params: Params,
    path: str | Path,
    *,
    fps: int = 20,
    max_frames: int = 300,
    dpi: int = 100,
    title: str | None = None,
) -> Path:
    """Write an animation of one (unbatched) run with dense output to `path`.

    `result` must come from `simulate(..., ts=...)`; one frame per saved time, thinned
    evenly to at most `max_frames`. `fps` frames per second of the movie (so the movie
    runs at (t1 / frames) · fps times real speed). The format follows the suffix of
    `path`: `.gif` (Pillow; fps ≤ `GIF_MAX_FPS`) or `.mp4` (ffmpeg; `RuntimeError`
    without it). Returns the path written.
    """
    from matplotlib.animation import FFMpegWriter, FuncAnimation, PillowWriter
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.patches import Polygon, Rectangle

    tr = result.trajectory
    if tr is None:
        raise ValueError("animate needs dense output: call simulate(..., ts=...)")
    x_all = np.asarray(tr.x)
    if x_all.ndim != 2:
        raise ValueError(f"animate draws one run; got positions of shape {x_all.shape}")
    check_int("fps", fps, 1, None, kind="option")  # NumPy integers too, never a bool
    check_int("max_frames", max_frames, 1, None, kind="option")
    fps, max_frames = int(fps), int(max_frames)
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in (".gif", ".mp4"):
        raise ValueError(f"animation file {str(path)!r}: the suffix must be .gif or .mp4")
    if suffix == ".mp4" and not ffmpeg_available():
        raise RuntimeError(
            f"animation file {str(path)!r}: MP4 needs ffmpeg on the PATH; write a .gif instead"
        )
    if suffix == ".gif" and fps > GIF_MAX_FPS:
        raise ValueError(gif_fps_problem(fps))

    finite = np.all(np.isfinite(x_all), axis=1) & np.isfinite(np.asarray(tr.x_c))
    idx = np.flatnonzero(finite)
    if idx.size == 0:
        raise ValueError("animate: the trajectory holds no finite frame")
    idx = idx[
        np.unique(np.linspace(0, idx.size - 1, min(max_frames, idx.size)).round().astype(int))
    ]
    ts, x_all, x_c = np.asarray(tr.ts)[idx], x_all[idx], np.asarray(tr.x_c)[idx]

    b, s = params.body, params.soil
    w0, l0, w_c = (float(np.asarray(v)) for v in (b.w0, b.l0, s.w_c))
    margin = 1.5 * l0
    width_view = _window(x_all, x_c, margin)
    geoms = [frame_geometry(x, xc, w0, l0, w_c) for x, xc in zip(x_all, x_c)]
    w_max = max(float(np.max(g["opening"])) for g in geoms)
    ylim = 0.75 * w_max * 1e3  # mm, half height of the view

    fig = Figure(figsize=(9.0, 2.8))
    fig.subplots_adjust(left=0.08, right=0.98, bottom=0.18, top=0.88)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    ax.set_ylim(-ylim, ylim)
    ax.set_xlabel("position [cm]")
    ax.set_ylabel("width [mm]")
    ax.set_facecolor(_SOIL)
    n_seg = x_all.shape[1] - 1
    channel = Polygon(
        np.zeros((4, 2)), closed=True, facecolor="white", edgecolor="0.3", lw=0.8, zorder=1
    )
    ax.add_patch(channel)
    segs = [
        Rectangle((0, 0), 0, 0, facecolor=_BODY, edgecolor="k", lw=0.6, zorder=3)
        for _ in range(n_seg)
    ]
    for r in segs:
        ax.add_patch(r)
    (nodes,) = ax.plot([], [], "k.", ms=3, zorder=4)
    (tip,) = ax.plot(
        [], [], marker="<", ms=10, color=_TIP, ls="none", zorder=5, label="crack tip $x_c$"
    )
    ax.plot([], [], color=_BODY, lw=6, label="segment, $w^k \\leq w_c$")
    ax.plot([], [], color=_OPEN, lw=6, label="segment, $w^k > w_c$ (opens the crack)")
    ax.legend(loc="upper left", fontsize=7, ncols=3, framealpha=0.9)
    label = ax.text(0.99, 0.04, "", transform=ax.transAxes, ha="right", fontsize=8, zorder=6)
    if title is None:
        g = params.gait
        parts = [
            f"{n} = {float(np.asarray(getattr(g, n))):.4g}"
            for n in ("A", "omega", "delta")
            if hasattr(g, n)
        ]
        title = "worm in its crack; " + ", ".join(parts) + f"; w_c = {w_c * 1e3:g} mm"
    ax.set_title(title, fontsize=9)

    def draw(i):
        g, x = geoms[i], x_all[i]
        lo = x[-1] - margin
        ax.set_xlim(lo * 100, (lo + width_view) * 100)
        # Crack channel: width w_c, opened to w^k along the segments, up to the tip.
        xs = [lo - width_view, x[-1]]
        half = [w_c / 2, w_c / 2]
        for k in range(n_seg - 1, -1, -1):  # tail to head
            xs += [x[k + 1], x[k]]
            half += [g["opening"][k] / 2] * 2
        ahead = g["x_c"] - (g["x_c"] - x[0]) * _TAPER  # head to tip: sqrt(r) profile
        xs += list(ahead)
        half += list(g["opening"][0] / 2 * np.sqrt(_TAPER))
        xs, half = np.asarray(xs) * 100, np.asarray(half) * 1e3
        channel.set_xy(np.column_stack([np.r_[xs, xs[::-1]], np.r_[half, -half[::-1]]]))
        for k, r in enumerate(segs):
            r.set_xy((g["left"][k] * 100, -g["width"][k] / 2 * 1e3))
            r.set_width(g["length"][k] * 100)
            r.set_height(g["width"][k] * 1e3)
            r.set_facecolor(_OPEN if g["compressed"][k] else _BODY)
        nodes.set_data(x * 100, np.zeros_like(x))
        tip.set_data([g["x_c"] * 100], [0.0])
        label.set_text(
            f"t = {ts[i]:.2f} s   head {x[0] * 100:.2f} cm   tip {g['x_c'] * 100:.2f} cm"
        )
        return [channel, *segs, nodes, tip, label]

    anim = FuncAnimation(fig, draw, frames=len(geoms), blit=False)
    writer = PillowWriter(fps=fps) if suffix == ".gif" else FFMpegWriter(fps=fps)
    path.parent.mkdir(parents=True, exist_ok=True)
    anim.save(str(path), writer=writer, dpi=dpi)
    return path

"""docs/figures/velocity_vs_delta.png from two sweeps (see docs/reproduction.md).

python docs/study/velocity_vs_delta.py DELTA_LINE.npz FINE_LINE.npz OUT.png
"""

import sys

import numpy as np
from matplotlib.figure import Figure

import jaxworm as jw


def _failed(ax, d, v, status):
    """Scenes that did not end `ok` (rows of `v`, `status` along δ = `d`), a black marker
    each, one marker and legend entry per status naming it and the δ where it happened."""
    v, status = np.atleast_2d(v), np.atleast_2d(status)
    for code in np.unique(status[status != 0]):
        bad = status == code
        where = ", ".join(f"{x:.3g}π" for x in np.unique(np.broadcast_to(d, bad.shape)[bad]))
        name = jw.status_name(int(code))
        marker = {"energy_balance": "x", "too_many_cracks": "^"}.get(name, "s")
        ax.plot(
            np.broadcast_to(d, bad.shape)[bad],
            v[bad],
            marker,
            color="k",
            ms=8,
            ls="none",
            label=f"status {name} at δ = {where}",
        )


coarse, fine, out = sys.argv[1:4]
c, f = jw.load_sweep(coarse), jw.load_sweep(fine)
fig = Figure(figsize=(9.0, 5.0), layout="constrained")
axes = fig.subplots(1, 2)
for ax, s, title in ((axes[0], c, "ω = 4π, δ ∈ [−π, π]"), (axes[1], f, "δ ∈ [0, π/3], three ω")):
    ax.axvspan(1 / 6, 1 / 3, color="0.88", label="paper's δ window")
    ax.axhline(0, color="k", lw=0.6)
    ax.plot([0.25], [0.0022], "r*", ms=12, label="paper, nominal")
    ax.axvline(0.74 / np.pi, color="r", ls=":", lw=1, label="paper: retreat below δ = 0.74")
    d = s["coords"]["delta"] / np.pi
    if "omega" in s["coords"]:
        for i, w in enumerate(s["coords"]["omega"]):
            ok = s["status"][i] == 0
            ax.plot(d[ok], s["mean_velocity"][i][ok], ".-", label=f"jaxworm, ω = {w / np.pi:.0f}π")
    else:
        ok = s["status"] == 0
        ax.plot(d[ok], s["mean_velocity"][ok], "o-", ms=4, label="jaxworm, ω = 4π")
    _failed(ax, d, s["mean_velocity"], s["status"])
    ax.set_xlabel("δ [π rad]")
    ax.set_title(title + ", t1 = 60 s", fontsize=9)
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.16))
axes[0].set_ylabel("mean velocity [m/s]")
fig.savefig(out, dpi=110)

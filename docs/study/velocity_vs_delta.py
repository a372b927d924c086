"""docs/figures/velocity_vs_delta.png from two sweeps (see docs/reproduction.md)."""

import sys

import numpy as np
from matplotlib.figure import Figure

import jaxworm as jw

coarse, fine, out = sys.argv[1:4]
c, f = jw.load_sweep(coarse), jw.load_sweep(fine)
fig = Figure(figsize=(9.0, 3.6), layout="constrained")
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
            ax.plot(d[~ok], s["mean_velocity"][i][~ok], "kx")
    else:
        ok = s["status"] == 0
        ax.plot(d[ok], s["mean_velocity"][ok], "o-", ms=4, label="jaxworm, ω = 4π")
        ax.plot(d[~ok], s["mean_velocity"][~ok], "kx", ms=8, label="status not ok")
    ax.set_xlabel("δ [π rad]")
    ax.set_title(title + ", t1 = 60 s", fontsize=9)
    ax.legend(fontsize=7)
axes[0].set_ylabel("mean velocity [m/s]")
fig.savefig(out, dpi=110)

"""Readings of the paper's gait on a 5 x 5 grid over its Fig. 3 window, 60 s each.

    python docs/study/readings.py default mirrored tail nentries eq5   # ~1 min per reading

`default` is MODEL.md; `mirrored` flips the sign of δ (ψ_k = ωt − δk, the wave run from
head to tail); `tail` counts the gait's segments from the tail (ψ_k = ωt + δ(N − k),
the mirrored wave shifted in phase by δN); `nentries` gives segment k the (k+1)-th of
eq. 24's N entries (ψ_{k+1}, the first dropped); `eq5` takes Wg from eq. 5. Prints the
mean velocity [m/s] (rows ω = 3π … 5π, columns δ = π/6 … π/3; for `mirrored`, columns
|δ|), the crack counts and the statuses. See docs/reproduction.md.
"""

import dataclasses
import sys
import time

import jax.numpy as jnp
import numpy as np

import jaxworm as jw
from jaxworm.paper import paper_grid


class TailNumbered(jw.TravellingWave):
    """ψ_k = ω t + δ (N − k): the gait's segments counted from the tail."""

    def phase(self, t, n_segments):
        return self.omega * t + self.delta * jnp.arange(n_segments, 0, -1)


class NEntries(jw.TravellingWave):
    """Segment k takes ψ_{k+1} = ω t + δ (k + 1): eq. 24's first entry dropped."""

    def phase(self, t, n_segments):
        return self.omega * t + self.delta * jnp.arange(2, n_segments + 2)


def base(name: str) -> jw.Params:
    p = jw.Params()
    if name in ("default", "mirrored"):
        return p
    if name == "tail":
        return dataclasses.replace(p, gait=TailNumbered())
    if name == "nentries":
        return dataclasses.replace(p, gait=NEntries())
    if name == "eq5":
        return dataclasses.replace(p, soil=dataclasses.replace(p.soil, wedge="eq5"))
    raise SystemExit(f"unknown reading {name!r}")


def main(names):
    np.set_printoptions(precision=5, suppress=True, linewidth=150)
    for name in names:
        grid = paper_grid(5, delta_sign=-1 if name == "mirrored" else 1)
        start = time.perf_counter()
        s = jw.sweep(grid, base(name), 60.0, chunk=25, progress=False)
        v, n = s["mean_velocity"], s["n_cracks"]
        if name == "mirrored":  # columns in |δ| order, as the paper's
            v, n = v[:, ::-1], n[:, ::-1]
        print(
            f"{name}: {time.perf_counter() - start:.0f} s; mean velocity "
            f"{np.nanmin(v):+.4f} … {np.nanmax(v):+.4f} m/s, cracks {int(n.min())}–"
            f"{int(n.max())}, statuses {sorted({int(c) for c in s['status'].ravel()})}"
        )
        print(v)


if __name__ == "__main__":
    main(sys.argv[1:] or ["default", "mirrored", "tail", "nentries", "eq5"])

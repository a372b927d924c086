"""How derivatives through crack events hold up as the horizon (and the crack count) grows.

d(mean velocity)/dA on the forward gait delta = -pi/4 (Table 1 otherwise), by forward-mode
AD (vmapped over the horizons) against central finite differences (relative step 3e-3),
with the crack tips differentiated exactly and held constant (`crack_sensitivity`
"exact" and "tips_held").

    python benchmarks/gradient_horizon.py [--preset default] [--horizons 2.5,5,10,20,40]

Writes benchmarks/results/gradient_horizon/gradient_horizon[_<preset>].json (the
suffix unless `--preset default`, the library's) and prints a table.
"""

from __future__ import annotations

import argparse
import platform
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from _results import results_dir, write_json

import jaxworm as jw

BASE = jw.Params().replace(delta=-jnp.pi / 4)
A0, REL = 0.02, 3e-3


def run(preset: str, horizons: list[float]) -> dict:
    t1s = jnp.asarray(horizons)
    out = {"preset": preset, "t1": horizons, "rel_step": REL}
    for tips in (True, False):
        num = jw.PRESETS[preset].replace(
            adjoint="forward", crack_sensitivity="exact" if tips else "tips_held"
        )

        def v(A, t1, num=num):
            return jw.simulate(BASE.replace(A=A), t1, num).mean_velocity

        ad = eqx.filter_jit(jax.vmap(jax.jacfwd(v), in_axes=(None, 0)))(A0, t1s)
        out[f"ad_tips_{'exact' if tips else 'constant'}"] = np.asarray(ad).tolist()
    num = jw.PRESETS[preset]
    both = jnp.array([A0 * (1 + REL), A0 * (1 - REL)])
    runs = eqx.filter_jit(
        jax.vmap(
            jax.vmap(lambda A, t1: jw.simulate(BASE.replace(A=A), t1, num), in_axes=(None, 0)),
            in_axes=(0, None),
        )
    )(both, t1s)
    v = np.asarray(runs.mean_velocity)
    out["fd"] = ((v[0] - v[1]) / (2 * A0 * REL)).tolist()
    out["n_cracks"] = np.asarray(runs.n_cracks).tolist()
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--preset",
        default="default",
        choices=tuple(jw.PRESETS),
        help="numerics preset (default: default, jw.simulate's)",
    )
    ap.add_argument("--horizons", default="2.5,5,10,20,40")
    args = ap.parse_args()
    horizons = [float(h) for h in args.horizons.split(",")]
    t = time.perf_counter()
    out = run(args.preset, horizons)
    out["wall_s"] = time.perf_counter() - t
    out["machine"] = f"{platform.platform()}, {__import__('os').cpu_count()} CPUs"
    suffix = "" if args.preset == "default" else f"_{args.preset}"
    path = results_dir("gradient_horizon") / f"gradient_horizon{suffix}.json"
    write_json(path, out)
    print(f"{'t1 [s]':>7} {'cracks':>7} {'AD exact':>10} {'AD tips const':>14} {'FD':>10}")
    for i, h in enumerate(horizons):
        print(
            f"{h:7.1f} {out['n_cracks'][0][i]:7d} {out['ad_tips_exact'][i]:10.4f} "
            f"{out['ad_tips_constant'][i]:14.4f} {out['fd'][i]:10.4f}"
        )
    print(f"-> {path}")


if __name__ == "__main__":
    main()

"""How accurate a gradient is each differentiable preset, and do batching modes agree?

d(mean velocity)/dω of the nominal gait (Table 1) at 8 frequencies across [3π, 5π],
t1 = 10 s, from:

- `accurate` in forward mode (`jax.vmap(jax.jacfwd)`): the reference, itself checked
  against central finite differences of `accurate` (relative step 1e-3);
- `default` in forward mode (`jax.vmap(jax.jacfwd)`), in reverse mode batched
  (`jax.vmap(jax.grad)`) and in reverse mode one after another (`jax.lax.map`).

    python benchmarks/gradient_presets.py [--t1 10] [--n 8]

Writes benchmarks/results/gradient_presets/gradient_presets.{json,md}.
"""

from __future__ import annotations

import argparse
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from _bench import machine_info, md_table, results_dir, write_json

import jaxworm as jw

REL = 1e-3


def _speed(numerics: jw.Numerics, t1: float):
    p = jw.Params()
    return lambda w: jw.simulate(p.replace(omega=w), t1, numerics).mean_velocity


def run(t1: float, n: int) -> dict:
    omegas = jnp.linspace(3 * jnp.pi, 5 * jnp.pi, n)
    out, walls = {"omega": np.asarray(omegas).tolist(), "t1": t1}, {}
    # The nominal gait does not crack: "exact" is the only derivative a diffrax preset gives.
    presets = {k: jw.PRESETS[k].replace(crack_sensitivity="exact") for k in ("accurate", "default")}
    forward = {k: v.replace(adjoint="forward") for k, v in presets.items()}
    modes = {
        "accurate_jacfwd_vmap": lambda: jax.vmap(jax.jacfwd(_speed(forward["accurate"], t1))),
        "default_jacfwd_vmap": lambda: jax.vmap(jax.jacfwd(_speed(forward["default"], t1))),
        "default_grad_vmap": lambda: jax.vmap(jax.grad(_speed(presets["default"], t1))),
        "default_grad_lax_map": lambda: (
            lambda o: jax.lax.map(jax.grad(_speed(presets["default"], t1)), o)
        ),
    }
    for name, make in modes.items():
        t = time.perf_counter()
        out[name] = np.asarray(eqx.filter_jit(make())(omegas)).tolist()
        walls[name] = time.perf_counter() - t
    both = jnp.concatenate([omegas * (1 + REL), omegas * (1 - REL)])
    v = np.asarray(eqx.filter_jit(jax.vmap(_speed(jw.PRESETS["accurate"], t1)))(both))
    out["accurate_fd"] = ((v[:n] - v[n:]) / (2 * REL * np.asarray(omegas))).tolist()
    out["wall_s_with_compile"] = walls
    ref = np.asarray(out["accurate_jacfwd_vmap"])
    out["max_abs_error_vs_accurate"] = {
        k: float(np.max(np.abs(np.asarray(out[k]) - ref)))
        for k in ("accurate_fd", "default_jacfwd_vmap", "default_grad_vmap", "default_grad_lax_map")
    }
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--t1", type=float, default=10.0)
    ap.add_argument("--n", type=int, default=8)
    args = ap.parse_args()
    out = run(args.t1, args.n)
    out["machine"] = machine_info()
    folder = results_dir("gradient_presets")
    write_json(folder / "gradient_presets.json", out)
    cols = [
        "accurate_jacfwd_vmap",
        "accurate_fd",
        "default_jacfwd_vmap",
        "default_grad_vmap",
        "default_grad_lax_map",
    ]
    rows = [
        [f"{w / np.pi:.3f}π"] + [f"{out[c][i]:.4e}" for c in cols]
        for i, w in enumerate(out["omega"])
    ]
    rows.append(
        ["max abs. diff. from accurate", "-"]
        + [f"{out['max_abs_error_vs_accurate'][c]:.2e}" for c in cols[1:]]
    )
    lines = [
        f"# d(mean velocity)/dω [(m/s)/(rad/s)], nominal gait, t1 = {args.t1:g} s",
        "",
        "Machine: {cpu}, {cpus} CPUs, jax {jax}, diffrax {diffrax}, commit {git_commit}; "
        "{date}.".format(**out["machine"]),
        "",
    ]
    lines += md_table(["ω"] + cols, rows)
    lines += [
        "",
        "Walls with compilation [s]: "
        + ", ".join(f"{k} {v:.1f}" for k, v in out["wall_s_with_compile"].items()),
    ]
    (folder / "gradient_presets.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()

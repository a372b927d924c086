"""How far each preset's mean velocity is from a tight solve, over random gaits.

    python benchmarks/random_gaits.py [--quick] [--gaits 48] [--seed 0]

Draws `--gaits` travelling waves (A in [0.005, 0.03] m/s, ω in [2π, 6π] rad/s, δ in
[−π/2, π/2], K_Ith in [200, 240] Pa·√m, the rest Table 1) from `--seed`, and solves each
over t1 = 2 s and 10 s with the presets `fast`, `default` and `accurate`, and with the
reference, Rodas4 on positions at atol 1e-12 m (which agrees with Tsit5 on the full norm
at rtol 1e-8 to ~0.1 % on the worst gait seen). Every solve is one vmapped batch. For
the runs that end `ok` (preset and reference) it reports the head's position error at
t1, |Δv̄|·t1, and the relative error of v̄ (on |v̄| ≥ 1e-4 m/s, `_bench.V_FLOOR`), and
counts the runs beyond 1 % and 5 %: a
status `ok` is no promise that v̄ is within 1 % when |v̄|·t1 is small against the
position error (short horizons, slow gaits). Writes
`results/random_gaits/random_gaits[_quick].{json,md}`.
"""

from __future__ import annotations

import argparse

import _bench as B  # (first: sets the BLAS threads before numpy loads)
import jax
import numpy as np

jw = B.jw

PRESETS = ("fast", "default", "accurate")
REFERENCE = jw.PRESETS["fast"].replace(atol=1e-12)


def draw(n: int, seed: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {
        "A": rng.uniform(0.005, 0.03, n),
        "omega": rng.uniform(2 * np.pi, 6 * np.pi, n),
        "delta": rng.uniform(-np.pi / 2, np.pi / 2, n),
        "K_Ith": rng.uniform(200.0, 240.0, n),
    }


def solve(gaits: dict[str, np.ndarray], t1: float, numerics) -> dict[str, np.ndarray]:
    def one(A, omega, delta, K_Ith):
        p = jw.Params().replace(A=A, omega=omega, delta=delta, K_Ith=K_Ith)
        r = jw.simulate(p, t1, numerics)
        return r.mean_velocity, r.status, r.energy_residual, r.n_cracks

    out = jax.jit(jax.vmap(one))(*(gaits[k] for k in ("A", "omega", "delta", "K_Ith")))
    return dict(zip(("v", "status", "energy_residual", "n_cracks"), map(np.asarray, out)))


def compare(run: dict, ref: dict, t1: float, gaits: dict) -> dict:
    ok = (run["status"] == 0) & (ref["status"] == 0)
    head = np.abs(run["v"] - ref["v"]) * t1
    rel = np.abs(run["v"] - ref["v"]) / np.maximum(np.abs(ref["v"]), B.V_FLOOR)
    worst = int(np.argmax(np.where(ok, rel, -1.0)))
    return {
        "ok": int(ok.sum()),
        "head_error_max_m": float(head[ok].max()),
        "head_error_median_m": float(np.median(head[ok])),
        "over_1pct": int((rel[ok] > 0.01).sum()),
        "over_5pct": int((rel[ok] > 0.05).sum()),
        "v": run["v"].tolist(),
        "status": run["status"].tolist(),
        "energy_residual": run["energy_residual"].tolist(),
        "worst": {
            **{k: float(v[worst]) for k, v in gaits.items()},
            "v_reference": float(ref["v"][worst]),
            "relative_error": float(rel[worst]),
            "energy_residual": float(run["energy_residual"][worst]),
            "n_cracks": int(run["n_cracks"][worst]),
        },
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="8 gaits, 0.5 s and 2 s")
    ap.add_argument("--gaits", type=int, default=48)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    n = 8 if args.quick else args.gaits
    horizons = (0.5, 2.0) if args.quick else (2.0, 10.0)
    gaits = draw(n, args.seed)
    rows, references = [], []
    for t1 in horizons:
        ref = solve(gaits, t1, REFERENCE)
        references.append({"t1": t1, "v": ref["v"].tolist(), "status": ref["status"].tolist()})
        B.log(f"t1 = {t1:g}: reference ok {int((ref['status'] == 0).sum())}/{n}")
        for name in PRESETS:
            row = {
                "t1": t1,
                "preset": name,
                **compare(solve(gaits, t1, jw.PRESETS[name]), ref, t1, gaits),
            }
            B.log(str(row))
            rows.append(row)
    out = B.results_dir("random_gaits")
    stem = "random_gaits" + B.quick_suffix(args.quick)
    machine = B.machine_info()
    B.write_json(
        out / f"{stem}.json",
        {
            "machine": machine,
            "run": B.run_record(),
            "seed": args.seed,
            "gaits": {k: v.tolist() for k, v in gaits.items()},
            "references": references,
            "rows": rows,
        },
    )
    lines = [
        f"# Preset errors over {n} random gaits (seed {args.seed})",
        "",
        f"`{B.run_record()['command']}`; {B.machine_line(machine)}.",
        "",
        "Reference: Rodas4 on positions at atol 1e-12 m. Head error |Δv̄|·t1 over the runs",
        "that end ok in both; relative error of v̄ beyond 1 % and 5 %; the worst gait by",
        "relative error (|Δv̄| / max(|v̄|, 1e-4 m/s)).",
        "",
        "| t1 s | preset | ok | head error max / median µm | > 1 % | > 5 % "
        "| worst gait (A, ω, δ): v̄ ref, error, energy residual |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        w = r["worst"]
        lines.append(
            f"| {r['t1']:g} | {r['preset']} | {r['ok']}/{n} | {r['head_error_max_m'] * 1e6:.0f} / "
            f"{r['head_error_median_m'] * 1e6:.0f} | {r['over_1pct']} | {r['over_5pct']} | "
            f"({w['A']:.4f}, {w['omega']:.2f}, {w['delta']:.3f}): {w['v_reference']:.2e} m/s, "
            f"{w['relative_error']:.1%}, {w['energy_residual']:.3f} |"
        )
    (out / f"{stem}.md").write_text("\n".join(lines) + "\n", encoding="utf-8")
    print("\n".join(lines))


if __name__ == "__main__":
    main()

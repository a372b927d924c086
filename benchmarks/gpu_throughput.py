"""Value-and-gradient and forward throughput of vmapped batches on one accelerator, with
the error on the same work against the CPU of the same machine.

    python benchmarks/gpu_throughput.py [--t1 10] [--batches 1024 16384 4096]
                                        [--budget-s 330] [--out DIR]

Work: B random travelling waves around Table 1 (A ∈ [0.015, 0.025] m, ω ∈ [3π, 5π]
rad/s, δ ∈ [−π/2, −π/8]: the cracking half of the Fig. 3 window), the mean velocity over
the whole gait periods within t1 (`horizon="whole_periods"`). Two programs, each
`jax.jit(jax.vmap(...))` over the batch:

- `forward`: `jw.simulate` with its defaults (the `fast` preset);
- `jacfwd`: value and `jax.jacfwd` with respect to (A, ω, δ), default numerics (the
  forward sensitivities of `jw.simulate`), the value as jacfwd's aux (one solve).

Each (program, B) is compiled once (timed), then run twice; the faster run is kept.
Reported: lanes per second, simulated seconds per second (each lane's own whole-period
horizon), the per-lane cost against the median of `--lone` lone solves of the same
program on one CPU core of the same machine, memory, and how many lanes ended ok.

Error on the same work: the first `--check` lanes of the batch are solved again on the
CPU (float64), vmapped together (`vs_cpu_batched`: the same function, a smaller batch)
and the first `--lone` of them one by one (`vs_cpu_lone`), and compared: relative
difference of v̄, and of each scaled gradient component θ_i·∂v̄/∂θ_i relative to the
largest of the lane's. Batches of other sizes round differently and the adaptive steps
amplify it (docs: known issues), so these differences are the solver's tolerance, not
zero; the default derivative's accuracy against finite differences is
`gradient_accuracy.py --batched`'s.

The script stops starting new measurements when `--budget-s` is spent and writes its
JSON after every one, so a run cut short keeps what it measured. Without an accelerator
it runs on the CPU (a smoke test: use small batches).

`--probe` first: the forward program at `--probe-batch` (64) and `--probe-t1` (0.1 s), in
one fresh process per XLA setting (`PROBE_VARIANTS`: XLA's defaults, no CUDA graphs, the
while loops in CUDA graphs too), each
cut at `--probe-limit-s`, its phases logged to `probe_<variant>.log` under `--out`,
before this process takes the device. It tells compilation apart from stepping before a
lease is spent on large batches; `--probe-only` stops there. The budget counts the probe.
Peak memory: XLA's buffer plan of each compiled program (`xla_buffer_bytes`) and the
device's peak so far in the process (`peak_device_bytes_so_far`, cumulative).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import _bench  # noqa: F401  (first: the caches off, so compile times are real)
import _results as R
import jax
import jax.numpy as jnp
import numpy as np

import jaxworm as jw

BOX = {"A": (0.015, 0.025), "omega": (3 * np.pi, 5 * np.pi), "delta": (-np.pi / 2, -np.pi / 8)}


def _gaits(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    lo = np.array([b[0] for b in BOX.values()])
    hi = np.array([b[1] for b in BOX.values()])
    return lo + (hi - lo) * rng.random((n, 3))


def _params(z):
    return jw.Params(gait=jw.TravellingWave(A=z[0], omega=z[1], delta=z[2]))


def _forward(z, t1):
    r = jw.simulate(_params(z), t1, horizon="whole_periods")
    return {"v": r.mean_velocity, "status": r.status, "steps": r.steps, "t1": r.t1}


def _value_and_jacfwd(z, t1):
    def with_aux(q):
        r = jw.simulate(_params(q), t1, horizon="whole_periods")
        aux = {"v": r.mean_velocity, "status": r.status, "steps": r.steps, "t1": r.t1}
        return r.mean_velocity, aux

    g, out = jax.jacfwd(with_aux, has_aux=True)(z)
    return out | {"grad": g}


PROGRAMS = {"forward": _forward, "jacfwd": _value_and_jacfwd}

#: XLA settings the probe compares (name -> XLA_FLAGS).
PROBE_VARIANTS = {
    "defaults": "",
    "no_cuda_graphs": "--xla_gpu_enable_command_buffer=",
    # The solver's while loops inside CUDA graphs too (conditional nodes): the loop's
    # condition stays on the device instead of a round trip to the host every step.
    "while_graphs": "--xla_gpu_enable_command_buffer=+WHILE,+CONDITIONAL",
}


def _probe(out_dir: Path, limit_s: float, batch: int = 64, t1: float = 0.1) -> list[dict]:
    """The small forward program under each `PROBE_VARIANTS` setting, a fresh process
    each: (variant, exit code, wall s, last lines of its log)."""
    rows = []
    for name, flags in PROBE_VARIANTS.items():
        env = dict(os.environ, XLA_FLAGS=flags, PYTHONUNBUFFERED="1")
        env["XLA_PYTHON_CLIENT_PREALLOCATE"] = "false"  # one probe's memory at a time
        log = out_dir / f"probe_{name}.log"
        cmd = [sys.executable, __file__, "--programs", "forward", "--batches", str(batch)]
        cmd += ["--t1", str(t1), "--check", "1", "--lone", "1", "--budget-s", "0"]
        cmd += ["--out", str(out_dir / f"probe_{name}")]
        start = time.perf_counter()
        with open(log, "w") as f:
            try:
                code = subprocess.run(
                    cmd, env=env, stdout=f, stderr=subprocess.STDOUT, timeout=limit_s
                ).returncode
            except subprocess.TimeoutExpired:
                code = None
        wall = time.perf_counter() - start
        tail = log.read_text().splitlines()[-8:]
        rows.append(
            {"variant": name, "XLA_FLAGS": flags, "exit": code, "wall_s": wall, "log_tail": tail}
        )
        print(f"probe {name}: exit {code} after {wall:.0f} s", *tail, sep="\n  ", flush=True)
    return rows


def _peak_bytes(device) -> int | None:
    try:
        stats = device.memory_stats() or {}
    except Exception:  # the CPU backend may not report
        return None
    return stats.get("peak_bytes_in_use")


def _phase(what: str, start: float) -> float:
    """Print how long a phase took, at once (a run cut short still says where it was)."""
    took = time.perf_counter() - start
    print(f"  {what}: {took:.1f} s", flush=True)
    return took


def _batched(name: str, z: np.ndarray, t1: float, device, n_runs: int = 2) -> dict:
    print(f"{name} B={z.shape[0]} t1={t1:g}", flush=True)
    fn = jax.jit(jax.vmap(PROGRAMS[name], in_axes=(0, None)))
    zd = jax.device_put(jnp.asarray(z), device)
    td = jax.device_put(jnp.float64(t1), device)
    start = time.perf_counter()
    lowered = fn.lower(zd, td)
    lower_s = _phase("trace and lower", start)
    start = time.perf_counter()
    compiled = lowered.compile()
    compile_s = _phase("compile", start)
    try:
        m = compiled.memory_analysis()
        xla_bytes = int(m.temp_size_in_bytes + m.argument_size_in_bytes + m.output_size_in_bytes)
    except Exception:  # not every backend reports it
        xla_bytes = None
    runs = []
    out = None
    for i in range(n_runs):
        start = time.perf_counter()
        out = jax.block_until_ready(compiled(zd, td))
        runs.append(_phase(f"run {i + 1}", start))
    out = {k: np.asarray(o) for k, o in out.items()}
    return {
        "program": name,
        "batch": int(z.shape[0]),
        "lower_s": lower_s,
        "compile_s": compile_s,
        "run_s": min(runs),
        "runs_s": runs,
        "lanes_per_s": z.shape[0] / min(runs),
        "sim_s_per_s": float(out["t1"].sum()) / min(runs),
        "ok_lanes": int((out["status"] == 0).sum()),
        "steps_mean": float(out["steps"].mean()),
        "steps_max": int(out["steps"].max()),
        "xla_buffer_bytes": xla_bytes,
        "peak_device_bytes_so_far": _peak_bytes(device),
        "_out": out,
    }


def _cpu_reference(name: str, z: np.ndarray, t1: float, lone: int) -> dict:
    """The same work on one CPU core: the batch program over the check lanes (vmapped,
    as on the device), and the program for one lane alone over the first `lone` of them
    (the per-core anchor of the speedup)."""
    cpu = jax.devices("cpu")[0]
    td = jax.device_put(jnp.float64(t1), cpu)
    # Runs where its arguments are: on the CPU.
    batched = jax.jit(jax.vmap(PROGRAMS[name], in_axes=(0, None)))
    out_b = jax.block_until_ready(batched(jax.device_put(jnp.asarray(z), cpu), td))
    fn = jax.jit(PROGRAMS[name])
    jax.block_until_ready(fn(jax.device_put(jnp.asarray(z[0]), cpu), td))
    runs, outs = [], []
    for zi in z[:lone]:
        zi = jax.device_put(jnp.asarray(zi), cpu)
        start = time.perf_counter()
        out = jax.block_until_ready(fn(zi, td))
        runs.append(time.perf_counter() - start)
        outs.append({k: np.asarray(o) for k, o in out.items()})
    return {
        "program": name,
        "run_s_per_lane": float(np.median(runs)),
        "runs_s": runs,
        "_batched": {k: np.asarray(o) for k, o in out_b.items()},
        "_lone": outs,
    }


def _compare(dev, ref, z) -> dict:
    """Device lanes against reference lanes (dicts of arrays with the lane first): v̄
    relative, the gradient scaled θ_i·∂v̄/∂θ_i over the lane's largest."""
    n = len(z)
    v_d, v_r = np.asarray(dev["v"][:n], float), np.asarray(ref["v"][:n], float)
    dv = np.abs(v_d - v_r) / np.maximum(np.abs(v_r), 1e-4)  # NaN stays NaN in np.max
    out = {
        "lanes": n,
        "not_ok": int(np.sum((dev["status"][:n] != 0) | (ref["status"][:n] != 0))),
        "max_rel_dv": float(np.max(dv)),
        "max_scaled_dgrad": None,
    }
    if "grad" in ref:
        s_d, s_r = z[:n] * dev["grad"][:n], z[:n] * ref["grad"][:n]
        scale = np.maximum(np.max(np.abs(s_r), axis=1), 1e-300)
        out["max_scaled_dgrad"] = float(np.max(np.max(np.abs(s_d - s_r), axis=1) / scale))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--t1", type=float, default=10.0)
    ap.add_argument("--batches", type=int, nargs="+", default=[1024, 16384, 4096])
    ap.add_argument(
        "--programs", nargs="+", default=["jacfwd", "forward"], choices=sorted(PROGRAMS)
    )
    ap.add_argument("--check", type=int, default=4, help="lanes re-solved on the CPU")
    ap.add_argument("--lone", type=int, default=4, help="lanes timed alone on one CPU core")
    ap.add_argument("--runs", type=int, default=2, help="timed runs per (program, batch)")
    ap.add_argument("--budget-s", type=float, default=330.0)
    ap.add_argument("--probe", action="store_true", help="the phase probe first (see above)")
    ap.add_argument("--probe-limit-s", type=float, default=100.0)
    ap.add_argument("--probe-batch", type=int, default=64)
    ap.add_argument("--probe-t1", type=float, default=0.1)
    ap.add_argument("--probe-only", action="store_true", help="the probe alone, then stop")
    ap.add_argument("--out", default=os.environ.get("OUT") or "benchmarks/results/gpu_throughput")
    args = ap.parse_args(argv)
    t_start = time.perf_counter()  # the budget counts the probe too
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    # The probe's processes first, before this one takes the device (and, on a GPU, most
    # of its memory).
    probe = (
        _probe(out_dir, args.probe_limit_s, args.probe_batch, args.probe_t1)
        if args.probe or args.probe_only
        else None
    )
    if args.probe_only:
        R.write_json(out_dir / "gpu_throughput.json", {"probe": probe})
        return
    device = jax.devices()[0]
    versions = {}
    for mod in ("jaxlib", "diffrax", "equinox", "optimistix", "lineax"):
        try:
            versions[mod] = __import__(mod).__version__
        except Exception as e:  # report, do not fail
            versions[mod] = repr(e)
    run = R.run_record()
    if device.platform != "cpu":
        run["machine"] = f"{getattr(device, 'device_kind', device.platform)}, host {run['machine']}"
    record = {
        "run": run,
        "device": str(device),
        "device_kind": getattr(device, "device_kind", ""),
        "jax": jax.__version__,
        "versions": versions,
        "cpu_count": os.cpu_count(),
        "t1": args.t1,
        "horizon": "whole_periods",
        "box": {k: list(v) for k, v in BOX.items()},
        "rows": [],
        "cpu_reference": [],
        "errors": [],
        "skipped": [],
        "probe": probe,
    }
    print(
        json.dumps({k: record[k] for k in ("device", "device_kind", "jax", "versions")}), flush=True
    )

    def save():
        R.write_json(out_dir / "gpu_throughput.json", record)

    z_all = _gaits(max(args.batches))
    z_check = z_all[: args.check]
    ref = {}
    # Each program at the first batch size listed (with its CPU reference), then the rest.
    plan = [(p, b) for b in args.batches for p in args.programs]
    for name, b in plan:
        spent = time.perf_counter() - t_start
        if spent > args.budget_s and (record["rows"] or record["errors"]):  # one at least
            record["skipped"].append({"program": name, "batch": b, "spent_s": spent})
            print(f"skip {name} B={b}: {spent:.0f} s spent", flush=True)
            continue
        try:
            row = _batched(name, z_all[:b], args.t1, device, args.runs)
            out = row.pop("_out")
            if name not in ref:
                ref[name] = _cpu_reference(name, z_check, args.t1, args.lone)
                record["cpu_reference"].append(
                    {k: v for k, v in ref[name].items() if not k.startswith("_")}
                )
            r = ref[name]
            row["cpu_lone_s_per_lane"] = r["run_s_per_lane"]
            row["speedup_vs_one_cpu_core_lone"] = row["lanes_per_s"] * r["run_s_per_lane"]
            row["vs_cpu_batched"] = _compare(out, r["_batched"], z_check)
            lone_out = {k: np.stack([o[k] for o in r["_lone"]]) for k in out}
            row["vs_cpu_lone"] = _compare(out, lone_out, z_check[: args.lone])
        except Exception as e:  # keep what was measured; say what failed
            import traceback

            record["errors"].append(
                {
                    "program": name,
                    "batch": b,
                    "error": repr(e),
                    "traceback": traceback.format_exc()[-4000:],
                }
            )
            save()
            print(f"ERROR {name} B={b}: {traceback.format_exc()[-2000:]}", flush=True)
            continue
        record["rows"].append(row)
        save()
        same, lone = row["vs_cpu_batched"], row["vs_cpu_lone"]
        print(
            f"{name:8s} B={b:6d} compile {row['compile_s']:6.1f} s run {row['run_s']:7.2f} s "
            f"{row['lanes_per_s']:9.1f} lanes/s ({row['speedup_vs_one_cpu_core_lone']:.1f}x one "
            f"CPU core) ok {row['ok_lanes']}/{b} XLA buffers {row['xla_buffer_bytes']} B | vs CPU "
            f"batched dv {same['max_rel_dv']:.1e} dg {same['max_scaled_dgrad']}; "
            f"vs lone dv {lone['max_rel_dv']:.1e} dg {lone['max_scaled_dgrad']}",
            flush=True,
        )
    record["total_s"] = time.perf_counter() - t_start
    save()


if __name__ == "__main__":
    main()

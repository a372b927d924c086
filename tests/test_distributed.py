"""Sweeps across processes of JAX's multi-controller runtime (`jax.distributed`): two
local CPU processes, the coordinator on the loopback interface, through the `jaxworm`
command as a user launches them (one command per process)."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time

import numpy as np
import pytest

import jaxworm as jw

GRID = {"omega": np.linspace(3 * np.pi, 5 * np.pi, 6), "delta": np.linspace(-1.0, -0.5, 5)}
T1 = 30.0
FLAGS = [
    "--grid", "omega=3*pi:5*pi:6", "--grid", "delta=-1:-0.5:5",
    "--set", f"t1={T1}", "--chunk", "1", "--workers", "1", "--quiet",
]  # fmt: skip


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _launch(out, tmp_path, port, index, n=2, extra=()):
    env = dict(os.environ)
    # one device per process, the program cache shared by every process of these tests
    env["XLA_FLAGS"] = "--xla_force_host_platform_device_count=1"
    env["JAXWORM_CACHE_DIR"] = str(tmp_path.parent / "shared-cache")
    cmd = [sys.executable, "-m", "jaxworm", "sweep", *FLAGS, "--out", str(out)]
    cmd += ["--coordinator", f"127.0.0.1:{port}", "--num-processes", str(n)]
    cmd += ["--process-id", str(index), *extra]
    cmd = [c for c in cmd if not (c == "--quiet" and index == 0)]  # process 0 shows progress
    return subprocess.Popen(
        cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path
    )


def _run_both(out, tmp_path):
    port = _free_port()
    procs = [_launch(out, tmp_path, port, i) for i in range(2)]
    outputs = [p.communicate(timeout=600) for p in procs]
    return [p.returncode for p in procs], outputs


@pytest.fixture(scope="module")
def one_process():
    """The same sweep in this process, one device, the same chunks."""
    return jw.sweep(GRID, t1=T1, chunk=1, progress=False)


def _same(a, b) -> bool:
    return all(np.array_equal(a[n], b[n], equal_nan=True) for n in jw.SWEEP_FIELDS)


def test_two_processes_give_the_one_process_sweep_bit_for_bit(one_process, tmp_path):
    out = tmp_path / "two.npz"
    codes, outputs = _run_both(out, tmp_path)
    assert codes == [0, 0], outputs
    assert _same(jw.load_sweep(out), one_process)
    assert one_process.done.all() and (one_process.n_cracks > 0).any()
    # Process 0 reports and shows progress; process 1 does neither (Gloo, the CPU
    # collectives, prints its own connection line on both).
    (out0, err0), (out1, err1) = outputs
    assert "jaxworm sweep: 30 scenes" in out0 and "sweep: 30/30 scenes" in err0
    assert "jaxworm sweep" not in out1 and "sweep:" not in err1


def test_killed_process_then_all_restarted_resumes_without_recomputing(one_process, tmp_path):
    out = tmp_path / "resumed.npz"
    port = _free_port()
    procs = [_launch(out, tmp_path, port, i) for i in range(2)]
    done = 0
    deadline = time.monotonic() + 600
    while time.monotonic() < deadline and done < 4:
        time.sleep(0.02)
        if out.exists():
            try:
                done = int(jw.load_sweep(out).done.sum())
            except jw.ResultFileError:
                done = 0
    procs[1].send_signal(signal.SIGKILL)  # one process dies ...
    procs[1].wait()
    procs[0].send_signal(signal.SIGKILL)  # ... and the user stops the other
    procs[0].wait()
    saved = jw.load_sweep(out)
    d = int(saved.done.sum())
    assert 4 <= d < saved.done.size, f"the kill came too late to test a resume ({d} done)"
    assert _same(
        {n: np.where(saved.done, saved[n], np.nan) for n in jw.SWEEP_FIELDS},
        {n: np.where(saved.done, one_process[n], np.nan) for n in jw.SWEEP_FIELDS},
    )
    codes, ((out0, err0), _) = _run_both(out, tmp_path)
    assert codes == [0, 0], err0
    assert f"sweep: resuming, {d}/30 scenes already done" in err0
    assert _same(jw.load_sweep(out), one_process)


def test_processes_given_different_arguments_are_refused(tmp_path):
    port = _free_port()
    procs = [
        _launch(tmp_path / "x.npz", tmp_path, port, i, extra=("--set", f"t1={T1 + i}"))
        for i in range(2)
    ]
    outputs = [p.communicate(timeout=600) for p in procs]
    assert [p.returncode for p in procs] == [2, 2], outputs
    for _, err in outputs:
        assert "process 1 was given other arguments than process 0" in err, err
    assert not (tmp_path / "x.npz").exists()


_OPTIMISE = """
import os, sys
import jax, jax.numpy as jnp, numpy as np, optax
from jaxworm import _distributed, _optimise
_distributed.initialize(sys.argv[1], 2, int(sys.argv[2]))

def toy(theta):
    v = -jnp.sum((theta - jnp.array([1.0, -1.0])) ** 2)
    return v, {"status": jnp.array(0), "n_cracks": jnp.array(0), "velocity": v}

real, calls = _optimise._step, []
def step(*args):
    calls.append(1)
    if len(calls) == int(sys.argv[4]):
        raise KeyboardInterrupt
    return real(*args)
_optimise._step = step
lo, hi = np.array([0.0, -3.0]), np.array([2.0, 0.0])
header = {"format": "jaxworm-optimise/1", "names": ["a", "b"], "maximise": True,
          "bounds": {"a": [0.0, 2.0], "b": [-3.0, 0.0]}, "objective": "toy", "unit": "-"}
try:
    _optimise._descend(toy, lo, hi, _optimise._initial_points(5, ("a", "b"), lo, hi, 0),
        True, 6, optax.adam(0.3), "map", header, path=sys.argv[3], progress=False, workers=1)
except KeyboardInterrupt:
    sys.stdout.flush()
    os._exit(3)
print("steps", len(calls))
# the leader's signed zero and NaN reach every process bit for bit
mine = np.array([-0.0, np.nan, 1.5]) if int(sys.argv[2]) == 0 else np.zeros(3)
print("bits", _distributed.from_leader(mine).view(np.int64).tolist())
"""


def _optimise_in_two_processes(path, tmp_path, kill_at=0):
    port = _free_port()
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=1")
    env["JAXWORM_CACHE_DIR"] = ""
    procs = [
        subprocess.Popen(
            [sys.executable, "-c", _OPTIMISE, f"127.0.0.1:{port}", str(i), str(path), str(kill_at)],
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            cwd=tmp_path,
        )  # fmt: skip
        for i in range(2)
    ]
    outputs = [p.communicate(timeout=300) for p in procs]
    return [p.returncode for p in procs], outputs


def test_a_killed_optimisation_over_two_processes_resumes_as_if_never_stopped(tmp_path):
    """5 starts over 2 processes (3 and 2): the saved state of every start is gathered to
    process 0, and a rerun hands each process its share of it back."""
    whole, resumed = tmp_path / "whole.npz", tmp_path / "resumed.npz"
    codes, outputs = _optimise_in_two_processes(whole, tmp_path)
    assert codes == [0, 0], outputs
    codes, outputs = _optimise_in_two_processes(resumed, tmp_path, kill_at=4)
    assert codes == [3, 3], outputs
    assert jw.load_optimisation(resumed).steps_done == 3
    codes, outputs = _optimise_in_two_processes(resumed, tmp_path)
    assert codes == [0, 0], outputs
    assert all("steps 3" in out for out, _ in outputs), outputs  # three steps left, not six
    bits = np.array([-0.0, np.nan, 1.5]).view(np.int64).tolist()
    assert all(f"bits {bits}" in out for out, _ in outputs), outputs
    a, b = jw.load_optimisation(whole), jw.load_optimisation(resumed)
    assert a.steps_done == b.steps_done == 6
    for key in ("theta", "value", "grad", "status"):
        np.testing.assert_array_equal(getattr(a, key), getattr(b, key), err_msg=key)
    assert all(np.array_equal(x, y) for x, y in zip(a.state, b.state, strict=True))

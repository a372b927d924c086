"""Result files: damaged files, other runs' files, output checks before any
computation, one writer at a time, a save after every chunk.

Most tests here never solve: a sweep's chunks are replaced by `_fake_chunk` (a
deterministic function of the scene), which exercises the file handling alone. The
last tests run real sweeps in subprocesses, killed with SIGKILL or side by side.
"""

import dataclasses
import importlib.util
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

import jaxworm as jw
from jaxworm import _files, _history, _optimise, _sweep
from jaxworm._cli import main

GRID = {"omega": [3 * np.pi, 4 * np.pi, 5 * np.pi], "delta": [-np.pi / 3, -np.pi / 4]}
T1 = 0.5


def _fake_chunk(calls):
    """A stand-in for `_sweep._run_chunk`: results a function of each scene, every
    call's scenes recorded in `calls`."""

    def run(base, names, values, t1, numerics, horizon="t1"):
        v = np.asarray(values)
        calls.append(v.copy())
        n = len(v)
        return {
            "mean_velocity": 1e-3 * v[:, 0] + 1e-5 * v[:, 1],
            "n_cracks": np.arange(n) % 3,
            "status": np.zeros(n, int),
            "steps": np.full(n, 7),
            "final_head": v[:, 0],
            "final_crack_tip": v[:, 1],
            "energy_residual": np.full(n, 1e-9),
        }

    return run


@pytest.fixture
def calls(monkeypatch):
    """Replace the solve of a sweep's chunks by `_fake_chunk`; the list of its calls."""
    made = []
    monkeypatch.setattr(_sweep, "_run_chunk", _fake_chunk(made))
    monkeypatch.setenv("JAXWORM_CACHE_DIR", "")  # the CLI leaves JAX's cache alone
    return made


@pytest.fixture
def no_solve(monkeypatch):
    """Fail the test if a sweep chunk or an optimiser step is computed."""

    def refuse(*args, **kwargs):
        raise AssertionError("computed although the output was unusable")

    monkeypatch.setattr(_sweep, "_run_chunk", refuse)
    monkeypatch.setattr(_optimise, "_step", refuse)
    monkeypatch.setenv("JAXWORM_CACHE_DIR", "")


def _sweep_file(path, grid=GRID, t1=T1, calls=None):
    """A whole sweep file, as `jw.sweep` writes it (chunks by `_fake_chunk`)."""
    import unittest.mock

    with unittest.mock.patch.object(
        _sweep, "_run_chunk", _fake_chunk([] if calls is None else calls)
    ):
        return jw.sweep(grid, t1=t1, path=path, progress=False, chunk=2)


HEADER = {
    "format": _history.FORMAT,
    "names": ["a", "b"],
    "bounds": {"a": [0.0, 2.0], "b": [-3.0, 0.0]},
    "maximise": True,
    "objective": "toy",
    "unit": "-",
    "t1": 1.0,
}


def _toy(theta):
    import jax.numpy as jnp

    v = -jnp.sum(theta**2)
    return v, {"status": jnp.array(0), "n_cracks": jnp.array(0), "velocity": v}


_SGD = optax.sgd(0.1)  # one object: one compiled step for every history here


def _toy_history(path, steps=3, header=HEADER, overwrite=False, optimiser=_SGD):
    """An optimisation history (the loop `optimise` runs, on a toy objective)."""
    lo, hi = np.array([0.0, -3.0]), np.array([2.0, 0.0])
    theta0 = _optimise._initial_points(2, ("a", "b"), lo, hi, seed=0)
    return _optimise._descend(
        _toy,
        lo,
        hi,
        theta0,
        True,
        steps,
        optimiser,
        "map",
        dict(header),
        path=path,
        progress=False,
        overwrite=overwrite,
        workers=1,  # one _step call per step
    )


def _run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _one_line(code, out, err):
    assert code == 2, (code, out, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    assert "allow_pickle" not in err
    return lines[0]


def _leftovers(folder: Path, name: str) -> list[str]:
    """Temporary or lock files of the output `name` in `folder`."""
    return sorted(
        p.name
        for p in folder.iterdir()
        if p.name.startswith(f".{name}.") or p.name == f"{name}.lock"
    )


# --- the format ------------------------------------------------------------------------------


def test_a_sweep_file_round_trips_and_the_same_results_give_the_same_bytes(tmp_path, calls):
    s = _sweep_file(tmp_path / "a.npz")
    _sweep_file(tmp_path / "b.npz")
    assert (tmp_path / "a.npz").read_bytes() == (tmp_path / "b.npz").read_bytes()
    back = jw.load_sweep(tmp_path / "a.npz")
    assert back["header"]["integrity"].startswith("sha256") and back["done"].all()
    for n in jw.SWEEP_FIELDS:
        assert back[n].tobytes() == s[n].tobytes()
    assert _leftovers(tmp_path, "a.npz") == []


def _damage(kind: str, good: bytes, history: bytes) -> bytes:
    if kind == "empty":
        return b""
    if kind == "truncated_half":
        return good[: len(good) // 2]
    if kind == "truncated_last_byte":
        return good[:-1]
    if kind == "text":
        return b"omega,delta\n1,2\n"
    if kind == "pickled_npy":  # numpy would advise allow_pickle=True for these
        return b"\x80\x04\x95" + good[:50]
    if kind == "npz_of_objects":
        import io

        buf = io.BytesIO()
        np.savez(buf, header=np.array([{"format": "jaxworm-sweep/1"}], dtype=object))
        return buf.getvalue()
    if kind == "optimisation_history":
        return history
    raise ValueError(kind)


DAMAGE = {
    "empty": "empty",
    "truncated_half": "truncated",
    "truncated_last_byte": "truncated",
    "text": "not a jaxworm sweep file",
    "pickled_npy": "not a jaxworm sweep file",
    "npz_of_objects": "pickled Python objects",
    "optimisation_history": "optimisation history, not a jaxworm sweep",
}


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """The bytes of a sweep file and of an optimisation history."""
    folder = tmp_path_factory.mktemp("written")
    _sweep_file(folder / "good.npz")
    _toy_history(folder / "history.npz")
    return (folder / "good.npz").read_bytes(), (folder / "history.npz").read_bytes()


@pytest.fixture
def files(tmp_path, written):
    """`good.npz` (a sweep) and `history.npz` in tmp_path; their bytes."""
    (tmp_path / "good.npz").write_bytes(written[0])
    (tmp_path / "history.npz").write_bytes(written[1])
    return written


@pytest.mark.parametrize("kind", DAMAGE)
def test_a_damaged_or_foreign_file_is_a_named_error_in_the_api_and_exit_2_in_the_cli(
    kind, files, tmp_path, capsys, no_solve
):
    bad = tmp_path / "bad.npz"
    bad.write_bytes(_damage(kind, *files))
    before = bad.read_bytes()
    with pytest.raises(jw.ResultFileError, match=DAMAGE[kind]) as e:
        jw.load_sweep(bad)
    assert isinstance(e.value, ValueError) and e.value.path == str(bad)
    assert str(bad) in str(e.value) and "allow_pickle" not in str(e.value)
    # jaxworm fig3 on it: one line naming the file and the damage
    line = _one_line(*_run(capsys, "fig3", bad, "--out", tmp_path / "f.png"))
    assert str(bad) in line and DAMAGE[kind].split(",")[0] in line
    assert not (tmp_path / "f.png").exists()
    # as a sweep's --out: refused before any solve (no_solve), left as it was
    line = _one_line(
        *_run(
            capsys, "sweep", "--grid", "omega=3*pi,4*pi", "--set", "t1=0.5", "--quiet", "--out", bad
        )
    )
    assert str(bad) in line and "will not overwrite it" in line and "--overwrite" in line
    assert bad.read_bytes() == before and _leftovers(tmp_path, "bad.npz") == []
    if kind != "optimisation_history":
        with pytest.raises(jw.ResultFileError) as e:
            jw.load_optimisation(bad)
        assert str(bad) in str(e.value) and "allow_pickle" not in str(e.value)


def test_a_flipped_byte_is_detected_or_changes_nothing(files, tmp_path):
    good, _ = files
    ref = jw.load_sweep(tmp_path / "good.npz")
    data = ref["mean_velocity"].tobytes()
    at = good.find(data)
    assert at > 0
    rng = np.random.default_rng(15)
    positions = [at + len(data) // 2, *rng.choice(len(good), size=300, replace=False)]
    detected = 0
    bad = tmp_path / "flip.npz"
    for i in positions:
        flipped = bytearray(good)
        flipped[i] ^= 1 << int(rng.integers(8))
        bad.write_bytes(bytes(flipped))
        try:
            s = jw.load_sweep(bad)
        except jw.ResultFileError as e:
            assert "damaged" in str(e) and str(bad) in str(e)
            detected += 1
            continue
        # a byte the reader does not use (a zip timestamp, a version field): same content
        assert i != positions[0], "a flipped byte in the results was not detected"
        assert s["header"] == ref["header"]
        for n in ("done", *jw.SWEEP_FIELDS):
            assert s[n].tobytes() == ref[n].tobytes(), (i, n)
    assert detected > 0.8 * len(positions)


def test_a_member_edited_by_other_tools_is_caught_by_the_checksum(files, tmp_path):
    """Rewritten with numpy (zip CRCs right), not by jaxworm: the checksum no longer fits."""
    with np.load(tmp_path / "good.npz") as f:
        data = dict(f)
    np.savez(tmp_path / "copy.npz", **data)  # the same members: the checksum still fits
    assert jw.load_sweep(tmp_path / "copy.npz")["done"].all()
    data["result_mean_velocity"] = data["result_mean_velocity"].copy()
    data["result_mean_velocity"][0, 0] = 1.0
    np.savez(tmp_path / "edited.npz", **data)
    with pytest.raises(jw.ResultFileError, match="checksum does not match"):
        jw.load_sweep(tmp_path / "edited.npz")


def test_files_written_before_the_checksum_still_load(files, tmp_path):
    """As the histories committed under benchmarks/results: `np.savez`, no checksum."""
    header, arrays = _files.load(tmp_path / "good.npz", "sweep")
    del header["integrity"]
    np.savez(tmp_path / "legacy.npz", header=json.dumps(header), **arrays)
    s = jw.load_sweep(tmp_path / "legacy.npz")
    assert s["done"].all() and "integrity" not in s["header"]
    header["integrity"] = "sha256 of the other members in member 'checksum'"  # but none
    np.savez(tmp_path / "stripped.npz", header=json.dumps(header), **arrays)
    with pytest.raises(jw.ResultFileError, match="checksum is missing"):
        jw.load_sweep(tmp_path / "stripped.npz")


def test_a_damaged_or_foreign_history_is_a_named_error(files, tmp_path):
    good, history = files
    for content, match in [
        (history[:100], "truncated"),
        (b"", "empty"),
        (good, "is a jaxworm sweep file, not a jaxworm optimisation history"),
    ]:
        (tmp_path / "h.npz").write_bytes(content)
        with pytest.raises(jw.ResultFileError, match=match):
            jw.load_optimisation(tmp_path / "h.npz")


# --- nothing overwritten but by the same run -------------------------------------------------


def test_optimise_refuses_a_sweep_file_and_another_optimisations_history(
    files, tmp_path, capsys, no_solve
):
    sweep = tmp_path / "good.npz"
    before = sweep.read_bytes()
    with pytest.raises(jw.ResultFileError, match="is a jaxworm sweep file"):
        jw.optimise(path=sweep, steps=2, progress=False)
    line = _one_line(*_run(capsys, "optimise", "--steps", "2", "--quiet", "--out", sweep))
    assert str(sweep) in line and "will not overwrite" in line
    assert sweep.read_bytes() == before
    history = tmp_path / "history.npz"
    before = history.read_bytes()
    with pytest.raises(jw.ResultFileError, match=r"another optimisation \(t1 differ\)"):
        _toy_history(history, header={**HEADER, "t1": 2.0})
    assert history.read_bytes() == before
    assert _leftovers(tmp_path, "good.npz") == _leftovers(tmp_path, "history.npz") == []


def test_the_same_optimisation_rewrites_its_history_and_overwrite_replaces_another(
    tmp_path, monkeypatch
):
    monkeypatch.setenv("JAXWORM_CACHE_DIR", "")
    path = tmp_path / "h.npz"
    first = _toy_history(path)
    again = _toy_history(path)  # a rerun of the same problem
    np.testing.assert_array_equal(again.value, first.value)
    other = {**HEADER, "t1": 2.0}
    with pytest.raises(jw.ResultFileError, match="another optimisation"):
        _toy_history(path, steps=4, header=other)
    assert jw.load_optimisation(path).steps_done == 3
    _toy_history(path, steps=4, header=other, overwrite=True)
    back = jw.load_optimisation(path)
    assert back.steps_done == 4 and back.header["t1"] == 2.0


def test_a_sweep_file_of_another_grid_is_refused_a_matching_one_resumed(tmp_path, calls, capsys):
    path = tmp_path / "s.npz"
    _sweep_file(path)
    before, n = path.read_bytes(), len(calls)
    other = {**GRID, "delta": [-np.pi / 3, -np.pi / 5]}
    with pytest.raises(jw.ResultFileError, match=r"different sweep \(grid values differ\)"):
        jw.sweep(other, t1=T1, path=path, progress=False)
    line = _one_line(
        *_run(
            capsys,
            "sweep",
            "--grid",
            "omega=3*pi:5*pi:4",
            "--set",
            "t1=0.5",
            "--quiet",
            "--out",
            path,
        )
    )
    assert "different sweep (axes differ)" in line
    assert path.read_bytes() == before and len(calls) == n
    s = jw.sweep(GRID, t1=T1, path=path, progress=False)  # the same sweep: all done
    assert len(calls) == n and path.read_bytes() == before and s["done"].all()
    jw.sweep(other, t1=T1, path=path, progress=False, overwrite=True)
    np.testing.assert_array_equal(jw.load_sweep(path)["coords"]["delta"], other["delta"])
    assert len(calls) > n


def test_overwrite_discards_this_same_sweeps_finished_chunks_as_its_help_says(
    tmp_path, capsys, calls
):
    path = tmp_path / "s.npz"
    argv = ["sweep", "--grid", "omega=3*pi:5*pi:3", "--grid", "delta=-pi/4", "--quiet"]
    assert _run(capsys, *argv, "--chunk", "1", "--out", path)[0] == 0
    n = len(calls)
    assert _run(capsys, *argv, "--out", path)[0] == 0  # the same sweep, all done: resumed
    assert len(calls) == n
    assert _run(capsys, *argv, "--out", path, "--overwrite")[0] == 0  # afresh: solved again
    assert len(calls) > n and jw.load_sweep(path)["done"].all()
    assert main(["sweep", "--help"]) == 0
    usage = " ".join(capsys.readouterr().out.split())
    assert "discarding whatever the file at --out holds, this same sweep's finished" in usage
    assert "resume this same sweep" in usage


_PHASES = np.arange(1, 7) * np.pi / 4
#: Scenes whose flat parameters and model options are equal: only the digest of the
#: whole scene tells each pair apart.
TWINS = {
    "segment wave phases": (
        lambda: jw.SegmentWave(A=np.full(6, 0.02), phase=_PHASES),
        lambda: jw.SegmentWave(A=np.full(6, 0.02), phase=-_PHASES),
    ),
    "reflex gains": (lambda: jw.ReflexWave(), lambda: jw.ReflexWave(gain_stress=0.5)),
    "policy weights": (
        lambda: jw.PolicyMLP.init(jax.random.key(0), 7),
        lambda: jw.PolicyMLP.init(jax.random.key(1), 7),
    ),
    "policy feedback (static)": (
        lambda: jw.PolicyMLP.init(jax.random.key(0), 7),
        lambda: jw.PolicyMLP.init(jax.random.key(0), 7, feedback=False),
    ),
}


@pytest.mark.parametrize("twins", list(TWINS))
def test_a_sweep_file_of_another_gait_is_refused_and_an_equal_scene_resumes(tmp_path, calls, twins):
    make_one, make_other = TWINS[twins]
    one, other = (jw.Params().replace(gait=make()) for make in (make_one, make_other))
    assert one.flat().keys() == other.flat().keys() and one.options() == other.options()
    grid, path = {"E_s": [1e5, 2e5], "K_Ic": [250.0, 300.0]}, tmp_path / "s.npz"
    jw.sweep(grid, base=one, t1=T1, path=path, progress=False)
    before, n = path.read_bytes(), len(calls)
    with pytest.raises(jw.ResultFileError, match=r"different sweep \(base_scene differ\)"):
        jw.sweep(grid, base=other, t1=T1, path=path, progress=False)
    assert path.read_bytes() == before and len(calls) == n
    rebuilt = jw.Params().replace(gait=make_one())  # equal values, new objects: resumes
    assert jw.sweep(grid, base=rebuilt, t1=T1, path=path, progress=False)["done"].all()
    assert path.read_bytes() == before and len(calls) == n
    jw.sweep(grid, base=other, t1=T1, path=path, progress=False, overwrite=True)
    assert len(calls) > n and jw.load_sweep(path).header["base_scene"]["classes"]["gait"] == (
        type(other.gait).__name__
    )


def test_a_sweep_file_written_before_the_scene_digest_loads_and_is_not_resumed(tmp_path, calls):
    path = tmp_path / "s.npz"
    _sweep_file(path)
    header, data = _files.load(path, "sweep")
    del header["base_scene"]
    _files.save(path, header, data)
    assert jw.load_sweep(path).done.all()  # still read
    with pytest.raises(jw.ResultFileError, match=r"different sweep \(base_scene differ\)"):
        jw.sweep(GRID, t1=T1, path=path, progress=False)


def _scaled(k):
    return lambda r: k * r.mean_velocity


_DIGESTS_IN_A_NEW_PROCESS = """
import json, numpy as np, jaxworm as jw
from jaxworm._fingerprint import callable_digest, scene_fingerprint
def _scaled(k):
    return lambda r: k * r.mean_velocity
phases = np.arange(1, 7) * np.pi / 4
scene = jw.Params().replace(gait=jw.SegmentWave(A=np.full(6, 0.02), phase=phases))
print(json.dumps([scene_fingerprint(scene), callable_digest(_scaled(2.5))]))
"""


def test_the_digests_are_functions_of_the_values_alone_in_any_process():
    from jaxworm._fingerprint import callable_digest, scene_fingerprint

    env = {**os.environ, "PYTHONHASHSEED": "random", "JAXWORM_CACHE_DIR": ""}
    out = subprocess.run(
        [sys.executable, "-c", _DIGESTS_IN_A_NEW_PROCESS],
        capture_output=True,
        text=True,
        env=env,
        check=True,
    ).stdout
    scene = jw.Params().replace(gait=jw.SegmentWave(A=np.full(6, 0.02), phase=_PHASES))
    assert json.loads(out) == [scene_fingerprint(scene), callable_digest(_scaled(2.5))]
    assert callable_digest(_scaled(3.0)) != json.loads(out)[1]  # another closure value


class _Scorer:
    def __init__(self, w):
        self.w = w

    def score(self, r):
        return self.w * r.mean_velocity


@dataclasses.dataclass(frozen=True)
class _Weights:
    w: float


class _Slotted:
    __slots__ = ("w",)

    def __init__(self, w):
        self.w = w


class _Proxy:
    __slots__ = ("_d",)

    def __init__(self, **values):
        object.__setattr__(self, "_d", values)

    def __getattr__(self, name):
        return self._d[name]


def _reading(held):
    return lambda r: held.w * r.mean_velocity


def test_objects_a_callable_holds_are_digested_by_what_they_hold():
    """A bound method's object, a dataclass or slotted object in a closure: two weights
    are two objectives (their type name alone made them one, and a rerun with the other
    weight got the first one's history back); equal weights, one digest."""
    from fractions import Fraction

    from jaxworm._fingerprint import callable_digest

    for make in (lambda w: _Scorer(w).score, lambda w: _reading(_Weights(w))):
        assert callable_digest(make(1.0)) != callable_digest(make(-1.0))
        assert callable_digest(make(1.0)) == callable_digest(make(1.0))
    assert callable_digest(_reading(_Slotted(2.0))) != callable_digest(_reading(_Slotted(3.0)))
    assert callable_digest(_reading(Fraction(1, 2))) != callable_digest(_reading(Fraction(1, 3)))
    cyclic = _Scorer(1.0)
    cyclic.me = cyclic  # a cycle ends at the depth limit
    assert callable_digest(cyclic.score) == callable_digest(cyclic.score)
    # What changes as the process runs (a logger's registry, a lock's state) is not
    # followed: a rerun in the same session matches its own file.
    import logging
    import threading

    held = _Scorer(1.0)
    log = logging.getLogger("jaxworm-test")
    held.log, held.lock = log, threading.Lock()
    before, closed = callable_digest(held.score), callable_digest(lambda r: log and r)
    logging.getLogger("jaxworm-test.child")  # the logging manager's registry grows
    log.debug("x")  # the logger's level cache fills
    with held.lock:
        assert callable_digest(held.score) == before
    assert callable_digest(lambda r: log and r) == closed
    # Data nested deeper counts (an evaluator holding a config holding the weight).
    assert callable_digest(_Scorer(_Weights(1.0)).score) != callable_digest(
        _Scorer(_Weights(2.0)).score
    )
    # An object whose __getattr__ answers every name (a config proxy) is digested by
    # what it holds, not asked for __dict__ (which raised KeyError in the header).
    assert callable_digest(_reading(_Proxy(w=2.0))) != callable_digest(_reading(_Proxy(w=3.0)))


def _headers_of(monkeypatch, runs: list[dict]) -> list[dict]:
    """The headers `jw.optimise` builds for each of `runs` (its keyword arguments),
    nothing computed."""
    headers = []
    with monkeypatch.context() as m:
        m.setattr(_optimise, "_descend", lambda *a, **k: headers.append(a[8]))
        for kwargs in runs:
            jw.optimise(**{"steps": 2, "starts": 2, "progress": False, **kwargs})
    return headers


def _phase_setter(sign):
    """An `apply` of optimise: a segment wave of amplitude θ_0 and phases sign·θ_1·(π/4)k."""

    def set_phases(base, names, theta):
        return base.replace(
            gait=jw.SegmentWave(A=theta[0] * np.ones(6), phase=sign * theta[1] * _PHASES)
        )

    return set_phases


def test_optimisations_of_other_callables_or_scenes_are_other_problems(tmp_path, monkeypatch):
    monkeypatch.setenv("JAXWORM_CACHE_DIR", "")
    bounds = {"E_s": (1e5, 2e5), "mu_s": (0.2, 0.45)}
    g1 = jw.SegmentWave(A=np.full(6, 0.02), phase=_PHASES)
    g2 = jw.SegmentWave(A=np.full(6, 0.02), phase=-_PHASES)
    k = 2.0
    scaled = lambda r: k * r.mean_velocity  # noqa: E731
    runs = {
        "velocity": dict(objective=lambda r: r.mean_velocity),
        "energy": dict(objective=lambda r: -r.energy_residual),
        "velocity again": dict(objective=lambda r: r.mean_velocity),
        "scaled": dict(objective=scaled),
        "gait 1": dict(base=jw.Params().replace(gait=g1)),
        "gait 2": dict(base=jw.Params().replace(gait=g2)),
        "apply": dict(apply=_phase_setter(1.0), bounds={"a": (0.01, 0.03), "p": (0.5, 1.5)}),
        "apply reversed": dict(
            apply=_phase_setter(-1.0), bounds={"a": (0.01, 0.03), "p": (0.5, 1.5)}
        ),
        "ts": dict(ts=np.linspace(0.1, 1.0, 4)),
        "other ts": dict(ts=np.linspace(0.1, 1.0, 5)),
    }
    kw = dict(bounds=bounds, maximise=True, t1=1.0, horizon="t1")
    h = dict(zip(runs, _headers_of(monkeypatch, [{**kw, **r} for r in runs.values()])))
    differ = _history._same_problem
    assert differ(h["velocity"], h["energy"]) == ["objective_sha256"]
    assert h["velocity"]["objective"] == h["energy"]["objective"] == "<lambda>"
    assert differ(h["velocity"], h["velocity again"]) == []
    k = 3.0  # the same function, another value in its closure
    assert differ(h["scaled"], _headers_of(monkeypatch, [{**kw, "objective": scaled}])[0]) == [
        "objective_sha256"
    ]
    assert differ(h["gait 1"], h["gait 2"]) == ["base_scene"]
    assert differ(h["apply"], h["apply reversed"]) == ["apply_sha256"]
    assert differ(h["ts"], h["other ts"]) == ["ts_sha256"]
    # The file: the history of one lambda is refused to the other, kept whole.
    path = tmp_path / "h.npz"
    _toy_history(path, header=h["velocity"])
    before = path.read_bytes()
    with pytest.raises(jw.ResultFileError, match=r"another optimisation \(objective_sha256"):
        _toy_history(path, header=h["energy"])
    assert path.read_bytes() == before
    _toy_history(path, header=h["velocity again"])  # the same problem: rewritten


# --- outputs checked before any computation --------------------------------------------------


def test_unusable_sweep_outputs_are_refused_before_any_solve_naming_the_given_path(
    tmp_path, capsys, no_solve
):
    missing = tmp_path / "nonexistent" / "dir" / "s.npz"
    with pytest.raises(jw.ResultFileError, match="folder .* does not exist") as e:
        jw.sweep(GRID, t1=T1, path=missing, progress=False)
    assert e.value.path == str(missing) and ".tmp" not in str(e.value)
    start = time.perf_counter()
    line = _one_line(
        *_run(capsys, "sweep", "--grid", "omega=3*pi,4*pi", "--quiet", "--out", missing)
    )
    assert time.perf_counter() - start < 10.0
    assert str(missing) in line and "does not exist" in line and ".tmp" not in line
    assert not missing.parent.parent.exists()
    with pytest.raises(jw.ResultFileError, match="is a folder"):
        jw.sweep(GRID, t1=T1, path=tmp_path, progress=False)
    assert list(tmp_path.iterdir()) == []


def test_unusable_optimise_outputs_are_refused_before_any_step(tmp_path, capsys, no_solve):
    folder = tmp_path / "adir"
    folder.mkdir()
    line = _one_line(*_run(capsys, "optimise", "--steps", "2", "--quiet", "--out", folder))
    assert str(folder) in line and "is a folder" in line
    assert list(folder.iterdir()) == [] and sorted(p.name for p in tmp_path.iterdir()) == ["adir"]
    with pytest.raises(jw.ResultFileError, match="does not exist"):
        jw.optimise(path=tmp_path / "no" / "h.npz", steps=2, progress=False)
    line = _one_line(
        *_run(
            capsys,
            "optimise",
            "--steps",
            "2",
            "--quiet",
            "--plot",
            tmp_path / "no" / "p.png",
            "--out",
            tmp_path / "h.npz",
        )
    )
    assert "--plot" in line and "does not exist" in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["adir"]


@pytest.mark.skipif(
    hasattr(os, "geteuid") and os.geteuid() == 0, reason="root may write in any folder"
)
def test_a_folder_without_write_permission_is_refused_at_once(tmp_path, no_solve):
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o500)
    try:
        with pytest.raises(jw.ResultFileError, match="no permission"):
            jw.sweep(GRID, t1=T1, path=folder / "s.npz", progress=False)
    finally:
        folder.chmod(0o700)


def test_fig3_prints_the_file_it_writes_and_creates_no_folder(files, tmp_path, capsys):
    sweep = tmp_path / "good.npz"
    code, out, err = _run(capsys, "fig3", sweep, "--out", tmp_path / "fig")
    assert code == 0, err
    assert out.strip() == f"jaxworm fig3: {tmp_path / 'fig.png'}"
    assert (tmp_path / "fig.png").read_bytes()[:4] == b"\x89PNG"
    line = _one_line(*_run(capsys, "fig3", sweep, "--out", tmp_path / "no" / "f.png"))
    assert "does not exist" in line and not (tmp_path / "no").exists()
    (tmp_path / "adir").mkdir()
    line = _one_line(*_run(capsys, "fig3", sweep, "--out", tmp_path / "adir"))
    assert "is a folder" in line and list((tmp_path / "adir").iterdir()) == []
    assert "unknown figure format" in _one_line(
        *_run(capsys, "fig3", sweep, "--out", tmp_path / "f.npz")
    )


def test_a_result_file_and_a_figure_naming_one_file_are_refused_before_any_solve(
    tmp_path, capsys, calls, monkeypatch
):
    monkeypatch.setattr(_optimise, "_step", None)  # no optimiser step may run

    def refused(*argv):
        line = _one_line(*_run(capsys, *argv))
        assert "name the same file" in line and "Traceback" not in line
        return line

    # GRID and T1, as `_sweep_file` writes them
    grid = ("--grid", "omega=3*pi:5*pi:3", "--grid", "delta=-pi/3,-pi/4", "--set", "t1=0.5")
    grid = (*grid, "--quiet")
    same = tmp_path / "r.png"
    line = refused("sweep", *grid, "--out", same, "--plot", same)
    assert f"--out {str(same)!r} and --plot {str(same)!r}" in line
    (tmp_path / "sub").mkdir()
    refused("sweep", *grid, "--out", same, "--plot", tmp_path / "sub" / ".." / "r.png")
    (tmp_path / "link.png").symlink_to(same)
    refused("sweep", *grid, "--out", same, "--plot", tmp_path / "link.png")
    assert not same.exists() and calls == []
    refused("optimise", "--steps", "2", "--quiet", "--out", same, "--plot", same)
    assert not same.exists()
    # A sweep file named like a figure: never drawn over by its own heatmap.
    _sweep_file(same)
    before = same.read_bytes()
    line = refused("fig3", same, "--out", same)
    assert "sweep file" in line and "--out" in line
    line = refused("optimise", "--steps", "2", "--quiet", "--heatmap", same, "--plot", same)
    assert "--plot" in line and "--heatmap" in line
    assert same.read_bytes() == before
    code, out, err = _run(capsys, "sweep", *grid, "--out", same, "--plot", tmp_path / "f.png")
    assert code == 0, err  # two files: it runs (and resumes the sweep in r.png)


# --- chunks: each saved when done, the same cuts on resume -----------------------------------


def test_each_chunk_is_saved_when_done_and_a_resume_cuts_the_same_chunks(tmp_path, monkeypatch):
    import jax

    monkeypatch.setenv("JAXWORM_CACHE_DIR", "")
    grid = {"omega": np.linspace(3, 5, 5) * np.pi, "delta": [-np.pi / 3, -np.pi / 4]}
    whole = []
    monkeypatch.setattr(_sweep, "_run_chunk", _fake_chunk(whole))
    jw.sweep(grid, t1=T1, path=tmp_path / "whole.npz", progress=False, chunk=3)

    class Killed(Exception):
        pass

    seen = []
    fake = _fake_chunk(seen)

    def killed_on_the_third(*args, **kwargs):
        if len(seen) == 2:
            raise Killed
        return fake(*args, **kwargs)

    monkeypatch.setattr(_sweep, "_run_chunk", killed_on_the_third)
    path = tmp_path / "s.npz"
    with pytest.raises(Killed):  # one worker: the third call is the third chunk
        jw.sweep(grid, t1=T1, path=path, progress=False, chunk=3, workers=1)
    assert jw.load_sweep(path)["done"].ravel().tolist() == [True] * 6 + [False] * 4
    assert _leftovers(tmp_path, "s.npz") == []
    # resumed on two devices without --chunk: the file's chunks, only those not done
    rest = []
    monkeypatch.setattr(_sweep, "_run_chunk", _fake_chunk(rest))
    jw.sweep(grid, t1=T1, path=path, progress=False, devices=[jax.devices()[0]] * 2)
    # the same chunks, each solved once (workers take them in no fixed order)
    assert sorted(c.tolist() for c in seen + rest) == sorted(c.tolist() for c in whole)
    assert len(seen + rest) == len(whole)
    assert path.read_bytes() == (tmp_path / "whole.npz").read_bytes()


def test_default_chunks_stay_within_the_time_target_by_the_measured_cost():
    fast = jw.PRESETS["fast"]
    a, b = _sweep.CHUNK_COST["fast"]
    for total, devices, t1 in [(441, 2, 60.0), (49, 2, 60.0), (441, 1, 600.0), (9, 4, 1.0)]:
        c = _sweep.default_chunk(total, devices, t1, fast)
        assert 1 <= c <= 64
        assert c == 1 or t1 * (a + b * c) <= _sweep.CHUNK_SECONDS, (total, devices, t1, c)
        rounds = -(-total // (c * devices))
        assert rounds * c * devices - total < c * devices  # no round of padding alone
    assert _sweep.default_chunk(441, 2, 1e5, fast) == 1
    # not a preset: the costliest model, so no larger chunks
    odd = fast.replace(rtol=1e-5)
    assert _sweep.default_chunk(441, 2, 10.0, odd) <= _sweep.default_chunk(441, 2, 10.0, fast)


# --- one writer at a time --------------------------------------------------------------------


def _holder(path: Path):
    """A process that holds the lock of `path` (jaxworm's `_files`, loaded alone: no JAX)
    until its stdin closes; returns it once the lock is held."""
    code = (
        "import importlib.util, sys\n"
        f"spec = importlib.util.spec_from_file_location('f', {_files.__file__!r})\n"
        "f = importlib.util.module_from_spec(spec); spec.loader.exec_module(f)\n"
        "with f.claim(sys.argv[1]):\n"
        "    print('locked', flush=True); sys.stdin.read()\n"
    )
    p = subprocess.Popen(
        [sys.executable, "-c", code, str(path)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    assert p.stdout.readline().strip() == "locked"
    return p


def test_a_second_writer_is_refused_at_once_and_a_killed_writers_lock_is_taken_over(
    tmp_path, capsys, calls
):
    assert importlib.util  # the holder loads _files by path
    path = tmp_path / "s.npz"
    holder = _holder(path)
    try:
        start = time.perf_counter()
        with pytest.raises(
            jw.ResultFileError, match=rf"another jaxworm process \(pid {holder.pid}"
        ):
            jw.sweep(GRID, t1=T1, path=path, progress=False)
        with pytest.raises(jw.ResultFileError, match="another jaxworm process"):
            _toy_history(path)
        line = _one_line(
            *_run(capsys, "sweep", "--grid", "omega=3*pi,4*pi", "--quiet", "--out", path)
        )
        assert str(path) in line and f"pid {holder.pid}" in line and "wait for it" in line
        assert time.perf_counter() - start < 10.0 and calls == [] and not path.exists()
    finally:
        holder.kill()  # SIGKILL: its lock file stays, its lock goes with it
        holder.wait()
    assert (tmp_path / "s.npz.lock").exists()
    s = jw.sweep(GRID, t1=T1, path=path, progress=False)
    assert s["done"].all() and _leftovers(tmp_path, "s.npz") == []


def test_a_filesystem_that_refuses_locks_is_written_unlocked_with_a_warning(tmp_path, monkeypatch):
    import errno
    import fcntl

    def refuse(fd, op):
        raise OSError(errno.ENOLCK, "No locks available")

    monkeypatch.setattr(fcntl, "flock", refuse)
    path = tmp_path / "h.npz"
    with pytest.warns(UserWarning, match=r"h\.npz' is written unlocked.*No locks available"):
        with _files.claim(path) as claimed:
            assert claimed == path.resolve()


def test_a_writer_through_a_link_is_refused_while_its_file_is_written_and_the_link_stays(
    tmp_path, capsys, calls
):
    real, link = tmp_path / "c3.npz", tmp_path / "l3.npz"
    link.symlink_to("c3.npz")  # as `ln -s c3.npz l3.npz`, before c3.npz exists
    holder = _holder(real)  # process A writes c3.npz
    try:
        with pytest.raises(
            jw.ResultFileError, match=rf"another jaxworm process \(pid {holder.pid}"
        ):
            jw.sweep(GRID, t1=T1, path=link, progress=False)  # process B, through the link
        line = _one_line(
            *_run(capsys, "sweep", "--grid", "omega=3*pi,4*pi", "--quiet", "--out", link)
        )
        assert f"pid {holder.pid}" in line
        assert calls == [] and not real.exists() and link.is_symlink()
    finally:
        holder.kill()
        holder.wait()
    s = jw.sweep(GRID, t1=T1, path=link, progress=False)  # alone now: written through it
    assert link.is_symlink() and os.readlink(link) == "c3.npz"
    assert real.is_file() and not real.is_symlink()
    np.testing.assert_array_equal(jw.load_sweep(real)["mean_velocity"], s["mean_velocity"])
    calls.clear()
    jw.sweep(GRID, t1=T1, path=real, progress=False)  # either name resumes the one file
    assert calls == [] and _leftovers(tmp_path, "l3.npz") == []


# --- sweeps in subprocesses: killed, and two at once ------------------------------------------
#
# The tests run without the jaxworm cache, so every process that solves would compile a
# chunk anew (~10-20 s). These processes
# run the real `jaxworm sweep` (parsing, checks, lock, chunks, saves, progress) with
# `_SLOW_FAKE` for the solve of a chunk: a fixed time per chunk, results a function of
# the scenes. That a resumed sweep of real solves is bit-identical to an uninterrupted
# one, given the same chunks, is tested in test_sweep.py.

SUB_ARGV = [
    "--grid",
    "omega=3*pi:5*pi:4",
    "--grid",
    "delta=-pi/3:-pi/6:3",
    "--set",
    "t1=0.5",
    "--chunk",
    "1",
    "--workers",
    "1",
]
SUB_SCENES = 12
CHUNK_S = 0.25
_SLOW_FAKE = f"""
import sys, time
import numpy as np
from jaxworm import _sweep
from jaxworm._cli import main


def run(base, names, values, t1, numerics, horizon="t1"):
    time.sleep({CHUNK_S})
    v = np.asarray(values)
    n = len(v)
    return {{"mean_velocity": 1e-3 * v[:, 0] + 1e-5 * v[:, 1], "n_cracks": np.arange(n) % 3,
            "status": np.zeros(n, int), "steps": np.full(n, 7), "final_head": v[:, 0],
            "final_crack_tip": v[:, 1], "energy_residual": np.full(n, 1e-9)}}


_sweep._run_chunk = run
sys.exit(main(sys.argv[1:]))
"""


class _Sweep:
    """`jaxworm sweep` in a subprocess (one worker: one chunk in flight), its
    progress lines (written after each save) read as they come."""

    def __init__(self, out: Path):
        env = {
            **os.environ,
            "JAXWORM_CACHE_DIR": "",
            "PYTHONPATH": os.pathsep.join(
                [str(Path(jw.__file__).parents[1]), os.environ.get("PYTHONPATH", "")]
            ),
        }
        self.proc = subprocess.Popen(
            [sys.executable, "-c", _SLOW_FAKE, "sweep", *SUB_ARGV, "--out", str(out)],
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
        )
        self.err, self.events = b"", []
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()

    def _read(self):
        while chunk := os.read(self.proc.stderr.fileno(), 4096):
            self.err += chunk
            for _ in re.findall(rb"sweep: (\d+)/", chunk):
                self.events.append(time.perf_counter())

    def progress(self) -> list[int]:
        return [int(k) for k in re.findall(rb"sweep: (\d+)/", self.err)]

    def wait_for_progress(self, timeout=120.0):
        end = time.perf_counter() + timeout
        while not self.events:
            assert self.proc.poll() is None, self.err.decode()
            assert time.perf_counter() < end, "no chunk finished in time"
            time.sleep(0.005)

    def finish(self):
        self.proc.wait(timeout=120)
        self.reader.join(timeout=10)
        return self.proc.returncode


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    """A sweep run to its end in a subprocess while this process, a second writer, tries
    the same output through the API and the command line."""
    out = tmp_path_factory.mktemp("subprocess_sweeps") / "whole.npz"
    first = _Sweep(out)
    first.wait_for_progress()
    refusals = []
    start = time.perf_counter()
    try:
        jw.sweep({"omega": [4 * np.pi]}, t1=0.5, path=out, progress=False)
    except jw.ResultFileError as e:
        refusals.append(str(e))
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("JAXWORM_CACHE_DIR", "")
        refusals.append(main(["sweep", *SUB_ARGV, "--out", str(out), "--quiet"]))
    refused_s = time.perf_counter() - start
    running = first.proc.poll() is None
    assert first.finish() == 0, first.err.decode()
    return {
        "out": out,
        "refusals": refusals,
        "refused_s": refused_s,
        "running": running,
        "progress": first.progress(),
        "pid": first.proc.pid,
    }


def test_two_writers_the_second_is_refused_at_once_and_nothing_is_lost(uninterrupted):
    u = uninterrupted
    assert u["running"], "the first sweep ended before the second writer came"
    message, code = u["refusals"]
    assert f"is being written by another jaxworm process (pid {u['pid']}" in message
    assert code == 2 and u["refused_s"] < 5.0
    s = jw.load_sweep(u["out"])
    assert s["done"].all() and s["done"].size == SUB_SCENES
    assert u["progress"] == list(range(1, SUB_SCENES + 1))  # a save after every chunk


def test_random_kills_lose_at_most_the_chunk_in_flight_and_the_result_is_bit_identical(
    uninterrupted, tmp_path
):
    rng = np.random.default_rng(15)
    path = tmp_path / "killed.npz"
    saved = 0
    for _kill in range(2):
        run = _Sweep(path)
        run.wait_for_progress()
        time.sleep(rng.uniform(0.0, 2.5) * CHUNK_S)
        run.proc.send_signal(signal.SIGKILL)
        assert run.finish() == -signal.SIGKILL, "the sweep ended before its kill"
        progress = run.progress()
        # it resumed after the scenes saved before: one save per chunk (scene), in order
        assert progress == list(range(saved + 1, saved + 1 + len(progress)))
        s = jw.load_sweep(path)  # whole after a kill: saves are atomic
        saved = int(s["done"].sum())
        # everything reported was saved; beyond it at most the chunk in flight
        assert progress[-1] <= saved <= progress[-1] + 1
        assert saved < SUB_SCENES
    last = _Sweep(path)
    assert last.finish() == 0, last.err.decode()
    assert last.progress() == list(range(saved + 1, SUB_SCENES + 1))
    assert path.read_bytes() == uninterrupted["out"].read_bytes()
    assert _leftovers(tmp_path, "killed.npz") == []


def test_an_optimisations_header_is_the_same_for_the_same_problem(monkeypatch):
    """A rerun (another process, new optimiser objects) must match its own history: no
    memory addresses in the optimiser's description."""
    headers = []
    monkeypatch.setattr(_optimise, "_descend", lambda *a, **k: headers.append(a[8]))
    for _ in range(2):
        jw.optimise(optimiser=optax.adam(0.1), steps=2, progress=False)
    assert "0x" not in headers[0]["optimiser"] and headers[0] == headers[1]
    assert _history._same_problem(headers[0], headers[1]) == []


def test_an_optimisations_header_tells_the_optimisers_hyperparameters_apart(monkeypatch):
    """adam(0.1) and adam(0.2) print alike; a history of one must not be resumed as the
    other's (the fingerprint of their updates differs), while a rebuilt adam(0.1) matches."""
    headers = []
    monkeypatch.setattr(_optimise, "_descend", lambda *a, **k: headers.append(a[8]))
    for opt in (optax.adam(0.1), optax.adam(0.2), optax.adam(0.1, b1=0.8), optax.adam(0.1)):
        jw.optimise(optimiser=opt, steps=2, progress=False)
    described = [h["optimiser"] for h in headers]
    assert all("behaviour " in d for d in described), described
    assert len(set(described[:3])) == 3 and described[3] == described[0]
    assert _history._same_problem(headers[0], headers[1]) != []


_ADAM = optax.adam(0.3)  # a state of its own (moments, count): a resume must restore it


def _counting_step(monkeypatch, kill_at=None):
    """`_optimise._step`, counted (the list returned), raising KeyboardInterrupt at its
    call number `kill_at` (a kill between two steps)."""
    real, calls = _optimise._step, []

    def step(*args, **kwargs):
        calls.append(1)
        if len(calls) == kill_at:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(_optimise, "_step", step)
    return calls


def _without_state(path):
    """Rewrite the history at `path` as an older jaxworm wrote it: no saved state."""
    old = jw.load_optimisation(path)
    _history.save_history(path, dataclasses.replace(old, state=None))


_RECORDS = ("theta", "value", "grad", "status", "n_cracks", "velocity")


def test_a_killed_optimisation_resumes_from_its_last_step_as_if_never_stopped(
    tmp_path, monkeypatch
):
    monkeypatch.setenv("JAXWORM_CACHE_DIR", "")
    whole = _toy_history(tmp_path / "whole.npz", steps=6, optimiser=_ADAM)
    path = tmp_path / "h.npz"
    with monkeypatch.context() as m:
        _counting_step(m, kill_at=4)
        with pytest.raises(KeyboardInterrupt):
            _toy_history(path, steps=6, optimiser=_ADAM)
    assert jw.load_optimisation(path).steps_done == 3
    calls = _counting_step(monkeypatch)
    resumed = _toy_history(path, steps=6, optimiser=_ADAM)
    assert len(calls) == 3  # the three steps left, not six
    back = jw.load_optimisation(path)
    for res in (resumed, back):
        assert res.steps_done == 6
        for key in _RECORDS:
            np.testing.assert_array_equal(getattr(res, key), getattr(whole, key), err_msg=key)
    assert np.all(np.diff(back.wall_time) >= 0)  # the earlier run's time counted on
    # A finished history is returned as it is, nothing solved; overwrite recomputes it.
    assert _toy_history(path, steps=6, optimiser=_ADAM).steps_done == 6 and len(calls) == 3
    _toy_history(path, steps=6, optimiser=_ADAM, overwrite=True)
    assert len(calls) == 9


def test_a_resume_on_fewer_cores_cuts_the_starts_as_the_run_it_continues(tmp_path, monkeypatch):
    # The starts are cut into one group per core (`workers`), and a batch of another size
    # is another program, which rounds differently: a rerun with another core count
    # (a smaller CPU affinity, another machine) continued the history with other groups
    # and its steps came out up to 1.7 % apart, with nothing said. The history records
    # its groups; a rerun that is not told `workers` takes them, one that is told others
    # is refused.
    monkeypatch.setenv("JAXWORM_CACHE_DIR", "")
    lo, hi = np.array([0.0, -3.0]), np.array([2.0, 0.0])
    theta0 = _optimise._initial_points(4, ("a", "b"), lo, hi, seed=0)

    def history(path, cores, workers=None):
        monkeypatch.setattr(_optimise, "default_workers", lambda devices: cores)
        return _optimise._descend(
            _toy, lo, hi, theta0, True, 5, _ADAM, "map", dict(HEADER),
            path=path, progress=False, workers=workers,
        )  # fmt: skip

    whole = history(tmp_path / "whole.npz", cores=2)
    assert whole.header["workers"] == 2
    path = tmp_path / "h.npz"
    with monkeypatch.context() as m:
        _counting_step(m, kill_at=5)  # two groups a step: in the third step
        with pytest.raises(KeyboardInterrupt):
            history(path, cores=2)
    assert jw.load_optimisation(path).steps_done == 2
    calls = _counting_step(monkeypatch)
    resumed = history(path, cores=1)  # one core now: the file's two groups all the same
    assert len(calls) == 3 * 2 and resumed.header["workers"] == 2
    for key in _RECORDS:
        np.testing.assert_array_equal(getattr(resumed, key), getattr(whole, key), err_msg=key)
    with pytest.raises(jw.ResultFileError, match="workers"):
        history(path, cores=1, workers=1)
    # A history written before the groups were recorded is the same problem still.
    old = {k: v for k, v in whole.header.items() if k != "workers"}
    assert _history._same_problem(old, whole.header) == []
    assert _history._same_problem(whole.header, old) == []  # a run of several processes
    # A record that does not cut these starts into equal groups (a run of another number
    # of starts per process, or an edited file): resumed with the default groups, and said.
    bad = tmp_path / "bad.npz"
    with monkeypatch.context() as m:
        _counting_step(m, kill_at=5)
        with pytest.raises(KeyboardInterrupt):
            history(bad, cores=2)
    h = jw.load_optimisation(bad)
    _history.save_history(bad, dataclasses.replace(h, header={**h.header, "workers": 3}))
    with pytest.warns(RuntimeWarning, match="records workers = 3"):
        again = history(bad, cores=1)
    assert again.steps_done == 5 and again.header["workers"] == 1


@pytest.mark.parametrize(
    "optimiser",
    [
        # optax's noisy_sgd keeps a JAX PRNG key, which NumPy cannot hold: its key data
        # is saved, and the key rebuilt.
        optax.noisy_sgd(0.05, key=jax.random.key(0)),
        # NumPy has no bfloat16: its .npy member read back as another dtype and the
        # file's checksum failed (a finished history could not be loaded): saved by bits.
        optax.adam(0.3, mu_dtype=jnp.bfloat16),
    ],
    ids=["prng-key", "bfloat16"],
)
def test_optimiser_states_numpy_cannot_hold_are_saved_and_resumed(tmp_path, monkeypatch, optimiser):
    monkeypatch.setenv("JAXWORM_CACHE_DIR", "")
    whole = _toy_history(tmp_path / "whole.npz", steps=4, optimiser=optimiser)
    assert jw.load_optimisation(tmp_path / "whole.npz").steps_done == 4
    path = tmp_path / "h.npz"
    with monkeypatch.context() as m:
        _counting_step(m, kill_at=3)
        with pytest.raises(KeyboardInterrupt):
            _toy_history(path, steps=4, optimiser=optimiser)
    calls = _counting_step(monkeypatch)
    resumed = _toy_history(path, steps=4, optimiser=optimiser)
    assert len(calls) == 2
    for key in _RECORDS:
        np.testing.assert_array_equal(getattr(resumed, key), getattr(whole, key), err_msg=key)


def test_a_broadcast_from_the_leader_keeps_every_bit():
    """JAX broadcasts by a sum with zeros (-0.0 + 0.0 = +0.0): arrays travel as bytes."""
    from jaxworm._distributed import _bits, _unbits

    for a in (
        np.array([-0.0, np.nan, 1.5]),
        np.array(-0.0),
        np.array([[1 + 2j, -0.0j]])[:, ::-1],
        np.array([-0.0, 1.5], dtype=jnp.bfloat16),
        np.zeros(0),
        np.array([True, False]),
        np.array([-(2**62)], np.int64),
    ):
        back = _unbits(_bits(a), a)
        assert back.dtype == a.dtype and back.shape == a.shape
        assert back.tobytes() == a.copy(order="C").tobytes()


def test_optimisers_differing_late_in_the_run_are_other_problems():
    """Two schedules that differ after the first five steps (the probe's old length)
    were one header: a rerun with the other got the first one's history back."""
    from jaxworm._optimise import describe_optimiser

    a = optax.adam(optax.piecewise_constant_schedule(0.1, {10: 0.5}))
    b = optax.adam(optax.piecewise_constant_schedule(0.1, {20: 0.5}))
    assert describe_optimiser(a, 30) != describe_optimiser(b, 30)
    assert describe_optimiser(a, 10) == describe_optimiser(b, 10)  # alike over 10 steps
    assert describe_optimiser(a, 30) == describe_optimiser(
        optax.adam(optax.piecewise_constant_schedule(0.1, {10: 0.5})), 30
    )


def test_a_history_without_a_state_is_recomputed_with_a_warning_and_kept_until_then(
    tmp_path, monkeypatch
):
    monkeypatch.setenv("JAXWORM_CACHE_DIR", "")
    path = tmp_path / "h.npz"
    first = _toy_history(path, steps=3)
    _without_state(path)
    with monkeypatch.context() as m:
        _counting_step(m, kill_at=3)
        with pytest.warns(RuntimeWarning, match="cannot resume .*keeps no optimiser state"):
            with pytest.raises(KeyboardInterrupt):
                _toy_history(path, steps=3)  # two steps recomputed, then killed
    back = jw.load_optimisation(path)
    assert back.steps_done == 3 and back.state is None  # left whole
    np.testing.assert_array_equal(back.value, first.value)
    calls = _counting_step(monkeypatch)
    with pytest.warns(RuntimeWarning, match="recomputing from step 0"):
        again = _toy_history(path, steps=3)
    assert len(calls) == 3
    np.testing.assert_array_equal(again.value, first.value)
    assert jw.load_optimisation(path).state is not None


def test_a_history_of_another_jaxworm_version_is_recomputed_not_resumed(tmp_path, monkeypatch):
    monkeypatch.setenv("JAXWORM_CACHE_DIR", "")
    path = tmp_path / "h.npz"
    _toy_history(path, steps=3, header={**HEADER, "version": "0.0.1"})
    calls = _counting_step(monkeypatch)
    with pytest.warns(RuntimeWarning, match="written by jaxworm 0.0.1"):
        _toy_history(path, steps=3, header={**HEADER, "version": "0.0.2"})
    assert len(calls) == 3


def test_a_saved_state_that_does_not_fit_the_optimiser_is_not_restored(tmp_path, monkeypatch):
    monkeypatch.setenv("JAXWORM_CACHE_DIR", "")
    path = tmp_path / "h.npz"
    _toy_history(path, steps=2, optimiser=_ADAM)
    calls = _counting_step(monkeypatch)
    # the same header, another optimiser state (SGD keeps none): refused, recomputed
    with pytest.warns(RuntimeWarning, match="saved state has 5 arrays, the optimiser's 2"):
        _toy_history(path, steps=2)
    assert len(calls) == 2
    res = jw.load_optimisation(path)
    arrays = {k: getattr(res, k) for k in _history._HISTORY}
    arrays |= {"steps_done": np.asarray(2), "state_0": res.state[0], "state_2": res.state[1]}
    _files.save(path, res.header, arrays)
    with pytest.raises(jw.ResultFileError, match=r"state's members \[0, 2\] are not numbered"):
        jw.load_optimisation(path)


def _standing_step(problem, optimiser, batch, derivatives, z, z_good, opt_state):
    """A stand-in for `_optimise._step`: every run ok, value 0, no move."""
    n = z.shape[0]
    zeros = jnp.zeros(n)
    out = {"value": zeros, "grad": jnp.zeros_like(z), "velocity": zeros}
    out |= {"status": jnp.zeros(n, int), "n_cracks": jnp.zeros(n, int)}
    return z, z_good, opt_state, out


def test_the_command_line_resumes_an_optimisation_and_warns_in_one_line(
    tmp_path, monkeypatch, capsys
):
    monkeypatch.setattr(_optimise, "_step", _standing_step)
    monkeypatch.setenv("JAXWORM_CACHE_DIR", "")
    monkeypatch.chdir(tmp_path)
    argv = ("optimise", "--steps", "2", "--starts", "2", "--set", "t1=0.7", "--out", "h.npz")
    code, _, err = _run(capsys, *argv)
    assert code == 0 and "warning" not in err
    _without_state(tmp_path / "h.npz")  # as an older jaxworm wrote it
    code, out, err = _run(capsys, *argv)
    assert code == 0 and "history in h.npz" in out
    lines = [ln for ln in err.splitlines() if "warning" in ln]
    assert lines == [
        "jaxworm: warning: optimise: cannot resume 'h.npz' (the file keeps no optimiser "
        "state (written by an older jaxworm)): recomputing from step 0 (the file is kept "
        "until this run has as many steps)"
    ], err
    code, _, err = _run(capsys, *argv)  # finished, with its state: returned, no warning
    assert code == 0 and "warning" not in err and "resuming, 2/2 steps" in err


def test_another_optimisations_start_points_are_another_problem(tmp_path, monkeypatch):
    monkeypatch.setattr(_optimise, "_step", _standing_step)
    monkeypatch.setenv("JAXWORM_CACHE_DIR", "")
    path = tmp_path / "h.npz"
    kw = dict(bounds={"delta": (-1.0, -0.4)}, t1=0.5, steps=2, path=path, progress=False)
    jw.optimise("velocity", starts={"delta": [-0.9]}, **kw)
    before = path.read_bytes()
    with pytest.raises(jw.ResultFileError, match=r"another optimisation \(starts_sha256 differ"):
        jw.optimise("velocity", starts={"delta": [-0.5]}, **kw)
    assert path.read_bytes() == before
    jw.optimise("velocity", starts={"delta": [-0.9]}, **kw)  # the same problem: a rerun


def test_a_sweep_file_of_another_package_version_is_not_resumed(tmp_path, calls, monkeypatch):
    import jaxworm._version

    path = tmp_path / "s.npz"
    with monkeypatch.context() as m:
        m.setattr(jaxworm._version, "__version__", "0.0.1")
        _sweep_file(path, calls=calls)
    before, n = path.read_bytes(), len(calls)
    with pytest.raises(jw.ResultFileError, match=r"different sweep \(version differ"):
        jw.sweep(GRID, t1=T1, path=path, progress=False)
    assert path.read_bytes() == before and len(calls) == n

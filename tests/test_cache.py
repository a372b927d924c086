"""Programs kept between processes (`jaxworm._cache`): the exported program of
`simulate` gives what the traced one gives, bit for bit; a damaged file is replaced; an
empty JAXWORM_CACHE_DIR writes nothing; traced calls never use it."""

import jax
import numpy as np
import pytest

import jaxworm as jw
from jaxworm import _cache
from jaxworm._solve import _simulate
from jaxworm._validation import check_t1

T1 = 0.3


def _leaves(result):
    return [np.asarray(x) for x in jax.tree_util.tree_leaves(result)]


def _same(a, b):
    la, lb = _leaves(a), _leaves(b)
    assert len(la) == len(lb)
    for x, y in zip(la, lb):
        np.testing.assert_array_equal(x, y)


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("JAXWORM_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(_cache, "_programs", {})
    return tmp_path / "exported"


@pytest.fixture(scope="module")
def traced():
    p = jw.Params().replace(delta=-0.7)
    return p, _simulate(p, check_t1(T1), jw.PRESETS["fast"], None, False)


def test_a_later_process_loads_the_same_program(cache, traced, monkeypatch):
    p, expected = traced
    first = jw.simulate(p, T1)
    files = list(cache.glob("simulate-*.bin"))
    assert len(files) == 1
    _same(first, expected)
    # As a fresh process: nothing in memory, and tracing is not allowed.
    monkeypatch.setattr(_cache, "_programs", {})

    def no_export(*a, **k):
        raise AssertionError("the program should come from the file, not a new trace")

    monkeypatch.setattr(jax.export, "export", no_export)
    second = jw.simulate(p, T1)
    _same(second, expected)
    assert second.status_name == "ok" and isinstance(second, jw.Result)


def test_a_damaged_file_is_replaced(cache, traced, monkeypatch):
    p, expected = traced
    jw.simulate(p, T1)
    (path,) = cache.glob("simulate-*.bin")
    path.write_bytes(b"not a program")
    monkeypatch.setattr(_cache, "_programs", {})
    _same(jw.simulate(p, T1), expected)
    assert jax.export.deserialize(bytearray(path.read_bytes())) is not None


def test_other_static_options_are_other_programs(cache):
    p = jw.Params()
    jw.simulate(p, T1)
    jw.simulate(p, T1, jw.PRESETS["fast"].replace(norm="full"))
    jw.simulate(p.replace(A=0.021), T1)  # same program: A is an input
    assert len(list(cache.glob("simulate-*.bin"))) == 2


def test_tolerances_are_inputs_of_one_program(cache):
    # The float options (tolerances, PID coefficients, ...) are inputs of the compiled
    # program, as the parameters are: another value is neither another file nor another
    # compilation, and it still takes effect.
    p, fast = jw.Params(), jw.PRESETS["fast"]
    loose = jw.simulate(p, T1, fast)
    tight = jw.simulate(p, T1, fast.replace(atol=1e-10, rtol=1e-9, pcoeff=0.2, icoeff=0.5))
    assert len(list(cache.glob("simulate-*.bin"))) == 1
    assert int(tight.steps) > 2 * int(loose.steps)
    assert tight.status_name == loose.status_name == "ok"


def test_an_empty_cache_dir_turns_it_off(tmp_path, monkeypatch, traced):
    monkeypatch.setenv("JAXWORM_CACHE_DIR", "")
    monkeypatch.setattr(_cache, "_programs", {})
    p, expected = traced
    _same(jw.simulate(p, T1), expected)
    assert _cache.cache_dir() is None and not _cache._programs


def test_traced_calls_do_not_use_it(cache, monkeypatch):
    def refuse(*a, **k):
        raise AssertionError("a traced call must not go through the exported program")

    monkeypatch.setattr(_cache, "exported_call", refuse)
    monkeypatch.setattr("jaxworm._solve.exported_call", refuse)
    p = jw.Params()
    # Tracing is enough: a call that reached the exported path would raise.
    jax.eval_shape(
        jax.vmap(lambda d: jw.simulate(p.replace(delta=d), T1).mean_velocity),
        np.array([-0.7, -0.6]),
    )
    jax.eval_shape(
        jax.grad(lambda a: jw.simulate(jw.Params().replace(A=a), T1).mean_velocity), 0.02
    )
    assert not cache.exists()


def test_a_sweep_chunk_from_the_file_is_the_traced_one(cache, monkeypatch):
    from jaxworm import _sweep

    args = (jw.Params(), ("omega", "delta"), np.array([[4 * np.pi, -0.7], [3 * np.pi, -0.6]]))
    expected = _sweep._traced_chunk(*args, 0.3, jw.PRESETS["fast"], "t1")
    _sweep._run_chunk(*args, 0.3, jw.PRESETS["fast"], "t1")
    assert len(list(cache.glob("sweep_chunk-*.bin"))) == 1
    monkeypatch.setattr(_cache, "_programs", {})
    got = _sweep._run_chunk(*args, 0.3, jw.PRESETS["fast"], "t1")
    assert set(got) == set(expected)
    for k in expected:
        np.testing.assert_array_equal(np.asarray(got[k]), np.asarray(expected[k]))


class _UserWave(jw.TravellingWave):
    """A user's controller: its code is not part of the cache key, so never cached."""


def test_a_users_controller_is_never_taken_from_the_cache(cache):
    p = jw.Params(gait=_UserWave())
    jw.simulate(p, T1)
    assert not cache.exists()
    jw.simulate(jw.Params(), T1)
    assert len(list(cache.glob("simulate-*.bin"))) == 1


def test_a_dense_output_program_is_kept_too_and_is_the_traced_one(cache, monkeypatch):
    # diffrax checks `SaveAt` times at run time, by a host callback that would keep the
    # program out of jax.export and JAX's compilation cache; simulate checks them itself.
    from equinox import _errors

    p = jw.Params().replace(delta=-0.7)
    ts = np.linspace(0.0, T1, 7)
    setting = _errors.EQX_ON_ERROR
    first = jw.simulate(p, T1, ts=ts)
    assert _errors.EQX_ON_ERROR == setting  # restored after the trace
    assert len(list(cache.glob("simulate-*.bin"))) == 1
    _same(first, _simulate(p, check_t1(T1), jw.PRESETS["fast"], jax.numpy.asarray(ts), False))
    monkeypatch.setattr(_cache, "_programs", {})
    monkeypatch.setattr(jax.export, "export", lambda *a, **k: pytest.fail("traced again"))
    _same(jw.simulate(p, T1, ts=ts), first)
    assert first.trajectory is not None and np.all(np.isfinite(first.trajectory.x))


def test_another_tolerance_compiles_nothing(caplog):
    # Without the file cache (the tests' default): the program compiled in this process
    # serves another atol, rtol or sensitivity_tol too, its value or its derivative.
    p, fast = jw.Params().replace(delta=-0.6), jw.PRESETS["fast"]

    def speed(a, numerics):
        return jw.simulate(p.replace(A=a), T1, numerics).mean_velocity

    jw.simulate(p, T1, fast)
    jax.grad(speed)(0.02, fast)
    with jax.log_compiles(True), caplog.at_level("WARNING"):
        other = fast.replace(atol=3e-9, rtol=1e-9, sensitivity_tol=3.0, sensitivity_ramp=0.5)
        jw.simulate(p, T1, other)
        jax.grad(speed)(0.02, other)
    compiled = [r.getMessage() for r in caplog.records if "_simulate" in r.getMessage()]
    assert not compiled, compiled

"""Training a controller by gradient through the simulator (`jaxworm.train`).

One short training (three steps of a reflex wave's gains over two soils, 1.4 s
simulated, reverse mode): the objective improves, the history is saved and read back,
its file is refused to another training. The stop at a failed solve and the checks of
the input need no solve (the step is replaced by a stand-in for the former).
"""

import dataclasses
import json
import math
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

import jaxworm as jw
from jaxworm import _train

GAIT = jw.ReflexWave(A=0.02, omega=3 * math.pi, delta=-math.pi / 4)
BASE = jw.Params().replace(K_Ith=235.0)  # several cracks in 2 s (test_feedback.py)
GAINS = lambda c: (c.gain_stress, c.gain_speed, c.gain_phase)  # noqa: E731


def _friction(x):
    """μ_s 0.3 -> 0.45 across a smoothed interface at x [m], K_Ith 235 Pa√m."""
    return jw.Soil(K_Ith=235.0, mu_s=jw.Layered([x], [0.3, 0.45], width=0.004))


SOILS = {"soil": [_friction(-0.03), _friction(-0.01)]}
# A reflex wave reads K_I/K_Ic: only the exact jump conditions differentiate it.
KW = dict(
    base=BASE,
    samples=SOILS,
    t1=1.4,
    trainable=GAINS,
    progress=False,
    crack_sensitivity="exact",
)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    path = tmp_path_factory.mktemp("train") / "t.npz"
    res = jw.train(GAIT, steps=3, optimiser=optax.adam(0.1), derivatives="reverse", path=path, **KW)
    return res, path


def test_training_improves_the_mean_velocity_over_the_soils(trained):
    res, _ = trained
    assert res.steps_done == 3 and res.stopped == ""
    assert np.all(res.status == 0) and np.all(res.n_cracks >= 1)
    assert np.all(np.diff(res.value) > 0), res.value  # each step climbs
    np.testing.assert_allclose(res.value, res.sample_value.mean(axis=1), rtol=1e-14)
    assert res.best_step == 2
    best = res.best_controller
    assert isinstance(best, jw.ReflexWave)
    # Only the gains moved; the wave and the leak are the starting controller's.
    assert float(best.A) == float(GAIT.A) and float(best.leak) == float(GAIT.leak)
    assert float(best.gain_stress) != 0.0
    np.testing.assert_array_equal(
        res.theta[2], [best.gain_stress, best.gain_speed, best.gain_phase]
    )


def test_training_history_is_saved_and_reads_back(trained):
    res, path = trained
    back = jw.load_training(path, like=GAIT)
    for key in ("value", "sample_value", "status", "theta", "grad_norm", "wall_time"):
        np.testing.assert_array_equal(getattr(back, key), getattr(res, key))
    assert back.summary() == res.summary() and json.dumps(back.summary())
    assert float(back.best_controller.gain_phase) == float(res.best_controller.gain_phase)
    assert back.header["samples"]["count"] == 2 and back.header["controller"] == "ReflexWave"
    with pytest.raises(ValueError, match="load_training\\(path, like="):
        jw.load_training(path).best_controller  # noqa: B018
    with pytest.raises(ValueError, match="has no array .gain_stress"):
        jw.load_training(path, like=jw.PolicyMLP.init(jax.random.key(0), 7))
    # A `like` of the same structure but other untrained values (the probe's wave of
    # another A and omega) rebuilt controllers mixing them with the trained gains, silently.
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        jw.load_training(path, like=res.best_controller)  # other gains: those are trained
    other = jw.ReflexWave(A=0.05, omega=5 * math.pi, delta=0.3)
    with pytest.warns(RuntimeWarning, match="holds other values than the controller"):
        jw.load_training(path, like=other)
    # Another training (more steps; the optimiser's probe covers the run's steps, so its
    # description differs too) may not write over it; nothing is computed.
    with pytest.raises(jw.ResultFileError, match="another training \\(optimiser, steps differ\\)"):
        jw.train(GAIT, steps=4, optimiser=optax.adam(0.1), derivatives="reverse", path=path, **KW)


def test_a_step_whose_solve_fails_is_not_taken_and_says_which_sample(monkeypatch, tmp_path):
    calls = []

    def fake_step(loss, optimiser, derivatives, trained, opt_state):
        k = len(calls)
        calls.append(k)
        status = jnp.array([0, 3 if k == 1 else 0])
        aux = {"status": status, "n_cracks": jnp.array([2, 2]), "velocity": jnp.array([0.01, 0.02])}
        moved = tuple(t + 1.0 for t in trained)
        return moved, opt_state, jnp.asarray(0.015), jnp.array([0.01, 0.02]), aux, jnp.asarray(1.0)

    monkeypatch.setattr(_train, "_step", fake_step)
    path = tmp_path / "t.npz"
    with pytest.warns(RuntimeWarning, match="step 1: sample 1 ended solver_failed"):
        res = jw.train(GAIT, steps=5, path=path, **KW)
    assert res.steps_done == 2 and "sample 1 ended solver_failed" in res.stopped
    assert res.best_step == 0
    np.testing.assert_array_equal(res.theta[1], res.theta[0] + 1.0)  # step 0 was taken
    assert jw.load_training(path).stopped == res.stopped


def _fake_step(loss, optimiser, derivatives, trained, opt_state):
    """A stand-in for `_train._step` on two samples, every solve ok."""
    aux = {"status": jnp.array([0, 0]), "n_cracks": jnp.array([2, 2]), "velocity": jnp.ones(2)}
    return trained, opt_state, jnp.asarray(1.0), jnp.ones(2), aux, jnp.asarray(1.0)


def _moving_step(loss, optimiser, derivatives, trained, opt_state):
    """A stand-in for `_train._step` that steps the optimiser on a made-up gradient."""
    grads = tuple(jnp.sin(t) + 1.0 for t in trained)
    updates, new_state = optimiser.update(grads, opt_state, trained)
    value = sum(jnp.sum(t) for t in trained)
    aux = {"status": jnp.array([0, 0]), "n_cracks": jnp.array([2, 2]), "velocity": jnp.ones(2)}
    return optax.apply_updates(trained, updates), new_state, value, jnp.ones(2), aux, value


def _counted(monkeypatch, kill_at=None):
    calls = []

    def step(*args):
        calls.append(1)
        if len(calls) == kill_at:
            raise KeyboardInterrupt
        return _moving_step(*args)

    monkeypatch.setattr(_train, "_step", step)
    return calls


def test_a_killed_training_resumes_from_its_last_step_as_if_never_stopped(monkeypatch, tmp_path):
    kw = dict(KW, steps=5, optimiser=optax.adam(0.1))
    _counted(monkeypatch)
    whole = jw.train(GAIT, path=tmp_path / "whole.npz", **kw)
    path = tmp_path / "t.npz"
    _counted(monkeypatch, kill_at=3)
    with pytest.raises(KeyboardInterrupt):
        jw.train(GAIT, path=path, **kw)
    assert jw.load_training(path).steps_done == 2
    calls = _counted(monkeypatch)
    resumed = jw.train(GAIT, path=path, **kw)
    assert len(calls) == 3  # the steps left, not five
    for res in (resumed, jw.load_training(path)):
        assert res.steps_done == 5
        np.testing.assert_array_equal(res.theta, whole.theta)  # the Adam state restored
        np.testing.assert_array_equal(res.value, whole.value)
    assert jw.train(GAIT, path=path, **kw).steps_done == 5 and len(calls) == 3  # finished


def test_a_rerun_of_a_training_that_stopped_returns_it_and_says_why(monkeypatch, tmp_path):
    calls = []

    def failing(*args):
        calls.append(1)
        trained, opt_state, value, values, aux, g = _moving_step(*args)
        aux["status"] = jnp.array([0, 3])
        return trained, opt_state, value, values, aux, g

    monkeypatch.setattr(_train, "_step", failing)
    path = tmp_path / "t.npz"
    with pytest.warns(RuntimeWarning, match="step 0: sample 1 ended solver_failed"):
        jw.train(GAIT, steps=3, path=path, **KW)
    with pytest.warns(RuntimeWarning, match="step 0: sample 1 ended solver_failed"):
        again = jw.train(GAIT, steps=3, path=path, **KW)
    assert len(calls) == 1 and again.steps_done == 1 and again.controller_at(0) == GAIT


def test_a_killed_rerun_of_a_training_without_a_state_leaves_its_history_whole(
    monkeypatch, tmp_path
):
    """A history of an older jaxworm keeps no state: the rerun recomputes it, with a
    warning, and replaces the file only once it has as many steps."""
    calls = []

    def killed_at_the_third_step(*args):
        calls.append(1)
        if len(calls) == 6:  # the rerun's third step
            raise KeyboardInterrupt
        return _fake_step(*args)

    monkeypatch.setattr(_train, "_step", killed_at_the_third_step)
    path = tmp_path / "t.npz"
    jw.train(GAIT, steps=3, path=path, **KW)
    _train._save(path, dataclasses.replace(jw.load_training(path), state=None))
    before = path.read_bytes()
    with pytest.warns(RuntimeWarning, match="cannot resume .*keeps no optimiser state"):
        with pytest.raises(KeyboardInterrupt):
            jw.train(GAIT, steps=3, path=path, **KW)
    assert path.read_bytes() == before and jw.load_training(path).steps_done == 3


def test_a_training_of_another_objective_or_static_controller_field_is_refused(
    monkeypatch, tmp_path
):
    monkeypatch.setattr(_train, "_step", _fake_step)
    policy = jw.PolicyMLP.init(jax.random.key(0), 7)
    open_loop = jw.PolicyMLP.init(jax.random.key(0), 7, feedback=False)  # same arrays
    kw = dict(base=BASE, samples=SOILS, t1=1.4, steps=1, progress=False, maximise=True)
    path = tmp_path / "t.npz"
    jw.train(policy, lambda r: r.mean_velocity, path=path, **kw)
    before = path.read_bytes()
    with pytest.raises(jw.ResultFileError, match=r"another training \(objective_sha256 differ"):
        jw.train(policy, lambda r: -r.energy_residual, path=path, **kw)
    with pytest.raises(jw.ResultFileError, match=r"another training \(base_scene differ"):
        jw.train(open_loop, lambda r: r.mean_velocity, path=path, **kw)
    assert path.read_bytes() == before
    jw.train(policy, lambda r: r.mean_velocity, path=path, **kw)  # the same training


@pytest.mark.parametrize(
    "kwargs, error, match",
    [
        (dict(numerics="fast"), TypeError, r"option numerics = 'fast' \(str\) is not a Numerics"),
        (dict(base={"omega": 3.0}), TypeError, r"option base = \{'omega': 3.0\} \(dict\)"),
    ],
)
def test_options_of_the_wrong_type_are_refused_naming_them(kwargs, error, match, monkeypatch):
    monkeypatch.setattr(_train, "_step", None)  # refused before any step
    with pytest.raises(error, match=match):
        jw.train(GAIT, progress=False, **kwargs)


@pytest.mark.parametrize(
    "args, kwargs, match",
    [
        ((3.0,), {}, "controller = 3.0: need an AbstractController"),
        ((GAIT,), dict(steps=0), "option steps = 0"),
        ((GAIT,), dict(t1=-1.0), "parameter t1 = -1.0"),
        ((GAIT,), dict(samples={"soil": []}), "soil is an empty list"),
        ((GAIT,), dict(trainable="gains"), "option trainable = 'gains'"),
        ((GAIT,), dict(trainable=lambda c: c.nothing), "option trainable"),
        ((GAIT,), dict(optimiser="adam"), "option optimiser = 'adam'"),
        ((GAIT,), dict(derivatives="sideways"), "option derivatives = 'sideways'"),
        ((GAIT,), dict(objective="speed"), "objective = 'speed' is unknown"),
        ((GAIT,), dict(horizon="cycles"), "option horizon = 'cycles'"),
        ((jw.TravellingWave(),), dict(trainable=lambda c: ()), "nothing to train"),
    ],
)
def test_bad_input_is_refused_naming_the_option_and_value(args, kwargs, match):
    with pytest.raises(ValueError, match=match):
        jw.train(*args, progress=False, **kwargs)


class _CheckedWave(jw.AbstractController):
    """A wave whose rates pass an equinox run-time check that fails while c > 1."""

    c: jax.Array

    def __call__(self, t, x, v, lbar, body):
        u = 0.02 * jnp.sin(3 * jnp.pi * t + jnp.pi / 4 * jnp.arange(body.N - 1)) * self.c
        return eqx.error_if(u, self.c > 1.0, "a failed check")


def test_a_failed_check_inside_a_step_is_recorded_and_the_step_not_taken():
    # equinox's checks (lineax's linear solves, say) raise by default; inside a training
    # step they give NaN, so the step is refused by the contract, not the process.
    with pytest.warns(RuntimeWarning, match="step 0: "):
        res = jw.train(_CheckedWave(c=jnp.asarray(2.0)), t1=0.2, steps=3, progress=False)
    assert res.steps_done == 1 and res.stopped.startswith("step 0: ")
    assert not res.ok[0]
    with pytest.raises(ValueError, match="no step ended with every sample ok"):
        _ = res.best_step
    ok = jw.train(_CheckedWave(c=jnp.asarray(0.5)), t1=0.2, steps=1, progress=False)
    assert ok.ok[0] and np.isfinite(ok.grad_norm[0])

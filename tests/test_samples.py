"""Objectives averaged over samples of the scene (`jaxworm.optimise(..., samples=...)`).

One value-and-gradient solve of two soils (layered friction; 2.1 s simulated) against the
individual `jw.simulate` runs of the same scenes and central differences of a tight
solve; the checks of `samples` and the pooling of the samples' diagnostics need no
solve.
"""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxworm as jw
from jaxworm._samples import check_samples, describe_samples, pool

OMEGA, DELTA = 3 * math.pi, -math.pi / 4
T1 = 2.1  # [s]: several cracks (test_feedback.py)
BASE = jw.Params(gait=jw.TravellingWave(A=0.02, omega=OMEGA, delta=DELTA)).replace(K_Ith=235.0)


def _soil(x):
    """K_Ic 250 -> 300 Pa√m across a smoothed interface at x [m] (smooth in the tip)."""
    return jw.Layered([x], [250.0, 300.0], width=0.004)


def _friction(x):
    """μ_s 0.3 -> 0.45 across a smoothed interface at x [m], K_Ith 235 Pa√m."""
    return jw.Soil(K_Ith=235.0, mu_s=jw.Layered([x], [0.3, 0.45], width=0.004))


#: Two soils: the body (from −0.06 m to the head at 0, advancing ~3 cm) meets more
#: friction ahead of an interface it crosses at different times.
SOILS = {"soil": [_friction(-0.03), _friction(-0.01)]}
A0 = 0.02


# --- checks and pooling, no solve ----------------------------------------------------


@pytest.mark.parametrize(
    "samples, match",
    [
        ([1.0, 2.0], r"option samples = \[1.0, 2.0\]: need a dict"),
        ({}, r"option samples = \{\}: need a dict"),
        ({"K_Ic": []}, "K_Ic is an empty list"),
        ({"K_Ic": 250.0}, "leading axes"),
        ({"K_Ic": [250.0, 300.0], "E_s": [1e5]}, "different numbers of samples"),
        ({"K_Ic": [_soil(0.01), jw.Layered([0.1, 0.2], [1.0, 2.0, 3.0])]}, r"K_Ic\[1\] differs"),
        ({"K_Ic": [250.0, 150.0]}, "sample 1: parameter K_Ith = 200.0 is out of range"),
        ({"omgea": [1.0]}, "sample 0: unknown parameter 'omgea'"),
    ],
)
def test_bad_samples_are_refused_naming_what_is_wrong(samples, match):
    with pytest.raises(ValueError, match=match):
        check_samples(samples, jw.Params())


def test_a_sampled_name_that_the_bounds_set_is_refused():
    with pytest.raises(ValueError, match="omega is set by the optimisation itself"):
        jw.optimise(samples={"omega": [3.0, 4.0]}, progress=False)


def test_samples_take_numbers_profiles_and_whole_soils_with_one_leading_axis():
    soils = [jw.Soil(K_Ic=_soil(x), K_Ith=200.0) for x in (0.01, 0.02, 0.03)]
    batch, n = check_samples({"soil": soils, "lam": np.array([1.2, 1.5, 2.0])}, jw.Params())
    assert n == 3 and batch is not None
    assert batch["soil"].K_Ic.interfaces.shape == (3, 1)
    assert check_samples(None, jw.Params()) == (None, 1)


def test_the_samples_digest_tells_other_samples_apart():
    a = describe_samples(check_samples(SOILS, BASE)[0])
    b = describe_samples(check_samples({"soil": [_friction(-0.03), _friction(-0.02)]}, BASE)[0])
    assert a is not None and b is not None
    assert a == describe_samples(check_samples(SOILS, BASE)[0])
    assert a["count"] == 2 and a["names"] == ["soil"] and a["sha256"] != b["sha256"]


def test_pooled_status_is_the_first_sample_not_ok_cracks_add_velocities_average():
    aux = {
        "status": jnp.array([0, 3, 2]),
        "n_cracks": jnp.array([4, 5, 6]),
        "velocity": jnp.array([0.01, 0.02, 0.03]),
    }
    value, pooled = pool(jnp.array([1.0, 2.0, 6.0]), aux)
    assert float(value) == 3.0 and int(pooled["status"]) == 3 and int(pooled["n_cracks"]) == 15
    assert float(pooled["velocity"]) == pytest.approx(0.02, rel=1e-15)
    _, ok = pool(jnp.zeros(3), {**aux, "status": jnp.zeros(3, int)})
    assert int(ok["status"]) == 0


# --- through the solver ----------------------------------------------------------------

#: The derivative with the exact jump conditions, right on short horizons, and the
#: sensitivities solved to tolerance (test_gradients.py).
EXACT = jw.PRESETS["fast"].replace(max_cracks=8, sensitivity_tol=1.0)
#: Relative steps of the central differences in A: the step and its check.
FD_STEPS = (1e-2, 3e-3)


def _scene_velocity(A, soil, numerics):
    p = BASE.replace(A=A, soil=soil)
    r = jw.simulate(p, T1, numerics)
    return r.mean_velocity, r.n_cracks, r.status


def _optimise_a(samples, path):
    """One step of `optimise` in A from A0 over `samples`, its history at `path`."""
    return jw.optimise(
        "velocity",
        {"A": (0.01, 0.03)},
        base=BASE,
        samples=samples,
        t1=T1,
        numerics=EXACT,
        crack_sensitivity="exact",
        starts={"A": [A0]},
        steps=1,
        progress=False,
        path=path,
    )


@pytest.fixture(scope="module")
def optimised(tmp_path_factory):
    path = tmp_path_factory.mktemp("samples") / "h.npz"
    res = _optimise_a(SOILS, path)
    soils = check_samples(SOILS, BASE)[0]["soil"]  # type: ignore[index]
    # Each scene alone, a plain solve, in one batch.
    run = eqx.filter_jit(jax.vmap(_scene_velocity, in_axes=(None, 0, None)))
    alone = [np.asarray(a) for a in run(jnp.asarray(A0), soils, EXACT)]
    # Central differences of a tight solve (local error <= 1e-10 m per step) at two steps.
    tight = EXACT.replace(atol=1e-10)
    points = jnp.array([A0 * (1 + s * rel) for rel in FD_STEPS for s in (1.0, -1.0)])
    fd_run = eqx.filter_jit(
        jax.vmap(jax.vmap(_scene_velocity, in_axes=(None, 0, None)), in_axes=(0, None, None))
    )
    v_fd, cracks_fd, status_fd = (np.asarray(a) for a in fd_run(points, soils, tight))
    assert np.all(status_fd == 0) and np.all(cracks_fd >= 2)  # through crack events
    means = v_fd.mean(axis=1).reshape(len(FD_STEPS), 2)
    fd = (means[:, 0] - means[:, 1]) / (2 * A0 * np.asarray(FD_STEPS))
    return res, path, alone, fd, means[-1].mean()


def test_optimise_value_is_the_mean_of_the_samples_own_simulations(optimised):
    res, _, (v, cracks, status), _, tight = optimised
    assert np.all(status == 0) and np.all(cracks >= 2)  # through crack events
    # The soils' velocities differ by > 1e-2 (relative), so a value that is not their
    # mean (one soil alone, other weights) is off it by ~5e-3 or more.
    assert abs(v[0] / v[1] - 1) > 1e-2
    # The sensitivities enter the step control (`Numerics.sensitivity_tol`), so the solve
    # with derivatives takes other steps than a plain one: they agree to the solver's
    # accuracy, not to rounding. Both are within 1e-3 of the tight solve's mean (the
    # mean of A0 (1 ± 3e-3): v̄ is smooth in A, so that is v̄(A0) to ~1e-5), and so
    # within 2e-3 of each other: `fast` is within 2.4e-3 of its reference on every
    # scene of the presets check; seen here ~2e-4.
    assert res.value[0, 0] == pytest.approx(tight, rel=1e-3)
    assert v.mean() == pytest.approx(tight, rel=1e-3)
    assert res.velocity[0, 0] == res.value[0, 0]
    assert int(res.n_cracks[0, 0]) == int(cracks.sum()) and int(res.status[0, 0]) == 0


def test_optimise_gradient_over_samples_matches_central_differences(optimised):
    res, _, _, fd, _ = optimised
    grad = float(res.grad[0, 0, 0])
    # 2 % of the difference, or twice the differences' own disagreement between the two
    # steps (test_gradients.py).
    noise = abs(fd[0] - fd[1])
    assert abs(fd[0]) > 0
    assert abs(grad - fd[0]) <= max(0.02 * abs(fd[0]), 2 * noise), (grad, fd)


def test_optimise_history_records_the_samples(optimised, tmp_path):
    res, path, _, _, _ = optimised
    back = jw.load_optimisation(path)
    assert back.header["samples"] == describe_samples(check_samples(SOILS, BASE)[0])
    np.testing.assert_array_equal(back.value, res.value)
    assert back.header["samples"]["names"] == ["soil"]
    # A rerun with other samples is another problem: its history is not overwritten.
    with pytest.raises(jw.ResultFileError, match="samples differ"):
        _optimise_a({"soil": [_friction(-0.03), _friction(-0.02)]}, path)

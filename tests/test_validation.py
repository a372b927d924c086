"""Input validation at its cause, one path for the API and the command line.

Python values are refused at construction with the parameter's name, the value and the
allowed range; traced values end in a named status, and an invalid lane takes no step.
"""

import math
import re

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import FLAT_BATCH_NUMERICS, FLAT_BATCH_SIZE

import jaxworm as jw
from jaxworm._control import mean_abs_sine
from jaxworm._dynamics import COLLAPSE_FRACTION
from jaxworm._numerics import numerics_valid
from jaxworm._params import EPS_N_MAX, EPS_V_MAX, N_MAX, speed_bound
from jaxworm._result import STATUS_CODE, mean_velocity_of
from jaxworm._solve import _final_status


def _refused(exc, name, **values):
    with pytest.raises(exc) as info:
        jw.Params().replace(**values)
    assert re.search(rf"\b{re.escape(name)} = ", str(info.value)), str(info.value)
    return str(info.value)


# --- Params.replace: wrong types, shapes, huge integers -----------------------------


@pytest.mark.parametrize("name", ["A", "omega", "E_s", "eps_v", "crack_gap0", "lam"])
@pytest.mark.parametrize(
    "bad",
    [
        "abc",
        "1e5",
        [1.0, 2.0],
        (1.0,),
        True,
        False,
        1 + 2j,
        {"a": 1},
        np.array(["x"]),
        np.bool_(True),
    ],
)
def test_wrong_types_are_refused_naming_the_parameter(name, bad):
    msg = _refused(TypeError, name, **{name: bad})
    assert "need a float" in msg and name in msg


@pytest.mark.parametrize("name", ["A", "omega", "E_s", "eps_v"])
def test_none_is_refused_except_for_crack_gap0(name):
    assert "need a float" in _refused(TypeError, name, **{name: None})
    assert jw.Params().replace(crack_gap0=None).crack_gap0 is None  # None: eq. 13


@pytest.mark.parametrize("bad", [np.array([1.0, 2.0]), jnp.ones(3), np.zeros((1, 1))])
def test_arrays_of_many_values_are_refused(bad):
    with pytest.raises(ValueError, match=r"omega of shape .*need one number"):
        jw.Params().replace(omega=bad)


@pytest.mark.parametrize(
    "value,shown", [(10**300, "~1e300"), (-(10**400), "-~1e400")], ids=["1e300", "-1e400"]
)
def test_huge_integers_are_refused_by_name(value, shown):
    with pytest.raises(ValueError, match=rf"\bN = {re.escape(shown)}.*N >= 2 and <= {N_MAX}"):
        jw.Params().replace(N=value)


def test_integers_beyond_the_float_range_are_refused_by_name():
    with pytest.raises(ValueError, match=r"E_s = ~1e400 \(an integer\) is out of range"):
        jw.Params().replace(E_s=10**400)
    assert float(jw.Params().replace(E_s=10**300).soil.E_s) == 1e300  # a float: in range


def test_N_upper_bound_and_types():
    assert jw.Params().replace(N=N_MAX).body.N == N_MAX
    with pytest.raises(ValueError, match=rf"N = {N_MAX + 1} is out of range"):
        jw.Params().replace(N=N_MAX + 1)
    with pytest.raises(TypeError, match=r"N = True"):
        jw.Params().replace(N=True)
    with pytest.raises(TypeError, match=r"N = '7'"):
        jw.Params().replace(N="7")


@pytest.mark.parametrize("value", [np.float32(0.03), np.int64(2), 3, jnp.float32(0.5)])
def test_real_numbers_of_any_type_become_float64(value):
    p = jw.Params().replace(A=value)
    assert p.gait.A.dtype == jnp.float64 and float(p.gait.A) == float(np.float32(value))


# --- smoothing widths: an upper bound -----------------------------------------------


def test_smoothing_widths_are_bounded_above():
    assert float(jw.Params().replace(eps_v=EPS_V_MAX).smoothing.eps_v) == EPS_V_MAX
    assert float(jw.Params().replace(eps_N=EPS_N_MAX).smoothing.eps_N) == EPS_N_MAX
    for v in (1.01 * EPS_V_MAX, 1.0, 1e300):  # the eps_v = 1 and 1e300
        assert f"<= {EPS_V_MAX:g} m/s" in _refused(ValueError, "eps_v", eps_v=v)
    assert f"<= {EPS_N_MAX:g} N" in _refused(ValueError, "eps_N", eps_N=1e-5)
    ok = jax.vmap(lambda e: jw.params_valid(jw.Params().replace(eps_v=e)))(jnp.array([1e-4, 1.0]))
    np.testing.assert_array_equal(np.asarray(ok), [True, False])


# --- t1 in the API --------------------------------------------------------------------


@pytest.mark.parametrize("t1", [0.0, -1.0, math.nan, math.inf, -math.inf, np.float64(0.0)])
def test_simulate_refuses_a_bad_t1_by_name(t1):
    with pytest.raises(ValueError, match=r"parameter t1 = .* is out of range: need t1 > 0"):
        jw.simulate(jw.Params(), t1)


@pytest.mark.parametrize("t1", ["2", None, [1.0], True])
def test_simulate_refuses_a_t1_of_the_wrong_type(t1):
    with pytest.raises((TypeError, ValueError), match=r"\bt1\b"):
        jw.simulate(jw.Params(), t1)


# --- Numerics ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    "name,value,allowed",
    [
        ("atol", math.inf, "atol > 0"),
        ("rtol", math.inf, "rtol >= 0 and < 1"),
        ("dt", math.inf, "dt > 0"),
        ("pcoeff", math.nan, "pcoeff >= 0 and <= 1"),
        ("icoeff", 0.0, "icoeff > 0"),
        ("atol", -1e-8, "atol > 0"),
        ("dt_max", math.nan, "dt_max"),
        ("energy_tol", math.inf, "energy_tol > 0"),
        ("sensitivity_tol", math.inf, "sensitivity_tol"),
        ("sensitivity_ramp", -0.1, "sensitivity_ramp >= 0 s"),
        ("sensitivity_ramp", math.inf, "sensitivity_ramp >= 0 s"),
        ("max_cracks", 10**9, "<= 10000"),
        ("max_steps", 2**70, "<= 2147483647"),
        ("max_steps", 0, ">= 1"),
        ("newton_max_steps", 10**6, "<= 1000"),
        # 1e-2 located a crack 0.45 s early with status ok.
        ("event_atol", 1e-2, "event_atol > 0 and <= 1e-06 s"),
        ("event_rtol", 1e-2, "event_rtol > 0 and <= 1e-06"),
    ],
)
def test_numerics_out_of_range_is_refused_by_name(name, value, allowed):
    with pytest.raises(ValueError) as info:
        jw.Numerics(**{name: value})
    msg = str(info.value)
    assert f"option {name} = " in msg and allowed in msg, msg


@pytest.mark.parametrize(
    "name,value",
    [
        ("linear_solve", "foo"),
        ("solver", "rk4"),
        ("norm", None),
        ("adjoint", 1),
        ("crack_sensitivity", "held"),
        ("sensitivity_frame", "space"),
        ("interpolant", "linear"),
        ("newton", "half"),
    ],
)
def test_numerics_unknown_choices_are_refused(name, value):
    with pytest.raises(ValueError, match=rf"option {name} = .*need one of"):
        jw.Numerics(**{name: value})


@pytest.mark.parametrize(
    "name,value",
    [("atol", "1e-8"), ("max_cracks", "64"), ("max_steps", True), ("sensitivity_hessian", 1)],
)
def test_numerics_wrong_types_are_refused(name, value):
    with pytest.raises(TypeError, match=rf"option {name} = "):
        jw.Numerics(**{name: value})


def test_numerics_accepts_numpy_scalars_and_traced_tolerances():
    n = jw.Numerics(atol=np.float32(1e-8), rtol=np.float64(0.0), max_cracks=np.int64(8))
    assert n.atol == float(np.float32(1e-8)) and isinstance(n.atol, float)
    assert n.max_cracks == 8
    assert hash(n) == hash(jw.Numerics(atol=float(np.float32(1e-8)), max_cracks=8))
    # traced: accepted at construction, checked by the solve (numerics_valid)
    ok = jax.vmap(lambda a: numerics_valid(jw.Numerics(atol=a)))(jnp.array([1e-8, jnp.inf, -1.0]))
    np.testing.assert_array_equal(np.asarray(ok), [True, False, False])


# --- the speed bound: its derivation, checked ------------------------------------------


@pytest.mark.parametrize(
    "omega,t1",
    [(4 * math.pi, 0.01), (4 * math.pi, 0.3), (3 * math.pi, 2.0), (5 * math.pi, 7.3), (1.0, 60.0)],
)
def test_mean_abs_sine_bounds_the_stroke_for_every_phase(omega, t1):
    t = np.linspace(0.0, t1, 20001)
    worst = max(
        np.trapezoid(np.abs(np.sin(omega * t + phi)), t) / t1
        for phi in np.linspace(0, 2 * np.pi, 64)
    )
    bound = float(mean_abs_sine(omega, t1))
    assert worst <= bound * (1 + 1e-6)
    # the bound tends to the mean of |sin|, 2/π, within one half period in ωt1
    assert 2 / math.pi <= bound <= 2 / math.pi * (1 + math.pi / (omega * t1)) or bound == 1.0


def test_speed_bound_for_table1():
    p = jw.Params()
    # long horizons: (N − 1)·2A/π (the stroke) + (N − 1) l0 / t1 (the shape allowance)
    assert float(speed_bound(p, 1e4)) == pytest.approx(
        6 * 2 * 0.02 / math.pi + 6 * 0.01 / 1e4, rel=1e-3
    )
    assert float(speed_bound(p.replace(A=0.0), 2.0)) == pytest.approx(6 * 0.01 / 2.0)
    for bad in (0.0, -1.0, math.nan):  # a positive bound at t1 = -1 s, NaN at 0
        with pytest.raises(ValueError, match="t1 = .* is out of range: need t1 > 0"):
            speed_bound(p, bad)


def test_a_run_faster_than_the_stroke_allows_is_not_ok():
    p = jw.Params()
    y0 = jw.initial_state(p)
    x_c = jw.initial_crack_tip(p, y0)
    t_end = jnp.float64(2.0)
    bound = float(speed_bound(p, t_end))
    for factor, expected in ((0.9, "ok"), (1.1, "implausible_speed")):
        y = eqx.tree_at(lambda s: s.x, y0, y0.x + factor * bound * t_end)
        v = mean_velocity_of(y0.x, y.x, t_end, t_end)
        code = _final_status(jnp.array(0), y, x_c, jnp.array(0.0), p, FLAT_BATCH_NUMERICS, v, t_end)
        assert jw.status_name(code) == expected
    # backward motion is not bounded by the stroke (the back pressure pushes back)
    y = eqx.tree_at(lambda s: s.x, y0, y0.x - 10 * bound * t_end)
    v = mean_velocity_of(y0.x, y.x, t_end, t_end)
    code = _final_status(jnp.array(0), y, x_c, jnp.array(0.0), p, FLAT_BATCH_NUMERICS, v, t_end)
    assert jw.status_name(code) == "ok"


# --- status messages -------------------------------------------------------------------


def test_too_many_cracks_names_its_remedy():
    msg = jw.status_message(STATUS_CODE["too_many_cracks"])
    assert "max_cracks" in msg and "--max-cracks" in msg


# --- traced values in a batch: named status, no step, other lanes untouched --------------


def test_invalid_lanes_take_no_step_and_leave_the_others_bit_identical(run_flat_batch):
    t1 = 0.2
    clean_rows = [{}, {"omega": 3 * math.pi}, {"delta": -math.pi / 4}, {"A": 0.015}]
    clean = run_flat_batch(clean_rows, [t1] * FLAT_BATCH_SIZE)
    assert list(jw.status_name(clean.status)) == ["ok"] * FLAT_BATCH_SIZE
    for bad_row, bad_t1 in (
        ({"omega": math.nan}, t1),
        ({"omega": 0.0}, t1),
        ({"eps_v": 1.0}, t1),
        ({"E_s": -1.0}, t1),
        ({}, -1.0),
        ({}, math.nan),
        ({}, 0.0),
    ):
        rows = [bad_row] + clean_rows[1:]
        r = run_flat_batch(rows, [bad_t1] + [t1] * (FLAT_BATCH_SIZE - 1))
        assert jw.status_name(r.status[0]) == "invalid_parameters", (bad_row, bad_t1)
        assert int(r.steps[0]) == 0 and np.isnan(float(r.mean_velocity[0]))
        for a, b in zip(jax.tree_util.tree_leaves(r), jax.tree_util.tree_leaves(clean)):
            np.testing.assert_array_equal(np.asarray(a)[1:], np.asarray(b)[1:])


# --- a body that collapses ends the run at once -----------------------------------------

#: Table 1 with A = 0.05 m/s, ω = 2π: the intrinsic length of segment 5, l_0 +
#: (A/ω)(cos 5δ − cos(ωt + 5δ)), reaches 0 at t ≈ 0.2176 s, and the segment with it.
COLLAPSING = {"A": 0.05, "omega": 2 * math.pi}
COLLAPSE_T1 = 0.25
#: Steps to the collapse: ~1,600 (`fast`). Past it the solver used to grind on with
#: inverted segments, ~70,000 steps to a failure here, up to the whole step bound
#: (2**20) with other gaits.
COLLAPSE_STEPS = 5_000


def _first_zero_of_the_intrinsic_lengths(A, omega, delta, t1):
    """The first t at which min_k l̄_k(t) = l_0 + (A/ω)(cos δk − cos(ωt + δk)) ≤ 0
    (eq. 24 integrated from rest), to 1e-7 s."""
    body = jw.Body()
    k = np.arange(1, body.N)
    t = np.linspace(0.0, t1, int(t1 / 1e-7) + 1)[:, None]
    lbar = body.l0 + (A / omega) * (np.cos(delta * k) - np.cos(omega * t + delta * k))
    return float(t[np.argmax(np.min(lbar, axis=1) <= 0), 0])


def test_a_collapsing_body_ends_body_inverted_where_its_lengths_reach_zero():
    r = jw.simulate(jw.Params().replace(**COLLAPSING), COLLAPSE_T1)
    assert r.status_name == "body_inverted"
    t_zero = _first_zero_of_the_intrinsic_lengths(
        COLLAPSING["A"], COLLAPSING["omega"], math.pi / 4, COLLAPSE_T1
    )
    assert 0.2 < t_zero < COLLAPSE_T1
    # It stops at the collapse (the segment, compressed, reaches 0 a little before its
    # intrinsic length), not after grinding on past it.
    assert abs(float(r.t_end) - t_zero) < 1e-4, (float(r.t_end), t_zero)
    assert int(r.steps) < COLLAPSE_STEPS
    lengths = np.concatenate([np.diff(-np.asarray(r.final.x)), np.asarray(r.final.lbar)])
    assert lengths.min() <= COLLAPSE_FRACTION * jw.Body().l0 and np.all(np.isfinite(lengths))
    summary = r.summary()
    assert summary["t_end"] == float(r.t_end) and "zero" in summary["status_message"]


def test_a_collapsing_lane_stops_at_once_and_leaves_the_others_unchanged(run_flat_batch):
    clean_rows = [{}, {"omega": 3 * math.pi}, {"delta": -math.pi / 4}, {"A": 0.015}]
    t1s = [COLLAPSE_T1] * FLAT_BATCH_SIZE
    clean = run_flat_batch(clean_rows, t1s)
    r = run_flat_batch([COLLAPSING] + clean_rows[1:], t1s)
    assert list(jw.status_name(r.status)) == ["body_inverted"] + ["ok"] * (FLAT_BATCH_SIZE - 1)
    assert float(r.t_end[0]) < COLLAPSE_T1 and int(r.steps[0]) < COLLAPSE_STEPS
    # The other lanes take the same steps to the same times. When any lane's event
    # fires, diffrax reads every lane's end state off its last step's interpolant (as
    # for a crack), which rounds differently from the step's own end state: measured
    # ≤ 5e-16 relative on the state, 4e-15 absolute on the energy residual.
    for a, b in zip(jax.tree_util.tree_leaves(r), jax.tree_util.tree_leaves(clean)):
        a, b = np.asarray(a)[1:], np.asarray(b)[1:]
        if a.dtype.kind == "f":
            np.testing.assert_allclose(a, b, rtol=1e-13, atol=1e-14)
        else:
            np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(np.asarray(r.t_end)[1:], np.asarray(clean.t_end)[1:])


# Batched and single runs of one scene round differently (XLA's batched kernels), and the
# adaptive step control turns that into a different step sequence (e.g. 1673 against
# 1700 steps): the difference is of the solver's own error. Both must be within that
# error of a tight solve: for `fast` the head's position error over 48 random gaits
# reached 110 µm at 2 s (docs/numerics.md, benchmarks/random_gaits.py). A relative bound
# on v̄ of 5e-3, set from 8 gaits (≤ 4.1e-3 at 1 s), was exceeded (5.9e-3: 54 µm against
# a tight solve, the single run 18 µm) once the state gained a fourth work integral and
# rounded differently. A lane that ran another scene would be millimetres off.
BATCH_FAST_HEAD_ERROR = 1.1e-4  # [m]


def test_batched_and_single_fast_runs_agree_within_the_solver_error(run_flat_batch):
    t1 = 1.0
    rows = [
        {},
        {"omega": 3 * math.pi, "delta": -math.pi / 3},
        {"delta": -math.pi / 4},
        {"omega": 5 * math.pi, "delta": math.pi / 6},
    ]
    batch = run_flat_batch(rows, [t1] * FLAT_BATCH_SIZE)
    tight = FLAT_BATCH_NUMERICS.replace(atol=1e-11)
    for i, row in enumerate(rows):
        p = jw.Params().replace(**row)
        one = jw.simulate(p, t1, FLAT_BATCH_NUMERICS)
        ref = jw.simulate(p, t1, tight)
        assert one.status_name == batch.status_name[i] == ref.status_name == "ok"
        assert int(one.n_cracks) == int(batch.n_cracks[i]) == int(ref.n_cracks)
        for v in (float(batch.mean_velocity[i]), float(one.mean_velocity)):
            assert abs(v - float(ref.mean_velocity)) * t1 < BATCH_FAST_HEAD_ERROR


@pytest.mark.parametrize(
    "ts, message",
    [
        ([0.1, 0.5], r"ts\[1\] = 0.5: need 0 <= ts <= 0.3"),
        ([-0.1, 0.2], r"ts\[0\] = -0.1: need 0 <= ts"),
        ([0.1, float("nan"), 0.2], r"ts\[1\] = nan: need finite"),
        ([0.2, 0.1], r"ts\[1\] = 0.1 < ts\[0\] = 0.2: need non-decreasing"),
        ([[0.1, 0.2]], r"ts has shape \(1, 2\)"),
        ([], r"ts is empty: need at least one output time"),
    ],
)
def test_output_times_outside_the_run_are_refused(ts, message):
    # Before, times past t1 or below 0 gave a NaN trajectory with status ok, and a NaN
    # wiped the entries after it.
    with pytest.raises(ValueError, match=message):
        jw.simulate(jw.Params(), 0.3, ts=np.array(ts))


@pytest.mark.parametrize("ts", ["abc", [0.1, "x"], [True, False], [0.1j]])
def test_output_times_that_are_not_real_numbers_are_refused_naming_ts(ts):
    with pytest.raises(TypeError, match=r"ts = .*: need real numbers, the output times"):
        jw.simulate(jw.Params(), 0.3, ts=ts)


def test_status_helpers_refuse_unknown_codes_and_batches_by_name():
    assert jw.status_name(0) == "ok" and list(jw.status_name(np.array([0, 1]))) == [
        "ok",
        "too_many_cracks",
    ]
    with pytest.raises(ValueError, match=r"unknown status code 42: the codes are 0 \(ok\)"):
        jw.status_name(42)
    with pytest.raises(ValueError, match=r"unknown status code 0.5"):
        jw.status_name(np.array([0.0, 0.5]))
    with pytest.raises(ValueError, match=r"the status of one run, not an array of shape \(2,\)"):
        jw.status_message(np.array([0, 1]))


def test_summary_of_a_batch_says_to_index_a_run():
    r = jax.vmap(lambda a: jw.simulate(jw.Params().replace(A=a), 0.01))(jnp.array([0.02, 0.03]))
    with pytest.raises(ValueError, match=r"one run's result, not a batch of shape \(2,\)"):
        r.summary()
    one = jax.tree_util.tree_map(lambda a: a[1], r)
    assert one.summary()["status"] == str(one.status_name)


def test_traced_output_times_outside_the_run_end_invalid_parameters():
    # Traced times are checked in the solve (diffrax's own run-time check is left out
    # of dense programs so that they can be cached): a bad lane takes no step, the
    # others run.
    good = [0.0, 0.1, 0.3]
    lanes = np.array([good, [0.0, 0.2, 0.1], [0.0, np.nan, 0.2], [-0.1, 0.0, 0.1], [0.0, 0.1, 0.4]])
    r = jax.jit(jax.vmap(lambda t: jw.simulate(jw.Params(), 0.3, ts=t)))(lanes)
    names = [jw.status_name(int(s)) for s in r.status]
    assert names == ["ok"] + ["invalid_parameters"] * 4
    assert [int(n) for n in r.steps[1:]] == [0] * 4
    lone = jw.simulate(jw.Params(), 0.3, ts=np.array(good))
    # Batched and lone solves round differently, which moves adaptive steps: their
    # positions part by at most the local errors summed over the steps (atol per step).
    bound = float(jw.PRESETS["fast"].atol) * int(lone.steps)
    np.testing.assert_allclose(r.trajectory.x[0], lone.trajectory.x, rtol=0, atol=bound)


def test_output_times_are_checked_against_the_whole_periods_horizon():
    # horizon="whole_periods" simulates 0.5 s of a requested 0.7 s (ω = 4π).
    with pytest.raises(ValueError, match=r"need 0 <= ts <= 0.5 \[s\]"):
        jw.simulate(jw.Params(), 0.7, ts=np.array([0.69]), horizon="whole_periods")


def test_an_invalid_lanes_derivative_is_nan_and_the_others_are_untouched():
    # Before, a NaN amplitude's lane gave d v̄/dA = 0 (its placeholder run's derivative).
    p = jw.Params()

    def v(a, omega):
        return jw.simulate(p.replace(A=a, omega=omega), 0.2).mean_velocity

    grads = jax.vmap(jax.grad(v, argnums=(0, 1)))(
        jnp.array([jnp.nan, 0.02, 0.02]), jnp.array([4 * jnp.pi, -1.0, 4 * jnp.pi])
    )
    grads = np.asarray(grads)
    assert np.all(np.isnan(grads[:, :2])), grads  # NaN A; ω < 0
    assert np.all(np.isfinite(grads[:, 2])) and abs(grads[0, 2]) > 0.1, grads


def test_a_traced_controller_with_function_leaves_traces():
    # A PolicyMLP holds functions (its activations) among its leaves: the traced path's
    # checks must take its arrays only (a function once reached a custom JVP and failed).
    mlp = jw.PolicyMLP.init(jax.random.key(0), 7, omega=4 * jnp.pi, delta=-jnp.pi / 4)
    out = eqx.filter_eval_shape(lambda g: jw.simulate(jw.Params(gait=g), 0.1).mean_velocity, mlp)
    assert out.shape == () and out.dtype == jnp.float64

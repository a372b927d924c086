"""Intrinsic-length control (eq. 23) and the travelling wave (eqs. 24-25)."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import jaxworm as jw

close = np.testing.assert_allclose
# no deadline: the first call of each shape compiles
FAST = settings(
    deadline=None, max_examples=40, derandomize=True, suppress_health_check=[HealthCheck.too_slow]
)
BODY = jw.Body()  # N = 7: six segments
L0 = 0.01
A_OVER_OMEGA = 0.0015915494309189536  # A/ω = 0.02 / (4π)


def _u(gait, t, body=BODY):
    z = jnp.zeros(body.N)
    return gait(t, z, z, jnp.full(body.N - 1, L0), body)


def test_travelling_wave_hand_values():
    # Table 1 gait: u_k = 0.02 sin(4π t + kπ/4), k = 1..6 (one per segment).
    # t = 0.1: 4π·0.1 = 72°, so angles 117°, 162°, 207°, 252°, 297°, 342°:
    # sin = 0.8910065241883679, 0.3090169943749475, −0.4539904997395467,
    #       −0.9510565162951535, −0.8910065241883679, −0.3090169943749476
    u = _u(jw.TravellingWave(), 0.1)
    assert u.shape == (6,)
    close(
        u,
        0.02
        * np.array(
            [
                0.8910065241883679,
                0.3090169943749475,
                -0.4539904997395467,
                -0.9510565162951535,
                -0.8910065241883679,
                -0.3090169943749476,
            ]
        ),
        rtol=1e-12,
    )
    # t = 0: 0.02 sin(45°·k) = 0.02·(√2/2, 1, √2/2, 0, −√2/2, −1)
    r = math.sqrt(2) / 2
    close(
        _u(jw.TravellingWave(), 0.0), 0.02 * np.array([r, 1, r, 0, -r, -1]), rtol=1e-12, atol=1e-17
    )


def test_travelling_wave_other_gait_and_size():
    # A = 0.01, ω = 3π, δ = π/3, N = 3 (two segments), t = 0.5:
    # ψ = 1.5π + π/3·k → 270° + 60°, 270° + 120° = 330°, 390° ≡ 30°
    # u = 0.01 (sin 330°, sin 30°) = (−0.005, 0.005)
    g = jw.TravellingWave(A=0.01, omega=3 * math.pi, delta=math.pi / 3)
    close(_u(g, 0.5, jw.Body(N=3)), [-0.005, 0.005], rtol=1e-12)


def test_travelling_wave_ignores_the_state():
    # open loop: the state does not enter u
    g = jw.TravellingWave()
    rng = np.random.default_rng(1)
    a = g(
        0.3,
        jnp.asarray(rng.normal(size=7)),
        jnp.asarray(rng.normal(size=7)),
        jnp.asarray(rng.normal(size=6)),
        BODY,
    )
    close(a, _u(g, 0.3), rtol=0, atol=0)


def test_intrinsic_lengths_hand_values():
    # l̄_k(t) = l_0 + (A/ω)(cos δk − cos(ωt + δk)), t = 0.1:
    # cos 45k° = 0.70710678, 0, −0.70710678, −1, −0.70710678, 0
    # cos(72° + 45k°) = −0.45399050, −0.95105652, −0.89100652, −0.30901699, 0.45399050, 0.95105652
    # e.g. k = 1: 0.01 + 0.00159154943 · (0.70710678 + 0.45399050) = 0.0118479437
    expected = [
        0.01184794371669947,
        0.011513653457281314,
        0.01029268553132069,
        0.00890026639062278,
        0.00815205628330053,
        0.008486346542718686,
    ]
    close(jw.TravellingWave().intrinsic_lengths(0.1, BODY), expected, rtol=1e-12)
    # rest offset: l̄(0) = l_0 (MODEL.md)
    close(jw.TravellingWave().intrinsic_lengths(0.0, BODY), np.full(6, L0), rtol=1e-15)


gait_values = dict(
    A=st.floats(-0.05, 0.05),
    omega=st.floats(0.5, 30.0),
    delta=st.floats(-3.2, 3.2),
    t=st.floats(0.0, 60.0),
)


@FAST
@given(
    a=st.floats(-2000.0, 2000.0),
    b=st.floats(-30.0, 30.0),
    f=st.sampled_from(["sin", "cos"]),
)
def test_sine_of_sum_is_the_sine_of_the_sum(a, b, f):
    # The angle-addition formula against the library's sine of the rounded sum: the two
    # differ by the sum's rounding (half an ulp of a + b) and a few ulps of the products.
    from jaxworm._control import sine_of_sum

    exact = math.sin(a + b) if f == "sin" else math.cos(a + b)
    got = float(sine_of_sum(jnp.asarray(a), jnp.asarray(b), f))
    assert abs(got - exact) <= 4 * np.finfo(float).eps * (1.0 + abs(a) + abs(b))


def test_the_wave_is_the_sine_of_its_phase_for_every_entries_and_numbering():
    for entries in ("segment", "node_difference", "node_mean"):
        for numbering in ("head", "tail"):
            g = jw.TravellingWave(
                A=0.03, omega=3.7, delta=-0.9, entries=entries, numbering=numbering
            )
            for t in (0.0, 0.37, 59.3):
                n = BODY.N - 1 if entries == "segment" else BODY.N
                sines = np.sin(np.asarray(g.phase(t, n)))
                if entries == "node_difference":
                    expected = sines[:-1] - sines[1:]
                elif entries == "node_mean":
                    expected = 0.5 * (sines[:-1] + sines[1:])
                else:
                    expected = sines
                close(_u(g, t), 0.03 * expected, rtol=0, atol=0.03 * 1e-13)


@FAST
@given(**gait_values)
def test_intrinsic_lengths_closed_form(A, omega, delta, t):
    g = jw.TravellingWave(A=A, omega=omega, delta=delta)
    k = np.arange(1, 7)
    expected = L0 + (A / omega) * (np.cos(delta * k) - np.cos(omega * t + delta * k))
    close(g.intrinsic_lengths(t, BODY), expected, rtol=1e-10, atol=1e-14)


@FAST
@given(**gait_values)
def test_intrinsic_lengths_derivative_is_u(A, omega, delta, t):
    # eq. 23: d l̄/dt = u
    g = jw.TravellingWave(A=A, omega=omega, delta=delta)
    dl = jax.jacfwd(lambda s: g.intrinsic_lengths(s, BODY))(jnp.asarray(t))
    close(dl, _u(g, t), rtol=1e-8, atol=1e-13)


def test_centred_offset_oscillates_about_l0():
    g = jw.TravellingWave(offset="centred")
    k = np.arange(1, 7)
    # l̄(0) = l_0 − (A/ω) cos δk
    close(g.lbar0(BODY), L0 - A_OVER_OMEGA * np.cos(np.pi / 4 * k), rtol=1e-12)
    # over one period (2π/ω = 0.5 s) the mean is l_0, and the extremes are l_0 ± A/ω
    ts = jnp.linspace(0.0, 0.5, 400, endpoint=False)
    lb = np.asarray(jax.vmap(lambda t: g.intrinsic_lengths(t, BODY))(ts))
    close(lb.mean(axis=0), np.full(6, L0), rtol=1e-12)
    close(lb.max(axis=0), np.full(6, L0 + A_OVER_OMEGA), rtol=1e-6)
    close(lb.min(axis=0), np.full(6, L0 - A_OVER_OMEGA), rtol=1e-6)
    # the rest offset instead oscillates about l_0 + (A/ω) cos δk
    lr = np.asarray(jax.vmap(lambda t: jw.TravellingWave().intrinsic_lengths(t, BODY))(ts))
    close(lr.mean(axis=0), L0 + A_OVER_OMEGA * np.cos(np.pi / 4 * k), rtol=1e-12)
    # and both offsets share the same u
    close(jax.jacfwd(lambda t: g.intrinsic_lengths(t, BODY))(0.2), _u(g, 0.2), rtol=1e-10)


def test_initial_state_uses_the_gait_initial_lengths():
    k = np.arange(1, 7)
    y = jw.initial_state(jw.Params(gait=jw.TravellingWave(offset="centred")))
    close(y.lbar, L0 - A_OVER_OMEGA * np.cos(np.pi / 4 * k), rtol=1e-12)
    y = jw.initial_state(jw.Params())
    close(y.lbar, np.full(6, L0), rtol=1e-15)
    # x_k(0) = −(k−1) l_0, v = 0
    close(y.x, -L0 * np.arange(7), rtol=1e-15, atol=0)
    close(y.v, np.zeros(7), atol=0)


def test_abstract_controller_needs_call():
    class NoCall(jw.AbstractController):
        pass

    with pytest.raises(TypeError):
        NoCall()


def test_default_controller_lbar0_and_valid():
    class HoldStill(jw.AbstractController):
        def __call__(self, t, x, v, lbar, body):
            return jnp.zeros(body.N - 1)

    c = HoldStill()
    close(c.lbar0(jw.Body(N=4)), np.full(3, L0), rtol=1e-15)
    assert bool(c.valid())


# --- a user controller inside jw.simulate ----------------------------------------------


def test_zero_controller_keeps_the_worm_at_rest(constant_rate_runs):
    # no friction (mu_s = 0), negligible back pressure, u = 0: nothing may move
    r = jax.tree_util.tree_map(lambda a: a[0], constant_rate_runs["result"])
    assert constant_rate_runs["rates"][0] == 0.0
    assert str(r.status_name) == "ok"
    assert int(r.n_cracks) == 0
    close(r.final.x, r.x0, rtol=0, atol=1e-12)
    close(r.final.v, np.zeros(7), rtol=0, atol=1e-9)
    close(r.final.lbar, np.full(6, L0), rtol=0, atol=1e-15)


def test_custom_controller_drives_the_intrinsic_lengths(constant_rate_runs):
    # u_k = 1e-3 m/s for 0.1 s: l̄ = 0.01 + 1e-4 = 0.0101 for every segment
    r = jax.tree_util.tree_map(lambda a: a[1], constant_rate_runs["result"])
    rate, t1 = constant_rate_runs["rates"][1], constant_rate_runs["t1"]
    assert rate == 1e-3 and t1 == 0.1
    assert str(r.status_name) == "ok"
    close(r.final.lbar, np.full(6, L0 + rate * t1), rtol=1e-10)
    # the stiff body follows l̄: total length 6·0.0101 = 0.0606 m (ringing ~1e-7 m)
    close(r.final.x[0] - r.final.x[-1], 6 * (L0 + rate * t1), atol=2e-6)
    # no external force: the centre of mass (end nodes weigh half) stays put, so
    # the head moves forward by half the growth, 3·1e-4 = 3e-4 m
    m = np.array([0.5, 1, 1, 1, 1, 1, 0.5])
    close(np.dot(m, r.final.x) / m.sum(), np.dot(m, r.x0) / m.sum(), atol=1e-9)
    close(r.final.x[0] - r.x0[0], 3 * rate * t1, atol=2e-6)


@FAST
@given(omega=st.floats(0.5, 100.0), t1=st.floats(0.05, 100.0))
def test_whole_period_horizon_is_the_last_whole_period_within_t1(omega, t1):
    period = 2 * math.pi / omega
    if t1 < period:  # no whole period fits: refused, NaN when traced
        with pytest.raises(ValueError, match=r"parameter t1 = .*needs t1 >= one gait period"):
            jw.whole_period_horizon(omega, t1)
        assert bool(jnp.isnan(jax.jit(jw.whole_period_horizon)(omega, t1)))
        return
    h = float(jw.whole_period_horizon(omega, t1))
    K = h / period
    assert abs(K - round(K)) < 1e-9 and round(K) >= 1
    assert t1 - period < h <= t1 * (1 + 1e-12)
    # K is piecewise constant: d/dω (2πK/ω) = −horizon/ω
    g = float(jax.grad(jw.whole_period_horizon)(omega, t1))
    assert math.isclose(g, -h / omega, rel_tol=1e-12)


@pytest.mark.parametrize("omega, delta", [(4 * math.pi, math.pi / 4), (9.7, -0.9)])
def test_intrinsic_lengths_return_to_their_start_after_whole_periods(omega, delta):
    # ∫ sin over whole periods vanishes (eq. 24), so l̄(K·2π/ω) = l̄(0) for every segment.
    gait = jw.TravellingWave(A=0.02, omega=omega, delta=delta)
    h = jw.whole_period_horizon(omega, 10.1)
    close(gait.intrinsic_lengths(h, BODY), gait.lbar0(BODY), rtol=0, atol=1e-15)
    assert not np.allclose(gait.intrinsic_lengths(10.1, BODY), gait.lbar0(BODY), atol=1e-6)


class _Hold(jw.AbstractController):
    """A controller that is not periodic (the default `period`)."""

    def __call__(self, t, x, v, lbar, body):
        return jnp.zeros(body.N - 1)


class _Square(jw.AbstractController):
    """A periodic controller that says only its period."""

    def __call__(self, t, x, v, lbar, body):
        return jnp.zeros(body.N - 1)

    def period(self):
        return jnp.asarray(0.3)


def test_a_controller_says_its_period_and_frequency_or_none():
    wave = jw.TravellingWave(omega=3 * math.pi)
    assert float(wave.period()) == 2 * math.pi / float(3 * math.pi)
    assert float(wave.frequency()) == float(3 * math.pi)  # ω itself, not 2π/(2π/ω)
    seg = jw.SegmentWave.from_wave(wave, BODY.N)
    assert float(seg.period()) == float(wave.period()) and float(seg.frequency()) == float(
        wave.frequency()
    )
    assert _Hold().period() is None and _Hold().frequency() is None
    assert math.isclose(float(_Square().frequency()), 2 * math.pi / 0.3, rel_tol=1e-15)


def test_the_horizon_of_a_run_comes_from_the_gaits_period():
    from jaxworm._control import check_horizon, simulated_horizon

    wave = jw.TravellingWave(omega=9.7)
    assert simulated_horizon(wave, 10.1, "t1") == 10.1
    assert float(simulated_horizon(wave, 10.1, "whole_periods")) == float(
        jw.whole_period_horizon(9.7, 10.1)
    )
    assert math.isclose(
        float(simulated_horizon(_Square(), 1.0, "whole_periods")), 0.9, rel_tol=1e-15
    )  # ⌊1/0.3⌋ = 3 periods
    check_horizon("whole_periods", _Square())
    with pytest.raises(ValueError, match="needs a periodic gait .* _Hold"):
        check_horizon("whole_periods", _Hold())
    with pytest.raises(ValueError, match="option horizon = 'cycles'"):
        check_horizon("cycles", wave)


def test_simulate_over_whole_periods_is_the_run_up_to_the_last_whole_period():
    p = jw.Params(gait=jw.TravellingWave(omega=9.7))
    num = jw.PRESETS["fast"]
    h = jw.whole_period_horizon(9.7, 0.9)  # one period, 0.648 s
    whole = jw.simulate(p, 0.9, num, horizon="whole_periods")
    direct = jw.simulate(p, h, num)
    assert float(whole.t1) == float(h)
    np.testing.assert_array_equal(np.asarray(whole.final.x), np.asarray(direct.final.x))
    assert float(jw.simulate(p, 0.9, num, horizon="t1").t1) == 0.9
    with pytest.raises(ValueError, match="needs a periodic gait"):
        jw.simulate(jw.Params(gait=_Hold()), 0.9, num, horizon="whole_periods")


def test_a_traced_t1_that_is_not_positive_is_refused_over_whole_periods_too():
    # The horizon rounds t1 down to whole periods: the check of t1 must see the t1 asked
    # for, and a t1 shorter than one period (0.648 s) leaves no horizon.
    p = jw.Params(gait=jw.TravellingWave(omega=9.7))
    run = jax.jit(jax.vmap(lambda t: jw.simulate(p, t, horizon="whole_periods")))
    r = run(jnp.array([-1.0, 0.0, jnp.nan, 0.5, 0.9]))
    assert list(jw.status_name(r.status)) == ["invalid_parameters"] * 4 + ["ok"]
    assert float(r.t1[4]) == float(jw.whole_period_horizon(9.7, 0.9))
    with pytest.raises(ValueError, match="parameter t1 = 0.5: horizon 'whole_periods' needs"):
        jw.simulate(p, 0.5, horizon="whole_periods")
    for omega, t1, name in [(0.0, 1.0, "omega"), (-1.0, 1.0, "omega"), (9.7, -1.0, "t1")]:
        with pytest.raises(ValueError, match=f"parameter {name} = -?[0-9.]+: need a finite"):
            jw.whole_period_horizon(omega, t1)
    assert bool(jnp.isnan(jax.jit(jw.whole_period_horizon)(9.7, -1.0)))


def test_sweep_and_optimise_refuse_a_t1_shorter_than_the_longest_period_before_solving():
    # ω down to 1 rad/s: a 6.28-s period, longer than t1 = 1 s
    msg = r"parameter t1 = 1.0: horizon 'whole_periods' needs t1 >= one gait period \(6.28"
    with pytest.raises(ValueError, match=msg):
        jw.optimise(bounds={"omega": (1.0, 20.0)}, t1=1.0, steps=1)
    with pytest.raises(ValueError, match=msg):
        jw.sweep({"omega": [1.0, 20.0]}, t1=1.0, horizon="whole_periods")
    slow = jw.Params(gait=jw.TravellingWave(omega=1.0))
    with pytest.raises(ValueError, match=msg):
        jw.optimise(bounds={"A": (0.01, 0.03)}, base=slow, t1=1.0, steps=1, horizon="whole_periods")


# --- eq. 24's N node entries combined per segment (option entries) --------------------


def test_node_entries_combined_per_segment_hand_values():
    # N = 7: node entries a_k = 0.02 sin(45°·k), k = 1..7, at t = 0:
    # a = 0.02·(r, 1, r, 0, −r, −1, −r), r = √2/2
    r = math.sqrt(2) / 2
    a = 0.02 * np.array([r, 1, r, 0, -r, -1, -r])
    diff = _u(jw.TravellingWave(entries="node_difference"), 0.0)
    close(diff, a[:-1] - a[1:], rtol=1e-12, atol=1e-17)
    mean = _u(jw.TravellingWave(entries="node_mean"), 0.0)
    close(mean, 0.5 * (a[:-1] + a[1:]), rtol=1e-12, atol=1e-17)
    # amplitudes 2A sin(δ/2) and A cos(δ/2)
    gait = jw.TravellingWave(entries="node_difference")
    ts = np.linspace(0.0, 0.5, 101)
    peak = max(float(jnp.max(jnp.abs(_u(gait, t)))) for t in ts)
    assert peak <= 0.02 * 2 * math.sin(math.pi / 8) * (1 + 1e-12)
    assert peak >= 0.02 * 2 * math.sin(math.pi / 8) * 0.99
    close(float(gait.amplitude_factor()), 2 * math.sin(math.pi / 8), rtol=1e-14)
    close(float(jw.TravellingWave(entries="node_mean").amplitude_factor()), math.cos(math.pi / 8))


@pytest.mark.parametrize("entries", ["node_difference", "node_mean"])
@pytest.mark.parametrize("offset", ["rest", "centred"])
def test_node_entries_intrinsic_lengths_integrate_u(entries, offset):
    gait = jw.TravellingWave(omega=3 * math.pi, delta=math.pi / 3, entries=entries, offset=offset)
    t = 0.37
    du = jax.jacfwd(lambda s: gait.intrinsic_lengths(s, BODY))(t)
    close(du, _u(gait, t), rtol=1e-10, atol=1e-14)
    close(gait.intrinsic_lengths(0.0, BODY), gait.lbar0(BODY), rtol=1e-14)
    if offset == "rest":
        close(gait.lbar0(BODY), np.full(6, L0), rtol=1e-15)
    else:  # oscillates about l0: the mean over a period is l0
        ts = np.linspace(0.0, 2 / 3, 600, endpoint=False)
        mean = np.mean([np.asarray(gait.intrinsic_lengths(s, BODY)) for s in ts], axis=0)
        close(mean, np.full(6, L0), rtol=1e-12)


def test_entries_option_is_validated_and_the_default_is_one_per_segment():
    assert jw.TravellingWave().entries == "segment"
    with pytest.raises(ValueError, match=r"option entries = 'nodes': need 'segment' or "):
        jw.TravellingWave(entries="nodes")
    # the default is the one-entry-per-segment wave (to rounding: `sine_of_sum`)
    g = jw.TravellingWave()
    expected = 0.02 * np.sin(4 * np.pi * 0.3 + np.pi / 4 * np.arange(1, 7))
    phase = 4 * np.pi * 0.3 + np.pi / 4 * 6  # the largest; bound as for `sine_of_sum`
    close(_u(g, 0.3), expected, rtol=0, atol=0.02 * 4 * np.finfo(float).eps * (1 + phase))


@pytest.mark.parametrize("numbering", ["head", "tail"])
@pytest.mark.parametrize("entries", ["segment", "node_difference", "node_mean"])
def test_segment_wave_from_a_wave_has_its_rates(entries, numbering):
    wave = jw.TravellingWave(omega=3 * math.pi, delta=0.7, entries=entries, numbering=numbering)
    seg = jw.SegmentWave.from_wave(wave, BODY.N)
    for t in (0.0, 0.13, 0.41):
        close(_u(seg, t), _u(wave, t), rtol=1e-12, atol=1e-16)


def test_tail_numbering_counts_k_from_the_tail():
    # ψ_k = ωt + δ(N − k) for segment k from the head (N = 7): at t = 0, δ = π/4:
    # 0.02 sin(45°·(6, 5, 4, 3, 2, 1)) = 0.02·(−1, −r, 0, r, 1, r)
    r = math.sqrt(2) / 2
    u = _u(jw.TravellingWave(numbering="tail"), 0.0)
    close(u, 0.02 * np.array([-1, -r, 0, r, 1, r]), rtol=1e-12, atol=1e-17)
    # node entries: node k has ψ = δ(N + 1 − k): 0.02 sin(45°·(7, 6, ..., 1))
    a = 0.02 * np.sin(np.pi / 4 * np.arange(7, 0, -1))
    close(
        _u(jw.TravellingWave(numbering="tail", entries="node_mean"), 0.0),
        0.5 * (a[:-1] + a[1:]),
        rtol=1e-12,
        atol=1e-17,
    )
    with pytest.raises(ValueError, match=r"option numbering = 'back': need 'head' or 'tail'"):
        jw.TravellingWave(numbering="back")


class _ScaledWave(jw.TravellingWave):
    """A user's wave: the travelling wave's rate times a gain of its own."""

    gain: jax.Array = eqx.field(default=1.0, converter=jnp.asarray)

    def __call__(self, t, x, v, lbar, body):
        return self.gain * super().__call__(t, x, v, lbar, body)


def test_a_subclassed_wave_runs_and_its_invalid_lanes_are_flagged():
    # A lane's placeholder keeps the gait's type: a subclass once made every traced run
    # fail with a pytree-structure error (the placeholder was a plain TravellingWave).
    num = jw.PRESETS["fast"].replace(atol=1e-11)  # batched and lone runs agree closely
    mine = jw.simulate(jw.Params(gait=_ScaledWave(gain=1.0)), 0.3, num)
    wave = jw.simulate(jw.Params(gait=jw.TravellingWave()), 0.3, num)
    close(mine.mean_velocity, wave.mean_velocity, rtol=1e-12)
    batch = jax.vmap(lambda a, g: jw.simulate(jw.Params(gait=_ScaledWave(A=a, gain=g)), 0.3, num))(
        jnp.array([0.02, jnp.nan]), jnp.array([0.5, 0.5])
    )
    assert list(jw.status_name(batch.status)) == ["ok", "invalid_parameters"]
    half = jw.simulate(jw.Params(gait=_ScaledWave(gain=0.5)), 0.3, num)
    close(batch.mean_velocity[0], half.mean_velocity, rtol=1e-5)

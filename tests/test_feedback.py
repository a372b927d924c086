"""Closed-loop control: the sensors against eqs. (12) and (16), the reflex wave against
the open-loop wave it extends, the leak's bound on the intrinsic lengths, the policy's
rate bound, the sensor noise's statistics, derivatives against finite differences, and
the errors a user meets.

Solves are few and short (2 s): the TravellingWave and its zero-gain ReflexWave solved
tightly, one vmapped batch of reflex runs over soil samples and noise, one derivative
and one vmapped batch of finite differences."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import jaxworm as jw
from jaxworm._dynamics import COLLAPSE_FRACTION
from jaxworm._sensors import band_limited_noise

close = np.testing.assert_allclose
OMEGA, DELTA, A = 3 * jnp.pi, -jnp.pi / 4, 0.03
BODY = jw.Body()


def _wave_lengths(A, omega, delta, t, N, l0):
    """l̄°_k(t) = l_0 + (A/ω)(cos δk − cos(ωt + δk)), k = 1..N−1: eq. (24) integrated
    from rest, written out here."""
    k = np.arange(1, N)
    phase = omega * np.asarray(t)[..., None] + delta * k
    return l0 + (A / omega) * (np.cos(delta * k) - np.cos(phase))


def _moving_state(p, seed=0):
    """The rest state with its nodes moved, moving, and its actuators off rest."""
    y0 = jw.initial_state(p)
    k1, k2, k3 = jax.random.split(jax.random.key(seed), 3)
    return eqx.tree_at(
        lambda y: (y.x, y.v, y.lbar),
        y0,
        (
            y0.x + 1e-4 * jax.random.normal(k1, y0.x.shape),
            1e-2 * jax.random.normal(k2, y0.v.shape),
            y0.lbar * (1 + 0.05 * jax.random.normal(k3, y0.lbar.shape)),
        ),
    )


def _sensors(t, lbar, *, seed=0):
    """Sensors of an arbitrary instant: random velocities, lengths near l_0 and stress
    ratio in [0, 1.5), the given intrinsic lengths."""
    N = BODY.N
    k1, k2, k3, k4 = jax.random.split(jax.random.key(seed), 4)
    return jw.Sensors(
        t=jnp.asarray(t, dtype=float),
        v=0.05 * jax.random.normal(k1, (N,)),
        lengths=BODY.l0 * (1 + 0.1 * jax.random.normal(k2, (N - 1,))),
        lbar=jnp.asarray(lbar, dtype=float),
        back_pressure=1e-6 * jax.random.uniform(k3),
        stress_ratio=1.5 * jax.random.uniform(k4),
    )


# --- the sensors: eqs. (12) and (16) --------------------------------------------------


@pytest.mark.parametrize("wedge", ["given", "eq5"])
@pytest.mark.parametrize("side", [-1, 1], ids=["tip_in_first_layer", "tip_in_second_layer"])
def test_sensors_are_eqs_12_and_16_with_the_soil_at_the_crack_tip(side, wedge):
    interface = 0.004
    E = (1.4e5, 2.1e5)
    K_Ic, K_Ith = (250.0, 500.0), (200.0, 400.0)
    p = jw.Params().replace(
        E_s=jw.Layered([interface], list(E)),
        K_Ic=jw.Layered([interface], list(K_Ic)),
        K_Ith=jw.Layered([interface], list(K_Ith)),
        wedge=wedge,
    )
    y = _moving_state(p)
    x_c = interface + side * 1e-3
    s = jw.sensors_of(0.3, y, x_c, p)

    b, soil = p.body, p.soil
    i = 0 if side < 0 else 1
    E_s, K_c, nu = E[i], K_Ic[i], float(soil.nu)
    w0, l0, h = float(b.w0), float(b.l0), float(b.h)
    x = np.asarray(y.x)
    gap, l1 = x_c - x[0], x[0] - x[1]
    Wg = K_c**2 * float(soil.w_c) / (E_s**2 * h * w0) if wedge == "eq5" else float(soil.Wg)
    K_I = E_s * w0 * l0 / (math.sqrt(2 * math.pi * gap) * (1 - nu**2) * l1)  # eq. (12)
    F_p = E_s * (w0 * l0) ** 2 * h * Wg / (2 * math.pi * gap * l1**2 * (1 - nu**2))  # eq. (16)

    assert 0.0 < gap and float(s.t) == 0.3
    close(s.stress_ratio, K_I / K_c, rtol=1e-13)
    close(s.back_pressure, F_p, rtol=1e-13)
    close(s.lengths, x[:-1] - x[1:], rtol=1e-15)
    close(s.v, y.v, rtol=0)
    close(s.lbar, y.lbar, rtol=0)


# --- the reflex wave against the open-loop wave ---------------------------------------


def test_zero_gain_reflex_rate_is_the_wave_rate_exactly_on_the_wave_lengths():
    wave = jw.TravellingWave(A=A, omega=OMEGA, delta=DELTA)
    tw = jw.Params(gait=wave)
    rw = jw.Params(gait=jw.ReflexWave(A=A, omega=OMEGA, delta=DELTA, leak=2.0))
    y = _moving_state(tw, seed=1)
    for t in (0.0, 0.37, 1.9):
        on_wave = eqx.tree_at(lambda y: y.lbar, y, wave.intrinsic_lengths(t, tw.body))
        u = jw.control_rate(t, on_wave, 0.01, rw)
        expected = wave(t, on_wave.x, on_wave.v, on_wave.lbar, tw.body)
        np.testing.assert_array_equal(u, expected)
        np.testing.assert_array_equal(u, jw.control_rate(t, on_wave, 0.01, tw))
        # Off the wave's lengths the leak pulls back at rate κ = leak·ω.
        off = eqx.tree_at(lambda y: y.lbar, on_wave, on_wave.lbar + 1e-5)
        close(jw.control_rate(t, off, 0.01, rw), expected - 2.0 * OMEGA * 1e-5, rtol=1e-12)


def test_reflex_amplitude_stays_below_twice_A_and_follows_the_resistance():
    g = jw.ReflexWave(A=A, omega=OMEGA, delta=DELTA, gain_stress=50.0, gain_speed=-30.0)
    t = 0.21
    lbar = _wave_lengths(A, OMEGA, DELTA, t, BODY.N, BODY.l0)
    k = np.arange(1, BODY.N)
    for seed in range(5):
        s = _sensors(t, lbar, seed=seed)
        u = np.asarray(g.control(s, BODY))
        z = 50.0 * (float(s.stress_ratio) - 0.5) - 30.0 * float(s.v[0]) / A
        amplitude = A * 2 / (1 + math.exp(-z))  # 2σ(z)
        close(u, amplitude * np.sin(OMEGA * t + DELTA * k), rtol=1e-12, atol=1e-18)
        assert np.all(np.abs(u) < 2 * A)


def test_reflex_rate_is_its_formula_written_out_with_every_gain():
    """u_k = A·2σ(g_K(K_I/K_Ic − r_0) + g_v v_1/A) sin(ωt + (δ + g_δ(K_I/K_Ic − r_0))k)
    − κ(l̄_k − l̄°_k), in numpy, off the wave's lengths, on a 40-node body (the phase
    offsets are built by angle addition up to k = 39)."""
    body = jw.Body(N=40)
    g = jw.ReflexWave(
        A=A, omega=OMEGA, delta=DELTA, gain_stress=0.7, gain_speed=-0.4, gain_phase=0.9,
        stress_ref=0.3, leak=1.5,
    )  # fmt: skip
    k = np.arange(1, body.N)
    for seed, t in enumerate((0.0, 0.21, 7.3)):
        lbar0 = _wave_lengths(A, OMEGA, DELTA, t, body.N, body.l0)
        lbar = lbar0 * (1 + 0.01 * np.cos(k + seed))
        rng = np.random.default_rng(seed)
        s = jw.Sensors(
            t=jnp.asarray(t),
            v=jnp.asarray(0.05 * rng.standard_normal(body.N)),
            lengths=jnp.full(body.N - 1, body.l0),
            lbar=jnp.asarray(lbar),
            back_pressure=jnp.asarray(1e-4),
            stress_ratio=jnp.asarray(1.5 * rng.random()),
        )
        r = float(s.stress_ratio) - 0.3
        amplitude = A * 2 / (1 + math.exp(-(0.7 * r - 0.4 * float(s.v[0]) / A)))
        expected = amplitude * np.sin(OMEGA * t + (DELTA + 0.9 * r) * k)
        expected -= 1.5 * OMEGA * (lbar - lbar0)
        close(g.control(s, body), expected, rtol=1e-11, atol=1e-16)


@pytest.fixture(scope="module")
def zero_gain_pair():
    """The wave and its zero-gain reflex over 2 s (one crack), solved tightly: local
    error ≤ 1e-10 m per step on the positions, ~12,000 steps."""
    tight = jw.PRESETS["fast"].replace(atol=1e-10)
    tw = jw.simulate(jw.Params().replace(A=A, omega=OMEGA, delta=DELTA), 2.0, tight)
    g = jw.ReflexWave(A=A, omega=OMEGA, delta=DELTA)
    rw = jw.simulate(jw.Params(gait=g), 2.0, tight)
    return tw, rw, tight


def test_zero_gain_reflex_reproduces_the_travelling_wave(zero_gain_pair):
    tw, rw, tight = zero_gain_pair
    assert tw.status_name == rw.status_name == "ok"
    n = int(tw.n_cracks)
    assert int(rw.n_cracks) == n >= 1
    # The same ODE solved two ways: the open-loop wave by the structured Schur solve,
    # the closed-loop reflex by a dense (N+S) LU, so their adaptive steps differ. Each
    # accepted step's error is ≤ atol in RMS over the positions and lengths, so ≤ √2·atol
    # on the mean node position; summed over the steps of both solves and divided by t1
    # this bounds how far their mean velocities part. Measured: 2.1e-7 m/s against this
    # bound of 1.7e-6 m/s; the wave alone moves by 3.4e-7 m/s from atol 1e-10 to 1e-11.
    bound = math.sqrt(2) * float(tight.atol) * (int(tw.steps) + int(rw.steps)) / 2.0
    assert abs(float(rw.mean_velocity) - float(tw.mean_velocity)) <= bound
    # The crack time: where K_I, rising slowly, reaches K_Ic, so a position error δ
    # moves it by ~(δ/l_1)/(d ln K_I/dt); measured 2.0e-6 s apart here (and the wave's
    # own moves by 3.3e-6 s from atol 1e-10 to 1e-11).
    close(rw.crack_times[:n], tw.crack_times[:n], rtol=0, atol=2e-5)


# --- the leak, sensor noise and soil samples: one batch -------------------------------

STRONG = dict(gain_stress=4.0, gain_speed=2.0, gain_phase=-0.5, stress_ref=0.3)
BATCH_T1 = 2.0
BATCH_TS = jnp.linspace(0.0, BATCH_T1, 201)
#: Lanes: soil sample (RandomField key), noise on (σ's scale), gains.
LANES = (
    dict(soil=0, noise=0.0),  # clean
    dict(soil=0, noise=1.0),  # the same soil, noisy sensors
    dict(soil=1, noise=0.0),
    dict(soil=2, noise=0.0),
)
NOISE = dict(velocity=0.005, length=1e-4, stress_ratio=0.1, back_pressure=0.3)


@pytest.fixture(scope="module")
def reflex_batch():
    """Strong reflexes over three soil samples (K_Ic, K_Ith random fields, 10 %, 2 cm),
    one lane with sensor noise; dense output."""
    soil_keys = jax.random.split(jax.random.key(7), 3)
    keys = jnp.stack([soil_keys[lane["soil"]] for lane in LANES])
    scales = jnp.array([lane["noise"] for lane in LANES])

    def run(key, scale):
        noise = jw.SensorNoise(jax.random.key(11), **{n: scale * s for n, s in NOISE.items()})
        g = jw.ReflexWave(A=A, omega=OMEGA, delta=DELTA, noise=noise, **STRONG)
        soil = dict(
            K_Ic=jw.RandomField(250.0, 0.1, 0.02, key), K_Ith=jw.RandomField(235.0, 0.1, 0.02, key)
        )
        return jw.simulate(jw.Params(gait=g).replace(**soil), BATCH_T1, ts=BATCH_TS)

    return eqx.filter_jit(jax.vmap(run))(keys, scales)


def test_every_reflex_lane_ends_ok_with_cracks_and_finite_values(reflex_batch):
    r = reflex_batch
    assert [status for status in np.asarray(r.status)] == [0] * len(LANES)
    assert np.all(np.asarray(r.n_cracks) >= 2)
    assert np.all(np.isfinite(np.asarray(r.mean_velocity)))
    assert np.all(np.asarray(r.mean_velocity) > 0)
    assert np.all(np.isfinite(np.asarray(r.trajectory.x)))
    # The soil samples differ, and so do their runs.
    v = np.asarray(r.mean_velocity)
    assert v[2] != v[0] and v[3] != v[0] and v[2] != v[3]


def test_leak_keeps_the_intrinsic_lengths_within_3A_over_kappa_of_the_wave(reflex_batch):
    # e = l̄ − l̄° obeys e' = A_eff sin(ωt + δ_eff k) − A sin(ωt + δk) − κ e with
    # A_eff < 2A, so |e'| ≤ 3A − κ|e| and |e| ≤ 3A/κ from e(0) = 0, whatever the sensors.
    traj = reflex_batch.trajectory
    nominal = _wave_lengths(A, OMEGA, DELTA, np.asarray(BATCH_TS), BODY.N, BODY.l0)
    e = np.abs(np.asarray(traj.lbar) - nominal[None])
    bound = 3 * A / (1.0 * OMEGA)
    assert np.all(e <= bound), (e.max(), bound)
    # The reflexes do move the lengths off the wave's: the bound is not vacuous.
    assert e.max() > 0.05 * bound


def test_sensor_noise_changes_the_run_and_it_stays_ok(reflex_batch):
    r = reflex_batch
    clean, noisy = (jax.tree_util.tree_map(lambda a, i=i: a[i], r) for i in (0, 1))
    assert int(noisy.status) == 0
    assert float(clean.mean_velocity) != float(noisy.mean_velocity)
    # The noise reaches the intrinsic lengths (through the reflexes), not by a crash.
    dl = np.max(np.abs(np.asarray(noisy.trajectory.lbar) - np.asarray(clean.trajectory.lbar)))
    assert 1e-8 < dl < 3 * A / OMEGA


# --- sensor noise ---------------------------------------------------------------------


def test_band_limited_noise_has_zero_mean_and_unit_variance_over_keys():
    keys = jax.random.split(jax.random.key(0), 4000)
    for t in (0.0, 1.3):
        n = np.asarray(jax.vmap(lambda k, t=t: band_limited_noise(k, t, (3,), 20.0, 16))(keys))
        # 12,000 samples (4,000 keys × 3 independent elements): the standard error of
        # the mean is 1/√12,000 = 0.009, of the variance ≈ √(2/12,000) = 0.013 for a
        # Gaussian (a sum of 16 random-phase cosines is close to one); 4.5 standard errors.
        assert abs(n.mean()) < 0.04, n.mean()
        assert abs(n.var() - 1.0) < 0.06, n.var()
    a = band_limited_noise(keys[0], 0.7, (5,), 20.0, 16)
    np.testing.assert_array_equal(a, band_limited_noise(keys[0], 0.7, (5,), 20.0, 16))
    assert np.all(a != band_limited_noise(keys[1], 0.7, (5,), 20.0, 16))


def test_band_limited_noise_is_smooth_with_frequencies_below_the_bandwidth():
    # |dn/dt| ≤ √(2/M) Σ ω_j < √(2M)·bandwidth for any key.
    key, bandwidth, modes = jax.random.key(3), 20.0, 16
    dn = jax.vmap(jax.grad(lambda t: band_limited_noise(key, t, (), bandwidth, modes)))(
        jnp.linspace(0.0, 2.0, 101)
    )
    assert np.all(np.abs(np.asarray(dn)) < math.sqrt(2 * modes) * bandwidth)


def test_sensor_noise_of_zero_sigma_leaves_the_sensors_unchanged():
    s = _sensors(0.4, BODY.l0 * jnp.ones(BODY.N - 1), seed=2)
    same = jw.SensorNoise(jax.random.key(5))(s)
    for a, b in zip(jax.tree_util.tree_leaves(s), jax.tree_util.tree_leaves(same)):
        np.testing.assert_array_equal(a, b)


def test_sensor_noise_perturbs_the_measured_signals_only_and_reproducibly():
    s = _sensors(0.4, BODY.l0 * jnp.ones(BODY.N - 1), seed=2)
    noise = jw.SensorNoise(
        jax.random.key(5), velocity=1e-3, length=1e-4, stress_ratio=0.1, back_pressure=0.2
    )
    m = noise(s)
    assert float(m.t) == float(s.t)
    np.testing.assert_array_equal(m.lbar, s.lbar)  # the commanded lengths are known
    for name in ("v", "lengths", "stress_ratio"):
        assert np.all(np.asarray(getattr(m, name)) != np.asarray(getattr(s, name))), name
    assert float(m.back_pressure) > 0  # relative noise keeps F_p positive
    for a, b in zip(jax.tree_util.tree_leaves(m), jax.tree_util.tree_leaves(noise(s))):
        np.testing.assert_array_equal(a, b)


# --- the neural policy ----------------------------------------------------------------


@jax.jit
def _policy_rate(key, t, lbar, v, lengths, stress_ratio, scale):
    """A policy with every weight random (scaled by `scale`) and the sensors given."""
    policy = jw.PolicyMLP.init(jax.random.key(0), BODY.N, width=8, depth=2, A_max=A, b=2.0)
    params, static = eqx.partition(policy, eqx.is_inexact_array)
    leaves, tree = jax.tree_util.tree_flatten(params)
    keys = jax.random.split(key, len(leaves))
    leaves = [scale * jax.random.normal(k, x.shape) for k, x in zip(keys, leaves)]
    policy = eqx.combine(jax.tree_util.tree_unflatten(tree, leaves), static)
    fixed = (jnp.asarray(OMEGA), jnp.asarray(A), jnp.asarray(1.0))
    policy = eqx.tree_at(lambda q: (q.omega, q.A_max, q.leak), policy, fixed)
    s = jw.Sensors(t, v, lengths, lbar, jnp.asarray(1e-7), stress_ratio)
    return policy.control(s, BODY)


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    t=st.floats(0.0, 100.0),
    lbar_off=st.floats(-0.5, 0.5),
    v=st.floats(-1.0, 1.0),
    stress=st.floats(0.0, 10.0),
    scale=st.floats(0.0, 10.0),
)
def test_policy_rates_are_bounded_by_A_max_for_any_weights_and_sensors(
    seed, t, lbar_off, v, stress, scale
):
    N = BODY.N
    u = _policy_rate(
        jax.random.key(seed),
        t,
        BODY.l0 * (1 + lbar_off) * jnp.ones(N - 1),
        v * jnp.ones(N),
        BODY.l0 * jnp.ones(N - 1),
        stress,
        scale,
    )
    # ≤, not <: tanh rounds to 1 in float64 beyond ~19.
    assert np.all(np.isfinite(np.asarray(u)))
    assert np.all(np.abs(np.asarray(u)) <= A)


def test_fresh_policy_on_the_wave_lengths_is_the_squashed_wave():
    N, b, A_max = BODY.N, 3.0, 0.025
    k = np.arange(1, N)
    for depth in (0, 1, 2):
        policy = jw.PolicyMLP.init(
            jax.random.key(depth), N, depth=depth, omega=OMEGA, delta=DELTA, b=b, A_max=A_max
        )
        for seed, t in enumerate((0.0, 0.41, 3.3)):
            lbar = _wave_lengths(A_max, OMEGA, DELTA, t, N, BODY.l0)
            u = policy.control(_sensors(t, lbar, seed=seed), BODY)
            close(u, A_max * np.tanh(b * np.sin(OMEGA * t + DELTA * k)), rtol=1e-13, atol=1e-18)


def _numpy_mlp(mlp, x):
    """An equinox MLP with tanh hidden layers and an identity output, in numpy."""
    for i, layer in enumerate(mlp.layers):
        x = np.asarray(layer.weight) @ x + np.asarray(layer.bias)
        if i < len(mlp.layers) - 1:
            x = np.tanh(x)
    return x


@pytest.mark.parametrize("depth", [0, 1, 2])
def test_trained_policy_rate_is_its_formula_written_out(depth):
    """u_k = A_max tanh(b sin(ωt + δk) + m_k(features) − κ(l̄_k − l̄°_k)/A_max) with every
    weight random (a trained network's last layer is not zero) and m in numpy."""
    N, b, A_max, leak = BODY.N, 2.0, 0.025, 1.5
    policy = jw.PolicyMLP.init(
        jax.random.key(depth), N, depth=depth, omega=OMEGA, delta=DELTA, b=b, A_max=A_max
    )
    leaves, tree = jax.tree_util.tree_flatten(eqx.filter(policy.mlp, eqx.is_inexact_array))
    keys = jax.random.split(jax.random.key(10 + depth), len(leaves))
    mlp = eqx.combine(
        jax.tree_util.tree_unflatten(
            tree, [jax.random.normal(k, x.shape) for k, x in zip(keys, leaves)]
        ),
        policy.mlp,
    )
    policy = eqx.tree_at(lambda c: (c.mlp, c.leak), policy, (mlp, leak))
    k = np.arange(1, N)
    for seed, t in enumerate((0.0, 0.41, 3.3)):
        lbar0 = _wave_lengths(A_max, OMEGA, DELTA, t, N, BODY.l0)
        lbar = lbar0 * (1 + 0.01 * np.sin(k + seed))
        s = _sensors(t, lbar, seed=seed)
        v, lengths = np.asarray(s.v), np.asarray(s.lengths)
        features = np.array(
            [
                np.sin(OMEGA * t),
                np.cos(OMEGA * t),
                v[0] / A_max,
                v.mean() / A_max,
                float(s.stress_ratio),
                10 * (lengths[0] - lbar[0]) / BODY.l0,
            ]
        )
        z = b * np.sin(OMEGA * t + DELTA * k) + _numpy_mlp(mlp, features)
        z -= leak * OMEGA * (lbar - lbar0) / A_max
        close(policy.control(s, BODY), A_max * np.tanh(z), rtol=1e-12, atol=1e-18)


GRAD_Z = (1.0, A)  # (gain_stress, A)
GRAD_T1 = 2.1  # whole periods: 3 × 2π/ω = 2 s
#: Relative steps of the central differences: the step and its check.
GRAD_STEPS = (1e-2, 5e-3)


def _reflex_velocity(z, numerics):
    g = jw.ReflexWave(A=z[1], omega=OMEGA, delta=DELTA, gain_stress=z[0])
    p = jw.Params(gait=g).replace(K_Ith=235.0)  # several cracks in 2 s (test_gradients.py)
    r = jw.simulate(p, GRAD_T1, numerics, horizon="whole_periods")
    return r.mean_velocity, r.n_cracks


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(depth=0, final_activation=jnp.sin),
        dict(depth=1),
        dict(depth=2, final_activation=jnp.sin, use_bias=False, use_final_bias=False),
        dict(depth=2, activation=eqx.nn.PReLU(0.1), final_activation=eqx.nn.PReLU(0.2)),
        dict(depth=3, scan=True),
    ],
    ids=["depth0_final_sin", "depth1", "no_bias", "prelu", "scan"],
)
def test_the_policys_network_is_equinoxs_mlp_call(kwargs):
    """The policy's network evaluated as products and sums (`mlp_by_products`) is
    `eqx.nn.MLP.__call__` (depth 0 takes no activation, per-layer activations, no bias,
    a scanned MLP passed through), and a subclass with its own call keeps it."""
    from jaxworm._feedback import mlp_by_products

    mlp = eqx.nn.MLP(6, 5, 8, key=jax.random.key(3), dtype=float, **kwargs)
    x = jax.random.normal(jax.random.key(4), (6,))
    close(mlp_by_products(mlp, x), mlp(x), rtol=1e-14, atol=1e-15)

    class Doubled(eqx.nn.MLP):
        def __call__(self, x, *, key=None):
            return 2.0 * super().__call__(x, key=key)

    doubled = jax.tree_util.tree_unflatten(
        jax.tree_util.tree_structure(
            Doubled(6, 5, 8, key=jax.random.key(3), dtype=float, **kwargs)
        ),
        jax.tree_util.tree_leaves(mlp),
    )
    close(mlp_by_products(doubled, x), 2.0 * mlp(x), rtol=1e-14, atol=1e-15)


# --- derivatives against finite differences -------------------------------------------


@pytest.fixture(scope="module")
def reflex_gradient():
    # The exact jump conditions at the events, right on short horizons, and the
    # sensitivities solved to tolerance (sensitivity_tol = 1): test_gradients.py.
    exact = jw.PRESETS["fast"].replace(max_cracks=8, crack_sensitivity="exact", sensitivity_tol=1.0)
    z = jnp.array(GRAD_Z)
    grad = jax.grad(lambda z: _reflex_velocity(z, exact)[0])(z)
    # The reference: central differences of a tight solve (local error ≤ 1e-10 m per
    # step, as test_sensitivity.py), at two steps, all in one vmapped batch.
    lanes = []
    for rel in GRAD_STEPS:
        for i in range(2):
            for sign in (1.0, -1.0):
                lanes.append(z.at[i].add(sign * rel * abs(GRAD_Z[i])))
    tight = jw.PRESETS["fast"].replace(atol=1e-10, max_cracks=8)
    vals, cracks = eqx.filter_jit(jax.vmap(lambda z: _reflex_velocity(z, tight)))(jnp.stack(lanes))
    vals = np.asarray(vals).reshape(len(GRAD_STEPS), 2, 2)
    steps = np.array([[rel * abs(x) for x in GRAD_Z] for rel in GRAD_STEPS])
    fd = (vals[:, :, 0] - vals[:, :, 1]) / (2 * steps)
    return np.asarray(grad), fd, np.asarray(cracks)


@pytest.mark.parametrize("i", [0, 1], ids=["gain_stress", "A"])
def test_reflex_gradient_matches_finite_differences_of_a_tight_solve(reflex_gradient, i):
    grad, fd, cracks = reflex_gradient
    assert np.all(cracks >= 2)  # the derivative goes through crack events
    # 2 % of the difference, or twice the differences' own disagreement between the
    # two steps (their truncation and the tight solve's step jitter): test_gradients.py.
    noise = abs(fd[0, i] - fd[1, i])
    assert abs(fd[0, i]) > 0
    assert abs(grad[i] - fd[0, i]) <= max(0.02 * abs(fd[0, i]), 2 * noise), (grad, fd)


# --- a reflex that collapses the body ------------------------------------------------

#: At ω = 2π the wave's lengths swing down to l_0 − 2A/ω = 0.45 cm, and a stress reflex
#: of gain 4 raises the amplitude towards 2A: a length reaches zero at t ≈ 0.41 s.
COLLAPSING_REFLEX = dict(A=A, omega=2 * jnp.pi, delta=DELTA, gain_stress=4.0)
#: Steps to the collapse: ~2,000 (`fast`, atol 1e-8 or 1e-10), ~9,400 with forward
#: sensitivities. Past it the solver used to run on through inverted segments to the
#: step bound, 2**20 steps (~35 s); with sensitivities the steps shrank with the length
#: until time stood still, short of zero.
COLLAPSE_STEPS = 10_000


def _collapsed(r):
    """A length at or below the collapse threshold, and no runaway past it."""
    lengths = np.concatenate([np.diff(-np.asarray(r.final.x)), np.asarray(r.final.lbar)])
    return lengths.min() <= COLLAPSE_FRACTION * BODY.l0 and np.all(np.abs(lengths) < BODY.l0 * 10)


def test_a_reflex_that_collapses_the_body_ends_body_inverted_at_once():
    # The numerics of `zero_gain_pair`: the same compiled program.
    tight = jw.PRESETS["fast"].replace(atol=1e-10)
    r = jw.simulate(jw.Params(gait=jw.ReflexWave(**COLLAPSING_REFLEX)), 1.0, tight)
    assert r.status_name == "body_inverted"
    assert 0.3 < float(r.t_end) < 0.5 and int(r.steps) < COLLAPSE_STEPS
    assert _collapsed(r)


def test_the_derivative_of_a_collapsing_run_stops_there_too():
    # Forward sensitivities (the program of `reflex_gradient`): the solve carries them
    # and stops at the collapse as the plain solve does.
    exact = jw.PRESETS["fast"].replace(max_cracks=8, crack_sensitivity="exact", sensitivity_tol=1.0)

    def velocity(z):
        g = jw.ReflexWave(**{**COLLAPSING_REFLEX, "A": z[1], "gain_stress": z[0]})
        r = jw.simulate(
            jw.Params(gait=g).replace(K_Ith=235.0), GRAD_T1, exact, horizon="whole_periods"
        )
        return r.mean_velocity, r

    z = jnp.array([COLLAPSING_REFLEX["gain_stress"], A])
    _, r = jax.grad(velocity, has_aux=True)(z)
    assert r.status_name == "body_inverted"
    assert float(r.t_end) < 0.5 and int(r.steps) < COLLAPSE_STEPS
    assert _collapsed(r)


# --- errors ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: jw.ReflexWave(omega=-1.0), r"omega.*-1"),
        (lambda: jw.ReflexWave(leak=0.0), r"leak.*0"),
        (lambda: jw.ReflexWave(A=-0.01), r"A.*-0\.01"),
        (lambda: jw.ReflexWave(gain_stress=float("nan")), r"gain_stress.*nan"),
        (lambda: jw.SensorNoise(jax.random.key(0), velocity=-1.0), r"velocity.*-1"),
        (lambda: jw.SensorNoise(jax.random.key(0), bandwidth=0.0), r"bandwidth.*0"),
        (lambda: jw.SensorNoise(jax.random.key(0), modes=0), r"modes.*0"),
        (lambda: jw.PolicyMLP.init(jax.random.key(0), 1), r"N.*1"),
        (lambda: jw.PolicyMLP.init(jax.random.key(0), 7, A_max=0.0), r"A_max.*0"),
        (lambda: jw.PolicyMLP.init(jax.random.key(0), 7, width=0), r"width.*0"),
        (lambda: jw.PolicyMLP.init(jax.random.key(0), 7, depth=-1), r"depth.*-1"),
    ],
)
def test_invalid_controllers_are_refused_naming_the_parameter_and_value(make, match):
    with pytest.raises(ValueError, match=match):
        make()


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: jw.ReflexWave(noise=0.1), r"noise = 0\.1 \(float\).*SensorNoise"),
        (lambda: jw.PolicyMLP.init(jax.random.key(0), 7, noise=1), r"noise = 1 \(int\)"),
        (lambda: jw.SensorNoise(0, velocity=1e-3), r"key = 0 \(int\).*jax.random.key"),
        (lambda: jw.SensorNoise(jax.random.key(0), modes=True), r"modes = True \(bool\)"),
    ],
)
def test_what_is_not_a_noise_a_key_or_an_integer_is_refused_when_built(make, match):
    # These were taken, and the solve then failed in JAX's own words.
    with pytest.raises(TypeError, match=match):
        make()


def test_a_policy_built_for_another_body_is_refused_naming_both_sizes():
    policy = jw.PolicyMLP.init(jax.random.key(0), 5)
    with pytest.raises(ValueError, match=r"4 rates.*N = 7 nodes, 6 segments.*init\(key, 7\)"):
        jw.simulate(jw.Params(gait=policy), 0.1)


@pytest.mark.parametrize(
    "controller",
    [jw.ReflexWave(), jw.PolicyMLP.init(jax.random.key(0), 7)],
    ids=["ReflexWave", "PolicyMLP"],
)
def test_calling_a_feedback_controller_like_an_open_loop_one_says_what_to_call(controller):
    y = jw.initial_state(jw.Params())
    with pytest.raises(TypeError, match=r"control\(sensors, body\)"):
        controller(0.0, y.x, y.v, y.lbar, BODY)

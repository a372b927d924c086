"""The default derivative: forward sensitivities of the Rosenbrock solve (`_sensitivity`).

`jax.jacfwd` and `jax.grad` of `jw.simulate(p, t1)` with its default numerics, checked
against an analytic solution, the finite-difference slope of a tightly solved model
through many cracks, each other, and `vmap`. The exact jump conditions at the events
are checked against finite differences in `test_gradients.py`; the 60-s checks are
`benchmarks/gradient_accuracy.py`.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxworm as jw

MIRROR = jw.Params().replace(delta=-jnp.pi / 4)
NAMES = ("A", "omega", "delta")


def _velocity(base, t1, numerics=None, whole_periods=True):
    def v(z):
        p = base.replace(**dict(zip(NAMES, z)))
        horizon = jw.whole_period_horizon(z[1], t1) if whole_periods else t1
        return jw.simulate(p, horizon, numerics).mean_velocity

    return v


def _z(p):
    return jnp.array([float(p.flat()[n]) for n in NAMES])


def test_intrinsic_length_sensitivities_match_the_closed_form():
    # l̄_k(t) = l0 + (A/ω)(cos δk − cos(ωt + δk)) (eq. 24 integrated): the sensitivity
    # integration must reproduce its derivatives, an independent check of the method.
    t1 = 0.37
    z = _z(MIRROR)

    def lbar(z):
        return jw.simulate(MIRROR.replace(A=z[0], omega=z[1], delta=z[2]), t1).final.lbar

    def closed(z):
        return MIRROR.replace(A=z[0], omega=z[1], delta=z[2]).gait.intrinsic_lengths(
            t1, MIRROR.body
        )

    np.testing.assert_allclose(
        np.asarray(jax.jacfwd(lbar)(z)), np.asarray(jax.jacfwd(closed)(z)), rtol=1e-7, atol=1e-12
    )


@pytest.fixture(scope="module")
def slope_check():
    """The forward-sensitivity derivative (solved to tolerance) and the least-squares
    slope of 11 tight solves over ±0.5 % per parameter, over whole gait periods through
    many cracks (ω = 3π, K_Ith = 235: ~18 cracks in 10 s)."""
    base = jw.Params().replace(omega=3 * jnp.pi, delta=-jnp.pi / 6, K_Ith=235.0)
    t1, z = 10.0, _z(base)
    tight = jw.PRESETS["fast"].replace(atol=1e-10)
    k = np.arange(-5, 6)
    Z = np.repeat(np.asarray(z)[None, None, :], 3, axis=0).repeat(len(k), axis=1)
    for i in range(3):
        Z[i, :, i] *= 1 + 1e-3 * k
    v_tight = jax.jit(jax.vmap(_velocity(base, t1, tight)))
    vals = np.asarray(v_tight(jnp.asarray(Z.reshape(-1, 3)))).reshape(3, len(k))
    fits = [np.polyfit(Z[i, :, i] - z[i], vals[i], 1, cov=True) for i in range(3)]
    slope = np.array([c[0] for c, _ in fits])
    stderr = np.array([np.sqrt(cov[0, 0]) for _, cov in fits])
    r = jw.simulate(base, t1)
    # The sensitivities solved to tolerance: at the default sensitivity_tol the
    # whole-period ω component, a ~7 % residual of two cancelling terms over only 15
    # periods, moves by ±4 % (scaled) under a 10 % change of atol on this scene, so one
    # default solve tests the rounding, not the method. The default's accuracy over
    # 60 s is benchmarks/gradient_accuracy.py's.
    converged = jw.PRESETS["fast"].replace(sensitivity_tol=1.0)
    jac = np.asarray(jax.jit(jax.jacfwd(_velocity(base, t1, converged)))(z))
    return {
        "z": np.asarray(z),
        "slope": slope,
        "stderr": stderr,
        "jac": jac,
        "cracks": int(r.n_cracks),
    }


def test_sensitivity_derivative_matches_the_slope_through_many_cracks(slope_check):
    z, ref = slope_check["z"], slope_check["slope"]
    assert slope_check["cracks"] >= 15
    top = np.max(np.abs(z * ref))
    scaled = np.abs(z * (slope_check["jac"] - ref)) / top
    # 2 % of the largest scaled sensitivity, beyond the fit's own uncertainty (2σ).
    noise = 2 * np.abs(z * slope_check["stderr"]) / top
    assert np.all(scaled <= 0.02 + noise), (slope_check["jac"], ref, scaled, noise)


def test_the_mean_position_norm_matches_the_slope_in_fewer_steps(slope_check):
    # Goal-oriented step control (`Numerics.sensitivity_norm="mean_position"`, what
    # jw.optimise takes for the mean velocity): only the mean node position's
    # sensitivities steer the steps. The mean velocity's derivative must still meet the
    # slope, in fewer steps (accepted and rejected) than the state norm's.
    z, ref = slope_check["z"], slope_check["slope"]
    base = jw.Params().replace(omega=3 * jnp.pi, delta=-jnp.pi / 6, K_Ith=235.0)
    t1 = 10.0

    def steps_and_jac(norm):
        numerics = jw.PRESETS["fast"].replace(sensitivity_tol=1.0, sensitivity_norm=norm)

        def v(z):
            p = base.replace(**dict(zip(NAMES, z)))
            r = jw.simulate(p, jw.whole_period_horizon(z[1], t1), numerics)
            return r.mean_velocity, r.steps + r.rejected_steps

        jac, steps = jax.jit(jax.jacfwd(v, has_aux=True))(jnp.asarray(z))
        return int(steps), np.asarray(jac)

    state_steps, state_jac = steps_and_jac("state")
    np.testing.assert_array_equal(state_jac, slope_check["jac"])  # the fixture's solve
    goal_steps, goal_jac = steps_and_jac("mean_position")
    top = np.max(np.abs(z * ref))
    scaled = np.abs(z * (goal_jac - ref)) / top
    noise = 2 * np.abs(z * slope_check["stderr"]) / top
    assert np.all(scaled <= 0.02 + noise), (goal_jac, ref, scaled, noise)
    assert goal_steps < state_steps, (goal_steps, state_steps)


def test_vmap_of_grad_is_the_stack_of_grads():
    # The lanes crack 4 and 1 times, so one finishes its segments early.
    t1 = 2.5
    base = jw.Params().replace(K_Ith=235.0)
    zs = jnp.array([[0.02, 4 * jnp.pi, -jnp.pi / 6], [0.025, 3.5 * jnp.pi, jnp.pi / 3]])
    # Sensitivities solved to tolerance, so that what remains between a lane and a lone
    # solve is rounding: at the default sensitivity_tol, over 2.5 s, the ω component
    # moves by ~25 % (scaled) under a 5 % change of atol, hiding a lane mix-up.
    numerics = jw.PRESETS["fast"].replace(sensitivity_tol=1.0)
    v = _velocity(base, t1, numerics, whole_periods=False)
    # The plain phase frame (no start-up ramp): there the batched reverse- and
    # forward-mode programs round alike, so any difference between them is a mix-up.
    plain = jw.PRESETS["fast"].replace(sensitivity_tol=1.0, sensitivity_ramp=0.0)
    v_plain = _velocity(base, t1, plain, whole_periods=False)

    def with_cracks(z):
        r = jw.simulate(base.replace(**dict(zip(NAMES, z))), t1, plain)
        return r.mean_velocity, r.n_cracks

    batched_plain = np.asarray(jax.jit(jax.vmap(jax.grad(v_plain)))(zs))
    batched_fwd, cracks = jax.jit(jax.vmap(jax.jacfwd(with_cracks, has_aux=True)))(zs)
    np.testing.assert_allclose(batched_plain, np.asarray(batched_fwd), rtol=1e-10, atol=1e-14)
    assert cracks[0] >= 3 and cracks[1] < cracks[0]
    batched = np.asarray(jax.jit(jax.vmap(jax.grad(v)))(zs))  # the default numerics
    single = jax.jit(jax.grad(v))  # one program for both lone solves
    lone_fwd = jax.jit(jax.jacfwd(v))
    for i in range(2):
        one = np.asarray(single(zs[i]))
        # Lone, the two modes' programs round alike: the same derivative bit for bit.
        np.testing.assert_array_equal(one, np.asarray(lone_fwd(zs[i])))
        # Batched and single solves round differently, which moves adaptive steps: the
        # two derivatives differ within the solve's error, not by a lane mix-up.
        np.testing.assert_allclose(batched[i], one, rtol=2e-2, atol=2e-4)


def test_a_derivative_along_the_elastic_body_matches_a_tight_slope():
    # l0 sets the initial state and, with m and EA, the elastic ringing that the
    # positions norm steps over: the default derivative along them takes the full norm.
    # At 0.3 s the positions norm's was 0.45 against the slope 0.017 (and 0.062, its own
    # solve's slope); the full norm's 0.0180 (`benchmarks/body_gradient.py`).
    t1, l0 = 0.3, 1e-2

    def v(x, numerics=None):
        return jw.simulate(MIRROR.replace(l0=x), t1, numerics).mean_velocity

    d = float(jax.grad(v)(l0))
    tight = jw.Numerics(solver="Rodas4", atol=1e-11)
    h = 0.01 * l0
    slope = (float(v(l0 + h, tight)) - float(v(l0 - h, tight))) / (2 * h)
    assert abs(d - slope) <= 0.1 * abs(slope), (d, slope)
    held = jw.PRESETS["fast"].replace(norm="full")
    assert d == float(jax.grad(lambda x: v(x, held))(l0))  # the same solve


def test_fixed_steps_refuse_derivatives():
    num = jw.PRESETS["fast"].replace(dt=2e-4)
    with pytest.raises(jw.SensitivityUnavailableError, match="fixed step"):
        jax.grad(lambda a: jw.simulate(MIRROR.replace(A=a), 0.1, num).mean_velocity)(0.02)
    assert np.isfinite(float(jw.simulate(MIRROR, 0.1, num).mean_velocity))


#: A scene that cracks within 2 s, with dense output at five times: the surrogate's tests
#: below share its compiled programs.
CRACKING = MIRROR.replace(K_Ic=215.0)
CRACKING_T1, CRACKING_TS = 2.0, jnp.linspace(0.0, 2.0, 5)


def _cracking_run(a):
    return jw.simulate(CRACKING.replace(A=a), CRACKING_T1, ts=CRACKING_TS)


def test_schedule_held_gives_no_derivative_of_the_crack_records():
    # Under the default surrogate the per-crack derivatives are not available: NaN, while
    # the mean velocity's gradient stays finite.
    def records(a):
        r = _cracking_run(a)
        return r.crack_times, r.mean_velocity

    d_times, d_v = jax.jacfwd(records)(0.02)
    n = int(_cracking_run(0.02).n_cracks)
    assert n >= 1
    assert np.all(np.isnan(np.asarray(d_times)[:n])) and np.all(np.asarray(d_times)[n:] == 0)
    assert np.isfinite(float(d_v))
    g = jax.grad(lambda a: _cracking_run(a).mean_velocity)(0.02)
    assert np.isfinite(float(g)) and abs(float(g) - float(d_v)) < 1e-10


def test_derivative_with_respect_to_the_horizon_is_the_velocity_identity():
    t1 = 0.61
    dv = float(jax.grad(lambda t: jw.simulate(MIRROR, t).mean_velocity)(t1))
    r = jw.simulate(MIRROR, t1)
    expected = (float(jnp.mean(r.final.v)) - float(r.mean_velocity)) / t1
    np.testing.assert_allclose(dv, expected, rtol=1e-6)


def test_the_derivative_of_a_whole_result_carries_the_mean_velocitys():
    # A Result of tangents (`jax.jvp` of the whole Result) holds d v̄ as its field, equal to
    # the derivative of the number itself: along a parameter and along t1 (a computed
    # property there once divided the positions' tangents by the end time's, 0: inf).
    t1 = 0.61

    def run(a, t):
        return jw.simulate(MIRROR.replace(A=a), t)

    for tangent in ((1.0, 0.0), (0.0, 1.0)):
        _, d_result = jax.jvp(run, (0.02, t1), tangent)
        _, d_v = jax.jvp(lambda a, t: run(a, t).mean_velocity, (0.02, t1), tangent)
        assert np.isfinite(float(d_v)) and float(d_v) != 0.0
        np.testing.assert_allclose(float(d_result.mean_velocity), float(d_v), rtol=1e-12)
    for read in (lambda r: r.ok, lambda r: r.status_name, lambda r: r.summary()):
        with pytest.raises(TypeError, match="this Result holds derivatives .* no status"):
            read(d_result)


def test_derivative_with_respect_to_output_times_is_refused():
    with pytest.raises(ValueError, match="output times"):
        jax.jacfwd(lambda ts: jw.simulate(MIRROR, 0.2, ts=ts).trajectory.x[:, 0])(
            jnp.array([0.05, 0.1])
        )


def test_trajectory_sensitivities_match_finite_differences():
    ts = jnp.linspace(0.0, 0.3, 4)
    # At atol = 1e-10, S(0.2 s) still moves by ~4 % under a 10 % change of atol (the
    # start-up transient; docs/known-issues.md): compare where both sides have converged.
    num = jw.PRESETS["fast"].replace(atol=1e-11)

    def head(a):
        return jw.simulate(MIRROR.replace(A=a), 0.3, num, ts=ts).trajectory.x[:, 0]

    d = np.asarray(jax.jacfwd(head)(0.02))
    # The slope of a line through nine runs over ±1 % of A: a single central difference
    # of two runs carries their step sequences' jitter (S(0.2 s) by ±0.5 % steps: 0.0150
    # to 0.0158 as the rounding of the state changed, while the sensitivity and this
    # slope stayed within 0.6 % of each other).
    dA = 0.02 * 0.0025 * np.arange(-4, 5)
    heads = np.asarray(jax.vmap(head)(jnp.asarray(0.02 + dA)))
    fd = np.polyfit(dA, heads, 1)[0]
    np.testing.assert_allclose(d, fd, rtol=2e-2, atol=1e-6)
    assert np.max(np.abs(fd)) > 1e-3


def test_a_diffrax_solver_refuses_the_schedule_held_derivative():
    num = jw.PRESETS["default"]
    with pytest.raises(jw.SensitivityUnavailableError, match="crack_sensitivity='exact'"):
        jax.grad(lambda a: jw.simulate(MIRROR.replace(A=a), 0.1, num).mean_velocity)(0.02)
    # Asking for a mode the diffrax solver can give is accepted: the derivative traces
    # (jax.eval_shape: no compilation; the diffrax derivative through the events is
    # checked against finite differences in test_gradients.py, with the exact jumps).
    g = jax.eval_shape(
        jax.grad(
            lambda a: (
                jw.simulate(
                    MIRROR.replace(A=a), 0.1, num.replace(crack_sensitivity="tips_held")
                ).mean_velocity
            )
        ),
        0.02,
    )
    assert g.shape == () and g.dtype == jnp.float64


def test_second_derivatives_are_refused():
    with pytest.raises(jw.SecondDerivativeError, match="second derivatives"):
        jax.hessian(lambda a: jw.simulate(MIRROR.replace(A=a), 0.05).mean_velocity)(0.02)


@pytest.mark.parametrize("name", ["atol", "sensitivity_tol", "pcoeff"])
def test_a_derivative_with_respect_to_a_numerics_option_is_refused(name):
    # The options are inputs of the program (arrays), but the solve depends on them only
    # through its discrete steps: such a derivative was a JAX error about a "keyword
    # tangent"; it is refused, naming what to differentiate instead.
    fast = jw.PRESETS["fast"]

    def v(x):
        return jw.simulate(MIRROR, 0.05, fast.replace(**{name: x})).mean_velocity

    with pytest.raises(jw.SensitivityUnavailableError, match="numerics' options"):
        jax.grad(v)(jnp.asarray(getattr(fast, name)))
    with pytest.raises(jw.SensitivityUnavailableError, match="numerics' options"):
        jax.jacfwd(v)(jnp.asarray(getattr(fast, name)))


def test_bad_sensitivity_options_name_the_option():
    with pytest.raises(ValueError, match="crack_sensitivity = 'sometimes'"):
        jw.Numerics(crack_sensitivity="sometimes")
    with pytest.raises(ValueError, match="sensitivity_tol = -1"):
        jw.Numerics(sensitivity_tol=-1.0)


def test_the_tip_has_no_derivative_after_a_crack_under_the_surrogate():
    # The tip after a crack is a per-crack record (the helper probe found the surrogate's
    # d x_c/dA sign-flipped and 5x off the finite differences): NaN, as are K_I and the
    # back pressure along the trajectory from the first crack on; before it, finite.
    def tip(a):
        r = _cracking_run(a)
        return r.x_c, r.trajectory.x_c, r.trajectory.K_I, r.trajectory.back_pressure

    r = _cracking_run(0.02)
    first = float(r.crack_times[0])
    assert int(r.n_cracks) >= 1 and 0.0 < first < CRACKING_T1
    d_xc, d_traj_xc, d_K, d_bp = (np.asarray(d) for d in jax.jacfwd(tip)(0.02))
    after = np.asarray(CRACKING_TS) >= first
    assert np.isnan(d_xc)
    for d in (d_traj_xc, d_K, d_bp):
        assert np.all(np.isnan(d[after])) and np.all(np.isfinite(d[~after]))


@pytest.mark.parametrize("name", ["K_Ic", "K_Ith"])
def test_fracture_constants_are_refused_under_the_surrogate(name):
    # The surrogate holds the crack schedule these constants set: d v̄/dK_Ic would be 0.
    def v(k, numerics=jw.PRESETS["fast"]):
        return jw.simulate(MIRROR.replace(**{name: k}), 0.5, numerics).mean_velocity

    value = float(MIRROR.flat()[name])
    with pytest.raises(jw.SensitivityUnavailableError, match=f"respect to {name} .*'exact'"):
        jax.grad(v)(value)
    # A soil field's values too.
    with pytest.raises(jw.SensitivityUnavailableError, match=f"respect to {name}"):
        jax.jacfwd(lambda k: v(jw.Layered([0.05], k)))(jnp.array([value, 1.1 * value]))
    # The exact jump conditions give it (traced only: its values are in test_gradients).
    exact = jw.PRESETS["fast"].replace(crack_sensitivity="exact")
    assert jax.eval_shape(jax.grad(lambda k: v(k, exact)), value).shape == ()


class _Brake(jw.AbstractFeedbackController):
    """The wave, slowed as the crack ahead nears running (reads K_I/K_Ic)."""

    gain: float = 0.5
    stop: bool = False  # the stress signal behind jax.lax.stop_gradient

    def control(self, s, body):
        ratio = jax.lax.stop_gradient(s.stress_ratio) if self.stop else s.stress_ratio
        return (1.0 - self.gain * ratio) * jw.TravellingWave()(s.t, None, None, None, body)


class _Blind(jw.AbstractFeedbackController):
    """The wave, as a feedback controller that reads only the velocities."""

    def control(self, s, body):
        return jw.TravellingWave()(s.t, None, None, None, body) * (1.0 + 0.0 * s.v[0])


def test_which_controllers_read_the_crack():
    from jaxworm._dynamics import reads_crack

    reads = {
        "wave": jw.TravellingWave(),
        "reflex (gains 0: still reads)": jw.ReflexWave(),
        "policy": jw.PolicyMLP.init(jax.random.key(0), 7),
        "brake": _Brake(),
    }
    for name, gait in reads.items():
        assert reads_crack(jw.Params(gait=gait)) == (name != "wave"), name
    assert not reads_crack(jw.Params(gait=_Blind()))
    assert not reads_crack(jw.Params(gait=_Brake(stop=True)))


@pytest.mark.parametrize(
    "numerics",
    [
        jw.PRESETS["fast"],
        jw.PRESETS["fast"].replace(crack_sensitivity="tips_held"),
        jw.Numerics(solver="Kvaerno3", crack_sensitivity="tips_held"),
    ],
    ids=["schedule_held", "tips_held", "Kvaerno3 tips_held"],
)
def test_a_controller_that_reads_the_crack_is_refused_a_held_crack_derivative(numerics):
    # Both held modes drop how u moves with the crack times: for a ReflexWave with a
    # stress reflex over 15 s (4 cracks) d v̄/dA came out +0.49 (schedule held) and +0.32
    # (tips held) against -0.091 by finite differences and -0.091 exact.
    def v(gain):
        return jw.simulate(jw.Params(gait=_Brake(gain)), 0.5, numerics).mean_velocity

    with pytest.raises(jw.SensitivityUnavailableError, match="reads the crack.*'exact'"):
        jax.grad(v)(0.5)
    # Values are still given (once: the refusal is the same in every mode), and the exact
    # mode differentiates it (traced only).
    if numerics.crack_sensitivity == "schedule_held":
        assert np.isfinite(float(v(0.5)))
    exact = jw.PRESETS["fast"].replace(crack_sensitivity="exact")
    run = lambda g: jw.simulate(jw.Params(gait=_Brake(g)), 0.5, exact).mean_velocity  # noqa: E731
    assert jax.eval_shape(jax.grad(run), 0.5).shape == ()


def test_a_run_that_does_not_end_ok_has_nan_derivatives():
    # Stopped at max_cracks, the run ends at a crack time, which the derivative would
    # hold fixed (d v̄/dt1 came out 1.3e-3 where finite differences give exactly 0).
    stopped = jw.PRESETS["fast"].replace(max_cracks=1)

    def v(z, numerics):
        return jw.simulate(MIRROR.replace(A=z[0]), z[1], numerics).mean_velocity

    z = jnp.array([0.02, 5.0])
    r = jw.simulate(MIRROR, 5.0, stopped)
    assert r.status_name == "too_many_cracks"
    assert np.all(np.isnan(jax.grad(v)(z, stopped)))
    assert np.all(np.isnan(jax.jacfwd(v)(z, stopped)))


def test_the_frame_moves_no_derivative():
    # Any frame φ gives the same sensitivities once converted back (`Frame`): the plain
    # phase frame, the ramped one and one that stays at fixed time within each segment
    # must agree, at the end, at output times on both sides of a crack, and across it.
    t1 = 4.5
    ts = jnp.array([0.7, 1.9, 3.1, 4.2])

    def run(ramp):
        num = jw.PRESETS["fast"].replace(atol=1e-10, sensitivity_tol=1.0, sensitivity_ramp=ramp)

        def f(z):
            r = jw.simulate(MIRROR.replace(**dict(zip(NAMES, z))), t1, num, ts=ts)
            return (r.mean_velocity, r.final.x, r.trajectory.x), r.n_cracks

        return jax.jacfwd(f, has_aux=True)(_z(MIRROR))

    (plain, cracks), ramped, held = run(0.0), run(0.3)[0], run(1e3)[0]
    assert 1 <= cracks and int(jw.simulate(MIRROR, 3.1).n_cracks) >= 1  # ts past a crack
    for other in (ramped, held):
        for a, b in zip(plain, other):
            a, b = np.asarray(a), np.asarray(b)
            # Each column (A, ω, δ) to 2e-3 of its largest entry: the frames take other
            # steps, so they differ by the solve's error (~3e-4 seen); a conversion at the
            # wrong φ is off by r (t − φ) f, several % of the ω column.
            diff, scale = np.abs(a - b).reshape(-1, 3), np.max(np.abs(a).reshape(-1, 3), axis=0)
            np.testing.assert_array_less(diff, np.broadcast_to(2e-3 * scale + 1e-14, diff.shape))


def test_the_ramped_frame_starts_at_fixed_time_and_ends_at_fixed_phase():
    from jaxworm._sensitivity import Frame

    frame = Frame(jnp.ones(3), jnp.array(0.3))
    assert float(frame.phi(0.0)) == 0.0 and float(frame.slope(0.0)) == 0.0
    for t in (0.1, 0.7, 3.0):
        np.testing.assert_allclose(float(jax.grad(frame.phi)(t)), float(frame.slope(t)), rtol=1e-12)
    np.testing.assert_allclose(float(frame.phi(20.0)), 20.0, rtol=1e-14)  # at fixed phase
    plain = Frame(jnp.ones(3), jnp.array(0.0))
    assert float(plain.phi(3.3)) == 3.3 and float(plain.slope(3.3)) == 1.0

"""Physics of whole runs: Newton's laws, energy conservation, constant volume, crack law.

Each test states a law the solution must obey and checks it on the solver's output,
independently of how the vector field computes it.
"""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jaxtyping import Array, Float

import jaxworm as jw

# Full error norm, resolving the elastic ringing: for short horizons.
TIGHT = jw.Numerics(
    solver="Kvaerno5", rtol=1e-9, atol=1e-12, norm="full", pcoeff=0.0, icoeff=1.0, max_steps=2**18
)
# Error on positions only, 1e-10 m per step: for runs of seconds with cracks.
TIGHT_POS = jw.Numerics(solver="Kvaerno5", rtol=0.0, atol=1e-10, norm="positions")


class Frozen(jw.AbstractController):
    """l̄ frozen at a perturbed shape: u = 0, l̄(0) = l_0 (1 + a_k)."""

    bumps: Float[Array, " S"]

    def __call__(self, t, x, v, lbar, body):
        return jnp.zeros(body.N - 1)

    def lbar0(self, body):
        return body.l0 * (1.0 + self.bumps)


def _far_crack(p: jw.Params) -> jw.Params:
    """No back pressure worth the name: a crack tip 1 km ahead and Wg tiny."""
    return p.replace(crack_gap0=1e3, Wg=1e-30)


#: Dense output times of the TIGHT runs with a travelling wave: one shape, so that they
#: share one compiled program (their crack tips are all given, `crack_gap0`).
TIGHT_TIMES = 2001


@pytest.fixture(scope="module")
def frictionless_wave():
    """Travelling wave, μ_s = 0, no back pressure: the soil exerts no force at all."""
    p = _far_crack(jw.Params().replace(mu_s=0.0))
    ts = jnp.linspace(0.0, 0.5, TIGHT_TIMES)
    return p, jw.simulate(p, 0.5, TIGHT, ts=ts)


def test_momentum_is_conserved_when_no_external_force_acts(frictionless_wave):
    p, r = frictionless_wave
    m = p.body.node_masses
    momentum = r.trajectory.v @ m
    centre = r.trajectory.x @ m / jnp.sum(m)
    # Internal spring forces cancel in pairs (Newton's third law): Σ m_k v_k = 0 and
    # the centre of mass stays where it started, while the body itself moves.
    assert float(jnp.max(jnp.abs(momentum))) < 1e-14  # kg m/s; m v ~ 1e-7 here
    assert float(jnp.max(jnp.abs(centre - centre[0]))) < 1e-11
    assert float(jnp.max(jnp.abs(r.trajectory.x[:, 0] - r.trajectory.x[0, 0]))) > 1e-4


def test_momentum_changes_by_the_back_pressure_impulse():
    # μ_s = 0 but the crack is 1 cm ahead of the head: d(Σ m v)/dt = −F_p (eq. 17 summed).
    p = jw.Params().replace(mu_s=0.0, crack_gap0=0.08, Wg=1.0)
    ts = jnp.linspace(0.0, 0.2, TIGHT_TIMES)
    r = jw.simulate(p, 0.2, TIGHT, ts=ts)
    tr = r.trajectory
    momentum = tr.v @ p.body.node_masses
    impulse = jnp.concatenate(
        [
            jnp.zeros(1),
            jnp.cumsum(0.5 * (tr.back_pressure[1:] + tr.back_pressure[:-1]) * jnp.diff(ts)),
        ]
    )
    assert float(jnp.max(jnp.abs(impulse))) > 1e-5  # the force is felt
    np.testing.assert_allclose(np.asarray(momentum), -np.asarray(impulse), rtol=1e-5, atol=1e-12)


def test_energy_is_conserved_without_friction_and_with_frozen_intrinsic_lengths():
    bumps = jnp.array([0.01, -0.02, 0.015, 0.0, -0.01, 0.005])
    p = _far_crack(jw.Params(gait=Frozen(bumps)).replace(mu_s=0.0))
    ts = jnp.linspace(0.0, 0.005, 401)  # ~8 periods of the fastest elastic mode
    r = jw.simulate(p, 0.005, TIGHT, ts=ts)
    tr = r.trajectory
    total = tr.kinetic + tr.stretching_energy
    assert float(jnp.max(tr.kinetic)) > 0.3 * float(total[0])  # it really oscillates
    assert float(jnp.max(jnp.abs(total - total[0])) / total[0]) < 1e-6


@pytest.fixture(scope="module")
def cracking_run():
    """A forward gait over 4 s, three cracks or more: the laws of a run with friction and
    cracks are checked on it (one compiled program, one solve)."""
    p = jw.Params().replace(delta=-jnp.pi / 6, K_Ith=235.0)
    ts = jnp.linspace(0.0, 4.0, 801)
    return p, jw.simulate(p, 4.0, TIGHT_POS, ts=ts)


def test_work_energy_balance_closes_on_a_cracking_run(cracking_run):
    p, r = cracking_run
    assert r.status_name == "ok"
    assert int(r.n_cracks) >= 2
    e = jw.energy_terms(jw.initial_state(p), r.final, p)
    assert float(e["friction_dissipation"]) > 0  # friction dissipates
    assert abs(float(r.energy_residual)) < 1e-4


def test_friction_uses_widths_by_constant_volume(cracking_run):
    # Eq. (7) in its stress form, σ_N = E_s max(w − w_c, 0) with w = w0 l0 / l (eq. 6),
    # times the contact area l h, rebuilt from the trajectory, gives the node friction.
    p, r = cracking_run
    tr = r.trajectory
    b, s = p.body, p.soil
    l = tr.x[:, :-1] - tr.x[:, 1:]
    width = b.w0 * b.l0 / l
    normal = l * b.h * s.E_s * jnp.maximum(width - s.w_c, 0.0)
    vseg = 0.5 * (tr.v[:, :-1] + tr.v[:, 1:])
    sgn = jnp.tanh(vseg / p.smoothing.eps_v)
    f_seg = s.mu_s * ((b.lam - 1) / 2 - (b.lam + 1) / 2 * sgn) * normal
    f_node = 0.5 * (jnp.pad(f_seg, ((0, 0), (0, 1))) + jnp.pad(f_seg, ((0, 0), (1, 0))))
    assert float(jnp.max(normal)) > 1e-5  # segments do press on the crack walls
    # eps_N = 1e-8 N of smoothing in the max is the only difference allowed.
    np.testing.assert_allclose(
        np.asarray(tr.friction), np.asarray(f_node), atol=2e-8 * float(s.mu_s * b.lam)
    )
    np.testing.assert_allclose(np.asarray(width * l), float(b.w0 * b.l0), rtol=1e-12)


def test_stress_intensity_equals_K_Ic_at_each_crack_and_K_Ith_right_after(cracking_run):
    p, r = cracking_run
    n = int(r.n_cracks)
    assert n >= 3
    s, b = p.soil, p.body
    x1, l1 = np.asarray(r.crack_x1[:n]), np.asarray(r.crack_l1[:n])
    tips = np.asarray(r.crack_tips[:n])
    before = np.concatenate([[float(r.x_c0)], tips[:-1]])

    def K(tip):
        return (
            s.E_s * b.w0 * b.l0 / (np.sqrt(2 * np.pi * (tip - x1)) * (1 - s.nu**2) * l1)
        )  # eq. 12

    np.testing.assert_allclose(K(before), float(s.K_Ic), rtol=1e-8)  # the event is located
    np.testing.assert_allclose(K(tips), float(s.K_Ith), rtol=1e-12)  # eq. 13
    assert np.all(np.diff(np.asarray(r.crack_times[:n])) > 0)
    assert np.all(np.diff(tips) > 0)


def test_stress_intensity_never_exceeds_K_Ic_between_cracks(cracking_run):
    p, r = cracking_run
    K = np.asarray(r.trajectory.K_I)
    assert K.max() <= float(p.soil.K_Ic) * (1 + 1e-8)
    assert K.max() > 0.99 * float(p.soil.K_Ic)  # it does get there
    # the tip in the trajectory only ever moves forward, by jumps
    assert np.all(np.diff(np.asarray(r.trajectory.x_c)) >= 0)


def test_a_tip_given_within_the_critical_distance_jumps_at_t0():
    # 1 mm ahead of the head: K_I(0) ≈ 8 K_Ic, above K_Ic with no upward crossing to
    # detect. Eq. (13) applies at t = 0 (K_I = K_Ith right after), and the run goes on.
    p = jw.Params().replace(delta=-jnp.pi / 6, K_Ith=235.0, crack_gap0=1e-3)
    s, b = p.soil, p.body
    x = -np.arange(b.N) * float(b.l0)  # rest, head at 0 (MODEL.md)

    def K(gap):
        return s.E_s * b.w0 * b.l0 / (np.sqrt(2 * np.pi * gap) * (1 - s.nu**2) * (x[0] - x[1]))

    assert K(1e-3) > 5 * float(s.K_Ic)
    r = jw.simulate(p, 3.0, TIGHT_POS)
    assert r.status_name == "ok"
    assert float(r.x_c0) == pytest.approx(x[0] + 1e-3, abs=1e-15)
    assert float(r.crack_times[0]) == 0.0
    np.testing.assert_allclose(K(float(r.crack_tips[0]) - x[0]), float(s.K_Ith), rtol=1e-12)
    assert int(r.n_cracks) >= 2  # and it cracks again as it advances
    assert np.all(np.diff(np.asarray(r.crack_times[: int(r.n_cracks)])) > 0)
    assert float(r.mean_velocity) > 1e-3  # no stall (it stalled at -6e-5 m/s before)


def test_crack_bound_is_a_named_status_not_a_truncation():
    p = jw.Params().replace(delta=-jnp.pi / 6, K_Ith=235.0)
    r = jw.simulate(p, 4.0, TIGHT_POS.replace(max_cracks=2))
    assert r.status_name == "too_many_cracks"
    assert int(r.n_cracks) == 2
    assert float(r.final.x[0]) < 0.5  # stopped before t1, and says so
    # the time reached is reported, and the speed is over it, never the distance / t1
    # (at the third crack, the one beyond the bound: after the two recorded)
    assert float(r.crack_times[1]) < float(r.t_end) < float(r.t1) == 4.0
    advance = float(jnp.mean(r.final.x) - jnp.mean(r.x0))
    assert float(r.mean_velocity) == pytest.approx(advance / float(r.t_end), rel=1e-12)
    assert "max_cracks" in r.summary()["status_message"]
    # The crack beyond the bound is not recorded, and its jump not applied: the final
    # tip is the last recorded one (it had moved on to the unrecorded crack's).
    assert float(r.x_c) == float(r.crack_tips[1])


def test_step_bound_is_a_named_status():
    r = jw.simulate(jw.Params(), 1.0, TIGHT.replace(max_steps=50))
    assert r.status_name == "max_steps_reached"


class _NaNAfter(jw.AbstractController):
    """Rates that turn NaN at t = 0.1 s: no step can pass that time."""

    def __call__(self, t, x, v, lbar, body):
        return jnp.where(t > 0.1, jnp.nan, 0.01) * jnp.ones(body.N - 1)


@pytest.mark.parametrize("preset", ["fast", "default"])
def test_a_vector_field_that_turns_nan_fails_at_once(preset):
    # The steps shrink until t + dt == t; a zero-length step then has no error and was
    # accepted, again and again, until max_steps (2**20: 9 s for fast, 67 s for
    # default), which named the step bound as the cause. It ends at the first
    # zero-length step instead, named as a failure of the solver.
    numerics = jw.PRESETS[preset].replace(max_steps=20_000)
    r = jw.simulate(jw.Params(gait=_NaNAfter()), 0.5, numerics)
    assert r.status_name == "solver_failed"
    assert float(r.t_end) == pytest.approx(0.1, abs=1e-9)
    assert int(r.steps) < 5_000
    assert "not finite" in r.summary()["status_message"]


# Batched XLA kernels round differently from unbatched ones, and an adaptive solve
# turns round-off into differences up to its own tolerance: at the default atol (1e-8)
# over 1 s, batched and single runs of (5π, π/6) were 3e-4 apart, and 1.4e-3 apart
# (3433 and 3642 steps) once the wave's sines were computed by angle addition (a
# rounding-level change), both within the default's error there (5e-3 against atol
# 1e-10). So the check solves tightly (atol 1e-10), where they agree to ~2e-6.
BATCH_NUMERICS = jw.Numerics(atol=1e-10)
BATCH_RTOL = 1e-4


def test_vmap_over_gaits_matches_single_runs():
    p = jw.Params()
    omegas = jnp.array([3 * jnp.pi, 5 * jnp.pi])
    deltas = jnp.array([-jnp.pi / 3, jnp.pi / 6])
    num = BATCH_NUMERICS
    batch = jax.vmap(lambda w, d: jw.simulate(p.replace(omega=w, delta=d), 1.0, num))(
        omegas, deltas
    )
    for i in range(2):
        one = jw.simulate(p.replace(omega=omegas[i], delta=deltas[i]), 1.0, num)
        np.testing.assert_allclose(
            float(batch.mean_velocity[i]), float(one.mean_velocity), rtol=BATCH_RTOL
        )
        assert int(batch.n_cracks[i]) == int(one.n_cracks)


def test_vmap_over_soil_and_body_parameters():
    p = jw.Params()
    E = jnp.array([1.2e5, 1.6e5])
    EA = jnp.array([10.0, 16.0])
    num = BATCH_NUMERICS
    batch = eqx.filter_jit(jax.vmap(lambda e, k: jw.simulate(p.replace(E_s=e, EA=k), 0.5, num)))(
        E, EA
    )
    assert batch.mean_velocity.shape == (2,)
    assert np.all(np.asarray(batch.status) == 0)
    one = jw.simulate(p.replace(E_s=E[1], EA=EA[1]), 0.5, num)
    np.testing.assert_allclose(
        float(batch.mean_velocity[1]), float(one.mean_velocity), rtol=BATCH_RTOL
    )


@pytest.mark.parametrize(
    "delta,mirrored_wave",
    [
        (2 * math.pi / 7, {"delta": -2 * math.pi / 7}),
        (math.pi / 4, {"delta": math.pi / 4, "numbering": "tail"}),
    ],
)
def test_tail_forward_friction_with_the_mirrored_wave_mirrors_the_motion(delta, mirrored_wave):
    # The body seen from its tail: node k ↦ N + 1 − k, x ↦ −x. Segment k ↦ N − k, so the
    # wave ψ_k = ωt + δk becomes ωt + δ(N − k) (numbering = "tail"), which is the
    # mirrored wave ωt − δk up to the phase δN (0 mod 2π for δ = 2π/7, N = 7), and eq.
    # 10's forward turns tail-ward. With the crack forces negligible (Wg → 1e-12: back
    # pressure ~1e-15 N against friction ~1e-4 N) the two runs are mirror images:
    # x'_j(t) = −x_{N+1−j}(t) − (N − 1) l0, v̄' = −v̄.
    base = jw.Params().replace(Wg=1e-12)
    num = jw.PRESETS["default"]
    head = jw.simulate(base.replace(delta=delta), t1=0.25, numerics=num)
    tail = jw.simulate(
        base.replace(friction_forward="tail", **mirrored_wave), t1=0.25, numerics=num
    )
    assert head.status_name == tail.status_name == "ok"
    mirrored = -np.asarray(head.final.x)[::-1] - 6 * 0.01
    # the solver's position error (default preset: ~1e-7 m here) against a travel of ~2.5 mm
    np.testing.assert_allclose(np.asarray(tail.final.x), mirrored, rtol=0, atol=1e-6)
    assert abs(float(head.mean_velocity)) > 5e-3
    np.testing.assert_allclose(float(tail.mean_velocity), -float(head.mean_velocity), rtol=1e-3)
    # flipping the friction alone does not mirror it
    alone = jw.simulate(base.replace(delta=delta, friction_forward="tail"), t1=0.25, numerics=num)
    assert abs(float(alone.mean_velocity) + float(head.mean_velocity)) > 1e-3


def test_a_run_driven_by_the_back_pressure_alone_balances_its_energy():
    # A = 0: no actuation; the crack's back pressure pushes the head back and its work
    # becomes kinetic energy and friction. Measured against the dissipation alone, the
    # fast solve's round-off showed as a 5.6 % residual and the run ended energy_balance.
    p = jw.Params().replace(A=0.0)
    r = jw.simulate(p, 0.5, jw.PRESETS["fast"])
    e = jw.energy_terms(jw.initial_state(p), r.final, p)
    assert float(e["actuation"]) == 0.0 and float(e["back_pressure_work"]) < 0
    assert abs(float(e["back_pressure_work"])) > 5 * abs(float(e["friction_dissipation"]))
    assert r.status_name == "ok" and abs(float(r.energy_residual)) < 0.02
    assert float(r.mean_velocity) < 0  # pushed back


def test_a_standing_wave_balances_its_energy_against_the_gross_actuation():
    # δ = 0: every segment in phase. The net actuation work (~5e-10 J over 2 s) is ~1e-4
    # of the work that flows in and out, so the solver's quadrature error of those flows
    # (the structured solve integrates the work at lower order) swamped a residual
    # measured against the net terms: 0.98 with `fast`, and the run ended energy_balance
    # although its velocity agrees with `accurate` to 1e-4.
    p = jw.Params().replace(delta=0.0)
    ts = jnp.linspace(0.0, 2.0, 40001)
    fast = jw.simulate(p, 2.0, jw.PRESETS["fast"])
    ref = jw.simulate(p, 2.0, jw.PRESETS["accurate"], ts=ts)
    assert fast.status_name == "ok" and abs(float(fast.energy_residual)) < 0.01
    np.testing.assert_allclose(float(fast.mean_velocity), float(ref.mean_velocity), rtol=1e-3)
    # The gross work is ∫|∂V/∂l̄·u| dt: the sum of |Δ| of the net work over a dense
    # trajectory (it changes sign only a few times per gait period) agrees with it.
    w = np.asarray(ref.trajectory.work)
    gross = float(ref.final.work[3])
    np.testing.assert_allclose(np.sum(np.abs(np.diff(w[:, 0]))), gross, rtol=1e-3)
    e = jw.energy_terms(jw.initial_state(p), ref.final, p)
    assert gross > 100 * abs(float(e["actuation"]))

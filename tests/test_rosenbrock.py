"""The Rosenbrock solver (`jaxworm._rosenbrock`) and the structured Newton-matrix solve.

Checked against what does not depend on this code: convergence order on a problem with a
known solution, stability far into the stiff range, and the structured solve against a
dense LU of the same matrix.
"""

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.flatten_util import ravel_pytree

import jaxworm as jw
from jaxworm._dynamics import control_rate, initial_crack_tip, initial_state, vector_field
from jaxworm._linear_solve import (
    _feedback_rows,
    dense_factor,
    structured_factor,
    structured_lanes_factor,
)
from jaxworm._rosenbrock import ForwardOnlyError, Rodas4
from jaxworm._sensitivity import Frame, Rodas4Sensitivity, split_params


def _prothero_robinson(lam):
    """y' = −λ (y − g(t)) + g'(t), y(0) = g(0): the exact solution is g(t) = sin t + t²/2
    for every λ; large λ makes it stiff (Prothero & Robinson 1974)."""

    def vf(t, y, args):
        g, dg = jnp.sin(t) + 0.5 * t**2, jnp.cos(t) + t
        return -lam * (y - g) + dg

    return diffrax.ODETerm(vf)


def _solve_fixed(term, n, y0=0.0, t1=1.0, looped=False):
    sol = diffrax.diffeqsolve(
        term,
        Rodas4(looped=looped),
        0.0,
        t1,
        t1 / n,
        jnp.array(y0),
        stepsize_controller=diffrax.ConstantStepSize(),
        max_steps=10 * n,
    )
    return float(sol.ys[-1])


# `looped`: the stages as one loop (`looped_stages`), which the sensitivity step uses;
# each form must be the method on its own.
LOOPED = pytest.mark.parametrize("looped", [False, True], ids=["unrolled", "looped"])


@LOOPED
def test_rodas4_converges_at_fourth_order_on_a_nonstiff_problem(looped):
    term = _prothero_robinson(1.0)
    exact = np.sin(1.0) + 0.5
    errors = [abs(_solve_fixed(term, n, looped=looped) - exact) for n in (8, 16, 32)]
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all(orders > 3.7), (errors, orders)


@LOOPED
def test_rodas4_is_stable_and_accurate_far_into_the_stiff_range(looped):
    # Steps 1e6 times the stiff time scale: an explicit method would blow up; an
    # L-stable, stiffly accurate one tracks the smooth solution.
    exact = np.sin(1.0) + 0.5
    for lam in (1e4, 1e8):
        value = _solve_fixed(_prothero_robinson(lam), 10, y0=1.0, looped=looped)  # y(0) ≠ g(0)
        assert abs(value - exact) < 1e-6, (lam, value)


def _dense_one_step(lam, h, thetas, interpolant, looped=False, t0=0.3, y0=None):
    """One fixed step of Rodas4 on Prothero-Robinson from t0; its dense output at
    t0 + θh and the exact solution there."""
    g = lambda t: np.sin(t) + 0.5 * t**2  # noqa: E731
    ts = t0 + h * np.asarray(thetas)
    sol = diffrax.diffeqsolve(
        _prothero_robinson(lam),
        Rodas4(interpolant=interpolant, looped=looped),
        t0,
        t0 + h,
        h,
        jnp.array(g(t0) if y0 is None else y0),
        saveat=diffrax.SaveAt(ts=jnp.asarray(ts)),
        stepsize_controller=diffrax.ConstantStepSize(),
        max_steps=4,
    )
    return np.asarray(sol.ys), g(ts)


@LOOPED
@pytest.mark.parametrize("interpolant", ["rodas", "hermite"])
def test_dense_output_is_third_order_inside_a_step(interpolant, looped):
    # Local error of the interpolant at interior points, one step from the exact
    # solution: O(h⁴) for a third-order dense output.
    errors = []
    for h in (0.2, 0.1, 0.05):
        ys, exact = _dense_one_step(1.0, h, (0.3, 0.7), interpolant, looped)
        errors.append(np.max(np.abs(ys - exact)))
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all(orders > 3.5), (errors, orders)


@pytest.mark.parametrize("lam", [1e6, 1e8])
def test_rodas_dense_output_keeps_third_order_when_stiff(lam):
    # RODAS's own extension is formed from the stages and stays third order when hλ ≫ 1
    # (5e4 to 2e7 here: measured 2.96-2.99); the Hermite cubic's slope f(y₁) carries λ
    # times y₁'s error and falls to about first order (1.5, 1.1). In between (λ = 1e3,
    # hλ 50-200) both lose order: 2.7, 2.3 against 2.3, 1.2.
    errors = []
    for h in (0.2, 0.1, 0.05):
        ys, exact = _dense_one_step(lam, h, (0.3, 0.7), "rodas")
        errors.append(np.max(np.abs(ys - exact)))
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert np.all(orders > 2.8), (errors, orders)


def test_rodas_dense_output_does_not_overshoot_a_stiff_transient():
    # y − g = (y₀ − g₀) e^{−λt}: the exact solution decays monotonically onto g. Inside a
    # step 1e7 times the decay time the interpolant must stay within the initial offset
    # (it gives ≤ 0.4 of it); the Hermite cubic, with slope −λ(y₀ − g₀) at t₀, reaches
    # ~1e6 times it.
    ys, exact = _dense_one_step(1e8, 0.1, np.linspace(0.05, 0.95, 19), "rodas", y0=1.0)
    offset0 = 1.0 - (np.sin(0.3) + 0.5 * 0.3**2)
    assert np.all(np.abs(ys - exact) <= abs(offset0)), np.abs(ys - exact).max()


def test_rodas4_adaptive_meets_its_tolerance_on_a_nonlinear_system():
    # Van der Pol with μ = 10 (mildly stiff), against SciPy's Radau at tight tolerance.
    scipy_integrate = pytest.importorskip("scipy.integrate")
    mu = 10.0

    def vf(t, y, args):
        return jnp.stack([y[1], mu * (1 - y[0] ** 2) * y[1] - y[0]])

    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(vf),
        Rodas4(),
        0.0,
        5.0,
        1e-3,
        jnp.array([2.0, 0.0]),
        stepsize_controller=diffrax.PIDController(rtol=1e-8, atol=1e-10),
        max_steps=100_000,
    )
    ref = scipy_integrate.solve_ivp(
        lambda t, y: [y[1], mu * (1 - y[0] ** 2) * y[1] - y[0]],
        (0.0, 5.0),
        [2.0, 0.0],
        method="Radau",
        rtol=1e-12,
        atol=1e-12,
    )
    np.testing.assert_allclose(np.asarray(sol.ys[-1]), ref.y[:, -1], rtol=1e-5, atol=1e-6)


class _Feedback(jw.AbstractController):
    """A closed-loop controller: u depends on the state, so l̄ stays in the linear solve."""

    def __call__(self, t, x, v, lbar, body):
        return 0.01 * jnp.sin(3.0 * t) - 5.0 * (lbar - body.l0) + 0.1 * (x[:-1] - x[1:] - lbar)


def _policy(N: int):
    """A network that reads the sensors (velocities, lengths, the crack): a dense ∂u/∂y.
    Its last layer, zero as built, drawn at random so that every feature reaches u."""
    policy = jw.PolicyMLP.init(jax.random.PRNGKey(3), N, b=3.0)
    last = policy.mlp.layers[-1]
    k_w, k_b = jax.random.split(jax.random.PRNGKey(5))
    return eqx.tree_at(
        lambda q: (q.mlp.layers[-1].weight, q.mlp.layers[-1].bias),
        policy,
        (
            0.5 * jax.random.normal(k_w, last.weight.shape),
            0.1 * jax.random.normal(k_b, last.bias.shape),
        ),
    )


def _moving_state(y0, key, speed: float):
    """y0 moved, stretched and set in motion at random (velocities of order `speed`
    m/s), so that every Jacobian block is non-trivial."""
    k1, k2, k3 = jax.random.split(key, 3)
    return y0.__class__(
        x=y0.x + 1e-4 * jax.random.normal(k1, y0.x.shape),
        v=speed * jax.random.normal(k2, y0.v.shape),
        lbar=y0.lbar * (1 + 0.05 * jax.random.normal(k3, y0.lbar.shape)),
        work=y0.work,
    )


class _ReadsMotion(jw.AbstractFeedbackController):
    """A feedback controller that reads the head's speed and the lengths, not the crack."""

    def control(self, sensors, body):
        return 0.02 * jnp.tanh(sensors.v[0] / 0.01) - 3.0 * (sensors.lbar - sensors.lengths)


@pytest.mark.parametrize(
    "gait",
    [
        _policy,
        lambda N: jw.ReflexWave(gain_stress=0.7, gain_speed=0.3, gain_phase=0.4, leak=2.0),
        lambda N: _ReadsMotion(),
    ],
    ids=["policy", "reflex", "reads_motion"],
)
def test_feedback_rows_equal_jacobian_of_control(gait):
    """∂u/∂(x, v, l̄) by the chain rule through the sensors (`_feedback_rows`: reverse
    mode for the vectors, forward mode for the crack sensors) equals forward mode
    through `control_rate` as a whole, at a moving state near the crack tip."""
    N = 7
    p = jw.Params().replace(gait=gait(N))
    y0 = initial_state(p)
    x_c = initial_crack_tip(p, y0)
    y = _moving_state(y0, jax.random.PRNGKey(4), speed=1e-2)
    assert float(x_c - y.x[0]) > 1e-3 * float(p.body.l0)  # off the gap's floor
    u, rows = _feedback_rows(0.37, y, x_c, p)

    def u_of(x, v, lbar):
        return control_rate(
            0.37, eqx.tree_at(lambda q: (q.x, q.v, q.lbar), y, (x, v, lbar)), x_c, p
        )

    expected = jax.jacfwd(u_of, argnums=(0, 1, 2))(y.x, y.v, y.lbar)
    np.testing.assert_allclose(np.asarray(u), np.asarray(control_rate(0.37, y, x_c, p)), rtol=1e-14)
    for got, want in zip(rows, expected, strict=True):
        scale = float(jnp.max(jnp.abs(want)))
        assert scale > 0
        np.testing.assert_allclose(
            np.asarray(got), np.asarray(want), rtol=1e-10, atol=1e-12 * scale
        )


@pytest.mark.parametrize(
    "gait",
    [lambda N: None, lambda N: _Feedback(), _policy],
    ids=["open_loop", "closed_loop", "policy"],
)
@pytest.mark.parametrize("sigma", [1e2, 1e5])
@pytest.mark.parametrize(
    "structured_factor", [structured_factor, structured_lanes_factor], ids=["lone", "lanes"]
)
# N = 10: T⁻¹ in two blocks of columns (`_tridiagonal_factor`).
@pytest.mark.parametrize("N", [7, 10])
def test_structured_newton_solve_equals_dense_lu(gait, sigma, structured_factor, N):
    gait = gait(N)
    p = jw.Params().replace(N=N)
    p = p if gait is None else p.replace(gait=gait)
    y0 = initial_state(p)
    y = _moving_state(y0, jax.random.PRNGKey(0), speed=1e-3)
    args = (p, initial_crack_tip(p, y0))
    flat, unravel = ravel_pytree(y)

    def f(yf):
        return ravel_pytree(vector_field(0.3, unravel(yf), args))[0]

    jac = jax.jacfwd(f)(flat)
    rhs = jax.random.normal(jax.random.PRNGKey(1), flat.shape)
    structured = structured_factor(f, 0.3, flat, sigma, y, args)(rhs)
    dense = jnp.linalg.solve(sigma * jnp.eye(flat.shape[0]) - jac, rhs)
    # (x, v, l̄) exactly as with the full matrix. The work rows of J are dropped by
    # design (k_w = r_w / σ), except, for a closed-loop gait, those of the work that u
    # drives: the net and gross actuation work (`actuation_work_rates`), the first and
    # the last.
    n_state = flat.shape[0] - y.work.shape[0]  # the work integrals last
    np.testing.assert_allclose(
        np.asarray(structured[:n_state]),
        np.asarray(dense[:n_state]),
        rtol=1e-9,
        atol=1e-12 * float(jnp.max(jnp.abs(dense))),
    )
    work = rhs[n_state:] / sigma
    if gait is not None:
        work = work.at[jnp.array([0, 3])].set(dense[n_state:][jnp.array([0, 3])])
    np.testing.assert_allclose(
        np.asarray(structured[n_state:]),
        np.asarray(work),
        rtol=1e-9,
        atol=1e-12 * float(jnp.max(jnp.abs(dense))),
    )
    # P right-hand sides at once (the forward sensitivities' stages): row by row the same.
    rhs_p = jax.random.normal(jax.random.PRNGKey(2), (3,) + flat.shape)
    solve = structured_factor(f, 0.3, flat, sigma, y, args)
    np.testing.assert_allclose(
        np.asarray(solve(rhs_p)),
        np.asarray(jnp.stack([solve(r) for r in rhs_p])),
        rtol=1e-9,
        atol=1e-12 * float(jnp.max(jnp.abs(dense))),
    )
    # Under vmap (the lanes of a sweep), each lane as alone.
    lanes = jax.vmap(lambda r: structured_factor(f, 0.3, flat, sigma, y, args)(r))(rhs_p)
    np.testing.assert_allclose(
        np.asarray(lanes),
        np.asarray(jnp.stack([solve(r) for r in rhs_p])),
        rtol=1e-9,
        atol=1e-12 * float(jnp.max(jnp.abs(dense))),
    )


@pytest.mark.parametrize("gait", [None, _Feedback()], ids=["open_loop", "closed_loop"])
@pytest.mark.parametrize("factor", [structured_factor, dense_factor], ids=["structured", "dense"])
def test_many_right_hand_sides_solve_like_one_each(gait, factor):
    # The forward sensitivities' stages solve (P, n) right-hand sides at once.
    p = jw.Params() if gait is None else jw.Params(gait=gait)
    y = initial_state(p)
    y = y.__class__(
        x=y.x, v=1e-3 * jnp.cos(jnp.arange(y.v.shape[0])), lbar=y.lbar * 1.02, work=y.work
    )
    args = (p, initial_crack_tip(p, y))
    flat, unravel = ravel_pytree(y)

    def f(yf):
        return ravel_pytree(vector_field(0.3, unravel(yf), args))[0]

    rhs = jax.random.normal(jax.random.PRNGKey(2), (3,) + flat.shape)
    solve = factor(f, 0.3, flat, 1e3, y, args)
    expected = jnp.stack([solve(r) for r in rhs])
    np.testing.assert_allclose(
        np.asarray(solve(rhs)),
        np.asarray(expected),
        rtol=1e-10,
        atol=1e-14 * float(jnp.max(jnp.abs(expected))),
    )


def test_dropped_work_rows_keep_the_energy_balance():
    # The structured solve integrates the work at lower order; the balance must still
    # close far below the 5 % that flags a false solution (1e-4 with exact rows).
    p = jw.Params().replace(delta=-np.pi / 4)
    r = jw.simulate(p, 3.0, jw.PRESETS["fast"])
    assert r.status_name == "ok" and int(r.n_cracks) >= 1
    assert abs(float(r.energy_residual)) < 5e-3


def test_structured_and_dense_solves_give_the_same_simulation():
    # Fixed steps, so that rounding cannot shift an adaptive step sequence.
    p = jw.Params()
    a = jw.simulate(p, 0.2, jw.Numerics(solver="Rodas4", dt=2e-4))
    b = jw.simulate(p, 0.2, jw.Numerics(solver="Rodas4", dt=2e-4, linear_solve="dense"))
    assert a.status_name == b.status_name == "ok"
    np.testing.assert_allclose(np.asarray(a.final.x), np.asarray(b.final.x), rtol=0, atol=1e-12)
    np.testing.assert_allclose(float(a.mean_velocity), float(b.mean_velocity), rtol=1e-9)


def test_a_two_node_body_balances_its_energy():
    # One segment takes long steps, at which dropping the work rows of the Newton matrix
    # broke the energy balance (residual 0.34 over 2 s): N = 2 takes the full matrix,
    # the same run as "dense".
    p = jw.Params(body=jw.Body(N=2))
    a = jw.simulate(p, 2.0)
    b = jw.simulate(p, 2.0, jw.PRESETS["fast"].replace(linear_solve="dense"))
    assert a.status_name == "ok" and abs(float(a.energy_residual)) < 0.05
    assert float(a.mean_velocity) == float(b.mean_velocity)


@pytest.mark.parametrize(
    "gait, coding",
    [(None, "sensitivity"), (_Feedback(), "looped")],
    ids=["open_loop-sensitivity", "closed_loop-looped"],
)
def test_other_codings_of_the_step_take_the_unrolled_state_step(gait, coding):
    # One RODAS step on the worm coded three ways: the unrolled stages, the looped
    # stages (closed-loop controllers), and the state part of the step that carries the
    # forward sensitivities with looped stages (which must not feed back into the state).
    # They differ only by rounding.
    p = jw.Params() if gait is None else jw.Params(gait=gait)
    y0 = initial_state(p)
    x_c = initial_crack_tip(p, y0)
    y0 = eqx.tree_at(lambda y: y.v, y0, y0.v + 1e-3 * jnp.arange(y0.v.shape[0]))  # off rest
    term = diffrax.ODETerm(vector_field)
    h = 2e-3

    def forward(looped):
        solver = Rodas4(factor=structured_factor, looped=looped)
        return jax.jit(lambda y: solver.step(term, 0.0, h, y, (p, x_c), None, False)[:2])(y0)

    def sensitivity():
        none = jax.tree_util.tree_map(lambda _: None, p)
        pd, pr = split_params(p, none)
        S0 = jax.tree_util.tree_map(lambda a: jnp.ones((2,) + a.shape), y0)
        sens = Rodas4Sensitivity(vf=vector_field, factor=structured_factor)
        args = (pd, pr, x_c, none, jnp.zeros(2), Frame(jnp.zeros(2), jnp.array(1.0)))
        z, err = jax.jit(lambda z: sens.step(None, 0.0, h, z, args, None, False)[:2])((y0, S0))
        return z[0], err[0]

    y_u, err_u = forward(False)
    y, err = forward(True) if coding == "looped" else sensitivity()
    flat = lambda t: ravel_pytree(t)[0]  # noqa: E731
    scale = np.max(np.abs(flat(y_u)))
    assert np.max(np.abs(flat(y_u) - flat(y0))) > 1e-9 * scale  # the step moved the state
    np.testing.assert_allclose(flat(y), flat(y_u), rtol=0, atol=1e-13 * scale)
    np.testing.assert_allclose(flat(err), flat(err_u), rtol=1e-8, atol=1e-15 * scale)


def test_differentiating_the_rodas4_steps_themselves_raises_a_clear_error():
    # simulate differentiates Rodas4 by forward sensitivities (test_sensitivity.py);
    # the solver's own steps still refuse, so a solve built on them is never silently
    # differentiated through its Jacobian.
    p = jw.Params()
    y0 = jw.initial_state(p)

    def final_x(a):
        q = p.replace(A=a)
        sol = diffrax.diffeqsolve(
            diffrax.ODETerm(jw.vector_field),
            Rodas4(),
            0.0,
            0.01,
            1e-4,
            y0,
            args=(q, 0.02),
            stepsize_controller=diffrax.ConstantStepSize(),
        )
        return sol.ys.x[-1, 0]

    with pytest.raises(ForwardOnlyError, match="forward-only"):
        jax.grad(final_x)(0.02)


def test_simulate_defaults_to_fast():
    p = jw.Params()
    a, b = jw.simulate(p, 0.05), jw.simulate(p, 0.05, jw.PRESETS["fast"])
    assert int(a.steps) == int(b.steps)
    assert float(a.mean_velocity) == float(b.mean_velocity)


def _newton_bands(n, sigma, seed):
    """Bands of a random nonsymmetric tridiagonal σI − J, diagonally dominant for large σ."""
    rng = np.random.default_rng(seed)
    lower, upper = rng.normal(size=(2, n))
    diag = sigma + np.abs(rng.normal(size=n)) * 3.0
    return jnp.asarray(lower), jnp.asarray(diag), jnp.asarray(upper)


@pytest.mark.parametrize("sigma", [5.0, 1e5])
def test_thomas_inverse_equals_the_library_inverse(sigma):
    # The non-CPU path of the structured solve (pure JAX elimination) against LAPACK's
    # tridiagonal solve and a dense inverse of the same matrix, alone and under vmap.
    from jaxworm._linear_solve import _library_inverse, _thomas_inverse

    bands = [_newton_bands(12, sigma, seed) for seed in range(4)]
    for lower, diag, upper in bands:
        dense = np.diag(np.asarray(diag)) + np.diag(np.asarray(lower)[1:], -1)
        dense += np.diag(np.asarray(upper)[:-1], 1)
        expected = np.linalg.inv(dense)
        scale = np.max(np.abs(expected))
        for inverse in (_thomas_inverse, _library_inverse):
            got = np.asarray(inverse(lower, diag, upper))
            np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12 * scale)
    stacked = [jnp.stack(b) for b in zip(*bands)]
    np.testing.assert_allclose(
        np.asarray(jax.vmap(_thomas_inverse)(*stacked)),
        np.asarray(jax.vmap(_library_inverse)(*stacked)),
        rtol=1e-12,
        atol=1e-15,
    )


def test_gpu_program_makes_no_library_call_per_lane():
    # cuSPARSE's gtsv2 (what `jax.lax.linalg.tridiagonal_solve` calls on a GPU) solves
    # a batch one system at a time; a vmapped solve on a GPU must not call it every
    # step. The program lowered for CUDA (no GPU needed) holds no custom call at all.
    import re

    def v(z):
        gait = jw.TravellingWave(A=z[0], omega=z[1], delta=z[2])
        return jw.simulate(jw.Params(gait=gait), 0.1).mean_velocity

    z = jnp.array([[0.02, 12.0, -0.8]] * 2)
    exported = jax.export.export(jax.jit(jax.vmap(v)), platforms=["cuda"])(z)
    text = exported.mlir_module()
    calls = set(re.findall(r'call_target_name = "([^"]+)"', text))
    calls |= set(re.findall(r"custom_call @([\w.]+)", text))
    assert not calls, calls
    # The CPU program keeps LAPACK's solve (the faster one there).
    cpu = jax.export.export(jax.jit(jax.vmap(v)), platforms=["cpu"])(z).mlir_module()
    assert "gtsv" in cpu


def test_a_simulation_through_the_elimination_inverse_matches_the_library_one(monkeypatch):
    # The whole fixed-step solve with T⁻¹ from the non-CPU path (forced here on the CPU)
    # against the CPU's library path: the same trajectory to rounding.
    import jaxworm._linear_solve as linear_solve

    p = jw.Params().replace(delta=-np.pi / 4)
    numerics = jw.Numerics(solver="Rodas4", dt=2e-4)
    a = jw.simulate(p, 0.2, numerics)  # the library path (nothing here traces the other)
    monkeypatch.setattr(linear_solve, "_tridiagonal_inverse", linear_solve._thomas_inverse)
    try:
        jax.clear_caches()  # no program traced with the library path may be reused
        b = jw.simulate(p, 0.2, numerics)
    finally:
        monkeypatch.undo()
        jax.clear_caches()
    assert a.status_name == b.status_name == "ok"
    np.testing.assert_allclose(np.asarray(b.final.x), np.asarray(a.final.x), rtol=0, atol=1e-12)
    np.testing.assert_allclose(float(b.mean_velocity), float(a.mean_velocity), rtol=1e-9)

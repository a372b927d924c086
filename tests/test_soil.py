"""Soil that varies along the burrow (`jaxworm._soil`): the profiles' values by hand, the
arrest of a crack in them (eq. 13), homogeneous equivalence, a layer's physics, the
derivative through a layer's constants and vmap over soil samples."""

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxworm as jw
from jaxworm import physics as phys
from jaxworm._soil import arrest_tip

close = np.testing.assert_allclose
NU, W0, L0 = 0.3, 1e-3, 1e-2
# Many cracks in 2.5 s (tips near 0.076, 0.083, 0.090, 0.098 m): tests/test_gradients.py.
RETRO = jw.Params().replace(delta=-jnp.pi / 6, K_Ith=235.0)


# --- profiles ------------------------------------------------------------------------


def test_sharp_layers_take_each_layer_value_and_the_layer_ahead_on_an_interface():
    f = jw.Layered([0.1, 0.3], [1.0, 5.0, 2.0])
    close(f(jnp.array([-1.0, 0.0999, 0.1, 0.2, 0.3, 7.0])), [1.0, 1.0, 5.0, 5.0, 2.0, 2.0])


def test_smoothed_interface_passes_the_mean_and_tends_to_the_layers():
    f = jw.Layered([0.1], [250.0, 500.0], width=0.01)
    close(f(0.1), 375.0, rtol=1e-15)
    # tanh(±5) = ±0.9999092: (1 + tanh)/2 = 0.9999546 and 4.54e-5
    close(f(jnp.array([0.05, 0.15])), [250.0 + 250.0 * 4.5398e-5, 500.0 - 250.0 * 4.5398e-5])


def test_gradient_is_linear_between_its_positions_and_constant_outside():
    f = jw.Gradient((0.0, 0.5), (1.4e5, 2.8e5))
    close(
        f(jnp.array([-1.0, 0.0, 0.125, 0.25, 0.5, 3.0])),
        [1.4e5, 1.4e5, 1.75e5, 2.1e5, 2.8e5, 2.8e5],
    )


def test_random_field_has_unit_log_moments_and_gaussian_correlation_over_keys():
    keys = jax.random.split(jax.random.key(0), 4000)
    fields = jax.vmap(lambda k: jw.RandomField(250.0, 0.2, 0.05, k))(keys)
    x = jnp.array([0.0, 0.05, 0.37])
    g = jnp.log(jax.vmap(lambda f: f(x))(fields) / 250.0) / 0.2  # the unit field g(x)
    # 4000 samples: the mean's standard error is 1/√4000 = 0.016, the variance's ~0.022
    close(np.mean(g, axis=0), 0.0, atol=0.07)
    close(np.var(g, axis=0), 1.0, atol=0.1)
    # E[g(0) g(ℓ)] = exp(-1/2) = 0.607
    close(np.mean(g[:, 0] * g[:, 1]), math.exp(-0.5), atol=0.07)


def test_random_field_is_a_pure_function_of_its_key():
    a = jw.RandomField(250.0, 0.2, 0.05, jax.random.key(3))
    b = jw.RandomField(250.0, 0.2, 0.05, jax.random.key(3))
    c = jw.RandomField(250.0, 0.2, 0.05, jax.random.key(4))
    x = jnp.linspace(0.0, 1.0, 50)
    np.testing.assert_array_equal(a(x), b(x))
    assert np.max(np.abs(a(x) - c(x))) > 1.0
    assert np.all(a(x) > 0)


# --- validation ----------------------------------------------------------------------


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: jw.Layered([0.2, 0.1], [1.0, 2.0, 3.0]), r"interfaces = .*increasing"),
        (lambda: jw.Layered([0.1], [1.0, 2.0, 3.0]), r"values = .*need 2 numbers"),
        (lambda: jw.Layered([0.1], [1.0, 2.0], width=-1.0), r"width = -1.0"),
        (lambda: jw.Layered([0.1], [1.0, 2.0], width=jnp.array(0.01)), r"width.*not an array"),
        (lambda: jw.Gradient((0.5, 0.0), (1.0, 2.0)), r"positions = .*x_0 < x_1"),
        (lambda: jw.Soil(E_s=jw.Layered([0.1], [1.4e5, -1.0])), r"parameter E_s = Layered .*> 0"),
        (
            lambda: jw.Soil(
                K_Ic=jw.Layered([0.1], [250.0, 300.0]), K_Ith=jw.Layered([0.1], [200.0, 300.0])
            ),
            r"parameter K_Ith = 300.0 at x = 0.1 m .*K_Ith < K_Ic = 300.0",
        ),
        (
            lambda: jw.Soil(K_Ic=jw.Gradient((0.0, 1.0), (250.0, 150.0))),
            r"parameter K_Ith = 200.0 at x = 0.5 m",
        ),
        (lambda: jw.RandomField(-1.0, 0.2, 0.05, jax.random.key(0)), r"median = -1.0"),
    ],
)
def test_invalid_profiles_are_refused_naming_the_parameter_and_value(make, match):
    with pytest.raises(ValueError, match=match):
        make()


def test_a_random_field_without_its_key_says_to_give_one():
    with pytest.raises(TypeError, match=r"RandomField needs key, a jax.random key"):
        jw.RandomField(250.0, 0.2, 0.05)
    # A number or a list is not a key (JAX's own error said "invalid PRNG key data").
    for key in (0, [0, 1]):
        with pytest.raises(TypeError, match=r"parameter key = .*: need a jax.random key"):
            jw.RandomField(250.0, 0.2, 0.05, key)
    jw.RandomField(250.0, 0.2, 0.05, jax.random.PRNGKey(0))  # a raw key is one
    # 10⁹ modes allocated 16 GB before any check.
    with pytest.raises(ValueError, match=r"modes = 1000000000: need an integer 1 <= modes"):
        jw.RandomField(250.0, 0.2, 0.05, jax.random.key(0), modes=10**9)


def test_a_traced_invalid_profile_ends_invalid_parameters():
    def run(v):
        soil = jw.Soil(K_Ic=jw.Layered([0.1], [250.0, v]))
        return jw.simulate(jw.Params(soil=soil), 0.05).status

    status = jax.vmap(run)(jnp.array([300.0, 190.0]))  # K_Ith = 200 > 190 beyond 0.1 m
    assert [jw.status_name(int(s)) for s in status] == ["ok", "invalid_parameters"]


def test_profiles_go_into_result_file_headers():
    from jaxworm import _files

    p = jw.Params().replace(K_Ic=jw.Layered([0.1], [250.0, 300.0]))
    header = _files.plain(p.flat())
    assert header["K_Ic"] == {
        "profile": "Layered",
        "interfaces": [0.1],
        "values": [250.0, 300.0],
        "width": 0.0,
    }
    assert header["K_Ith"] == 200.0


# --- the arrest (eq. 13) -------------------------------------------------------------


def _a(E, K, l1=L0):
    return float(phys.arrest_gap(l1, K, E, NU, W0, L0))


def test_arrest_in_uniform_layers_is_eq13():
    E, K = jw.Layered([0.01, 0.02], [1.4e5] * 3), jw.Layered([0.05], [200.0] * 2)
    close(arrest_tip(0.0, L0, 0.02, E, K, NU, W0, L0), _a(1.4e5, 200.0), rtol=1e-15)


def test_crack_stops_on_an_interface_where_the_threshold_rises():
    # Threshold 200 up to 0.02 m, 400 beyond: eq. 13 in the first layer would reach
    # a(200) = 1.4²/(2π·200²·0.8281) = 0.009417 m... place the interface before it.
    a1, a2 = _a(1.4e5, 200.0), _a(1.4e5, 400.0)  # a2 = a1/4
    x_i = 0.5 * (a2 + a1)
    K = jw.Layered([x_i], [200.0, 400.0])
    close(arrest_tip(0.0, L0, 0.5 * a2, 1.4e5, K, NU, W0, L0), x_i, rtol=1e-15)
    # An interface beyond a1: the crack arrests inside the first layer, by eq. 13.
    K = jw.Layered([1.5 * a1], [200.0, 400.0])
    close(arrest_tip(0.0, L0, 0.5 * a2, 1.4e5, K, NU, W0, L0), a1, rtol=1e-15)


def test_crack_does_not_jump_over_a_tough_band():
    # A thin tough band [0.6 a1, 0.7 a1] holds the crack on its near face even though
    # K_I > K_Ith again beyond it.
    a1 = _a(1.4e5, 200.0)
    K = jw.Layered([0.6 * a1, 0.7 * a1], [200.0, 1000.0, 200.0])
    close(arrest_tip(0.0, L0, 0.1 * a1, 1.4e5, K, NU, W0, L0), 0.6 * a1, rtol=1e-15)


@pytest.mark.parametrize(
    "K",
    [
        jw.Layered([0.005], [200.0, 300.0], width=2e-3),
        jw.Gradient((0.0, 0.02), (180.0, 320.0)),
        jw.RandomField(200.0, 0.3, 5e-3, jax.random.key(1)),
    ],
    ids=["smoothed", "gradient", "random"],
)
def test_arrest_in_smooth_soil_is_the_first_point_where_K_I_falls_to_the_threshold(K):
    start = 1e-3
    tip = float(arrest_tip(0.0, L0, start, 1.4e5, K, NU, W0, L0))

    def g(x):  # (x − x1) − a(x): < 0 while K_I(x) > K_Ith(x)
        return x - phys.arrest_gap(L0, K(x), 1.4e5, NU, W0, L0)

    close(g(tip), 0.0, atol=1e-15)
    assert np.all(g(jnp.linspace(start, tip, 2001)[:-1]) < 0)


def test_a_profile_too_steep_for_the_arrest_search_gives_no_tip_and_no_ok_run():
    # A smoothed interface 1 µm wide, 0.5 m ahead: the march (steps of a quarter of the
    # width, at most _MAX_MARCH) cannot reach the arrest at ~0.094 m. The tip is NaN,
    # not where the march stopped (0.025 m), and the run says so: `nonfinite`.
    K = jw.Layered([0.5], [200.0, 200.5], width=1e-6)
    assert np.isnan(float(arrest_tip(0.0, L0, 1e-3, 1.4e5, K, NU, W0, L0)))
    r = jw.simulate(jw.Params().replace(K_Ith=K), 0.05)
    assert r.status_name == "nonfinite" and np.isnan(float(r.x_c))


def test_arrest_tip_derivative_matches_finite_differences():
    def tip(v, width):
        K = jw.Layered([0.005], [200.0, v], width=width)
        return arrest_tip(0.0, L0, 1e-3, 1.4e5, K, NU, W0, L0)

    for width in (0.0, 2e-3):
        d = jax.grad(tip)(300.0, width)
        fd = (tip(300.0 + 1e-3, width) - tip(300.0 - 1e-3, width)) / 2e-3
        close(d, fd, rtol=1e-5)
        assert abs(float(d)) > 0


# --- the model -----------------------------------------------------------------------


def test_layers_of_table1_values_agree_with_homogeneous_soil():
    p = jw.Params().replace(delta=-jnp.pi / 4)
    layered = p.replace(
        E_s=jw.Layered([0.02], [1.4e5, 1.4e5]),
        K_Ic=jw.Layered([0.03, 0.06], [250.0] * 3),
        K_Ith=jw.Layered([0.03, 0.06], [200.0] * 3),
        mu_s=jw.Layered([0.01], [0.3, 0.3]),
    )
    a, b = jw.simulate(p, 5.0), jw.simulate(layered, 5.0)
    assert int(a.n_cracks) == int(b.n_cracks) == 2
    close(b.mean_velocity, a.mean_velocity, rtol=1e-12)
    close(b.final.x, a.final.x, rtol=1e-12)
    close(b.crack_times, a.crack_times, rtol=1e-12)
    close(b.crack_tips, a.crack_tips, rtol=1e-12)


def test_crack_events_sit_where_K_I_reaches_K_Ic_of_the_layer_at_the_tip():
    # The interface at 0.085 m: the third crack runs from a tip in the soft layer into
    # the tough one, later cracks start from tough tips.
    K_Ic = jw.Layered([0.085], [250.0, 300.0])
    K_Ith = jw.Layered([0.085], [235.0, 282.0])
    r = jw.simulate(RETRO.replace(K_Ic=K_Ic, K_Ith=K_Ith), 4.0)
    n = int(r.n_cracks)
    assert n >= 4
    old = np.concatenate([[float(r.x_c0)], np.asarray(r.crack_tips[: n - 1])])
    new = np.asarray(r.crack_tips[:n])
    x1, l1 = np.asarray(r.crack_x1[:n]), np.asarray(r.crack_l1[:n])
    K_old = phys.stress_intensity(old - x1, l1, 1.4e5, NU, W0, L0)
    close(K_old / K_Ic(old), 1.0, rtol=1e-6)  # the event: K_I = K_Ic(x_c)
    assert np.any(old >= 0.085) and np.any(old < 0.085)
    K_new = phys.stress_intensity(new - x1, l1, 1.4e5, NU, W0, L0)
    # After the jump: K_I = K_Ith(new tip) inside a layer; a crack reaching the tougher
    # layer with K_I below its threshold stops on the interface (K_I ≤ K_Ith there).
    # Either way K_I < K_Ic(new tip): the condition restarts below 0.
    on = new == 0.085
    assert np.any(on) and np.all(K_new[on] < K_Ith(new[on]))
    close(K_new[~on], K_Ith(new[~on]), rtol=1e-12)
    assert np.all(K_new / K_Ic(new) - 1 < -0.05)


def test_cracks_advance_less_in_a_tougher_layer():
    # eqs. 12-13: the advance per crack is ((K_Ic/K_Ith)² − 1) times the gap at the
    # event, which scales as (E_s/K_Ic)²: in a layer 2x as tough (K_Ith scaled too)
    # each crack advances ~1/4 as far, so the worm cracks ~4x as often per metre.
    base = jw.Params().replace(delta=-jnp.pi / 4)
    p = base.replace(
        K_Ic=jw.Layered([0.2], [250.0, 500.0]), K_Ith=jw.Layered([0.2], [200.0, 400.0])
    )
    r = jw.simulate(p, 14.0)
    n = int(r.n_cracks)
    tips = np.concatenate([[float(r.x_c0)], np.asarray(r.crack_tips[:n])])
    step = np.diff(tips)
    soft, tough = step[tips[:-1] < 0.2 - 0.05], step[tips[:-1] >= 0.2]
    assert soft.size >= 2 and tough.size >= 3, tips
    ratio = np.mean(tough) / np.mean(soft)
    assert 0.15 < ratio < 0.4, (ratio, tips)


def test_vmap_over_soil_samples_equals_single_runs():
    keys = jax.random.split(jax.random.key(7), 3)

    def run(key):
        K_Ic = jw.RandomField(250.0, 0.1, 0.02, key)
        K_Ith = jw.RandomField(235.0, 0.1, 0.02, key)  # the same field: K_Ith/K_Ic = 0.94
        r = jw.simulate(RETRO.replace(K_Ic=K_Ic, K_Ith=K_Ith), 1.5)
        return r.mean_velocity, r.crack_tips[:3], r.n_cracks

    batch = jax.vmap(run)(keys)
    # Batched adaptive steps round differently (tests/test_dynamics.BATCH_NUMERICS): at
    # the default tolerance, within 1e-3.
    for i, key in enumerate(keys):
        one = run(key)
        close(batch[0][i], one[0], rtol=1e-3)
        close(batch[1][i], one[1], rtol=1e-3)
        assert int(batch[2][i]) == int(one[2]) >= 1
    assert np.ptp(np.asarray(batch[1][:, 0])) > 1e-4  # the samples differ


def test_gradient_wrt_a_layer_K_Ic_matches_finite_differences():
    # The third and fourth cracks start in the tougher layer: their times move with its
    # K_Ic. Exact jump conditions, sensitivities solved to tolerance (test_gradients).
    numerics = jw.PRESETS["fast"].replace(
        max_cracks=8, crack_sensitivity="exact", sensitivity_tol=1.0
    )

    def crack_time(v):
        p = RETRO.replace(
            K_Ic=jw.Layered([0.08], [250.0, v]), K_Ith=jw.Layered([0.08], [235.0, 240.0])
        )
        return jw.simulate(p, 2.5, numerics).crack_times[3]

    d = jax.grad(crack_time)(255.0)
    h = 255.0 * 1e-4
    fd = (crack_time(255.0 + h) - crack_time(255.0 - h)) / (2 * h)
    fd_half = (crack_time(255.0 + h / 3) - crack_time(255.0 - h / 3)) / (2 * h / 3)
    assert abs(float(fd)) > 0
    assert abs(float(d) - float(fd)) <= max(0.02 * abs(float(fd)), 2 * abs(float(fd - fd_half)))


def test_the_new_tips_derivative_in_a_smoothed_interfaces_position_is_its_slope():
    # A single smoothed interface (no layer between two): its `length` took a min over
    # no thicknesses, whose derivative is NaN, and the arrest search's step carried it,
    # so d(tip)/d(interface) was NaN and any solve differentiated along the interface
    # (of E_s or K_Ith) rejected every step until max_steps. The tip follows the
    # interface by the implicit function theorem (tip ~0.0235 m, interface 4 mm wide).
    def tip(a, field):
        values = {"E_s": [1.4e5, 2e5], "K_Ith": [400.0, 420.0]}[field]
        scene = {"delta": -jnp.pi / 4, "K_Ic": 500.0, "K_Ith": 400.0}
        scene[field] = jw.Layered(jnp.reshape(a, (1,)), jnp.array(values), width=0.004)
        p = jw.Params().replace(**scene)
        return jw.initial_crack_tip(p, jw.initial_state(p))

    for field in ("E_s", "K_Ith"):
        a, h = 0.03, 1e-6
        d = float(jax.jvp(functools.partial(tip, field=field), (a,), (1.0,))[1])
        fd = (float(tip(a + h, field)) - float(tip(a - h, field))) / (2 * h)
        assert abs(fd) > 1e-4, (field, fd)  # the tip sits in the interface's transition
        np.testing.assert_allclose(d, fd, rtol=1e-4, err_msg=field)


def test_a_solve_differentiated_along_a_smoothed_interface_ends_ok():
    def run(a):
        E_s = jw.Layered(jnp.reshape(a, (1,)), jnp.array([1.4e5, 2e5]), width=0.004)
        return jw.simulate(RETRO.replace(E_s=E_s), 0.3)

    out, tangent = jax.jvp(run, (jnp.asarray(0.01),), (jnp.asarray(1.0),))
    assert out.status_name == "ok" and np.isfinite(float(tangent.mean_velocity))

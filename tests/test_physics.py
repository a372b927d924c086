"""Each physics function against its equation in the paper, with hand-computed values.

Table 1 numbers used throughout: E_s = 1.4e5 Pa, K_Ic = 250, K_Ith = 200 Pa√m, ν = 0.3,
w_c = w_0 = 1e-3 m, l_0 = 1e-2 m, h = 1e-3 m, Wg = 4.59e-4, EA = 13 N, m = 1e-5 kg,
μ_s = 0.3, λ = 1.5.  Handy products: 1 − ν² = 0.91, (1 − ν²)² = 0.8281,
w_0 l_0 = 1e-5 m², E_s w_0 l_0 = 1.4 N/m, E_s h = 140 N/m².

The expected numbers are literals worked out from the equations (arithmetic in the
comments), never values returned by the code under test.
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import jaxworm as jw
from jaxworm import physics as phys

E_S, K_IC, K_ITH, NU, W_C, WG = 1.4e5, 250.0, 200.0, 0.3, 1e-3, 4.59e-4
EA, W0, L0, H, M, MU, LAM = 13.0, 1e-3, 1e-2, 1e-3, 1e-5, 0.3, 1.5
EPS_V, EPS_N = 1e-4, 1e-8

close = np.testing.assert_allclose
# no deadline: the first call of each shape compiles
FAST = settings(
    deadline=None, max_examples=40, derandomize=True, suppress_health_check=[HealthCheck.too_slow]
)

lengths = st.floats(1e-4, 5e-2)  # segment lengths [m]
gaps = st.floats(1e-4, 1.0)  # head-to-tip distance [m]
positions = st.floats(-1.0, 1.0)

# jitted once per array shape, so the property tests below stay fast
_stretching_force = jax.jit(phys.stretching_force)
_grad_x_energy = jax.jit(jax.grad(phys.stretching_energy))
_grad_lbar_energy = jax.jit(jax.grad(phys.stretching_energy, argnums=1))
_actuation_power = jax.jit(phys.actuation_power)


# --- smoothing ----------------------------------------------------------------------


def test_exact_smoothing_is_exact_sign_and_max():
    v = jnp.array([-1e-20, 0.0, 1e-20, -3.0, 2.0])
    close(phys.smooth_sign(v, EPS_V, exact=True), [-1.0, 0.0, 1.0, -1.0, 1.0], rtol=0, atol=0)
    close(phys.smooth_max0(v, EPS_N, exact=True), [0.0, 0.0, 1e-20, 0.0, 2.0], rtol=0, atol=0)


def test_smooth_sign_and_max_values():
    # tanh(1e-6 / 1e-4) = tanh(0.01) = 0.0099996666799994...
    close(phys.smooth_sign(jnp.array(1e-6), EPS_V), 0.009999666679999458, rtol=1e-12)
    # far from zero the smooth sign is ±1 to machine precision
    close(phys.smooth_sign(jnp.array([-0.01, 0.01]), EPS_V), [-1.0, 1.0], rtol=1e-15)
    # softplus at 0: eps·ln 2 = 1e-8 · 0.6931471805599453
    close(phys.smooth_max0(jnp.array(0.0), EPS_N), 6.931471805599453e-09, rtol=1e-12)


# --- geometry -----------------------------------------------------------------------


def test_segment_lengths_hand_values():
    # l^k = x_k − x_{k+1}: 0 − (−0.009) = 0.009, −0.009 − (−0.021) = 0.012,
    # −0.021 − (−0.030) = 0.009
    x = jnp.array([0.0, -0.009, -0.021, -0.030])
    close(phys.segment_lengths(x), [0.009, 0.012, 0.009], rtol=1e-12)


def test_segment_velocities_eq9_hand_values():
    # v^k = (v_k + v_{k+1})/2: (0.002 − 0.004)/2 = −0.001, (−0.004 + 0.001)/2 = −0.0015,
    # (0.001 + 0.003)/2 = 0.002
    v = jnp.array([0.002, -0.004, 0.001, 0.003])
    close(phys.segment_velocities(v), [-0.001, -0.0015, 0.002], rtol=1e-12)


def test_segment_widths_eq6_hand_values():
    # w = w_0 l_0 / l = 1e-5 / l: 1e-5/0.008 = 1.25e-3, 1e-5/0.0125 = 8e-4, 1e-5/0.01 = 1e-3
    l = jnp.array([0.008, 0.0125, 0.01])
    close(phys.segment_widths(l, W0, L0), [1.25e-3, 8e-4, 1e-3], rtol=1e-12)


@FAST
@given(l=lengths, w0=st.floats(1e-4, 1e-2), l0=st.floats(1e-3, 5e-2))
def test_segment_widths_conserve_volume(l, w0, l0):
    # constant volume: w l h = w_0 l_0 h
    w = phys.segment_widths(jnp.array(l), w0, l0)
    close(float(w) * l, w0 * l0, rtol=1e-13)


def test_segments_to_nodes_eq11_hand_values():
    # F_{f,1} = 1/2 = 0.5; F_{f,2} = (1 + 2)/2 = 1.5; F_{f,3} = (2 + 4)/2 = 3; F_{f,4} = 4/2 = 2
    close(phys.segments_to_nodes(jnp.array([1.0, 2.0, 4.0])), [0.5, 1.5, 3.0, 2.0], rtol=1e-15)


@FAST
@given(st.lists(st.floats(-1.0, 1.0), min_size=1, max_size=10))
def test_segments_to_nodes_keeps_the_total_force(f):
    nodes = phys.segments_to_nodes(jnp.array(f))
    assert nodes.shape == (len(f) + 1,)
    close(float(jnp.sum(nodes)), math.fsum(f), atol=1e-14)


# --- stretching ----------------------------------------------------------------------


def test_stretching_force_eq20_hand_values():
    # l = (0.011, 0.009), l̄ = (0.01, 0.01): tensions EA(l/l̄ − 1) = 13·0.1 = 1.3, 13·(−0.1) = −1.3
    # eq. 20: node 1: 1.3; node 2: EA(l²/l̄² − l¹/l̄¹) = 13(0.9 − 1.1) = −2.6;
    # node 3: EA(1 − 0.9) = 1.3
    x = jnp.array([0.0, -0.011, -0.020])
    close(phys.stretching_force(x, jnp.array([0.01, 0.01]), EA), [1.3, -2.6, 1.3], rtol=1e-10)
    # unequal l̄ = (0.0125, 0.008) with l = (0.01, 0.01): tensions 13(0.8 − 1) = −2.6,
    # 13(1.25 − 1) = 3.25 → nodes (−2.6, 3.25 + 2.6 = 5.85, −3.25)
    x = jnp.array([0.0, -0.01, -0.02])
    close(phys.stretching_force(x, jnp.array([0.0125, 0.008]), EA), [-2.6, 5.85, -3.25], rtol=1e-10)


@FAST
@given(
    st.integers(2, 9).flatmap(
        lambda n: st.tuples(
            st.lists(st.floats(5e-3, 1.5e-2), min_size=n - 1, max_size=n - 1),
            st.lists(st.floats(5e-3, 1.5e-2), min_size=n - 1, max_size=n - 1),
            positions,
        )
    )
)
def test_stretching_force_newtons_third_law_and_gradient(data):
    l, lbar, x1 = data
    x = x1 - np.concatenate([[0.0], np.cumsum(l)])
    lbar = np.array(lbar)
    f = _stretching_force(x, lbar, EA)
    # internal forces only: they sum to zero (Newton's third law)
    close(math.fsum(np.asarray(f)), 0.0, atol=1e-12)
    # 𝒱_s is the gradient of the stretching energy (eq. 2) w.r.t. x: Lagrange's eq. (3)
    close(f, _grad_x_energy(x, lbar, EA), rtol=1e-9, atol=1e-12)


def test_stretching_energy_eq2_hand_value():
    # V = ½ EA Σ (l − l̄)²/l̄ = 6.5 (0.001²/0.01 + 0.001²/0.01) = 6.5 · 2e-4 = 1.3e-3 J
    x = jnp.array([0.0, -0.011, -0.020])
    close(phys.stretching_energy(x, jnp.array([0.01, 0.01]), EA), 1.3e-3, rtol=1e-10)
    # l = (0.01, 0.01), l̄ = (0.0125, 0.008): first form of eq. 2, ½EA Σ l̄ (l/l̄ − 1)²
    # = 6.5 (0.0125 · 0.04 + 0.008 · 0.0625) = 6.5 (5e-4 + 5e-4) = 6.5e-3 J
    x = jnp.array([0.0, -0.01, -0.02])
    close(phys.stretching_energy(x, jnp.array([0.0125, 0.008]), EA), 6.5e-3, rtol=1e-10)


def test_kinetic_energy_eq1_hand_value():
    # eq. 1: ¼ m v_1² + ½ m v_2² + ¼ m v_3² with m = 1e-5, v = (0.01, 0.02, −0.01):
    # 2.5e-6·1e-4 + 5e-6·4e-4 + 2.5e-6·1e-4 = 2.5e-10 + 2e-9 + 2.5e-10 = 2.5e-9 J
    masses = jw.Body(N=3).node_masses
    close(masses, [5e-6, 1e-5, 5e-6], rtol=1e-15)
    close(phys.kinetic_energy(jnp.array([0.01, 0.02, -0.01]), masses), 2.5e-9, rtol=1e-12)


def test_node_masses_table1():
    close(jw.Body().node_masses, [5e-6] + [1e-5] * 5 + [5e-6], rtol=1e-15)


def test_actuation_power_hand_value():
    # ∂V/∂l̄_k = ½EA(1 − (l/l̄)²): ½·13·(1 − 1.21) = −1.365, ½·13·(1 − 0.81) = 1.235
    # with u = (0.02, −0.01): −1.365·0.02 + 1.235·(−0.01) = −0.0273 − 0.01235 = −0.03965 W
    x = jnp.array([0.0, -0.011, -0.020])
    p = phys.actuation_power(x, jnp.array([0.01, 0.01]), jnp.array([0.02, -0.01]), EA)
    close(p, -0.03965, rtol=1e-10)


@FAST
@given(
    st.integers(2, 8).flatmap(
        lambda n: st.tuples(
            st.lists(st.floats(5e-3, 1.5e-2), min_size=n - 1, max_size=n - 1),
            st.lists(st.floats(5e-3, 1.5e-2), min_size=n - 1, max_size=n - 1),
            st.lists(st.floats(-0.05, 0.05), min_size=n - 1, max_size=n - 1),
        )
    )
)
def test_actuation_power_is_grad_of_energy_wrt_lbar(data):
    l, lbar, u = data
    x = -np.concatenate([[0.0], np.cumsum(l)])
    lbar, u = np.array(lbar), np.array(u)
    dV = np.asarray(_grad_lbar_energy(x, lbar, EA))
    close(_actuation_power(x, lbar, u, EA), np.dot(dV, u), rtol=1e-9, atol=1e-13)


# --- normal force and friction -----------------------------------------------------


def test_normal_force_eq8_hand_values_exact():
    # F_N = max{E_s h (w_0 l_0 − w_c l), 0} = max{140 (1e-5 − 1e-3 l), 0}
    # l = 0.008: 140·2e-6 = 2.8e-4 N; l = 0.009: 140·1e-6 = 1.4e-4 N;
    # l = 0.01: 0 (w_c = w_0 and l = l_0); l = 0.012: 140·(−2e-6) < 0 → 0
    l = jnp.array([0.008, 0.009, 0.01, 0.012])
    F = phys.normal_force(l, E_S, H, W0, L0, W_C, EPS_N, exact=True)
    close(F, [2.8e-4, 1.4e-4, 0.0, 0.0], rtol=1e-10, atol=1e-20)
    # a narrower crack, w_c = 1.2e-3: l = 0.008 → 140(1e-5 − 9.6e-6) = 5.6e-5 N; l = 0.009 → 0
    F = phys.normal_force(jnp.array([0.008, 0.009]), E_S, H, W0, L0, 1.2e-3, EPS_N, exact=True)
    close(F, [5.6e-5, 0.0], rtol=1e-9, atol=1e-20)


@FAST
@given(l=st.floats(1.0001e-2, 5e-2))
def test_normal_force_zero_when_longer_than_l0(l):
    # with w_c = w_0 a segment longer than l_0 is thinner than the crack: no contact
    assert float(phys.normal_force(jnp.array(l), E_S, H, W0, L0, W_C, EPS_N, exact=True)) == 0.0
    # the smooth max is below eps_N ln 2 there
    assert float(phys.normal_force(jnp.array(l), E_S, H, W0, L0, W_C, EPS_N)) <= EPS_N * math.log(2)


@FAST
@given(l=st.floats(5e-3, 1.5e-2), w_c=st.floats(5e-4, 2e-3))
def test_normal_force_eq8_first_form_and_smooth_bound(l, w_c):
    # eq. 8, first form: F_N = l h max{E_s (w − w_c), 0} with the width w of eq. 6
    w = W0 * L0 / l
    first_form = l * H * max(E_S * (w - w_c), 0.0)
    exact = float(phys.normal_force(jnp.array(l), E_S, H, W0, L0, w_c, EPS_N, exact=True))
    close(exact, first_form, rtol=1e-9, atol=1e-18)
    smooth = float(phys.normal_force(jnp.array(l), E_S, H, W0, L0, w_c, EPS_N))
    # softplus lies above max and at most eps·ln 2 above it
    assert exact - 1e-18 <= smooth <= exact + EPS_N * math.log(2) * (1 + 1e-9) + 1e-18


def test_friction_segment_eq10_hand_values():
    # F_N = 2.8e-4 N. v > 0: μ[(λ−1)/2 − (λ+1)/2] F_N = −μ F_N = −0.3·2.8e-4 = −8.4e-5
    # v < 0: μ[(λ−1)/2 + (λ+1)/2] F_N = λ μ F_N = 1.5·0.3·2.8e-4 = 1.26e-4
    # v = 0: μ (λ−1)/2 F_N = 0.3·0.25·2.8e-4 = 2.1e-5 (sgn 0 = 0)
    v = jnp.array([0.01, 1e-12, -0.01, -1e-12, 0.0])
    F = phys.friction_segment(v, 2.8e-4, MU, LAM, EPS_V, exact=True)
    close(F, [-8.4e-5, -8.4e-5, 1.26e-4, 1.26e-4, 2.1e-5], rtol=1e-12)
    # smoothed: equal to exact away from 0 (tanh(±100) = ±1) and at 0 (tanh 0 = 0)
    v = jnp.array([0.01, -0.01, 0.0])
    F = phys.friction_segment(v, 2.8e-4, MU, LAM, EPS_V)
    close(F, [-8.4e-5, 1.26e-4, 2.1e-5], rtol=1e-12)


@FAST
@given(v=st.floats(-1.0, 1.0), F_N=st.floats(0.0, 1e-3))
def test_friction_opposes_motion_with_anisotropy(v, F_N):
    # exact law: forward motion feels −μF_N, backward +λμF_N; never zero at v ≠ 0
    F = float(phys.friction_segment(jnp.array(v), F_N, MU, LAM, EPS_V, exact=True))
    expected = -MU * F_N if v > 0 else (LAM * MU * F_N if v < 0 else MU * 0.25 * F_N)
    close(F, expected, rtol=1e-12, atol=1e-20)
    # the smooth law lies between the two one-sided values
    Fs = float(phys.friction_segment(jnp.array(v), F_N, MU, LAM, EPS_V))
    assert -MU * F_N * (1 + 1e-12) <= Fs <= LAM * MU * F_N * (1 + 1e-12)


def test_friction_force_eqs8_to_11_together():
    # x = (0, −0.009, −0.0185): l = (0.009, 0.0095) → F_N = 140·1e-6 = 1.4e-4, 140·5e-7 = 7e-5
    # v = (0.003, 0.001, −0.001): v^1 = 0.002 > 0, v^2 = 0
    # F_f^1 = −0.3·1.4e-4 = −4.2e-5; F_f^2 = 0.3·0.25·7e-5 = 5.25e-6
    # nodes (eq. 11): (−2.1e-5, (−4.2e-5 + 5.25e-6)/2 = −1.8375e-5, 2.625e-6)
    x = jnp.array([0.0, -0.009, -0.0185])
    v = jnp.array([0.003, 0.001, -0.001])
    F = phys.friction_force(x, v, E_S, H, W0, L0, W_C, MU, LAM, EPS_V, EPS_N, exact=True)
    close(F, [-2.1e-5, -1.8375e-5, 2.625e-6], rtol=1e-9)


# --- fracture -------------------------------------------------------------------------


def test_stress_intensity_eq12_hand_value():
    # gap 0.05, l1 = 0.01: K_I = 1.4 / (√(0.1π) · 0.91 · 0.01)
    # √(0.1π) = 0.5604991216397929 → 1.4 / 0.005100542006922 = 274.4806332542725 Pa√m
    close(phys.stress_intensity(0.05, 0.01, E_S, NU, W0, L0), 274.4806332542725, rtol=1e-12)
    # eq. 12 with l1 = l0 reduces to eq. 4 with w^1 = w_0: halving l1 doubles K_I
    close(phys.stress_intensity(0.05, 0.005, E_S, NU, W0, L0), 2 * 274.4806332542725, rtol=1e-12)


def test_crack_tip_after_jump_eq13_hand_value():
    # x_c = x_1 + (E_s w_0 l_0)² / (2π K_Ith² (1−ν²)² l1²); l1 = 0.01:
    # 1.4² = 1.96; 2π · 4e4 · 0.8281 · 1e-4 = 20.812423011501664 → gap 0.09417452253958306 m
    close(
        phys.crack_tip_after_jump(0.0, 0.01, K_ITH, E_S, NU, W0, L0),
        0.09417452253958306,
        rtol=1e-12,
    )
    close(
        phys.crack_tip_after_jump(0.3, 0.01, K_ITH, E_S, NU, W0, L0),
        0.39417452253958306,
        rtol=1e-12,
    )
    # l1 = 0.008: 0.09417452253958306 · (0.01/0.008)² = 0.14714769146809853
    close(
        phys.crack_tip_after_jump(-0.1, 0.008, K_ITH, E_S, NU, W0, L0),
        -0.1 + 0.14714769146809853,
        rtol=1e-12,
    )


@FAST
@given(x1=positions, l1=st.floats(2e-3, 2e-2), K=st.floats(10.0, 1000.0))
def test_crack_tip_after_jump_arrests_at_threshold(x1, l1, K):
    # at the new tip K_I (eq. 12) equals K_Ith exactly: eq. 13 solves eq. 12 = K_Ith
    xc = phys.crack_tip_after_jump(x1, l1, K, E_S, NU, W0, L0)
    assert float(xc) > x1
    close(phys.stress_intensity(xc - x1, l1, E_S, NU, W0, L0), K, rtol=1e-9)


def test_arrest_gap_hand_value_and_jump_ratio():
    # K = K_Ic = 250, l1 = 0.01: 1.96 / (2π · 62500 · 0.8281 · 1e-4) = 0.06027169442533315 m
    gap_c = phys.arrest_gap(0.01, K_IC, E_S, NU, W0, L0)
    close(gap_c, 0.06027169442533315, rtol=1e-12)
    # a jump from K_Ic to K_Ith lengthens the gap by (K_Ic/K_Ith)² = 1.5625 (≈ 56 % advance)
    gap_th = phys.arrest_gap(0.01, K_ITH, E_S, NU, W0, L0)
    close(gap_th / gap_c, 1.5625, rtol=1e-12)


def test_back_pressure_eq16_hand_value():
    # F_p = E_s (w_0 l_0)² h Wg / (2π gap l1² (1−ν²))
    # numerator 1.4e5 · 1e-10 · 1e-3 · 4.59e-4 = 6.426e-12
    # gap 0.05, l1 0.01: 2π·0.05·1e-4·0.91 = 2.8588493147667123e-5 → 2.2477575039747677e-7 N
    close(phys.back_pressure(0.05, 0.01, E_S, NU, W0, L0, H, WG), 2.2477575039747677e-7, rtol=1e-12)
    # l1 0.009: 2π·0.05·8.1e-5·0.91 = 2.3156679449610364e-5 → 2.7750092641663805e-7 N
    close(
        phys.back_pressure(0.05, 0.009, E_S, NU, W0, L0, H, WG), 2.7750092641663805e-7, rtol=1e-12
    )


@FAST
@given(gap=gaps, l1=st.floats(2e-3, 2e-2))
def test_back_pressure_eq16_equals_eq15(gap, l1):
    # eq. 15: F_p = K_I / √(2π gap) · Wg · w^1 · h with w^1 = w_0 l_0 / l1 (eq. 6)
    K = phys.stress_intensity(gap, l1, E_S, NU, W0, L0)
    eq15 = K / math.sqrt(2 * math.pi * gap) * WG * (W0 * L0 / l1) * H
    close(phys.back_pressure(gap, l1, E_S, NU, W0, L0, H, WG), eq15, rtol=1e-10)


def test_wedge_number_eq5_hand_value():
    # Wg = K_Ic² w_c / (E_s² h w_0) = 62500·1e-3 / (1.96e10·1e-6) = 62.5/19600 = 3.18877551e-3
    close(phys.wedge_number_eq5(K_IC, W_C, E_S, H, W0), 0.0031887755102040817, rtol=1e-12)
    p = jw.Params().replace()
    close(p.wedge_number, WG, rtol=1e-15)  # default "given": Table 1's Wg
    p5 = jw.Params(soil=jw.Soil(wedge="eq5"))
    close(p5.wedge_number, 0.0031887755102040817, rtol=1e-12)


# --- the full vector field (eqs. 17-23) ---------------------------------------------


def _state(x, v, lbar):
    return jw.WormState(x=jnp.array(x), v=jnp.array(v), lbar=jnp.array(lbar), work=jnp.zeros(4))


P3_EXACT = jw.Params(body=jw.Body(N=3), smoothing=jw.Smoothing(exact=True))


def test_vector_field_eq17_no_springs():
    # N = 3 and l̄ = l, so the springs are slack and only friction and back pressure act.
    # x = (0, −0.009, −0.0185), v = (0.003, 0.001, −0.001), x_c = 0.05 (gap 0.05):
    # friction per node (see test_friction_force_eqs8_to_11_together):
    #   (−2.1e-5, −1.8375e-5, 2.625e-6) N
    # F_p (gap 0.05, l1 0.009) = 2.7750092641663805e-7 N on the head
    # eq. 17: a_1 = (2/m)(F_f1 − F_p) = 2e5·(−2.1e-5 − 2.7750092641663805e-7) = −4.25550018528
    #         a_2 = (1/m) F_f2 = 1e5·(−1.8375e-5) = −1.8375
    #         a_3 = (2/m) F_f3 = 2e5·2.625e-6 = 0.525
    y = _state([0.0, -0.009, -0.0185], [0.003, 0.001, -0.001], [0.009, 0.0095])
    dy = jw.vector_field(0.0, y, (P3_EXACT, jnp.array(0.05)))
    close(dy.x, [0.003, 0.001, -0.001], rtol=1e-15)
    close(dy.v, [-4.2555001852832770, -1.8375, 0.525], rtol=1e-9, atol=1e-9)


def test_vector_field_eq17_with_springs_and_control():
    # same x, v but l̄ = (0.01, 0.01): tensions 13(0.9 − 1) = −1.3, 13(0.95 − 1) = −0.65
    # 𝒱_s = (−1.3, −0.65 + 1.3 = 0.65, 0.65)
    # a_1 = 2e5(−2.1e-5 − 2.7750092641663805e-7 + 1.3) = 259995.74449981472
    # a_2 = 1e5(−1.8375e-5 − 0.65) = −65001.8375
    # a_3 = 2e5(2.625e-6 − 0.65) = −129999.475
    # l̄' = u = 0.02 sin(ωt + δk), t = 0.1: ωt = 0.4π = 72°, δk = 45°, 90°
    #   sin 117° = 0.8910065241883679, sin 162° = 0.3090169943749475
    y = _state([0.0, -0.009, -0.0185], [0.003, 0.001, -0.001], [0.01, 0.01])
    dy = jw.vector_field(0.1, y, (P3_EXACT, jnp.array(0.05)))
    close(dy.v, [259995.74449981472, -65001.8375, -129999.475], rtol=1e-12, atol=1e-8)
    close(dy.lbar, [0.017820130483767358, 0.00618033988749895], rtol=1e-12)


def test_vector_field_power_balance():
    # d(T + V)/dt along the field = Σ F_f,k v_k − F_p v_1 + ∂V/∂l̄·u (eqs. 1, 2, 17, 23);
    # the field's work rates must carry exactly these three terms.
    p = jw.Params()
    b = p.body
    rng = np.random.default_rng(0)
    x = -np.cumsum(np.r_[0.0, 0.01 + 1e-3 * rng.standard_normal(b.N - 1)])
    y = _state(x, 1e-3 * rng.standard_normal(b.N), 0.01 + 5e-4 * rng.standard_normal(b.N - 1))
    x_c = jnp.array(x[0] + 0.05)
    dy = jw.vector_field(0.3, y, (p, x_c))

    def energy(y):
        return phys.kinetic_energy(y.v, b.node_masses) + phys.stretching_energy(y.x, y.lbar, b.EA)

    _, dE = jax.jvp(energy, (y,), (dy,))
    act, diss, bp, gross = dy.work
    close(dE, act - diss - bp, rtol=1e-9)
    close(gross, jnp.abs(act), rtol=1e-15)
    f = jw.forces(0.3, y, x_c, p)
    close(diss, -jnp.sum(f["friction"] * y.v), rtol=1e-12)
    close(bp, f["back_pressure"] * y.v[0], rtol=1e-12)


def test_exact_and_smooth_vector_fields_agree_away_from_switches():
    # every segment compressed (F_N ≫ eps_N) and every |v^k| ≫ eps_v: smoothing changes nothing
    x = -np.cumsum([0.0, 0.009, 0.0092, 0.0094])
    y = _state(x, [0.01, 0.012, 0.011, 0.013], [0.0095, 0.0095, 0.0095])
    p = jw.Params(body=jw.Body(N=4))
    pe = jw.Params(body=jw.Body(N=4), smoothing=jw.Smoothing(exact=True))
    a = jw.vector_field(0.0, y, (p, jnp.array(0.05))).v
    ae = jw.vector_field(0.0, y, (pe, jnp.array(0.05))).v
    close(a, ae, rtol=1e-12)


def test_exact_smoothing_friction_at_rest_on_uncompressed_body_is_zero():
    # at rest and unstretched with w_c = w_0: F_N = max(0, 0) = 0 (up to the rounding of
    # x_k = −(k−1) l_0, ~1e-20 N), so no friction; the smooth max leaves eps_N ln 2 per
    # segment, i.e. 0.3·0.25·eps_N·ln2 ≈ 5.2e-10 N of friction per segment.
    y = jw.initial_state(jw.Params())
    pe = jw.Params(smoothing=jw.Smoothing(exact=True))
    fe = jw.forces(0.0, y, jnp.array(0.05), pe)["friction"]
    close(fe, np.zeros(7), rtol=0, atol=1e-18)
    fs = jw.forces(0.0, y, jnp.array(0.05), jw.Params())["friction"]
    seg = 0.3 * 0.25 * EPS_N * math.log(2)
    close(fs, [seg / 2] + [seg] * 5 + [seg / 2], rtol=1e-9)


# --- readings of eqs. 7 and 10 (model options) ---------------------------------------


def test_normal_force_strain_reading_hand_values():
    # σ_N = E_s (w − w_c)/w_c, F_N = l h σ_N. l = 0.008: w = 1e-5/0.008 = 1.25e-3,
    # strain 0.25, σ_N = 3.5e4 Pa, F_N = 0.008·1e-3·3.5e4 = 0.28 N (1/w_c = 1000 × the
    # printed 2.8e-4 N); l = 0.009: w = 1.1111e-3, σ_N = 1.4e5/9 Pa, F_N = 0.14 N;
    # l = l0 and longer: no contact
    l = jnp.array([0.008, 0.009, 0.01, 0.012])
    F = phys.normal_force(l, E_S, H, W0, L0, W_C, EPS_N, exact=True, stress="strain")
    close(F, [0.28, 0.14, 0.0, 0.0], rtol=1e-10, atol=1e-20)
    # a narrower crack, w_c = 1.2e-3: l = 0.008 → strain 1.25/1.2 − 1, F_N = 1.12e4·8e-6/1.2·...
    w_c = 1.2e-3
    by_hand = 0.008 * H * E_S * (W0 * L0 / 0.008 - w_c) / w_c  # = 5.6e-5 / 1.2e-3
    F = phys.normal_force(
        jnp.array([0.008]), E_S, H, W0, L0, w_c, EPS_N, exact=True, stress="strain"
    )
    close(F, [by_hand], rtol=1e-10)
    close(by_hand, 5.6e-5 / 1.2e-3, rtol=1e-10)


def test_the_default_readings_are_the_printed_formulas_bit_for_bit():
    l = jnp.array([0.008, 0.0093, 0.0101])
    v = jnp.array([0.01, -3e-5, 0.0])
    F_N = phys.normal_force(l, E_S, H, W0, L0, W_C, EPS_N)
    assert np.array_equal(F_N, phys.normal_force(l, E_S, H, W0, L0, W_C, EPS_N, stress="printed"))
    F = phys.friction_segment(v, F_N, MU, LAM, EPS_V)
    assert np.array_equal(F, phys.friction_segment(v, F_N, MU, LAM, EPS_V, forward="head"))
    s = jnp.tanh(v / EPS_V)
    assert np.array_equal(F, MU * (0.5 * (LAM - 1.0) - 0.5 * (LAM + 1.0) * s) * F_N)


def test_friction_tail_forward_hand_values():
    # forward = tail: head-ward motion (v > 0) meets λ μ F_N backward, tail-ward μ F_N
    # forward; at v = 0 the constant term pushes tail-ward, −μ (λ−1)/2 F_N
    v = jnp.array([0.01, -0.01, 0.0])
    F = phys.friction_segment(v, 2.8e-4, MU, LAM, EPS_V, exact=True, forward="tail")
    close(F, [-1.26e-4, 8.4e-5, -2.1e-5], rtol=1e-12)
    # the mirror image of the head-forward law: F_tail(v) = −F_head(−v)
    vs = jnp.linspace(-3e-4, 3e-4, 13)
    close(
        phys.friction_segment(vs, 2.8e-4, MU, LAM, EPS_V, forward="tail"),
        -phys.friction_segment(-vs, 2.8e-4, MU, LAM, EPS_V),
        rtol=1e-14,
        atol=1e-22,
    )

"""The forces and the fracture law of the paper, one small pure function each.

Arguments are plain arrays in SI units, so each function can be checked alone against
its equation. Index conventions (`MODEL.md`): nodes k = 1..N from head to tail
(array index k − 1); segment k joins nodes k and k+1 and has length l^k = x_k − x_{k+1}.
"""

from __future__ import annotations

from typing import Literal

import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

#: A scalar (a parameter, a time, a crack tip): a float64 0-d array, or a Python float.
Scalar = Float[Array, ""] | float
#: Elementwise functions take and return arrays of any one shape (per node, per segment,
#: or a scalar).
Elementwise = Float[Array, "*shape"]


# --- smoothing -------------------------------------------------------------------


def smooth_sign(v: Elementwise, eps_v: Scalar, exact: bool = False) -> Elementwise:
    """sgn(v) ≈ tanh(v / eps_v); the exact signum (sgn(0) = 0) when `exact`."""
    return jnp.sign(v) if exact else jnp.tanh(v / eps_v)


def smooth_max0(z: Elementwise, eps: Scalar, exact: bool = False) -> Elementwise:
    """max(z, 0) ≈ eps·softplus(z / eps) (error ≤ eps·ln 2); exact when `exact`."""
    return jnp.maximum(z, 0.0) if exact else eps * jax.nn.softplus(z / eps)


# --- geometry ----------------------------------------------------------------------


def segment_lengths(x: Float[Array, " N"]) -> Float[Array, " S"]:
    """l^k = x_k − x_{k+1} (§2.1)."""
    return x[:-1] - x[1:]


def segment_velocities(v: Float[Array, " N"]) -> Float[Array, " S"]:
    """v^k = (v_k + v_{k+1}) / 2 (eq. 9)."""
    return 0.5 * (v[:-1] + v[1:])


def segment_widths(l: Float[Array, " S"], w0: Scalar, l0: Scalar) -> Float[Array, " S"]:
    """Constant volume: w^k = w_0 l_0 / l^k (eq. 6)."""
    return w0 * l0 / l


def segments_to_nodes(f_seg: Float[Array, " S"]) -> Float[Array, " N"]:
    """Half of each segment's force to each of its two nodes (eq. 11)."""
    zero = jnp.zeros(1, f_seg.dtype)
    return 0.5 * (jnp.concatenate([f_seg, zero]) + jnp.concatenate([zero, f_seg]))


# --- forces ------------------------------------------------------------------------


def stretching_tension(
    l: Float[Array, " S"], lbar: Float[Array, " S"], EA: Scalar
) -> Float[Array, " S"]:
    """Segment tension EA (l^k / l̄^k − 1) (the terms of eqs. 3 and 20)."""
    return EA * (l / lbar - 1.0)


def stretching_force(
    x: Float[Array, " N"], lbar: Float[Array, " S"], EA: Scalar
) -> Float[Array, " N"]:
    """𝒱_s(x, l̄) of eq. (20): the elastic term on the left of eq. (17), per node."""
    tension = stretching_tension(segment_lengths(x), lbar, EA)
    zero = jnp.zeros(1, tension.dtype)
    return jnp.concatenate([tension, zero]) - jnp.concatenate([zero, tension])


def normal_force(
    l: Float[Array, " S"],
    E_s: Scalar,
    h: Scalar,
    w0: Scalar,
    l0: Scalar,
    w_c: Scalar,
    eps_N: Scalar,
    exact: bool = False,
    stress: Literal["printed", "strain"] = "printed",
) -> Float[Array, " S"]:
    """F_N^k = l^k h σ_N^k (eq. 8), smoothed unless `exact`, with σ_N of eq. (7) read by
    `stress`:

    - `"printed"`: σ_N = E_s (w − w_c) as printed, so F_N = max{E_s h (w_0 l_0 − w_c l^k), 0};
    - `"strain"`: σ_N = E_s (w − w_c)/w_c (a stress: the soil's strain times E_s), so
      F_N = max{E_s h (w_0 l_0 − w_c l^k)/w_c, 0}, 1/w_c times the printed force.
    """
    if stress == "strain":
        return smooth_max0(E_s * h * (w0 * l0 - w_c * l) / w_c, eps_N, exact)
    return smooth_max0(E_s * h * (w0 * l0 - w_c * l), eps_N, exact)


def friction_segment(
    v_seg: Float[Array, " S"],
    F_N: Float[Array, " S"],
    mu_s: Scalar,
    lam: Scalar,
    eps_v: Scalar,
    exact: bool = False,
    forward: Literal["head", "tail"] = "head",
) -> Float[Array, " S"]:
    """F_f^k = μ_s [(λ−1)/2 − (λ+1)/2 sgn(v^k)] F_N^k (eq. 10), with "forward" (v^k > 0
    in eq. 10) pointing to `forward`:

    - `"head"`: a segment moving tail-ward (v^k < 0) meets λ μ_s, head-ward μ_s;
    - `"tail"`: the law mirrored, F_f^k = −μ_s [(λ−1)/2 − (λ+1)/2 sgn(−v^k)] F_N^k:
      head-ward motion meets λ μ_s, tail-ward μ_s.
    """
    if forward == "tail":
        s = smooth_sign(-v_seg, eps_v, exact)
        return -mu_s * (0.5 * (lam - 1.0) - 0.5 * (lam + 1.0) * s) * F_N
    s = smooth_sign(v_seg, eps_v, exact)
    return mu_s * (0.5 * (lam - 1.0) - 0.5 * (lam + 1.0) * s) * F_N


def friction_force(
    x: Float[Array, " N"],
    v: Float[Array, " N"],
    E_s: Scalar,
    h: Scalar,
    w0: Scalar,
    l0: Scalar,
    w_c: Scalar,
    mu_s: Scalar,
    lam: Scalar,
    eps_v: Scalar,
    eps_N: Scalar,
    exact: bool = False,
    stress: Literal["printed", "strain"] = "printed",
    forward: Literal["head", "tail"] = "head",
) -> Float[Array, " N"]:
    """ℱ_f(x, ẋ) of eq. (21): node friction forces, eqs. (8)-(11) together (`stress` and
    `forward` as in `normal_force` and `friction_segment`)."""
    F_N = normal_force(segment_lengths(x), E_s, h, w0, l0, w_c, eps_N, exact, stress)
    F_f = friction_segment(segment_velocities(v), F_N, mu_s, lam, eps_v, exact, forward)
    return segments_to_nodes(F_f)


def stress_intensity(
    gap: Elementwise, l1: Elementwise, E_s: Scalar, nu: Scalar, w0: Scalar, l0: Scalar
) -> Elementwise:
    """K_I = E_s w_0 l_0 / (√(2π (x_c − x_1)) (1 − ν²) (x_1 − x_2)) (eq. 12).

    `gap` = x_c − x_1 > 0 and `l1` = x_1 − x_2 the head segment's length.
    """
    return E_s * w0 * l0 / (jnp.sqrt(2 * jnp.pi * gap) * (1 - nu**2) * l1)


def arrest_gap(
    l1: Elementwise, K: Scalar, E_s: Scalar, nu: Scalar, w0: Scalar, l0: Scalar
) -> Elementwise:
    """The gap x_c − x_1 at which K_I = K for head length l1: eq. (12) solved for it."""
    return (E_s * w0 * l0) ** 2 / (2 * jnp.pi * K**2 * (1 - nu**2) ** 2 * l1**2)


def crack_tip_after_jump(
    x1: Elementwise,
    l1: Elementwise,
    K_Ith: Scalar,
    E_s: Scalar,
    nu: Scalar,
    w0: Scalar,
    l0: Scalar,
) -> Elementwise:
    """x_c(t_{n+1}) = x_1 + E_s² w_0² l_0² / (2π K_Ith² (1−ν²)² (x_1 − x_2)²) (eq. 13)."""
    return x1 + arrest_gap(l1, K_Ith, E_s, nu, w0, l0)


def back_pressure(
    gap: Elementwise,
    l1: Elementwise,
    E_s: Scalar,
    nu: Scalar,
    w0: Scalar,
    l0: Scalar,
    h: Scalar,
    Wg: Scalar,
) -> Elementwise:
    """F_p = E_s w_0² l_0² h Wg / (2π (x_c − x_1) (x_1 − x_2)² (1 − ν²)) (eq. 16)."""
    return E_s * (w0 * l0) ** 2 * h * Wg / (2 * jnp.pi * gap * l1**2 * (1 - nu**2))


def wedge_number_eq5(K_Ic: Scalar, w_c: Scalar, E_s: Scalar, h: Scalar, w0: Scalar) -> Scalar:
    """Wg = K_Ic² w_c / (E_s² h w_0) (eq. 5)."""
    return K_Ic**2 * w_c / (E_s**2 * h * w0)


# --- energies ----------------------------------------------------------------------


def kinetic_energy(v: Float[Array, " N"], node_masses: Float[Array, " N"]) -> Float[Array, ""]:
    """T = ½ Σ m_k ẋ_k² (eq. 1)."""
    return 0.5 * jnp.sum(node_masses * v**2)


def stretching_energy(
    x: Float[Array, " N"], lbar: Float[Array, " S"], EA: Scalar
) -> Float[Array, ""]:
    """V = ½ EA Σ (l^k − l̄^k)² / l̄^k (eq. 2)."""
    return 0.5 * EA * jnp.sum((segment_lengths(x) - lbar) ** 2 / lbar)


def actuation_power(
    x: Float[Array, " N"], lbar: Float[Array, " S"], u: Float[Array, " S"], EA: Scalar
) -> Float[Array, ""]:
    """∂V/∂l̄ · u = Σ ½ EA (1 − (l^k/l̄^k)²) u_k: the power the controller puts in."""
    return jnp.sum(0.5 * EA * (1.0 - (segment_lengths(x) / lbar) ** 2) * u)

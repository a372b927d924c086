"""The state-space model (eqs. 17-23) as a pure vector field, and the crack condition.

The state is (x, v, l̄) with three running integrals for the energy balance; the crack
tip x_c is constant between crack events and travels in `args`.
"""

from __future__ import annotations

from typing import Any

import equinox as eqx
import jax
import jax.extend.core as jex
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float

from . import _physics as phys
from ._feedback import AbstractFeedbackController
from ._params import Body, Params
from ._physics import Scalar
from ._sensors import Sensors
from ._soil import AbstractProfile, arrest_tip, is_profile, value_at

__all__ = [
    "WormState",
    "reads_crack",
    "initial_state",
    "initial_crack_tip",
    "vector_field",
    "forces",
    "vector_field_stiff",
    "vector_field_nonstiff",
    "crack_condition",
    "body_collapsed",
    "collapse_condition",
    "crack_jump",
    "stress_intensity_of",
    "sensors_of",
    "control_rate",
    "actuation_work_rates",
    "actuation_work_of_power",
]

# Smallest head-to-tip gap the formulas see, relative to l_0. Only a state that has
# overshot the crack event reaches it; K_I is then huge, so the event still fires.
_GAP_FLOOR = 1e-9


class WormState(eqx.Module):
    """State of the ODE.

    - `x`, `v`: node positions [m] and velocities [m/s], head first (N,).
    - `lbar`: intrinsic segment lengths l̄ [m] (N−1,), integrated from u (eq. 23).
    - `work`: running integrals [J]: actuation work ∫∂V/∂l̄·u, friction dissipation
      −∫Σ F_f,k v_k, back-pressure work ∫F_p v_1 (the energy balance's terms) and the
      gross actuation work ∫|∂V/∂l̄·u| (the balance's scale where the net work is a
      small difference of large flows in and out: a standing wave).
    """

    x: Float[Array, " N"]
    v: Float[Array, " N"]
    lbar: Float[Array, " S"]
    work: Float[Array, " 4"]


def initial_state(p: Params) -> WormState:
    """Rest, unstretched, head at 0: x_k(0) = −(k−1) l_0, v = 0 (`MODEL.md`)."""
    b = p.body
    x = -jnp.arange(b.N) * b.l0
    return WormState(
        x=x, v=jnp.zeros(b.N), lbar=p.gait.lbar0(b) * jnp.ones(b.N - 1), work=jnp.zeros(4)
    )


def initial_crack_tip(p: Params, y0: WormState) -> Float[Array, ""]:
    """x_c(0): eq. (13) at t = 0 (K_I(0) = K_Ith; for soil that varies, the first x
    ahead of the head where K_I(x) ≤ K_Ith(x)), or x_1(0) + `crack_gap0`."""
    if p.crack_gap0 is not None:
        return y0.x[0] + p.crack_gap0
    return crack_jump(y0, p)


def _gap(x, x_c, p: Params):
    return jnp.maximum(x_c - x[0], _GAP_FLOOR * p.body.l0)


def stress_intensity_of(y: WormState, x_c: Scalar, p: Params) -> Float[Array, ""]:
    """K_I of the state (eq. 12), with the soil's E_s at the crack tip x_c."""
    b, s = p.body, p.soil
    E_s = value_at(s.E_s, x_c)
    return phys.stress_intensity(_gap(y.x, x_c, p), y.x[0] - y.x[1], E_s, s.nu, b.w0, b.l0)


def _segment_soil(y: WormState, p: Params) -> tuple[Any, Any]:
    """E_s and μ_s of each segment: at its midpoint where they vary, else the numbers."""
    s = p.soil
    if not (is_profile(s.E_s) or is_profile(s.mu_s)):
        return s.E_s, s.mu_s
    mid = 0.5 * (y.x[:-1] + y.x[1:])
    return value_at(s.E_s, mid), value_at(s.mu_s, mid)


def _stiff_forces(y: WormState, p: Params):
    b, s, sm = p.body, p.soil, p.smoothing
    E_s, mu_s = _segment_soil(y, p)
    f_s = phys.stretching_force(y.x, y.lbar, b.EA)
    f_f = phys.friction_force(
        y.x,
        y.v,
        E_s,
        b.h,
        b.w0,
        b.l0,
        s.w_c,
        mu_s,
        b.lam,
        sm.eps_v,
        sm.eps_N,
        sm.exact,
        s.normal_stress,
        b.friction_forward,
    )
    return f_s, f_f


def _back_pressure(y: WormState, x_c, p: Params):
    b, s = p.body, p.soil
    E_s = value_at(s.E_s, x_c)
    return phys.back_pressure(
        _gap(y.x, x_c, p), y.x[0] - y.x[1], E_s, s.nu, b.w0, b.l0, b.h, p.wedge_number_at(x_c)
    )


def forces(t: Float[ArrayLike, ""], y: WormState, x_c: Scalar, p: Params) -> dict[str, Array]:
    """Every force of eq. (17) at one instant [N], and the control u [m/s].

    `stretching` is 𝒱_s (eq. 20), `friction` ℱ_f (eq. 21), both per node;
    `back_pressure` is F_p (eq. 16) on the head.
    """
    f_s, f_f = _stiff_forces(y, p)
    return {
        "stretching": f_s,
        "friction": f_f,
        "back_pressure": _back_pressure(y, x_c, p),
        "u": control_rate(t, y, x_c, p),
    }


def sensors_of(t: Float[ArrayLike, ""], y: WormState, x_c: Scalar, p: Params) -> Sensors:
    """What the robot measures at one instant (`Sensors`), without noise: the
    velocities, segment and intrinsic lengths, F_p (eq. 16) and K_I/K_Ic(x_c) (eq. 12)."""
    return Sensors(
        t=jnp.asarray(t, dtype=float),
        v=y.v,
        lengths=phys.segment_lengths(y.x),
        lbar=y.lbar,
        back_pressure=_back_pressure(y, x_c, p),
        stress_ratio=_stress_ratio(y, x_c, p),
    )


def control_rate(t: Float[ArrayLike, ""], y: WormState, x_c: Scalar, p: Params) -> Array:
    """u = d l̄/dt (eq. 23) from the gait: u(t, x, v, l̄), or, for an
    `AbstractFeedbackController`, u of the sensors (`sensors_of`, its noise added)."""
    if isinstance(p.gait, AbstractFeedbackController):
        return p.gait.control(sensors_of(t, y, x_c, p), p.body)
    return p.gait(t, y.x, y.v, y.lbar, p.body)


#: The sensors that carry the crack: F_p (eq. 16) and K_I/K_Ic at the tip (eq. 12).
CRACK_SENSORS = ("back_pressure", "stress_ratio")


def reads_crack(p: Params) -> bool:
    """Whether the gait's u depends on a crack sensor (`CRACK_SENSORS`): a feedback
    controller whose `control` reads F_p or K_I/K_Ic. Decided on its traced program,
    whatever the values of its parameters (a reflex gain of 0 still reads); a sensor
    passed through `jax.lax.stop_gradient` is not counted."""
    gait = p.gait
    if not isinstance(gait, AbstractFeedbackController):
        return False
    S = p.body.N - 1

    def u(signals):
        zeros = jnp.zeros(S)
        s = Sensors(t=jnp.zeros(()), v=jnp.zeros(p.body.N), lengths=zeros, lbar=zeros, **signals)
        return gait.control(s, p.body)

    signals = {name: jnp.zeros(()) for name in CRACK_SENSORS}
    jaxpr = jax.make_jaxpr(u)(signals).jaxpr
    return _reaches(jaxpr, jaxpr.invars, jaxpr.outvars)


def _reaches(jaxpr, inputs, outputs) -> bool:
    """Whether any of `outputs` is computed from any of `inputs` in `jaxpr` (each
    equation taken whole: an output of an equation with a reached input is reached)."""
    reached = set(inputs)
    for eqn in jaxpr.eqns:
        if eqn.primitive.name == "stop_gradient":
            continue
        if any(isinstance(v, jex.Var) and v in reached for v in eqn.invars):
            reached.update(eqn.outvars)
    return any(isinstance(v, jex.Var) and v in reached for v in outputs)


def vector_field_stiff(
    t: Float[ArrayLike, ""], y: WormState, args: tuple[Params, Scalar]
) -> WormState:
    """The stiff part: ẋ = v, v̇ = −ℳ⁻¹(𝒱_s − ℱ_f), and the friction dissipation rate."""
    p, _ = args
    f_s, f_f = _stiff_forces(y, p)
    dwork = jnp.stack([0.0, -jnp.sum(f_f * y.v), 0.0, 0.0])
    return WormState(
        x=y.v, v=(f_f - f_s) / p.body.node_masses, lbar=jnp.zeros_like(y.lbar), work=dwork
    )


def vector_field_nonstiff(
    t: Float[ArrayLike, ""], y: WormState, args: tuple[Params, Scalar]
) -> WormState:
    """The non-stiff part: l̄' = u (eq. 23), −ℳ⁻¹ℱ_p (eq. 22), actuation and back-pressure work."""
    p, x_c = args
    b = p.body
    u = control_rate(t, y, x_c, p)
    f_p = _back_pressure(y, x_c, p)
    dv = jnp.zeros_like(y.v).at[0].set(-f_p / b.node_masses[0])
    dwork = actuation_work_rates(y.x, y.lbar, u, b) + jnp.stack([0.0, 0.0, f_p * y.v[0], 0.0])
    return WormState(x=jnp.zeros_like(y.x), v=dv, lbar=u, work=dwork)


def actuation_work_rates(x, lbar, u, body: Body) -> Float[Array, " 4"]:
    """The rates of the work integrals that the control u drives, from the actuation
    power P = ∂V/∂l̄·u (`actuation_work_of_power`)."""
    return actuation_work_of_power(phys.actuation_power(x, lbar, u, body.EA))


def actuation_work_of_power(power: Scalar) -> Float[Array, " 4"]:
    """P (the net actuation work's rate) and |P| (the gross work's) in the places of
    `WormState.work` (net actuation, friction, back pressure, gross actuation); 0 in the
    others."""
    return jnp.stack([power, 0.0, 0.0, jnp.abs(power)])


def vector_field(t: Float[ArrayLike, ""], y: WormState, args: tuple[Params, Scalar]) -> WormState:
    """d/dt (x, v, l̄) = (v, −ℳ⁻¹(𝒱_s − ℱ_f + ℱ_p), u) (eqs. 18-23), plus the work rates.

    `args` is `(params, x_c)`.
    """
    a, b = vector_field_stiff(t, y, args), vector_field_nonstiff(t, y, args)
    return jax.tree_util.tree_map(jnp.add, a, b)


def crack_condition(
    t: Float[ArrayLike, ""], y: WormState, args: tuple[Params, Scalar], **kwargs
) -> Float[Array, ""]:
    """K_I / K_Ic(x_c) − 1: the crack event is its upward zero crossing (eq. 12).

    x_c is constant between events, so for soil that varies K_Ic(x_c) and the E_s(x_c)
    of K_I are too: the condition is as continuous in time as for homogeneous soil."""
    p, x_c = args
    return _stress_ratio(y, x_c, p) - 1.0


#: A segment or intrinsic length at or below this fraction of l_0 counts as collapsed
#: (`body_collapsed`): 10 nm for Table 1's body, a strain of −(1 − 1e-6). Zero itself
#: can be out of reach: the tension's stiffness EA/l̄ grows without bound on the way,
#: and a solve with forward sensitivities was seen to shrink its steps with l̄ until
#: time stood still at l̄ ~ 1e-19 m.
COLLAPSE_FRACTION = 1e-6


def body_collapsed(y: WormState, body: Body) -> Bool[Array, ""]:
    """Whether a segment length l^k = x_k − x_{k+1} or an intrinsic length l̄^k is at
    or below `COLLAPSE_FRACTION`·l_0: the body has collapsed. The tension
    EA(l^k/l̄^k − 1) of eq. (20) is singular at l̄^k = 0; past it the lengths run away
    and no step the solver takes means anything."""
    floor = COLLAPSE_FRACTION * body.l0
    return (jnp.min(phys.segment_lengths(y.x)) <= floor) | (jnp.min(y.lbar) <= floor)


def collapse_condition(
    t: Float[ArrayLike, ""], y: WormState, args: tuple[Params, Scalar], **kwargs
) -> Bool[Array, ""]:
    """`body_collapsed` as a boolean event condition: the solve stops at the end of the
    first step whose state has collapsed."""
    p, _ = args
    return body_collapsed(y, p.body)


def _stress_ratio(y: WormState, x_c: Scalar, p: Params) -> Float[Array, ""]:
    """K_I/K_Ic(x_c) (eq. 12): the crack jumps at 1."""
    return stress_intensity_of(y, x_c, p) / value_at(p.soil.K_Ic, x_c)


def crack_jump(y: WormState, p: Params, x_c: Scalar | None = None) -> Float[Array, ""]:
    """The new tip x_c(t_{n+1}) where K_I falls to K_Ith (eq. 13).

    For soil that varies (E_s or K_Ith a profile) the crack runs from the old tip `x_c`
    (from the head when None) to the first x with K_I(x) ≤ K_Ith(x) (`arrest_tip`);
    for homogeneous soil `x_c` is not used."""
    b, s = p.body, p.soil
    E_s, K_Ith = s.E_s, s.K_Ith
    if isinstance(E_s, AbstractProfile) or isinstance(K_Ith, AbstractProfile):
        start = y.x[0] if x_c is None else x_c
        return arrest_tip(y.x[0], y.x[0] - y.x[1], start, E_s, K_Ith, s.nu, b.w0, b.l0)
    return phys.crack_tip_after_jump(y.x[0], y.x[0] - y.x[1], K_Ith, E_s, s.nu, b.w0, b.l0)

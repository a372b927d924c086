"""Forward sensitivities integrated by the Rosenbrock method alongside the state.

For parameters θ (P directions in parameter space), the sensitivities S = ∂y/∂θ obey
the linear variational equation

    Ṡ = J S + ∂f/∂θ,   J = ∂f/∂y,

which `Rodas4Sensitivity` integrates with the state, step for step, as RODAS applied to
the augmented system (y, S). The augmented Jacobian is block lower-triangular,
[[J, 0], [H, J]] with H = ∂(J S + ∂f/∂θ)/∂y, so every stage reuses the state's
factorisation of (I/(γh) − J): the sensitivities cost back-substitutions and
directional derivatives, not factorisations. With `hessian=True` the H·k term of the
exact augmented Jacobian enters the sensitivity stages (second directional
derivatives); with `hessian=False` it is dropped (a W-method on the sensitivities).

The crack tip x_c is a parameter of the vector field between events; its sensitivity
`s_c` (P,) rides in `args` and enters through ∂f/∂x_c. The jump conditions at an event
are in `event_jump`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import ClassVar

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
from jax.flatten_util import ravel_pytree
from jaxtyping import Array, Float

from ._rosenbrock import (
    RODAS4,
    AbstractRosenbrock,
    RosenbrockTableau,
    hermite_slopes,
    looped_stages,
    refusing,
)

__all__ = [
    "Rodas4Sensitivity",
    "sensitivity_field",
    "state_and_sensitivity_field",
    "event_jump",
    "split_params",
    "at_fixed_time",
    "Frame",
]


class SecondDerivativeError(TypeError):
    """Raised when the forward-sensitivity solve is itself differentiated: a second
    derivative of `simulate` with the Rosenbrock solver (`jax.hessian`, `jax.grad` of
    `jax.grad`). Take it by finite differences of the gradient, or differentiate a
    diffrax solver twice."""


_no_second_derivative = refusing(
    SecondDerivativeError,
    (
        "second derivatives of simulate with the Rosenbrock solver (preset 'fast') are not "
        "available: the first derivative is a forward-sensitivity solve, and differentiating "
        "its Rosenbrock steps is not their sensitivity (docs: Gradients). Take second "
        "derivatives by finite differences of the gradient, or differentiate a diffrax "
        "solver twice (crack_sensitivity='exact' or 'tips_held')."
    ),
)


def split_params(params, dp):
    """(perturbed part, rest) of `params`, the first structured as the directions `dp`
    (None where a leaf is not perturbed), so derivatives are taken along those only."""
    mask = jax.tree_util.tree_map(lambda d: d is not None, dp, is_leaf=lambda x: x is None)
    return eqx.partition(params, mask)


class Frame(eqx.Module):
    """Where the sensitivities are integrated: S̃ = S − r φ(t) f, f the vector field.

    `rate` r (P,): dω/ω along each direction, the relative change of the gait
    frequency (0: at fixed time). With φ(t) = t, S̃ are the sensitivities at fixed gait
    phase τ = ωt: along a frequency change the state at fixed t moves with the phase,
    a term t ẏ/ω that grows with t and carries every fast feature of ẏ, while at fixed
    phase the response is small. Any φ gives the same S once converted back
    (`at_fixed_time`); φ only changes what the step control sees. At fixed phase S̃ is
    driven by −r f, whose elastic ringing the state's steps jump (positions norm), and
    at the start, while the ringing of the start-up lasts, the sensitivities' error
    control then takes many short steps. So the frame turns from fixed time to fixed
    phase over the first few `ramp` t_s seconds:

        φ(t) = t (1 − e^{−t/t_s}),   φ' = 1 − e^{−t/t_s} + (t/t_s) e^{−t/t_s},

    φ(0) = φ'(0) = 0, and φ − t vanishes after a few t_s (an offset r (φ − t) f left
    in S̃ would carry f's ringing for the whole run). `ramp` 0 is the plain phase
    frame, φ = t.
    """

    rate: Float[Array, " P"]
    ramp: Float[Array, ""]

    def _x(self, t):
        """t/t_s, and whether the ramp is on (t_s > 0)."""
        on = self.ramp > 0
        return t / jnp.where(on, self.ramp, 1.0), on

    def phi(self, t):
        """φ(t)."""
        x, on = self._x(t)
        return jnp.where(on, -t * jnp.expm1(-x), t)

    def slope(self, t):
        """φ'(t)."""
        x, on = self._x(t)
        return jnp.where(on, x * jnp.exp(-x) - jnp.expm1(-x), 1.0)


def sensitivity_field(vf, t, y, S, args):
    """Ṡ̃_j = J S̃_j + ∂f/∂θ·dθ_j + ∂f/∂x_c·s_c,j − r_j (φ ∂f/∂t + φ' f), each direction j.

    The sensitivities in the `Frame` (r, φ): S̃ = S − r φ f (r = 0: at fixed time).
    `vf(t, y, (params, x_c))` is the state's vector field; `args` is
    `(pd, pr, x_c, dp, s_c, frame)`: the parameters split (`split_params`) into the
    perturbed part `pd` and the rest `pr`, the tip, the parameter directions `dp`
    (structured as `pd`, leading axis P), the tip's sensitivities `s_c` (P,) and the
    `Frame`. `y` and `S` are pytrees, S with a leading axis P.
    """
    return state_and_sensitivity_field(vf, t, y, S, args)[1]


def state_and_sensitivity_field(vf, t, y, S, args):
    """(f, Ṡ): the state's vector field and `sensitivity_field`, f evaluated once (it is
    the primal of every direction's JVP)."""
    pd, pr, x_c, dp, s_c, frame = args
    phi, slope = frame.phi(t), frame.slope(t)

    def one(Sj, dpj, scj, rj):
        f, df = jax.jvp(
            lambda t_, y_, d_, c_: vf(t_, y_, (eqx.combine(d_, pr), c_)),
            (t, y, pd, x_c),
            (-phi * rj, Sj, dpj, scj),
        )
        return f, jax.tree_util.tree_map(lambda a, b: a - (rj * slope) * b, df, f)

    return jax.vmap(one, out_axes=(None, 0))(S, dp, s_c, frame.rate)


def at_fixed_time(S, phi, f, r):
    """Sensitivities at fixed time from those in a `Frame`: S = S̃ + r φ f, `phi` the
    frame's φ at that time."""
    return _shifted(S, r * phi, f)


def _shifted(S, dt, f):
    """S + dt_j f for each direction j."""
    return jax.tree_util.tree_map(lambda s, a: s + dt.reshape((-1,) + (1,) * a.ndim) * a, S, f)


class Rodas4Sensitivity(AbstractRosenbrock):
    """RODAS on the state and its forward sensitivities; state (y, S).

    `factor` factorises σI − J for the state (see `jaxworm._rosenbrock`). `vf` is the
    state's vector field `vf(t, y, (params, x_c))`. `hessian`: keep the H·k term of
    the augmented Jacobian (see the module docstring). The stages always run as one
    loop (`looped_stages`; `looped` is not read): this step is costly enough that the
    loop runs and compiles faster than the unrolled stages.
    """

    vf: Callable | None = eqx.field(static=True, default=None)
    hessian: bool = eqx.field(static=True, default=True)

    tableau: ClassVar[RosenbrockTableau] = RODAS4

    def step(self, terms, t0, t1, z0, args, solver_state, made_jump):
        del solver_state, made_jump, terms
        tab, vf = self.tableau, self.vf
        assert vf is not None, "Rodas4Sensitivity needs the state's vector field `vf`"
        zero = t1 == t0
        h = jnp.where(zero, 1e-6, t1 - t0)
        t1 = jnp.where(zero, t0 + h, t1)
        y0, S0 = z0
        p, x_c = eqx.combine(args[0], args[1]), args[2]
        flat0, unravel = ravel_pytree(y0)
        unravel_S = jax.vmap(unravel)
        ravel_S = jax.vmap(lambda s: ravel_pytree(s)[0])
        S0f = ravel_S(S0)

        def f(t, yf):
            return ravel_pytree(vf(t, unravel(yf), (p, x_c)))[0]

        def f_z(t, z):  # (f, Ṡ), f shared by the sensitivities' JVPs
            fz, sz = state_and_sensitivity_field(vf, t, unravel(z[0]), unravel_S(z[1]), args)
            return ravel_pytree(fz)[0], ravel_S(sz)

        # One linearisation of (f, Ṡ) at (t0, y0) gives their values, their time
        # derivatives and, applied to a state increment, the H·k term.
        (f0, fs0), fz_lin = jax.linearize(lambda t, yf: f_z(t, (yf, S0f)), t0, flat0)
        f_t, fs_t = fz_lin(jnp.ones_like(t0), jnp.zeros_like(flat0))
        solve = self.factor(lambda yf: f(t0, yf), t0, flat0, 1.0 / (tab.gamma * h), y0, (p, x_c))

        def h_times(k):
            return fz_lin(jnp.zeros_like(t0), k)[1]

        def solve_z(r):
            k = solve(r[0])
            return k, solve(r[1] + h_times(k) if self.hessian else r[1])

        (y1f, S1f), (err, err_s), (q2, q3) = looped_stages(
            tab, h, t0, (flat0, S0f), (f0, fs0), (f_t, fs_t), f_z, solve_z
        )
        finite = jnp.all(jnp.isfinite(y1f)) & jnp.all(jnp.isfinite(S1f))
        err = jnp.where(finite, err, jnp.inf)
        err_s = jnp.where(finite, err_s, jnp.inf)
        # Differentiating these steps (a second derivative of simulate) would take the
        # discrete derivative that `_rosenbrock` explains is wrong: refuse instead.
        y1f = _no_second_derivative(jnp.where(zero, flat0, y1f))
        S1f = _no_second_derivative(jnp.where(zero, S0f, S1f))
        err = jnp.where(zero, 0.0, err)
        err_s = jnp.where(zero, 0.0, err_s)
        z1 = (unravel(y1f), unravel_S(S1f))
        if self.interpolant == "hermite":
            (k0, k0s), (k1, k1s) = (f0 * h, fs0 * h), (k * h for k in f_z(t1, (y1f, S1f)))
        else:
            k0, k1 = hermite_slopes(flat0, y1f, q2[0], q3[0])
            k0s, k1s = hermite_slopes(S0f, S1f, q2[1], q3[1])
        k0, k1, k0s, k1s = (jnp.where(zero, 0.0, k) for k in (k0, k1, k0s, k1s))
        dense_info = dict(
            y0=z0,
            y1=z1,
            k0=(unravel(k0), unravel_S(k0s)),
            k1=(unravel(k1), unravel_S(k1s)),
        )
        return z1, (unravel(err), unravel_S(err_s)), dense_info, None, diffrax.RESULTS.successful


def event_jump(vf, condition, jump, t, y, S, pd, pr, x_c, dp, s_c, r, mode: str, frame: Frame):
    """Sensitivities across a crack event at time t (state y, S = ∂y/∂θ just before).

    The event time moves by dt = −(∂g/∂y S + ∂g/∂x_c s_c + ∂g/∂θ dθ)/(∂g/∂y f⁻) (g the
    event function), the state's total sensitivity at the event is Y = S + f⁻ dt, the
    new tip's is ∂c/∂y Y + ∂c/∂θ dθ (c = eq. 13), and the sensitivities continue from
    S⁺ = Y − f⁺ dt, f∓ the vector field with the old and the new tip.

    `mode`: `"exact"` as above; `"tips_held"` holds the new tip's sensitivity at 0;
    `"schedule_held"` holds every crack at its gait phase, dt = −t r with r = dω/ω
    along each direction (r = 0, the time held, for a gait without a frequency), and
    the tip follows the state by eq. (13).
    `S` comes in the `Frame` and S⁺ leaves in it.
    Returns (dt, Y, new tip, its sensitivities, S⁺), each with a leading axis P.
    """
    p = eqx.combine(pd, pr)
    f_minus = vf(t, y, (p, x_c))
    S = at_fixed_time(S, frame.phi(t), f_minus, frame.rate)
    if mode == "schedule_held":
        dt = -t * r
    else:
        g_dot = jax.jvp(lambda y_: condition(t, y_, (p, x_c)), (y,), (f_minus,))[1]

        def directional(Sj, dpj, scj):
            return jax.jvp(
                lambda y_, d_, c_: condition(t, y_, (eqx.combine(d_, pr), c_)),
                (y, pd, x_c),
                (Sj, dpj, scj),
            )[1]

        dt = -jax.vmap(directional)(S, dp, s_c) / g_dot
    Y = _shifted(S, dt, f_minus)
    tip = jump(y, p, x_c)
    s_tip = jax.vmap(
        lambda Yj, dpj: jax.jvp(
            lambda y_, d_: jump(y_, eqx.combine(d_, pr), x_c), (y, pd), (Yj, dpj)
        )[1]
    )(Y, dp)
    if mode == "tips_held":
        s_tip = jnp.zeros_like(s_tip)
    f_plus = vf(t, y, (p, tip))
    S_plus = _shifted(Y, -dt, f_plus)
    return dt, Y, tip, s_tip, _shifted(S_plus, -frame.rate * frame.phi(t), f_plus)

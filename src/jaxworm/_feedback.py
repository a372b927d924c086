"""Closed-loop controllers: the intrinsic-length rates from what the robot measures.

An `AbstractFeedbackController` gives u = d l̄/dt (eq. 23) from the `Sensors` of the
instant, the back pressure and the stress intensity at the crack tip included, which
a plain `AbstractController` (u from t, x, v, l̄) cannot see. Two are provided:

- `ReflexWave`: the travelling wave of eqs. (24)-(25) whose amplitude and phase offset
  follow the measured resistance (K_I/K_Ic) and the head's speed; six numbers.
- `PolicyMLP`: a small equinox MLP from the gait phase and the sensors to the rates,
  bounded by |u_k| ≤ `A_max`.

Both are periodic in time (their clock is the phase ωt), so runs over whole periods and
the phase-held crack derivative apply to them as to the open-loop wave.
"""

from __future__ import annotations

import abc
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, PRNGKeyArray

from ._control import AbstractController, TravellingWave, sines_of_multiples
from ._sensors import SensorNoise, Sensors
from ._validation import check_instance, check_int, check_range, to_float

__all__ = ["AbstractFeedbackController", "ReflexWave", "PolicyMLP"]


def _check_noise(noise) -> None:
    if noise is not None:
        check_instance("noise", noise, SensorNoise, "SensorNoise(jax.random.key(0), 1e-3)")


class AbstractFeedbackController(AbstractController):
    """A control law u(`Sensors`) for the intrinsic lengths, l̄' = u (eq. 23).

    Subclass it and implement `control`; the solver passes it the sensors of each
    instant. A field `noise: SensorNoise | None` adds noise to them (`measure`).

    ```python
    class Brake(AbstractFeedbackController):
        def control(self, s, body):
            k = jnp.arange(1, body.N)
            phase = 4 * jnp.pi * s.t - k
            lengths = body.l0 + 0.02 / (4 * jnp.pi) * (jnp.cos(k) - jnp.cos(phase))
            brake = 1.0 - 0.5 * jnp.clip(s.stress_ratio, 0.0, 1.0)
            return brake * 0.02 * jnp.sin(phase) - 4 * jnp.pi * (s.lbar - lengths)
    ```

    Keep the intrinsic lengths bounded: a rate that follows the sensors within a gait
    period ratchets them away unless something pulls them back (here, and in
    `ReflexWave` and `PolicyMLP`, a leak towards the open-loop wave's lengths).
    """

    open_loop: ClassVar[bool] = False

    @abc.abstractmethod
    def control(self, sensors: Sensors, body) -> Float[Array, " S"]:
        """Rate of change of the intrinsic lengths [m/s], one per segment."""

    def measure(self, sensors: Sensors) -> Sensors:
        """The sensors as this controller reads them: with its `noise` field's noise,
        if it has one that is not None."""
        noise = getattr(self, "noise", None)
        return sensors if noise is None else noise(sensors)

    def __call__(self, t, x, v, lbar, body):
        raise TypeError(
            f"a {type(self).__name__} reads the crack (back pressure, K_I/K_Ic): call its "
            "control(sensors, body), or let jaxworm.simulate / jaxworm.forces call it"
        )


def _sigmoid_gain(z):
    """2·sigmoid(z): 1 at z = 0, between 0 and 2."""
    return 2.0 * jax.nn.sigmoid(z)


class ReflexWave(AbstractFeedbackController):
    """The travelling wave with reflexes: for the segments k = 1..N−1,

        u_k = A_eff sin(ω t + δ_eff k) − κ (l̄_k − l̄°_k(t)),
        A_eff = A · 2σ(g_K (K_I/K_Ic − r_0) + g_v v_1/A),   δ_eff = δ + g_δ (K_I/K_Ic − r_0),

    σ the logistic function, l̄° the intrinsic lengths of the open-loop wave
    `TravellingWave(A, ω, δ)` (rest start) and κ = `leak`·ω. With the gains at 0 it is
    that wave exactly. A_eff < 2A whatever the sensors say. The leak keeps the lengths
    within 3A/κ of the wave's: an amplitude that follows the sensors within a period
    would otherwise ratchet the lengths away (they drifted until the solve failed).

    - `A`, `omega`, `delta`: the wave's amplitude [m/s], angular frequency [rad/s] and
      phase offset [rad], as `TravellingWave`.
    - `gain_stress` (g_K): amplitude reflex to the resistance ahead, K_I/K_Ic. Default 0.
    - `gain_speed` (g_v): amplitude reflex to the head's speed v_1 (in units of A).
      Default 0.
    - `gain_phase` (g_δ): phase-offset reflex to K_I/K_Ic [rad]. Default 0.
    - `stress_ref` (r_0): the K_I/K_Ic at which the stress reflexes are neutral. Default 0.5.
    - `leak`: κ/ω, how fast the lengths return to the wave's. Default 1.
    - `noise`: `SensorNoise` or None (default).
    """

    A: Float[Array, ""] = eqx.field(default=0.02, converter=to_float)
    omega: Float[Array, ""] = eqx.field(default=4 * jnp.pi, converter=to_float)
    delta: Float[Array, ""] = eqx.field(default=jnp.pi / 4, converter=to_float)
    gain_stress: Float[Array, ""] = eqx.field(default=0.0, converter=to_float)
    gain_speed: Float[Array, ""] = eqx.field(default=0.0, converter=to_float)
    gain_phase: Float[Array, ""] = eqx.field(default=0.0, converter=to_float)
    stress_ref: Float[Array, ""] = eqx.field(default=0.5, converter=to_float)
    leak: Float[Array, ""] = eqx.field(default=1.0, converter=to_float)
    noise: SensorNoise | None = None

    def __check_init__(self):
        check_range("A", self.A, lambda v: v >= 0, ">= 0")
        check_range("omega", self.omega, lambda v: v > 0, "> 0")
        check_range("leak", self.leak, lambda v: v > 0, "> 0")
        for name in ("delta", "gain_stress", "gain_speed", "gain_phase", "stress_ref"):
            check_range(name, getattr(self, name), lambda v: v == v, "a real number")
        _check_noise(self.noise)

    def control(self, sensors, body):
        s = self.measure(sensors)
        r = s.stress_ratio - self.stress_ref
        amplitude = self.A * _sigmoid_gain(
            self.gain_stress * r + self.gain_speed * s.v[0] / jnp.maximum(self.A, 1e-12)
        )
        # sin(ωt + δk + g_δ r k) from the wave's sin and cos(ωt + δk) and those of g_δ r k.
        S = body.N - 1
        wave = TravellingWave(A=self.A, omega=self.omega, delta=self.delta)
        sin_shift, cos_shift = sines_of_multiples(self.gain_phase * r, S)
        rate = amplitude * (wave.sine(s.t, S) * cos_shift + wave.sine(s.t, S, "cos") * sin_shift)
        return rate - self.leak * self.omega * (s.lbar - wave.intrinsic_lengths(s.t, body))

    def valid(self):
        leaves = (self.A, self.delta, self.gain_stress, self.gain_speed, self.gain_phase)
        finite = jnp.all(jnp.stack([jnp.isfinite(x) for x in leaves]))
        positive = (self.omega > 0) & (self.A >= 0) & (self.leak > 0)
        return finite & positive & jnp.isfinite(self.stress_ref)

    def stroke_speed(self, body, t1):
        """(N − 1)·5A: |A_eff sin| < 2A, and the leak term adds at most κ·3A/κ."""
        return (body.N - 1) * 5.0 * jnp.abs(self.A)

    def period(self):
        """2π/ω: u depends on time through the phase ωt only."""
        return 2 * jnp.pi / self.omega

    def frequency(self):
        """ω."""
        return self.omega

    def placeholder(self):
        return ReflexWave(noise=self.noise)


#: The features `PolicyMLP` feeds its network: how many, and their names.
POLICY_FEATURES = (
    "sin(ωt)",
    "cos(ωt)",
    "head velocity / A_max",
    "mean velocity / A_max",
    "K_I/K_Ic",
    "head strain (l_1 − l̄_1)/l_0 × 10",
)


def _policy_features(s: Sensors, omega, A_max, l0) -> Float[Array, " F"]:
    phase = omega * s.t
    return jnp.stack(
        [
            jnp.sin(phase),
            jnp.cos(phase),
            s.v[0] / A_max,
            jnp.mean(s.v) / A_max,
            s.stress_ratio,
            10.0 * (s.lengths[0] - s.lbar[0]) / l0,
        ]
    )


def mlp_by_products(mlp: eqx.nn.MLP, x: Float[Array, " F"]) -> Array:
    """`mlp(x)`, each layer's W x + b written as a product and a sum.

    The same function as equinox's `MLP.__call__` (to rounding), for vector inputs and
    outputs and unscanned layers; anything else (a subclass with its own `__call__`
    among them) is passed to `mlp` itself. On a CPU a matrix product is a library call
    of its own, several per solver step for a small policy, where a product and a sum
    fuse with the code around them."""
    if (
        type(mlp).__call__ is not eqx.nn.MLP.__call__  # not an MLP, or its own call
        or getattr(mlp, "scan", False)
        or "scalar" in (mlp.in_size, mlp.out_size)
    ):
        return mlp(x)

    def linear(layer, z):
        out = jnp.sum(layer.weight * z[None, :], axis=-1)
        return out if layer.bias is None else out + layer.bias

    if len(mlp.layers) == 1:  # depth 0: equinox applies no activation at all
        return linear(mlp.layers[0], x)
    apply = eqx.filter_vmap(lambda a, b: a(b))
    for i, layer in enumerate(mlp.layers[:-1]):
        x = linear(layer, x)
        x = apply(_layer_activation(mlp.activation, i), x)
    return apply(mlp.final_activation, linear(mlp.layers[-1], x))


def _layer_activation(activation, i: int):
    """Layer i's activation: equinox stores one per hidden layer, stacked in its arrays."""
    return jax.tree_util.tree_map(lambda a: a[i] if eqx.is_array(a) else a, activation)


class PolicyMLP(AbstractFeedbackController):
    """A neural policy: for the segments k = 1..N−1,

        u_k = A_max tanh(b sin(ω t + δ k) + m_k(features) − κ (l̄_k − l̄°_k(t))/A_max),

    m an `equinox.nn.MLP` of the features `POLICY_FEATURES` (gait phase, head and mean
    velocity, K_I/K_Ic, head strain), l̄° the intrinsic lengths of the open-loop wave
    A_max sin(ωt + δk) from rest and κ = `leak`·ω. |u_k| ≤ `A_max` always; the leak keeps
    the lengths near the wave's (without it a state-dependent rate ratchets them away).

    Built with its last layer at zero, so that it starts as a bounded travelling wave
    (b sin, squashed); training moves every weight.

    - `mlp`: the network (features → N − 1 rates before the squashing).
    - `omega`, `delta`, `b`: the underlying wave's frequency [rad/s], phase offset [rad]
      and gain.
    - `A_max`: the rate bound [m/s].
    - `leak`: κ/ω. Default 1.
    - `feedback`: static; False zeroes the sensor features, leaving an open-loop policy
      of the phase alone (the same network shape, for comparisons). Default True.
    - `noise`: `SensorNoise` or None.

    `PolicyMLP.init(key, N, width=8, depth=1, omega=…, delta=…, A_max=…)` builds one.
    """

    mlp: eqx.nn.MLP
    omega: Float[Array, ""] = eqx.field(converter=to_float)
    delta: Float[Array, ""] = eqx.field(converter=to_float)
    b: Float[Array, ""] = eqx.field(converter=to_float)
    A_max: Float[Array, ""] = eqx.field(converter=to_float)
    leak: Float[Array, ""] = eqx.field(default=1.0, converter=to_float)
    feedback: bool = eqx.field(static=True, default=True)
    noise: SensorNoise | None = None

    def __check_init__(self):
        check_range("omega", self.omega, lambda v: v > 0, "> 0")
        check_range("leak", self.leak, lambda v: v > 0, "> 0")
        if not isinstance(self.feedback, bool):
            raise TypeError(f"option feedback = {self.feedback!r}: need True or False")
        check_range("A_max", self.A_max, lambda v: v > 0, "> 0")
        check_range("delta", self.delta, lambda v: v == v, "a real number")
        check_range("b", self.b, lambda v: v == v, "a real number")
        _check_noise(self.noise)

    @classmethod
    def init(
        cls,
        key: PRNGKeyArray,
        N: int,
        *,
        width: int = 8,
        depth: int = 1,
        omega=4 * jnp.pi,
        delta=-jnp.pi / 4,
        b: float = 1.0,
        A_max: float = 0.03,
        feedback: bool = True,
        noise: SensorNoise | None = None,
    ) -> PolicyMLP:
        """A policy for a body of N nodes that starts as the squashed wave
        A_max tanh(b sin(ω t + δ k)): random hidden layers, a zero last layer."""
        if isinstance(N, bool) or not isinstance(N, int | np.integer) or N < 2:
            raise ValueError(f"parameter N = {N!r}: need an integer >= 2")
        check_int("width", width, 1, None, kind="option")
        check_int("depth", depth, 0, None, kind="option")
        N = int(N)
        mlp = eqx.nn.MLP(
            len(POLICY_FEATURES), N - 1, width, depth, activation=jnp.tanh, key=key, dtype=float
        )
        mlp = eqx.tree_at(
            lambda m: (m.layers[-1].weight, m.layers[-1].bias),
            mlp,
            (jnp.zeros((N - 1, width if depth else len(POLICY_FEATURES))), jnp.zeros(N - 1)),
        )
        return cls(
            mlp=mlp, omega=omega, delta=delta, b=b, A_max=A_max, feedback=feedback, noise=noise
        )

    def control(self, sensors, body):
        if self.mlp.out_size != body.N - 1:
            raise ValueError(
                f"PolicyMLP: its network gives {self.mlp.out_size} rates, one per segment; "
                f"this body has N = {body.N} nodes, {body.N - 1} segments: build the "
                f"policy with PolicyMLP.init(key, {body.N})"
            )
        s = self.measure(sensors)
        l0 = body.l0
        features = _policy_features(s, self.omega, self.A_max, l0)
        if not self.feedback:
            features = features * jnp.array([1.0, 1.0] + [0.0] * (len(POLICY_FEATURES) - 2))
        wave = TravellingWave(A=self.A_max, omega=self.omega, delta=self.delta)
        squashed = self.b * wave.sine(s.t, body.N - 1)
        restore = self.leak * self.omega * (s.lbar - wave.intrinsic_lengths(s.t, body))
        net = mlp_by_products(self.mlp, features)
        return self.A_max * jnp.tanh(squashed + net - restore / self.A_max)

    def valid(self):
        leaves = jax.tree_util.tree_leaves(eqx.filter(self.mlp, eqx.is_inexact_array))
        finite = jnp.all(jnp.stack([jnp.all(jnp.isfinite(x)) for x in leaves]))
        positive = (self.omega > 0) & (self.A_max > 0) & (self.leak > 0)
        return finite & positive & jnp.isfinite(self.b + self.delta)

    def placeholder(self):
        """The same network with zero weights, ω = 4π, δ = 0, b = 1, A_max = 0.03 and
        leak 1: valid values of this structure (see `AbstractController.placeholder`)."""
        mlp = jax.tree_util.tree_map(
            lambda x: jnp.zeros_like(x) if eqx.is_inexact_array(x) else x, self.mlp
        )
        return PolicyMLP(
            mlp=mlp,
            omega=4 * jnp.pi,
            delta=0.0,
            b=1.0,
            A_max=0.03,
            feedback=self.feedback,
            noise=self.noise,
        )

    def stroke_speed(self, body, t1):
        """(N − 1)·A_max: no rate exceeds A_max."""
        return (body.N - 1) * self.A_max

    def period(self):
        """2π/ω: u depends on time through the phase ωt only."""
        return 2 * jnp.pi / self.omega

    def frequency(self):
        """ω."""
        return self.omega

"""What a burrowing robot can measure, and the noise on it.

`Sensors` holds the signals a closed-loop controller (`AbstractFeedbackController`) sees
at one instant: node velocities, segment lengths, the intrinsic lengths it commands, the
back pressure on the head (eq. 16) and the stress intensity at the crack tip relative to
the soil's toughness, K_I/K_Ic (eq. 12), a proxy for how close the next crack is.
`SensorNoise` adds seeded band-limited Gaussian noise to them, a smooth function of time,
so that a noisy run is as reproducible and as differentiable as a clean one.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PRNGKeyArray

from ._validation import check_int, check_range, to_float

__all__ = ["Sensors", "SensorNoise", "band_limited_noise"]


class Sensors(eqx.Module):
    """The signals of one instant (units SI).

    - `t`: time [s].
    - `v`: node velocities [m/s] (N,), head first; `v[0]` is the head's.
    - `lengths`: segment lengths l_k = x_k − x_{k+1} [m] (N − 1,).
    - `lbar`: intrinsic lengths l̄_k the actuators hold [m] (N − 1,).
    - `back_pressure`: F_p on the head [N] (eq. 16), ≥ 0.
    - `stress_ratio`: K_I/K_Ic at the crack tip (eq. 12); the crack jumps at 1.
    """

    t: Float[Array, ""]
    v: Float[Array, " N"]
    lengths: Float[Array, " S"]
    lbar: Float[Array, " S"]
    back_pressure: Float[Array, ""]
    stress_ratio: Float[Array, ""]


def band_limited_noise(
    key: PRNGKeyArray, t, shape: tuple[int, ...], bandwidth, modes: int
) -> Float[Array, " *shape"]:
    """Independent unit-variance Gaussian processes of time, one per element of `shape`:
    n(t) = √(2/M) Σ_j cos(ω_j t + φ_j), ω_j ~ U(0, `bandwidth`), φ_j ~ U(0, 2π), M = `modes`.

    Over keys n(t) has mean 0 and variance 1 at every t, and a flat spectrum up to
    `bandwidth` [rad/s]; for one key it is smooth in t, so an adaptive solver steps
    through it. The same key gives the same signal."""
    k_freq, k_phase = jax.random.split(key)
    freq = bandwidth * jax.random.uniform(k_freq, shape + (modes,))
    phase = 2 * jnp.pi * jax.random.uniform(k_phase, shape + (modes,))
    return jnp.sqrt(2.0 / modes) * jnp.sum(jnp.cos(freq * t + phase), axis=-1)


def _is_key(key) -> bool:
    """Whether `key` is a JAX random key: a typed one (`jax.random.key`), or a raw one
    (`jax.random.PRNGKey`: uint32, last axis 2), traced or not."""
    dtype = getattr(key, "dtype", None)
    if dtype is None:
        return False
    if jnp.issubdtype(dtype, jax.dtypes.prng_key):
        return True
    return dtype == jnp.uint32 and key.shape[-1:] == (2,)


class SensorNoise(eqx.Module):
    """Seeded noise on the sensors: each signal plus σ·n(t), n a unit band-limited
    Gaussian process per element (`band_limited_noise`), independent between signals.

    - `key`: the seed (`jax.random.key`); the same key, the same noise.
    - `velocity`: σ of the velocities [m/s]. Default 0.
    - `length`: σ of the segment lengths [m]. Default 0.
    - `stress_ratio`: σ of K_I/K_Ic. Default 0.
    - `back_pressure`: σ of log F_p (relative noise: F_p·exp(σ n)). Default 0.
    - `bandwidth`: highest noise frequency [rad/s]. Default 20π (10 Hz).
    - `modes`: static, cosines per signal. Default 16.

    Time and the commanded lengths l̄ are known exactly.
    """

    key: PRNGKeyArray
    velocity: Float[Array, ""] = eqx.field(default=0.0, converter=to_float)
    length: Float[Array, ""] = eqx.field(default=0.0, converter=to_float)
    stress_ratio: Float[Array, ""] = eqx.field(default=0.0, converter=to_float)
    back_pressure: Float[Array, ""] = eqx.field(default=0.0, converter=to_float)
    bandwidth: Float[Array, ""] = eqx.field(default=20 * jnp.pi, converter=to_float)
    modes: int = eqx.field(static=True, default=16)

    def __check_init__(self):
        if not _is_key(self.key):
            raise TypeError(
                f"option key = {self.key!r} ({type(self.key).__name__}): need a JAX random "
                "key, e.g. jax.random.key(0)"
            )
        for name in ("velocity", "length", "stress_ratio", "back_pressure"):
            check_range(name, getattr(self, name), lambda v: v >= 0, ">= 0")
        check_range("bandwidth", self.bandwidth, lambda v: v > 0, "> 0")
        check_int("modes", self.modes, 1, None, kind="option")

    def __call__(self, s: Sensors) -> Sensors:
        """The sensors as measured: `s` with this noise added."""
        k_v, k_l, k_k, k_p = jax.random.split(self.key, 4)

        def n(key, shape):
            return band_limited_noise(key, s.t, shape, self.bandwidth, self.modes)

        return Sensors(
            t=s.t,
            v=s.v + self.velocity * n(k_v, s.v.shape),
            lengths=s.lengths + self.length * n(k_l, s.lengths.shape),
            lbar=s.lbar,
            back_pressure=s.back_pressure * jnp.exp(self.back_pressure * n(k_p, ())),
            stress_ratio=s.stress_ratio + self.stress_ratio * n(k_k, ()),
        )

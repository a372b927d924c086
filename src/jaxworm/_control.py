"""Intrinsic-length control (§2.2, eq. 23) and the travelling-wave gait (eqs. 24-25).

A controller gives u = d l̄/dt, one entry per segment, from the time and the state, so
closed-loop controllers plug in the same way as the open-loop wave.
"""

from __future__ import annotations

import abc
from typing import ClassVar, Literal

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float

from ._physics import Scalar
from ._validation import check_range, to_float

__all__ = [
    "AbstractController",
    "TravellingWave",
    "whole_period_horizon",
    "HORIZONS",
    "simulated_horizon",
    "check_horizon",
    "mean_abs_sine",
]


class AbstractController(eqx.Module):
    """A control law u(t, x, v, l̄) for the intrinsic lengths, l̄' = u (eq. 23).

    Subclass it and implement `__call__`; override `lbar0` for another initial shape.

    ```python
    class HoldStill(AbstractController):
        def __call__(self, t, x, v, lbar, body):
            return jnp.zeros(body.N - 1)
    ```

    Set the class attribute `open_loop = True` when u depends on t alone: the
    Rosenbrock solvers then eliminate l̄ from their linear systems.
    """

    open_loop: ClassVar[bool] = False

    @abc.abstractmethod
    def __call__(
        self, t, x: Float[Array, " N"], v: Float[Array, " N"], lbar: Float[Array, " S"], body
    ) -> Float[Array, " S"]:
        """Rate of change of the intrinsic lengths [m/s], one per segment."""

    def lbar0(self, body) -> Float[Array, " S"]:
        """Intrinsic lengths at t = 0: l_0 for every segment (`MODEL.md`)."""
        return jnp.full(body.N - 1, 1.0) * body.l0

    def valid(self) -> Bool[Array, ""]:
        """Traced validity of the controller's own parameters."""
        return jnp.asarray(True)

    def stroke_speed(self, body, t1) -> Float[Array, ""] | None:
        """A bound on (1/t1) ∫_0^t1 Σ_k |u_k| dt [m/s]: how fast, on average over [0, t1],
        the controller changes the intrinsic lengths. It bounds the forward speed a gait
        can reach (`speed_bound`). `None` (the default) when unknown: no speed check."""
        return None

    def period(self) -> Float[Array, ""] | None:
        """The period T [s] of the control when it repeats in time, u(t + T, ·) = u(t, ·)
        for every state, else `None` (the default): not periodic.

        A run can then average over whole periods (`horizon="whole_periods"` of
        `simulate`, `sweep`, `optimise`), and a derivative can hold each crack at its
        phase of the period (`Numerics.crack_sensitivity`)."""
        return None

    def frequency(self) -> Float[Array, ""] | None:
        """The angular frequency ω = 2π/T [rad/s] of a periodic control (`period`), else
        `None`. Override it together with `period` when ω is the parameter, so that
        derivatives with respect to it are exact."""
        period = self.period()
        return None if period is None else 2 * jnp.pi / period

    def placeholder(self) -> AbstractController:
        """A valid controller of the same structure, run in place of this one for a lane
        whose parameters are invalid (that lane takes no step; see `simulate`). The
        default is the controller itself, whose values are then not checked."""
        return self


class TravellingWave(AbstractController):
    """The open-loop peristaltic wave of eqs. (24)-(25): u_k = A sin(ω t + δ k).

    One input per segment, k = 1..N−1 (segment k joins nodes k and k+1), as
    `MODEL.md` pins.

    - `A`: gait amplitude [m/s]. Default 0.02.
    - `omega`: angular frequency ω > 0 [rad/s]. Default 4π.
    - `delta`: phase offset δ between segments [rad]. Default π/4.
    - `offset`: static. `"rest"` (default): l̄^k(0) = l_0, so
      l̄^k(t) = l_0 + (A/ω)(cos δk − cos(ωt + δk)). `"centred"`: l̄^k(0) = l_0 − (A/ω) cos δk,
      so l̄^k oscillates about l_0 (another reading the paper allows).
    """

    open_loop: ClassVar[bool] = True

    A: Float[Array, ""] = eqx.field(default=0.02, converter=to_float)
    omega: Float[Array, ""] = eqx.field(default=4 * jnp.pi, converter=to_float)
    delta: Float[Array, ""] = eqx.field(default=jnp.pi / 4, converter=to_float)
    offset: Literal["rest", "centred"] = eqx.field(static=True, default="rest")

    def __check_init__(self):
        check_range("A", self.A, lambda v: v == v, "a real number")
        check_range("omega", self.omega, lambda v: v > 0, "> 0")
        check_range("delta", self.delta, lambda v: v == v, "a real number")
        if self.offset not in ("rest", "centred"):
            raise ValueError(f"option offset = {self.offset!r}: need 'rest' or 'centred'")

    def phase(self, t, n_segments: int) -> Float[Array, " S"]:
        """ψ_k(t) = ω t + δ k for k = 1..N−1 (eq. 25)."""
        k = jnp.arange(1, n_segments + 1)
        return self.omega * t + self.delta * k

    def __call__(self, t, x, v, lbar, body):
        return self.A * jnp.sin(self.phase(t, body.N - 1))

    def lbar0(self, body):
        if self.offset == "centred":
            return body.l0 - (self.A / self.omega) * jnp.cos(self.phase(0.0, body.N - 1))
        return super().lbar0(body)

    def intrinsic_lengths(self, t, body) -> Float[Array, " S"]:
        """Closed form of l̄(t) = l̄(0) + ∫u: the integral of eq. (24)."""
        psi0, psi = self.phase(0.0, body.N - 1), self.phase(t, body.N - 1)
        return self.lbar0(body) + (self.A / self.omega) * (jnp.cos(psi0) - jnp.cos(psi))

    def valid(self):
        return jnp.isfinite(self.A) & jnp.isfinite(self.delta) & (self.omega > 0)

    def stroke_speed(self, body, t1):
        """(N − 1)·|A|·`mean_abs_sine`(ω, t1): every segment strokes 2|A|/ω per half period."""
        return (body.N - 1) * jnp.abs(self.A) * mean_abs_sine(self.omega, t1)

    def period(self):
        """2π/ω."""
        return 2 * jnp.pi / self.omega

    def frequency(self):
        """ω."""
        return self.omega

    def placeholder(self):
        return TravellingWave(offset=self.offset)


def mean_abs_sine(omega: Scalar, t1: Scalar) -> Float[Array, ""]:
    """A bound on (1/t1) ∫_0^t1 |sin(ωt + φ)| dt for every phase φ: min(1, 2⌈ωt1/π⌉/(ωt1)).

    The interval covers ωt1 of phase; extended to ⌈ωt1/π⌉ whole half periods it holds
    exactly 2/ω of ∫|sin| per half period, and |sin| ≤ 1. Tends to 2/π over long horizons.
    """
    phase = omega * t1
    return jnp.minimum(1.0, 2.0 * jnp.ceil(phase / jnp.pi) / phase)


def whole_period_horizon(omega: Scalar, t1: Scalar) -> Float[Array, ""]:
    """The end of the last whole gait period within [0, t1]: K·2π/ω, K = ⌊ω t1/2π⌋
    (at least one period).

    The mean velocity over [0, t1] carries the phase of the gait at t1: as ω varies, the
    unfinished last period makes it a sawtooth in ω of period 2π/t1 (~0.5 % of the
    speed at t1 = 10 s, with slopes ~100× those of the velocity averaged over whole
    periods). Averaged up to this horizon instead, the speed is smooth in ω. K is
    piecewise constant, so the horizon's derivative is d/dω (2πK/ω) = −horizon/ω.
    """
    return _whole_periods(2 * jnp.pi / omega, t1)


def _whole_periods(period, t1):
    """K·T, K = ⌊t1/T⌋ (at least 1)."""
    return jnp.maximum(jnp.floor(t1 / period), 1.0) * period


#: What a run over "t1" simulates: [0, t1], or up to the last whole gait period in it.
HORIZONS = ("t1", "whole_periods")


def check_horizon(horizon: str, gait: AbstractController) -> None:
    """ValueError unless `horizon` is one of `HORIZONS` and the gait can take it (a
    periodic gait for `"whole_periods"`: `AbstractController.period`)."""
    if horizon not in HORIZONS:
        raise ValueError(f"option horizon = {horizon!r}: need one of {', '.join(HORIZONS)}")
    if horizon == "whole_periods" and gait.period() is None:
        raise ValueError(
            "option horizon = 'whole_periods' needs a periodic gait (one whose "
            f"period() is not None); the gait is a {type(gait).__name__}"
        )


def simulated_horizon(gait: AbstractController, t1, horizon: str):
    """The end time to simulate for `t1` under `horizon` (see `HORIZONS`): t1, or the end
    of the gait's last whole period in [0, t1], K·T with K = ⌊t1/T⌋ ≥ 1
    (`whole_period_horizon`)."""
    return t1 if horizon == "t1" else _whole_periods(gait.period(), t1)

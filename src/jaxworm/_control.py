"""Intrinsic-length control (§2.2, eq. 23) and the travelling-wave gait (eqs. 24-25).

A controller gives u = d l̄/dt, one entry per segment, from the time and the state, so
closed-loop controllers plug in the same way as the open-loop wave.
"""

from __future__ import annotations

import abc
import dataclasses
from typing import ClassVar, Literal

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from ._physics import Scalar
from ._validation import check_choice, check_range, concrete, show, to_float

__all__ = [
    "AbstractController",
    "TravellingWave",
    "ENTRIES",
    "whole_period_horizon",
    "HORIZONS",
    "simulated_horizon",
    "check_horizon",
    "mean_abs_sine",
    "sine_of_sum",
    "sines_of_multiples",
    "keep_type",
]


def keep_type(controller, valid):
    """`controller` with every field that `valid`'s class declares (static ones aside) set
    to `valid`'s value. `valid` is `controller.placeholder()`, which may be of a base
    class: the placeholder run then keeps the controller's own type, so that a subclass
    keeps its methods and its own fields (which are then not checked)."""
    if type(controller) is type(valid):
        return valid
    names = [f.name for f in dataclasses.fields(valid) if not f.metadata.get("static", False)]
    return eqx.tree_at(
        lambda g: [getattr(g, n) for n in names],
        controller,
        [getattr(valid, n) for n in names],
        is_leaf=lambda x: x is None,
    )


def sine_of_sum(a, b, f: Literal["sin", "cos"] = "sin"):
    """sin(a + b) (or cos(a + b)) by the angle-addition formula, for a wave's phase
    a + b = ωt + φ_k: a sine and a cosine of the time's part ωt (a scalar) and of the
    phases φ_k, which do not change with time, so that XLA computes them once per solve
    rather than at every evaluation. On a CPU a float64 sine is a scalar library call
    and the vector field's costliest operation.

    Within rounding of sin(a + b); more accurate for large a, since a + b is not rounded."""
    sa, ca, sb, cb = jnp.sin(a), jnp.cos(a), jnp.sin(b), jnp.cos(b)
    if f == "cos":
        return ca * cb - sa * sb
    return sa * cb + ca * sb


def sines_of_multiples(c, n: int):
    """(sin kc, cos kc) for k = 1..n, each of shape (n,), from sin c and cos c: two
    library calls instead of 2n (see `sine_of_sum`). e^{ikc} is the product of the
    e^{i 2^b c} over the binary digits b of k, the e^{i 2^b c} by doubling the angle:
    ~log₂ n rounds of elementwise code with static masks, which XLA fuses. Exact for
    c = 0."""
    k = np.arange(1, n + 1)
    s_b, c_b = jnp.sin(c), jnp.cos(c)  # sin, cos of 2^b c
    sines, cosines = jnp.zeros(n, s_b.dtype), jnp.ones(n, s_b.dtype)
    for b in range(int(n).bit_length()):
        digit = (k >> b) & 1 == 1
        sines, cosines = (
            jnp.where(digit, sines * c_b + cosines * s_b, sines),
            jnp.where(digit, cosines * c_b - sines * s_b, cosines),
        )
        s_b, c_b = 2 * s_b * c_b, c_b * c_b - s_b * s_b
    return sines, cosines


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


#: How `TravellingWave` turns eq. (24)'s entries into segment rates (`entries`).
ENTRIES = ("segment", "node_difference", "node_mean")


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
    - `entries`: static, how eq. (24)'s entries give the N − 1 segment rates.
      `"segment"` (default): one entry per segment, u_k = a_k for k = 1..N−1, with
      a_k = A sin(ψ_k). The paper lists N entries a_1..a_N, one per node; read so, they
      combine per segment as `"node_difference"`: u_k = a_k − a_{k+1} (the entries as
      node velocities, since l^k = x_k − x_{k+1}), amplitude 2A|sin(δ/2)|; or
      `"node_mean"`: u_k = (a_k + a_{k+1})/2, amplitude A|cos(δ/2)|. `offset` applies to
      the combined rates.
    - `numbering`: static, where eq. (25) counts k from. `"head"` (default): k = 1 at the
      head. `"tail"`: k = 1 at the tail, so segment k (from the head) has
      ψ = ωt + δ(N − k) (its node entries ψ = ωt + δ(N + 1 − k)): the wave of the body
      seen from its tail. It runs the other way along the body, like δ → −δ, but the
      two differ by the constant phase δN, which the rest start (`offset`) turns into
      other mean lengths of the segments.
    """

    open_loop: ClassVar[bool] = True

    A: Float[Array, ""] = eqx.field(default=0.02, converter=to_float)
    omega: Float[Array, ""] = eqx.field(default=4 * jnp.pi, converter=to_float)
    delta: Float[Array, ""] = eqx.field(default=jnp.pi / 4, converter=to_float)
    offset: Literal["rest", "centred"] = eqx.field(static=True, default="rest")
    entries: Literal["segment", "node_difference", "node_mean"] = eqx.field(
        static=True, default="segment"
    )
    numbering: Literal["head", "tail"] = eqx.field(static=True, default="head")

    def __check_init__(self):
        check_range("A", self.A, lambda v: v == v, "a real number")
        check_range("omega", self.omega, lambda v: v > 0, "> 0")
        check_range("delta", self.delta, lambda v: v == v, "a real number")
        if self.offset not in ("rest", "centred"):
            raise ValueError(f"option offset = {self.offset!r}: need 'rest' or 'centred'")
        check_choice("entries", self.entries, ENTRIES)
        check_choice("numbering", self.numbering, ("head", "tail"))

    def phase(self, t, n_segments: int) -> Float[Array, " S"]:
        """ψ_k(t) = ω t + δ k (eq. 25) for `n_segments` entries, head first: k = 1..n
        (`numbering = "head"`) or n..1 (`"tail"`)."""
        return self.omega * t + self._offsets(n_segments)

    def _offsets(self, n_segments: int) -> Float[Array, " S"]:
        """δ k, the part of ψ_k that does not change with time."""
        k = jnp.arange(1, n_segments + 1)
        if self.numbering == "tail":
            k = n_segments + 1 - k
        return self.delta * k

    def sine(self, t, n_segments: int, f: Literal["sin", "cos"] = "sin") -> Float[Array, " S"]:
        """sin ψ_k(t) (or cos ψ_k(t) when `f` is `"cos"`) for `n_segments` entries, as
        `phase` numbers them, by `sine_of_sum` of ωt and δk."""
        return sine_of_sum(self.omega * t, self._offsets(n_segments), f)

    def _per_segment(self, node_values: Float[Array, " N"]) -> Float[Array, " S"]:
        """Node entries k = 1..N combined per segment as `entries` says."""
        if self.entries == "node_difference":
            return node_values[:-1] - node_values[1:]
        return 0.5 * (node_values[:-1] + node_values[1:])

    def _wave(self, f, t, body) -> Float[Array, " S"]:
        """f(ψ) per segment: of ψ_k, k = 1..N−1 (`"segment"`), or of the N node phases
        combined (`_per_segment`). Every quantity of the wave is linear in such terms."""
        if self.entries == "segment":
            return f(self.phase(t, body.N - 1))
        return self._per_segment(f(self.phase(t, body.N)))

    def __call__(self, t, x, v, lbar, body):
        if self.entries == "segment":
            return self.A * self.sine(t, body.N - 1)
        return self.A * self._per_segment(self.sine(t, body.N))

    def lbar0(self, body):
        if self.offset == "centred":
            if self.entries == "segment":
                return body.l0 - (self.A / self.omega) * jnp.cos(self.phase(0.0, body.N - 1))
            return body.l0 - (self.A / self.omega) * self._wave(jnp.cos, 0.0, body)
        return super().lbar0(body)

    def intrinsic_lengths(self, t, body) -> Float[Array, " S"]:
        """Closed form of l̄(t) = l̄(0) + ∫u: the integral of eq. (24)."""
        if self.entries == "segment":
            S = body.N - 1
            change = jnp.cos(self._offsets(S)) - self.sine(t, S, "cos")
            return self.lbar0(body) + (self.A / self.omega) * change
        change = self._wave(jnp.cos, 0.0, body) - self._per_segment(self.sine(t, body.N, "cos"))
        return self.lbar0(body) + (self.A / self.omega) * change

    def amplitude_factor(self) -> Float[Array, ""]:
        """|u_k| ≤ A × this: 1 (`"segment"`), 2|sin(δ/2)| (`"node_difference"`),
        |cos(δ/2)| (`"node_mean"`)."""
        if self.entries == "node_difference":
            return 2.0 * jnp.abs(jnp.sin(0.5 * self.delta))
        if self.entries == "node_mean":
            return jnp.abs(jnp.cos(0.5 * self.delta))
        return jnp.asarray(1.0)

    def valid(self):
        return jnp.isfinite(self.A) & jnp.isfinite(self.delta) & (self.omega > 0)

    def stroke_speed(self, body, t1):
        """(N − 1)·|A|·(`amplitude_factor`)·`mean_abs_sine`(ω, t1): every segment's rate
        is a sine of that amplitude, which strokes it by 2·amplitude/ω per half period."""
        if self.entries == "segment":
            return (body.N - 1) * jnp.abs(self.A) * mean_abs_sine(self.omega, t1)
        amplitude = jnp.abs(self.A) * self.amplitude_factor()
        return (body.N - 1) * amplitude * mean_abs_sine(self.omega, t1)

    def period(self):
        """2π/ω."""
        return 2 * jnp.pi / self.omega

    def frequency(self):
        """ω."""
        return self.omega

    def placeholder(self):
        return TravellingWave(offset=self.offset, entries=self.entries, numbering=self.numbering)


def mean_abs_sine(omega: Scalar, t1: Scalar) -> Float[Array, ""]:
    """A bound on (1/t1) ∫_0^t1 |sin(ωt + φ)| dt for every phase φ: min(1, 2⌈ωt1/π⌉/(ωt1)).

    The interval covers ωt1 of phase; extended to ⌈ωt1/π⌉ whole half periods it holds
    exactly 2/ω of ∫|sin| per half period, and |sin| ≤ 1. Tends to 2/π over long horizons.
    """
    phase = omega * t1
    return jnp.minimum(1.0, 2.0 * jnp.ceil(phase / jnp.pi) / phase)


def whole_period_horizon(omega: Scalar, t1: Scalar) -> Float[Array, ""]:
    """The end of the last whole gait period within [0, t1]: K·2π/ω, K = ⌊ω t1/2π⌋.

    The mean velocity over [0, t1] carries the phase of the gait at t1: as ω varies, the
    unfinished last period makes it a sawtooth in ω of period 2π/t1, small in value
    but with slopes far steeper than those of the velocity averaged over whole periods
    (docs: Gradients). Averaged up to this horizon instead, the speed is smooth in ω. K is
    piecewise constant, so the horizon's derivative is d/dω (2πK/ω) = −horizon/ω.

    ω and t1 must be finite and > 0, and t1 at least one period 2π/ω (K ≥ 1): `ValueError`
    for other values given as numbers, NaN for traced ones (a `simulate` lane given it
    ends `"invalid_parameters"`).
    """
    for name, value in (("omega", omega), ("t1", t1)):
        if concrete(value):
            v = np.asarray(value, dtype=float)
            if not np.all(np.isfinite(v) & (v > 0)):
                raise ValueError(f"parameter {name} = {show(value)}: need a finite number > 0")
    period = 2 * jnp.pi / jnp.asarray(omega, dtype=float)
    check_one_period(period, t1)
    return _whole_periods(period, t1)


def check_one_period(period, t1) -> None:
    """ValueError when t1 and the gait's period are numbers and t1 is shorter than one
    period: no whole period fits in [0, t1]."""
    if not (concrete(period) and concrete(t1)):
        return
    T, t = np.asarray(period, dtype=float), np.asarray(t1, dtype=float)
    short = np.isfinite(T) & np.isfinite(t) & (t < T)
    if np.any(short):
        raise ValueError(
            f"parameter t1 = {show(t1)}: horizon 'whole_periods' needs t1 >= one gait "
            f"period ({show(np.max(np.where(short, T, 0.0)))} s); no whole period fits "
            "before t1 (horizon='t1' runs a shorter time)"
        )


def _whole_periods(period, t1):
    """K·T, K = ⌊t1/T⌋; NaN unless T and t1 are finite and > 0 and K ≥ 1, so that a
    traced lane with such a t1 is refused (`simulate` checks the horizon)."""
    K = jnp.floor(t1 / period)
    valid = jnp.isfinite(t1) & (t1 > 0) & jnp.isfinite(period) & (period > 0) & (K >= 1)
    return jnp.where(valid, K * period, jnp.nan)


#: What a run over "t1" simulates: [0, t1], or up to the last whole gait period in it.
HORIZONS = ("t1", "whole_periods")


def check_horizon(horizon: str, gait: AbstractController, t1=None, period=None) -> None:
    """ValueError unless `horizon` is one of `HORIZONS` and the gait can take it (a
    periodic gait for `"whole_periods"`: `AbstractController.period`), and, given `t1`,
    one period fits in it (`check_one_period`; `period`: the longest the caller's gaits
    take, default the gait's)."""
    if horizon not in HORIZONS:
        raise ValueError(f"option horizon = {horizon!r}: need one of {', '.join(HORIZONS)}")
    if horizon == "whole_periods" and gait.period() is None:
        raise ValueError(
            "option horizon = 'whole_periods' needs a periodic gait (one whose "
            f"period() is not None); the gait is a {type(gait).__name__}"
        )
    if horizon == "whole_periods" and t1 is not None:
        check_one_period(gait.period() if period is None else period, t1)


def simulated_horizon(gait: AbstractController, t1, horizon: str):
    """The end time to simulate for `t1` under `horizon` (see `HORIZONS`): t1, or the end
    of the gait's last whole period in [0, t1], K·T with K = ⌊t1/T⌋ ≥ 1
    (`whole_period_horizon`; NaN for a traced t1 shorter than one period: numbers are
    refused by `check_horizon`)."""
    return t1 if horizon == "t1" else _whole_periods(gait.period(), t1)

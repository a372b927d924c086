"""Per-segment gaits: an amplitude and a phase for every segment (2(N − 1) parameters).

The travelling wave of eqs. (24)-(25) gives every segment the same amplitude A and the
phase δk; `SegmentWave` frees both, segment by segment, at one common frequency ω:

    u_k = A_k sin(ω t + φ_k),   k = 1..N−1.

`TravellingWave(A, ω, δ)` is the case A_k = A, φ_k = δk (`SegmentWave.from_wave`).
To optimise it, name the parameters `A_1..A_{N−1}` and `phase_1..phase_{N−1}` in the
bounds (`segment_bounds`) and pass `apply=apply_segments` to `jaxworm.optimise`:

```python
import numpy as np, jaxworm as jw
base = jw.Params(gait=jw.SegmentWave.from_wave(jw.TravellingWave(delta=-np.pi / 4), N=7))
res = jw.optimise("velocity", jw.segment_bounds(7, A=(0.01, 0.03), phase=(-2 * np.pi, 0.5)),
                  base=base, apply=jw.apply_segments, t1=10.0, steps=20)
```
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from ._control import (
    AbstractController,
    TravellingWave,
    mean_abs_sine,
    sine_of_sum,
)
from ._validation import check_range, concrete, is_real_dtype, show, to_float

if TYPE_CHECKING:
    from ._params import Params

__all__ = ["SegmentWave", "segment_bounds", "apply_segments"]


def _to_vector(x: Any) -> Any:
    """Real numbers (a sequence, a NumPy or JAX array, tracers included) as a float64
    vector; anything else (strings, bools, complex numbers, None) unchanged, for
    `SegmentWave`'s check to refuse by name (hence `Any -> Any`)."""
    if isinstance(x, jax.Array):
        return jnp.atleast_1d(x.astype(jnp.float64)) if is_real_dtype(x.dtype) else x
    if isinstance(x, (list, tuple)) and any(isinstance(e, jax.Array) for e in x):
        return _to_vector(jnp.stack([jnp.asarray(e) for e in x]))
    try:
        a = np.asarray(x)
    except (TypeError, ValueError):  # ragged nesting and the like
        return x
    return jnp.atleast_1d(jnp.asarray(a, dtype=jnp.float64)) if is_real_dtype(a.dtype) else x


class SegmentWave(AbstractController):
    """u_k = A_k sin(ω t + φ_k) for the segments k = 1..N−1; l̄(0) = l_0 (rest start).

    - `A`: amplitudes [m/s], one per segment (N − 1,).
    - `phase`: phases φ_k [rad], one per segment (N − 1,).
    - `omega`: the common angular frequency ω > 0 [rad/s]. Default 4π.
    """

    open_loop: ClassVar[bool] = True

    A: Float[Array, " S"] = eqx.field(converter=_to_vector)
    phase: Float[Array, " S"] = eqx.field(converter=_to_vector)
    omega: Float[Array, ""] = eqx.field(default=4 * np.pi, converter=to_float)

    def __check_init__(self):
        for name, unit in (("A", "[m/s]"), ("phase", "[rad]")):
            values = getattr(self, name)
            if not (isinstance(values, jax.Array) and is_real_dtype(values.dtype)):
                raise TypeError(
                    f"parameter {name} = {show(values)}: need real numbers {unit}, one per segment"
                )
        if self.A.shape != self.phase.shape or self.A.ndim != 1 or self.A.shape[0] < 1:
            raise ValueError(
                f"parameters A (shape {self.A.shape}) and phase (shape "
                f"{self.phase.shape}): need two 1-D arrays of one length, N − 1 ≥ 1 (a "
                "SegmentWave takes an amplitude and a phase per segment)"
            )
        check_range("omega", self.omega, lambda v: v > 0, "> 0")
        for name in ("A", "phase"):
            values = getattr(self, name)
            if concrete(values) and not np.all(np.isfinite(np.asarray(values))):
                k = int(np.argmin(np.isfinite(np.asarray(values))))
                raise ValueError(
                    f"parameter {name}[{k}] = {float(values[k])!r}: need finite values "
                    f"({'[m/s]' if name == 'A' else '[rad]'}), one per segment"
                )

    @classmethod
    def from_wave(cls, wave: TravellingWave, N: int) -> SegmentWave:
        """The travelling wave as a per-segment gait: A_k = A, φ_k = δk (k = 1..N−1, or
        δ(N − k) when `wave.numbering == "tail"`). For the wave's node entries combined
        per segment (`TravellingWave.entries`), with node phases φ'_k (k = 1..N) that step
        by s = ±δ from node to node: A_k = 2A sin(s/2), φ_k = φ'_k + s/2 − π/2
        (`"node_difference"`), or A_k = A cos(s/2), φ_k = φ'_k + s/2 (`"node_mean"`)."""
        tail = wave.numbering == "tail"
        if wave.entries == "segment":
            k = jnp.arange(1, N)
            amplitude, phase = wave.A, wave.delta * (N - k if tail else k)
        else:
            k = jnp.arange(1, N)
            node_phase = wave.delta * (N + 1 - k if tail else k)
            step = -wave.delta if tail else wave.delta
            if wave.entries == "node_difference":
                amplitude = 2 * wave.A * jnp.sin(0.5 * step)
                phase = node_phase + 0.5 * step - 0.5 * jnp.pi
            else:
                amplitude = wave.A * jnp.cos(0.5 * step)
                phase = node_phase + 0.5 * step
        return cls(A=jnp.full(N - 1, 1.0) * amplitude, phase=phase, omega=wave.omega)

    def __call__(self, t, x, v, lbar, body):
        if self.A.shape[-1] != body.N - 1:
            raise ValueError(
                f"SegmentWave has {self.A.shape[-1]} segments; the body has N − 1 = {body.N - 1}"
            )
        return self.A * sine_of_sum(self.omega * t, self.phase)

    def valid(self) -> Bool[Array, ""]:
        return jnp.all(jnp.isfinite(self.A)) & jnp.all(jnp.isfinite(self.phase)) & (self.omega > 0)

    def stroke_speed(self, body, t1):
        """Σ_k |A_k|·`mean_abs_sine`(ω, t1) (as `TravellingWave.stroke_speed`)."""
        return jnp.sum(jnp.abs(self.A)) * mean_abs_sine(self.omega, t1)

    def period(self):
        """2π/ω."""
        return 2 * jnp.pi / self.omega

    def frequency(self):
        """ω."""
        return self.omega

    def placeholder(self):
        return SegmentWave(A=jnp.full(self.A.shape, 0.02), phase=jnp.zeros(self.phase.shape))


def segment_bounds(N: int, A: tuple[float, float], phase: tuple[float, float]) -> dict:
    """Bounds `{"A_1": A, ..., "A_{N−1}": A, "phase_1": phase, ...}` for `optimise`."""
    out = {f"A_{k}": tuple(A) for k in range(1, N)}
    out.update({f"phase_{k}": tuple(phase) for k in range(1, N)})
    return out


def apply_segments(base: Params, names: Sequence[str], theta: Float[Array, " P"]) -> Params:
    """`optimise`'s `apply` for per-segment gaits: θ named `A_k`, `phase_k` (and `omega`)
    set into `base.gait`, a `SegmentWave`; names left out keep the base gait's values."""
    gait = base.gait
    if not isinstance(gait, SegmentWave):
        raise ValueError(
            f"apply_segments needs base.gait to be a SegmentWave, got "
            f"{type(gait).__name__} (use SegmentWave.from_wave)"
        )
    names = list(names)
    if jnp.shape(theta) != (len(names),):
        raise ValueError(
            f"apply_segments: theta (shape {jnp.shape(theta)}) for {len(names)} names: "
            f"need one value per name, shape ({len(names)},)"
        )
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise ValueError(f"apply_segments: parameter {repeated[0]!r} named twice")
    A, phase, omega = gait.A, gait.phase, gait.omega
    segments = {str(k) for k in range(1, A.shape[0] + 1)}  # "1".."S", no leading zeros
    for i, name in enumerate(names):
        kind, _, k = name.partition("_")
        if name == "omega":
            omega = theta[i]
        elif kind in ("A", "phase") and k in segments:
            if kind == "A":
                A = A.at[int(k) - 1].set(theta[i])
            else:
                phase = phase.at[int(k) - 1].set(theta[i])
        else:
            raise ValueError(
                f"apply_segments: parameter {name!r} is not A_k, phase_k "
                f"(k = 1..{A.shape[0]}) or omega"
            )
    return dataclasses.replace(base, gait=SegmentWave(A=A, phase=phase, omega=omega))

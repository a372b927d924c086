"""Soil that varies along the burrow: profiles of E_s, K_Ic, K_Ith and μ_s in position.

A soil property of `Soil` is either a number (homogeneous soil, Table 1) or a profile:
an `AbstractProfile`, a pure function x ↦ value of the position x [m] along the burrow
axis (the axis of the node positions, the head starting at 0, positive ahead). Three are
provided:

- `Layered`: layers separated by interfaces, sharp (an exact step) or smoothed by tanh;
- `Gradient`: linear between two positions, constant outside;
- `RandomField`: a log-normal random field, a sum of random Fourier modes drawn from a
  `jax.random` key at construction (so the field itself is a fixed, pure function).

Every profile is an `eqx.Module` whose numbers are array leaves: `jax.grad` flows to
them, and a batch of profiles of one structure (the same class, number of layers,
smoothing width, number of modes) goes through `jax.vmap`. Build a batch by vmapping
the constructor, e.g. `jax.vmap(lambda k: RandomField(250.0, 0.2, 0.05, k))(keys)`.

Where each property is evaluated (`docs/MODEL.md`, "soil that varies"): K_Ic, K_Ith and
the E_s of K_I (eq. 12) and of the back pressure (eq. 16) at the crack tip x_c; E_s and
μ_s of the normal force and friction (eqs. 8, 10) at each segment's midpoint
(x_k + x_{k+1})/2. `arrest_tip` solves eq. (13) when E_s or K_Ith varies.
"""

from __future__ import annotations

import abc
import math
from collections.abc import Callable
from typing import Any, ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, PRNGKeyArray

from . import _physics as phys
from ._physics import Scalar
from ._validation import check_range, concrete, show, to_float

__all__ = [
    "AbstractProfile",
    "Layered",
    "Gradient",
    "RandomField",
    "value_at",
    "is_profile",
    "arrest_tip",
    "CHECK_WINDOW",
]

#: Most random modes of a `RandomField` (each is evaluated at every segment, every step).
MAX_MODES = 100_000

#: The window [m] of the grid (2048 points) on which a random field is checked against
#: another profile (K_Ith < K_Ic pointwise) at construction and in `params_valid`: a
#: burrow from the origin reaches ~1 m in a minute at the fastest gaits seen.
CHECK_WINDOW = (-1.0, 10.0)
# Grid points of a random field in that check (spacing 5.4 mm).
_CHECK_POINTS = 2048
# Bisection steps of the arrest search: the bracket (≤ a few cm) falls below 1e-17 m.
_BISECTIONS = 64
# Most march steps of the arrest search (a bound, so that any input terminates).
_MAX_MARCH = 100_000


class AbstractProfile(eqx.Module):
    """A soil property as a function of position x [m] along the burrow.

    Subclasses implement `__call__` (elementwise in x), `_values` (the numbers that
    bound the profile: its layer or end values), `points` and `placeholder`, and say
    how smooth they are: `piecewise_constant` profiles give their `jumps`, the others
    their smallest length of variation `length`.
    """

    #: True when the profile is constant between its `jumps`.
    piecewise_constant: ClassVar[bool] = False

    @abc.abstractmethod
    def __call__(self, x: Float[Array, "*shape"]) -> Float[Array, "*shape"]:
        """The value at positions x [m]."""

    @abc.abstractmethod
    def _values(self) -> Float[Array, " n"]:
        """Numbers whose range bounds the profile's values (min ≤ value ≤ max)."""

    @abc.abstractmethod
    def points(self) -> Float[Array, " P"]:
        """Positions [m] that sample the profile's features (interfaces, ends, a grid),
        on which two profiles are compared (K_Ith < K_Ic)."""

    @abc.abstractmethod
    def placeholder(self, value: float) -> AbstractProfile:
        """A valid profile of the same structure, constant at `value`."""

    @abc.abstractmethod
    def describe(self) -> dict:
        """The profile as plain values (for JSON headers of result files)."""

    @property
    def jumps(self) -> Float[Array, " J"]:
        """Positions where the value jumps (empty for a continuous profile)."""
        return jnp.zeros(0)

    @property
    def length(self) -> Float[Array, ""]:
        """The smallest length [m] over which the value changes (inf: piecewise constant)."""
        return jnp.asarray(jnp.inf)

    def check(self, name: str, ok: Callable, allowed: str) -> None:
        """Refuse, naming the parameter `name` and the profile, values not `ok`."""
        values = self._values()
        if not concrete(values):
            return
        a = np.asarray(values)
        if not np.all(np.isfinite(a)) or not np.all(ok(a)):
            raise ValueError(
                f"parameter {name} = {type(self).__name__} with values {show(values)} is "
                f"out of range: need every value of {name} {allowed} (finite)"
            )

    def valid(self, ok: Callable) -> Bool[Array, ""]:
        """`check` and the profile's own checks as a traced boolean."""
        v = self._values()
        return jnp.all(jnp.isfinite(v) & ok(v)) & self._valid()

    def _valid(self) -> Bool[Array, ""]:
        return jnp.asarray(True)


def is_profile(value: Any) -> bool:
    """True for an `AbstractProfile` (a property that varies), False for a number."""
    return isinstance(value, AbstractProfile)


def value_at(value: Scalar | AbstractProfile, x: Any) -> Any:
    """A soil property at positions x: `value(x)` for a profile, `value` itself for a
    number (homogeneous soil: nothing is evaluated, the number broadcasts)."""
    return value(x) if isinstance(value, AbstractProfile) else value


def _vector(name: str, value, n: int | None = None) -> Float[Array, " n"]:
    try:
        a = jnp.asarray(value, dtype=jnp.float64)
    except (TypeError, ValueError):
        a = None
    if a is None or a.ndim != 1:
        raise ValueError(f"parameter {name} = {show(value)}: need a 1-d sequence of numbers")
    if n is not None and a.shape[0] != n:
        raise ValueError(f"parameter {name} = {show(value)}: need {n} numbers, got {a.shape[0]}")
    return a


class Layered(AbstractProfile):
    """Layers of constant value: `values[j]` between `interfaces[j−1]` and
    `interfaces[j]` (one more value than interfaces; the first and last layers extend to
    ∓∞):

        f(x) = v_0 + Σ_i (v_{i+1} − v_i) H((x − x_i)/width),

    with H the unit step (H(0) = 1: at an interface the layer ahead applies) when
    `width` = 0, else the smooth step H(s) = (1 + tanh s)/2. A smoothed interface
    passes the mean of its two layers, (v_i + v_{i+1})/2, at x_i; with sorted
    interfaces f is a convex combination of the layer values, so it stays between their
    least and greatest.

    - `interfaces`: positions x_i [m], strictly increasing.
    - `values`: the layer values, head-ward last (the burrow runs to +x).
    - `width`: static smoothing width [m] (0: sharp). Part of the structure: profiles of
      one batch share it.

    ```python
    K_Ic = jw.Layered(interfaces=[0.05], values=[250.0, 500.0])   # 2x tougher ahead
    p = jw.Params().replace(K_Ic=K_Ic, K_Ith=jw.Layered([0.05], [200.0, 400.0]))
    ```
    """

    interfaces: Float[Array, " n"]
    values: Float[Array, " n+1"]
    width: float = eqx.field(static=True, default=0.0)

    def __init__(self, interfaces, values, width: float = 0.0):
        self.interfaces = _vector("interfaces", interfaces)
        self.values = _vector("values", values, self.interfaces.shape[0] + 1)
        if (
            isinstance(width, bool)
            or not isinstance(width, (int, float))
            or not math.isfinite(width)
            or width < 0
        ):
            raise ValueError(
                f"parameter width = {show(width)} ({type(width).__name__}): need a Python "
                "number >= 0 [m] (static, part of the profile's structure: not an array)"
            )
        self.width = float(width)
        if concrete(self.interfaces):
            a = np.asarray(self.interfaces)
            if not np.all(np.isfinite(a)) or np.any(np.diff(a) <= 0):
                raise ValueError(
                    f"parameter interfaces = {show(self.interfaces)}: need finite positions "
                    "in strictly increasing order [m]"
                )

    @property
    def piecewise_constant(self) -> bool:  # type: ignore[override]
        return self.width == 0.0

    def __call__(self, x):
        s = jnp.asarray(x)[..., None] - self.interfaces
        if self.width == 0.0:
            step = (s >= 0).astype(self.values.dtype)
        else:
            step = 0.5 * (1.0 + jnp.tanh(s / self.width))
        return self.values[0] + jnp.sum(jnp.diff(self.values) * step, axis=-1)

    def _values(self):
        return self.values

    def _valid(self):
        return jnp.all(jnp.isfinite(self.interfaces)) & jnp.all(jnp.diff(self.interfaces) > 0)

    @property
    def jumps(self):
        return self.interfaces if self.width == 0.0 else jnp.zeros(0)

    @property
    def length(self):
        if self.width == 0.0:
            return jnp.asarray(jnp.inf)
        if self.interfaces.shape[0] < 2:
            # No layer between two interfaces (and no min over an empty array, whose
            # derivative is NaN: it made the tip's derivative in an interface NaN).
            return jnp.asarray(self.width)
        return jnp.minimum(self.width, jnp.min(jnp.diff(self.interfaces)))

    def points(self):
        x = self.interfaces
        if x.shape[0] == 0:
            return jnp.zeros(1)
        pad = jnp.maximum(4 * self.width, 1e-9)
        mid = 0.5 * (x[:-1] + x[1:])
        return jnp.concatenate([x, x - pad, x + pad, mid, x[:1] - 1.0, x[-1:] + 1.0])

    def placeholder(self, value):
        n = self.interfaces.shape[0]
        return Layered(jnp.arange(n, dtype=float), jnp.full(n + 1, value), self.width)

    def describe(self):
        return {
            "profile": "Layered",
            "interfaces": np.asarray(self.interfaces).tolist(),
            "values": np.asarray(self.values).tolist(),
            "width": self.width,
        }


class Gradient(AbstractProfile):
    """A linear gradient between two positions, constant outside them:

        f(x) = v_0 + (v_1 − v_0) clip((x − x_0)/(x_1 − x_0), 0, 1).

    - `positions`: (x_0, x_1) [m], x_0 < x_1.
    - `values`: (v_0, v_1), the values at x_0 and x_1 (and beyond them).

    ```python
    E_s = jw.Gradient(positions=(0.0, 0.5), values=(1.4e5, 2.8e5))  # stiffer with depth
    ```
    """

    positions: Float[Array, " 2"]
    values: Float[Array, " 2"]

    def __init__(self, positions, values):
        self.positions = _vector("positions", positions, 2)
        self.values = _vector("values", values, 2)
        if concrete(self.positions):
            a = np.asarray(self.positions)
            if not np.all(np.isfinite(a)) or not a[0] < a[1]:
                raise ValueError(
                    f"parameter positions = {show(self.positions)}: need finite x_0 < x_1 [m]"
                )

    def __call__(self, x):
        x0, x1 = self.positions[0], self.positions[1]
        s = jnp.clip((jnp.asarray(x) - x0) / (x1 - x0), 0.0, 1.0)
        return self.values[0] + (self.values[1] - self.values[0]) * s

    def _values(self):
        return self.values

    def _valid(self):
        return jnp.all(jnp.isfinite(self.positions)) & (self.positions[0] < self.positions[1])

    @property
    def length(self):
        return self.positions[1] - self.positions[0]

    def points(self):
        x0, x1 = self.positions[0], self.positions[1]
        return jnp.stack([x0 - 1.0, x0, 0.5 * (x0 + x1), x1, x1 + 1.0])

    def placeholder(self, value):
        return Gradient(jnp.array([0.0, 1.0]), jnp.full(2, value))

    def describe(self):
        return {
            "profile": "Gradient",
            "positions": np.asarray(self.positions).tolist(),
            "values": np.asarray(self.values).tolist(),
        }


class RandomField(AbstractProfile):
    """A stationary log-normal random field with a Gaussian correlation:

        f(x) = median · exp(σ g(x)),   g(x) = √(2/M) Σ_{j=1..M} cos(k_j x + φ_j),

    k_j = z_j / ℓ with z_j ~ N(0, 1) and φ_j ~ U[0, 2π) drawn from `key` at
    construction. Over keys, g(x) has mean 0, variance 1 and correlation
    E[g(x) g(x + r)] = exp(−r²/(2ℓ²)) (and tends to a Gaussian as M grows), so
    log f has mean log(median) and standard deviation σ. The same key gives the same
    field; f is positive for any key.

    - `median` [unit of the property] > 0, `sigma` σ ≥ 0 (of log f), `length` ℓ > 0 [m],
      the correlation length; `key` a `jax.random` key; `modes` M (static, default 64).

    The drawn `z` and `phase` are leaves (fixed per field; the derivative in `length`
    moves every k_j = z_j/ℓ). A batch: `jax.vmap(lambda k: RandomField(250.0, 0.2,
    0.05, k))(jax.random.split(key, B))`.
    """

    median: Float[Array, ""]
    sigma: Float[Array, ""]
    length_scale: Float[Array, ""]
    z: Float[Array, " M"]
    phase: Float[Array, " M"]

    def __init__(
        self, median, sigma, length, key: PRNGKeyArray | None = None, modes: int = 64, **kw
    ):
        # `z`, `phase` given (no key): rebuilding a field, e.g. a placeholder.
        self.median, self.sigma, self.length_scale = (
            to_float(median),
            to_float(sigma),
            to_float(length),
        )
        check_range("median", self.median, lambda v: v > 0, "> 0")
        check_range("sigma", self.sigma, lambda v: v >= 0, ">= 0")
        check_range("length", self.length_scale, lambda v: v > 0, "> 0 [m]")
        if key is None:
            if "z" not in kw or "phase" not in kw:
                raise TypeError(
                    "RandomField needs key, a jax.random key (e.g. jax.random.key(0)): the "
                    "seed of its random modes"
                )
            self.z, self.phase = jnp.asarray(kw["z"]), jnp.asarray(kw["phase"])
            return
        if isinstance(modes, bool) or not isinstance(modes, int) or not 1 <= modes <= MAX_MODES:
            raise ValueError(
                f"parameter modes = {show(modes)}: need an integer 1 <= modes <= {MAX_MODES}"
            )
        typed = isinstance(key, jax.Array) and jnp.issubdtype(key.dtype, jax.dtypes.prng_key)
        raw = np.ndim(key) == 1 and getattr(key, "dtype", None) == np.uint32
        if not (typed or raw):
            raise TypeError(
                f"parameter key = {show(key)}: need a jax.random key (e.g. jax.random.key(0))"
            )
        kz, kp = jax.random.split(key)
        self.z = jax.random.normal(kz, (modes,), dtype=jnp.float64)
        self.phase = jax.random.uniform(kp, (modes,), dtype=jnp.float64, maxval=2 * jnp.pi)

    def normal(self, x):
        """g(x): the unit Gaussian field (mean 0, variance 1 over keys)."""
        x = jnp.asarray(x)[..., None]
        M = self.z.shape[-1]
        k = self.z / self.length_scale
        return math.sqrt(2.0 / M) * jnp.sum(jnp.cos(k * x + self.phase), axis=-1)

    def __call__(self, x):
        return self.median * jnp.exp(self.sigma * self.normal(x))

    def _values(self):
        return jnp.reshape(self.median, (1,))

    def _valid(self):
        return (self.sigma >= 0) & (self.length_scale > 0)

    @property
    def length(self):
        return self.length_scale

    def points(self):
        return jnp.linspace(*CHECK_WINDOW, _CHECK_POINTS)

    def placeholder(self, value):
        return RandomField(
            value, 0.0, 1.0, z=jnp.zeros_like(self.z), phase=jnp.zeros_like(self.phase)
        )

    def describe(self):
        return {
            "profile": "RandomField",
            "median": float(self.median),
            "sigma": float(self.sigma),
            "length": float(self.length_scale),
            "z": np.asarray(self.z).tolist(),
            "phase": np.asarray(self.phase).tolist(),
        }


def arrest_tip(
    x1: Scalar,
    l1: Scalar,
    start: Scalar,
    E_s: Scalar | AbstractProfile,
    K_Ith: Scalar | AbstractProfile,
    nu: Scalar,
    w0: Scalar,
    l0: Scalar,
) -> Float[Array, ""]:
    """The new crack tip, eq. (13) for soil that varies: the first position x > `start`
    (the old tip) at which the running crack's K_I falls to the threshold there,

        K_I(x) = E_s(x) w_0 l_0 / (√(2π (x − x_1)) (1 − ν²) l_1) ≤ K_Ith(x),

    i.e. the first zero crossing of g(x) = (x − x_1) − a(x), a(x) = `arrest_gap` with
    E_s(x), K_Ith(x). The crack runs from the old tip (where K_I = K_Ic > K_Ith, g < 0)
    and stops at the first point where it can no longer propagate; it does not jump
    over a tough patch to a point beyond where g ≥ 0 again. For numbers this is eq. (13)
    (g is linear); the solve:

    - `E_s`, `K_Ith` piecewise constant (numbers, sharp `Layered`): exact. On each piece
      [p_j, p_{j+1}) between their jumps a(x) = a_j, so the first crossing in it is
      max(p_j, x_1 + a_j, start) if that is < p_{j+1}; the tip is the least of these
      (an arrest at a jump where the threshold rises: the tip stops on the interface).
    - otherwise: march from `start` in steps of a quarter of the smaller of the
      profiles' `length` and of a(start) (at most `_MAX_MARCH` steps: a profile
      so steep that the march runs out gives a NaN tip, and the run does not end ok),
      bisect the first step where g ≥ 0, and take
      the derivative by the implicit function theorem, dx/dθ = −(∂g/∂θ)/(∂g/∂x),
      where g is continuous at the tip (with a sharp `Layered` mixed in and the tip on
      its jump, the tip's derivative is zero).
    """

    x1, l1, start = jnp.asarray(x1), jnp.asarray(l1), jnp.asarray(start)

    def gap_to_arrest(x, E, K):
        return (x - x1) - phys.arrest_gap(l1, value_at(K, x), value_at(E, x), nu, w0, l0)

    varying = [f for f in (E_s, K_Ith) if isinstance(f, AbstractProfile)]
    if all(f.piecewise_constant for f in varying):
        knots = jnp.sort(jnp.concatenate([f.jumps for f in varying]))
        if knots.shape[0] == 0:
            inside = jnp.reshape(jnp.asarray(start, dtype=float), (1,))
        else:
            inside = jnp.concatenate([knots[:1] - 1.0, knots])
        lo = jnp.concatenate([jnp.array([-jnp.inf]), knots])
        hi = jnp.concatenate([knots, jnp.array([jnp.inf])])
        a = phys.arrest_gap(l1, value_at(K_Ith, inside), value_at(E_s, inside), nu, w0, l0)
        first = jnp.maximum(jnp.maximum(lo, x1 + a), jax.lax.stop_gradient(start))
        return jnp.min(jnp.where(first < hi, first, jnp.inf))

    # Search without derivatives (a while loop has none in reverse mode) ...
    c = jax.lax.stop_gradient((x1, l1, start, E_s, K_Ith, nu, w0, l0))
    cx1, cl1, cstart, cE, cK = c[0], c[1], c[2], c[3], c[4]

    def g0(x):
        return (x - cx1) - phys.arrest_gap(cl1, value_at(cK, x), value_at(cE, x), *c[5:])

    # The march's step is the search's own: no derivative (taken from the stopped profiles).
    stopped = [f for f in (cE, cK) if isinstance(f, AbstractProfile)]
    lengths = jnp.stack([jnp.asarray(f.length, dtype=float) for f in stopped])
    a_start = phys.arrest_gap(cl1, value_at(cK, cstart), value_at(cE, cstart), *c[5:])
    step = 0.25 * jnp.minimum(jnp.min(lengths), a_start)

    def more(state):
        j, x = state
        return (g0(x) < 0) & (j < _MAX_MARCH)

    _, hi = jax.lax.while_loop(more, lambda s: (s[0] + 1, s[1] + step), (0, cstart))
    # A march that ran out of steps found no arrest: the tip is unknown (NaN), never the
    # point where the march stopped.
    hi = jnp.where(g0(hi) < 0, jnp.nan, hi)
    lo = jnp.maximum(hi - step, cstart)

    def bisect(_, bracket):
        lo, hi = bracket
        mid = 0.5 * (lo + hi)
        up = g0(mid) >= 0
        return jnp.where(up, lo, mid), jnp.where(up, mid, hi)

    _, tip = jax.lax.fori_loop(0, _BISECTIONS, bisect, (lo, hi))
    # ... then the derivative at the tip (the value stays the bisected one).
    g, dg = jax.jvp(lambda x: gap_to_arrest(x, E_s, K_Ith), (tip,), (jnp.ones_like(tip),))
    continuous = jnp.abs(jax.lax.stop_gradient(g)) <= 1e-9 * jnp.abs(a_start)
    newton = jnp.where(continuous, g / jnp.where(continuous, dg, 1.0), 0.0)
    return tip - (newton - jax.lax.stop_gradient(newton))

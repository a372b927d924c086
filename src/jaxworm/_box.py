"""Reparametrisations of a box: an unconstrained z to a point θ of [lo, hi], elementwise.

The optimiser (`jaxworm.optimise`) works on z, the simulation sees θ = `to_box(z)`, so
every evaluated point lies in the box by construction, not by clipping. Its steps are
in units of the box, whatever the parameter's unit.

- `SineBox` (the default): θ = lo + (hi − lo)(1 + sin z)/2, the transformation of
  MINUIT (James & Roos 1975). A bound is reached at a finite z = ±π/2, where
  dθ/dz = 0: an optimiser with bounded steps gets there in a few steps and settles,
  as gait optima on a bound need (an amplitude at its actuator limit, the lowest
  frequency allowed).
- `SigmoidBox`: θ = lo + (hi − lo) σ(z), σ(z) = 1/(1 + e^{−z}). Every point lies
  strictly inside (z ∈ [−3, 3] covers 5 %–95 % of each side), and a bound is
  approached only as z → ±∞; for optima inside the box (`identify`'s soil).

```python
import jax.numpy as jnp, jaxworm as jw
box = jw.SineBox()
theta = box.to_box(jnp.array([0.0, jnp.pi / 2]), 0.0, 2.0)   # [1.0, 2.0]
box.from_box(jnp.array(1.5), 0.0, 2.0)                       # π/6
```
"""

from __future__ import annotations

import abc
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

__all__ = ["AbstractBox", "SineBox", "SigmoidBox", "BOXES", "DEFAULT_BOX", "as_box"]


class AbstractBox(eqx.Module):
    """θ = to_box(z, lo, hi) ∈ [lo, hi] for every real z, with its inverse and slope.

    `name` is how `jaxworm.optimise(box=...)` and result headers spell it; `formula`
    is the map in words (recorded in the optimisation history's header).
    """

    name: ClassVar[str]
    formula: ClassVar[str]

    @abc.abstractmethod
    def to_box(
        self,
        z: Float[Array, "*shape"],
        lo: Float[Array, "*#shape"] | float,
        hi: Float[Array, "*#shape"] | float,
    ) -> Float[Array, "*shape"]:
        """The point θ of [lo, hi] for the unconstrained z."""

    @abc.abstractmethod
    def from_box(
        self,
        theta: Float[Array, "*shape"],
        lo: Float[Array, "*#shape"] | float,
        hi: Float[Array, "*#shape"] | float,
    ) -> Float[Array, "*shape"]:
        """The inverse of `to_box` for lo < θ < hi."""

    @abc.abstractmethod
    def slope(
        self,
        z: Float[Array, "*shape"],
        lo: Float[Array, "*#shape"] | float,
        hi: Float[Array, "*#shape"] | float,
    ) -> Float[Array, "*shape"]:
        """dθ/dz of `to_box`."""


class SineBox(AbstractBox):
    """θ = lo + (hi − lo)(1 + sin z)/2: the bounds at z = ±π/2, periodic in z."""

    name: ClassVar[str] = "sine"
    formula: ClassVar[str] = "theta = lo + (hi - lo) * (1 + sin(z)) / 2"

    def to_box(
        self,
        z: Float[Array, "*shape"],
        lo: Float[Array, "*#shape"] | float,
        hi: Float[Array, "*#shape"] | float,
    ) -> Float[Array, "*shape"]:
        return lo + (hi - lo) * 0.5 * (1.0 + jnp.sin(z))

    def from_box(
        self,
        theta: Float[Array, "*shape"],
        lo: Float[Array, "*#shape"] | float,
        hi: Float[Array, "*#shape"] | float,
    ) -> Float[Array, "*shape"]:
        """arcsin(2u − 1) ∈ (−π/2, π/2), u = (θ − lo)/(hi − lo)."""
        u = (theta - lo) / (hi - lo)
        return jnp.arcsin(2.0 * u - 1.0)

    def slope(
        self,
        z: Float[Array, "*shape"],
        lo: Float[Array, "*#shape"] | float,
        hi: Float[Array, "*#shape"] | float,
    ) -> Float[Array, "*shape"]:
        return (hi - lo) * 0.5 * jnp.cos(z)


class SigmoidBox(AbstractBox):
    """θ = lo + (hi − lo) σ(z): strictly inside the box, the bounds at z = ±∞."""

    name: ClassVar[str] = "sigmoid"
    formula: ClassVar[str] = "theta = lo + (hi - lo) * sigmoid(z)"

    def to_box(
        self,
        z: Float[Array, "*shape"],
        lo: Float[Array, "*#shape"] | float,
        hi: Float[Array, "*#shape"] | float,
    ) -> Float[Array, "*shape"]:
        return lo + (hi - lo) * jax.nn.sigmoid(z)

    def from_box(
        self,
        theta: Float[Array, "*shape"],
        lo: Float[Array, "*#shape"] | float,
        hi: Float[Array, "*#shape"] | float,
    ) -> Float[Array, "*shape"]:
        """logit(u), u = (θ − lo)/(hi − lo)."""
        u = (theta - lo) / (hi - lo)
        return jnp.log(u) - jnp.log1p(-u)

    def slope(
        self,
        z: Float[Array, "*shape"],
        lo: Float[Array, "*#shape"] | float,
        hi: Float[Array, "*#shape"] | float,
    ) -> Float[Array, "*shape"]:
        s = jax.nn.sigmoid(z)
        return (hi - lo) * s * (1.0 - s)


#: The boxes by name (`jaxworm.optimise(box=name)`, `jaxworm optimise --box`).
BOXES: dict[str, AbstractBox] = {b.name: b for b in (SineBox(), SigmoidBox())}

#: The name of `optimise`'s box unless told otherwise.
DEFAULT_BOX = "sine"


def as_box(box: str | AbstractBox) -> AbstractBox:
    """The box named `box` (`BOXES`), or `box` itself; ValueError for anything else."""
    if isinstance(box, AbstractBox):
        return box
    if isinstance(box, str) and box in BOXES:
        return BOXES[box]
    raise ValueError(f"option box = {box!r}: need one of {', '.join(BOXES)} or an AbstractBox")

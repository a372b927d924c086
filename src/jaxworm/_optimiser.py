"""The optimisers of `jaxworm.optimise`, built in one place: `make_optimiser`.

Each is an optax `GradientTransformation` acting on the unconstrained z of the box
(`_box`). The optax ones take a first step `learning_rate` cosine-decayed to 5 % of it
over the steps; `rprop` (iRprop−) controls its own steps. The defaults depend on the
box (`DEFAULT_OPTIMISERS`): Adam without momentum on the sine box, where momentum
carries z past a bound and back into the box; Adam with b1 = 0.9 on the sigmoid.

```python
import jaxworm as jw
opt = jw.make_optimiser("rprop", 30)                  # iRprop−, first step 0.5 in z
opt = jw.make_optimiser("adam", 30, box="sigmoid")    # = default_optimiser(30, "sigmoid")
res = jw.optimise(optimiser=opt, steps=30, t1=10.0)
```
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import optax

from ._box import DEFAULT_BOX, AbstractBox, as_box
from ._validation import check_int, check_range, to_float

__all__ = [
    "make_optimiser",
    "default_optimiser",
    "describe_default_optimiser",
    "rprop",
    "OPTIMISERS",
    "DEFAULT_OPTIMISERS",
]

#: The names `make_optimiser` builds: optax transformations of one cosine-decayed
#: learning rate (sgd with momentum 0.9), and jaxworm's iRprop− (`rprop`).
OPTIMISERS = ("adam", "adabelief", "rmsprop", "sgd", "rprop")

#: Optimisers with a momentum `b1`.
_WITH_B1 = ("adam", "adabelief")

#: The default optimiser on each box (by name): Adam, its first step in z and its
#: momentum b1. `rprop(0.25)` (iRprop−) needed fewer simulations than the sine default
#: in 6 of 10 gait problems and start sets measured, more in 2
#: (benchmarks/results/optimise_amplitude*, segment_gait*, optimise_vs_grid*).
DEFAULT_OPTIMISERS = {
    "sine": {"learning_rate": 0.5, "b1": 0.0},
    "sigmoid": {"learning_rate": 0.2, "b1": 0.9},
}

#: The fraction of the first step the cosine decay ends at.
_DECAY_TO = 0.05


def _check(name: str, value, ok, allowed: str) -> None:
    """Refuse an optimiser's setting unless a real number with `ok(value)`, naming it."""
    check_range(name, to_float(value), ok, allowed, kind="option")


def _defaults(box: str | AbstractBox) -> dict:
    name = as_box(box).name
    if name not in DEFAULT_OPTIMISERS:
        raise ValueError(f"box {name!r} has no default optimiser: give learning_rate (and b1)")
    return DEFAULT_OPTIMISERS[name]


def make_optimiser(
    name: str,
    steps: int,
    *,
    box: str | AbstractBox = DEFAULT_BOX,
    learning_rate: float | None = None,
    b1: float | None = None,
) -> optax.GradientTransformation:
    """The optimiser `name` (`OPTIMISERS`) for a run of `steps` steps on `box`.

    - `learning_rate`: the first step in z (default: the box's, `DEFAULT_OPTIMISERS`);
      the optax optimisers cosine-decay it to 5 % over `steps`, `rprop` takes it as its
      first step Δ.
    - `b1`: the momentum of adam and adabelief (default: the box's); ValueError for the
      others, which have none.

    `sgd` has momentum 0.9; `rmsprop` is optax's with its defaults.
    """
    if name not in OPTIMISERS:
        raise ValueError(f"option optimiser = {name!r}: need one of {', '.join(OPTIMISERS)}")
    check_int("steps", steps, 1, None, kind="option")
    if b1 is not None and name not in _WITH_B1:
        raise ValueError(
            f"option b1 = {b1!r}: only {' and '.join(_WITH_B1)} have a momentum b1, not {name}"
        )
    if learning_rate is not None:
        _check("learning_rate", learning_rate, lambda v: v > 0, "> 0")
    if b1 is not None:
        _check("b1", b1, lambda v: (v >= 0) & (v < 1), "in [0, 1)")
    needs_defaults = learning_rate is None or (b1 is None and name in _WITH_B1)
    defaults = _defaults(box) if needs_defaults else {}
    lr = defaults["learning_rate"] if learning_rate is None else learning_rate
    if name == "rprop":  # its own step control: no schedule
        return rprop(lr)
    schedule = optax.cosine_decay_schedule(lr, max(steps, 1), alpha=_DECAY_TO)
    if name == "sgd":
        return optax.sgd(schedule, momentum=0.9)
    if name == "rmsprop":
        return optax.rmsprop(schedule)
    return getattr(optax, name)(schedule, b1=defaults["b1"] if b1 is None else b1)


def default_optimiser(
    steps: int, box: str | AbstractBox = DEFAULT_BOX, learning_rate: float | None = None
) -> optax.GradientTransformation:
    """The box's default optimiser (`DEFAULT_OPTIMISERS`): Adam on z, its step decaying
    from `learning_rate` (default: the box's) to 5 % of it (cosine) over `steps`."""
    return make_optimiser("adam", steps, box=box, learning_rate=learning_rate)


def describe_default_optimiser(box: str | AbstractBox = DEFAULT_BOX) -> str:
    """`default_optimiser` in words, for a result header."""
    d = _defaults(box)
    return (
        f"adam (b1 {d['b1']:g}), cosine decay {d['learning_rate']:g} -> "
        f"{_DECAY_TO * d['learning_rate']:g} over the steps"
    )


class RpropState(NamedTuple):
    step_size: jax.Array  # Δ_i, per coordinate
    last_grad: jax.Array  # the previous gradient, zeroed where its sign flipped


def rprop(
    learning_rate: float = 0.25,
    eta_minus: float = 0.5,
    eta_plus: float = 1.2,
    min_step: float = 1e-6,
    max_step: float = 1.0,
) -> optax.GradientTransformation:
    """iRprop− (Igel & Hüsken 2000), for a deterministic objective: every coordinate
    steps −sign(g_i)·Δ_i; Δ_i grows by `eta_plus` while g_i keeps its sign and shrinks
    by `eta_minus` when it flips, and then that coordinate does not move for one step.
    `learning_rate` is the first Δ (in z). On the sine box a coordinate whose optimum is
    on a bound oscillates about z = ±π/2 with halving steps, and one at an interior kink
    bisects onto it.

    Written here because `optax.rprop` (0.2.8) emits each update one step late (its first
    update is zero; google-deepmind/optax#1725).
    """

    _check("learning_rate", learning_rate, lambda v: v > 0, "> 0")
    _check("eta_minus", eta_minus, lambda v: (v > 0) & (v < 1), "in (0, 1)")
    _check("eta_plus", eta_plus, lambda v: v > 1, "> 1")
    _check("min_step", min_step, lambda v: v > 0, "> 0")
    _check("max_step", max_step, lambda v: v >= min_step, f">= min_step = {min_step}")

    def init(params):
        return RpropState(jnp.full_like(params, learning_rate), jnp.zeros_like(params))

    def update(updates, state, params=None):
        del params
        grad = updates
        turn = grad * state.last_grad
        step = jnp.where(
            turn > 0,
            jnp.minimum(state.step_size * eta_plus, max_step),
            jnp.where(
                turn < 0, jnp.maximum(state.step_size * eta_minus, min_step), state.step_size
            ),
        )
        grad = jnp.where(turn < 0, 0.0, grad)
        return -step * jnp.sign(grad), RpropState(step, grad)

    return optax.GradientTransformation(init, update)

"""Samples of a scene: parameter values an objective is averaged over, as one batch.

`optimise(..., samples=...)` and `train(..., samples=...)` take `samples` as a dict
{name: values} whose names are those `Params.replace` sets (flat parameter names such as
`K_Ic`, or a whole part: `soil`, `body`, `gait`, `smoothing`), each value carrying a
leading sample axis of one length S: an array (S,) of numbers, a batch of profiles or
soils (a pytree whose arrays have the leading axis, as `jax.vmap` of a constructor
gives), or a list of S values of one structure (stacked here). Sample i is the scene
`base.replace(**{name: values[i]})`; the objective is solved on the S scenes as one
`jax.vmap` batch and averaged (`per_sample`, `pool`).

```python
import jaxworm as jw
soils = [jw.Soil(K_Ic=jw.Layered([x], [250.0, 500.0]), K_Ith=jw.Layered([x], [200.0, 400.0]))
         for x in (0.05, 0.1)]
res = jw.optimise("velocity", samples={"soil": soils}, t1=4.0, starts=2, steps=5)
```
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from ._fingerprint import tree_digest
from ._params import Params
from ._validation import show

__all__ = ["check_samples", "describe_samples", "sample_at", "per_sample", "pool"]

_SAMPLES_NEED = (
    "need a dict {name: values} of parameter names (or parts: soil, body, gait, "
    "smoothing), each value an array or batch with a leading sample axis, or a list of "
    "one value per sample"
)


def _as_batch(name: str, value):
    """`value` with its leaves as arrays with a leading sample axis (a list stacked)."""
    if isinstance(value, (list, tuple)):
        if not value:
            raise ValueError(f"option samples: {name} is an empty list; {_SAMPLES_NEED}")
        first = jax.tree_util.tree_structure(value[0])
        for i, v in enumerate(value):
            if jax.tree_util.tree_structure(v) != first:
                raise ValueError(
                    f"option samples: {name}[{i}] differs in structure from {name}[0] "
                    "(type, number of layers or modes, static options): the samples of one "
                    "name must share one structure"
                )
        return jax.tree_util.tree_map(lambda *a: jnp.stack([jnp.asarray(x) for x in a]), *value)
    leaves = jax.tree_util.tree_leaves(value)
    if not leaves:
        raise ValueError(f"option samples: {name} = {show(value)} holds no arrays; {_SAMPLES_NEED}")
    return jax.tree_util.tree_map(jnp.asarray, value)


def _count(name: str, batch) -> int:
    sizes = {int(np.shape(a)[0]) if np.ndim(a) else 0 for a in jax.tree_util.tree_leaves(batch)}
    if len(sizes) != 1 or 0 in sizes:
        raise ValueError(
            f"option samples: the arrays of {name} have leading axes {sorted(sizes)}: "
            "need one leading sample axis of one length >= 1"
        )
    return sizes.pop()


def sample_at(samples: dict, i) -> dict:
    """Sample i of a checked batch: {name: value}."""
    return jax.tree_util.tree_map(lambda a: a[i], samples)


def check_samples(samples, base: Params, fixed=()) -> tuple[dict | None, int]:
    """(samples as a batch of arrays, S), or (None, 1) for `samples=None`.

    Refuses, naming what is wrong, anything but a non-empty dict of names `base.replace`
    takes, with one leading sample axis of one length, names in `fixed` (those the
    optimisation itself sets), and samples whose values are out of range (each sample's
    scene is built once here, so the parameter's own check names it)."""
    if samples is None:
        return None, 1
    if not isinstance(samples, dict) or not samples:
        raise ValueError(f"option samples = {show(samples)}: {_SAMPLES_NEED}")
    clash = sorted(set(samples) & set(fixed))
    if clash:
        raise ValueError(
            f"option samples: {', '.join(clash)} is set by the optimisation itself "
            "(bounds); it cannot be sampled too"
        )
    batch = {name: _as_batch(name, v) for name, v in samples.items()}
    counts = {name: _count(name, b) for name, b in batch.items()}
    if len(set(counts.values())) != 1:
        raise ValueError(
            f"option samples: the names have different numbers of samples {counts}: need "
            "one number for all"
        )
    n = next(iter(counts.values()))
    for i in range(n):
        try:
            base.replace(**sample_at(batch, i))
        except (TypeError, ValueError) as e:
            raise type(e)(f"option samples, sample {i}: {e}") from None
    return batch, n


def describe_samples(samples: dict | None) -> dict | None:
    """The samples for a result header: their number, names and a SHA-256 of their
    values and structure (so that a run with other samples is another problem)."""
    if samples is None:
        return None
    n = _count("samples", samples)
    return {"count": n, "names": sorted(samples), "sha256": tree_digest(samples)}


def per_sample(run: Callable, base: Params, samples: dict | None):
    """`run(scene)` on every sample's scene, as one `jax.vmap` batch (a leading axis of
    S = 1 without samples)."""
    if samples is None:
        return jax.tree_util.tree_map(lambda a: jnp.asarray(a)[None], run(base))
    return jax.vmap(lambda s: run(base.replace(**s)))(samples)


def pool(values, aux: dict) -> tuple:
    """(mean of `values`, aux over the samples): the status of the first sample that
    is not ok (0 if all are), the cracks of all samples, their mean velocity."""
    status = aux["status"]
    first = jnp.argmax(status != 0)
    return jnp.mean(values), {
        "status": status[first],
        "n_cracks": jnp.sum(aux["n_cracks"]),
        "velocity": jnp.mean(aux["velocity"]),
    }

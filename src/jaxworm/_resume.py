"""The state a history file keeps so that a rerun continues where a killed run stopped.

`optimise` and `train` save, after every step, the state the next step starts from (the
points, the optax state) as its flat leaves beside the history (`state_arrays`). A rerun
of the same problem reads them back (`saved_state`), rebuilds the state on the structure
of its own (`restore`) and takes the remaining steps: the same program from the same
arrays, so the resumed history equals the uninterrupted one bit for bit.
"""

from __future__ import annotations

import re
import warnings
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["numpy_leaves", "state_arrays", "saved_state", "restore", "resumable"]

_PREFIX = "state_"
_KEY = re.compile(rf"{_PREFIX}(\d+)")


def _is_key(a) -> bool:
    return isinstance(a, jax.Array) and jnp.issubdtype(a.dtype, jax.dtypes.prng_key)


def _plain(a: np.ndarray) -> np.ndarray:
    """`a`, or its bits as unsigned integers when its dtype is not NumPy's own (bfloat16,
    float8: `.npy` stores those as raw bytes that read back as another dtype)."""
    return a.view(np.dtype(f"u{a.dtype.itemsize}")) if a.dtype.kind == "V" else a


def numpy_leaves(state) -> list[np.ndarray]:
    """The leaves of `state` (a pytree of arrays) as NumPy arrays: a JAX PRNG key (an
    optimiser's noise, say) by its key data, a bfloat16 or float8 array by its bits."""
    return [
        _plain(np.asarray(jax.random.key_data(a) if _is_key(a) else a))
        for a in jax.tree_util.tree_leaves(state)
    ]


def state_arrays(state) -> dict[str, np.ndarray]:
    """The leaves of `state` (`numpy_leaves`) as file members `state_0`, `state_1`, ..."""
    return {f"{_PREFIX}{i}": a for i, a in enumerate(numpy_leaves(state))}


def saved_state(arrays: dict[str, np.ndarray]) -> list[np.ndarray] | None:
    """The saved leaves among a file's `arrays`, in order (None if it keeps none: a file
    written before states were saved); ValueError if they are not numbered 0, 1, ..."""
    found = {int(m.group(1)): a for k, a in arrays.items() if (m := _KEY.fullmatch(k))}
    if not found:
        return None
    if sorted(found) != list(range(len(found))):
        raise ValueError(f"its saved state's members {sorted(found)} are not numbered 0, 1, ...")
    return [found[i] for i in range(len(found))]


def restore(leaves: list[np.ndarray] | None, like) -> tuple[Any, str]:
    """(`like`'s pytree holding the saved `leaves` (`numpy_leaves`), "") when they fit
    its leaves' shapes and dtypes, else (None, why not). `like` holds arrays (its PRNG
    keys give the key implementation)."""
    if leaves is None:
        return None, "the file keeps no optimiser state (written by an older jaxworm)"
    flat, treedef = jax.tree_util.tree_flatten(like)
    if len(leaves) != len(flat):
        return None, f"its saved state has {len(leaves)} arrays, the optimiser's {len(flat)}"
    for i, (a, b) in enumerate(zip(leaves, numpy_leaves(like))):
        if a.shape != b.shape or a.dtype != b.dtype:
            return None, (
                f"its saved state's array {i} is {a.dtype}{list(a.shape)}, the optimiser's "
                f"{b.dtype}{list(b.shape)}"
            )
    rebuilt = [
        jax.random.wrap_key_data(jnp.asarray(a), impl=jax.random.key_impl(b))
        if _is_key(b)
        else jnp.asarray(a.view(np.asarray(b).dtype))
        for a, b in zip(leaves, flat)
    ]
    return treedef.unflatten(rebuilt), ""


def resumable(command: str, old, header: dict, like, path, stacklevel: int = 2):
    """The state to continue `old` (a history of this problem at `path`, with `header`,
    `state`, `steps_done`) from, in the structure of `like` (`restore`); or None: no
    history, no step saved, or one this run cannot continue (written by another jaxworm,
    or with no state fitting the optimiser), which `command` then recomputes, with a
    warning (`stacklevel`, as `warnings.warn`'s, counted from the caller)."""
    if old is None or not old.steps_done:
        return None
    state, why = None, f"it was written by jaxworm {old.header.get('version')}"
    if old.header.get("version") == header.get("version"):
        state, why = restore(old.state, like)
    if state is None:
        warnings.warn(
            f"{command}: cannot resume {str(path)!r} ({why}): recomputing from step 0 (the "
            "file is kept until this run has as many steps)",
            RuntimeWarning,
            stacklevel=stacklevel + 1,
        )
        return None
    return state

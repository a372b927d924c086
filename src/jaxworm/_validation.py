"""Construction-time checks of Python values, with errors that name the parameter."""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np


def to_float(x):
    """Convert Python and NumPy numbers to float64 JAX arrays; leave the rest alone."""
    if isinstance(x, bool):
        return x
    if isinstance(x, (int, float, np.ndarray, np.generic)):
        return jnp.asarray(x, dtype=jnp.float64)
    return x


def concrete(x) -> bool:
    """True when `x` holds values (not a tracer under jit/vmap/grad)."""
    return not isinstance(x, jax.core.Tracer)


def show(x) -> str:
    a = np.asarray(x)
    return repr(float(a)) if a.ndim == 0 else np.array2string(a, threshold=6)


def check_range(name: str, value, ok: Callable, allowed: str) -> None:
    """Raise `ValueError` naming `name`, the value and the range unless `ok(value)`.

    Traced values are skipped here; the solve checks them (`params_valid`).
    """
    if not concrete(value):
        return
    a = np.asarray(value, dtype=float)
    if not np.all(np.isfinite(a)) or not np.all(ok(a)):
        raise ValueError(f"parameter {name} = {show(value)} is out of range: need {name} {allowed} (finite)")

"""Construction-time checks of Python values, with errors that name the parameter.

One path for the API and the command line: every scalar parameter goes through
`to_float` (its converter) and `check_range` (its check). Wrong types (strings, `None`,
lists, bools, complex numbers) raise `TypeError`, and values out of range (NaN and
±inf included) `ValueError`; both name the parameter, the value given and what is
allowed. Traced values are not checked here (they hold no value yet): the solve checks
them (`params_valid`) and reports a named status instead.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import jax
import jax.core
import jax.numpy as jnp
import numpy as np

__all__ = [
    "to_float",
    "concrete",
    "show",
    "check_range",
    "check_int",
    "check_instance",
    "check_option_float",
    "option_float",
    "check_t1",
    "check_choice",
]


def is_real_dtype(dtype) -> bool:
    """Integer or floating, not bool or complex."""
    return np.dtype(dtype).kind in "iuf"


def to_float(x: Any) -> Any:
    """Convert real numbers (Python, NumPy, JAX; float32 and ints included) to float64
    arrays; leave anything else (strings, None, bools, lists, ints too large for a
    float) unchanged for `check_range` to refuse by name.

    Typed `Any -> Any` because it returns what it cannot convert unchanged: as the
    converter of the `Float[Array, ""]` fields of `Params`, it lets the constructor
    take Python numbers, and the field's check refuses the rest."""
    if isinstance(x, (bool, np.bool_)):
        return x
    if isinstance(x, jax.Array):  # tracers included
        return x.astype(jnp.float64) if is_real_dtype(x.dtype) else x
    if isinstance(x, int):
        try:
            x = float(x)
        except OverflowError:  # beyond the float range: refused by check_range
            return x
    if isinstance(x, (float, np.ndarray, np.generic)):
        if not is_real_dtype(np.asarray(x).dtype):
            return x
        return jnp.asarray(x, dtype=jnp.float64)
    return x


def static_int(x: Any) -> Any:
    """A NumPy integer, or a concrete 0-d integer array, as a Python int (the converter of
    static integer fields, where equinox warns of arrays); anything else unchanged, for
    the field's check to refuse by name."""
    if isinstance(x, (bool, np.bool_)):
        return x
    if isinstance(x, np.integer):
        return int(x)
    if (
        isinstance(x, (np.ndarray, jax.Array))
        and concrete(x)
        and x.ndim == 0
        and np.issubdtype(x.dtype, np.integer)
    ):
        return int(x)
    return x


def concrete(x) -> bool:
    """True when `x` holds values (not a tracer under jit/vmap/grad)."""
    return not isinstance(x, jax.core.Tracer)


def show(x) -> str:
    """A short text of a value for messages (huge integers abbreviated)."""
    if isinstance(x, int) and not isinstance(x, bool) and abs(x) >= 10**15:
        return f"{'-' if x < 0 else ''}~1e{len(str(abs(x))) - 1} (an integer)"
    if isinstance(x, (int, np.integer)) and not isinstance(x, (bool, np.bool_)):
        return str(int(x))
    if isinstance(x, (str, type(None), bool, np.bool_, list, tuple, dict, complex)):
        text = repr(x)
        return text if len(text) <= 40 else text[:37] + "..."
    try:
        a = np.asarray(x)
    except Exception:  # noqa: BLE001 - any object: show its type
        return f"<{type(x).__name__}>"
    if a.dtype.kind not in "iufb":
        return f"<{type(x).__name__}>"
    return repr(float(a)) if a.ndim == 0 else np.array2string(a, threshold=6)


def _type_error(name: str, value, allowed: str, kind: str = "parameter") -> TypeError:
    return TypeError(
        f"{kind} {name} = {show(value)} ({type(value).__name__}) is not a real "
        f"number: need a float, {name} {allowed}"
    )


def check_range(name: str, value, ok: Callable, allowed: str, kind: str = "parameter") -> None:
    """Refuse `value` unless it is one real number (a scalar, for a batch vmap over
    scalars) with `ok(value)`: `TypeError` for a wrong type, `ValueError` for a wrong
    shape or a value out of range (non-finite included), naming `name`, the value and
    the range.

    Traced values only have their type and shape checked here; the solve checks their
    values (`params_valid`).
    """
    if isinstance(value, int) and not isinstance(value, bool):  # beyond the float range
        raise ValueError(
            f"{kind} {name} = {show(value)} is out of range: need {name} {allowed} (finite)"
        )
    if (
        not isinstance(value, (jax.Array, np.ndarray, np.generic))
        or isinstance(value, np.bool_)
        or not is_real_dtype(value.dtype)
    ):
        raise _type_error(name, value, allowed, kind)
    if np.ndim(value) != 0:
        raise ValueError(
            f"{kind} {name} of shape {np.shape(value)}: need one number, "
            f"{name} {allowed} (for a batch, vmap over scalars)"
        )
    if not concrete(value):
        return
    a = np.asarray(value, dtype=float)
    if not np.all(np.isfinite(a)) or not np.all(ok(a)):
        raise ValueError(
            f"{kind} {name} = {show(value)} is out of range: need {name} {allowed} (finite)"
        )


def check_int(name: str, value, lo: int, hi: int | None, kind: str = "parameter") -> None:
    """Refuse `value` unless it is an integer (Python or NumPy, not a bool) in [lo, hi]
    (no upper bound for `hi=None`): `ValueError` for a number out of range or not whole,
    `TypeError` for anything else."""
    allowed = f"need an integer {name} >= {lo}" + ("" if hi is None else f" and <= {hi}")
    if isinstance(value, (bool, np.bool_)) or not isinstance(
        value, (int, np.integer, float, np.floating)
    ):
        raise TypeError(
            f"{kind} {name} = {show(value)} ({type(value).__name__}) is not an integer: {allowed}"
        )
    if not isinstance(value, (int, np.integer)):
        raise ValueError(f"{kind} {name} = {show(value)} is not an integer: {allowed}")
    if not (lo <= value and (hi is None or value <= hi)):
        raise ValueError(f"{kind} {name} = {show(value)} is out of range: {allowed}")


def check_instance(name: str, value, cls: type, example: str, kind: str = "option") -> None:
    """Refuse `value` unless it is a `cls`: `TypeError` naming the option, the value, its
    type and what is allowed (`example`, e.g. "jw.PRESETS['fast']")."""
    if not isinstance(value, cls):
        raise TypeError(
            f"{kind} {name} = {show(value)} ({type(value).__name__}) is not a "
            f"{cls.__name__}: need a jaxworm {cls.__name__}, e.g. {example}"
        )


def check_t1(t1):
    """`t1` as a float64 array, refused (naming t1) unless one finite number > 0 [s];
    a traced t1 is checked in the solve instead (`invalid_parameters`)."""
    t1 = to_float(t1)
    check_range("t1", t1, lambda v: v > 0, "> 0 [s]")
    return t1


def ts_valid(ts, t1):
    """Whether traced output times pass `check_ts`: finite, non-decreasing and within
    [0, t1] (a traced run's own check, in place of diffrax's at run time: see
    `jaxworm._solve`'s `_without_runtime_checks`)."""
    finite = jnp.all(jnp.isfinite(ts), axis=-1)
    ordered = jnp.all(ts[..., 1:] >= ts[..., :-1], axis=-1)
    return finite & ordered & (ts[..., 0] >= 0) & (ts[..., -1] <= t1)


def check_ts(ts, t1):
    """`ts` (the output times of a dense trajectory) as a float64 array, refused (naming
    ts) unless one-dimensional, not empty, finite, non-decreasing and within [0, t1] [s]
    (`t1` the horizon simulated). Traced times, or a traced t1, are checked in the solve
    instead (`ts_valid`: `invalid_parameters`)."""
    if ts is None:
        return None
    try:
        real = is_real_dtype(ts.dtype if isinstance(ts, jax.Array) else np.asarray(ts).dtype)
    except (TypeError, ValueError):  # ragged nesting and the like
        real = False
    if not real:
        raise TypeError(f"ts = {show(ts)}: need real numbers, the output times [s]")
    ts = jnp.asarray(ts, dtype=jnp.float64)
    if ts.ndim != 1:
        raise ValueError(f"ts has shape {ts.shape}: need one dimension (the output times [s])")
    if ts.shape[0] == 0:
        raise ValueError("ts is empty: need at least one output time [s] (or ts=None)")
    if not concrete(ts):
        return ts
    values = np.asarray(ts)
    bad = ~np.isfinite(values)
    if bad.any():
        raise ValueError(
            f"ts[{int(np.argmax(bad))}] = {float(values[bad][0])!r}: need finite times [s]"
        )
    drops = np.flatnonzero(np.diff(values) < 0)
    if drops.size:
        i = int(drops[0])
        raise ValueError(
            f"ts[{i + 1}] = {float(values[i + 1])!r} < ts[{i}] = {float(values[i])!r}: "
            "need non-decreasing times"
        )
    if concrete(t1) and values.size:
        end = float(t1)
        outside = (values < 0) | (values > end)
        if outside.any():
            i = int(np.argmax(outside))
            raise ValueError(
                f"ts[{i}] = {float(values[i])!r}: need 0 <= ts <= {end!r} [s], "
                "the horizon simulated"
            )
    return ts


def option_float(x: Any) -> Any:
    """Converter of the float options of `Numerics`: NumPy scalars (float32 included) and
    0-d arrays to Python floats (hashable, static), Python ints to floats; JAX arrays
    and tracers, None and anything else unchanged (checked by `check_option_float`;
    hence `Any -> Any`)."""
    if isinstance(x, (bool, np.bool_)):
        return x
    if isinstance(x, int):
        try:
            return float(x)
        except OverflowError:
            return x
    if (
        isinstance(x, (np.generic, np.ndarray))
        and np.ndim(x) == 0
        and is_real_dtype(np.asarray(x).dtype)
    ):
        return float(x)
    return x


def check_option_float(
    name: str, value, ok: Callable, allowed: str, allow_none: bool = False
) -> None:
    """`check_range` for a float option of `Numerics` (Python floats, JAX arrays or
    tracers; None where `allow_none`)."""
    if value is None and allow_none:
        return
    if isinstance(value, float):
        if not (math.isfinite(value) and ok(value)):
            raise ValueError(
                f"option {name} = {value!r} is out of range: need {name} {allowed} "
                f"(finite){' or None' if allow_none else ''}"
            )
        return
    check_range(name, value, ok, allowed + (" or None" if allow_none else ""), kind="option")


def check_choice(name: str, value, choices: tuple) -> None:
    """Refuse a static option `value` unless it is one of `choices` (compared by type
    and value, so `1` is not `True`): `ValueError` naming the option, the value and the
    choices."""
    if not any(type(value) is type(c) and value == c for c in choices):
        allowed = " or ".join(repr(c) for c in choices)
        raise ValueError(f"option {name} = {show(value)}: need {allowed}")

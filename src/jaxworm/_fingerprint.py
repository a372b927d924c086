"""Fingerprints for result headers: SHA-256 digests of scenes and of callables.

A result file is resumed (or replaced) only by the same run, so its header must tell
apart everything that makes another run. Readable fields (`Params.flat`, an objective's
name) do not: two `SegmentWave` phases, two `PolicyMLP` weights or two lambdas would pass
as equal. These digests identify the whole thing, and depend on values only (no memory
address, no hash seed), so a rerun in another process with equal values matches its
own file:

- `tree_digest`: a pytree (a `Params`, a controller, samples): its structure (the treedef,
  static fields included, addresses removed) and every leaf, by path (arrays by dtype,
  shape and bytes; callables by `callable_digest`; other objects as below);
- `callable_digest`: a function by its code (bytecode, constants recursively, global
  names), defaults and closure values (numbers, strings, arrays, containers of them,
  functions and Modules; other objects by their type and what they hold: a dataclass's
  fields, instance attributes, slots, else their repr without addresses; loggers, locks,
  files and random generators by type alone). A function's
  name is not part of it (the header records the name beside it), nor are the values of
  the globals it names;
- `scene_fingerprint`: a `Params` as a header field, its parts' classes and digest;
  `callable_fields`: a callable's digest as a header field.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import inspect
import io
import logging
import re
import threading
import types

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from . import _files

__all__ = [
    "tree_digest",
    "callable_digest",
    "callable_fields",
    "scene_fingerprint",
    "no_addresses",
]

#: How deep closures and nested code are followed (a cycle stops at the first repeat).
_MAX_DEPTH = 8


def no_addresses(text: str) -> str:
    """`text` without memory addresses (` at 0x7f...`), which differ from run to run."""
    return re.sub(r" at 0x[0-9a-fA-F]+", "", text)


def _type_name(x) -> str:
    return f"{type(x).__module__}.{type(x).__qualname__}"


def _plain_array(x) -> np.ndarray | None:
    """`x` as a NumPy array when it is an array or number of numbers (PRNG keys by their
    data), else None."""
    if isinstance(x, jax.Array) and jnp.issubdtype(x.dtype, jax.dtypes.prng_key):
        return np.asarray(jax.random.key_data(x))
    if isinstance(x, (jax.Array, np.ndarray, np.generic, bool, int, float, complex)):
        try:
            a = np.asarray(x)
        except Exception:  # noqa: BLE001 - a huge int, a tracer: not plain
            return None
        return a if a.dtype.kind in "biufc" else None
    return None


def _leaf(leaf, depth: int) -> np.ndarray:
    """One pytree leaf as a member of the digest."""
    a = _plain_array(leaf)
    if a is not None:
        return a
    if isinstance(leaf, str):
        return np.asarray("str:" + leaf)
    if callable(leaf):
        return np.asarray("callable:" + _callable(leaf, depth + 1))
    h = _Hash()
    _object(h, leaf, depth + 1)
    return np.asarray("object:" + h.h.hexdigest())


def _tree(tree, depth: int) -> str:
    flat, treedef = jax.tree_util.tree_flatten_with_path(tree)
    members = {
        "structure": np.asarray(no_addresses(str(treedef))),
        **{jax.tree_util.keystr(path): _leaf(leaf, depth) for path, leaf in flat},
    }
    return _files.digest(members)


def tree_digest(tree) -> str:
    """SHA-256 (hex) of a pytree: its treedef (static fields included, addresses removed)
    and its leaves by path, arrays by dtype, shape and values, callables by
    `callable_digest`, other objects by their type and what they hold."""
    return _tree(tree, 0)


class _Hash:
    """A SHA-256 fed with tagged, length-prefixed parts (so parts cannot run together)."""

    def __init__(self):
        self.h = hashlib.sha256()

    def add(self, tag: str, data: bytes = b"") -> None:
        self.h.update(f"{tag}:{len(data)}:".encode())
        self.h.update(data)


def _constant(h: _Hash, c, depth: int) -> None:
    """A code object's constant: nested code followed, frozensets in sorted order."""
    if isinstance(c, types.CodeType):
        _code(h, c, depth + 1)
    elif isinstance(c, tuple):
        h.add("tuple", str(len(c)).encode())
        for x in c:
            _constant(h, x, depth)
    elif isinstance(c, frozenset):
        h.add("frozenset", repr(sorted(repr(x) for x in c)).encode())
    else:
        h.add(type(c).__name__, repr(c).encode())


def _code(h: _Hash, code: types.CodeType, depth: int) -> None:
    if depth > _MAX_DEPTH:
        h.add("code-too-deep")
        return
    h.add("co_code", code.co_code)
    h.add("co_names", repr(code.co_names).encode())
    h.add("co_consts", str(len(code.co_consts)).encode())
    for c in code.co_consts:
        _constant(h, c, depth)


def _value(h: _Hash, v, depth: int) -> None:
    """A value a function holds (closure cell, default, bound object, partial argument)."""
    if depth > _MAX_DEPTH:
        h.add("value-too-deep")
        return
    a = _plain_array(v)
    if a is not None:
        h.add("array", f"{a.dtype.str}{list(a.shape)}".encode())
        h.add("bytes", np.ascontiguousarray(a).tobytes())
    elif v is None or isinstance(v, (str, bytes)):
        h.add(type(v).__name__, repr(v).encode())
    elif isinstance(v, (tuple, list)):
        h.add(type(v).__name__, str(len(v)).encode())
        for x in v:
            _value(h, x, depth + 1)
    elif isinstance(v, (set, frozenset)):
        h.add(type(v).__name__, repr(sorted(repr(x) for x in v)).encode())
    elif isinstance(v, dict):
        h.add("dict", str(len(v)).encode())
        for k in sorted(v, key=repr):
            h.add("key", repr(k).encode())
            _value(h, v[k], depth + 1)
    elif isinstance(v, eqx.Module):
        h.add("pytree", _tree(v, depth + 1).encode())
    elif isinstance(v, types.ModuleType):
        h.add("module", v.__name__.encode())
    elif isinstance(v, _RUN_STATE):
        h.add("object", _type_name(v).encode())
    elif callable(v):
        h.add("callable", _callable(v, depth + 1).encode())
    else:
        _object(h, v, depth)


#: Objects whose state changes as the process runs and says nothing of what a callable
#: computes (a logger's registry, a lock, a file, a random generator's position): named
#: by their type alone, so that a rerun in the same session matches its own file.
_RUN_STATE: tuple[type, ...] = (
    logging.Logger,
    logging.Handler,
    logging.Manager,
    type(threading.Lock()),
    type(threading.RLock()),
    threading.Condition,
    threading.Event,
    threading.Semaphore,
    threading.Thread,
    io.IOBase,
    np.random.Generator,
    np.random.BitGenerator,
)


def _held(v) -> dict:
    """The data an object holds: a dataclass's fields, its slots, its instance
    attributes (read without its `__getattr__`; an attribute that cannot be read is
    left out)."""
    held = {}
    if dataclasses.is_dataclass(v):
        for f in dataclasses.fields(v):
            try:
                held[f.name] = object.__getattribute__(v, f.name)
            except Exception:  # noqa: BLE001 - a field the object does not hold
                pass
    for cls in type(v).__mro__:
        slots = cls.__dict__.get("__slots__", ())
        for name in (slots,) if isinstance(slots, str) else slots:
            if name in ("__dict__", "__weakref__") or name in held:
                continue
            try:
                held[name] = object.__getattribute__(v, name)
            except Exception:  # noqa: BLE001 - an empty slot
                pass
    try:
        attributes = object.__getattribute__(v, "__dict__")
    except Exception:  # noqa: BLE001 - none
        attributes = None
    if isinstance(attributes, dict):
        held.update(attributes)
    return held


def _object(h: _Hash, v, depth: int) -> None:
    """Any other object a callable holds: its type and the data it holds (`_held`,
    followed to the depth limit), or, holding none, its repr when that tells a value
    (not `<...>`)."""
    h.add("object", _type_name(v).encode())
    held = _held(v)
    if held:
        _value(h, held, depth + 1)
        return
    try:
        text = no_addresses(repr(v))
    except Exception:  # noqa: BLE001 - a repr that raises
        return
    if not text.startswith("<"):
        h.add("repr", text.encode())


def _callable(fn, depth: int) -> str:
    h = _Hash()
    if depth > _MAX_DEPTH:
        h.add("callable-too-deep")
        return h.h.hexdigest()
    try:
        fn = inspect.unwrap(fn)  # jax.jit and functools.wraps keep the function inside
    except ValueError:  # a cycle of __wrapped__
        pass
    if isinstance(fn, functools.partial):
        h.add("partial", _callable(fn.func, depth + 1).encode())
        _value(h, fn.args, depth + 1)
        _value(h, fn.keywords, depth + 1)
    elif inspect.ismethod(fn):
        h.add("method", _callable(fn.__func__, depth + 1).encode())
        _value(h, fn.__self__, depth + 1)
    elif isinstance(fn, types.FunctionType):
        _code(h, fn.__code__, depth)
        _value(h, fn.__defaults__, depth + 1)
        _value(h, fn.__kwdefaults__, depth + 1)
        for name, cell in zip(fn.__code__.co_freevars, fn.__closure__ or ()):
            h.add("free", name.encode())
            try:
                contents = cell.cell_contents
            except ValueError:  # an empty cell
                h.add("empty")
                continue
            _value(h, contents, depth + 1)
    elif isinstance(fn, eqx.Module):  # its data, and the code of its type's __call__
        h.add("module", _tree(fn, depth + 1).encode())
        h.add("call", _callable(type(fn).__call__, depth + 1).encode())
    elif isinstance(fn, (types.BuiltinFunctionType, type)) or not hasattr(fn, "__dict__"):
        qualname = getattr(fn, "__qualname__", getattr(fn, "__name__", ""))
        name = f"{getattr(fn, '__module__', '')}.{qualname}"
        h.add("named", name.encode())
        h.add("type", _type_name(fn).encode())
    else:  # an instance with __call__: the code of its type's __call__ and its attributes
        h.add("instance", _type_name(fn).encode())
        call = inspect.getattr_static(type(fn), "__call__", None)
        if isinstance(call, types.FunctionType):
            h.add("call", _callable(call, depth + 1).encode())
        _value(h, dict(vars(fn)), depth + 1)
    return h.h.hexdigest()


def callable_digest(fn) -> str:
    """SHA-256 (hex) of what a callable computes, as far as its code and the values it
    holds tell: a function's bytecode, constants (nested code followed), the global
    names it uses, its defaults and closure values; a `functools.partial` or bound
    method with its arguments or object; an `eqx.Module` by its data and its type's
    `__call__`; wrappers (`jax.jit`, `functools.wraps`) by the function inside; a
    builtin by its qualified name. Names (its own, its parameters') do not count, nor
    the values of the globals it uses."""
    return _callable(fn, 0)


def callable_fields(key: str, fn) -> dict:
    """`{key + "_sha256": callable_digest(fn)}`, for a header beside `key`; {} when `fn`
    is None or a name (a string, which says itself what it is)."""
    return {} if fn is None or isinstance(fn, str) else {f"{key}_sha256": callable_digest(fn)}


def scene_fingerprint(params) -> dict:
    """A `Params` for a result header: the class of each part (`body`, `soil`, `gait`,
    `smoothing`) and `tree_digest` of the whole scene."""
    return {
        "classes": {
            f.name: type(getattr(params, f.name)).__name__
            for f in dataclasses.fields(params)
            if isinstance(getattr(params, f.name), eqx.Module)
        },
        "sha256": tree_digest(params),
    }

"""Programs kept between Python processes: JAX's persistent compilation cache, and the
traced programs of `simulate` and of a sweep's chunks, exported with `jax.export`.

A first `simulate` in a fresh process spends most of its time tracing the solver (about
1.5 s on 2 cores) before it can even look up the compiled program in JAX's persistent
cache. Here the traced program of each distinct static setup (the structure of the
parameters and numerics, the values of the static options, the shapes and dtypes of the
arrays, and the versions of jaxworm's source, JAX, jaxlib, diffrax and equinox) is kept
as a serialized `jax.export.Exported`: a later process deserializes it instead of
tracing, and its compiled form comes from the persistent compilation cache.

It is the same program, so results are bit-identical to the traced path. It serves only
calls whose inputs all hold values: under `jit`, `vmap` or a derivative, `simulate`
traces as usual.

The folder is `$JAXWORM_CACHE_DIR`, else `~/.cache/jaxworm`; `JAXWORM_CACHE_DIR=""`
turns both caches off (set it before the first solve). The compilation cache goes to its
`jax/` subfolder unless JAX already has a cache folder set (`jax_compilation_cache_dir`),
which is then respected. The folder holds only what jaxworm wrote, and the programs in
it are executable code: trust it as you trust the package's `__pycache__`.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import os
import tempfile
from collections.abc import Callable
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import equinox as eqx
import jax

__all__ = ["cache_dir", "configure_compilation_cache", "exported_call", "result_skeleton"]

_PACKAGE = Path(__file__).parent
_configured: str | None = None
_programs: dict[str, Callable | None] = {}


def cache_dir() -> Path | None:
    """The jaxworm cache folder, or None when caching is off (`JAXWORM_CACHE_DIR=""`)."""
    path = os.environ.get("JAXWORM_CACHE_DIR")
    if path is None:
        return Path.home() / ".cache" / "jaxworm"
    return Path(path) if path else None


def configure_compilation_cache(min_compile_time: float | None = None) -> str | None:
    """Point JAX's persistent compilation cache at `cache_dir()/jax`, unless JAX has a
    cache folder already (then that one is kept). Returns the folder in use (None: off).

    `min_compile_time` [s] sets `jax_persistent_cache_min_compile_time_secs` (the CLI
    keeps every program: 0); None leaves JAX's threshold.
    """
    global _configured
    root = cache_dir()
    if root is None:
        return None
    current = jax.config.values["jax_compilation_cache_dir"]
    if current is None or current == _configured:
        path = str(root / "jax")
        if current != path:
            # JAX opens its persistent cache at the first compilation of a process: a
            # folder set after that takes effect once the cache is reset.
            from jax.experimental.compilation_cache import compilation_cache

            jax.config.update("jax_compilation_cache_dir", path)
            compilation_cache.reset_cache()
        _configured = current = path
    if min_compile_time is not None:
        jax.config.update("jax_persistent_cache_min_compile_time_secs", min_compile_time)
        jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)
    return current


@functools.cache
def _versions() -> str:
    parts = [jax.__version__, jax.default_backend(), str(jax.config.values["jax_enable_x64"])]
    for name in ("jaxlib", "diffrax", "equinox"):
        try:
            parts.append(version(name))
        except PackageNotFoundError:
            parts.append("?")
    source = hashlib.sha256()
    for f in sorted(_PACKAGE.glob("*.py")):
        source.update(f.name.encode())
        source.update(f.read_bytes())
    parts.append(source.hexdigest())
    return "|".join(parts)


def _key(name: str, static, dynamic) -> str:
    """The program's identity: everything that `eqx.filter_jit` would bake into it."""
    leaves, treedef = jax.tree_util.tree_flatten(dynamic)
    text = "\n".join(
        [
            name,
            _versions(),
            str(treedef),
            repr(jax.tree_util.tree_leaves(static)),
            repr(jax.tree_util.tree_structure(static)),
            repr([(x.shape, str(x.dtype), getattr(x, "weak_type", False)) for x in leaves]),
            str(jax.devices()[0].device_kind),
        ]
    )
    return hashlib.sha256(text.encode()).hexdigest()[:32]


_PLAIN = (str, int, float, bool, complex, type(None))


def _own(tree) -> bool:
    """Whether `tree` holds only jaxworm's Modules, containers, arrays and plain values."""
    if isinstance(tree, eqx.Module):
        if not type(tree).__module__.startswith("jaxworm."):
            return False
        return all(_own(getattr(tree, f.name)) for f in dataclasses.fields(tree))
    if isinstance(tree, (tuple, list)):
        return all(_own(x) for x in tree)
    if isinstance(tree, dict):
        return all(isinstance(k, str) and _own(v) for k, v in tree.items())
    return isinstance(tree, _PLAIN) or eqx.is_array(tree)


def result_skeleton(result_cls, state_cls, trajectory_cls, dense: bool):
    """A `Result` of placeholders, for its tree structure (no tracing needed)."""

    def filled(cls, **given):
        names = [f.name for f in dataclasses.fields(cls)]
        return cls(**{n: given.get(n, 0) for n in names})

    traj = filled(trajectory_cls) if dense else None
    return filled(result_cls, final=filled(state_cls), trajectory=traj)


def exported_call(fn, name: str, args: tuple, out_structure):
    """`fn(*args)` through an exported program kept on disk (see the module docstring);
    None when it cannot be used (caching off, an unwritable folder, a stale or damaged
    file), so the caller runs `fn` as usual.

    `fn` is a pure function of `args` (pytrees; arrays are inputs, everything else is
    static); `out_structure` is a pytree with the structure of its output. Only setups
    built from jaxworm's own classes and plain values are kept: the key holds jaxworm's
    source, not a user's, so a user's controller (whose code may change between
    processes under the same name) is always traced.
    """
    root = cache_dir()
    if root is None or not _own(args):
        return None
    dynamic, static = eqx.partition(args, eqx.is_array)
    key = _key(name, static, dynamic)
    flat, in_tree = jax.tree_util.tree_flatten(dynamic)
    out_tree = jax.tree_util.tree_structure(out_structure)
    if key not in _programs:
        try:
            _programs[key] = _load_or_export(
                fn,
                root / "exported" / f"{name}-{key}.bin",
                static,
                in_tree,
                flat,
                out_tree.num_leaves,
            )
        except NotImplementedError:
            # A program that cannot be serialized: one with host callbacks (a run-time
            # check, e.g. diffrax's of a fixed step's sign). It is traced as usual.
            _programs[key] = None
    call = _programs[key]
    if call is None:
        return None
    return jax.tree_util.tree_unflatten(out_tree, call(*flat))


def _load_or_export(fn, path: Path, static, in_tree, flat, n_out):
    exported = None
    try:
        exported = jax.export.deserialize(bytearray(path.read_bytes()))
    except FileNotFoundError:
        pass
    except Exception:  # a damaged or foreign file: export afresh and replace it
        exported = None
    if exported is not None and (
        len(exported.out_avals) != n_out or len(exported.in_avals) != len(flat)
    ):
        exported = None
    if exported is None:

        def flat_fn(*leaves):
            dynamic = jax.tree_util.tree_unflatten(in_tree, leaves)
            out = fn(*eqx.combine(dynamic, static))
            return tuple(jax.tree_util.tree_leaves(out))

        specs = [
            jax.ShapeDtypeStruct(x.shape, x.dtype, weak_type=getattr(x, "weak_type", False))
            for x in flat
        ]
        exported = jax.export.export(jax.jit(flat_fn))(*specs)
        if len(exported.out_avals) != n_out:
            return None
        _write_atomic(path, bytes(exported.serialize()))
    return jax.jit(exported.call)


def _write_atomic(path: Path, data: bytes) -> None:
    """Best effort: a cache that cannot be written is a cache miss next time."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except OSError:
        pass

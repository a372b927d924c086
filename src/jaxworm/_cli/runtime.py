"""JAX's runtime for a command: CPU devices and the persistent compilation cache.

float64 is switched on by `import jaxworm` itself.
"""

from __future__ import annotations

import os

import jax
from jax.experimental.compilation_cache import compilation_cache


def use_all_cores() -> None:
    """One JAX CPU device per core, so that sweeps run a chunk on each (`jw.sweep`).
    Only before JAX's backend starts, and never over a user's own device count."""
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_force_host_platform_device_count" not in flags:
        cores = (len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
                 else os.cpu_count())
        os.environ["XLA_FLAGS"] = (
            f"{flags} --xla_force_host_platform_device_count={cores or 1}".strip())


def configure_cache() -> str | None:
    """Point JAX's persistent compilation cache at the jaxworm cache folder:
    `JAXWORM_CACHE_DIR`, else `~/.cache/jaxworm/jax`; none when that variable is empty.
    Returns the folder."""
    path = os.environ.get("JAXWORM_CACHE_DIR")
    if path is None:
        path = os.path.join(os.path.expanduser("~"), ".cache", "jaxworm", "jax")
    if not path:
        return None
    if jax.config.jax_compilation_cache_dir != path:
        # JAX opens its persistent cache once per process, at the first compilation: a
        # folder set after that (an earlier compile in a notebook, or another command
        # with another folder) only takes effect once the cache is reset.
        jax.config.update("jax_compilation_cache_dir", path)
        compilation_cache.reset_cache()
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)
    return path

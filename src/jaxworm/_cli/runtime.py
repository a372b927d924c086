"""JAX's runtime for a command: CPU devices and the persistent compilation cache.

float64 is switched on by `import jaxworm` itself.
"""

from __future__ import annotations

import os

from .._cache import configure_compilation_cache


def use_all_cores() -> None:
    """One JAX CPU device per core, so that sweeps run a chunk on each (`jw.sweep`).
    Only before JAX's backend starts, and never over a user's own device count."""
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_force_host_platform_device_count" not in flags:
        cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
        os.environ["XLA_FLAGS"] = (
            f"{flags} --xla_force_host_platform_device_count={cores or 1}".strip()
        )


def configure_cache() -> str | None:
    """JAX's persistent compilation cache in the jaxworm cache folder (`jaxworm._cache`),
    keeping every program a command compiles. Returns the folder (None: caching off)."""
    return configure_compilation_cache(min_compile_time=0.0)

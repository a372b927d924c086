"""Threads that solve at once on one JAX device: how many a CPU gives.

One XLA CPU solve runs on one core, and calls of one compiled program from several
Python threads run in parallel on one CPU device. Sweeps (chunks of scenes) and
optimisations (groups of starts) use that to put every core to work with one program.
An accelerator runs its solves one after another however many threads dispatch them.
"""

from __future__ import annotations

import os

__all__ = ["cores", "default_workers", "MAX_WORKERS"]

#: The most threads a sweep or optimisation takes per device.
MAX_WORKERS = 1024


def cores() -> int:
    """The cores this process may use (its CPU affinity; a container's CPU quota is not
    read: pass `workers` where it is lower)."""
    n = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return max(1, n or 1)


def default_workers(devices) -> int:
    """Threads per entry of `devices`: the cores shared among the CPU entries, 1 when
    any entry is an accelerator."""
    cpus = sum(d.platform == "cpu" for d in devices)
    if cpus < len(devices):
        return 1
    return max(1, cores() // cpus)

"""Several processes, one computation: JAX's multi-controller runtime (`jax.distributed`).

After `jax.distributed.initialize()` every process runs the same Python program and sees
every device, but computes only on its own (`jax.local_devices()`). Sweeps and
optimisation starts split their work by process (`share_of`); the first process (the
leader, index 0) alone reads and writes result files and shows progress, and tells the
others what it read (`from_leader`); each finished round of work reaches every process
(`gather`), so all of them return the same result. With one process every function here
is the identity, so one code path serves one process and many.

Collectives between CPU processes go through Gloo (JAX's default CPU collectives).
"""

from __future__ import annotations

import hashlib
import json

import jax
import numpy as np
from jax.experimental import multihost_utils

__all__ = [
    "process",
    "check_same_run",
    "is_leader",
    "gather",
    "from_leader",
    "leader_verdict",
    "share_of",
    "initialize",
]


def process() -> tuple[int, int]:
    """(this process's index, the number of processes)."""
    return jax.process_index(), jax.process_count()


def is_leader() -> bool:
    """Whether this process is the one that writes files and shows progress (index 0)."""
    return jax.process_index() == 0


def gather(tree):
    """Every process's `tree` of NumPy arrays (the same shapes on all), stacked on a new
    leading axis in process order; with one process, `tree` with that axis added."""
    if jax.process_count() == 1:
        return jax.tree_util.tree_map(lambda a: np.asarray(a)[None], tree)
    return jax.tree_util.tree_map(np.asarray, multihost_utils.process_allgather(tree, tiled=False))


def _bits(a) -> np.ndarray:
    """An array other than integers and booleans as its bytes, on a new last axis (its
    bit pattern); integers and booleans as they are."""
    a = np.asarray(a)
    if a.dtype.kind in "biu":
        return a
    return a.copy(order="C")[..., None].view(np.uint8)


def _unbits(out, like) -> np.ndarray:
    """`_bits`'s inverse, to the dtype of `like`."""
    like, out = np.asarray(like), np.asarray(out)
    if like.dtype.kind in "biu":
        return out
    return out.copy(order="C").view(like.dtype)[..., 0]


def from_leader(tree):
    """The leader's `tree` of NumPy arrays, on every process (the others pass arrays of
    the same shapes and dtypes, whatever their values), bit for bit: JAX broadcasts by a
    sum with the others' zeros, which would turn -0.0 into +0.0, so arrays other than
    integers and booleans travel as their bytes."""
    if jax.process_count() == 1:
        return tree
    out = multihost_utils.broadcast_one_to_all(jax.tree_util.tree_map(_bits, tree))
    return jax.tree_util.tree_map(_unbits, out, tree)


_MESSAGE_BYTES = 4096


def leader_verdict(error: BaseException | None) -> None:
    """Raise on every process when the leader's checks failed (`error` on the leader;
    the others pass None): the leader re-raises its own error, the others a
    `RuntimeError` quoting it, so no process waits for work that will not come."""
    if jax.process_count() == 1:
        if error is not None:
            raise error
        return
    text = b"" if error is None else f"{type(error).__name__}: {error}".encode()[:_MESSAGE_BYTES]
    buf = np.zeros(_MESSAGE_BYTES + 1, np.int32)
    buf[0] = len(text) if error is not None else -1
    buf[1 : 1 + len(text)] = np.frombuffer(text, np.uint8)
    buf = from_leader(buf)
    if buf[0] < 0:
        return
    if error is not None and is_leader():
        raise error
    message = bytes(buf[1 : 1 + buf[0]].astype(np.uint8)).decode(errors="replace")
    raise RuntimeError(f"process 0 refused the run: {message}")


def check_same_run(what: str, description) -> None:
    """`ValueError` on every process unless all of them describe the same run
    (`description`: JSON-able, e.g. a result file's header and grid): processes given
    different arguments would otherwise merge the results of different runs."""
    if jax.process_count() == 1:
        return
    text = json.dumps(description, sort_keys=True, default=str).encode()
    digest = np.frombuffer(hashlib.sha256(text).digest(), np.uint8).astype(np.int32)
    every = gather(digest)
    differ = [i for i in range(every.shape[0]) if not np.array_equal(every[i], every[0])]
    if differ:
        raise ValueError(
            f"{what}: process {differ[0]} was given other arguments than process 0 "
            "(parameters, grid, t1, numerics or options); every process must run the same call"
        )


def share_of(n_items: int, index: int, count: int) -> slice:
    """The items [start, stop) of process `index` when `n_items` are split as evenly as
    possible over `count` processes, in order."""
    q, r = divmod(n_items, count)
    start = index * q + min(index, r)
    return slice(start, start + q + (index < r))


def initialize(
    coordinator: str | None = None, num_processes: int | None = None, process_id: int | None = None
) -> tuple[int, int]:
    """Start JAX's multi-controller runtime unless it runs already; returns `process()`.

    With no arguments JAX detects the cluster (SLURM, Open MPI, ...); otherwise give the
    coordinator's `host:port`, the number of processes and this process's id (0 is the
    leader). Call it before anything else uses JAX.
    """
    if not jax.distributed.is_initialized():
        jax.distributed.initialize(coordinator, num_processes, process_id)
    return process()

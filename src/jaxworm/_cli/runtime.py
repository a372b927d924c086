"""JAX's runtime for a command: the persistent compilation cache and several processes.

float64 is switched on by `import jaxworm` itself.
"""

from __future__ import annotations

import os

from .._cache import configure_compilation_cache


def configure_cache() -> str | None:
    """JAX's persistent compilation cache in the jaxworm cache folder (`jaxworm._cache`),
    keeping every program a command compiles. Returns the folder (None: caching off)."""
    return configure_compilation_cache(min_compile_time=0.0)


def add_process_options(cmd) -> None:
    """Options that start JAX's multi-controller runtime (`jax.distributed`), on the
    subcommand parser `cmd`."""
    from .values import host_port, positive_int

    g = cmd.add_argument_group(
        "several processes (jax.distributed)",
        "Run one such command per process (host, or GPU): each solves its share and "
        "process 0 writes the file and reports.",
    )
    g.add_argument(
        "--distributed",
        action="store_true",
        help="join a multi-process run whose coordinator, size and rank JAX finds in "
        "the environment (SLURM, Open MPI, ...)",
    )
    g.add_argument(
        "--coordinator",
        metavar="HOST:PORT",
        type=host_port("coordinator"),
        help="the coordinator's address (process 0 listens on PORT)",
    )
    g.add_argument(
        "--num-processes", type=positive_int("num-processes"), help="processes in the run"
    )
    g.add_argument(
        "--process-id",
        type=positive_int("process-id", low=0),
        help="this process (0 writes the file)",
    )


def start_processes(args) -> bool:
    """Join the multi-process run that `args` describes (`add_process_options`), before
    anything uses JAX; returns whether this process reports (process 0, or the only one)."""
    from .. import _distributed
    from .values import UsageError

    given = [args.coordinator, args.num_processes, args.process_id]
    if args.distributed and any(v is not None for v in given):
        raise UsageError(
            "--distributed finds the coordinator in the environment: drop --coordinator, "
            "--num-processes and --process-id, or drop --distributed"
        )
    if any(v is not None for v in given) and not all(v is not None for v in given):
        raise UsageError("--coordinator, --num-processes and --process-id go together")
    if all(v is not None for v in given) and args.process_id >= args.num_processes:
        raise UsageError(
            f"--process-id {args.process_id}: need 0 <= process-id < --num-processes "
            f"({args.num_processes})"
        )
    if args.distributed and not cluster_in_environment():
        raise UsageError(
            "--distributed: no cluster found in the environment (SLURM, Open MPI, "
            "Kubernetes, JAX_COORDINATOR_ADDRESS, ...): run the command under one, or "
            "give --coordinator HOST:PORT, --num-processes and --process-id instead"
        )
    if args.distributed or all(v is not None for v in given):
        try:
            _distributed.initialize(args.coordinator, args.num_processes, args.process_id)
        except ValueError as e:  # what JAX could not find in the environment
            option = "--distributed" if args.distributed else "--coordinator"
            raise UsageError(f"{option}: JAX cannot start the run: {e}") from None
        return _distributed.is_leader()
    return True


def cluster_in_environment() -> bool:
    """Whether `jax.distributed.initialize()` with no arguments finds a cluster to join:
    a coordinator address in `JAX_COORDINATOR_ADDRESS`, or a cluster JAX detects by
    itself (its `ClusterEnv`s: SLURM, Open MPI, Kubernetes, Cloud TPU). True when this
    JAX cannot be asked (then JAX decides)."""
    if os.environ.get("JAX_COORDINATOR_ADDRESS"):
        return True
    try:
        from jax._src.clusters import ClusterEnv
    except ImportError:  # pragma: no cover - another JAX layout
        return True
    kinds = getattr(ClusterEnv, "_cluster_types", None)
    if kinds is None:  # pragma: no cover - another JAX layout
        return True
    return any(not kind.opt_in_only_method and kind.is_env_present() for kind in kinds)

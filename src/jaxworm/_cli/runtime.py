"""JAX's runtime for a command: the persistent compilation cache and several processes.

float64 is switched on by `import jaxworm` itself.
"""

from __future__ import annotations

from .._cache import configure_compilation_cache


def configure_cache() -> str | None:
    """JAX's persistent compilation cache in the jaxworm cache folder (`jaxworm._cache`),
    keeping every program a command compiles. Returns the folder (None: caching off)."""
    return configure_compilation_cache(min_compile_time=0.0)


def add_process_options(cmd) -> None:
    """Options that start JAX's multi-controller runtime (`jax.distributed`), on the
    subcommand parser `cmd`."""
    from .values import positive_int

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
    g.add_argument("--coordinator", metavar="HOST:PORT", help="the coordinator's address")
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
    if args.distributed or all(v is not None for v in given):
        _distributed.initialize(args.coordinator, args.num_processes, args.process_id)
        return _distributed.is_leader()
    return True

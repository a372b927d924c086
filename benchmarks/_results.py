"""Where the benchmarks write, and what every result file records about its run.

Each benchmark writes under `results/<benchmark>/` (the script's name), its files named
`<stem>[_quick][<options>].<ext>`: `_quick` for a `--quick` run, then a suffix for each
option that differs from the script's default. Every JSON written through `write_json`
carries a `run` entry, `{command, machine, cores, date, load, code}`, from which `index.py`
builds `results/README.md`.

Imports no JAX, so scripts that configure JAX themselves can use it.
"""

from __future__ import annotations

import json
import os
import platform
import shlex
import subprocess
import sys
from datetime import UTC, datetime
from pathlib import Path

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"


def results_dir(benchmark: str, root: Path | None = None) -> Path:
    """`results/<benchmark>/` (under `root` instead of `results/` when given), created."""
    folder = (RESULTS if root is None else Path(root)) / benchmark
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def quick_suffix(quick: bool) -> str:
    """`_quick` for a `--quick` run's files, else ''."""
    return "_quick" if quick else ""


def cpu_model() -> str:
    """The CPU's model name (`/proc/cpuinfo`), else `platform.processor()`."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor()


def command_line() -> str:
    """The command that started this process, as `python benchmarks/<script> <args>`."""
    script = Path(sys.argv[0])
    name = f"benchmarks/{script.name}" if script.suffix == ".py" else str(script)
    return "python " + " ".join(shlex.quote(a) for a in [name, *sys.argv[1:]])


#: The paths whose uncommitted changes mark a run's code as not the commit's: the
#: library, the benchmark scripts and the project file (not the results they write).
CODE_PATHS = (
    ":(top)src",
    ":(top)benchmarks",
    ":(top,exclude)benchmarks/results",
    ":(top)pyproject.toml",
)


def code_version(root: Path = HERE.parent) -> str:
    """The short HEAD commit of the checkout at `root`, with `-dirty` when the library,
    the benchmark scripts or pyproject.toml differ from it (uncommitted or untracked);
    '' outside a git checkout. A result stamped `-dirty` was not made by the commit it
    names."""

    def git(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run(["git", *args], cwd=root, capture_output=True, text=True)

    try:
        head = git("rev-parse", "--short", "HEAD")
        if head.returncode != 0:
            return ""
        changed = git("status", "--porcelain", "--", *CODE_PATHS).stdout.strip()
    except OSError:
        return ""
    return head.stdout.strip() + ("-dirty" if changed else "")


def cores() -> int:
    """The cores this process may use (its CPU affinity where the platform has one)."""
    n = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return max(1, n or 1)


def run_record() -> dict:
    """`{command, machine, cores, date, load, code}` of this run (load: 1, 5, 15-min
    averages; code: `code_version()`)."""
    return {
        "command": command_line(),
        "machine": cpu_model(),
        "cores": os.cpu_count(),
        "date": datetime.now(UTC).isoformat(timespec="seconds"),
        "load": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
        "code": code_version(),
    }


def machine_info() -> dict:
    """Where and when: platform, CPU model, core count, load, library versions, date."""
    import diffrax
    import jax
    import numpy as np
    import scipy

    import jaxworm as jw

    return {
        "platform": platform.platform(),
        "cpu": cpu_model(),
        "cpus": os.cpu_count(),
        "load_average_at_start": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
        "python": sys.version.split()[0],
        "jax": jax.__version__,
        "diffrax": diffrax.__version__,
        "scipy": scipy.__version__,
        "numpy": np.__version__,
        "jaxworm": jw.__version__,
        "git_commit": code_version(),
        "device": str(jax.devices()[0]),
        "OPENBLAS_NUM_THREADS": os.environ.get("OPENBLAS_NUM_THREADS"),
        "date": datetime.now(UTC).isoformat(timespec="seconds"),
    }


def machine_line(m: dict) -> str:
    """One Markdown line naming the machine of `machine_info()`: CPU, cores, load, jax,
    date and commit."""
    return (
        f"Machine: {m['cpu']}, {m['cpus']} CPUs, load {m['load_average_at_start']}, "
        f"jax {m['jax']}; {m['date']}; commit {m['git_commit']}."
    )


def write_json(path: Path, obj, indent: int = 1) -> None:
    """Write `obj` as JSON, with this run's `run_record()` first when `obj` is a dict."""
    if isinstance(obj, dict) and "run" not in obj:
        obj = {"run": run_record(), **obj}
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(obj, indent=indent, default=_json_default))


def _json_default(o):
    import numpy as np

    if isinstance(o, (np.floating, np.integer, np.bool_)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if hasattr(o, "__array__"):  # a JAX array
        return np.asarray(o).tolist()
    return str(o)

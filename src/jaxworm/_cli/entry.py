"""`main`, the `jaxworm` console script: parse the arguments, run the command, and turn
usage errors and unusable files into one line on stderr and exit code 2."""

from __future__ import annotations

import os
import sys
import warnings

from .commands import COMMANDS
from .parser import build_parser
from .values import UsageError


def _warning(message, category, filename, lineno, file=None, line=None) -> None:
    """A warning as one line on stderr, as errors are (not Python's source excerpt)."""
    print(f"jaxworm: warning: {' '.join(str(message).split())}", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    """Entry point of the `jaxworm` console script; returns (and exits with) the exit code."""
    with warnings.catch_warnings():
        warnings.showwarning = _warning
        return _main(argv)


def _main(argv: list[str] | None) -> int:
    try:
        try:
            args = build_parser().parse_args(argv)
        except SystemExit as e:  # --help and --version print, then exit 0
            if argv is None:
                raise
            return e.code if isinstance(e.code, int) else 0
        code = COMMANDS[args.command].run(args)
    except UsageError as e:
        print(f"jaxworm: error: {' '.join(str(e).split())}", file=sys.stderr)
        code = 2
    except OSError as e:
        print(f"jaxworm: error: {e}", file=sys.stderr)
        code = 2
    except KeyboardInterrupt:
        if argv is not None:  # called from Python: the caller decides
            raise
        # What finished is saved (every save is atomic); leave now rather than wait for
        # the sweep's worker threads to end the chunks in flight, which a second Ctrl-C
        # during that wait would abort inside XLA.
        print("jaxworm: interrupted (result files keep what was finished)", file=sys.stderr)
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(130)
    if argv is None:
        sys.exit(code)
    return code

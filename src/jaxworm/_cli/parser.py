"""The argparse tree: `jaxworm [--version] COMMAND ...`, a subcommand per module of
`commands`, each adding its own options."""

from __future__ import annotations

import argparse

import jaxworm as jw

from .commands import COMMANDS
from .values import UsageError


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (no usage dump) and exit code 2."""

    def error(self, message):
        raise UsageError(message)


def build_parser() -> argparse.ArgumentParser:
    """The `jaxworm` parser, its subcommands in the order of `COMMANDS`."""
    parser = _Parser(
        prog="jaxworm",
        description=("Differentiable simulator of worm-inspired burrowing by crack propagation."),
    )
    parser.add_argument("--version", action="version", version=f"jaxworm {jw.__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for command in COMMANDS.values():
        command.add_parser(sub)
    return parser

"""The commands, one module each: `add_parser(sub)` adds its subcommand and options,
`run(args)` runs it and returns the exit code (0 ok, 1 a run not ok) or raises
`UsageError`."""

from . import animate, fig2, fig3, optimise, paper, simulate, sweep

#: Each command's module by its name, in the order `jaxworm --help` lists them.
COMMANDS = {
    "simulate": simulate,
    "sweep": sweep,
    "fig3": fig3,
    "optimise": optimise,
    "fig2": fig2,
    "animate": animate,
    "paper": paper,
}

"""The `jaxworm` command line: `jaxworm simulate` runs one scene and reports it;
`jaxworm sweep` solves a grid of scenes, saving as it goes; `jaxworm optimise` tunes
parameters within bounds by gradients through the solve; `jaxworm paper`, `fig2` and
`animate` reproduce the paper's figures and animate a run.

```
jaxworm simulate                                  # Table 1, 60 s, summary on stdout
jaxworm simulate --set omega=3*pi --set delta=pi/3 --json
jaxworm simulate --set t1=10 --preset accurate --plot out/
jaxworm sweep --grid omega=3*pi:5*pi:5 --grid delta=pi/6,pi/3 --set t1=10 --out s.npz
jaxworm optimise --set t1=10 --steps 20 --plot paths.png --heatmap s.npz
jaxworm paper --out out/                          # Fig. 2, 3 in two readings + the paper's numbers
```

Exit codes: 0 the run finished with status "ok"; 1 it finished with another status
(the summary or JSON is printed all the same); 2 a usage error (unknown parameter,
malformed or out-of-range value, bad option) or a file that cannot be used (a damaged
or foreign result file, another run's file at --out, an output another jaxworm process
is writing, a folder that does not exist or cannot be written), reported as one line on
stderr before anything is computed.

Result files (`sweep`, `optimise`, the grids of `paper`) are only ever replaced by the
same run: a sweep's file resumes the same sweep, an optimisation's --out the same
problem (from its last saved step); any other file there is refused unless --overwrite,
which discards whatever the file holds, a sweep's own finished chunks included.

Compiled programs are kept in JAX's persistent compilation cache, so a second run of the
same scene shape does not compile again: `~/.cache/jaxworm/jax` by default, or the
folder `JAXWORM_CACHE_DIR` names (set it empty to switch the cache off).

The package, a module per job:

- `values`: numbers and expressions in pi, and the NAME=VALUE forms of --set, --grid
  and --bound; the usage error;
- `parser`: the argparse tree, one subcommand per module of `commands`;
- `scenes`: the scene options every solving command shares, and the scene they give;
- `runtime`: the persistent compilation cache and multi-process runs;
- `report`: a run's summary, as JSON or text;
- `outputs`: output files and folders, checked before anything is computed;
- `commands`: one module per command, its options and its body;
- `entry`: `main`, the console script: parse, run, map errors to exit codes.
"""

from .entry import main as main
from .parser import build_parser as build_parser
from .values import parse_value as parse_value

__all__ = ["build_parser", "main", "parse_value"]

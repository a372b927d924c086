"""The `jaxworm` command line, in process: `main(argv)` runs one command as the
`jaxworm` console script would and returns its exit code (with `argv=None` it reads
`sys.argv` and exits, as the console script does); `build_parser()` is its argparse tree
(the CLI reference is generated from it).

Exit codes: 0 the run finished with status "ok"; 1 it finished with another status; 2 a
usage error or a file that cannot be used, reported as one line on stderr.

```python
from jaxworm.cli import main
code = main(["simulate", "--set", "t1=10", "--json"])   # prints the summary; 0 if ok
```
"""

from ._cli import build_parser as build_parser
from ._cli import main as main

__all__ = ["build_parser", "main"]

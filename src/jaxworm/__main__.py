"""`python -m jaxworm ...`: the command line (`jaxworm --help`)."""

import sys

from ._cli import main

sys.exit(main())

"""The paper's reported values, its Fig. 3 grid, and the comparison of a sweep with them."""

from ._reproduction import (
    PAPER as PAPER,
)
from ._reproduction import (
    compare_with_paper as compare_with_paper,
)
from ._reproduction import (
    format_comparison as format_comparison,
)
from ._reproduction import (
    format_readings as format_readings,
)
from ._reproduction import (
    mirror_sweep as mirror_sweep,
)
from ._reproduction import (
    paper_grid as paper_grid,
)
from ._reproduction import (
    zero_crossing as zero_crossing,
)

__all__ = [
    "PAPER",
    "compare_with_paper",
    "format_comparison",
    "format_readings",
    "mirror_sweep",
    "paper_grid",
    "zero_crossing",
]

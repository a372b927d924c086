"""Figures: the paper's Fig. 2 and Fig. 3, optimisation traces, and body animations.

matplotlib is imported when a figure is drawn, not when `jaxworm` is imported.
"""

from ._animate import animate as animate
from ._animate import ffmpeg_available as ffmpeg_available
from ._plot import (
    period_average as period_average,
)
from ._plot import (
    period_envelope as period_envelope,
)
from ._plot import (
    plot_fig2 as plot_fig2,
)
from ._plot import (
    plot_fig2_rows as plot_fig2_rows,
)
from ._plot import (
    plot_fig3 as plot_fig3,
)
from ._plot import (
    plot_fig3_panels as plot_fig3_panels,
)
from ._plot import (
    plot_optimisation as plot_optimisation,
)

__all__ = [
    "animate",
    "ffmpeg_available",
    "period_average",
    "period_envelope",
    "plot_fig2",
    "plot_fig2_rows",
    "plot_fig3",
    "plot_fig3_panels",
    "plot_optimisation",
]

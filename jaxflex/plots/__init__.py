"""Figures drawn from jaxflex results (never computing metrics themselves), and saving them.

Each figure is a plain Matplotlib figure (not registered with pyplot); the names below are the
ones a notebook or script needs, each defined in the module of its subject
(:mod:`jaxflex.plots.compare`, ...). The design page's interval figure is
``plot_design_intervals`` here, beside the fit's ``plot_intervals``.
"""

from jaxflex.plots._style import new_figure, save_figure
from jaxflex.plots.compare import plot_frf, plot_time
from jaxflex.plots.design import plot_design
from jaxflex.plots.design import plot_intervals as plot_design_intervals
from jaxflex.plots.diagnose import plot_diagnosis, plot_overlay
from jaxflex.plots.discover import plot_discovery
from jaxflex.plots.identify import plot_convergence, plot_fit, plot_intervals
from jaxflex.plots.prediction import plot_prediction

__all__ = [
    "new_figure",
    "plot_convergence",
    "plot_design",
    "plot_design_intervals",
    "plot_diagnosis",
    "plot_discovery",
    "plot_fit",
    "plot_frf",
    "plot_intervals",
    "plot_overlay",
    "plot_prediction",
    "plot_time",
    "save_figure",
]

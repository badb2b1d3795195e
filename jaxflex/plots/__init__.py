"""Figures drawn from jaxflex results (never computing metrics themselves), and saving them.

Each figure is a plain Matplotlib figure (not registered with pyplot); the names below are the
ones a notebook or script needs, each defined in the module of its subject
(:mod:`jaxflex.plots.compare`, ...). The design's interval figure is ``plot_design_intervals``
here, beside the fit's ``plot_intervals``. They are imported on first use, as the package's
top-level names are: drawing one figure loads only its module.
"""

from typing import TYPE_CHECKING

from jaxflex.plots._style import new_figure, save_figure

if TYPE_CHECKING:  # what static tools see; at run time __getattr__ imports each on first use
    from jaxflex.plots.compare import plot_frf, plot_time
    from jaxflex.plots.design import plot_design
    from jaxflex.plots.design import plot_intervals as plot_design_intervals
    from jaxflex.plots.diagnose import plot_diagnosis, plot_overlay
    from jaxflex.plots.discover import plot_discovery
    from jaxflex.plots.identify import plot_convergence, plot_fit, plot_intervals
    from jaxflex.plots.missing_torque import plot_missing_torque
    from jaxflex.plots.prediction import plot_prediction

_SOURCES: dict[str, tuple[str, str]] = {
    "plot_frf": ("compare", "plot_frf"),
    "plot_time": ("compare", "plot_time"),
    "plot_design": ("design", "plot_design"),
    "plot_design_intervals": ("design", "plot_intervals"),
    "plot_diagnosis": ("diagnose", "plot_diagnosis"),
    "plot_overlay": ("diagnose", "plot_overlay"),
    "plot_discovery": ("discover", "plot_discovery"),
    "plot_convergence": ("identify", "plot_convergence"),
    "plot_fit": ("identify", "plot_fit"),
    "plot_intervals": ("identify", "plot_intervals"),
    "plot_missing_torque": ("missing_torque", "plot_missing_torque"),
    "plot_prediction": ("prediction", "plot_prediction"),
}
"""Each lazily imported name: its module under ``jaxflex.plots`` and its name there."""
_QUALIFIED = {name: (f"{__name__}.{module}", attr) for name, (module, attr) in _SOURCES.items()}


def __getattr__(name: str):
    """A figure function, imported from its module on first use (PEP 562); a submodule too."""
    from jaxflex._lazy import lazy_attribute

    return lazy_attribute(__name__, name, _QUALIFIED, globals())


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


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
    "plot_missing_torque",
    "plot_overlay",
    "plot_prediction",
    "plot_time",
    "save_figure",
]

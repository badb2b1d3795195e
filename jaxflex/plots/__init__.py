"""Figures drawn from jaxflex results (never computing metrics themselves), and saving them."""

from jaxflex.plots._style import save_figure

__all__ = ["save_figure"]
